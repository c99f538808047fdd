//! Hygiene of an iceoryx2 namespace (one prefix and root path): what processes killed at the
//! wrong moment leave behind, found and removed before a process creates its node.
//!
//! # What a `kill -9` during start-up or shutdown leaves, and why iceoryx2 0.10 does not recover
//!
//! iceoryx2 creates each of its files in an "unfinished" state and marks it finished by its
//! permissions: a static record (`<root>/services/<prefix><hash>.service`, a node's
//! `nodes/<id>/<prefix>….service_tag` or `….port_tag`) starts as mode 0600 and becomes 0400 once
//! written; a shared-memory object (`/dev/shm/<prefix>…_<id>.dynamic`, `.data`, `.event_mgmt`,
//! `.connection`, the per-prefix `….global_mgmt` node counter) starts as 0200, is then sized and
//! becomes readable once initialised. Removing a service goes the other way: the last node leaves
//! the service's dynamic config (which locks it), removes its service tag, then the `.dynamic`,
//! then the `.service`. Fault injection (SIGKILL at each `openat`, `ftruncate`, `fchmod`, `write`,
//! `unlink`, `fcntl` of `sonar-fusion`'s start and shutdown, then another start) found:
//!
//! - an unfinished **`.service`** (0600, empty or fully written): every later opener reports
//!   `HangsInCreation` for ever (upstream iceoryx2 issue #1584), since a dead node's clean-up reads
//!   such a record as "no service" and `Node::force_remove_service` does the same;
//! - an unfinished, **0-byte shared-memory object**: opening it spins for ever (the 0.10 open
//!   loop retries a zero-sized mapping without looking at its timeout), in `open_or_create` of the
//!   service or already in the dead-node clean-up of `NodeBuilder::create`; a 0-byte
//!   `….global_mgmt` hangs every node creation of the prefix;
//! - a **service half-removed** at shutdown (its last node killed after removing its tag): a
//!   finished `.service` without `.dynamic` (`HangsInCreation` for ever) or with a locked one
//!   (`IsMarkedForDestruction` for ever); no node refers to it any more, so nothing removes it;
//! - an unfinished **tag** in a dead node's directory: iceoryx2's dead-node clean-up lists only
//!   finished tags, then cannot remove the non-empty directory and gives up, so the node's monitor
//!   files and directory stay for ever; likewise monitor files without a directory (killed while
//!   removing its node);
//! - a **node directory without a monitor** (killed while writing `node.details`, before the
//!   monitor existed), or monitor files left unfinished: no node list shows it, nothing removes it;
//! - a listener's **`.event_mgmt`** (or another port's memory) whose port never got into the
//!   service: the dead-node clean-up does not see it.
//!
//! # The recovery, and why it is safe
//!
//! [`recover`] runs before every node is created (see `ipc::IpcArgs::node`), under an exclusive
//! `flock` on the root directory so two of our processes never clean at once (one could otherwise
//! remove what the other's removal had just let a live process create again). It relies on two
//! facts about iceoryx2: every id in a file name (node, service, port) holds the creating process's
//! pid and creation time, so [`creator_may_run`] can tell a dead creator from a live one (a pid
//! reused by a later process does not count); and a node writes its service or port tag before it
//! creates or joins what the tag names, and removes it only after leaving it.
//!
//! 1. An unfinished shared-memory object is removed once a process named in it cannot run any
//!    more. A `.dynamic`, `.data` or `.event_mgmt` names only its creator, and nobody else ever
//!    finishes it; a `.connection` names both its ports, either of which may have been creating
//!    it, and with one of them gone it is of no use: a live other side would only spin on it. The
//!    `.global_mgmt` counter names no creator: it is waited for, and removed once unfinished for
//!    longer than [`GLOBAL_MGMT_GRACE`] (its creator sizes it a microsecond after creating it).
//! 2. An unfinished `.service` is removed when no live node holds its tag: a live creator always
//!    does, and an opener writes its tag only once the record is finished. A waiting opener then
//!    finds no service and creates it.
//! 3. A dead node (monitor lock free) loses its unfinished tags (a tag is written before what it
//!    names, so an unfinished one names nothing), then iceoryx2's own clean-up runs
//!    (`DeadNodeView::try_remove_stale_resources`). Whatever of a dead node is left after that
//!    (and all of a node whose monitor was never finished, once its process is gone) is removed
//!    if no tag is left in its directory: then nothing of it is in a service.
//! 4. A finished `.service` that no node (live or dead) holds a tag for has no members: every
//!    member holds a tag while it is one, and a dynamic config without members is locked for good,
//!    so nobody can join it again. Its `.dynamic` and then the record are removed, as its last
//!    member was doing when it was killed; the next opener creates the service anew. The services
//!    are listed before the tags are read, so a service a live process creates meanwhile (its tag
//!    first) is either not listed or has its tag read.
//! 5. A finished port's shared memory whose processes are all gone and whose port has no tag left
//!    is removed: iceoryx2's clean-up (step 3) is done with that port, or it never was in a service.
//!
//! A file unfinished by a process that still runs is somebody's creation in progress: recovery
//! waits for it (a pass every [`POLL`], at most [`PATIENCE`]) and then fails with an error naming
//! the file, the process and the fix, instead of letting iceoryx2 hang or fail later. Steps 3–5
//! run only in a pass that found nothing in progress, since iceoryx2's clean-up opens the services
//! a dead node used and would wait on memory its live creator has not sized yet.
//!
//! Left to iceoryx2: a process that is already opening or connecting to an object when its creator
//! is killed in the microseconds before sizing it (a subscriber connecting to a restarted
//! publisher that is killed while creating their connection, say) spins in iceoryx2's open loop
//! until the next process of the namespace starts, whose recovery removes the object; under the
//! launcher that is the killed process's successor, a restart delay later.

use std::collections::{BTreeMap, BTreeSet};
use std::ffi::OsStr;
use std::fs::{self, File};
use std::io;
use std::os::unix::ffi::OsStrExt;
use std::os::unix::fs::{DirBuilderExt, PermissionsExt};
use std::path::{Path as StdPath, PathBuf};
use std::time::{Duration, Instant, SystemTime};

use iceoryx2::node::NodeView;
use iceoryx2::prelude::*;
use iceoryx2::unique_id_generator::unique_system_id::UniqueSystemId;
use nix::fcntl::{Flock, FlockArg};
use nix::time::{ClockId, clock_gettime};
use nix::unistd::{SysconfVar, sysconf};
use tracing::{debug, info, warn};

/// Where Linux keeps POSIX shared memory, i.e. iceoryx2's `.dynamic`, `.data`, … objects.
const SHM_DIR: &str = "/dev/shm";
/// How long recovery waits for a live process to finish a file it is creating. Creating one takes
/// microseconds; a creator unfinished after this long is stopped or wedged.
pub const PATIENCE: Duration = Duration::from_secs(5);
/// Pause between two recovery passes while a live process is creating something.
pub const POLL: Duration = Duration::from_millis(10);
/// Age after which an unfinished node counter (`….global_mgmt`, which names no creator) is stale:
/// its creator sizes it right after creating it.
pub const GLOBAL_MGMT_GRACE: Duration = Duration::from_secs(1);
/// Mode of an iceoryx2 static record (service record, tag) that is still being written.
const UNFINISHED_RECORD_MODE: u32 = 0o600;
/// A shared-memory object becomes readable by its owner only once it is initialised.
const FINISHED_SHM_BIT: u32 = 0o400;
/// Size of iceoryx2 0.10's finished node counter (`….node.0_10_0.global_mgmt`, the version is in
/// its name): a finished counter of another size was truncated or written by someone else, and
/// every node creation of the prefix would hang on it.
const GLOBAL_MGMT_SIZE: u64 = 16;

/// Why a namespace could not be made usable.
#[derive(Debug, thiserror::Error)]
pub enum NamespaceError {
    #[error("cannot {action} {}: {source}", path.display())]
    Io {
        action: &'static str,
        path: PathBuf,
        source: io::Error,
    },
    #[error(
        "another process has held the clean-up lock of {} for {waited:?} (is a process of this \
         namespace stopped?)",
        root.display()
    )]
    Locked { root: PathBuf, waited: Duration },
    #[error(
        "{} has been left unfinished by {by} for {waited:?}: that process seems stuck \
         (stopped?). Stop it, and the next start cleans up; if no process of this iceoryx2 \
         namespace runs, remove the file",
        file.display()
    )]
    Stuck {
        file: PathBuf,
        /// `process <pid>`, or `an unknown process`.
        by: String,
        waited: Duration,
    },
    #[error("cannot list the iceoryx2 nodes of the namespace: {0:?}")]
    NodeList(iceoryx2::node::NodeListFailure),
    #[error(
        "{} belongs to uid {owner}, not to this user (uid {me}): another user's processes share \
         this iceoryx2 namespace. Run as that user, or give this pipeline a prefix and root of its \
         own (--iox-prefix, --iox-root, the same for every process)",
        file.display()
    )]
    Foreign { file: PathBuf, owner: u32, me: u32 },
}

/// Makes the namespace of `cfg` usable: removes what killed processes left half-created or
/// half-removed and what dead nodes left behind (see the module documentation for what and why),
/// waiting a bounded time for processes that are creating something right now.
pub fn recover(cfg: &Config) -> Result<(), NamespaceError> {
    let ns = Namespace::new(cfg);
    let start = Instant::now();
    loop {
        let lock = ns.lock(start)?;
        let busy = ns.pass()?;
        drop(lock);
        let Some(first) = busy.into_iter().next() else {
            return Ok(());
        };
        if start.elapsed() >= PATIENCE {
            return Err(NamespaceError::Stuck {
                file: first.file,
                by: first.pid.map_or_else(
                    || "an unknown process".into(),
                    |pid| format!("process {pid}"),
                ),
                waited: start.elapsed(),
            });
        }
        std::thread::sleep(POLL);
    }
}

/// A file a process that may still run is creating, and that process if the file names it.
#[derive(Debug)]
struct Busy {
    file: PathBuf,
    pid: Option<u32>,
}

/// The paths and names of one namespace.
struct Namespace<'a> {
    cfg: &'a Config,
    prefix: Vec<u8>,
    root: PathBuf,
    services: PathBuf,
    nodes: PathBuf,
}

fn to_path(path: &Path) -> PathBuf {
    PathBuf::from(OsStr::from_bytes(path.as_bytes()))
}

fn io_error(action: &'static str, path: &StdPath) -> impl FnOnce(io::Error) -> NamespaceError {
    let path = path.to_owned();
    move |source| NamespaceError::Io {
        action,
        path,
        source,
    }
}

/// The entries of `dir` (none if it does not exist).
fn entries(dir: &StdPath) -> Result<Vec<fs::DirEntry>, NamespaceError> {
    match fs::read_dir(dir) {
        Ok(read) => read
            .collect::<Result<_, _>>()
            .map_err(io_error("read directory", dir)),
        Err(e) if e.kind() == io::ErrorKind::NotFound => Ok(Vec::new()),
        Err(e) => Err(io_error("read directory", dir)(e)),
    }
}

/// The permission bits of an entry; `None` if it has gone meanwhile.
fn mode(entry: &fs::DirEntry) -> Result<Option<u32>, NamespaceError> {
    match entry.metadata() {
        Ok(meta) => Ok(Some(meta.permissions().mode() & 0o777)),
        Err(e) if e.kind() == io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(io_error("read", &entry.path())(e)),
    }
}

/// Removes a file left by a dead process, saying why; a file already gone is fine.
fn remove_stale(path: &StdPath, why: &str) -> Result<(), NamespaceError> {
    match fs::remove_file(path) {
        Ok(()) => {
            warn!("removed {} ({why})", path.display());
            Ok(())
        }
        Err(e) if e.kind() == io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(io_error("remove", path)(e)),
    }
}

/// A finished node counter must be this user's and of its size: iceoryx2 makes it writable by
/// everyone (0666), so another local user could truncate it, and every later node creation of
/// the prefix would hang. A foreign counter is refused with the fix; one of the wrong size is
/// removed (the next node creates it anew); an open one is made owner-only.
fn check_counter(path: &StdPath) -> Result<(), NamespaceError> {
    use std::os::unix::fs::MetadataExt;
    let meta = match fs::metadata(path) {
        Ok(meta) => meta,
        Err(e) if e.kind() == io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(io_error("inspect", path)(e)),
    };
    let me = nix::unistd::geteuid().as_raw();
    if meta.uid() != me {
        return Err(NamespaceError::Foreign {
            file: path.to_owned(),
            owner: meta.uid(),
            me,
        });
    }
    if meta.len() != GLOBAL_MGMT_SIZE {
        return remove_stale(
            path,
            &format!(
                "node counter of {} bytes instead of {GLOBAL_MGMT_SIZE}: truncated or not iceoryx2's",
                meta.len()
            ),
        );
    }
    let mode = meta.permissions().mode() & 0o777;
    if mode & 0o077 != 0 {
        fs::set_permissions(path, fs::Permissions::from_mode(mode & 0o700))
            .map_err(io_error("make owner-only", path))?;
        debug!("{} made owner-only (was {mode:04o})", path.display());
    }
    Ok(())
}

/// After this process's node is created: its prefix's node counter, which iceoryx2 has just made
/// writable by everyone, made owner-only ([`check_counter`]).
pub fn secure(cfg: &Config) -> Result<(), NamespaceError> {
    let ns = Namespace::new(cfg);
    let counter = cfg.global.node.global_mgmt_suffix.as_bytes();
    for (path, name, mode) in ns.shared_memory()? {
        if mode & FINISHED_SHM_BIT != 0 && name.ends_with(counter) {
            check_counter(&path)?;
        }
    }
    Ok(())
}

/// An iceoryx2 id written in decimal, as in file names.
fn parse_id(text: &[u8]) -> Option<u128> {
    std::str::from_utf8(text)
        .ok()?
        .parse()
        .ok()
        .filter(|&id| UniqueSystemId::from(id).pid().value() > 0)
}

/// The iceoryx2 ids in a shared-memory name, `<prefix><hash>_<id>[_<id>].<suffix>`.
fn ids_in_name(name: &[u8]) -> Vec<u128> {
    let stem = name.split(|&b| b == b'.').next().unwrap_or_default();
    stem.split(|&b| b == b'_').filter_map(parse_id).collect()
}

fn pid_of(id: u128) -> u32 {
    UniqueSystemId::from(id).pid().value().unsigned_abs()
}

/// Whether the process that made iceoryx2 id `id` may still run. The id holds the creator's pid
/// and its creation time on the monotonic clock; a process with that pid that started later is
/// another one that reuses the pid. Errs towards "may run" wherever it cannot tell. (All processes
/// of a namespace must see each other in `/proc`, as under one launcher they do.)
pub fn creator_may_run(id: u128) -> bool {
    let id = UniqueSystemId::from(id);
    let pid = id.pid().value();
    let stat = match fs::read_to_string(format!("/proc/{pid}/stat")) {
        Ok(stat) => stat,
        Err(e) => return e.kind() != io::ErrorKind::NotFound,
    };
    // `pid (comm) state ppid …`: comm may hold anything, so split after the last `)`.
    let Some((_, rest)) = stat.rsplit_once(')') else {
        return true;
    };
    let fields: Vec<&str> = rest.split_whitespace().collect();
    if matches!(fields.first(), Some(&"Z" | &"X")) {
        return false; // a zombie has released everything it held and creates nothing more
    }
    // Field 22, `starttime`: clock ticks since boot on the boot-time clock, which unlike the
    // monotonic one goes on during suspend, so the id's time is moved onto it.
    let (Some(start_ticks), Ok(Some(hz)), Ok(boot), Ok(mono)) = (
        fields.get(19).and_then(|t| t.parse::<u64>().ok()),
        sysconf(SysconfVar::CLK_TCK),
        clock_gettime(ClockId::CLOCK_BOOTTIME),
        clock_gettime(ClockId::CLOCK_MONOTONIC),
    ) else {
        return true;
    };
    let started = Duration::from_secs_f64(start_ticks as f64 / hz.max(1) as f64);
    let suspended = Duration::from(boot).saturating_sub(Duration::from(mono));
    let created = Duration::new(
        id.creation_time().seconds(),
        id.creation_time().nanoseconds(),
    );
    // The slack covers reading the two clocks one after the other.
    started <= created + suspended + Duration::from_millis(50)
}

/// The `[unique_service_id]` of a service record, which names its `.dynamic` object.
#[derive(serde::Deserialize)]
struct ServiceRecord {
    unique_service_id: RecordId,
}

#[derive(serde::Deserialize)]
struct RecordId {
    payload_value: u64,
    unique_value: u64,
}

impl<'a> Namespace<'a> {
    fn new(cfg: &'a Config) -> Self {
        Self {
            cfg,
            prefix: cfg.global.prefix.as_bytes().to_vec(),
            root: to_path(cfg.global.root_path()),
            services: to_path(&cfg.global.service_dir()),
            nodes: to_path(&cfg.global.node_dir()),
        }
    }

    /// The part of `name` after our prefix and before `suffix`, if it has both.
    fn strip<'n>(&self, name: &'n [u8], suffix: &FileName) -> Option<&'n [u8]> {
        name.strip_prefix(self.prefix.as_slice())?
            .strip_suffix(suffix.as_bytes())
    }

    /// `<prefix><middle><suffix>`, a name iceoryx2 gives a file.
    fn file_name(&self, middle: &[u8], suffix: &FileName) -> Vec<u8> {
        [self.prefix.as_slice(), middle, suffix.as_bytes()].concat()
    }

    /// Serialises the recoveries of our processes (see the module documentation). The lock is on
    /// the root directory itself, so it leaves no file behind; the kernel drops it with its holder.
    fn lock(&self, start: Instant) -> Result<Flock<File>, NamespaceError> {
        fs::DirBuilder::new()
            .recursive(true)
            // Owner-only: everything of the namespace below it is this user's alone.
            .mode(0o700)
            .create(&self.root)
            .map_err(io_error("create", &self.root))?;
        self.tighten_root()?;
        let mut dir = File::open(&self.root).map_err(io_error("open", &self.root))?;
        loop {
            match Flock::lock(dir, FlockArg::LockExclusiveNonblock) {
                Ok(lock) => return Ok(lock),
                Err((back, nix::errno::Errno::EWOULDBLOCK | nix::errno::Errno::EINTR)) => {
                    dir = back;
                }
                Err((_, errno)) => {
                    return Err(io_error("lock", &self.root)(io::Error::from(errno)));
                }
            }
            // A pass takes milliseconds: a holder this slow is stopped.
            if start.elapsed() >= PATIENCE * 2 {
                return Err(NamespaceError::Locked {
                    root: self.root.clone(),
                    waited: start.elapsed(),
                });
            }
            std::thread::sleep(POLL);
        }
    }

    /// A root made by an older version (or iceoryx2 itself, 0750) is made owner-only too, when it
    /// is this user's and iceoryx2's alone: it holds iceoryx2's `services` and `nodes` and nothing
    /// marks it shared (a sticky directory such as /tmp, or a root the user named that holds other
    /// things, is left as it is).
    fn tighten_root(&self) -> Result<(), NamespaceError> {
        use std::os::unix::fs::MetadataExt;
        let meta = fs::metadata(&self.root).map_err(io_error("inspect", &self.root))?;
        let mode = meta.permissions().mode() & 0o7777;
        let dedicated = self.services.is_dir()
            && self.nodes.is_dir()
            && entries(&self.root)?.iter().all(|e| {
                let path = e.path();
                path == self.services
                    || path == self.nodes
                    || path.extension().is_some_and(|x| x == "event")
            });
        if meta.uid() == nix::unistd::geteuid().as_raw()
            && mode & 0o1000 == 0
            && mode & 0o077 != 0
            && dedicated
        {
            fs::set_permissions(&self.root, fs::Permissions::from_mode(0o700))
                .map_err(io_error("make owner-only", &self.root))?;
            info!("{} made owner-only (was {mode:04o})", self.root.display());
        }
        Ok(())
    }

    /// One recovery pass (the steps of the module documentation); returns the files live
    /// processes are still creating.
    fn pass(&self) -> Result<Vec<Busy>, NamespaceError> {
        let mut busy = Vec::new();
        self.sweep_unfinished_memory(&mut busy)?;
        let nodes = Nodes::read(self)?;
        self.sweep_unfinished_records(&nodes, &mut busy)?;
        if busy.is_empty() {
            self.sweep_dead_nodes(nodes)?;
            self.sweep_abandoned_services()?;
            self.sweep_abandoned_port_memory()?;
        }
        Ok(busy)
    }

    /// Our shared-memory objects, with their names and permission bits.
    fn shared_memory(&self) -> Result<Vec<(PathBuf, Vec<u8>, u32)>, NamespaceError> {
        let mut found = Vec::new();
        for entry in entries(StdPath::new(SHM_DIR))? {
            let name = entry.file_name().as_bytes().to_vec();
            if !name.starts_with(&self.prefix) {
                continue;
            }
            if let Some(mode) = mode(&entry)? {
                found.push((entry.path(), name, mode));
            }
        }
        Ok(found)
    }

    /// Step 1: unfinished shared-memory objects whose creators are gone.
    fn sweep_unfinished_memory(&self, busy: &mut Vec<Busy>) -> Result<(), NamespaceError> {
        let counter = self.cfg.global.node.global_mgmt_suffix.as_bytes();
        for (path, name, mode) in self.shared_memory()? {
            if mode & FINISHED_SHM_BIT != 0 {
                if name.ends_with(counter) {
                    check_counter(&path)?;
                }
                continue;
            }
            if name.ends_with(counter) {
                let age = fs::metadata(&path)
                    .and_then(|m| m.modified())
                    .ok()
                    .and_then(|t| SystemTime::now().duration_since(t).ok())
                    .unwrap_or_default();
                if age >= GLOBAL_MGMT_GRACE {
                    remove_stale(&path, "node counter left unfinished by a killed process")?;
                } else {
                    busy.push(Busy {
                        file: path,
                        pid: None,
                    });
                }
                continue;
            }
            let ids = ids_in_name(&name);
            if ids.is_empty() {
                debug!("unfinished {} names no creator: left alone", path.display());
                continue;
            }
            if ids.iter().all(|&id| creator_may_run(id)) {
                busy.push(Busy {
                    file: path,
                    pid: Some(pid_of(ids[0])),
                });
            } else {
                remove_stale(&path, "left unfinished by a killed process")?;
            }
        }
        Ok(())
    }

    /// Step 2: unfinished service records that no live node is creating.
    fn sweep_unfinished_records(
        &self,
        nodes: &Nodes,
        busy: &mut Vec<Busy>,
    ) -> Result<(), NamespaceError> {
        let service = &self.cfg.global.service;
        for entry in entries(&self.services)? {
            let name = entry.file_name();
            let Some(hash) = self.strip(name.as_bytes(), &service.static_config_storage_suffix)
            else {
                continue;
            };
            if mode(&entry)? != Some(UNFINISHED_RECORD_MODE) {
                continue;
            }
            let tag = self.file_name(hash, &self.cfg.global.node.service_tag_suffix);
            let holder = nodes.ids().find(|&id| {
                nodes.live(id)
                    && self
                        .nodes
                        .join(id.to_string())
                        .join(OsStr::from_bytes(&tag))
                        .exists()
            });
            match holder {
                Some(id) => busy.push(Busy {
                    file: entry.path(),
                    pid: Some(pid_of(id)),
                }),
                None => remove_stale(
                    &entry.path(),
                    "service record left unfinished by a killed process; the service is created anew",
                )?,
            }
        }
        Ok(())
    }

    /// Step 3: what dead nodes left.
    fn sweep_dead_nodes(&self, nodes: Nodes) -> Result<(), NamespaceError> {
        let live: BTreeSet<u128> = nodes.ids().filter(|&id| nodes.live(id)).collect();
        for (id, state) in nodes.0 {
            if live.contains(&id) {
                continue;
            }
            let dir = self.nodes.join(id.to_string());
            self.remove_unfinished_tags(&dir)?;
            if let Some(NodeState::Dead(view)) = state {
                let who = view.details().as_ref().map_or_else(
                    || "details lost".to_owned(),
                    |d| format!("{} of pid {}", d.executable(), d.process_id().value()),
                );
                match view.try_remove_stale_resources() {
                    Ok(()) => info!("cleaned up after dead node {id} ({who})"),
                    Err(e) => {
                        debug!("iceoryx2 cannot clean up after dead node {id} ({who}): {e:?}")
                    }
                }
            }
            self.remove_node_leftovers(id, &dir)?;
        }
        Ok(())
    }

    /// Unfinished tags of a dead node: they name nothing (see the module documentation), but stop
    /// iceoryx2's clean-up from removing the node's directory.
    fn remove_unfinished_tags(&self, dir: &StdPath) -> Result<(), NamespaceError> {
        let node = &self.cfg.global.node;
        for entry in entries(dir)? {
            let name = entry.file_name();
            let is_tag = [&node.service_tag_suffix, &node.port_tag_suffix]
                .iter()
                .any(|suffix| self.strip(name.as_bytes(), suffix).is_some());
            if is_tag && mode(&entry)? == Some(UNFINISHED_RECORD_MODE) {
                remove_stale(&entry.path(), "tag left unfinished by a killed process")?;
            }
        }
        Ok(())
    }

    /// What is left of dead node `id` once iceoryx2 is done (its directory and monitor files),
    /// unless a tag says it is still in a service, which iceoryx2 must clean up.
    fn remove_node_leftovers(&self, id: u128, dir: &StdPath) -> Result<(), NamespaceError> {
        let node = &self.cfg.global.node;
        let files = entries(dir)?;
        if let Some(tag) = files.iter().find(|e| {
            let name = e.file_name();
            [&node.service_tag_suffix, &node.port_tag_suffix]
                .iter()
                .any(|suffix| self.strip(name.as_bytes(), suffix).is_some())
        }) {
            warn!(
                "dead node {id} is still in a service ({}), which iceoryx2 could not clean up",
                tag.path().display()
            );
            return Ok(());
        }
        for entry in files {
            remove_stale(&entry.path(), "left by a dead node")?;
        }
        match fs::remove_dir(dir) {
            Ok(()) => debug!("removed {}", dir.display()),
            Err(e) if e.kind() == io::ErrorKind::NotFound => (),
            Err(e) => return Err(io_error("remove", dir)(e)),
        }
        let monitor = self.file_name(id.to_string().as_bytes(), &node.monitor_suffix);
        for entry in entries(&self.nodes)? {
            if entry.file_name().as_bytes().starts_with(&monitor) {
                remove_stale(&entry.path(), "monitor of a dead node")?;
            }
        }
        Ok(())
    }

    /// Step 4: finished services without members, half-removed by a killed last member. The
    /// services are listed before the tags are read: a live member wrote its tag before the record
    /// was finished, so a service listed finished has its tag in the later read unless its last
    /// member left it. Tags read first, a service created by a live process between the two
    /// reads (tag, then record) looked abandoned and was removed under it (a consumer starting
    /// beside a starting `sonar-fusion`, 2026-12-06: the exporter then waited for ever).
    fn sweep_abandoned_services(&self) -> Result<(), NamespaceError> {
        let service = &self.cfg.global.service;
        let listed = entries(&self.services)?;
        let shm = self.shared_memory()?;
        let tags = Tags::read(self)?;
        for entry in listed {
            let name = entry.file_name();
            let Some(hash) = self.strip(name.as_bytes(), &service.static_config_storage_suffix)
            else {
                continue;
            };
            if tags.services.contains(hash) || mode(&entry)? == Some(UNFINISHED_RECORD_MODE) {
                continue;
            }
            let path = entry.path();
            let record = match fs::read_to_string(&path) {
                Ok(text) => toml::from_str::<ServiceRecord>(&text).ok(),
                Err(e) if e.kind() == io::ErrorKind::NotFound => continue,
                Err(e) => return Err(io_error("read", &path)(e)),
            };
            // iceoryx2's order: the dynamic config first, the record last.
            if let Some(record) = record {
                let id = u128::from(record.unique_service_id.unique_value) << 64
                    | u128::from(record.unique_service_id.payload_value);
                let dynamic = [
                    b"_",
                    id.to_string().as_bytes(),
                    service.dynamic_config_storage_suffix.as_bytes(),
                ]
                .concat();
                for (shm_path, shm_name, _) in &shm {
                    if shm_name.ends_with(&dynamic) {
                        remove_stale(shm_path, "state of a service whose last member was killed")?;
                    }
                }
            }
            remove_stale(
                &path,
                "service whose last member was killed while removing it",
            )?;
        }
        Ok(())
    }

    /// Step 5: port memory of dead processes that no port tag refers to any more (listed before
    /// the tags are read, as in step 4).
    fn sweep_abandoned_port_memory(&self) -> Result<(), NamespaceError> {
        let service = &self.cfg.global.service;
        let not_ports = [
            &service.dynamic_config_storage_suffix,
            &service.blackboard_mgmt_suffix,
            &service.blackboard_data_suffix,
            &self.cfg.global.node.global_mgmt_suffix,
        ];
        let listed = self.shared_memory()?;
        let tags = Tags::read(self)?;
        for (path, name, _) in listed {
            if not_ports.iter().any(|s| name.ends_with(s.as_bytes())) {
                continue;
            }
            let ids = ids_in_name(&name);
            let abandoned = !ids.is_empty()
                && ids
                    .iter()
                    .all(|&id| !tags.ports.contains(&id) && !creator_may_run(id));
            if abandoned {
                remove_stale(&path, "memory of a port whose process was killed")?;
            }
        }
        Ok(())
    }
}

/// The nodes of the namespace: every id that has a monitor or a directory holding our files, with
/// the state iceoryx2 reports for it (`None`: it lists none, e.g. no finished monitor).
struct Nodes(BTreeMap<u128, Option<NodeState<ipc::Service>>>);

impl Nodes {
    fn read(ns: &Namespace) -> Result<Self, NamespaceError> {
        let mut nodes = BTreeMap::new();
        Node::<ipc::Service>::list(ns.cfg, |state| {
            nodes.insert(state.node_id().value(), Some(state));
            CallbackProgression::Continue
        })
        .map_err(NamespaceError::NodeList)?;
        for entry in entries(&ns.nodes)? {
            let name = entry.file_name();
            let name = name.as_bytes();
            // `<prefix><id>.node_monitor`, `…_context`, `…_owner_lock`, or a directory `<id>`
            // holding our files (or nothing: killed right after creating it).
            let id = match name.strip_prefix(ns.prefix.as_slice()) {
                Some(monitor) => monitor.split(|&b| b == b'.').next().and_then(parse_id),
                None if entry.file_type().is_ok_and(|t| t.is_dir()) => {
                    let ours = entries(&entry.path())?
                        .iter()
                        .all(|e| e.file_name().as_bytes().starts_with(&ns.prefix));
                    parse_id(name).filter(|_| ours)
                }
                None => None,
            };
            if let Some(id) = id {
                nodes.entry(id).or_insert(None);
            }
        }
        Ok(Self(nodes))
    }

    fn ids(&self) -> impl Iterator<Item = u128> + '_ {
        self.0.keys().copied()
    }

    /// Whether node `id` may still be in use: iceoryx2 sees its monitor lock held, or, where its
    /// monitor says nothing for sure, its process still runs.
    fn live(&self, id: u128) -> bool {
        match self.0.get(&id) {
            Some(Some(NodeState::Alive(_))) => true,
            Some(Some(NodeState::Dead(_))) => false,
            _ => creator_may_run(id),
        }
    }
}

/// The services and ports some node (live or dead) still holds a tag for.
struct Tags {
    services: BTreeSet<Vec<u8>>,
    ports: BTreeSet<u128>,
}

impl Tags {
    fn read(ns: &Namespace) -> Result<Self, NamespaceError> {
        let node = &ns.cfg.global.node;
        let mut tags = Self {
            services: BTreeSet::new(),
            ports: BTreeSet::new(),
        };
        for dir in entries(&ns.nodes)? {
            if !dir.file_type().is_ok_and(|t| t.is_dir()) {
                continue;
            }
            for entry in entries(&dir.path())? {
                let name = entry.file_name();
                let name = name.as_bytes();
                if let Some(hash) = ns.strip(name, &node.service_tag_suffix) {
                    tags.services.insert(hash.to_vec());
                } else if let Some(port) = ns.strip(name, &node.port_tag_suffix).and_then(parse_id)
                {
                    tags.ports.insert(port);
                }
            }
        }
        Ok(tags)
    }
}

/// Why this process cannot use the namespace, if the cause is access: a root directory it cannot
/// write (or create), or shared memory of the prefix it may not open. iceoryx2 reports these as
/// an opaque `InternalError`; this names the file, its owner and mode, and the fix.
pub fn access_problem(cfg: &Config) -> Option<String> {
    let root = to_path(cfg.global.root_path());
    // The root, or the nearest ancestor that exists when the root has to be created.
    let existing = root.ancestors().find(|p| p.exists())?;
    let rwx = nix::unistd::AccessFlags::R_OK
        | nix::unistd::AccessFlags::W_OK
        | nix::unistd::AccessFlags::X_OK;
    if nix::unistd::access(existing, rwx).is_err() {
        let what = if existing == root {
            format!("the iceoryx2 root {}", root.display())
        } else {
            format!(
                "{} (to create the iceoryx2 root {})",
                existing.display(),
                root.display()
            )
        };
        return Some(format!(
            "{what} is not writable by this user ({}): run as the pipeline's user, or give a \
             root of this user's with --iox-root and the same to every process of the pipeline",
            owner_and_mode(existing)
        ));
    }
    let prefix = cfg.global.prefix.as_bytes();
    let rw = nix::unistd::AccessFlags::R_OK | nix::unistd::AccessFlags::W_OK;
    let dir = fs::read_dir(SHM_DIR).ok()?;
    dir.flatten()
        .map(|entry| entry.path())
        .filter(|path| {
            path.file_name()
                .is_some_and(|n| n.as_bytes().starts_with(prefix))
        })
        .find(|path| nix::unistd::access(path.as_path(), rw).is_err())
        .map(|path| {
            format!(
                "the pipeline's shared memory {} may not be opened by this user ({}; iceoryx2 \
                 makes it owner-only): run as the user the pipeline runs as",
                path.display(),
                owner_and_mode(&path)
            )
        })
}

/// `owner uid 1001, mode 0700`, as far as it can be read.
fn owner_and_mode(path: &StdPath) -> String {
    use std::os::unix::fs::MetadataExt;
    match fs::metadata(path) {
        Ok(m) => format!(
            "owner uid {}, mode {:04o}; this user is uid {}",
            m.uid(),
            m.mode() & 0o7777,
            nix::unistd::geteuid()
        ),
        Err(e) => format!("unreadable: {e}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An id as iceoryx2 lays it out: seconds and nanoseconds of the monotonic clock, pid, counter.
    fn id(pid: u32, created: Duration) -> u128 {
        u128::from(created.as_secs() as u32)
            | u128::from(created.subsec_nanos()) << 32
            | u128::from(pid) << 64
            | 7 << 96
    }

    fn now() -> Duration {
        clock_gettime(ClockId::CLOCK_MONOTONIC).map_or(Duration::ZERO, Duration::from)
    }

    /// A namespace of this test's own (prefix and root), and the path of its node counter.
    fn counter_namespace(test: &str) -> (Config, PathBuf) {
        let mut cfg = Config::default();
        let prefix = format!("sonar_u{}_{test}_", std::process::id());
        cfg.global.prefix = FileName::new(prefix.as_bytes()).unwrap();
        let root = std::env::temp_dir().join(format!("{prefix}root/"));
        cfg.global
            .set_root_path(&Path::new(root.as_os_str().as_bytes()).unwrap());
        let suffix = cfg.global.node.global_mgmt_suffix;
        let name = [prefix.as_bytes(), b"9204dd_node.0_10_0", suffix.as_bytes()].concat();
        let counter = StdPath::new(SHM_DIR).join(OsStr::from_bytes(&name));
        (cfg, counter)
    }

    #[test]
    fn a_node_counter_open_to_everyone_is_made_owner_only_and_a_truncated_one_removed() {
        let (cfg, counter) = counter_namespace("counter");
        fs::write(&counter, [0u8; GLOBAL_MGMT_SIZE as usize]).unwrap();
        fs::set_permissions(&counter, fs::Permissions::from_mode(0o666)).unwrap();
        secure(&cfg).unwrap();
        let mode = fs::metadata(&counter).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode, 0o600);

        // Truncated by somebody: removed by the next start's recovery instead of hanging it.
        fs::write(&counter, []).unwrap();
        fs::set_permissions(&counter, fs::Permissions::from_mode(0o666)).unwrap();
        recover(&cfg).unwrap();
        assert!(!counter.exists());

        // Another user's: refused with the fix (needs root to make a file another user's).
        if nix::unistd::geteuid().is_root() {
            fs::write(&counter, [0u8; GLOBAL_MGMT_SIZE as usize]).unwrap();
            fs::set_permissions(&counter, fs::Permissions::from_mode(0o666)).unwrap();
            nix::unistd::chown(&counter, Some(nix::unistd::Uid::from_raw(65534)), None).unwrap();
            let err = recover(&cfg).unwrap_err();
            assert!(
                matches!(err, NamespaceError::Foreign { owner: 65534, .. }),
                "{err}"
            );
            assert!(err.to_string().contains("--iox-prefix"), "{err}");
            fs::remove_file(&counter).unwrap();
        }
        let root = to_path(cfg.global.root_path());
        let mode_of = |p: &StdPath| fs::metadata(p).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode_of(&root), 0o700, "the root is its owner's only");

        // A root an older version left 0750 is tightened when it holds iceoryx2's alone...
        let ns = Namespace::new(&cfg);
        fs::create_dir_all(&ns.services).unwrap();
        fs::create_dir_all(&ns.nodes).unwrap();
        fs::set_permissions(&root, fs::Permissions::from_mode(0o750)).unwrap();
        recover(&cfg).unwrap();
        assert_eq!(mode_of(&root), 0o700);
        // ...and left alone when it holds anything else (a directory the user named).
        fs::write(root.join("notes.txt"), b"mine").unwrap();
        fs::set_permissions(&root, fs::Permissions::from_mode(0o750)).unwrap();
        recover(&cfg).unwrap();
        assert_eq!(mode_of(&root), 0o750);
        let _ = fs::remove_dir_all(root);
    }

    #[test]
    fn ids_are_read_from_shared_memory_names() {
        let dynamic =
            b"sonar_112437a14a36c452eeea7e2aefc2af954fc5a3f2_79228592400328447851396859691.dynamic";
        assert_eq!(ids_in_name(dynamic), vec![79228592400328447851396859691]);
        let made = Duration::new(2547, 558_095_836);
        assert_eq!(pid_of(id(14392, made)), 14392);
        let connection = format!("sonar_0354_{}_{}.connection", id(1, made), id(2, made));
        assert_eq!(
            ids_in_name(connection.as_bytes()),
            vec![id(1, made), id(2, made)]
        );
        let counter = b"sonar_9204dd183d1c4d8e1ff592a30766ffa6765aa8b5_node.0_10_0.global_mgmt";
        assert!(ids_in_name(counter).is_empty());
        assert_eq!(parse_id(b"0"), None, "pid 0 is no process");
    }

    #[test]
    fn a_creator_runs_while_its_process_does_and_not_after() {
        let me = std::process::id();
        assert!(creator_may_run(id(me, now())));
        // An id made before this process started belongs to an earlier process with this pid.
        assert!(!creator_may_run(id(me, Duration::from_secs(0))));
        let mut child = std::process::Command::new("true").spawn().unwrap();
        let pid = child.id();
        let made = now();
        child.wait().unwrap();
        assert!(!creator_may_run(id(pid, made)));
    }
}
