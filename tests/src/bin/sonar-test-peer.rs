//! A plain zenoh peer for the bridge's network tests (`tests/tests/bridge.rs`), playing the
//! machines the robot's bridge must keep out or survive: it connects with the credentials it is
//! given (none, another authority's, a valid but unlisted certificate, a listed one) and either
//! watches everything it can (`watch`) or sends raw bytes to a key (`put`). Not installed: a test
//! tool, built with the workspace's binaries.
//!
//! ```text
//! sonar-test-peer ENDPOINT [--tls CA CERT KEY] watch KEYEXPR
//!     subscribes to KEYEXPR, watches its liveliness tokens and asks for it twice a second; on a
//!     line (or the end) of standard input prints `samples=N replies=M tokens=T` and exits
//! sonar-test-peer ENDPOINT [--tls CA CERT KEY] put KEY FILE COUNT
//!     waits (at most 15 s) to see a robot's token and a subscriber of KEY, prints `robot seen` or
//!     `robot not seen` and `matched` or `not matched`, then puts FILE's bytes on KEY COUNT times
//!     and prints `sent COUNT`
//! ```
#![allow(clippy::unwrap_used, clippy::expect_used)] // a test tool: a failure is the test's failure

use std::io::BufRead;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, mpsc};
use std::time::{Duration, Instant};

use zenoh::Wait;
use zenoh::qos::CongestionControl;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (endpoint, rest) = args.split_first().expect("ENDPOINT");
    let mut config = zenoh::Config::default();
    let mut set = |key: &str, value: String| config.insert_json5(key, &value).unwrap();
    set("mode", "\"peer\"".into());
    set("connect/endpoints", format!("[\"{endpoint}\"]"));
    set("scouting/multicast/enabled", "false".into());
    set("connect/timeout_ms", "-1".into());
    set("connect/exit_on_failure", "false".into());
    let rest = match rest {
        [flag, ca, cert, key, rest @ ..] if flag == "--tls" => {
            for (k, v) in [
                ("root_ca_certificate", ca),
                ("connect_certificate", cert),
                ("connect_private_key", key),
            ] {
                set(&format!("transport/link/tls/{k}"), format!("\"{v}\""));
            }
            set("transport/link/tls/enable_mtls", "true".into());
            rest
        }
        rest => rest,
    };
    let session = zenoh::open(config).wait().unwrap();
    match rest {
        [what, key] if what == "watch" => watch(&session, key),
        [what, key, file, count] if what == "put" => {
            let frame = std::fs::read(file).unwrap();
            put(&session, key, frame, count.parse().unwrap());
        }
        other => panic!("unknown command {other:?}"),
    }
    session.close().wait().unwrap();
}

fn watch(session: &zenoh::Session, key: &str) {
    let samples = Arc::new(AtomicU64::new(0));
    let tokens = Arc::new(AtomicU64::new(0));
    let replies = Arc::new(AtomicU64::new(0));
    let counter = |c: &Arc<AtomicU64>| {
        let c = c.clone();
        move |_: zenoh::sample::Sample| {
            c.fetch_add(1, Ordering::Relaxed);
        }
    };
    let _sub = session
        .declare_subscriber(key.to_owned())
        .callback(counter(&samples))
        .wait()
        .unwrap();
    let _tokens = session
        .liveliness()
        .declare_subscriber(key.to_owned())
        .history(true)
        .callback(counter(&tokens))
        .wait()
        .unwrap();
    let (stop_tx, stop) = mpsc::channel();
    std::thread::spawn(move || {
        let _ = std::io::stdin().lock().lines().next();
        let _ = stop_tx.send(());
    });
    while stop.recv_timeout(Duration::from_millis(500)).is_err() {
        let replies = replies.clone();
        let _ = session
            .get(key.to_owned())
            .callback(move |reply| {
                if reply.result().is_ok() {
                    replies.fetch_add(1, Ordering::Relaxed);
                }
            })
            .wait();
    }
    let read = |c: &Arc<AtomicU64>| c.load(Ordering::Relaxed);
    println!(
        "samples={} replies={} tokens={}",
        read(&samples),
        read(&replies),
        read(&tokens)
    );
}

fn put(session: &zenoh::Session, key: &str, frame: Vec<u8>, count: u64) {
    let robots = session
        .liveliness()
        .declare_subscriber("sonar/*/bridge/robot")
        .history(true)
        .wait()
        .unwrap();
    let publisher = session
        .declare_publisher(key.to_owned())
        .congestion_control(CongestionControl::Block)
        .wait()
        .unwrap();
    // Wait (at most 15 s) for the robot's token and for a subscriber of KEY (the robot's), so
    // that the frames are sent to it rather than nowhere.
    let deadline = Instant::now() + Duration::from_secs(15);
    let (mut seen, mut matched) = (false, false);
    while Instant::now() < deadline && !(seen && matched) {
        seen |= matches!(robots.recv_timeout(Duration::from_millis(50)), Ok(Some(_)));
        matched |= publisher
            .matching_status()
            .wait()
            .is_ok_and(|m| m.matching());
    }
    println!("{}", if seen { "robot seen" } else { "robot not seen" });
    println!("{}", if matched { "matched" } else { "not matched" });
    for _ in 0..count {
        publisher.put(frame.clone()).wait().unwrap();
    }
    println!("sent {count}");
}
