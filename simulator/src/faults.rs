//! Fault injection between the device model and the line (`sonar-sim --faults SPEC`): damaged lines
//! at configured rates and timed events (a reset, a silence), so a driver can be tested against the
//! noise, cut cables and reboots of a real serial link, reproducibly (`--fault-seed`).
//!
//! [`FaultInjector`] is pure: it decides what becomes of each line the head sends and hands the bytes
//! to a writer given by the caller, and it writes a log of every line and event to any
//! [`Write`]. [`serve`](crate::serve::serve) only calls it.
//!
//! # What it does
//!
//! Each line (terminator included) suffers at most one of the [`LineFault`]s, drawn with the rates of
//! the [`FaultSpec`]. A line cut short (`truncate`, or a flipped terminator) runs into the next one,
//! as on a real line: the receiver sees one line made of both, and the log says so (`"joined"`, kind
//! `merged` if the second was otherwise intact). `HELLO` lines are spared unless `hello=damage`: a
//! driver that misses the head's announcement retries its handshake and flushes the port, and the
//! bytes such a flush throws away could not be accounted for by a test. A spared line after a line
//! cut short starts on a line of its own (the terminator is sent first).
//!
//! Nothing is damaged and no clock runs before the host's first bytes: until then nobody listens,
//! and a driver flushes what was queued before its handshake. Timed events count simulated time
//! from that moment (from the start for the hobby sketch, which nobody speaks to). A silence drops every line the head sends and every byte it receives; the model
//! itself runs on, as if the cable were cut.
//!
//! # The log (`--fault-log`)
//!
//! JSON lines, one object per line the head sent and per event, in order; byte strings as JSON
//! strings with one character per byte (U+0000–U+00FF, i.e. Latin-1), so any byte survives:
//!
//! ```text
//! {"sim_ms":5,"event":"start"}                                  the host's first bytes: faults start
//! {"sim_ms":240,"kind":"intact","line":"$RD,…*1A2B\n"}
//! {"sim_ms":480,"kind":"truncate","line":"$RD,…*77C1\n","sent":"$RD,1,4"}
//! {"sim_ms":720,"kind":"merged","line":"$RD,…*0F3E\n","joined":true}
//! {"sim_ms":9000,"event":"reset"}
//! {"sim_ms":20000,"event":"silence","until_ms":24000}
//! {"sim_ms":20010,"kind":"silenced","line":"$RD,…\n"}           not sent
//! {"sim_ms":20100,"event":"unheard","input":"$STATUS*…\n"}       host bytes the head ignored
//! {"sim_ms":24000,"event":"silence-end"}
//! ```
//!
//! `sim_ms` is the simulator's clock. `sent` is present when the bytes sent differ from `line`;
//! `written` when the terminal took only that many of them (a reader that stopped reading).

use std::fmt;
use std::io::{self, Write};
use std::str::FromStr;
use std::time::Duration;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use sonar_common::protocol::MAX_LINE_LEN;

/// An example of the `--faults` syntax.
pub const EXAMPLE_SPEC: &str = "bitflip=0.01,double-flip=0.01,truncate=0.005,garbage=0.01,\
                                overlong=0.002,stray=0.01,reset=30s,silence=20s:4s";

/// A way one line gets damaged.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum LineFault {
    /// A line of random bytes before the line, which follows intact.
    Garbage,
    /// One bit of one byte (the terminator too) flipped.
    BitFlip,
    /// The same bit (0–6, so both stay ASCII) flipped in two bytes before the terminator: the error
    /// that protocol version 1's XOR check cannot see.
    DoubleFlip,
    /// The line cut short, terminator included, so that it runs into the next line.
    Truncate,
    /// The line padded with printable bytes past [`MAX_LINE_LEN`].
    Overlong,
    /// A few random bytes before the line, on the same line.
    Stray,
}

impl LineFault {
    pub const ALL: [LineFault; 6] = [
        LineFault::Garbage,
        LineFault::BitFlip,
        LineFault::DoubleFlip,
        LineFault::Truncate,
        LineFault::Overlong,
        LineFault::Stray,
    ];

    /// The name in the spec, the log and the counts.
    pub fn name(self) -> &'static str {
        match self {
            LineFault::Garbage => "garbage",
            LineFault::BitFlip => "bitflip",
            LineFault::DoubleFlip => "double-flip",
            LineFault::Truncate => "truncate",
            LineFault::Overlong => "overlong",
            LineFault::Stray => "stray",
        }
    }

    fn index(self) -> usize {
        self as usize
    }

    fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|f| f.name() == name)
    }
}

/// A broken or misplaced limit switch, played by the device model (`sonar-sim --faults
/// min-switch=dead`) and by the firmware's emulated board (`sonar-firmware-sim --switch-fault
/// min=dead`). Written `dead`, `stuck`, `early:DEG` or `bouncing`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SwitchFault {
    /// Never closes: a broken contact or a cut wire.
    Dead,
    /// Always closed: a welded contact or a short to ground.
    Stuck,
    /// Closes this many degrees (1–90) before its place: a bent lever, a switch that moved.
    Early { deg: u32 },
    /// Bounces as badly as a mechanical switch may (sensor-facts: up to 10 ms) at every change.
    /// The firmware's debounce must make it a good switch; the device model's switches are
    /// debounced contacts, so there it behaves as a good one.
    Bouncing,
}

impl FromStr for SwitchFault {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        let bad = || format!("{s:?}: expected dead, stuck, bouncing or early:DEG (1 to 90)");
        Ok(match s.trim() {
            "dead" => SwitchFault::Dead,
            "stuck" => SwitchFault::Stuck,
            "bouncing" => SwitchFault::Bouncing,
            other => {
                let deg = other
                    .strip_prefix("early:")
                    .and_then(|d| d.trim().parse::<u32>().ok())
                    .filter(|d| (1..=90).contains(d))
                    .ok_or_else(bad)?;
                SwitchFault::Early { deg }
            }
        })
    }
}

/// The faults of the two limit switches (`None`: a good switch).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct SwitchFaults {
    pub min: Option<SwitchFault>,
    pub max: Option<SwitchFault>,
}

impl SwitchFaults {
    /// Whether either switch bounces badly.
    pub fn bouncing(&self) -> bool {
        [self.min, self.max].contains(&Some(SwitchFault::Bouncing))
    }
}

/// What `--faults` asks for.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct FaultSpec {
    /// Probability per line of each [`LineFault`], indexed in the order of [`LineFault::ALL`].
    rates: [f64; LineFault::ALL.len()],
    /// When the head resets, counted from the host's first bytes (simulated time).
    pub resets: Vec<Duration>,
    /// When the head falls silent and for how long (simulated time).
    pub silences: Vec<(Duration, Duration)>,
    /// Whether `HELLO` lines may be damaged too.
    pub damage_hello: bool,
    /// Broken limit switches (`min-switch=…`, `max-switch=…`): the device model plays them.
    pub switches: SwitchFaults,
}

impl FaultSpec {
    /// Probability that a line suffers `fault`.
    pub fn rate(&self, fault: LineFault) -> f64 {
        self.rates[fault.index()]
    }
}

/// Why a `--faults` spec was refused.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SpecError {
    #[error("empty fault spec (e.g. {EXAMPLE_SPEC})")]
    Empty,
    #[error("expected KEY=VALUE, got {0:?}")]
    NotKeyValue(String),
    #[error(
        "unknown key {0:?} (known: garbage, bitflip, double-flip, truncate, overlong, stray, \
         reset, silence, hello, min-switch, max-switch)"
    )]
    UnknownKey(String),
    #[error("{key}={why}")]
    BadSwitch { key: String, why: String },
    #[error("{0} is given twice")]
    Duplicate(String),
    #[error("{key}={value}: a rate is a probability per line, from 0 to 1 (or 0% to 100%)")]
    BadRate { key: String, value: String },
    #[error("the rates add up to {0}, more than 1: a line suffers at most one fault")]
    RatesAboveOne(f64),
    #[error("{key}={value}: expected a duration such as 30s, 500ms or 2min")]
    BadDuration { key: &'static str, value: String },
    #[error("silence={0}: expected START:LENGTH with a length above 0, e.g. silence=20s:5s")]
    BadSilence(String),
    #[error("hello={0}: expected spare or damage")]
    BadHello(String),
}

impl FromStr for FaultSpec {
    type Err = SpecError;

    /// Comma-separated `KEY=VALUE` items; see [`EXAMPLE_SPEC`] and `sonar-sim --help`.
    fn from_str(s: &str) -> Result<Self, SpecError> {
        if s.trim().is_empty() {
            return Err(SpecError::Empty);
        }
        let mut spec = FaultSpec::default();
        let mut seen = [false; LineFault::ALL.len()];
        let mut hello_seen = false;
        for item in s.split(',').map(str::trim) {
            let (key, value) = item
                .split_once('=')
                .map(|(k, v)| (k.trim(), v.trim()))
                .ok_or_else(|| SpecError::NotKeyValue(item.to_owned()))?;
            if let Some(fault) = LineFault::from_name(key) {
                if std::mem::replace(&mut seen[fault.index()], true) {
                    return Err(SpecError::Duplicate(key.to_owned()));
                }
                spec.rates[fault.index()] =
                    parse_rate(value).ok_or_else(|| SpecError::BadRate {
                        key: key.to_owned(),
                        value: value.to_owned(),
                    })?;
                continue;
            }
            match key {
                "reset" => spec.resets.push(parse_duration("reset", value)?),
                "silence" => {
                    let (at, length) = value
                        .split_once(':')
                        .ok_or_else(|| SpecError::BadSilence(value.to_owned()))?;
                    let at = parse_duration("silence", at.trim())?;
                    let length = parse_duration("silence", length.trim())?;
                    if length.is_zero() {
                        return Err(SpecError::BadSilence(value.to_owned()));
                    }
                    spec.silences.push((at, length));
                }
                "min-switch" | "max-switch" => {
                    let slot = if key == "min-switch" {
                        &mut spec.switches.min
                    } else {
                        &mut spec.switches.max
                    };
                    if slot.is_some() {
                        return Err(SpecError::Duplicate(key.to_owned()));
                    }
                    *slot = Some(value.parse().map_err(|why| SpecError::BadSwitch {
                        key: key.to_owned(),
                        why,
                    })?);
                }
                "hello" => {
                    if std::mem::replace(&mut hello_seen, true) {
                        return Err(SpecError::Duplicate(key.to_owned()));
                    }
                    spec.damage_hello = match value {
                        "spare" => false,
                        "damage" => true,
                        _ => return Err(SpecError::BadHello(value.to_owned())),
                    };
                }
                _ => return Err(SpecError::UnknownKey(key.to_owned())),
            }
        }
        let total: f64 = spec.rates.iter().sum();
        // Rates such as 0.1 + 0.2 + 0.7 may add up to a hair above 1 in binary.
        if total > 1.0 + 1e-9 {
            return Err(SpecError::RatesAboveOne(total));
        }
        Ok(spec)
    }
}

/// `0.01` or `1%`.
fn parse_rate(value: &str) -> Option<f64> {
    let (number, scale) = match value.strip_suffix('%') {
        Some(percent) => (percent, 100.0),
        None => (value, 1.0),
    };
    let rate = number.trim().parse::<f64>().ok()? / scale;
    (0.0..=1.0).contains(&rate).then_some(rate)
}

/// `30s`, `500ms`, `1.5s`, `2min`.
fn parse_duration(key: &'static str, value: &str) -> Result<Duration, SpecError> {
    let bad = || SpecError::BadDuration {
        key,
        value: value.to_owned(),
    };
    let (number, unit_s) = if let Some(n) = value.strip_suffix("ms") {
        (n, 1e-3)
    } else if let Some(n) = value.strip_suffix("min") {
        (n, 60.0)
    } else if let Some(n) = value.strip_suffix('s') {
        (n, 1.0)
    } else {
        return Err(bad());
    };
    let seconds = number.trim().parse::<f64>().map_err(|_| bad())? * unit_s;
    Duration::try_from_secs_f64(seconds).map_err(|_| bad())
}

/// How many of each fault were injected.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FaultCounts {
    lines: [u64; LineFault::ALL.len()],
    /// Lines sent intact that ran into a line cut short before them.
    pub merged: u64,
    /// Lines lost in a silence.
    pub silenced: u64,
    pub resets: u64,
    pub silences: u64,
}

impl FaultCounts {
    /// Lines that suffered `fault`.
    pub fn lines(&self, fault: LineFault) -> u64 {
        self.lines[fault.index()]
    }
}

impl fmt::Display for FaultCounts {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for fault in LineFault::ALL {
            write!(f, "{} {}, ", fault.name(), self.lines(fault))?;
        }
        write!(
            f,
            "merged {}, silenced {}, resets {}, silences {}",
            self.merged, self.silenced, self.resets, self.silences
        )
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum TimedEvent {
    Reset,
    Silence(Duration),
}

/// Damages the lines the head sends and times resets and silences; see the module docs.
pub struct FaultInjector {
    spec: FaultSpec,
    /// Timed events by time since the host's first bytes.
    events: Vec<(Duration, TimedEvent)>,
    next_event: usize,
    rng: ChaCha8Rng,
    log: Option<Box<dyn Write + Send>>,
    /// Simulated time of the host's first bytes, µs; faults and event clocks start there.
    start_us: Option<u64>,
    /// The end of the silence under way, simulated µs.
    silent_until_us: Option<u64>,
    /// The bytes sent last did not end their line: the next ones continue it.
    open: bool,
    counts: FaultCounts,
}

impl fmt::Debug for FaultInjector {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("FaultInjector")
            .field("spec", &self.spec)
            .field("start_us", &self.start_us)
            .field("silent_until_us", &self.silent_until_us)
            .field("counts", &self.counts)
            .finish_non_exhaustive()
    }
}

impl FaultInjector {
    /// Faults drawn from `seed`; the log, if any, gets one JSON object per line.
    pub fn new(spec: FaultSpec, seed: u64, log: Option<Box<dyn Write + Send>>) -> Self {
        let mut events: Vec<(Duration, TimedEvent)> = spec
            .resets
            .iter()
            .map(|&at| (at, TimedEvent::Reset))
            .chain(
                spec.silences
                    .iter()
                    .map(|&(at, length)| (at, TimedEvent::Silence(length))),
            )
            .collect();
        events.sort_by_key(|&(at, _)| at);
        Self {
            spec,
            events,
            next_event: 0,
            rng: ChaCha8Rng::seed_from_u64(seed),
            log,
            start_us: None,
            silent_until_us: None,
            open: false,
            counts: FaultCounts::default(),
        }
    }

    pub fn counts(&self) -> &FaultCounts {
        &self.counts
    }

    /// Whether the head is silent: it sends nothing and hears nothing.
    pub fn is_silent(&self) -> bool {
        self.silent_until_us.is_some()
    }

    /// Starts the faults and the event clocks at `now_us`, unless they run already: at the host's
    /// first bytes, or at once for a device that talks unasked (the hobby sketch), to whom a host
    /// never speaks. Logged as the event `start`.
    pub fn start(&mut self, now_us: u64) -> io::Result<()> {
        if self.start_us.is_some() {
            return Ok(());
        }
        self.start_us = Some(now_us);
        self.record(&Entry::event(now_us, "start"))
    }

    /// The host sent `input` at `now_us`; the first time, the faults start. Returns whether the
    /// head hears it (not during a silence).
    pub fn hears(&mut self, input: &[u8], now_us: u64) -> io::Result<bool> {
        self.start(now_us)?;
        if self.is_silent() {
            self.record(&Entry {
                input: Some(latin1(input)),
                ..Entry::event(now_us, "unheard")
            })?;
            return Ok(false);
        }
        Ok(true)
    }

    /// Starts and ends the timed events due at `now_us`; true when the head is to be reset now.
    pub fn advance(&mut self, now_us: u64) -> io::Result<bool> {
        let Some(start_us) = self.start_us else {
            return Ok(false);
        };
        let mut reset = false;
        while let Some(&(at, event)) = self.events.get(self.next_event)
            && start_us.saturating_add(micros(at)) <= now_us
        {
            self.next_event += 1;
            match event {
                TimedEvent::Reset => {
                    self.counts.resets += 1;
                    self.record(&Entry::event(now_us, "reset"))?;
                    reset = true;
                }
                TimedEvent::Silence(length) => {
                    let until = now_us.saturating_add(micros(length));
                    self.silent_until_us =
                        Some(self.silent_until_us.map_or(until, |u| u.max(until)));
                    self.counts.silences += 1;
                    self.record(&Entry {
                        until_ms: Some(until / 1000),
                        ..Entry::event(now_us, "silence")
                    })?;
                }
            }
        }
        if self.silent_until_us.is_some_and(|until| now_us >= until) {
            self.silent_until_us = None;
            self.record(&Entry::event(now_us, "silence-end"))?;
        }
        Ok(reset)
    }

    /// Sends one line the head produced at `now_us` (terminator included), damaged or not, through
    /// `write`, which returns how many bytes the line took (fewer when nobody reads).
    pub fn send(
        &mut self,
        line: &[u8],
        now_us: u64,
        write: impl FnOnce(&[u8]) -> io::Result<usize>,
    ) -> io::Result<()> {
        let Some(&terminator) = line.last() else {
            return Ok(());
        };
        if self.is_silent() {
            self.counts.silenced += 1;
            return self.record(&Entry::line(now_us, "silenced", line));
        }
        let spared = self.start_us.is_none() || (!self.spec.damage_hello && is_hello(line));
        let fault = if spared { None } else { self.draw() };
        let damaged = fault.and_then(|f| damage(f, line, &mut self.rng).map(|bytes| (f, bytes)));
        let (kind, sent) = match damaged {
            Some((fault, bytes)) => {
                self.counts.lines[fault.index()] += 1;
                (fault.name(), bytes)
            }
            None if self.open && spared => ("intact", [&[terminator], line].concat()),
            None if self.open => {
                self.counts.merged += 1;
                ("merged", line.to_vec())
            }
            None => ("intact", line.to_vec()),
        };
        let written = write(&sent)?;
        let entry = Entry {
            sent: (sent != line).then(|| latin1(&sent)),
            joined: self.open,
            written: (written < sent.len()).then_some(written),
            ..Entry::line(now_us, kind, line)
        };
        if let Some(&last) = sent[..written.min(sent.len())].last() {
            self.open = last != terminator;
        }
        self.record(&entry)
    }

    /// Writes what the log holds through.
    pub fn flush(&mut self) -> io::Result<()> {
        match &mut self.log {
            Some(log) => log.flush(),
            None => Ok(()),
        }
    }

    /// One of the line faults, or none, with the spec's rates.
    fn draw(&mut self) -> Option<LineFault> {
        let u: f64 = self.rng.random();
        let mut below = 0.0;
        LineFault::ALL.into_iter().find(|&f| {
            below += self.spec.rate(f);
            u < below
        })
    }

    fn record(&mut self, entry: &Entry) -> io::Result<()> {
        let Some(log) = &mut self.log else {
            return Ok(());
        };
        serde_json::to_writer(&mut *log, entry).map_err(io::Error::other)?;
        log.write_all(b"\n")
    }
}

/// One object of the log; the fields in the order people read them.
#[derive(Debug, Default, Serialize)]
struct Entry {
    sim_ms: u64,
    #[serde(skip_serializing_if = "Option::is_none")]
    event: Option<&'static str>,
    #[serde(skip_serializing_if = "Option::is_none")]
    kind: Option<&'static str>,
    #[serde(skip_serializing_if = "Option::is_none")]
    line: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    sent: Option<String>,
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    joined: bool,
    #[serde(skip_serializing_if = "Option::is_none")]
    written: Option<usize>,
    #[serde(skip_serializing_if = "Option::is_none")]
    until_ms: Option<u64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    input: Option<String>,
}

impl Entry {
    fn event(now_us: u64, event: &'static str) -> Self {
        Self {
            sim_ms: now_us / 1000,
            event: Some(event),
            ..Self::default()
        }
    }

    fn line(now_us: u64, kind: &'static str, line: &[u8]) -> Self {
        Self {
            sim_ms: now_us / 1000,
            kind: Some(kind),
            line: Some(latin1(line)),
            ..Self::default()
        }
    }
}

fn micros(d: Duration) -> u64 {
    u64::try_from(d.as_micros()).unwrap_or(u64::MAX)
}

fn is_hello(line: &[u8]) -> bool {
    line.starts_with(b"$HELLO,")
}

/// Bytes as a string of the characters U+0000–U+00FF, one per byte.
fn latin1(bytes: &[u8]) -> String {
    bytes.iter().map(|&b| char::from(b)).collect()
}

/// A random byte that ends no line in either dialect (`\n`, `\r`, `.`, `#`), so garbage stays the
/// one line it is meant to be.
fn noise_byte(rng: &mut impl Rng, printable: bool) -> u8 {
    loop {
        let b: u8 = if printable {
            rng.random_range(0x20..0x7f)
        } else {
            rng.random()
        };
        if !matches!(b, b'\n' | b'\r' | b'.' | b'#') {
            return b;
        }
    }
}

fn noise(rng: &mut impl Rng, len: usize, printable: bool) -> Vec<u8> {
    (0..len).map(|_| noise_byte(rng, printable)).collect()
}

/// `line` (terminator included) with `fault`; `None` when the line is too short for it.
fn damage(fault: LineFault, line: &[u8], rng: &mut impl Rng) -> Option<Vec<u8>> {
    let (&terminator, content) = line.split_last()?;
    let mut out = line.to_vec();
    match fault {
        LineFault::Garbage => {
            let len = rng.random_range(1..=80);
            let mut garbage = noise(rng, len, false);
            garbage.push(terminator);
            garbage.extend_from_slice(line);
            out = garbage;
        }
        LineFault::BitFlip => {
            let i = rng.random_range(0..out.len());
            out[i] ^= 1 << rng.random_range(0..8);
        }
        LineFault::DoubleFlip => {
            let n = content.len();
            if n < 2 {
                return None;
            }
            let i = rng.random_range(0..n);
            let j = (i + rng.random_range(1..n)) % n;
            let bit = 1 << rng.random_range(0..7);
            out[i] ^= bit;
            out[j] ^= bit;
        }
        LineFault::Truncate => {
            if content.is_empty() {
                return None;
            }
            out.truncate(rng.random_range(1..line.len()));
        }
        LineFault::Overlong => {
            // Longer than the receiver's buffer holds without a terminator.
            let len = rng.random_range(MAX_LINE_LEN + 1..=2 * MAX_LINE_LEN);
            out.truncate(content.len());
            let pad = len.saturating_sub(out.len());
            out.extend(noise(rng, pad, true));
            out.push(terminator);
        }
        LineFault::Stray => {
            let len = rng.random_range(1..=8);
            out = noise(rng, len, false);
            out.extend_from_slice(line);
        }
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::{Value, json};
    use std::sync::{Arc, Mutex};

    const LINE: &[u8] = b"$RD,7,123456,3,-,-14700,4,5800,5830,0,5790*1D0B\n";

    /// A log the test can read back.
    #[derive(Clone, Default)]
    struct Tape(Arc<Mutex<Vec<u8>>>);

    impl Write for Tape {
        fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
            self.0
                .lock()
                .map_err(|_| io::Error::other("poisoned"))?
                .extend_from_slice(buf);
            Ok(buf.len())
        }

        fn flush(&mut self) -> io::Result<()> {
            Ok(())
        }
    }

    impl Tape {
        fn entries(&self) -> Vec<Value> {
            let bytes = self.0.lock().map(|b| b.clone()).unwrap_or_default();
            String::from_utf8(bytes)
                .unwrap()
                .lines()
                .map(|l| serde_json::from_str(l).unwrap())
                .collect()
        }
    }

    fn spec(s: &str) -> FaultSpec {
        s.parse().unwrap()
    }

    fn injector(s: &str) -> (FaultInjector, Tape) {
        let tape = Tape::default();
        let mut faults = FaultInjector::new(spec(s), 7, Some(Box::new(tape.clone())));
        assert!(faults.hears(b"$HELLO,2*4975\n", 0).unwrap());
        (faults, tape)
    }

    /// Sends `line` and returns the bytes that went out.
    fn send(faults: &mut FaultInjector, line: &[u8], now_us: u64) -> Vec<u8> {
        let mut wire = Vec::new();
        faults
            .send(line, now_us, |b| {
                wire.extend_from_slice(b);
                Ok(b.len())
            })
            .unwrap();
        wire
    }

    fn from_latin1(s: &str) -> Vec<u8> {
        s.chars()
            .map(|c| u8::try_from(u32::from(c)).unwrap())
            .collect()
    }

    #[test]
    fn the_spec_reads_rates_and_events() {
        let s = spec(EXAMPLE_SPEC);
        assert_eq!(s.rate(LineFault::BitFlip), 0.01);
        assert_eq!(s.rate(LineFault::DoubleFlip), 0.01);
        assert_eq!(s.rate(LineFault::Truncate), 0.005);
        assert_eq!(s.rate(LineFault::Garbage), 0.01);
        assert_eq!(s.rate(LineFault::Overlong), 0.002);
        assert_eq!(s.rate(LineFault::Stray), 0.01);
        assert_eq!(s.resets, [Duration::from_secs(30)]);
        assert_eq!(
            s.silences,
            [(Duration::from_secs(20), Duration::from_secs(4))]
        );
        assert!(!s.damage_hello);

        let s = spec(" stray = 5% , reset=500ms, reset=1.5s,silence=2min:250ms, hello=damage ");
        assert_eq!(s.rate(LineFault::Stray), 0.05);
        assert_eq!(s.rate(LineFault::Garbage), 0.0);
        assert_eq!(
            s.resets,
            [Duration::from_millis(500), Duration::from_millis(1500)]
        );
        assert_eq!(
            s.silences,
            [(Duration::from_secs(120), Duration::from_millis(250))]
        );
        assert!(s.damage_hello);
        // Exactly 1 in decimal, a hair above in binary.
        assert!(
            "bitflip=0.1,garbage=0.2,stray=0.7"
                .parse::<FaultSpec>()
                .is_ok()
        );
    }

    #[test]
    fn switch_faults_are_read_per_switch() {
        let s = spec("min-switch=dead,max-switch=early:5");
        assert_eq!(s.switches.min, Some(SwitchFault::Dead));
        assert_eq!(s.switches.max, Some(SwitchFault::Early { deg: 5 }));
        assert!(!s.switches.bouncing());
        let s = spec("max-switch=bouncing, min-switch = stuck");
        assert_eq!(s.switches.min, Some(SwitchFault::Stuck));
        assert!(s.switches.bouncing());
        for bad in ["early:0", "early:91", "early", "broken", ""] {
            assert!(
                matches!(
                    format!("min-switch={bad}").parse::<FaultSpec>(),
                    Err(SpecError::BadSwitch { .. })
                ),
                "{bad}"
            );
        }
        assert_eq!(
            "max-switch=dead,max-switch=stuck".parse::<FaultSpec>(),
            Err(SpecError::Duplicate("max-switch".into()))
        );
    }

    #[test]
    fn a_bad_spec_says_what_is_wrong() {
        let err = |s: &str| s.parse::<FaultSpec>().unwrap_err();
        assert_eq!(err(" "), SpecError::Empty);
        assert_eq!(err("bitflip"), SpecError::NotKeyValue("bitflip".into()));
        assert_eq!(err("bitflip=0.1,"), SpecError::NotKeyValue("".into()));
        assert_eq!(err("flip=0.1"), SpecError::UnknownKey("flip".into()));
        assert_eq!(
            err("stray=0.1,stray=0.2"),
            SpecError::Duplicate("stray".into())
        );
        for rate in ["1.5", "-0.1", "x", "NaN", "200%", ""] {
            assert!(
                matches!(err(&format!("garbage={rate}")), SpecError::BadRate { .. }),
                "{rate}"
            );
        }
        assert_eq!(
            err("garbage=0.6,bitflip=0.6"),
            SpecError::RatesAboveOne(1.2)
        );
        for duration in ["30", "-1s", "1e30s", "s", "fast"] {
            assert!(
                matches!(
                    err(&format!("reset={duration}")),
                    SpecError::BadDuration { key: "reset", .. }
                ),
                "{duration}"
            );
        }
        assert_eq!(err("silence=20s"), SpecError::BadSilence("20s".into()));
        assert_eq!(
            err("silence=20s:0s"),
            SpecError::BadSilence("20s:0s".into())
        );
        assert!(matches!(
            err("silence=20s:x"),
            SpecError::BadDuration { key: "silence", .. }
        ));
        assert_eq!(err("hello=yes"), SpecError::BadHello("yes".into()));
        let text = err("reset=soon").to_string();
        assert!(text.contains("30s"), "{text}");
    }

    #[test]
    fn each_fault_damages_the_line_as_documented() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let content = &LINE[..LINE.len() - 1];
        for _ in 0..500 {
            let garbage = damage(LineFault::Garbage, LINE, &mut rng).unwrap();
            assert!(garbage.ends_with(LINE));
            let junk = &garbage[..garbage.len() - LINE.len()];
            assert_eq!(junk.iter().filter(|&&b| b == b'\n').count(), 1);
            assert_eq!(junk.last(), Some(&b'\n'));

            let flipped = damage(LineFault::BitFlip, LINE, &mut rng).unwrap();
            let diff: u32 = flipped
                .iter()
                .zip(LINE)
                .map(|(a, b)| (a ^ b).count_ones())
                .sum();
            assert_eq!((flipped.len(), diff), (LINE.len(), 1));

            let double = damage(LineFault::DoubleFlip, LINE, &mut rng).unwrap();
            let changed: Vec<u8> = double
                .iter()
                .zip(LINE)
                .map(|(a, b)| a ^ b)
                .filter(|&x| x != 0)
                .collect();
            assert_eq!(changed.len(), 2, "two bytes");
            assert_eq!(changed[0], changed[1], "the same bit");
            assert!(changed[0].is_power_of_two() && changed[0] < 0x80);
            assert_eq!(double.last(), Some(&b'\n'), "the terminator stays");
            assert!(
                double
                    .iter()
                    .zip(LINE)
                    .map(|(a, b)| a ^ b)
                    .fold(0, |x, y| x ^ y)
                    == 0,
                "an XOR of all bytes cannot see it"
            );

            let cut = damage(LineFault::Truncate, LINE, &mut rng).unwrap();
            assert!(!cut.is_empty() && cut.len() < LINE.len() && LINE.starts_with(&cut));

            let long = damage(LineFault::Overlong, LINE, &mut rng).unwrap();
            assert!(long.len() > MAX_LINE_LEN + 1 && long.starts_with(content));
            assert_eq!(long.iter().filter(|&&b| b == b'\n').count(), 1);
            assert_eq!(long.last(), Some(&b'\n'));

            let stray = damage(LineFault::Stray, LINE, &mut rng).unwrap();
            assert!(stray.ends_with(LINE) && (1..=8).contains(&(stray.len() - LINE.len())));
            assert!(!stray[..stray.len() - LINE.len()].contains(&b'\n'));
        }
        assert_eq!(damage(LineFault::DoubleFlip, b"$\n", &mut rng), None);
        assert_eq!(damage(LineFault::Truncate, b"\n", &mut rng), None);
        assert_eq!(damage(LineFault::BitFlip, b"", &mut rng), None);
    }

    #[test]
    fn rates_are_kept_and_the_seed_repeats_the_faults() {
        let run = |seed| {
            let mut faults = FaultInjector::new(spec("bitflip=0.2,truncate=0.1"), seed, None);
            faults.hears(b"\n", 0).unwrap();
            let wire: Vec<Vec<u8>> = (0..10_000).map(|_| send(&mut faults, LINE, 0)).collect();
            (wire, *faults.counts())
        };
        let (wire, counts) = run(3);
        assert_eq!(run(3).0, wire, "the same seed, the same faults");
        assert_ne!(run(4).0, wire);
        let flips = counts.lines(LineFault::BitFlip);
        let cuts = counts.lines(LineFault::Truncate);
        assert!((1800..2200).contains(&flips), "{counts}");
        assert!((850..1150).contains(&cuts), "{counts}");
        assert_eq!(counts.lines(LineFault::Garbage), 0);
        // Every cut line runs into the next one, which is counted as merged if otherwise intact.
        assert!(counts.merged > cuts * 6 / 10, "{counts}");
    }

    #[test]
    fn nothing_is_damaged_before_the_host_speaks_nor_hello_lines() {
        let mut faults = FaultInjector::new(spec("garbage=1"), 1, None);
        assert_eq!(send(&mut faults, LINE, 0), LINE);
        assert!(!faults.advance(1_000_000_000).unwrap(), "no clock yet");
        faults.hears(b"x", 5).unwrap();
        assert_ne!(send(&mut faults, LINE, 10), LINE);
        let hello = b"$HELLO,2,sonar-sim 0.1.0,X,150,4,-15000,15000*1234\n";
        assert_eq!(send(&mut faults, hello, 20), hello);
        let mut damaging = FaultInjector::new(spec("garbage=1,hello=damage"), 1, None);
        damaging.start(0).unwrap();
        assert_ne!(send(&mut damaging, hello, 20), hello);
        assert!(damaging.hears(b"x", 30).unwrap());
        assert_eq!(damaging.start_us, Some(0), "started once");
    }

    #[test]
    fn a_cut_line_runs_into_the_next_and_the_log_says_so() {
        let (mut faults, tape) = injector("truncate=1,hello=spare");
        let cut = send(&mut faults, LINE, 1000);
        assert!(!cut.ends_with(b"\n"));
        // The next line is cut too (rate 1), and joins the first.
        send(&mut faults, LINE, 2000);
        // A spared line closes the fragment first, so that it arrives on a line of its own.
        let hello = b"$HELLO,2,fw,X,150,4,-15000,15000*ABCD\n";
        assert_eq!(send(&mut faults, hello, 3000), [b"\n", &hello[..]].concat());

        let entries = tape.entries();
        assert_eq!(entries[0], json!({"sim_ms": 0, "event": "start"}));
        assert_eq!(entries[1]["kind"], "truncate");
        assert_eq!(entries[1]["sim_ms"], 1);
        assert_eq!(entries[1]["line"], latin1(LINE));
        assert_eq!(from_latin1(entries[1]["sent"].as_str().unwrap()), cut);
        assert_eq!(entries[1].get("joined"), None);
        assert_eq!(entries[2]["kind"], "truncate");
        assert_eq!(entries[2]["joined"], true);
        assert_eq!(entries[3]["kind"], "intact");
        assert_eq!(entries[3]["joined"], true);

        let (mut faults, tape) = injector("truncate=0.5");
        let mut after_cut = 0;
        for t in 0..200 {
            let cut = !send(&mut faults, LINE, t).ends_with(b"\n");
            if cut {
                let next = send(&mut faults, LINE, t);
                after_cut += 1;
                if next == LINE {
                    let entry = tape.entries().pop().unwrap();
                    assert_eq!(
                        (entry["kind"].as_str(), entry["joined"].as_bool()),
                        (Some("merged"), Some(true))
                    );
                }
            }
        }
        assert!(after_cut > 0 && faults.counts().merged > 0);
    }

    #[test]
    fn resets_and_silences_come_on_time_from_the_first_host_bytes() {
        let (mut faults, tape) = injector("reset=1s,silence=2s:500ms,reset=3s");
        // The host spoke at 0 in `injector`.
        assert!(!faults.advance(999_999).unwrap());
        assert!(faults.advance(1_000_000).unwrap());
        assert!(!faults.advance(1_500_000).unwrap(), "once");
        assert!(!faults.is_silent());
        faults.advance(2_000_100).unwrap();
        assert!(faults.is_silent());
        assert_eq!(send(&mut faults, LINE, 2_100_000), b"");
        assert!(!faults.hears(b"$STATUS*1234\n", 2_200_000).unwrap());
        assert!(!faults.advance(2_500_099).unwrap());
        assert!(faults.is_silent());
        assert!(!faults.advance(2_500_100).unwrap());
        assert!(!faults.is_silent());
        assert!(faults.hears(b"$STATUS*1234\n", 2_600_000).unwrap());
        assert_eq!(send(&mut faults, LINE, 2_700_000), LINE);
        assert!(faults.advance(3_000_000).unwrap());
        let counts = *faults.counts();
        assert_eq!((counts.resets, counts.silences, counts.silenced), (2, 1, 1));

        let events: Vec<String> = tape
            .entries()
            .iter()
            .map(|e| {
                let what = e.get("event").or_else(|| e.get("kind")).unwrap();
                format!("{}@{}", what.as_str().unwrap(), e["sim_ms"])
            })
            .collect();
        assert_eq!(
            events,
            [
                "start@0",
                "reset@1000",
                "silence@2000",
                "silenced@2100",
                "unheard@2200",
                "silence-end@2500",
                "intact@2700",
                "reset@3000"
            ]
        );
        assert_eq!(tape.entries()[2]["until_ms"], 2500);
        assert_eq!(tape.entries()[4]["input"], "$STATUS*1234\n");
    }

    #[test]
    fn a_line_the_terminal_took_only_in_part_leaves_the_line_open() {
        let (mut faults, tape) = injector("bitflip=0");
        faults.send(LINE, 0, |_| Ok(10)).unwrap();
        let entry = tape.entries().pop().unwrap();
        assert_eq!(entry["written"], 10);
        assert_eq!(entry["kind"], "intact");
        assert_eq!(send(&mut faults, LINE, 0), LINE);
        assert_eq!(tape.entries().pop().unwrap()["kind"], "merged");
        // Nothing taken changes nothing.
        faults.send(LINE, 0, |_| Ok(0)).unwrap();
        assert_eq!(send(&mut faults, LINE, 0), LINE);
        assert_eq!(tape.entries().pop().unwrap()["kind"], "intact");
    }

    #[test]
    fn counts_read_as_one_line() {
        let mut counts = FaultCounts::default();
        counts.lines[LineFault::Stray.index()] = 3;
        counts.resets = 1;
        assert_eq!(
            counts.to_string(),
            "garbage 0, bitflip 0, double-flip 0, truncate 0, overlong 0, stray 3, merged 0, \
             silenced 0, resets 1, silences 0"
        );
    }
}
