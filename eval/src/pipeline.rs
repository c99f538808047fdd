//! The pipeline without its transport: simulator → protocol lines → driver decoder → readings →
//! fusion, all in one process, on the simulator's virtual clock.
//!
//! Nothing here re-implements a piece of the pipeline. The device is the simulator's
//! [`NativeDevice`] (its firmware state machine and echo model, encoding real protocol lines), the
//! lines are cut by the same [`LineFramer`] and decoded by the same [`Decoder`] with the same
//! [`PingPolicy`] as in `sonar-driver`, and the readings go through [`Observation::from_reading`]
//! into a [`Mapper`] as in the fusion process. Only the pseudo-terminal, the pacing against wall
//! time and iceoryx2 are left out, so a run is a pure function of the scene, the scan, the number
//! of sweeps and the seed.

use anyhow::{Context, Result, bail, ensure};
use nalgebra::Isometry2;
use sonar_common::ipc::Reading;
use sonar_common::protocol::{
    DeviceMessage, FramedLine, HostCommand, LineFramer, PROTOCOL_VERSION, Terminators,
    encode_command,
};
use sonar_common::sensor::SensorConfig;
use sonar_driver::averaging::PingPolicy;
use sonar_driver::decoder::{Decoded, Decoder, Dialect};
use sonar_fusion::{FusionConfig, Mapper, Observation, Preset};
use sonar_sim::{
    Carrier, Device, EchoModel, Firmware, NativeDevice, OdometryParams, Pose, PoseSample, Post,
    Rover, Scene, SensorProfile, Surface, Timing, Vec2, Wall, act_carried, report_sweeps,
};

use std::str::FromStr;

use crate::metrics::{MapKind, MapView};

/// The scan the host asks for after the handshake, as `sonar-driver --scan` does.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Scan {
    Full,
    /// A local segment, degrees.
    Local {
        from_deg: f64,
        to_deg: f64,
    },
}

impl Scan {
    /// The command the driver sends for it (angles rounded to centidegrees like the driver's).
    pub fn command(self) -> HostCommand {
        match self {
            Scan::Full => HostCommand::FullScan,
            Scan::Local { from_deg, to_deg } => HostCommand::LocalScan {
                from_cdeg: (from_deg * 100.0).round() as i32,
                to_cdeg: (to_deg * 100.0).round() as i32,
            },
        }
    }

    /// The scene's suggested scan, or a full scan when it has none.
    pub fn for_scene(scene: &Scene) -> Self {
        match scene.scan {
            Some(sonar_sim::SuggestedScan::Local { from_deg, to_deg }) => {
                Scan::Local { from_deg, to_deg }
            }
            Some(sonar_sim::SuggestedScan::Full) | None => Scan::Full,
        }
    }

    /// The bearings (degrees) the beams of this scan can reach: the swept sector widened by the
    /// beam half-angle on each side.
    pub fn reach_deg(self, sensor: &SensorConfig) -> (f64, f64) {
        let half = f64::from(sensor.beam_half_angle_deg);
        let (a, b) = match self {
            Scan::Full => (
                f64::from(sensor.sweep_min_deg),
                f64::from(sensor.sweep_max_deg),
            ),
            Scan::Local { from_deg, to_deg } => (from_deg, to_deg),
        };
        (a - half, b + half)
    }
}

/// What came over the (virtual) serial line.
#[derive(Debug, Clone, Default)]
pub struct Capture {
    /// The driver's readings, in order, from the complete sweeps only.
    pub readings: Vec<Reading>,
    /// Complete sweeps captured.
    pub sweeps: u32,
    /// Lines the device wrote.
    pub lines: u64,
    /// Simulated time at the end, seconds.
    pub duration_s: f64,
}

/// Runs `scene` through the simulated device and the driver's decoder for `sweeps` complete
/// sweeps of `scan`, with the echo noise seeded by `seed`.
pub fn capture(scene: Scene, scan: Scan, sweeps: u32, seed: u64) -> Result<Capture> {
    let head = Head::default();
    capture_with(scene, head, scan, sweeps, seed)
}

/// A sensor profile, or `default`: the simulator's calibration without a profile (the one
/// behind the paper scenes' figures).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ProfileChoice(pub Option<SensorProfile>);

impl FromStr for ProfileChoice {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        if s == "default" {
            return Ok(Self(None));
        }
        s.parse::<SensorProfile>()
            .map(|p| Self(Some(p)))
            .map_err(|e| format!("{e}, or default"))
    }
}

impl std::fmt::Display for ProfileChoice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self.0 {
            Some(p) => write!(f, "{p}"),
            None => f.write_str("default"),
        }
    }
}

/// The simulated head's geometry and timing: the paper's by default, a sensor profile's
/// otherwise ([`Head::of`]).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Head {
    pub sensor: SensorConfig,
    pub timing: Timing,
}

impl Head {
    /// The head a scene's sensor profile gives it, the paper's without one.
    pub fn of(scene: &Scene) -> Self {
        scene.profile.map_or_else(Self::default, |p| Self {
            sensor: p.sensor(),
            timing: p.timing(),
        })
    }
}

/// As [`capture`], with the device's geometry and timing `head`.
pub fn capture_with(
    scene: Scene,
    head: Head,
    scan: Scan,
    sweeps: u32,
    seed: u64,
) -> Result<Capture> {
    ensure!(sweeps > 0, "at least one sweep is needed");
    run_device(scene, head, scan, seed, Until::Sweeps(sweeps), None)
}

/// A capture with the head on the scene's robot, and the robot's poses.
#[derive(Debug, Clone)]
pub struct TourCapture {
    pub capture: Capture,
    /// The true and odometry poses at the pose rate, from simulated time 0 to the end; the
    /// readings' `host_stamp_ns` and these `t_us` are the same virtual clock (ns = µs × 1000).
    pub poses: Vec<PoseSample>,
    /// Distance the robot truly drove, metres.
    pub driven_m: f64,
}

/// Runs `scene` with its `[robot]` touring, as `sonar-sim` does ([`act_carried`] around a
/// [`Rover`]: each action's pings from the robot's true pose of that instant, the robot told of
/// every sweep begun and ended), until the first sweep to end once the robot has driven
/// `metres`; the odometry with `odometry`'s errors, sampled at `pose_rate_hz` of simulated time.
/// `seed` seeds both the echo noise and the odometry's, as `sonar-sim --seed` does.
pub fn capture_tour(
    scene: Scene,
    scan: Scan,
    metres: f64,
    odometry: OdometryParams,
    pose_rate_hz: f64,
    seed: u64,
) -> Result<TourCapture> {
    ensure!(
        metres.is_finite() && metres > 0.0,
        "a tour must be longer than 0 m, got {metres}"
    );
    ensure!(
        pose_rate_hz.is_finite() && pose_rate_hz > 0.0,
        "the pose rate must be a positive number, got {pose_rate_hz}"
    );
    odometry
        .validate()
        .map_err(|e| anyhow::anyhow!("odometry: {e}"))?;
    let spec = scene
        .robot
        .clone()
        .with_context(|| format!("scene {} has no [robot] to tour with", scene.name))?;
    let mut robot = Robot {
        rover: Rover::new(&spec, odometry, pose_rate_hz, seed),
        poses: Vec::new(),
        driven_m: 0.0,
    };
    let head = Head::of(&scene);
    let capture = run_device(
        scene,
        head,
        scan,
        seed,
        Until::Driven(metres),
        Some(&mut robot),
    )?;
    Ok(TourCapture {
        capture,
        poses: robot.poses,
        driven_m: robot.driven_m,
    })
}

/// The robot of a tour as `sonar-sim` drives it, keeping every pose sample it takes.
struct Robot {
    rover: Rover,
    poses: Vec<PoseSample>,
    driven_m: f64,
}

impl Carrier for Robot {
    fn advance(&mut self, now_us: u64, _unix_ns: &dyn Fn(u64) -> u64) -> std::io::Result<Pose> {
        let Self {
            rover,
            poses,
            driven_m,
        } = self;
        Ok(rover.advance(now_us, |sample| {
            if let Some(last) = poses.last() {
                *driven_m += (sample.truth.at - last.truth.at).norm();
            }
            poses.push(sample);
        }))
    }

    fn sweep_started(&mut self) {
        self.rover.sweep_started();
    }

    fn sweep_ended(&mut self, now_us: u64) {
        self.rover.sweep_ended(now_us);
    }
}

/// When a capture ends.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Until {
    /// After this many complete sweeps.
    Sweeps(u32),
    /// At the first sweep to end once the robot has driven this many metres.
    Driven(f64),
}

/// The simulated device (on `robot`, if any) and the driver's side of the line until `until`.
fn run_device(
    scene: Scene,
    head: Head,
    scan: Scan,
    seed: u64,
    until: Until,
    mut robot: Option<&mut Robot>,
) -> Result<Capture> {
    let sensor = head.sensor;
    let name = scene.name.clone();
    let model = EchoModel::new(scene, sensor, seed).context("setting up the echo model")?;
    let firmware = Firmware::new(sensor, head.timing, model).context("setting up the firmware")?;
    let mut device = NativeDevice::new(firmware);
    let mut host = Host::new(sensor);
    // The virtual clock stamps the robot's poses as it stamps the readings.
    let virtual_ns = |t_us: u64| t_us * 1000;
    let mut sweeps_seen = device.sweeps();

    // The driver's session: HELLO, adopt the device's geometry, request the scan.
    let mut out = Vec::new();
    device.receive(
        encode_command(
            &HostCommand::Hello {
                version: PROTOCOL_VERSION.number(),
            },
            PROTOCOL_VERSION,
        )
        .as_bytes(),
        &mut out,
    );
    host.feed(&out, 0)?;
    let hello = host
        .hello
        .clone()
        .context("the simulated device did not answer HELLO")?;
    host.decoder.adopt_device_geometry(&hello);
    out.clear();
    device.receive(
        encode_command(&scan.command(), PROTOCOL_VERSION).as_bytes(),
        &mut out,
    );
    report_sweeps(&device, carrier(&mut robot), &mut sweeps_seen);
    host.feed(&out, device.now_us())?;
    if let Some(err) = &host.device_error {
        bail!("the device refused the scan {scan:?}: {err}");
    }

    // Then the device's actions (one motor step, ping or the rest of a ping's interval each)
    // until `until`. A full sweep is about 600 actions, a metre of a tour under 2 500 (5 s
    // driving, a sweep standing); the bound only guards against a device that never ends a
    // sweep or a robot that never gets there.
    let limit = match until {
        Until::Sweeps(sweeps) => 10_000 * u64::from(sweeps),
        Until::Driven(metres) => 10_000 + (metres * 4_000.0) as u64,
    };
    let mut done = false;
    for _ in 0..limit {
        out.clear();
        let busy = act_carried(
            &mut device,
            carrier(&mut robot),
            &virtual_ns,
            &mut sweeps_seen,
            &mut out,
        )?;
        let ended_before = host.sweeps_ended;
        host.feed(&out, device.now_us())?;
        done = match until {
            Until::Sweeps(sweeps) => host.sweeps_ended >= sweeps,
            Until::Driven(metres) => {
                host.sweeps_ended > ended_before
                    && robot.as_ref().is_some_and(|r| r.driven_m >= metres)
            }
        };
        if done {
            break;
        }
        ensure!(
            busy,
            "the device went idle after {} sweeps",
            host.sweeps_ended
        );
    }
    ensure!(
        done,
        "scene {name}: {until:?} not reached in {limit} device actions ({} sweeps)",
        host.sweeps_ended
    );
    host.readings.truncate(host.readings_at_last_end);
    Ok(Capture {
        readings: host.readings,
        sweeps: host.sweeps_ended,
        lines: host.lines,
        duration_s: device.now_us() as f64 / 1e6,
    })
}

/// The robot as the simulator's [`Carrier`], if there is one.
fn carrier<'a>(robot: &'a mut Option<&mut Robot>) -> Option<&'a mut dyn Carrier> {
    robot.as_deref_mut().map(|r| r as &mut dyn Carrier)
}

/// The driver's side of the line, without the port and iceoryx2.
struct Host {
    framer: LineFramer,
    decoder: Decoder,
    readings: Vec<Reading>,
    hello: Option<DeviceMessage>,
    device_error: Option<String>,
    sweeps_ended: u32,
    readings_at_last_end: usize,
    lines: u64,
}

impl Host {
    fn new(sensor: SensorConfig) -> Self {
        Self {
            framer: LineFramer::new(Terminators::Newline),
            // The hobby angle offset is unused by the native dialect; -90 is the driver's default.
            decoder: Decoder::new(Dialect::Native, sensor, PingPolicy::default(), -90.0),
            readings: Vec::new(),
            hello: None,
            device_error: None,
            sweeps_ended: 0,
            readings_at_last_end: 0,
            lines: 0,
        }
    }

    /// Feeds the device's lines through the framer and the decoder; `now_us` (simulated) stamps
    /// the readings, so runs repeat bit for bit.
    fn feed(&mut self, lines: &[String], now_us: u64) -> Result<()> {
        let mut result = Ok(());
        for line in lines {
            self.lines += 1;
            let Self {
                framer,
                decoder,
                readings,
                hello,
                device_error,
                sweeps_ended,
                readings_at_last_end,
                ..
            } = self;
            framer.push(line.as_bytes(), |item| {
                if result.is_err() {
                    return;
                }
                let FramedLine::Line(bytes) = item else {
                    result = Err(anyhow::anyhow!("the device wrote an overlong line"));
                    return;
                };
                match decoder.decode(bytes, now_us * 1000) {
                    Ok(Decoded::Reading(r)) => readings.push(r),
                    Ok(Decoded::Message(msg)) => match msg {
                        DeviceMessage::Hello { .. } => *hello = Some(msg),
                        DeviceMessage::SweepEnd { .. } => {
                            *sweeps_ended += 1;
                            *readings_at_last_end = readings.len();
                        }
                        DeviceMessage::Error { code, text } => {
                            *device_error = Some(format!("{code:?}: {text}"));
                        }
                        _ => {}
                    },
                    Err(e) => {
                        result = Err(anyhow::anyhow!(
                            "the driver rejected the device's line {:?}: {e}",
                            String::from_utf8_lossy(bytes)
                        ));
                    }
                }
            });
        }
        result
    }
}

/// The maps of one run under one fusion preset.
#[derive(Debug)]
pub struct Maps {
    pub preset: Preset,
    pub mapper: Mapper,
}

impl Maps {
    /// Fuses `readings` (taken at the origin, the robot standing still) with `preset`.
    pub fn fuse(readings: &[Reading], preset: Preset) -> Result<Self> {
        let mut mapper = Mapper::new(FusionConfig::preset(preset))
            .with_context(|| format!("setting up the {preset} preset"))?;
        for r in readings {
            mapper
                .update(&Observation::from_reading(r, Isometry2::identity()))
                .with_context(|| format!("fusing reading {}", r.seq))?;
        }
        mapper.close_region();
        Ok(Self { preset, mapper })
    }

    /// The probability grid, for the metrics.
    pub fn probability(&self) -> MapView {
        probability_view(&self.mapper)
    }

    /// The basic method's display: the radar array drawn as arcs across the beam, as
    /// [`sonar_fusion::RadarMap::rasterise_into`] draws it.
    pub fn basic(&self, beam_half_angle_deg: f32) -> MapView {
        let g = *self.mapper.grid().geometry();
        let mut bytes = vec![0u8; g.len()];
        self.mapper.radar().rasterise_into(
            &g,
            &Isometry2::identity(),
            beam_half_angle_deg.to_radians(),
            &mut bytes,
        );
        let cells = bytes
            .iter()
            .map(|&b| sonar_common::ipc::decode_probability(b))
            .collect();
        MapView::new(g, MapKind::Basic, cells)
    }
}

/// A mapper's probability grid as a [`MapView`], for the metrics.
pub fn probability_view(mapper: &Mapper) -> MapView {
    let grid = mapper.grid();
    let g = *grid.geometry();
    let n = g.cells_per_side();
    let cells = (0..n)
        .flat_map(|y| (0..n).map(move |x| (x, y)))
        .map(|(x, y)| grid.probability(x, y))
        .collect();
    MapView::new(g, MapKind::Probability, cells)
}

/// Post radius of the paper's small obstacles: 5 cm across.
pub const POST_RADIUS_M: f64 = 0.025;

/// The spacing sweep's scene: two 5 cm posts 1 m ahead, centres `spacing_m` apart symmetric about
/// the axis, in front of a 3 m wall 2 m ahead; the built-in `two-obstacles` scene at 0.30 m.
pub fn two_posts(spacing_m: f64) -> Result<Scene> {
    ensure!(
        spacing_m > 2.0 * POST_RADIUS_M,
        "posts {spacing_m} m apart would overlap"
    );
    let post = |y: f64| Post {
        centre: Vec2::new(1.0, y),
        radius: POST_RADIUS_M,
        surface: Surface::Hard,
    };
    let wall = Wall {
        a: Vec2::new(2.0, -1.5),
        b: Vec2::new(2.0, 1.5),
        surface: Surface::Hard,
    };
    let name = format!("two-posts-{:.0}cm", spacing_m * 100.0);
    let mut scene = Scene::new(
        &name,
        vec![wall],
        vec![post(spacing_m / 2.0), post(-spacing_m / 2.0)],
    )?;
    scene.scan = Some(sonar_sim::SuggestedScan::Local {
        from_deg: -45.0,
        to_deg: 45.0,
    });
    Ok(scene)
}

#[cfg(test)]
mod tests {
    use super::*;
    use sonar_common::ipc::flags;

    #[test]
    fn the_spacing_scene_at_30_cm_is_the_built_in_two_obstacles_scene() {
        let built = two_posts(0.30).unwrap();
        let builtin = Scene::builtin("two-obstacles").unwrap();
        assert_eq!(built.walls(), builtin.walls());
        let mut a = built.posts().to_vec();
        let mut b = builtin.posts().to_vec();
        a.sort_by(|p, q| p.centre.y.total_cmp(&q.centre.y));
        b.sort_by(|p, q| p.centre.y.total_cmp(&q.centre.y));
        assert_eq!(a.len(), b.len());
        for (p, q) in a.iter().zip(&b) {
            assert!((p.centre - q.centre).norm() < 1e-12 && p.radius == q.radius);
        }
        assert_eq!(built.scan, builtin.scan);
        assert_eq!(built.echo, builtin.echo);
        assert_eq!(built.noise, builtin.noise);
        assert!(two_posts(0.05).is_err());
    }

    #[test]
    fn a_local_scan_yields_whole_sweeps_of_decoded_readings() {
        let scene = Scene::builtin("obstacle").unwrap();
        let cap = capture(
            scene,
            Scan::for_scene(&Scene::builtin("obstacle").unwrap()),
            3,
            7,
        )
        .unwrap();
        // −45°…45° holds the reading centres −45, −39, …, 45: 16 per sweep.
        assert_eq!(cap.readings.len(), 3 * 16);
        assert_eq!(cap.sweeps, 3);
        let sweep_ids: Vec<u32> = cap.readings.iter().map(|r| r.sweep_id).collect();
        assert_eq!(sweep_ids[0], 1);
        assert_eq!(sweep_ids[47], 3);
        // Back and forth: the second sweep runs the other way.
        assert_eq!(cap.readings[0].angle_deg, -45.0);
        assert_eq!(cap.readings[16].angle_deg, 45.0);
        // Straight ahead of the post the driver reports its near face, 0.975 m (plus up to two
        // cycles of late detection); far off the axis, the wall's perpendicular foot is outside
        // the specular cut-off and the beam: no echo.
        let at = |deg: f32| cap.readings.iter().find(|r| r.angle_deg == deg).unwrap();
        let ahead = at(3.0);
        assert!(ahead.is_valid_range());
        assert!((0.97..0.99).contains(&ahead.distance_m), "{ahead:?}");
        assert!(at(45.0).has(flags::NO_ECHO), "{:?}", at(45.0));
    }

    #[test]
    fn runs_repeat_with_the_seed_and_differ_without_it() {
        let run = |seed| {
            let scene = Scene::builtin("two-obstacles").unwrap();
            let scan = Scan::for_scene(&scene);
            capture(scene, scan, 2, seed)
                .unwrap()
                .readings
                .iter()
                .map(|r| r.echo_us)
                .collect::<Vec<_>>()
        };
        assert_eq!(run(3), run(3));
        assert_ne!(run(3), run(4));
    }

    #[test]
    fn a_full_scan_sweeps_all_fifty_reading_centres() {
        let scene = Scene::builtin("room").unwrap();
        let cap = capture(scene, Scan::Full, 1, 1).unwrap();
        assert_eq!(cap.readings.len(), 50);
        assert_eq!(cap.readings[0].angle_deg, -147.0);
        assert_eq!(cap.readings[49].angle_deg, 147.0);
        // Facing a wall 1.2 m away.
        let ahead = cap.readings.iter().find(|r| r.angle_deg == 3.0).unwrap();
        assert!((ahead.distance_m - 1.2).abs() < 0.015, "{ahead:?}");
    }

    #[test]
    fn a_scan_the_device_refuses_is_an_error() {
        let scene = Scene::builtin("obstacle").unwrap();
        let bad = Scan::Local {
            from_deg: 160.0,
            to_deg: 170.0,
        };
        let err = capture(scene, bad, 1, 1).unwrap_err().to_string();
        assert!(err.contains("refused"), "{err}");
    }
}
