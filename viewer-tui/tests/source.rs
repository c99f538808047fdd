//! The IPC layer against real iceoryx2 services in a private namespace: snapshots arrive whichever
//! side starts first, only the newest is kept, liveness follows the producers, commands reach a
//! consumer. Time is passed in, so "gone" needs no waiting.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::path::PathBuf;
use std::time::{Duration, Instant};

use iceoryx2::port::update_connections::UpdateConnections;
use sonar_common::ipc::{
    self, DriverStatus, FeatureRecord, FeaturesHeader, GridHeader, IpcArgs, LAYOUT_VERSION, Radar,
    ScanCommand, ScanCommandKind, feature_kind,
};
use sonar_viewer::app::{App, Liveness, PEER_TIMEOUT, View};
use sonar_viewer::heatmap::{ColorMode, Palette};
use sonar_viewer::source::Source;

/// A private iceoryx2 namespace, removed when dropped.
struct Namespace {
    args: IpcArgs,
    prefix: String,
    root: PathBuf,
}

impl Namespace {
    fn new(name: &str) -> Self {
        let prefix = format!("svt{}{name}_", std::process::id());
        let root = std::env::temp_dir().join(format!("sonar-viewer-{prefix}"));
        let args = IpcArgs {
            iox_config: None,
            iox_prefix: Some(prefix.clone()),
            iox_root: Some(root.clone()),
        };
        Self { args, prefix, root }
    }
}

impl Drop for Namespace {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.root);
        if let Ok(entries) = std::fs::read_dir("/dev/shm") {
            for e in entries.flatten() {
                if e.file_name().to_string_lossy().starts_with(&self.prefix) {
                    let _ = std::fs::remove_file(e.path());
                }
            }
        }
    }
}

fn header(seq: u64, w: u32, h: u32) -> GridHeader {
    GridHeader {
        seq,
        layout_version: LAYOUT_VERSION,
        width: w,
        height: h,
        resolution_m: 0.05,
        ..GridHeader::default()
    }
}

fn app() -> App {
    App::new(Palette::new(ColorMode::TrueColor), View::Split)
}

#[test]
fn viewer_first_then_fusion_then_fusion_leaves() {
    let ns = Namespace::new("a");
    let t0 = Instant::now();
    let mut app = app();
    let mut source = Source::new(ns.args.node("viewer").unwrap(), t0);
    source.poll(&mut app, t0);
    assert_eq!(app.fusion_peer.liveness(t0), Liveness::Waiting);
    assert!(app.grid.is_none());
    assert_eq!(source.problem(), None);

    let fusion = ns.args.node("fusion").unwrap();
    let grid = ipc::grid_service(&fusion)
        .unwrap()
        .publisher_builder()
        .initial_max_slice_len(16)
        .create()
        .unwrap();
    let radar = ipc::radar_service(&fusion)
        .unwrap()
        .publisher_builder()
        .create()
        .unwrap();
    // Two snapshots before the viewer looks again: it keeps the newer one only.
    for seq in [1, 2] {
        let mut sample = grid.loan_slice_uninit(16).unwrap();
        *sample.user_header_mut() = header(seq, 4, 4);
        sample.write_from_fn(|i| i as u8).send().unwrap();
    }
    radar
        .send_copy(Radar {
            seq: 7,
            ..Radar::default()
        })
        .unwrap();
    let t1 = t0 + Duration::from_secs(1);
    let drawn = app.drawn(t1);
    source.poll(&mut app, t1);
    assert!(app.needs_redraw(t1, Some(&drawn)), "what arrived is drawn");
    let copy = app.grid.as_ref().unwrap();
    assert_eq!(copy.header.seq, 2);
    assert_eq!(copy.cells, (0..16).collect::<Vec<u8>>());
    assert_eq!(app.radar.map(|r| r.seq), Some(7));
    assert_eq!(app.fusion_peer.liveness(t1), Liveness::Alive);

    // Idle but present: a live publisher keeps it alive without samples.
    let t2 = t1 + PEER_TIMEOUT * 3;
    source.poll(&mut app, t2);
    assert_eq!(app.fusion_peer.liveness(t2), Liveness::Alive);

    drop((grid, radar));
    drop(fusion);
    let t3 = t2 + Duration::from_secs(1);
    source.poll(&mut app, t3);
    let t4 = t3 + PEER_TIMEOUT * 2;
    source.poll(&mut app, t4);
    assert!(matches!(app.fusion_peer.liveness(t4), Liveness::Gone(_)));
    assert!(app.grid.is_some(), "the last map stays");
}

#[test]
fn late_viewer_gets_the_driver_status_from_history() {
    let ns = Namespace::new("b");
    let driver = ns.args.node("driver").unwrap();
    let status = ipc::driver_status_service(&driver)
        .unwrap()
        .publisher_builder()
        .create()
        .unwrap();
    status
        .send_copy(DriverStatus {
            lines_rejected: 3,
            layout_version: LAYOUT_VERSION,
            ..DriverStatus::default()
        })
        .unwrap();

    let t0 = Instant::now();
    let mut app = app();
    let mut source = Source::new(ns.args.node("viewer").unwrap(), t0);
    source.poll(&mut app, t0);
    // The history sample is delivered when the publisher next looks at its connections.
    status.update_connections().unwrap();
    source.poll(&mut app, t0);
    assert_eq!(app.driver.map(|s| s.lines_rejected), Some(3));
    assert_eq!(app.driver_peer.liveness(t0), Liveness::Alive);
}

#[test]
fn commands_reach_the_driver_and_say_when_nobody_listens() {
    let ns = Namespace::new("c");
    let t0 = Instant::now();
    let mut source = Source::new(ns.args.node("viewer").unwrap(), t0);
    let full = ScanCommand::new(ScanCommandKind::FullScan, 0.0, 0.0);
    assert_eq!(source.send_scan(full, t0), Ok(0), "no driver yet");

    let driver = ns.args.node("driver").unwrap();
    let commands = ipc::commands_service(&driver)
        .unwrap()
        .subscriber_builder()
        .create()
        .unwrap();
    let local = ScanCommand::new(ScanCommandKind::LocalScan, -30.0, 30.0);
    assert_eq!(source.send_scan(local, t0), Ok(1));
    let received = commands.receive().unwrap().map(|s| *s.payload());
    assert_eq!(received, Some(local));
}

#[test]
fn features_arrive_and_a_snapshot_that_disagrees_with_its_header_is_refused() {
    let ns = Namespace::new("d");
    let t0 = Instant::now();
    let mut app = app();
    let mut source = Source::new(ns.args.node("viewer").unwrap(), t0);
    source.poll(&mut app, t0);

    let fusion = ns.args.node("fusion").unwrap();
    let features = ipc::features_service(&fusion)
        .unwrap()
        .publisher_builder()
        .initial_max_slice_len(ipc::MAX_FEATURES)
        .create()
        .unwrap();
    let post = FeatureRecord {
        id: 5,
        kind: feature_kind::POINT,
        x_m: 1.0,
        y_m: -0.5,
        confidence: 0.8,
        ..FeatureRecord::default()
    };
    let publish = |count: u32, len: usize| {
        let mut sample = features.loan_slice_uninit(len).unwrap();
        *sample.user_header_mut() = FeaturesHeader {
            layout_version: LAYOUT_VERSION,
            feature_count: count,
            sweeps: 3,
            ..FeaturesHeader::default()
        };
        sample.write_from_fn(|_| post).send().unwrap();
    };
    publish(1, 1);
    let drawn = app.drawn(t0);
    source.poll(&mut app, t0);
    assert!(app.needs_redraw(t0, Some(&drawn)), "what arrived is drawn");
    let copy = app.features.as_ref().unwrap();
    assert_eq!(copy.records, vec![post]);
    assert_eq!(copy.header.sweeps, 3);

    // Two records under a header that announces three: refused, the previous copy stays.
    publish(3, 2);
    source.poll(&mut app, t0);
    assert_eq!(app.features.as_ref().unwrap().records.len(), 1);
    let message = app.message.clone().unwrap_or_default();
    assert!(message.contains("ignored a features snapshot"), "{message}");
    assert_eq!(source.problem(), None);
}
