//! How long `sonar-slam` takes to close a sweep as its map grows: the generated loop (a
//! stop-and-scan tour round a block of rooms, `sonar-eval --slam --slam-tours loop`) driven for
//! `--laps` laps at 3 % / 2°/m odometry, its readings and odometry fed to the SLAM library as the
//! process feeds them, and the wall-clock time of each reading that closes a sweep (the solve,
//! the association and the covariance) printed as a mean per `--every` sweeps. A benchmark, not a
//! test: the figures depend on the machine (docs/benchmarks.md, "SLAM: the time a sweep takes as
//! the map grows").
//!
//!   cargo run --release -p sonar-eval --example slam_long_run -- --laps 12

use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use clap::Parser;
use sonar_eval::motion::POSE_RATE_HZ;
use sonar_eval::pipeline::{Scan, capture_tour};
use sonar_eval::slam::{Family, OdometryLevel, feed_tour};
use sonar_slam::{Slam, SlamConfig};

#[derive(Debug, Parser)]
struct Args {
    /// Laps of the loop (the evaluation drives three).
    #[arg(long, default_value_t = 12.0)]
    laps: f64,
    /// The loop's generated layout.
    #[arg(long, default_value_t = 29)]
    layout: u64,
    /// Sweeps per printed mean.
    #[arg(long, default_value_t = 25, value_parser = clap::value_parser!(u64).range(1..))]
    every: u64,
}

fn main() -> Result<()> {
    let args = Args::parse();
    let (scene, three_laps) = Family::Loop.scene(args.layout)?;
    let metres = three_laps / 3.0 * args.laps;
    eprintln!(
        "touring {metres:.0} m of the loop (layout {})…",
        args.layout
    );
    let tour = capture_tour(
        scene.clone(),
        Scan::for_scene(&scene),
        metres,
        OdometryLevel::MEDIUM.params(1),
        POSE_RATE_HZ,
        1,
    )
    .context("touring the loop")?;
    let mut slam = Slam::new(SlamConfig::default()).context("setting up the SLAM")?;
    let (mut sweeps, mut spent, mut slowest) = (0u64, Duration::ZERO, Duration::ZERO);
    println!("| sweeps | landmarks | mean time to close a sweep (ms) | slowest (ms) |");
    println!("|--:|--:|--:|--:|");
    feed_tour(&tour, &mut slam, |slam, r| {
        let started = Instant::now();
        let closed = slam.push_reading(r).is_some();
        let took = started.elapsed();
        if closed {
            sweeps += 1;
            spent += took;
            slowest = slowest.max(took);
            if sweeps % args.every == 0 {
                println!(
                    "| {sweeps} | {} | {:.1} | {:.1} |",
                    slam.landmark_count(),
                    spent.as_secs_f64() * 1e3 / args.every as f64,
                    slowest.as_secs_f64() * 1e3
                );
                (spent, slowest) = (Duration::ZERO, Duration::ZERO);
            }
        }
    });
    Ok(())
}
