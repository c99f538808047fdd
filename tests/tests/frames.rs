//! End to end: the frames `map → odom → sonar` that `sonar-record` writes for Foxglove, and
//! `sonar-export --slam-correction` writes from that recording, keep a drifting robot's scans on
//! the walls (issue 25).
#![allow(clippy::unwrap_used, clippy::expect_used)] // a panic is a failure

use std::collections::BTreeMap;

use foxglove::Decode;
use foxglove::messages::{FrameTransform, LaserScan};
use nalgebra::{Isometry2, Point2, Vector2};
use sonar_common::ipc::{self, LocalizedPose, Pose2D, SlamCorrection, slam_state};
use sonar_e2e::{
    Sandbox, TruePoses, check_ok, collect_with_truth, drive_drifting_corridor, path_str,
    readings_subscribers, slam_correction_subscriber, true_pose_subscriber, wait_until,
};
use sonar_sim::{Scene, Vec2};
use sonar_wellknown::live::Ports;
use sonar_wellknown::{Channel, Options, Output, WellKnown};

/// An echo placed with the true pose within this of a wall is one the wall answered on the beam's
/// axis (the others came from off the axis, anywhere in the cone): those are scored.
const ON_WALL_M: f64 = 0.03;

/// Non-revised corrections (one a sweep) to wait for: the tour into both rooms and back, as the
/// SLAM test drives it.
const SWEEPS: usize = 20;

fn stamp_ns(t: &foxglove::messages::Timestamp) -> u64 {
    u64::from(t.sec()) * 1_000_000_000 + u64::from(t.nsec())
}

/// The planar transform a FrameTransform carries.
fn isometry(t: &FrameTransform) -> Isometry2<f64> {
    let p = t.translation.as_ref().unwrap();
    let q = t.rotation.as_ref().unwrap();
    Isometry2::new(Vector2::new(p.x, p.y), 2.0 * q.z.atan2(q.w))
}

/// An edge's transforms: (stamp, transform), in stamp order.
type Edge = Vec<(u64, Isometry2<f64>)>;

/// Each (parent, child) edge's transforms; the one in force at a stamp is the latest at or before
/// it.
#[derive(Debug, Default)]
struct Tree(BTreeMap<(String, String), Edge>);

impl Tree {
    fn insert(&mut self, t: &FrameTransform) {
        let edge = (t.parent_frame_id.clone(), t.child_frame_id.clone());
        let stamp = stamp_ns(t.timestamp.as_ref().unwrap());
        let list = self.0.entry(edge).or_default();
        list.push((stamp, isometry(t)));
        list.sort_by_key(|(s, _)| *s);
    }

    fn at(&self, parent: &str, child: &str, stamp: u64) -> Option<Isometry2<f64>> {
        let list = self.0.get(&(parent.to_owned(), child.to_owned()))?;
        list.iter()
            .take_while(|(s, _)| *s <= stamp)
            .last()
            .map(|(_, t)| *t)
    }
}

fn median(values: &mut [f64]) -> f64 {
    values.sort_by(f64::total_cmp);
    values.get(values.len() / 2).copied().unwrap_or(f64::NAN)
}

/// The corridor tour with drifting odometry (3 % long, 2°/m), `sonar-slam` correcting it and
/// `sonar-record` writing the Foxglove channels. Decoded from the file: every scan's echoes placed
/// in `map` through `map → odom → sonar` at the scan's stamp, as Foxglove draws them, lie on the
/// scene's true walls; through `odom → sonar` alone (the tree before issue 25, the raw odometry)
/// they do not. An echo is drawn on the beam's axis while the wall that answered may lie anywhere
/// in its 55° cone, so only the echoes that the simulator's true pose (`robot/true_pose`) places
/// within 3 cm of a wall are scored: the ones a perfect tree draws on the walls. (Seen in three
/// runs: 232–233 of 831–832 echoes scored, median 3.9, 3.1 and 3.9 cm through the tree, 14.8 cm
/// through the odometry alone; 6 or 7 fixes in 20 sweeps.) The recording exported with
/// `sonar-export --mcap --slam-correction` is scored alike: its frames come from the recorded
/// corrections.
#[test]
fn the_recorded_frames_keep_a_drifting_robot_s_scans_on_the_walls() {
    let sandbox = Sandbox::new("frames");
    let node = sandbox.node("test-consumer");
    let truth = true_pose_subscriber(&node);
    let corrections = slam_correction_subscriber(&node);
    let file = sandbox.root.join("tour.mcap");
    let slam = sandbox.spawn("sonar-slam", &[]);
    let recorder = sandbox.spawn("sonar-record", &[path_str(&file)]);
    wait_until(
        &node,
        "the readings subscribers of sonar-slam and sonar-record",
        || readings_subscribers(&node) >= 2,
    );
    let (sim, driver) = drive_drifting_corridor(&sandbox);
    let (sweeps, true_poses) = collect_with_truth(
        &node,
        &truth,
        || loop {
            let c = *corrections.receive().unwrap()?.payload();
            if c.state != ipc::slam_state::REVISED {
                return Some(c);
            }
        },
        SWEEPS,
    );
    assert!(driver.terminate().success(), "driver did not exit cleanly");
    assert!(
        recorder.terminate().success(),
        "sonar-record did not exit cleanly"
    );
    assert!(
        slam.terminate().success(),
        "sonar-slam did not exit cleanly"
    );
    assert!(sim.terminate().success(), "simulator did not exit cleanly");
    let fixes = sweeps.iter().filter(|c| c.is_fix()).count();

    // The recording as sonar-record wrote it, and its export with the recorded corrections.
    let recorded = Scored::of(&std::fs::read(&file).unwrap(), &true_poses);
    let stem = sandbox.root.join("exported");
    let out = sandbox.run(
        "sonar-export",
        &[
            "--mcap",
            "--from-recording",
            path_str(&file),
            "--slam-correction",
            "--out",
            path_str(&stem),
        ],
    );
    check_ok("sonar-export --slam-correction", &out);
    let exported = Scored::of(
        &std::fs::read(stem.with_extension("mcap")).unwrap(),
        &true_poses,
    );
    eprintln!(
        "{} sweeps ({fixes} fixes); the echoes on a wall by the truth, their median distance to \
         the true walls:\n  recorded: {recorded}\n  exported with --slam-correction: {exported}",
        sweeps.len(),
    );
    assert!(fixes >= 4, "only {fixes} of {} sweeps fixed", sweeps.len());
    for (what, s) in [("recorded", &recorded), ("exported", &exported)] {
        assert!(s.scored >= 100, "{what}: only {} echoes scored", s.scored);
        assert!(
            s.placed_scans >= SWEEPS / 2,
            "{what}: {} scans placed",
            s.placed_scans
        );
        assert!(
            s.corrected < 0.06,
            "{what}: the corrected frames put the echoes {} m off the walls",
            s.corrected
        );
        assert!(
            s.odometry > 2.0 * s.corrected && s.odometry > 0.08,
            "{what}: the odometry alone kept the echoes {} m off the walls: nothing was corrected",
            s.odometry
        );
    }
}

/// A file's scans placed in `map` as Foxglove draws them, scored against the corridor's walls.
struct Scored {
    scans: usize,
    placed_scans: usize,
    echoes: usize,
    /// Echoes that the true pose puts within [`ON_WALL_M`] of a wall.
    scored: usize,
    /// Their median distance to the true walls through `map → odom → sonar`, and through
    /// `odom → sonar` alone.
    corrected: f64,
    odometry: f64,
    /// The largest of the scans' own medians through the tree (scans with 5 scored echoes or
    /// more).
    worst_scan: f64,
}

impl Scored {
    fn of(bytes: &[u8], true_poses: &TruePoses) -> Self {
        let mut tree = Tree::default();
        let mut scans = Vec::new();
        for message in mcap::MessageStream::new(bytes).unwrap() {
            let message = message.unwrap();
            match message.channel.topic.as_str() {
                "/foxglove/tf" => tree.insert(&FrameTransform::decode(&message.data[..]).unwrap()),
                "/foxglove/scan" => scans.push(LaserScan::decode(&message.data[..]).unwrap()),
                _ => {}
            }
        }
        let edges: Vec<_> = tree.0.keys().cloned().collect();
        assert_eq!(
            edges,
            [
                ("map".to_owned(), "odom".to_owned()),
                ("odom".to_owned(), "sonar".to_owned())
            ],
            "the frames written"
        );

        let scene = Scene::builtin("corridor").unwrap();
        let off_wall = |p: Point2<f64>| scene.distance_to_surface(Vec2::new(p.x, p.y));
        let (mut corrected, mut odometry) = (Vec::new(), Vec::new());
        let mut echoes = 0;
        let mut worst_scan = 0.0f64;
        let mut placed_scans = 0;
        for scan in &scans {
            assert_eq!(scan.frame_id, "sonar");
            let stamp = stamp_ns(scan.timestamp.as_ref().unwrap());
            let (Some(map_odom), Some(odom_sonar)) = (
                tree.at("map", "odom", stamp),
                tree.at("odom", "sonar", stamp),
            ) else {
                continue;
            };
            let Some(true_pose) = true_poses.at(stamp).map(|t| t.cast::<f64>()) else {
                continue;
            };
            placed_scans += 1;
            let mut this_scan = Vec::new();
            let n = scan.ranges.len();
            let step = if n > 1 {
                (scan.end_angle - scan.start_angle) / (n - 1) as f64
            } else {
                0.0
            };
            for (i, &range) in scan.ranges.iter().enumerate() {
                if !range.is_finite() {
                    continue;
                }
                let bearing = scan.start_angle + i as f64 * step;
                let p = Point2::new(range * bearing.cos(), range * bearing.sin());
                echoes += 1;
                if off_wall(true_pose * p) <= ON_WALL_M {
                    this_scan.push(off_wall(map_odom * odom_sonar * p));
                    odometry.push(off_wall(odom_sonar * p));
                }
            }
            if this_scan.len() >= 5 {
                worst_scan = worst_scan.max(median(&mut this_scan));
            }
            corrected.extend(this_scan);
        }
        Self {
            scans: scans.len(),
            placed_scans,
            echoes,
            scored: corrected.len(),
            corrected: median(&mut corrected),
            odometry: median(&mut odometry),
            worst_scan,
        }
    }
}

impl std::fmt::Display for Scored {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} of {} scans placed, {} of {} echoes scored; map → odom → sonar {:.3} m (the worst \
             scan's median {:.3} m), odom → sonar alone {:.3} m",
            self.placed_scans,
            self.scans,
            self.scored,
            self.echoes,
            self.corrected,
            self.worst_scan,
            self.odometry
        )
    }
}

/// The `map → odom` of the first Foxglove transform among `out`, as (x, θ).
fn map_to_odom(out: &[Output]) -> (f64, f64) {
    let t = out
        .iter()
        .find(|o| o.channel == Channel::FoxgloveTransform)
        .map(|o| FrameTransform::decode(&o.data[..]).unwrap())
        .expect("a transform");
    assert_eq!(
        (t.parent_frame_id.as_str(), t.child_frame_id.as_str()),
        ("map", "odom")
    );
    let i = isometry(&t);
    (i.translation.x, i.rotation.angle())
}

/// The ports the live servers (`sonar-foxglove`, `sonar-bridge --mode ros2`) read take the
/// corrections from `sonar/slam_correction` (a revision left out) and `sonar/localized_pose` over
/// shared memory, and the pose's transforms carry the latest above `odom`, on ROS 2's `/tf` in the
/// same message.
#[test]
fn the_live_ports_put_the_latest_correction_above_the_odometry() {
    let sandbox = Sandbox::new("frames_live");
    let node = sandbox.node("test-live");
    let ports = Ports::open(&node).unwrap();
    let slam = ipc::slam_correction_service(&node)
        .unwrap()
        .publisher_builder()
        .create()
        .unwrap();
    let localized = ipc::localized_pose_service(&node)
        .unwrap()
        .publisher_builder()
        .create()
        .unwrap();
    let pose = ipc::pose_service(&node)
        .unwrap()
        .publisher_builder()
        .create()
        .unwrap();
    let mut converter = WellKnown::new(Options {
        ros2: true,
        grid_period_ns: 1,
    });
    let pose_at = |stamp_ns| Pose2D {
        stamp_ns,
        x_m: 1.0,
        layout_version: ipc::LAYOUT_VERSION,
        ..Pose2D::default()
    };

    slam.send_copy(SlamCorrection {
        stamp_ns: 500_000_000,
        state: slam_state::FIX,
        correction_x_m: 0.4,
        correction_theta_rad: 0.2,
        ..SlamCorrection::default()
    })
    .unwrap();
    slam.send_copy(SlamCorrection {
        stamp_ns: 400_000_000,
        state: slam_state::REVISED,
        correction_x_m: 9.0,
        ..SlamCorrection::default()
    })
    .unwrap();
    pose.send_copy(pose_at(1_000_000_000)).unwrap();
    let out = ports.drain(&mut converter);
    let (x, theta) = map_to_odom(&out);
    assert!(
        (x - 0.4).abs() < 1e-6 && (theta - 0.2).abs() < 1e-6,
        "{x} {theta}"
    );
    let tf = out
        .iter()
        .find(|o| o.channel == Channel::Ros2Transform)
        .expect("a ROS 2 transform");
    assert_eq!(
        tf.data,
        sonar_wellknown::ros2::tf_message(&[
            sonar_wellknown::Transform::correction(
                1_000_000_000,
                sonar_wellknown::Correction {
                    x: f64::from(0.4f32),
                    y: 0.0,
                    theta: f64::from(0.2f32),
                }
            ),
            sonar_wellknown::Transform::sensor(1_000_000_000, 1.0, 0.0, 0.0),
        ]),
        "map -> odom and odom -> sonar in one TFMessage"
    );

    // The fusion's localisation: localised 1.5 m where its odometry says 1.0 m.
    localized
        .send_copy(LocalizedPose {
            stamp_ns: 1_500_000_000,
            x_m: 1.5,
            odometry_x_m: 1.0,
            layout_version: ipc::LAYOUT_VERSION,
            ..LocalizedPose::default()
        })
        .unwrap();
    pose.send_copy(pose_at(2_000_000_000)).unwrap();
    let (x, theta) = map_to_odom(&ports.drain(&mut converter));
    assert!((x - 0.5).abs() < 1e-6 && theta.abs() < 1e-9, "{x} {theta}");
}
