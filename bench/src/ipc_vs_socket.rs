//! Snapshot delivery through iceoryx2 as the pipeline uses it, against the Unix socket with
//! bincode a user would otherwise write: one process, a publisher thread and a subscriber thread,
//! one snapshot in flight at a time (the publisher sends the next once the subscriber has read
//! the last), so each figure is one snapshot's latency from the start of its loan or encoding to
//! the end of the subscriber's read.
//!
//! - **iceoryx2**: the grid service with the pipeline's QoS (`sonar_ipc::grid_service`), a publisher
//!   sized for the payload, `loan_slice_uninit`, header, fill, `send`, a wake-up on the grid's
//!   event service; the subscriber waits on its listener, `receive`s and reads every byte.
//! - **socket**: `UnixStream::pair`; the sender encodes header + cells with bincode (the cells as
//!   one byte string, `serialize_bytes`, so a copy and not a byte-by-byte sequence) into a reused
//!   buffer and writes it; the receiver decodes with `bincode::deserialize_from` through a
//!   `BufReader` (into a new `Vec`, as such code does) and reads every byte.
//! - **fill**: the publisher copies the cells from its own buffer into the sample (what
//!   `sonar-fusion` does), or encodes them into the socket buffer. **Transfer alone** leaves it
//!   out: the iceoryx2 sample keeps the bytes a previous loan of its slot left there (the
//!   segment's memory is always initialised, only stale), the socket sends a buffer encoded once.

use std::io::{BufReader, Write};
use std::os::unix::net::UnixStream;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, anyhow};
use serde::{Deserialize, Serialize};
use sonar_common::ipc::{self as sonar_ipc, GridHeader, IpcError};

use crate::sandbox::{Sandbox, grid_consumer, load_average, quantile, show};

/// Payload sizes: 64 KiB to 16 MiB (a 256² to a 4096² grid of one-byte cells).
pub const SIZES: [usize; 5] = [64 << 10, 256 << 10, 1 << 20, 4 << 20, 16 << 20];

/// Whether the publisher writes the payload.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Fill {
    TransferAlone,
    WithFill,
}

// The fill first, so that every slot the publisher will loan holds written bytes.
const FILLS: [Fill; 2] = [Fill::WithFill, Fill::TransferAlone];

/// The snapshots of a run, in the order both sides go through them.
fn schedule(samples: usize) -> Vec<(usize, Fill)> {
    SIZES
        .iter()
        .flat_map(|&size| FILLS.iter().map(move |&fill| (size, fill)))
        .flat_map(|case| std::iter::repeat_n(case, samples))
        .collect()
}

/// The cells a publisher copies from: not all zero, so nothing can skip them.
fn source_cells(size: usize) -> Vec<u8> {
    (0..size).map(|i| (i % 251) as u8).collect()
}

/// What a subscriber does with a snapshot at the least: read every byte (an XOR of them all,
/// which runs at the speed of memory).
fn read_all(cells: &[u8]) -> u8 {
    std::hint::black_box(cells.iter().fold(0, |acc, &b| acc ^ b))
}

/// One snapshot's times from the start of the publisher's work: until the subscriber has it
/// (the sample received, or the message decoded), and until it has read every byte.
#[derive(Debug, Clone, Copy)]
struct Latency {
    delivered: Duration,
    read: Duration,
}

fn nanos_since(origin: Instant) -> u64 {
    u64::try_from(origin.elapsed().as_nanos()).unwrap_or(u64::MAX)
}

/// Runs both transports over every size and prints the Markdown table.
pub fn run(samples: usize, warmup: usize) -> Result<()> {
    let load_before = load_average();
    let per_case = samples + warmup;
    let iox = iceoryx2_latencies(per_case)?;
    let socket = socket_latencies(per_case)?;
    let load_after = load_average();
    println!(
        "| payload | case | iceoryx2 delivered p50 / p99 | iceoryx2 read p50 / p99 | socket delivered p50 / p99 | socket read p50 / p99 | socket ÷ iceoryx2, read p50 |"
    );
    println!("|--:|---|--:|--:|--:|--:|--:|");
    for (i, (size, fill)) in schedule(1).into_iter().enumerate() {
        let measured = |all: &[Latency], part: fn(&Latency) -> Duration| -> Vec<Duration> {
            all[i * per_case + warmup..(i + 1) * per_case]
                .iter()
                .map(part)
                .collect()
        };
        let cell = |samples: &[Duration]| {
            format!(
                "{} / {}",
                show(quantile(samples, 0.5)),
                show(quantile(samples, 0.99))
            )
        };
        let (iox_read, socket_read) = (measured(&iox, |l| l.read), measured(&socket, |l| l.read));
        println!(
            "| {} KiB | {} | {} | {} | {} | {} | {:.1}× |",
            size >> 10,
            match fill {
                Fill::TransferAlone => "transfer alone",
                Fill::WithFill => "with the fill",
            },
            cell(&measured(&iox, |l| l.delivered)),
            cell(&iox_read),
            cell(&measured(&socket, |l| l.delivered)),
            cell(&socket_read),
            quantile(&socket_read, 0.5).as_secs_f64() / quantile(&iox_read, 0.5).as_secs_f64(),
        );
    }
    println!();
    println!(
        "{samples} snapshots per case after {warmup} unmeasured; load average {load_before} before, {load_after} after."
    );
    Ok(())
}

fn iceoryx2_latencies(per_case: usize) -> Result<Vec<Latency>> {
    let bin_dir = std::env::temp_dir();
    let sandbox = Sandbox::new("ipc", &bin_dir)?;
    let origin = Instant::now();
    let (ack_tx, ack_rx) = mpsc::channel::<()>();
    let (ready_tx, ready_rx) = mpsc::channel::<()>();
    let total = schedule(per_case).len();
    let args = sandbox.ipc_args();
    let subscriber = std::thread::spawn(move || -> Result<Vec<Latency>> {
        let node = args.node("bench-subscriber")?;
        let (subscriber, listener) = grid_consumer(&node)?;
        ready_tx.send(())?;
        let mut latencies = Vec::with_capacity(total);
        while latencies.len() < total {
            listener
                .timed_wait(|_| {}, Duration::from_secs(10))
                .map_err(|e| IpcError::new("wait for a snapshot", e))?;
            while let Some(sample) = subscriber
                .receive()
                .map_err(|e| IpcError::new("receive", e))?
            {
                let sent = Duration::from_nanos(sample.user_header().stamp_ns);
                let delivered = origin.elapsed().saturating_sub(sent);
                read_all(sample.payload());
                latencies.push(Latency {
                    delivered,
                    read: origin.elapsed().saturating_sub(sent),
                });
                drop(sample);
                ack_tx.send(())?;
            }
        }
        Ok(latencies)
    });
    ready_rx
        .recv()
        .map_err(|_| anyhow!("the subscriber thread failed to start"))?;
    let node = sandbox.node("bench-publisher")?;
    let service = sonar_ipc::grid_service(&node)?;
    let notifier = sonar_ipc::wakeup_notifier(&node, sonar_ipc::GRID_SERVICE)?;
    let mut current: Option<(usize, _, Vec<u8>)> = None;
    for (seq, (size, fill)) in schedule(per_case).into_iter().enumerate() {
        if current.as_ref().is_none_or(|(s, _, _)| *s != size) {
            drop(current.take()); // one publisher at a time, as in the pipeline
            let publisher = service
                .publisher_builder()
                .initial_max_slice_len(size)
                .create()
                .map_err(|e| IpcError::new("create grid publisher", e))?;
            current = Some((size, publisher, source_cells(size)));
        }
        let Some((_, publisher, cells)) = &current else {
            unreachable!("a publisher for this size was made above")
        };
        let stamp_ns = nanos_since(origin);
        let sample = publisher
            .loan_slice_uninit(size)
            .map_err(|e| IpcError::new("loan", e))?;
        let mut sample = match fill {
            // What `sonar-fusion` does with its encoded cells.
            Fill::WithFill => sample.write_from_slice(cells),
            // SAFETY: the slot's bytes are those a previous loan left (the warm-up fills every
            // slot first): stale, not uninitialised memory, since the segment is ordinary
            // mapped memory.
            Fill::TransferAlone => unsafe { sample.assume_init() },
        };
        *sample.user_header_mut() = GridHeader {
            seq: seq as u64,
            stamp_ns,
            ..GridHeader::default()
        };
        sample.send().map_err(|e| IpcError::new("send", e))?;
        notifier.notify().map_err(|e| IpcError::new("notify", e))?;
        ack_rx
            .recv_timeout(Duration::from_secs(10))
            .context("the subscriber did not read a snapshot within 10 s")?;
    }
    subscriber
        .join()
        .map_err(|_| anyhow!("the subscriber thread panicked"))?
}

#[derive(Serialize)]
struct SnapshotOut<'a> {
    header: [u64; 2],
    #[serde(serialize_with = "as_bytes")]
    cells: &'a [u8],
}

fn as_bytes<S: serde::Serializer>(cells: &&[u8], s: S) -> Result<S::Ok, S::Error> {
    s.serialize_bytes(cells)
}

#[derive(Deserialize)]
struct SnapshotIn {
    header: [u64; 2],
    cells: Cells,
}

/// Cells decoded as one byte string (the counterpart of `serialize_bytes`).
struct Cells(Vec<u8>);

impl<'de> Deserialize<'de> for Cells {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        struct Visitor;
        impl serde::de::Visitor<'_> for Visitor {
            type Value = Cells;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("a byte string")
            }
            fn visit_byte_buf<E>(self, v: Vec<u8>) -> Result<Cells, E> {
                Ok(Cells(v))
            }
            fn visit_bytes<E>(self, v: &[u8]) -> Result<Cells, E> {
                Ok(Cells(v.to_vec()))
            }
        }
        d.deserialize_byte_buf(Visitor)
    }
}

fn socket_latencies(per_case: usize) -> Result<Vec<Latency>> {
    let (mut tx, rx) = UnixStream::pair().context("socket pair")?;
    let origin = Instant::now();
    let (ack_tx, ack_rx) = mpsc::channel::<()>();
    let total = schedule(per_case).len();
    let receiver = std::thread::spawn(move || -> Result<Vec<Latency>> {
        let mut reader = BufReader::with_capacity(64 << 10, rx);
        let mut latencies = Vec::with_capacity(total);
        for _ in 0..total {
            let snapshot: SnapshotIn =
                bincode::deserialize_from(&mut reader).context("decode a snapshot")?;
            let sent = Duration::from_nanos(snapshot.header[1]);
            let delivered = origin.elapsed().saturating_sub(sent);
            read_all(&snapshot.cells.0);
            latencies.push(Latency {
                delivered,
                read: origin.elapsed().saturating_sub(sent),
            });
            ack_tx.send(())?;
        }
        Ok(latencies)
    });
    let mut encoded = Vec::new();
    let mut cells = Vec::new();
    for (seq, (size, fill)) in schedule(per_case).into_iter().enumerate() {
        if cells.len() != size {
            cells = source_cells(size);
        }
        let stamp_ns = nanos_since(origin);
        let snapshot = SnapshotOut {
            header: [seq as u64, stamp_ns],
            cells: &cells,
        };
        if fill == Fill::WithFill || encoded.is_empty() {
            encoded.clear();
            bincode::serialize_into(&mut encoded, &snapshot).context("encode")?;
        } else {
            // Transfer alone: the buffer encoded before, with this snapshot's stamp.
            let stamp_at = std::mem::size_of::<u64>();
            encoded[stamp_at..stamp_at + 8].copy_from_slice(&stamp_ns.to_le_bytes());
        }
        tx.write_all(&encoded).context("write")?;
        ack_rx
            .recv_timeout(Duration::from_secs(10))
            .context("the receiver did not read a snapshot within 10 s")?;
        if fill == Fill::WithFill {
            // The next case of this size starts from a buffer for its own size.
            encoded.clear();
        }
    }
    receiver
        .join()
        .map_err(|_| anyhow!("the receiver thread panicked"))?
}
