//! The namespace recovery against the leftovers of processes killed at the wrong moment, made by
//! hand from what the fault injection found (see `sonar_common::namespace`): each would make the
//! next process fail or hang without it.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::os::unix::fs::PermissionsExt;
use std::path::{Path, PathBuf};
use std::time::Duration;

use sonar_common::ipc::{self, IpcArgs};
use sonar_common::namespace::{self, NamespaceError};

/// A private namespace, removed when dropped.
struct Namespace {
    args: IpcArgs,
    prefix: String,
    root: PathBuf,
}

impl Namespace {
    fn new(test: &str) -> Self {
        let prefix = format!("sonar_u{}_{test}_", std::process::id());
        let root = std::env::temp_dir().join(format!("{prefix}root"));
        let _ = std::fs::remove_dir_all(&root);
        Self {
            args: IpcArgs {
                iox_config: None,
                iox_prefix: Some(prefix.clone()),
                iox_root: Some(root.clone()),
            },
            prefix,
            root,
        }
    }

    fn files(&self, dir: &Path, suffix: &str) -> Vec<PathBuf> {
        std::fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().path())
            .filter(|p| {
                let name = p.file_name().unwrap().to_string_lossy();
                name.starts_with(&self.prefix) && name.ends_with(suffix)
            })
            .collect()
    }

    /// Creates `sonar/readings` in a node that goes away again, and returns its service record
    /// (path, contents) and its `.dynamic` object's path, as they were.
    fn readings_service_files(&self) -> (PathBuf, String, PathBuf) {
        let node = self.args.node("maker").unwrap();
        let service = ipc::readings_service(&node).unwrap();
        let Ok([record]) = <[_; 1]>::try_from(self.files(&self.root.join("services"), ".service"))
        else {
            panic!("one service record");
        };
        let text = std::fs::read_to_string(&record).unwrap();
        let Ok([dynamic]) = <[_; 1]>::try_from(self.files(Path::new("/dev/shm"), ".dynamic"))
        else {
            panic!("one .dynamic");
        };
        drop((service, node));
        assert!(
            !record.exists() && !dynamic.exists(),
            "removed with its node"
        );
        (record, text, dynamic)
    }

    /// The next process: creates its node and opens the service.
    fn opens_readings(&self) {
        let node = self.args.node("next").unwrap();
        ipc::readings_service(&node).unwrap();
    }
}

impl Drop for Namespace {
    fn drop(&mut self) {
        for f in self.files(Path::new("/dev/shm"), "") {
            let _ = std::fs::remove_file(f);
        }
        let _ = std::fs::remove_dir_all(&self.root);
    }
}

fn write(path: &Path, contents: &str, mode: u32) {
    std::fs::write(path, contents).unwrap();
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(mode)).unwrap();
}

/// An iceoryx2 id as process `pid` would make it now: the monotonic clock's seconds and
/// nanoseconds, the pid, a counter.
fn id_now(pid: u32) -> u128 {
    let now = nix::time::clock_gettime(nix::time::ClockId::CLOCK_MONOTONIC).unwrap();
    u128::from(now.tv_sec() as u32) | u128::from(now.tv_nsec() as u32) << 32 | u128::from(pid) << 64
}

/// An iceoryx2 id of a process that has exited: a child, started and reaped here.
fn id_of_a_dead_process() -> u128 {
    let mut child = std::process::Command::new("true").spawn().unwrap();
    child.wait().unwrap();
    id_now(child.id())
}

/// The record with its `[unique_service_id]` changed to `id`.
fn with_service_id(record: &str, id: u128) -> String {
    let mut out = String::new();
    for line in record.lines() {
        if line.starts_with("payload_value = ") {
            out += &format!("payload_value = {}\n", id as u64);
        } else if line.starts_with("unique_value = ") {
            out += &format!("unique_value = {}\n", (id >> 64) as u64);
        } else {
            out += line;
            out += "\n";
        }
    }
    out
}

#[test]
fn an_unfinished_service_record_of_a_killed_creator_is_removed() {
    let ns = Namespace::new("record");
    let (record, _, _) = ns.readings_service_files();
    // Killed after creating the record (mode 0600), before writing it: HangsInCreation for ever.
    write(&record, "", 0o600);
    ns.opens_readings();
}

#[test]
fn a_zero_byte_dynamic_config_of_a_killed_creator_is_removed() {
    let ns = Namespace::new("dynamic");
    let (record, text, dynamic) = ns.readings_service_files();
    // Killed between creating the service's shared memory (mode 0200) and sizing it: opening it
    // spun for ever. Its name and the record name a creator that has exited.
    let dead = id_of_a_dead_process();
    let name = dynamic.file_name().unwrap().to_string_lossy().into_owned();
    let (stem, _) = name.rsplit_once('_').unwrap();
    let dynamic = dynamic.with_file_name(format!("{stem}_{dead}.dynamic"));
    write(&record, &with_service_id(&text, dead), 0o400);
    write(&dynamic, "", 0o200);
    ns.opens_readings();
    assert!(!dynamic.exists());
}

#[test]
fn a_service_half_removed_by_its_killed_last_member_is_removed() {
    let ns = Namespace::new("halfremoved");
    let (record, text, _) = ns.readings_service_files();
    // Killed after removing the `.dynamic`, before the record: HangsInCreation for ever.
    write(&record, &text, 0o400);
    ns.opens_readings();
}

#[test]
fn an_unfinished_connection_to_a_killed_port_is_removed_though_its_other_side_runs() {
    let ns = Namespace::new("connection");
    ns.readings_service_files();
    // Between a killed publisher and a subscriber of this process, which runs: the subscriber
    // would spin on it, and it connects to nothing.
    let connection = PathBuf::from(format!(
        "/dev/shm/{}0354a209029e7d094a819e2d4030ea331e6caaf0_{}_{}.connection",
        ns.prefix,
        id_of_a_dead_process(),
        id_now(std::process::id())
    ));
    write(&connection, "", 0o200);
    namespace::recover(&ns.args.config().unwrap()).unwrap();
    assert!(!connection.exists());
}

#[test]
fn a_file_a_live_process_leaves_unfinished_is_waited_for_then_named_in_an_error() {
    let ns = Namespace::new("stuck");
    let (_, _, dynamic) = ns.readings_service_files();
    // Named by this process, which runs: somebody's creation in progress, never finished.
    let name = dynamic.file_name().unwrap().to_string_lossy().into_owned();
    let (stem, _) = name.rsplit_once('_').unwrap();
    let mine = id_now(std::process::id());
    let dynamic = dynamic.with_file_name(format!("{stem}_{mine}.dynamic"));
    write(&dynamic, "", 0o200);
    let err = namespace::recover(&ns.args.config().unwrap()).unwrap_err();
    let NamespaceError::Stuck { file, waited, .. } = &err else {
        panic!("{err}");
    };
    assert_eq!(file, &dynamic);
    assert!(*waited >= namespace::PATIENCE - Duration::from_millis(1));
    let text = err.to_string();
    assert!(
        text.contains(&format!("process {}", std::process::id())),
        "{text}"
    );
    assert!(text.contains("remove the file"), "{text}");
}
