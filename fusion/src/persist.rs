//! The map on disk: a state file the fusion process saves every few seconds and on shutdown, and
//! restores at start when it was saved with the same settings.
//!
//! # What is saved
//!
//! A [`SavedMap`]: the settings ([`FusionConfig`]: model, rule, grid geometry, every parameter
//! that changes the map) and the engine's [`MapState`] (the cells in the rule's own representation,
//! the radar, the observations kept for re-fusing, poses, scan state and counters), so a restored
//! engine goes on exactly as the saved one would have.
//!
//! # The file
//!
//! | offset | size | field |
//! |---|---|---|
//! | 0 | 8 | magic `SONARMAP` |
//! | 8 | 4 | format version ([`FORMAT_VERSION`]), u32 little-endian |
//! | 12 | 4 | S: length of the settings, u32 LE |
//! | 16 | 8 | P: length of the payload, u64 LE |
//! | 24 | S | the settings: the `[fusion]` table as TOML text (UTF-8) |
//! | 24 + S | P | the payload: [`MapState`] in bincode 1 (fixed-width integers, little-endian) |
//! | 24 + S + P | 4 | CRC-32 (IEEE) of every byte before it, u32 LE |
//!
//! The settings are TOML rather than bincode because they are read first and compared key by key,
//! so a refusal can name what differs (and `head -c 2000 fusion-map.bin` shows them); bincode
//! could not read them back anyway (models and rules are internally tagged enums). The lengths
//! come first so that a short file is told apart from a corrupt one. The checksum covers the whole
//! file, so a torn or bit-rotted file is refused instead of misread.
//!
//! # Writing without ever losing the last good file
//!
//! [`write_atomic`]: the new file is written as `<name>.tmp` in the same directory, fsynced,
//! renamed over the old one (atomic within a file system), and the directory is fsynced so the
//! rename itself survives a power cut. A crash or a failed write at any point leaves the old file
//! as it was (and perhaps a stale `<name>.tmp`, overwritten by the next save).
//!
//! # Off the readings loop
//!
//! Encoding, checksumming, writing and two fsyncs of a large grid take far longer than a
//! snapshot, and an fsync can stall for a long time on a busy disk. The process therefore only
//! copies the state on its loop ([`crate::engine::Engine::capture`], a memory copy of the cells)
//! and hands the copy to a [`Saver`] thread that does the rest; while a save is still being
//! written the next one waits for it (it is never queued twice). `docs/benchmarks.md` has the
//! figures.
//!
//! # Restoring
//!
//! [`restore`] reads the file and takes it only if everything holds: the magic, the version, the
//! lengths, the checksum, settings equal to the process's own, a payload that fits them. Otherwise
//! the engine starts empty and the reason is returned (the process logs it at WARN), and the file
//! is renamed to `<name>.bad` (`<name>.bad.1`, … when that exists: an earlier refused map is never
//! overwritten): the next save would overwrite it, and a map saved under other
//! settings may still be wanted (start the fusion with those settings and that file to get it
//! back). A state file never stops the process from starting.
//!
//! # What can be lost
//!
//! At most what was fused since the last save: one save period (5 s by default) of readings,
//! plus the time a save takes to write. A kill at any moment loses no more than that, and never
//! the previous save.
//!
//! [`MapState`]: crate::state::MapState

use std::fs::{self, File};
use std::io::{self, BufWriter, Read, Write};
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};
use std::sync::mpsc::{self, Receiver, SyncSender, TryRecvError};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use bincode::Options;
use nix::sys::signal::{SigSet, Signal};
use serde::{Deserialize, Serialize};
use sonar_common::ipc::unix_time_ns;

use crate::config::{ConfigError, FusionConfig};
use crate::engine::{Engine, SavedMap};
use crate::state::StateError;

/// The first bytes of every map file.
pub const MAGIC: [u8; 8] = *b"SONARMAP";
/// Version of the file layout and of the payload's encoding; a file of another version is refused.
///
/// Version 2 added the bearing each cell was last heard occupied from (the smooth model's);
/// version 3 the radar's bins, which follow the head; version 4 the nearest echo of the readings
/// kept whose pings disagreed ([`crate::Observation::rejected_echo_m`]).
pub const FORMAT_VERSION: u32 = 4;
/// Magic, version and the two lengths.
const HEADER_LEN: u64 = 24;
const CHECKSUM_LEN: u64 = 4;
/// File name of the state file in [`sonar_common::state_dir`].
pub const DEFAULT_FILE_NAME: &str = "fusion-map.bin";

/// Where and how often the map is saved: `--state-file`, `--save-period`, `--no-persist`, and the
/// same keys in the `[fusion]` table of a pipeline configuration file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct PersistConfig {
    /// Save the map and restore it at start.
    pub persist: bool,
    /// The state file; without it, [`default_state_file`].
    pub state_file: Option<PathBuf>,
    /// Seconds between two saves of a map that changed.
    pub save_period: f64,
}

impl Default for PersistConfig {
    fn default() -> Self {
        Self {
            persist: true,
            state_file: None,
            save_period: 5.0,
        }
    }
}

impl PersistConfig {
    /// Its keys in the `[fusion]` table (see [`crate::config::FusionSection`]).
    pub const KEYS: [&'static str; 3] = ["persist", "state_file", "save_period"];

    /// The save period, if it is a positive number of seconds.
    pub fn period(&self) -> Result<Duration, ConfigError> {
        Duration::try_from_secs_f64(self.save_period)
            .ok()
            .filter(|d| !d.is_zero())
            .ok_or(ConfigError::InvalidParameter {
                name: "save_period",
                value: self.save_period as f32,
                expected: "a positive number of seconds",
            })
    }
}

/// The default state file: [`DEFAULT_FILE_NAME`] in the pipeline's state directory (where the
/// launcher keeps its logs). A pipeline with its own iceoryx2 prefix gets its own file,
/// `fusion-map-<prefix>.bin`, so two pipelines on one machine never share a map.
pub fn default_state_file(prefix: Option<&str>) -> PathBuf {
    let name = match prefix {
        None => DEFAULT_FILE_NAME.to_owned(),
        Some(p) => format!("fusion-map-{p}.bin"),
    };
    sonar_common::state_dir().join(name)
}

/// Why a saved map was not restored.
#[derive(Debug, thiserror::Error)]
pub enum LoadError {
    #[error("it cannot be read: {0}")]
    Unreadable(#[source] io::Error),
    #[error("it is not a sonar map file (no {} magic)", String::from_utf8_lossy(&MAGIC))]
    NotAMapFile,
    #[error("it is format version {found}; this build reads version {FORMAT_VERSION}")]
    WrongVersion { found: u32 },
    #[error("it is truncated: {found} bytes where its header promises {expected}")]
    Truncated { expected: u64, found: u64 },
    #[error("it has {found} bytes where its header promises {expected}: corrupt")]
    TrailingBytes { expected: u64, found: u64 },
    #[error("its checksum is bad (stored {stored:#010x}, computed {computed:#010x}): corrupt")]
    Checksum { stored: u32, computed: u32 },
    #[error("its settings cannot be read: {0}")]
    BadSettings(String),
    #[error("it was saved with other settings: {}", .0.join("; "))]
    SettingsDiffer(Vec<String>),
    #[error("its map cannot be decoded: {0}")]
    BadPayload(String),
    #[error("its map does not fit its settings: {0}")]
    Inconsistent(#[from] StateError),
}

/// Why a map could not be saved (the caller knows the path).
#[derive(Debug, thiserror::Error)]
pub enum SaveError {
    #[error(transparent)]
    Io(#[from] io::Error),
    #[error("cannot encode the settings: {0}")]
    Settings(#[from] toml::ser::Error),
    #[error("cannot encode the map: {0}")]
    Payload(#[from] bincode::Error),
    #[error("the saver thread has stopped")]
    SaverGone,
}

/// The payload's encoding: bincode 1 with fixed-width little-endian integers (so a cell array is
/// a plain run of little-endian values), the same options both ways.
fn payload_options() -> impl Options {
    bincode::DefaultOptions::new()
        .with_fixint_encoding()
        .with_little_endian()
}

/// A writer that checksums what goes through it.
struct Checksummed<W> {
    inner: W,
    crc: crc32fast::Hasher,
}

impl<W: Write> Write for Checksummed<W> {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        let n = self.inner.write(buf)?;
        self.crc.update(&buf[..n]);
        Ok(n)
    }

    fn flush(&mut self) -> io::Result<()> {
        self.inner.flush()
    }
}

/// Writes `map` in the file format to `out`, streaming (no second copy of the cells in memory).
pub fn encode(map: &SavedMap, out: impl Write) -> Result<(), SaveError> {
    let settings = toml::to_string(&map.settings)?;
    let settings_len = u32::try_from(settings.len()).map_err(|_| {
        SaveError::from(io::Error::new(
            io::ErrorKind::InvalidData,
            "settings longer than 4 GiB",
        ))
    })?;
    let payload_len = payload_options().serialized_size(&map.state)?;
    // Large writes through the checksum: it runs fastest on long slices.
    let mut w = BufWriter::with_capacity(
        1 << 20,
        Checksummed {
            inner: out,
            crc: crc32fast::Hasher::new(),
        },
    );
    w.write_all(&MAGIC)?;
    w.write_all(&FORMAT_VERSION.to_le_bytes())?;
    w.write_all(&settings_len.to_le_bytes())?;
    w.write_all(&payload_len.to_le_bytes())?;
    w.write_all(settings.as_bytes())?;
    payload_options().serialize_into(&mut w, &map.state)?;
    let Checksummed { mut inner, crc } = w.into_inner().map_err(|e| e.into_error())?;
    inner.write_all(&crc.finalize().to_le_bytes())?;
    inner.flush()?;
    Ok(())
}

fn le_u32(bytes: &[u8], at: usize) -> u32 {
    let mut b = [0; 4];
    b.copy_from_slice(&bytes[at..at + 4]);
    u32::from_le_bytes(b)
}

fn le_u64(bytes: &[u8], at: usize) -> u64 {
    let mut b = [0; 8];
    b.copy_from_slice(&bytes[at..at + 8]);
    u64::from_le_bytes(b)
}

/// The lengths a file's header declares.
struct Header {
    settings_len: u64,
    payload_len: u64,
}

/// Checks the header at the start of `prefix` against `found`, the length of the whole file:
/// enough to refuse a file that is not a map of this version, or not whole, without reading it.
fn header(prefix: &[u8], found: u64) -> Result<Header, LoadError> {
    let truncated = |expected| LoadError::Truncated { expected, found };
    if prefix.len() < MAGIC.len() {
        return Err(truncated(HEADER_LEN + CHECKSUM_LEN));
    }
    if prefix[..MAGIC.len()] != MAGIC {
        return Err(LoadError::NotAMapFile);
    }
    if prefix.len() < HEADER_LEN as usize {
        return Err(truncated(HEADER_LEN + CHECKSUM_LEN));
    }
    let version = le_u32(prefix, 8);
    if version != FORMAT_VERSION {
        return Err(LoadError::WrongVersion { found: version });
    }
    let header = Header {
        settings_len: u64::from(le_u32(prefix, 12)),
        payload_len: le_u64(prefix, 16),
    };
    // A corrupt length may be huge: that file is too short for it in any case.
    let expected =
        (HEADER_LEN + header.settings_len + CHECKSUM_LEN).saturating_add(header.payload_len);
    if found < expected {
        return Err(truncated(expected));
    }
    if found > expected {
        return Err(LoadError::TrailingBytes { expected, found });
    }
    Ok(header)
}

/// Reads a map file's bytes, checking everything but whether its settings are the wanted ones.
pub fn decode(bytes: &[u8]) -> Result<SavedMap, LoadError> {
    let Header {
        settings_len,
        payload_len,
    } = header(bytes, bytes.len() as u64)?;
    // Every offset below is within the length `header` checked.
    let body_end = bytes.len() - CHECKSUM_LEN as usize;
    let stored = le_u32(bytes, body_end);
    let computed = crc32fast::hash(&bytes[..body_end]);
    if stored != computed {
        return Err(LoadError::Checksum { stored, computed });
    }
    let settings_end = (HEADER_LEN + settings_len) as usize;
    let settings = std::str::from_utf8(&bytes[HEADER_LEN as usize..settings_end])
        .map_err(|e| LoadError::BadSettings(e.to_string()))?;
    let settings: FusionConfig =
        toml::from_str(settings).map_err(|e| LoadError::BadSettings(e.to_string()))?;
    let state = payload_options()
        .with_limit(payload_len)
        .deserialize(&bytes[settings_end..body_end])
        .map_err(|e| LoadError::BadPayload(e.to_string()))?;
    Ok(SavedMap { settings, state })
}

/// Replaces the file at `path` with what `write` writes, atomically: into `<name>.tmp` beside it,
/// fsync, rename over `path`, fsync the directory. If anything fails, the old file is untouched
/// and the temporary one removed. Creates the directory if needed.
pub fn write_atomic<E: From<io::Error>>(
    path: &Path,
    write: impl FnOnce(&mut File) -> Result<(), E>,
) -> Result<(), E> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    fs::create_dir_all(dir)?;
    let tmp = temporary_path(path);
    let result = (|| {
        // Owner-only: the map shows the robot's surroundings, and nobody else's process should
        // read or replace it.
        let mut file = fs::OpenOptions::new()
            .write(true)
            .create(true)
            .truncate(true)
            .mode(0o600)
            .open(&tmp)?;
        write(&mut file)?;
        file.sync_all()?;
        drop(file);
        fs::rename(&tmp, path)?;
        // The rename is durable only once the directory entry is on disk.
        File::open(dir)?.sync_all()?;
        Ok(())
    })();
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    result
}

fn with_suffix(path: &Path, suffix: &str) -> PathBuf {
    let mut name = path.file_name().unwrap_or_default().to_os_string();
    name.push(suffix);
    path.with_file_name(name)
}

/// Where [`write_atomic`] writes before the rename.
pub fn temporary_path(path: &Path) -> PathBuf {
    with_suffix(path, ".tmp")
}

/// Where a refused state file is kept.
pub fn quarantine_path(path: &Path) -> PathBuf {
    with_suffix(path, ".bad")
}

/// Moves a refused state file aside to the first free name of `<name>.bad`, `<name>.bad.1`, …:
/// never over an earlier refused map, which may be the one a user still wants back. The file is
/// linked to its new name (which fails rather than replace an existing one), then unlinked.
pub fn quarantine(path: &Path) -> io::Result<PathBuf> {
    let first = quarantine_path(path);
    for n in 0u32.. {
        let candidate = if n == 0 {
            first.clone()
        } else {
            with_suffix(&first, &format!(".{n}"))
        };
        match fs::hard_link(path, &candidate) {
            Ok(()) => {
                fs::remove_file(path)?;
                return Ok(candidate);
            }
            Err(e) if e.kind() == io::ErrorKind::AlreadyExists => continue,
            Err(e) => return Err(e),
        }
    }
    Err(io::Error::other("no free name for the refused state file"))
}

/// Whether a map can be saved at `path`: its directory is made if missing, and the temporary file
/// a save writes first is created and removed again. Checked at start, so that persistence that
/// cannot work stops the process with the reason instead of failing at every save period.
pub fn check_writable(path: &Path) -> io::Result<()> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    fs::create_dir_all(dir)?;
    let tmp = temporary_path(path);
    fs::OpenOptions::new()
        .write(true)
        .create(true)
        .truncate(true)
        .mode(0o600)
        .open(&tmp)?;
    fs::remove_file(&tmp)
}

/// Saves `map` to `path` atomically ([`write_atomic`]).
pub fn write(path: &Path, map: &SavedMap) -> Result<(), SaveError> {
    write_atomic(path, |file| encode(map, file))
}

/// Reads the map file at `path`; `Ok(None)` if there is none. The header is checked before the
/// rest is read, so a large file that is not a map is refused without reading it.
pub fn read(path: &Path) -> Result<Option<SavedMap>, LoadError> {
    let mut file = match File::open(path) {
        Ok(file) => file,
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(LoadError::Unreadable(e)),
    };
    let found = file.metadata().map_err(LoadError::Unreadable)?.len();
    let mut bytes = Vec::new();
    (&mut file)
        .take(HEADER_LEN)
        .read_to_end(&mut bytes)
        .map_err(LoadError::Unreadable)?;
    header(&bytes, found)?;
    file.read_to_end(&mut bytes)
        .map_err(LoadError::Unreadable)?;
    decode(&bytes).map(Some)
}

/// The settings that differ between a saved map and the process, one `key: saved …, now …` each,
/// by their keys in the `[fusion]` table.
pub fn settings_differences(saved: &FusionConfig, now: &FusionConfig) -> Vec<String> {
    fn flatten(prefix: &str, value: &toml::Value, out: &mut Vec<(String, String)>) {
        match value {
            toml::Value::Table(t) => {
                for (k, v) in t {
                    let key = if prefix.is_empty() {
                        k.clone()
                    } else {
                        format!("{prefix}.{k}")
                    };
                    flatten(&key, v, out);
                }
            }
            v => out.push((prefix.to_owned(), v.to_string())),
        }
    }
    let keys = |config: &FusionConfig| {
        let mut out = Vec::new();
        if let Ok(v) = toml::Value::try_from(config) {
            flatten("", &v, &mut out);
        }
        out
    };
    let (saved, now) = (keys(saved), keys(now));
    let value = |list: &[(String, String)], key: &str| {
        list.iter()
            .find(|(k, _)| k == key)
            .map_or_else(|| "absent".to_owned(), |(_, v)| v.clone())
    };
    let mut all: Vec<&String> = saved.iter().chain(&now).map(|(k, _)| k).collect();
    all.sort();
    all.dedup();
    all.into_iter()
        .filter_map(|key| {
            let (a, b) = (value(&saved, key), value(&now, key));
            (a != b).then(|| format!("{key}: saved {a}, now {b}"))
        })
        .collect()
}

/// What became of the state file at start.
#[derive(Debug)]
pub enum Restore {
    /// The map was restored.
    Restored,
    /// There was no state file: an empty map.
    NoFile,
    /// The file was refused for `reason`: an empty map; the file was moved to `kept_as` (or
    /// could not be moved, for the error given).
    Refused {
        reason: LoadError,
        kept_as: Result<PathBuf, io::Error>,
    },
}

/// The engine for `config` with the map saved at `path` if it was saved with exactly these
/// settings and reads back whole; else an empty one and why (see the module docs). Fails only
/// for an invalid `config`.
pub fn restore(
    path: &Path,
    config: FusionConfig,
    history_limit: usize,
) -> Result<(Engine, Restore), ConfigError> {
    // An invalid configuration is the caller's error, not the file's.
    config.validate()?;
    let loaded = read(path).and_then(|saved| {
        let Some(saved) = saved else {
            return Ok(None);
        };
        if saved.settings != config {
            let mut differences = settings_differences(&saved.settings, &config);
            if differences.is_empty() {
                // Equal as TOML but not as numbers: cannot happen for finite settings.
                differences.push("a value that prints the same".to_owned());
            }
            return Err(LoadError::SettingsDiffer(differences));
        }
        Ok(Some(Engine::restore(config, history_limit, saved.state)?))
    });
    match loaded {
        Ok(Some(engine)) => Ok((engine, Restore::Restored)),
        Ok(None) => Ok((Engine::new(config, history_limit)?, Restore::NoFile)),
        Err(reason) => {
            let kept_as = quarantine(path);
            let engine = Engine::new(config, history_limit)?;
            Ok((engine, Restore::Refused { reason, kept_as }))
        }
    }
}

/// How one save went, reported by the [`Saver`].
#[derive(Debug)]
pub struct SaveReport {
    /// When the map was handed over, ns since the Unix epoch.
    pub taken_ns: u64,
    /// `readings_fused` of the saved map.
    pub readings_fused: u64,
    /// Encoding, writing, fsyncs and rename.
    pub write_time: Duration,
    pub result: Result<(), SaveError>,
    /// The copy that was saved, handed back to capture the next save into
    /// ([`Engine::capture_into`]).
    pub spare: SavedMap,
}

/// The thread that writes maps to the state file, one at a time, off the readings loop.
#[derive(Debug)]
pub struct Saver {
    path: PathBuf,
    /// `None` once closed by [`Saver::finish`].
    jobs: Option<SyncSender<(u64, SavedMap)>>,
    reports: Receiver<SaveReport>,
    thread: Option<JoinHandle<()>>,
    /// Saves handed over whose report has not been taken yet.
    in_flight: usize,
}

impl Saver {
    /// Starts the thread for the state file at `path`.
    pub fn spawn(path: PathBuf) -> io::Result<Self> {
        // Capacity 0: a job is taken only by an idle thread, and `idle` knows when that is.
        let (jobs, job_rx) = mpsc::sync_channel::<(u64, SavedMap)>(0);
        let (report_tx, reports) = mpsc::channel();
        let thread_path = path.clone();
        let thread = std::thread::Builder::new()
            .name("map-saver".into())
            .spawn(move || {
                // SIGINT and SIGTERM go to the readings loop, whose wait they end at once; taken
                // by this thread, they would leave that loop asleep until its next tick.
                let mut termination = SigSet::empty();
                termination.add(Signal::SIGINT);
                termination.add(Signal::SIGTERM);
                let _ = termination.thread_block();
                for (taken_ns, map) in job_rx {
                    let start = Instant::now();
                    let result = write(&thread_path, &map);
                    let report = SaveReport {
                        taken_ns,
                        readings_fused: map.state.readings_fused(),
                        write_time: start.elapsed(),
                        result,
                        spare: map,
                    };
                    if report_tx.send(report).is_err() {
                        break;
                    }
                }
            })?;
        Ok(Self {
            path,
            jobs: Some(jobs),
            reports,
            thread: Some(thread),
            in_flight: 0,
        })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Whether no save is being written: the moment to take the next copy.
    pub fn idle(&self) -> bool {
        self.in_flight == 0
    }

    /// Hands `map` to the thread (waiting for a save in progress to end).
    pub fn save(&mut self, map: SavedMap) -> Result<(), SaveError> {
        let jobs = self.jobs.as_ref().ok_or(SaveError::SaverGone)?;
        jobs.send((unix_time_ns(), map))
            .map_err(|_| SaveError::SaverGone)?;
        self.in_flight += 1;
        Ok(())
    }

    /// The saves finished since the last call.
    pub fn finished(&mut self) -> Vec<SaveReport> {
        let mut out = Vec::new();
        loop {
            match self.reports.try_recv() {
                Ok(report) => out.push(report),
                Err(TryRecvError::Empty) => break,
                Err(TryRecvError::Disconnected) => {
                    // The thread is gone: nothing is in flight any more.
                    self.in_flight = 0;
                    break;
                }
            }
        }
        self.in_flight -= out.len().min(self.in_flight);
        out
    }

    /// Saves `last` if given, waits for every save to be written, stops the thread, and returns
    /// the reports not taken yet. Later saves fail with [`SaveError::SaverGone`].
    pub fn finish(&mut self, last: Option<SavedMap>) -> Vec<SaveReport> {
        let mut failed = Vec::new();
        if let Some(map) = last {
            let readings_fused = map.state.readings_fused();
            if let Err(e) = self.save(map) {
                failed.push(SaveReport {
                    taken_ns: unix_time_ns(),
                    readings_fused,
                    write_time: Duration::ZERO,
                    result: Err(e),
                    spare: SavedMap::default(),
                });
            }
        }
        self.jobs = None;
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
        let mut reports: Vec<SaveReport> = self.reports.try_iter().collect();
        reports.append(&mut failed);
        self.in_flight = 0;
        reports
    }
}

impl Drop for Saver {
    fn drop(&mut self) {
        // Closing the channel ends the thread after the save in progress; not waiting for it
        // here (`finish` does) keeps a drop on an error path from blocking.
        self.jobs = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::{GridConfig, Preset};
    use crate::rule::{RuleConfig, RuleKind};
    use sonar_common::ipc::{
        FusionCommand, FusionCommandKind, LAYOUT_VERSION, Pose2D, Reading, flags, preset_code,
    };

    /// A directory of its own under the system's temporary one, removed when dropped.
    struct TestDir(PathBuf);

    impl TestDir {
        fn new(name: &str) -> Self {
            let dir =
                std::env::temp_dir().join(format!("sonar-persist-{}-{name}", std::process::id()));
            let _ = fs::remove_dir_all(&dir);
            fs::create_dir_all(&dir).unwrap();
            Self(dir)
        }

        fn file(&self, name: &str) -> PathBuf {
            self.0.join(name)
        }
    }

    impl Drop for TestDir {
        fn drop(&mut self) {
            let _ = fs::remove_dir_all(&self.0);
        }
    }

    /// A small grid, so a test can afford to damage every byte of its file.
    fn small(rule: RuleKind) -> FusionConfig {
        FusionConfig {
            grid: GridConfig {
                cells: 24,
                resolution_m: 0.25,
                ..GridConfig::default()
            },
            rule: RuleConfig::default_for(rule),
            clear_on_no_echo: true,
            ..FusionConfig::default()
        }
    }

    fn reading(seq: u64, angle_deg: f32, distance_m: f32) -> Reading {
        Reading {
            seq,
            layout_version: LAYOUT_VERSION,
            sweep_id: (seq / 50) as u32,
            angle_deg,
            beam_half_angle_deg: 30.0,
            distance_m,
            min_range_m: 0.03,
            max_range_m: 4.0,
            direction: 1,
            mode: 1,
            flags: if seq.is_multiple_of(7) {
                flags::NO_ECHO
            } else {
                0
            },
            ..Reading::default()
        }
    }

    /// Readings of a wall, from `first` on, at a pose that moves now and then.
    fn feed(engine: &mut Engine, first: u64, count: u64) {
        for seq in first..first + count {
            if seq.is_multiple_of(20) {
                engine
                    .set_pose(&Pose2D {
                        x_m: 0.01 * seq as f32,
                        y_m: -0.02 * seq as f32,
                        theta_rad: 0.1 * seq as f32,
                        ..Pose2D::default()
                    })
                    .unwrap();
            }
            let angle = -147.0 + 6.0 * (seq % 50) as f32;
            let d = 1.2 / angle.to_radians().cos().abs().max(0.3);
            engine.fuse(&reading(seq, angle, d.min(3.9)));
        }
    }

    fn bytes_of(map: &SavedMap) -> Vec<u8> {
        let mut out = Vec::new();
        encode(map, &mut out).unwrap();
        out
    }

    fn engine_with_readings(config: FusionConfig) -> Engine {
        let mut engine = Engine::new(config, 80).unwrap();
        feed(&mut engine, 0, 130);
        engine
    }

    #[test]
    fn a_restored_engine_is_the_saved_one_bit_for_bit_and_fuses_on_the_same() {
        for rule in RuleKind::ALL {
            let config = small(rule);
            let mut live = engine_with_readings(config);
            let file = bytes_of(&live.capture());
            let saved = decode(&file).unwrap();
            assert_eq!(saved.settings, config);
            assert_eq!(saved.state.readings_fused(), 130);
            assert_eq!(saved.state.last_seq(), Some(129));
            let mut restored = Engine::restore(saved.settings, 80, saved.state).unwrap();
            // Everything, cells and NaN sentinels included, comes back to the bit.
            assert_eq!(bytes_of(&restored.capture()), file, "{rule}");
            // And goes on as the original would have: more readings, then a switch of preset
            // that re-fuses the kept observations.
            for engine in [&mut live, &mut restored] {
                feed(engine, 130, 70);
                engine
                    .apply(&FusionCommand::new(
                        FusionCommandKind::SetPreset,
                        preset_code::PAPER,
                    ))
                    .unwrap();
                feed(engine, 200, 10);
            }
            assert_eq!(
                bytes_of(&restored.capture()),
                bytes_of(&live.capture()),
                "{rule}"
            );
        }
    }

    #[test]
    fn a_shorter_history_keeps_the_latest_observations() {
        let config = small(RuleKind::LogOdds);
        let live = engine_with_readings(config);
        let state = decode(&bytes_of(&live.capture())).unwrap().state;
        assert_eq!(state.history.len(), 80);
        let restored = Engine::restore(config, 30, state.clone()).unwrap();
        let kept = restored.capture().state.history;
        assert_eq!(kept.len(), 30);
        let expected = &state.history[50..];
        for (a, b) in kept.iter().zip(expected) {
            assert_eq!(format!("{a:?}"), format!("{b:?}"));
        }
    }

    #[test]
    fn every_flipped_byte_is_refused() {
        let file = bytes_of(&engine_with_readings(small(RuleKind::Himm)).capture());
        for i in 0..file.len() {
            for bit in [0x01, 0x80] {
                let mut bad = file.clone();
                bad[i] ^= bit;
                let err = decode(&bad).expect_err("a damaged file must be refused");
                // Each kind of byte with the reason it gives.
                match i {
                    0..8 => assert!(matches!(err, LoadError::NotAMapFile), "{i}: {err}"),
                    8..12 => assert!(matches!(err, LoadError::WrongVersion { .. }), "{i}: {err}"),
                    12..24 => assert!(
                        matches!(
                            err,
                            LoadError::Truncated { .. } | LoadError::TrailingBytes { .. }
                        ),
                        "{i}: {err}"
                    ),
                    _ => assert!(matches!(err, LoadError::Checksum { .. }), "{i}: {err}"),
                }
            }
        }
    }

    #[test]
    fn every_truncation_is_refused_as_such() {
        let file = bytes_of(&engine_with_readings(small(RuleKind::Bayes)).capture());
        for len in 0..file.len() {
            match decode(&file[..len]) {
                Err(LoadError::Truncated { found, .. }) => assert_eq!(found, len as u64),
                other => panic!("{len} bytes: {other:?}"),
            }
        }
        let mut longer = file.clone();
        longer.push(0);
        assert!(matches!(
            decode(&longer),
            Err(LoadError::TrailingBytes { .. })
        ));
    }

    #[test]
    fn another_format_version_is_refused_with_its_number() {
        let mut file = bytes_of(&engine_with_readings(small(RuleKind::Bayes)).capture());
        file[8..12].copy_from_slice(&7u32.to_le_bytes());
        let err = decode(&file).unwrap_err();
        assert!(matches!(err, LoadError::WrongVersion { found: 7 }));
        assert_eq!(
            err.to_string(),
            "it is format version 7; this build reads version 4"
        );
    }

    #[test]
    fn other_settings_are_refused_naming_them_and_the_file_is_kept_aside() {
        let dir = TestDir::new("settings");
        let path = dir.file("map.bin");
        let saved = small(RuleKind::LogOdds);
        write(&path, &engine_with_readings(saved).capture()).unwrap();
        use std::os::unix::fs::PermissionsExt;
        let mode = fs::metadata(&path).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode, 0o600, "the state file is its owner's only: {mode:o}");
        let now = FusionConfig {
            grid: GridConfig {
                cells: 32,
                ..saved.grid
            },
            ..FusionConfig::preset(Preset::Paper)
        };
        let (engine, outcome) = restore(&path, now, 80).unwrap();
        assert_eq!(engine.mapper().readings_fused(), 0);
        assert_eq!(engine.mapper().config(), &now);
        let Restore::Refused { reason, kept_as } = outcome else {
            panic!("restored a map of other settings: {outcome:?}")
        };
        let LoadError::SettingsDiffer(differences) = &reason else {
            panic!("{reason}")
        };
        for expected in [
            "grid.cells: saved 24, now 32",
            "rule.kind: saved \"log-odds\", now \"bayes\"",
            "model.kind: saved \"smooth\", now \"paper\"",
            "clear_on_no_echo: saved true, now false",
            "rule.max_log_odds: saved 3.5, now absent",
        ] {
            assert!(
                differences.iter().any(|d| d == expected),
                "{expected} not in {differences:?}"
            );
        }
        assert!(
            !differences
                .iter()
                .any(|d| d.starts_with("grid.resolution_m"))
        );
        assert_eq!(kept_as.unwrap(), dir.file("map.bin.bad"));
        assert!(!path.exists());
        // With the file's own settings it is the map again.
        let (engine, outcome) = restore(&dir.file("map.bin.bad"), saved, 80).unwrap();
        assert!(matches!(outcome, Restore::Restored));
        assert_eq!(engine.mapper().readings_fused(), 130);
    }

    #[test]
    fn no_file_is_an_empty_map_and_a_bad_one_never_stops_the_start() {
        let dir = TestDir::new("bad");
        let config = small(RuleKind::DempsterShafer);
        let path = dir.file("map.bin");
        let (_, outcome) = restore(&path, config, 10).unwrap();
        assert!(matches!(outcome, Restore::NoFile));

        fs::write(&path, b"hello, world\n").unwrap();
        let (engine, outcome) = restore(&path, config, 10).unwrap();
        assert_eq!(engine.mapper().readings_fused(), 0);
        assert!(matches!(
            outcome,
            Restore::Refused {
                reason: LoadError::NotAMapFile,
                kept_as: Ok(_)
            }
        ));
        assert_eq!(
            fs::read(dir.file("map.bin.bad")).unwrap(),
            b"hello, world\n"
        );
        // A second refused file keeps the first refused one.
        fs::write(&path, b"second\n").unwrap();
        let (_, outcome) = restore(&path, config, 10).unwrap();
        assert!(
            matches!(outcome, Restore::Refused { kept_as: Ok(ref p), .. } if *p == dir.file("map.bin.bad.1"))
        );
        assert_eq!(
            fs::read(dir.file("map.bin.bad")).unwrap(),
            b"hello, world\n"
        );
        assert_eq!(fs::read(dir.file("map.bin.bad.1")).unwrap(), b"second\n");

        // Torn and bit-rotted files on disk, each refused for what it is.
        let good = bytes_of(&engine_with_readings(config).capture());
        let mut flipped = good.clone();
        flipped[good.len() / 2] ^= 0x10;
        for (bytes, expected) in [
            (&good[..good.len() - 100], "truncated"),
            (&good[..5], "truncated"),
            (&flipped[..], "checksum"),
        ] {
            fs::write(&path, bytes).unwrap();
            let (engine, outcome) = restore(&path, config, 10).unwrap();
            assert_eq!(engine.mapper().readings_fused(), 0);
            let Restore::Refused { reason, .. } = outcome else {
                panic!("{outcome:?}")
            };
            assert!(reason.to_string().contains(expected), "{reason}");
        }

        // A directory where the file should be: unreadable, still a start.
        fs::create_dir(&path).unwrap();
        let (_, outcome) = restore(&path, config, 10).unwrap();
        assert!(matches!(
            outcome,
            Restore::Refused {
                reason: LoadError::Unreadable(_),
                ..
            }
        ));
    }

    #[test]
    fn a_payload_that_does_not_fit_its_settings_is_refused() {
        let config = small(RuleKind::LogOdds);
        let mut map = engine_with_readings(config).capture();
        // Consistent framing and checksum, but another rule's cells.
        map.settings.rule = RuleConfig::Bayes;
        let dir = TestDir::new("payload");
        let path = dir.file("map.bin");
        write(&path, &map).unwrap();
        let (_, outcome) = restore(&path, map.settings, 10).unwrap();
        let Restore::Refused { reason, .. } = outcome else {
            panic!("{outcome:?}")
        };
        assert!(matches!(
            reason,
            LoadError::Inconsistent(StateError::Rule {
                expected: RuleKind::Bayes,
                found: RuleKind::LogOdds
            })
        ));
    }

    #[test]
    fn a_write_that_fails_midway_leaves_the_old_file_as_it_was() {
        let dir = TestDir::new("atomic");
        let path = dir.file("map.bin");
        let map = engine_with_readings(small(RuleKind::LogOdds)).capture();
        write(&path, &map).unwrap();
        let before = fs::read(&path).unwrap();

        // The new file is half written when the disk gives up.
        let result = write_atomic(&path, |file| -> io::Result<()> {
            file.write_all(&before[..before.len() / 2])?;
            Err(io::Error::new(io::ErrorKind::StorageFull, "disk full"))
        });
        assert_eq!(result.unwrap_err().kind(), io::ErrorKind::StorageFull);
        assert_eq!(fs::read(&path).unwrap(), before);
        assert!(
            !temporary_path(&path).exists(),
            "the temporary file is removed"
        );

        // The rename cannot happen (a directory holds the name): the same.
        let blocked = dir.file("blocked.bin");
        fs::create_dir(&blocked).unwrap();
        fs::write(blocked.join("inside"), b"x").unwrap();
        assert!(write(&blocked, &map).is_err());
        assert!(!temporary_path(&blocked).exists());

        // A stale temporary file from a crash is simply overwritten by the next save.
        fs::write(temporary_path(&path), b"torn").unwrap();
        write(&path, &map).unwrap();
        assert_eq!(fs::read(&path).unwrap(), before);
        assert!(!temporary_path(&path).exists());
    }

    #[test]
    fn the_saver_writes_off_the_calling_thread_and_reports() {
        let dir = TestDir::new("saver");
        let path = dir.file("nested/map.bin");
        let mut engine = engine_with_readings(small(RuleKind::Himm));
        let mut saver = Saver::spawn(path.clone()).unwrap();
        assert!(saver.idle());
        saver.save(engine.capture()).unwrap();
        feed(&mut engine, 130, 5);
        let reports = saver.finish(Some(engine.capture()));
        assert_eq!(reports.len(), 2);
        assert!(reports.iter().all(|r| r.result.is_ok()));
        assert_eq!(reports[1].readings_fused, 135);
        let saved = read(&path).unwrap().unwrap();
        assert_eq!(saved.state.readings_fused(), 135);
        assert_eq!(bytes_of(&saved), bytes_of(&engine.capture()));
    }

    #[test]
    fn capturing_into_an_earlier_copy_is_capturing_afresh() {
        let mut engine = engine_with_readings(small(RuleKind::LogOdds));
        let mut spare = engine.capture();
        feed(&mut engine, 130, 30);
        engine.capture_into(&mut spare);
        assert_eq!(bytes_of(&spare), bytes_of(&engine.capture()));
        // After a switch of rule the copy holds another kind of cell.
        engine
            .apply(&FusionCommand::new(
                FusionCommandKind::SetPreset,
                preset_code::PAPER,
            ))
            .unwrap();
        engine.capture_into(&mut spare);
        assert_eq!(
            spare.settings,
            FusionConfig {
                grid: small(RuleKind::LogOdds).grid,
                ..FusionConfig::preset(Preset::Paper)
            }
        );
        assert_eq!(bytes_of(&spare), bytes_of(&engine.capture()));
    }

    #[test]
    fn the_save_period_must_be_positive() {
        for (period, ok) in [(5.0, true), (0.1, true), (0.0, false), (-1.0, false)] {
            let config = PersistConfig {
                save_period: period,
                ..PersistConfig::default()
            };
            assert_eq!(config.period().is_ok(), ok, "{period}");
        }
        assert!(
            PersistConfig {
                save_period: f64::NAN,
                ..PersistConfig::default()
            }
            .period()
            .is_err()
        );
    }

    #[test]
    fn the_default_file_is_per_prefix_in_the_state_directory() {
        let dir = sonar_common::state_dir();
        assert_eq!(default_state_file(None), dir.join("fusion-map.bin"));
        assert_eq!(
            default_state_file(Some("robot_")),
            dir.join("fusion-map-robot_.bin")
        );
    }
}
