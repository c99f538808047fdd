//! `sonar-bench`: the pipeline measured as it runs, for `scripts/bench.sh` and
//! `docs/benchmarks.md`.
//!
//! Each subcommand prints Markdown table rows on stdout (progress and errors on stderr) and states
//! the load average beside its wall-clock figures, since the machine may be shared. The
//! subcommands that start the pipeline run the release binaries beside this one
//! (`target/release/`), each time in an iceoryx2 namespace of their own (prefix, root and state
//! directory under the temporary directory), and stop them and remove the namespace's shared
//! memory when done.
//!
//! - `ipc`: snapshot delivery, iceoryx2 as the pipeline uses it against a Unix socket with
//!   bincode, 64 KiB–16 MiB ([`ipc_vs_socket`]);
//! - `latency`: a reading's line on the serial line → the snapshot containing it visible
//!   ([`latency`]);
//! - `throughput`: lossless throughput of the fusion and its fused rate at 2× and 4× that
//!   ([`throughput`]);
//! - `idle`: CPU and wake-ups of every process of an idle pipeline ([`resources::idle`]);
//! - `memory`: RSS and shared memory per grid size and number of grid subscribers
//!   ([`resources::memory`]).

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use sonar_common::ipc::IpcArgs;

mod ipc_vs_socket;
mod latency;
mod resources;
mod sandbox;
mod throughput;

/// The pipeline's benchmarks; each prints Markdown rows (see `scripts/bench.sh`, which runs them
/// all and writes docs/benchmarks.md).
#[derive(Debug, Parser)]
#[command(version)]
struct Cli {
    /// Directory of the pipeline's binaries [default: this program's own].
    #[arg(long, global = true, value_name = "DIR")]
    bin_dir: Option<PathBuf>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Snapshot delivery, iceoryx2 against a Unix socket with bincode, 64 KiB–16 MiB.
    Ipc {
        /// Snapshots measured per payload size and case.
        #[arg(long, default_value_t = 300)]
        samples: usize,
        /// Snapshots sent before measuring, per size and case.
        #[arg(long, default_value_t = 20)]
        warmup: usize,
    },
    /// Reading line on the serial line → snapshot visible, through sonar-driver and sonar-fusion.
    Latency {
        /// Grid cells per side.
        #[arg(long, default_value_t = 400)]
        cells: u32,
        /// Cell edge, metres.
        #[arg(long, default_value_t = 0.02)]
        resolution: f32,
        /// Readings measured (after 10 unmeasured).
        #[arg(long, default_value_t = 150)]
        readings: usize,
        /// Print the table's header first.
        #[arg(long)]
        header: bool,
    },
    /// Lossless throughput of sonar-fusion, and its fused rate when offered 2× and 4× that.
    Throughput {
        #[arg(long, default_value_t = 400)]
        cells: u32,
        #[arg(long, default_value_t = 0.02)]
        resolution: f32,
        /// First offered rate, readings per second; then 1.5× per step while lossless.
        #[arg(long, default_value_t = 4000.0)]
        start_rate: f64,
        /// Seconds of readings offered per step.
        #[arg(long, default_value_t = 3.0)]
        seconds: f64,
        /// Drive the robot 10 cm per sweep round a circle of 1.5 m radius in a 6 m square room, its
        /// pose on robot/pose, so that no sweep repeats the one before (a standing head's sweeps
        /// repeat: the region model keeps them once, its best case).
        #[arg(long)]
        moving: bool,
        #[arg(long)]
        header: bool,
    },
    /// CPU and wake-ups per second of every process of an idle pipeline, viewer included.
    Idle {
        #[arg(long, default_value_t = 60)]
        seconds: u64,
    },
    /// RSS and shared memory of the scanning pipeline with N grid subscribers.
    Memory {
        #[arg(long, default_value_t = 400)]
        cells: u32,
        #[arg(long, default_value_t = 0.02)]
        resolution: f32,
        #[arg(long, default_value_t = 1)]
        subscribers: usize,
        #[arg(long)]
        header: bool,
    },
    /// A grid subscriber that reads every cell of every snapshot (for `memory`).
    #[command(hide = true)]
    ReadGrid {
        #[command(flatten)]
        ipc: IpcArgs,
    },
}

fn run(cli: Cli) -> Result<()> {
    let bin_dir = match cli.bin_dir {
        Some(dir) => dir,
        None => std::env::current_exe()
            .context("this program's path")?
            .parent()
            .context("this program's directory")?
            .to_owned(),
    };
    match cli.command {
        Command::Ipc { samples, warmup } => ipc_vs_socket::run(samples, warmup),
        Command::Latency {
            cells,
            resolution,
            readings,
            header,
        } => {
            if header {
                latency::print_header();
            }
            latency::run(&bin_dir, cells, resolution, readings)
        }
        Command::Throughput {
            cells,
            resolution,
            start_rate,
            seconds,
            moving,
            header,
        } => {
            if header {
                throughput::print_header();
            }
            throughput::run(&bin_dir, cells, resolution, start_rate, seconds, moving)
        }
        Command::Idle { seconds } => resources::idle(&bin_dir, seconds),
        Command::Memory {
            cells,
            resolution,
            subscribers,
            header,
        } => {
            if header {
                resources::print_memory_header();
            }
            resources::memory(&bin_dir, cells, resolution, subscribers)
        }
        Command::ReadGrid { ipc } => resources::read_grid(&ipc),
    }
}

fn main() -> ExitCode {
    sonar_common::init_tracing();
    sonar_common::report_exit("sonar-bench", run(Cli::parse()))
}
