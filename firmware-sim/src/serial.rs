//! The far end of the chip's UART: bytes between the pseudo-terminal (what the driver opens as its
//! serial port) and the emulated UART0, never blocking the emulation.
//!
//! Bytes from the host wait in a queue until the UART can take them (its XON). Bytes from the chip
//! are written to the terminal as far as it takes them; when nobody reads and its buffer stays full
//! for [`WRITE_PATIENCE`] (as in `sonar-sim`), what waits is dropped and counted, as a UART with no
//! listener loses its bytes.

use std::collections::VecDeque;
use std::io::{self, ErrorKind, Read, Write};
use std::time::Instant;

use sonar_sim::Pty;
use sonar_sim::serve::WRITE_PATIENCE;
use tracing::{info, warn};

/// Most bytes from the host waiting for the chip's UART (about 0.4 s of 115200 baud).
pub const HOST_QUEUE_MAX: usize = 4096;

/// Byte counters of the line.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LineStats {
    /// Bytes the host sent.
    pub from_host: u64,
    /// Bytes the chip sent that reached the terminal.
    pub to_host: u64,
    /// Bytes the chip sent that nobody read: dropped.
    pub dropped: u64,
}

/// The pseudo-terminal side of the serial line.
#[derive(Debug)]
pub struct SerialLine<'a> {
    pty: &'a Pty,
    to_chip: VecDeque<u8>,
    to_host: VecDeque<u8>,
    /// Since when the terminal takes nothing while bytes wait.
    blocked_since: Option<Instant>,
    /// Bytes are being dropped; logged once per episode.
    dropping: bool,
    stats: LineStats,
}

impl<'a> SerialLine<'a> {
    pub fn new(pty: &'a Pty) -> Self {
        Self {
            pty,
            to_chip: VecDeque::new(),
            to_host: VecDeque::new(),
            blocked_since: None,
            dropping: false,
            stats: LineStats::default(),
        }
    }

    /// Queues for the chip what the host has sent, up to [`HOST_QUEUE_MAX`] bytes waiting (the rest
    /// stays in the terminal, whose writer then blocks: flow control); never waits.
    pub fn read_host(&mut self) -> io::Result<()> {
        let mut chunk = [0u8; 1024];
        while self.to_chip.len() < HOST_QUEUE_MAX {
            let room = (HOST_QUEUE_MAX - self.to_chip.len()).min(chunk.len());
            match self.pty.master().read(&mut chunk[..room]) {
                Ok(0) => return Ok(()),
                Ok(n) => {
                    self.to_chip.extend(&chunk[..n]);
                    self.stats.from_host += n as u64;
                }
                Err(e) if e.kind() == ErrorKind::WouldBlock => return Ok(()),
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) => return Err(e),
            }
        }
        Ok(())
    }

    /// The next byte the host sent, for the chip.
    pub fn next_for_chip(&mut self) -> Option<u8> {
        self.to_chip.pop_front()
    }

    /// Queues bytes the chip sent, for [`SerialLine::flush`].
    pub fn send_to_host(&mut self, bytes: &[u8]) {
        self.to_host.extend(bytes);
    }

    /// Whether bytes wait for the terminal.
    pub fn has_output(&self) -> bool {
        !self.to_host.is_empty()
    }

    /// Writes what the terminal takes now; drops what waited too long without room (`now` is the
    /// wall time).
    pub fn flush(&mut self, now: Instant) -> io::Result<()> {
        while !self.to_host.is_empty() {
            let (head, _) = self.to_host.as_slices();
            match self.pty.master().write(head) {
                Ok(n) => {
                    self.to_host.drain(..n);
                    self.stats.to_host += n as u64;
                    self.blocked_since = None;
                    if self.dropping {
                        info!(dropped = self.stats.dropped, "the port is read again");
                        self.dropping = false;
                    }
                }
                Err(e) if e.kind() == ErrorKind::Interrupted => {}
                Err(e) if e.kind() == ErrorKind::WouldBlock => {
                    let since = *self.blocked_since.get_or_insert(now);
                    if now.duration_since(since) >= WRITE_PATIENCE {
                        if !self.dropping {
                            warn!("nobody reads the port: dropping bytes");
                            self.dropping = true;
                        }
                        self.stats.dropped += self.to_host.len() as u64;
                        self.to_host.clear();
                    }
                    return Ok(());
                }
                Err(e) => return Err(e),
            }
        }
        Ok(())
    }

    pub fn stats(&self) -> LineStats {
        self.stats
    }
}

#[cfg(test)]
mod tests {
    use std::fs::OpenOptions;
    use std::time::Duration;

    use super::*;

    #[test]
    fn bytes_cross_both_ways() {
        let pty = Pty::open().unwrap();
        let mut line = SerialLine::new(&pty);
        let mut host = OpenOptions::new()
            .read(true)
            .write(true)
            .open(pty.path())
            .unwrap();
        host.write_all(b"$STOP*AF2E\n").unwrap();
        // The terminal passes the bytes on at once, but not necessarily within the write call.
        let deadline = Instant::now() + Duration::from_secs(5);
        while line.stats().from_host < 11 && Instant::now() < deadline {
            line.read_host().unwrap();
        }
        let got: Vec<u8> = std::iter::from_fn(|| line.next_for_chip()).collect();
        assert_eq!(got, b"$STOP*AF2E\n");

        line.send_to_host(b"$ACK,STOP*1234\n");
        assert!(line.has_output());
        line.flush(Instant::now()).unwrap();
        assert!(!line.has_output());
        let mut buf = [0u8; 15];
        host.read_exact(&mut buf).unwrap();
        assert_eq!(&buf, b"$ACK,STOP*1234\n");
        assert_eq!(line.stats().to_host, 15);
    }

    #[test]
    fn the_host_is_held_back_when_the_chip_takes_nothing() {
        let pty = Pty::open().unwrap();
        let mut line = SerialLine::new(&pty);
        let mut host = OpenOptions::new().write(true).open(pty.path()).unwrap();
        host.write_all(&[b'x'; 3 * HOST_QUEUE_MAX / 2]).unwrap();
        let deadline = Instant::now() + Duration::from_secs(5);
        while line.stats().from_host < HOST_QUEUE_MAX as u64 && Instant::now() < deadline {
            line.read_host().unwrap();
        }
        assert_eq!(
            line.stats().from_host,
            HOST_QUEUE_MAX as u64,
            "the rest waits"
        );
        assert!(line.next_for_chip().is_some());
        while line.stats().from_host == HOST_QUEUE_MAX as u64 && Instant::now() < deadline {
            line.read_host().unwrap();
        }
        assert_eq!(
            line.stats().from_host,
            HOST_QUEUE_MAX as u64 + 1,
            "room for one more"
        );
    }

    #[test]
    fn bytes_nobody_reads_are_dropped_after_the_patience() {
        let pty = Pty::open().unwrap();
        let mut line = SerialLine::new(&pty);
        let t0 = Instant::now();
        let mut sent = 0u64;
        // Fill the terminal's buffers (the kernel moves bytes between them in the background:
        // full is when a pause frees no room).
        loop {
            line.send_to_host(&[b'x'; 4096]);
            sent += 4096;
            line.flush(t0).unwrap();
            assert!(sent < 1 << 24, "the terminal never filled up");
            if line.has_output() {
                std::thread::sleep(Duration::from_millis(20));
                line.flush(t0).unwrap();
                if line.has_output() {
                    break;
                }
            }
        }
        line.flush(t0 + WRITE_PATIENCE / 2).unwrap();
        assert!(line.has_output(), "still waiting");
        line.flush(t0 + WRITE_PATIENCE).unwrap();
        assert!(!line.has_output());
        let stats = line.stats();
        assert!(stats.dropped > 0);
        assert_eq!(stats.to_host + stats.dropped, sent);
    }
}
