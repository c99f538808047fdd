//! Lossless throughput of `sonar-fusion`, and what it fuses when offered 2× and 4× that.
//!
//! This program plays the driver: it publishes synthetic readings on `sonar/readings` (sweeps of
//! 50, −147° … 147° in 6° steps, forth and back, walls 1.5–3.5 m away) at an offered rate, in
//! the bursts a sleeping publisher makes (it wakes about every 200 µs and sends what is due, then
//! notifies once). Each step starts a fresh `sonar-fusion --no-persist` (default preset, features
//! on, `--max-rate 10`), warms it up with two sweeps at 1 k/s and stops it 1 s after the last
//! reading; its `fusion stopped` line gives
//! the readings fused and received and the snapshots. The offered rate climbs by 1.5× from
//! `--start-rate` while no more than 0.1 % is lost, then the step between the last such rate and
//! the first lossy one is halved three times (geometrically: to 5 %); the highest rate lost
//! nothing is the lossless throughput, then 2× and 4× of it are offered.
//!
//! The head stands still by default, so every sweep repeats the one before: the best case for
//! the region model, which keeps a repeated patch or weak echo once. With `--moving` the robot
//! drives 10 cm per sweep round a circle in a square room ([`sonar_bench::room_reading`]), its
//! pose published on `robot/pose` beside the readings (each burst's readings stamped just before
//! its pose), so no sweep repeats another.

use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use iceoryx2::port::publisher::Publisher;
use iceoryx2::prelude::ipc;
use sonar_bench::{moving_pose, room_reading, synthetic_reading};
use sonar_common::ipc::{self as sonar_ipc, IpcError, Pose2D, Reading, unix_time_ns};

use crate::sandbox::{ProcUsage, Sandbox, clock_ticks_per_second, load_average, wait_until};

/// One offered load and what the fusion made of it.
#[derive(Debug, Clone, Copy)]
struct Step {
    offered_per_s: f64,
    sent: u64,
    fused: u64,
    received: u64,
    snapshots: u64,
    wall: Duration,
    fusion_cpu: Duration,
}

impl Step {
    fn lost_fraction(&self) -> f64 {
        1.0 - self.received as f64 / self.sent.max(1) as f64
    }
    fn fused_per_s(&self) -> f64 {
        self.fused as f64 / self.wall.as_secs_f64()
    }
}

/// The number after `key=` on `line` (0 if absent).
fn field(line: &str, key: &str) -> u64 {
    line.split_whitespace()
        .find_map(|word| word.strip_prefix(key)?.strip_prefix('='))
        .and_then(|n| n.trim_matches(|c: char| !c.is_ascii_digit()).parse().ok())
        .unwrap_or(0)
}

/// Publishes the readings `from..to` (the moving robot's, with `poses`), then, with `poses`, the
/// pose of the last one's sweep stamped a microsecond after them (the readings wait for a pose at
/// or after their stamp).
fn send_burst(
    readings: &Publisher<ipc::Service, Reading, ()>,
    poses: Option<&Publisher<ipc::Service, Pose2D, ()>>,
    from: u64,
    to: u64,
) -> Result<()> {
    let stamp = unix_time_ns();
    for seq in from..to {
        let reading = if poses.is_some() {
            room_reading(seq, stamp)
        } else {
            synthetic_reading(seq, stamp)
        };
        readings
            .send_copy(reading)
            .map_err(|e| IpcError::new("send reading", e))?;
    }
    if let Some(poses) = poses
        && to > from
    {
        poses
            .send_copy(moving_pose(to - 1, stamp + 1_000))
            .map_err(|e| IpcError::new("send pose", e))?;
    }
    Ok(())
}

fn offer(
    sandbox: &mut Sandbox,
    cells: u32,
    resolution: f32,
    offered_per_s: f64,
    seconds: f64,
    moving: bool,
) -> Result<Step> {
    let fusion = sandbox.spawn_fusion(cells, resolution)?;
    let node = sandbox.node("bench-driver")?;
    let service = sonar_ipc::readings_service(&node)?;
    let publisher = service
        .publisher_builder()
        .create()
        .map_err(|e| IpcError::new("create readings publisher", e))?;
    let pose_publisher = moving
        .then(|| {
            sonar_ipc::pose_service(&node)?
                .publisher_builder()
                .create()
                .map_err(|e| IpcError::new("create pose publisher", e))
        })
        .transpose()?;
    let notifier = sonar_ipc::wakeup_notifier(&node, sonar_ipc::READINGS_SERVICE)?;
    wait_until("the fusion to subscribe", Duration::from_secs(30), || {
        use iceoryx2::service::port_factory::PortFactory;
        service.dynamic_config().number_of_subscribers() > 0
    })?;
    sandbox.check_running()?;
    // Warm-up: two sweeps at 1 k/s, so that the cone's spans of every direction are built (the
    // cold start, measured apart) before the load is offered; not counted in the rates.
    for seq in 0..WARMUP {
        send_burst(&publisher, pose_publisher.as_ref(), seq, seq + 1)?;
        notifier.notify().map_err(|e| IpcError::new("notify", e))?;
        std::thread::sleep(Duration::from_millis(1));
    }
    std::thread::sleep(Duration::from_millis(500));
    let total = WARMUP + (offered_per_s * seconds).round() as u64;
    let start = Instant::now();
    let mut sent = WARMUP;
    while sent < total {
        let due = (WARMUP + (start.elapsed().as_secs_f64() * offered_per_s) as u64).min(total);
        send_burst(&publisher, pose_publisher.as_ref(), sent, due.max(sent))?;
        sent = due.max(sent);
        notifier.notify().map_err(|e| IpcError::new("notify", e))?;
        std::thread::sleep(Duration::from_micros(200));
    }
    let wall = start.elapsed();
    std::thread::sleep(Duration::from_secs(1));
    let usage = ProcUsage::of(fusion)?;
    let log = sandbox.stop(fusion)?;
    let line = log
        .lines()
        .find(|l| l.contains("fusion stopped"))
        .with_context(|| format!("no `fusion stopped` line in the fusion's log:\n{log}"))?;
    drop((publisher, pose_publisher, notifier, service, node));
    Ok(Step {
        offered_per_s: (sent - WARMUP) as f64 / wall.as_secs_f64(),
        sent,
        fused: field(line, "readings").saturating_sub(WARMUP),
        received: field(line, "received"),
        snapshots: field(line, "snapshots"),
        wall,
        fusion_cpu: Duration::from_secs_f64(
            usage.cpu_ticks as f64 / clock_ticks_per_second() as f64,
        ),
    })
}

/// Readings sent slowly before each step's load.
const WARMUP: u64 = 100;

/// Most lost of what was sent for a step to count as lossless.
const LOSSLESS: f64 = 0.001;

/// Each step of the climb offers this many times the last.
const CLIMB: f64 = 1.5;

/// Halvings of the last climb step: 1.5^(1/8), the lossless rate known to 5 %.
const REFINE_STEPS: usize = 3;

pub fn print_header() {
    println!(
        "| grid | step | offered/s | sent | lost | fused/s | snapshots/s | fusion CPU s | fused per fusion CPU s | load average |"
    );
    println!("|---|---|--:|--:|--:|--:|--:|--:|--:|---|");
}

fn print_row(grid: &str, label: &str, step: &Step) {
    println!(
        "| {grid} | {label} | {:.1} k | {} | {:.1} % | {:.1} k | {:.1} | {:.2} | {:.1} k | {} |",
        step.offered_per_s / 1e3,
        step.sent,
        step.lost_fraction() * 100.0,
        step.fused_per_s() / 1e3,
        step.snapshots as f64 / step.wall.as_secs_f64(),
        step.fusion_cpu.as_secs_f64(),
        step.fused as f64 / step.fusion_cpu.as_secs_f64().max(1e-3) / 1e3,
        load_average(),
    );
}

pub fn run(
    bin_dir: &Path,
    cells: u32,
    resolution: f32,
    start_rate: f64,
    seconds: f64,
    moving: bool,
) -> Result<()> {
    let mut sandbox = Sandbox::new("tput", bin_dir)?;
    let head = if moving { ", moving" } else { "" };
    let grid = format!("{cells}² × {} cm{head}", (resolution * 100.0).round());
    let mut lossless: Option<Step> = None;
    let mut rate = start_rate;
    loop {
        let step = offer(&mut sandbox, cells, resolution, rate, seconds, moving)?;
        let passed = step.lost_fraction() <= LOSSLESS;
        print_row(&grid, if passed { "climb" } else { "climb (lossy)" }, &step);
        if !passed {
            break;
        }
        lossless = Some(step);
        rate *= CLIMB;
        if rate > 2e6 {
            break;
        }
    }
    let Some(mut lossless) = lossless else {
        println!("| {grid} | no lossless rate from {start_rate}/s | | | | | | | | |");
        return Ok(());
    };
    // Between the last lossless step and the first lossy one, halved (geometrically) a few
    // times: a climb's step alone leaves the rate known to 1.5×.
    let mut lossy = rate;
    for _ in 0..REFINE_STEPS {
        let between = (lossless.offered_per_s * lossy).sqrt();
        let step = offer(&mut sandbox, cells, resolution, between, seconds, moving)?;
        let passed = step.lost_fraction() <= LOSSLESS;
        print_row(
            &grid,
            if passed { "refine" } else { "refine (lossy)" },
            &step,
        );
        if passed {
            lossless = step;
        } else {
            lossy = between;
        }
    }
    print_row(&grid, "**lossless**", &lossless);
    for factor in [2.0, 4.0] {
        let step = offer(
            &mut sandbox,
            cells,
            resolution,
            lossless.offered_per_s * factor,
            seconds,
            moving,
        )?;
        print_row(
            &grid,
            &format!(
                "**{factor}× → fused {:.0} % of lossless**",
                100.0 * step.fused_per_s() / lossless.fused_per_s()
            ),
            &step,
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fields_of_the_stop_line() {
        let line = "2026-12-02T06:00:00Z  INFO sonar_fusion: fusion stopped readings=120 \
                    extrapolated_pose=0 stale_pose=0 received=125 lost=3 snapshots=14 saves=0";
        assert_eq!(field(line, "readings"), 120);
        assert_eq!(field(line, "received"), 125);
        assert_eq!(field(line, "snapshots"), 14);
        assert_eq!(field(line, "missing"), 0);
    }
}
