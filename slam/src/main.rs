//! `sonar-slam`: the SLAM of this crate as its own process.
//!
//! It takes the readings (`sonar/readings`) and the odometry (`robot/pose`), hands them to
//! [`sonar_slam::Slam`], and after every sweep publishes the estimate on
//! `sonar/slam_correction`: the `map → odom` transform with its covariance, the sweep's pose in
//! the map, and whether it is a fix; and on `sonar/slam_landmarks` the landmarks in the map with
//! their covariances. The fusion (`sonar-fusion --slam-correction`) places its
//! readings with it; it stays the grid engine, this process estimates and does nothing else.
//!
//! A reading newer than the newest odometry waits for the pose that covers its instant, for at
//! most [`MAX_POSE_WAIT`]: the sweep's pings are placed at the odometry of their own instants,
//! and a sweep is estimated when the first reading of the next arrives (or the readings stop for
//! [`SWEEP_IDLE`], or the process is stopped).

use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use clap::Parser;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::*;
use iceoryx2::service::ipc::Service as Ipc;
use iceoryx2::waitset::WaitSetRunResult;
use nalgebra::{Isometry2, Vector2};
use serde::Deserialize;
use sonar_common::ipc::{
    self, FeatureRecord, FeaturesHeader, IpcArgs, IpcError, MAX_FEATURES, Pose2D, Reading,
    SlamCorrection,
};
use sonar_common::throttle::Throttle;
use sonar_slam::message::{
    LandmarksStamp, Totals, correction_message, landmarks_snapshot, revision_message,
};
use sonar_slam::section::with_pipeline_features;
use sonar_slam::{FixState, Slam, SlamConfig, SlamSection, SweepEstimate};
use tracing::{debug, info, warn};

/// Longest a reading newer than the newest odometry waits for the pose that covers its instant
/// (the fusion's policy, `sonar_fusion::poses::MAX_POSE_WAIT`); after it, the reading is placed
/// at the newest pose there is.
const MAX_POSE_WAIT: Duration = Duration::from_millis(500);
/// Quiet time after which the readings of an unfinished sweep are estimated: the scan stopped (a
/// sweep of the paper's head takes seconds, its readings come every ~0.1 s).
const SWEEP_IDLE: Duration = Duration::from_secs(2);
/// How often the process wakes without readings: poses bring no wake-up, and a reading waiting
/// for its pose is looked at again this often.
const TICK: Duration = Duration::from_millis(10);
/// Odometry kept while no sweep is pending: readings arrive a few milliseconds after their
/// instant, so this is ample, and a robot driving with its sonar stopped keeps no more.
const ODOMETRY_KEPT: Duration = Duration::from_secs(10);
/// How often the publisher offers its last message to subscribers that joined since.
const REFRESH_PERIOD: Duration = Duration::from_secs(1);
/// Least time between two log lines about one kind of lost or refused input.
const LOG_PERIOD: Duration = Duration::from_secs(1);
/// An earlier sweep whose pose moved more than this (m, degrees) since it was last published is
/// published again as revised: below a centimetre grid's half cell and the heading at which a
/// wall 3 m away moves by one, so that the fusion, not this process, decides what is worth
/// re-fusing.
const REVISE_M: f64 = 0.005;
const REVISE_DEG: f64 = 0.1;

/// Estimates the robot's poses and the landmarks its sonar sees (walls, corners, posts) together,
/// from sonar/readings and the odometry of robot/pose, and publishes after every sweep the
/// correction of the odometry on sonar/slam_correction: the map → odom transform with its
/// covariance, the sweep's pose in the map, and "fix" or "no fix"; and the landmarks (walls,
/// points) with their covariances on sonar/slam_landmarks (docs/ipc.md).
///
/// The map's frame is the odometry's at the first sweep estimated. Without robot/pose nothing is
/// estimated (a sweep needs the odometry of its instant); the process says so once and waits.
///
/// Settings come from the `[slam]` table of --config (every field of the library's SlamConfig:
/// gates, kernel, fix limits, and in `[slam.features]` the feature extraction with the odometry's
/// error model in `[slam.features.odometry]`; `enabled` is sonar-pipeline's). The feature
/// extraction starts from the file's `[features]` (the head's pings, its echoes' cones, the range
/// offset `sonar calibrate-range` measured: the same head as the fusion's), with what
/// `[slam.features]` sets laid over it; other tables are ignored.
///
/// Examples:
///   sonar-slam
///   sonar-slam --config pipeline.toml
///   sonar-fusion --slam-correction   # the fusion places its readings with this correction
#[derive(Debug, Parser)]
#[command(version, verbatim_doc_comment)]
struct Args {
    /// Pipeline configuration file (TOML); its `[slam]` table is read, and `[features]` under
    /// `[slam.features]`; the others are ignored.
    #[arg(long, env = "SONAR_CONFIG")]
    config: Option<PathBuf>,
    #[command(flatten)]
    ipc: IpcArgs,
}

/// The part of a pipeline configuration file this process reads.
#[derive(Debug, Default, Deserialize)]
struct SlamFile {
    #[serde(default)]
    slam: SlamSection,
}

fn main() -> ExitCode {
    sonar_common::init_tracing();
    let args = Args::parse();
    sonar_common::report_exit("sonar-slam", run(&args))
}

fn load_config(path: Option<&Path>) -> Result<SlamConfig> {
    let Some(path) = path else {
        return Ok(SlamConfig::default());
    };
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    // Read as written first, for errors placed where they are; then with the head described by
    // [features] under what [slam.features] sets (`with_pipeline_features`).
    let table: toml::Table = sonar_common::toml_file::parse(&text)
        .map_err(|message| anyhow::anyhow!("{}: {message}", path.display()))?;
    let _: SlamFile = sonar_common::toml_file::parse(&text)
        .map_err(|message| anyhow::anyhow!("{}: {message}", path.display()))?;
    let file: SlamFile = with_pipeline_features(table).try_into().with_context(|| {
        format!(
            "{}: [features] as the SLAM reads it ([slam.features] over it)",
            path.display()
        )
    })?;
    Ok(file.slam.config)
}

fn run(args: &Args) -> Result<()> {
    let config = load_config(args.config.as_deref())?;
    let slam = Slam::new(config).context("invalid [slam] settings")?;
    sonar_common::ipc::catch_termination_requests();
    let node = args.ipc.node("sonar-slam")?;
    let ports = Ports::new(&node)?;
    let waitset = WaitSetBuilder::new()
        .create::<Ipc>()
        .map_err(|e| IpcError::new("create waitset", e))?;
    let readings_guard = waitset
        .attach_notification(&ports.readings_listener)
        .map_err(|e| IpcError::new("attach readings listener", e))?;
    let _tick_guard = waitset
        .attach_interval(TICK)
        .map_err(|e| IpcError::new("attach interval", e))?;
    info!(
        fix_max_sigma_m = config.fix_max_sigma_m,
        fix_max_sigma_deg = config.fix_max_sigma_deg,
        // The head as [features] (under [slam.features]) describes it.
        step_deg = config.features.sensor.step_deg,
        range_offset_m = config.features.range_offset_m,
        "sonar-slam ready: readings from {}, odometry from {}, corrections on {}, landmarks on {}",
        ipc::READINGS_SERVICE,
        ipc::POSE_SERVICE,
        ipc::SLAM_CORRECTION_SERVICE,
        ipc::SLAM_LANDMARKS_SERVICE
    );

    let mut process = Process::new(slam, &ports);
    loop {
        let mut readings = false;
        let result = waitset
            .wait_and_process_once_with_timeout(
                |id| {
                    readings |= id.has_event_from(&readings_guard);
                    CallbackProgression::Continue
                },
                TICK,
            )
            .map_err(|e| IpcError::new("wait", e))?;
        match result {
            WaitSetRunResult::TerminationRequest => break,
            // A stop and continue (SIGSTOP/SIGCONT) ends the wait too and must not end the
            // process; a SIGINT or SIGTERM is seen by the next wait.
            WaitSetRunResult::Interrupt => continue,
            _ => {}
        }
        if readings && let Err(e) = ports.readings_listener.try_wait(|_| {}) {
            warn!("readings listener: {e:?}");
        }
        process.turn(Instant::now(), PoseWait::Bounded)?;
    }
    // Stopping: what was delivered is estimated, the last sweep included, and published.
    process.turn(Instant::now(), PoseWait::None)?;
    if let Some(estimate) = process.slam.finish_sweep() {
        process.publish(&estimate);
    }
    info!(
        sweeps = process.sweeps,
        fixes = process.totals.fixes,
        refused = process.slam.refused(),
        landmarks = process.slam.landmark_count(),
        readings_lost = process.readings_lost,
        revisions = process.revisions,
        calibration = ?process.slam.calibration(),
        range_bias_m = ?process.slam.range_bias(),
        "sonar-slam stopped"
    );
    Ok(())
}

/// The process's iceoryx2 ports. Dropped before the node, leaving nothing in /dev/shm.
struct Ports {
    readings: Subscriber<Ipc, Reading, ()>,
    readings_listener: iceoryx2::port::listener::Listener<Ipc>,
    odometry: Subscriber<Ipc, Pose2D, ()>,
    corrections: Publisher<Ipc, SlamCorrection, ()>,
    landmarks: Publisher<Ipc, [FeatureRecord], FeaturesHeader>,
    landmarks_notifier: iceoryx2::port::notifier::Notifier<Ipc>,
}

impl Ports {
    fn new(node: &Node<Ipc>) -> Result<Self> {
        Ok(Self {
            readings: ipc::readings_service(node)?
                .subscriber_builder()
                .create()
                .map_err(|e| IpcError::new("create readings subscriber", e))?,
            readings_listener: ipc::wakeup_listener(node, ipc::READINGS_SERVICE)?,
            odometry: ipc::pose_service(node)?
                .subscriber_builder()
                .create()
                .map_err(|e| IpcError::new("create odometry subscriber", e))?,
            corrections: ipc::slam_correction_service(node)?
                .publisher_builder()
                .create()
                .map_err(|e| {
                    IpcError::new(
                        "create correction publisher (is another sonar-slam running?)",
                        e,
                    )
                })?,
            landmarks: ipc::slam_landmarks_service(node)?
                .publisher_builder()
                .initial_max_slice_len(MAX_FEATURES)
                .create()
                .map_err(|e| IpcError::new("create landmarks publisher", e))?,
            landmarks_notifier: ipc::wakeup_notifier(node, ipc::SLAM_LANDMARKS_SERVICE)?,
        })
    }
}

/// Whether a reading newer than the newest odometry waits for its pose.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum PoseWait {
    /// Up to [`MAX_POSE_WAIT`]: while running.
    Bounded,
    /// Not at all: when stopping.
    None,
}

/// The SLAM and what the loop keeps between turns.
struct Process<'a> {
    slam: Slam,
    ports: &'a Ports,
    /// Readings received and not yet given to the SLAM, with when they were received.
    queue: VecDeque<(Reading, Instant)>,
    /// Stamp of the newest odometry pose the SLAM took.
    newest_odometry_ns: Option<u64>,
    /// The SLAM holds readings of a sweep not yet estimated.
    sweep_open: bool,
    last_reading: Instant,
    last_refresh: Instant,
    next_seq: Option<u64>,
    readings_lost: u64,
    sweeps: u64,
    totals: Totals,
    lost_log: Throttle,
    odometry_log: Throttle,
    said_no_odometry: bool,
    /// Each sweep's pose in the map as last published, in the order of the trajectory.
    published: Vec<Isometry2<f64>>,
    /// Revised sweeps published.
    revisions: u64,
}

impl<'a> Process<'a> {
    fn new(slam: Slam, ports: &'a Ports) -> Self {
        let now = Instant::now();
        Self {
            slam,
            ports,
            queue: VecDeque::new(),
            newest_odometry_ns: None,
            sweep_open: false,
            last_reading: now,
            last_refresh: now,
            next_seq: None,
            readings_lost: 0,
            sweeps: 0,
            totals: Totals::default(),
            lost_log: Throttle::new(LOG_PERIOD),
            odometry_log: Throttle::new(LOG_PERIOD),
            said_no_odometry: false,
            published: Vec::new(),
            revisions: 0,
        }
    }

    /// Takes what arrived, gives the SLAM every reading whose odometry is there (or waited long
    /// enough), estimates a sweep the readings stopped in, and publishes.
    fn turn(&mut self, now: Instant, pose_wait: PoseWait) -> Result<()> {
        self.take_odometry()?;
        self.receive_readings(now)?;
        while let Some(&(reading, received)) = self.queue.front() {
            let covered = self
                .newest_odometry_ns
                .is_some_and(|t| t >= reading.host_stamp_ns);
            if pose_wait == PoseWait::Bounded
                && !covered
                && now.saturating_duration_since(received) < MAX_POSE_WAIT
            {
                break;
            }
            self.queue.pop_front();
            if self.newest_odometry_ns.is_none() {
                self.no_odometry();
            }
            if let Some(estimate) = self.slam.push_reading(&reading) {
                self.publish(&estimate);
            }
            self.sweep_open = true;
        }
        if self.sweep_open
            && self.queue.is_empty()
            && now.saturating_duration_since(self.last_reading) >= SWEEP_IDLE
        {
            self.sweep_open = false;
            if let Some(estimate) = self.slam.finish_sweep() {
                self.publish(&estimate);
            }
        }
        if now.saturating_duration_since(self.last_refresh) >= REFRESH_PERIOD {
            self.last_refresh = now;
            if let Err(e) = self.ports.corrections.update_connections() {
                warn!("update connections: {e:?}");
            }
            if let Err(e) = self.ports.landmarks.update_connections() {
                warn!("update connections: {e:?}");
            }
        }
        Ok(())
    }

    fn take_odometry(&mut self) -> Result<()> {
        while let Some(sample) = self
            .ports
            .odometry
            .receive()
            .map_err(|e| IpcError::new("receive odometry", e))?
        {
            let p = *sample.payload();
            let pose = Isometry2::new(
                Vector2::new(f64::from(p.x_m), f64::from(p.y_m)),
                f64::from(p.theta_rad),
            );
            if self.slam.push_odometry(p.stamp_ns, pose) {
                self.newest_odometry_ns = Some(p.stamp_ns);
                if self.queue.is_empty() && !self.sweep_open {
                    let kept = u64::try_from(ODOMETRY_KEPT.as_nanos()).unwrap_or(u64::MAX);
                    self.slam
                        .forget_odometry_before(p.stamp_ns.saturating_sub(kept));
                }
            } else if let Some(left_out) = self.odometry_log.allow(Instant::now()) {
                warn!(pose = ?p, left_out, "odometry refused: older than the last, or not finite");
            }
        }
        Ok(())
    }

    fn receive_readings(&mut self, now: Instant) -> Result<()> {
        while let Some(sample) = self
            .ports
            .readings
            .receive()
            .map_err(|e| IpcError::new("receive reading", e))?
        {
            let reading = *sample.payload();
            if let Some(expected) = self.next_seq
                && reading.seq > expected
            {
                let lost = reading.seq - expected;
                self.readings_lost += lost;
                if let Some(left_out) = self.lost_log.allow(now) {
                    warn!(
                        lost,
                        left_out, "readings lost before sonar-slam took them (a full buffer)"
                    );
                }
            }
            self.next_seq = Some(reading.seq + 1);
            self.last_reading = now;
            self.queue.push_back((reading, now));
        }
        Ok(())
    }

    /// Says once that sweeps go unestimated for want of odometry.
    fn no_odometry(&mut self) {
        if !self.said_no_odometry {
            self.said_no_odometry = true;
            warn!(
                "no odometry on {}: sweeps are not estimated until a pose arrives (a sweep's \
                 pings are placed at the odometry of their instants)",
                ipc::POSE_SERVICE
            );
        }
    }

    fn publish(&mut self, estimate: &SweepEstimate) {
        self.sweeps += 1;
        if estimate.state == FixState::Fix {
            self.totals.fixes += 1;
        }
        self.totals.landmarks = self.slam.landmark_count();
        self.totals.refused = self.slam.refused();
        let message = correction_message(estimate, self.totals);
        debug!(
            sweep = estimate.sweep_id,
            state = ?estimate.state,
            matched = estimate.matched,
            observations = estimate.observations,
            landmarks = self.totals.landmarks,
            sigma_x_m = estimate.covariance[(0, 0)].sqrt(),
            sigma_y_m = estimate.covariance[(1, 1)].sqrt(),
            sigma_deg = estimate.covariance[(2, 2)].sqrt().to_degrees(),
            "sweep estimated"
        );
        if let Err(e) = self.ports.corrections.send_copy(message) {
            warn!("send correction: {e:?}");
        }
        self.publish_revisions();
        self.publish_landmarks(estimate);
    }

    /// The landmarks as estimated after `estimate`'s sweep, on sonar/slam_landmarks.
    fn publish_landmarks(&mut self, estimate: &SweepEstimate) {
        let (header, records) = landmarks_snapshot(
            &self.slam.landmarks(),
            LandmarksStamp {
                seq: self.sweeps,
                stamp_ns: estimate.stamp_ns,
                sweep_id: estimate.sweep_id,
                sweeps: self.sweeps,
            },
        );
        if let Err(e) = ipc::send_snapshot(
            &self.ports.landmarks,
            &self.ports.landmarks_notifier,
            header,
            &records,
        ) {
            warn!("landmarks not published: {e}");
        }
    }

    /// Publishes every earlier sweep that the latest estimate moved (beyond [`REVISE_M`] or
    /// [`REVISE_DEG`]) with its pose as estimated now.
    fn publish_revisions(&mut self) {
        let trajectory = self.slam.trajectory();
        let mut revised = 0;
        for (k, sweep) in trajectory.iter().enumerate() {
            let Some(published) = self.published.get_mut(k) else {
                self.published.push(sweep.pose);
                continue;
            };
            let moved = published.inverse() * sweep.pose;
            if moved.translation.vector.norm() <= REVISE_M
                && moved.rotation.angle().abs() <= REVISE_DEG.to_radians()
            {
                continue;
            }
            *published = sweep.pose;
            revised += 1;
            if let Err(e) = self
                .ports
                .corrections
                .send_copy(revision_message(sweep, self.totals))
            {
                warn!("send revision: {e:?}");
            }
        }
        if revised > 0 {
            self.revisions += revised;
            debug!(revised, sweeps = trajectory.len(), "earlier sweeps revised");
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A configuration file in the temporary directory, removed when dropped.
    struct TempFile(PathBuf);

    impl Drop for TempFile {
        fn drop(&mut self) {
            let _ = std::fs::remove_file(&self.0);
        }
    }

    fn file(text: &str) -> TempFile {
        use std::sync::atomic::{AtomicU32, Ordering};
        static COUNT: AtomicU32 = AtomicU32::new(0);
        let path = std::env::temp_dir().join(format!(
            "sonar-slam-test-{}-{}.toml",
            std::process::id(),
            COUNT.fetch_add(1, Ordering::Relaxed)
        ));
        std::fs::write(&path, text).unwrap_or_else(|e| panic!("write {path:?}: {e}"));
        TempFile(path)
    }

    #[test]
    fn the_slam_table_is_read_and_the_others_ignored() {
        let f = file("[fusion]\ncells = 10\n\n[slam]\nenabled = true\nfix_max_sigma_m = 0.08\n");
        let config = load_config(Some(&f.0)).unwrap_or_else(|e| panic!("{e:#}"));
        assert_eq!(config.fix_max_sigma_m, 0.08);
        assert_eq!(config.gate_chi2, SlamConfig::default().gate_chi2);
        assert_eq!(load_config(None).ok(), Some(SlamConfig::default()));
    }

    #[test]
    fn the_head_and_its_calibration_come_from_the_features_table() {
        // What `sonar calibrate-range` prints, and the head of examples/nxt-head.toml.
        let text = format!(
            "{}\n[features]\nrange_offset_m = -0.024\nrange_offset_sigma_m = 0.003\n\n[slam]\nenabled = true\n",
            include_str!("../../examples/nxt-head.toml")
        );
        let f = file(&text);
        let config = load_config(Some(&f.0)).unwrap_or_else(|e| panic!("{e:#}"));
        assert_eq!(config.features.range_offset_m, -0.024);
        assert_eq!(config.features.range_offset_sigma_m, 0.003);
        assert_eq!(config.features.sensor.step_deg, 3.0);
        assert_eq!(config.features.echo.specular_cutoff_deg, 20.0);
        // A mistake in [features] is this process's error too.
        let f = file("[features]\nrange_offset_m = \"short\"\n");
        let e = format!(
            "{:#}",
            load_config(Some(&f.0)).err().unwrap_or_else(|| panic!())
        );
        assert!(e.contains("[features] as the SLAM reads it"), "{e}");
    }

    #[test]
    fn a_bad_slam_table_is_a_clear_error() {
        let f = file("[slam]\nfix_max_sigma_m = \"big\"\n");
        let e = format!(
            "{:#}",
            load_config(Some(&f.0)).err().unwrap_or_else(|| panic!())
        );
        assert!(e.contains("line 2") && e.contains("fix_max_sigma_m"), "{e}");
        let f = file("[slam]\nno_such_key = 1\n");
        let e = format!(
            "{:#}",
            load_config(Some(&f.0)).err().unwrap_or_else(|| panic!())
        );
        assert!(e.contains("no_such_key"), "{e}");
        // A value the library refuses is refused as the file is read.
        let f = file("[slam]\ngate_chi2 = -1.0\n");
        let e = format!(
            "{:#}",
            load_config(Some(&f.0)).err().unwrap_or_else(|| panic!())
        );
        assert!(e.contains("gate_chi2"), "{e}");
        let missing = std::env::temp_dir().join("sonar-slam-test-no-such-file.toml");
        let e = format!(
            "{:#}",
            load_config(Some(&missing))
                .err()
                .unwrap_or_else(|| panic!())
        );
        assert!(e.contains("cannot read"), "{e}");
    }
}
