//! What the pipeline's processes cost at rest and in memory: CPU and wake-ups of an idle
//! pipeline, and RSS and shared memory per grid size with 1 and 6 grid subscribers.

use std::fs::File;
use std::io::Read;
use std::path::Path;
use std::time::Duration;

use anyhow::{Context, Result, bail};
use iceoryx2::prelude::*;
use nix::pty::{Winsize, openpty};
use sonar_common::ipc::{IpcArgs, IpcError};

use crate::sandbox::{
    ProcUsage, Sandbox, clock_ticks_per_second, grid_consumer, load_average, status_field, wait,
    wait_until,
};

/// Starts `sonar-sim` (room) and `sonar-driver` on its link with `driver_args`.
fn start_head(sandbox: &mut Sandbox, sim_args: &[&str], driver_args: &[&str]) -> Result<()> {
    let link = sandbox.path("tty");
    let link_arg = link.to_string_lossy().into_owned();
    let mut args = vec!["--scene", "room", "--link", &link_arg];
    args.extend_from_slice(sim_args);
    sandbox.spawn("sonar-sim", &args)?;
    wait_until("the simulator's link", Duration::from_secs(20), || {
        link.exists()
    })?;
    let mut args = vec!["--port", &link_arg];
    args.extend_from_slice(driver_args);
    sandbox.spawn("sonar-driver", &args)?;
    Ok(())
}

/// The idle pipeline (head not scanning) with the viewer on a 160 × 50 terminal: CPU and wake-ups
/// of each process over `seconds`.
pub fn idle(bin_dir: &Path, seconds: u64) -> Result<()> {
    let load_before = load_average();
    let mut sandbox = Sandbox::new("idle", bin_dir)?;
    start_head(&mut sandbox, &[], &["--scan", "none"])?;
    sandbox.spawn("sonar-fusion", &["--no-persist"])?;
    // A 160 × 50 terminal for the viewer; whatever it draws is read and dropped, so that it never
    // blocks on a full terminal.
    let terminal = openpty(
        Some(&Winsize {
            ws_row: 50,
            ws_col: 160,
            ws_xpixel: 0,
            ws_ypixel: 0,
        }),
        None,
    )
    .context("open a pseudo-terminal")?;
    let slave = terminal.slave.try_clone()?;
    let (out, err) = (slave.try_clone()?, slave.try_clone()?);
    sandbox.spawn_with("sonar-viewer", &[], move |cmd| {
        cmd.stdin(slave)
            .stdout(out)
            .stderr(err)
            .env("TERM", "xterm-256color");
    })?;
    let mut master = File::from(terminal.master);
    std::thread::spawn(move || {
        let mut buf = [0u8; 4096];
        while matches!(master.read(&mut buf), Ok(n) if n > 0) {}
    });
    std::thread::sleep(Duration::from_secs(5)); // started, connected, first frame drawn
    sandbox.check_running()?;
    let processes = sandbox.processes();
    let before: Vec<ProcUsage> = processes
        .iter()
        .map(|(_, pid)| ProcUsage::of(*pid))
        .collect::<Result<_>>()?;
    std::thread::sleep(Duration::from_secs(seconds));
    sandbox.check_running()?;
    let ticks = clock_ticks_per_second() as f64;
    println!("| process | CPU (% of one core) | wake-ups/s |");
    println!("|---|--:|--:|");
    let (mut cpu_sum, mut wake_sum) = (0.0, 0.0);
    for ((name, pid), before) in processes.iter().zip(&before) {
        let after = ProcUsage::of(*pid)?;
        let cpu = (after.cpu_ticks - before.cpu_ticks) as f64 / ticks / seconds as f64 * 100.0;
        let wakes = (after.switches - before.switches) as f64 / seconds as f64;
        cpu_sum += cpu;
        wake_sum += wakes;
        println!("| {name} | {cpu:.2} % | {wakes:.1} |");
    }
    println!("| **all together** | **{cpu_sum:.2} %** | **{wake_sum:.1}** |");
    println!();
    println!(
        "Over {seconds} s after 5 s to settle; load average {load_before} before, {} after.",
        load_average()
    );
    Ok(())
}

/// One process's memory, kB: resident, of it shared memory, and its proportional share.
fn memory_kb(pid: u32) -> Result<(u64, u64, u64)> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status"))?;
    let rollup = std::fs::read_to_string(format!("/proc/{pid}/smaps_rollup")).unwrap_or_default();
    Ok((
        status_field(&status, "VmRSS:"),
        status_field(&status, "RssShmem:"),
        status_field(&rollup, "Pss:"),
    ))
}

pub fn print_memory_header() {
    println!(
        "| grid | subscribers | sonar-fusion RSS (of it shm) | each subscriber RSS (of it shm) | sonar-driver RSS | sonar-sim RSS | all processes PSS | /dev/shm in use (file sizes) | load average |"
    );
    println!("|---|--:|--:|--:|--:|--:|--:|--:|---|");
}

fn mib(kb: u64) -> String {
    format!("{:.1} MiB", kb as f64 / 1024.0)
}

/// The scanning pipeline at `cells`² with `subscribers` processes reading every grid snapshot.
pub fn memory(bin_dir: &Path, cells: u32, resolution: f32, subscribers: usize) -> Result<()> {
    let mut sandbox = Sandbox::new("mem", bin_dir)?;
    start_head(&mut sandbox, &["--speed", "20"], &[])?;
    let fusion = sandbox.spawn_fusion(cells, resolution)?;
    let readers: Vec<u32> = (0..subscribers)
        .map(|_| sandbox.spawn("sonar-bench", &["read-grid"]))
        .collect::<Result<_>>()?;
    std::thread::sleep(Duration::from_secs(10)); // several sweeps fused, every reader served
    sandbox.check_running()?;
    let pid_of = |name: &str| {
        sandbox
            .processes()
            .into_iter()
            .find(|(n, _)| n == name)
            .map(|(_, pid)| pid)
    };
    let (Some(driver), Some(sim)) = (pid_of("sonar-driver"), pid_of("sonar-sim")) else {
        bail!("the head's processes are gone");
    };
    let fusion_mem = memory_kb(fusion)?;
    let reader_mem: Vec<(u64, u64, u64)> = readers
        .iter()
        .map(|&pid| memory_kb(pid))
        .collect::<Result<_>>()?;
    let mean = |f: fn(&(u64, u64, u64)) -> u64| {
        reader_mem.iter().map(f).sum::<u64>() / reader_mem.len().max(1) as u64
    };
    let pss: u64 = sandbox
        .processes()
        .iter()
        .map(|(_, pid)| memory_kb(*pid).map(|m| m.2))
        .sum::<Result<u64>>()?;
    let (apparent, used) = sandbox.shm_bytes();
    println!(
        "| {cells}² × {} cm | {subscribers} | {} ({}) | {} ({}) | {} | {} | {} | {} ({}) | {} |",
        (resolution * 100.0).round(),
        mib(fusion_mem.0),
        mib(fusion_mem.1),
        mib(mean(|m| m.0)),
        mib(mean(|m| m.1)),
        mib(memory_kb(driver)?.0),
        mib(memory_kb(sim)?.0),
        mib(pss),
        mib(used / 1024),
        mib(apparent / 1024),
        load_average(),
    );
    Ok(())
}

/// A grid consumer for [`memory`]: takes every snapshot and reads every cell, until SIGTERM.
pub fn read_grid(ipc: &IpcArgs) -> Result<()> {
    let node = ipc.node("bench-reader")?;
    let (grid, listener) = grid_consumer(&node)?;
    let waitset = WaitSetBuilder::new()
        .create::<ipc::Service>()
        .map_err(|e| IpcError::new("create waitset", e))?;
    let _guard = waitset
        .attach_notification(&listener)
        .map_err(|e| IpcError::new("attach listener", e))?;
    let mut checksum = 0u64;
    loop {
        if !wait(&waitset, Duration::from_secs(3600))? {
            break;
        }
        let _ = listener.try_wait(|_| {});
        while let Some(sample) = grid
            .receive()
            .map_err(|e| IpcError::new("receive grid", e))?
        {
            checksum = checksum.wrapping_add(sample.payload().iter().map(|&b| u64::from(b)).sum());
        }
    }
    tracing::info!(checksum, "reader stopped");
    Ok(())
}
