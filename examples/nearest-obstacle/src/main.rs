//! `sonar-nearest-obstacle`: an example consumer of `sonar/grid` in a hundred lines.
//!
//! It sleeps on the grid's wake-up event (no polling), and for every snapshot finds the occupied
//! cell closest to the sensor pose in the header. When that is nearer than `--threshold` it prints
//!
//! ```text
//! bearing <degrees> distance <metres>
//! ```
//!
//! once per snapshot: the bearing of the cell's centre counter-clockwise from the sensor's forward
//! axis (the robot's heading `pose_theta_rad`; 0° straight ahead, +90° to the left), in
//! [-180, 180), and its distance from the sensor. Logs go to stderr, alerts alone to stdout; the
//! nearest occupied cell is logged once a second whether it alerts or not, so a quiet terminal
//! means nothing is near, not that nothing works.

use std::io::Write;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::Parser;
use iceoryx2::prelude::*;
use iceoryx2::service::ipc::Service as Ipc;
use iceoryx2::waitset::WaitSetRunResult;
use sonar_common::ipc::{self, GridHeader, IpcArgs, IpcError, decode_probability};
use sonar_common::throttle::Throttle;

/// How often the nearest occupied cell is logged.
const PROGRESS_PERIOD: Duration = Duration::from_secs(1);

/// Prints `bearing <deg> distance <m>` whenever the closest occupied cell of the sonar map is
/// nearer than --threshold (once per map snapshot). Bearing: degrees counter-clockwise from the
/// sensor's forward axis. Runs until Ctrl-C/SIGTERM, --max-alerts alerts or --snapshots snapshots.
/// Once a second the nearest occupied cell is logged on stderr, alert or not.
///
/// Example: sonar-nearest-obstacle --threshold 0.8
#[derive(Debug, Parser)]
#[command(version, verbatim_doc_comment)]
struct Args {
    /// Alert distance, metres: a snapshot whose nearest occupied cell is nearer prints an alert.
    #[arg(long, default_value_t = 0.5)]
    threshold: f32,
    /// A cell counts as occupied when its probability is above this.
    #[arg(long, default_value_t = 0.65)]
    occupied_above: f32,
    /// Exit after N alerts (0: never). (`--count` still works.)
    #[arg(long, value_name = "N", alias = "count", default_value_t = 0)]
    max_alerts: u64,
    /// Exit after N snapshots, alert or not (0: never).
    #[arg(long, value_name = "N", default_value_t = 0)]
    snapshots: u64,
    #[command(flatten)]
    ipc: IpcArgs,
}

/// Bearing (degrees) and distance (metres) of the centre of the occupied cell closest to the
/// sensor, `None` if no cell is occupied.
fn nearest(h: &GridHeader, cells: &[u8], occupied_above: f32) -> Option<(f32, f32)> {
    let width = (h.width as usize).max(1);
    let (x, y) = cells
        .iter()
        .enumerate()
        .filter(|(_, c)| decode_probability(**c).is_some_and(|p| p > occupied_above))
        .map(|(i, _)| {
            let x = h.origin_x_m + ((i % width) as f32 + 0.5) * h.resolution_m - h.pose_x_m;
            let y = h.origin_y_m + ((i / width) as f32 + 0.5) * h.resolution_m - h.pose_y_m;
            (x, y)
        })
        .min_by(|a, b| a.0.hypot(a.1).total_cmp(&b.0.hypot(b.1)))?;
    let bearing = (y.atan2(x) - h.pose_theta_rad).to_degrees();
    Some(((bearing + 180.0).rem_euclid(360.0) - 180.0, x.hypot(y)))
}

fn run(args: &Args) -> Result<()> {
    if !(args.threshold > 0.0 && (0.0..1.0).contains(&args.occupied_above)) {
        bail!("--threshold must be positive and --occupied-above in [0, 1)");
    }
    let node = args.ipc.node("sonar-nearest-obstacle")?;
    let grid = ipc::grid_service(&node)?
        .subscriber_builder()
        .create()
        .map_err(|e| IpcError::new("create grid subscriber", e))?;
    let listener = ipc::wakeup_listener(&node, ipc::GRID_SERVICE)?;
    let waitset = WaitSetBuilder::new()
        .create::<Ipc>()
        .map_err(|e| IpcError::new("create waitset", e))?;
    let _guard = waitset
        .attach_notification(&listener)
        .map_err(|e| IpcError::new("attach listener", e))?;
    let (mut alerts, mut snapshots, mut closest) = (0u64, 0u64, None);
    let done = |alerts, snapshots| {
        (args.max_alerts > 0 && alerts >= args.max_alerts)
            || (args.snapshots > 0 && snapshots >= args.snapshots)
    };
    let mut out = std::io::stdout().lock();
    let mut progress = Throttle::new(PROGRESS_PERIOD);
    'watch: while !done(alerts, snapshots) {
        let result = waitset
            .wait_and_process_once(|_| CallbackProgression::Continue)
            .map_err(|e| IpcError::new("wait", e))?;
        if matches!(
            result,
            WaitSetRunResult::Interrupt | WaitSetRunResult::TerminationRequest
        ) {
            break;
        }
        let _ = listener.try_wait(|_| {}); // consume the wake-ups, else the wait returns at once
        while !done(alerts, snapshots) {
            let Some(sample) = grid
                .receive()
                .map_err(|e| IpcError::new("receive grid", e))?
            else {
                break;
            };
            snapshots += 1;
            closest = nearest(sample.user_header(), sample.payload(), args.occupied_above);
            if progress.allow(Instant::now()).is_some() {
                match closest {
                    Some((bearing, distance)) => tracing::info!(
                        "nearest occupied cell: bearing {bearing:.1}°, distance {distance:.2} m \
                         (alerts below {} m)",
                        args.threshold
                    ),
                    None => tracing::info!("no occupied cell in the map yet"),
                }
            }
            if let Some((bearing, distance)) = closest.filter(|&(_, d)| d < args.threshold) {
                let written = writeln!(out, "bearing {bearing:.1} distance {distance:.3}")
                    .and_then(|()| out.flush());
                match written {
                    Ok(()) => alerts += 1,
                    // The reader is gone (`| head -1`): nobody is left to alert, as for `head`.
                    Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => break 'watch,
                    Err(e) => return Err(e).context("write an alert to standard output"),
                }
            }
        }
    }
    let nearest_m = closest.map_or("none".to_owned(), |(_, d)| format!("{d:.3} m"));
    tracing::info!("{snapshots} snapshots, {alerts} alerts, nearest occupied cell {nearest_m}");
    Ok(())
}

fn main() -> ExitCode {
    sonar_common::init_tracing();
    sonar_common::report_exit("sonar-nearest-obstacle", run(&Args::parse()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use sonar_common::ipc::CELL_UNKNOWN;

    #[test]
    fn the_closest_occupied_cell_is_found_relative_to_the_sensor_pose() {
        // 10 × 10 cells of 0.1 m from (0, 0); the sensor at (0.5, 0.5), heading +90° (along y).
        let h = GridHeader {
            width: 10,
            height: 10,
            resolution_m: 0.1,
            pose_x_m: 0.5,
            pose_y_m: 0.5,
            pose_theta_rad: std::f32::consts::FRAC_PI_2,
            ..GridHeader::default()
        };
        let mut cells = vec![0u8; 100];
        cells[5 * 10 + 9] = 254; // (0.95, 0.55): 0.45 m along world x, i.e. to the sensor's right
        cells[0] = 200; // (0.05, 0.05), farther
        cells[7 * 10 + 5] = 160; // nearer, but p = 0.63 only: not occupied above 0.65
        cells[1] = CELL_UNKNOWN;
        let (bearing, distance) = nearest(&h, &cells, 0.65).unwrap();
        assert!((distance - 0.45f32.hypot(0.05)).abs() < 1e-5, "{distance}");
        assert!(
            (bearing - (-90.0 + 0.05f32.atan2(0.45).to_degrees())).abs() < 1e-3,
            "{bearing}"
        );
        // Behind the sensor: the bearing wraps into [-180, 180).
        cells[5 * 10 + 9] = 0;
        let (bearing, _) = nearest(&h, &cells, 0.65).unwrap();
        assert!((bearing - 135.0).abs() < 1e-3, "{bearing}");
        assert_eq!(nearest(&h, &[0; 100], 0.65), None);
    }
}
