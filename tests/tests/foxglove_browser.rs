//! End to end in a real viewer: Foxglove Studio's web build (npm `@foxglove/studio-base`, pinned
//! in `tests/browser/package.json`) in headless Chromium (Debian's `chromium`, driven by
//! `playwright-core`), opening a recording `sonar-record` wrote and the live `sonar-foxglove` of a
//! running pipeline. `.ci/run` installs chromium and runs `npm ci` in `tests/browser`.
//!
//! Everything runs inside a network namespace of the test's own (loopback only): the pipeline,
//! the recorder, the page's static server, the browser. The screenshots of the 3D panel are kept
//! in `target/test-artifacts/foxglove-browser/` (`foxglove-recording.png`, `foxglove-live.png`,
//! and the whole page of each beside them).
#![allow(clippy::unwrap_used, clippy::expect_used)] // a panic is a failure

use std::path::PathBuf;
use std::process::Command;

use sonar_common::ipc;
use sonar_e2e::{
    Netns, Sandbox, check_ok, collect_until, grid_subscriber, path_str, wait_until, workspace,
};

/// The channels Foxglove must list, each a channel both the recording and the live server carry.
const CHANNELS: &str =
    "/foxglove/map,/foxglove/scan,/foxglove/tf,/foxglove/features,/foxglove/beam";

/// Where the screenshots are kept: under the build's target directory, which CI keeps.
fn artifacts() -> PathBuf {
    let target = std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| workspace().join("target"));
    target.join("test-artifacts/foxglove-browser")
}

/// The browser test's driver, with what it needs installed, or a panic that says how.
fn browser_check() -> Command {
    let dir = workspace().join("tests/browser");
    assert!(
        dir.join("node_modules/@foxglove/studio-base/assets/index.js")
            .exists()
            && dir.join("node_modules/playwright-core").exists(),
        "{}/node_modules is incomplete: run .ci/run once (it runs `npm ci` there)",
        dir.display()
    );
    let chromium = std::env::var("SONAR_CHROMIUM").unwrap_or_else(|_| "/usr/bin/chromium".into());
    assert!(
        std::path::Path::new(&chromium).exists(),
        "{chromium} missing: `apt-get install chromium` (.ci/run does), or set SONAR_CHROMIUM"
    );
    let mut command = Command::new("node");
    command
        .arg(dir.join("check_foxglove.mjs"))
        .args(["--chromium", &chromium]);
    command
}

/// The simulated room through `sonar-pipeline` (simulator, driver, fusion and `sonar-foxglove` from
/// its `[foxglove]` table) with `sonar-record` beside it; once the recording holds three sweeps it
/// is closed, and Foxglove opens it, then the live server: every channel in the topic list, no
/// entry in the Problems tab, and a screenshot of the 3D panel with the map, scan, beam and
/// features ticked.
#[test]
fn foxglove_studio_in_chromium_opens_a_recording_and_the_live_server() {
    let netns = Netns::new("foxweb");
    let sandbox = Sandbox::in_netns("foxweb", netns.name());
    let node = sandbox.node("test-grid");
    let grid = grid_subscriber(&node);
    let config = sandbox.root.join("fox.toml");
    let table = "[simulator]\nscene = \"room\"\nspeed = \"20\"\nseed = 4\n\n\
                 [foxglove]\nenabled = true\nport = 8766\ngrid_period = 0.5\n";
    std::fs::write(&config, table).unwrap();
    let logs = sandbox.root.join("logs");
    let file = sandbox.root.join("room.mcap");
    let recorder = sandbox.spawn("sonar-record", &[path_str(&file), "--grid-period", "0.5"]);
    let pipeline = sandbox.spawn(
        "sonar-pipeline",
        &[
            "--no-viewer",
            "--config",
            path_str(&config),
            "--log-dir",
            path_str(&logs),
        ],
    );
    // Three sweeps of 50 readings fused, and a map after them for the recording.
    collect_until(
        &node,
        || grid.receive().unwrap().map(|s| *s.user_header()),
        |got: &[ipc::GridHeader]| got.last().is_some_and(|h| h.readings_fused >= 160),
    );
    assert!(
        recorder.terminate().success(),
        "sonar-record did not exit cleanly"
    );
    let url = "ws://127.0.0.1:8766";
    let log = logs.join("sonar-foxglove.log");
    wait_until(&node, "sonar-foxglove's address in its log", || {
        std::fs::read_to_string(&log).is_ok_and(|l| l.contains(url))
    });

    let out_dir = artifacts();
    for shot in ["foxglove-recording.png", "foxglove-live.png"] {
        let _ = std::fs::remove_file(out_dir.join(shot));
    }
    let mut check = browser_check();
    check
        .args(["--out", path_str(&out_dir)])
        .args(["--topics", CHANNELS])
        .args(["--recording", path_str(&file)])
        .args(["--live", url])
        // The page loads a 56 MB bundle; a loaded machine takes its time.
        .args(["--timeout-s", "180"]);
    let out = netns.wrap(&check).output().unwrap();
    let report = check_ok("check_foxglove.mjs", &out);
    for channel in CHANNELS.split(',') {
        for source in ["recording", "live"] {
            assert!(
                report.contains(&format!("{source}: topic {channel} listed")),
                "{report}"
            );
        }
    }
    assert!(report.contains("recording: played to its end"), "{report}");
    assert!(report.contains("recording: no problems"), "{report}");
    assert!(report.contains("live: no problems"), "{report}");
    assert!(
        report.contains("recording: no error in the 3D panel's settings"),
        "{report}"
    );
    assert!(
        report.contains("live: no error in the 3D panel's settings"),
        "{report}"
    );
    for shot in ["foxglove-recording.png", "foxglove-live.png"] {
        let bytes = std::fs::read(out_dir.join(shot)).unwrap();
        assert!(bytes.starts_with(b"\x89PNG"), "{shot} is not a PNG");
    }

    let (status, stderr) = pipeline.terminate_with_stderr();
    assert!(status.success(), "{stderr}");
    drop((grid, node));
    let left = sandbox.stale_shm_files();
    assert!(left.is_empty(), "stale shared memory: {left:?}");
}
