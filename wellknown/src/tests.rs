use foxglove::Decode;
use foxglove::messages::{Color, FrameTransform, Grid, LaserScan, SceneUpdate};
use sonar_common::ipc::{
    CELL_UNKNOWN, FeatureRecord, FeaturesHeader, GridHeader, LocalizedPose, Pose2D, Reading,
    SlamCorrection, feature_flags, feature_kind, flags, slam_state,
};

use super::*;

const SECOND: u64 = 1_000_000_000;

fn options(ros2: bool) -> Options {
    Options {
        ros2,
        grid_period_ns: 2 * SECOND,
    }
}

fn header(stamp_ns: u64) -> GridHeader {
    GridHeader {
        seq: stamp_ns,
        stamp_ns,
        width: 3,
        height: 2,
        resolution_m: 0.05,
        origin_x_m: -0.1,
        origin_y_m: -0.05,
        pose_x_m: 0.5,
        pose_y_m: 0.25,
        pose_theta_rad: 0.3,
        ..GridHeader::default()
    }
}

const CELLS: [u8; 6] = [0, 127, 254, CELL_UNKNOWN, 1, 253];

fn channels(out: &[Output]) -> Vec<Channel> {
    out.iter().map(|o| o.channel).collect()
}

#[test]
fn occupancy_is_percent_rounded_half_up_and_unknown_is_minus_one() {
    assert_eq!(occupancy(0), 0);
    assert_eq!(occupancy(127), 50);
    assert_eq!(occupancy(254), 100);
    assert_eq!(occupancy(CELL_UNKNOWN), -1);
    // 1.27 → 1 (p = 1/254 = 0.39 %), 3.5 → 4 (7/254 = 2.76 %)
    assert_eq!(occupancy(3), 1);
    assert_eq!(occupancy(7), 3);
    for c in 0..=254u8 {
        let exact = f64::from(c) * 100.0 / 254.0;
        assert!((f64::from(occupancy(c)) - exact).abs() <= 0.5, "{c}");
    }
}

#[test]
fn the_grid_keeps_size_origin_rows_and_values_of_the_snapshot() {
    let grid =
        Grid::decode(&foxglove_msgs::encode(&foxglove_msgs::grid(&header(7), &CELLS))[..]).unwrap();
    assert_eq!(grid.frame_id, MAP_FRAME);
    assert_eq!(grid.column_count, 3);
    assert_eq!(grid.cell_stride, 5);
    assert_eq!(grid.row_stride, 15);
    assert_eq!(grid.data.len(), 30, "two rows");
    let cell = grid.cell_size.unwrap();
    assert_eq!((cell.x, cell.y), (f64::from(0.05f32), f64::from(0.05f32)));
    let origin = grid.pose.unwrap().position.unwrap();
    assert_eq!(
        (origin.x, origin.y),
        (f64::from(-0.1f32), f64::from(-0.05f32))
    );
    let values: Vec<i8> = grid.data.chunks(5).map(|c| c[0] as i8).collect();
    assert_eq!(values, CELLS.map(occupancy));
    // Free white, occupied black, unknown transparent.
    assert_eq!(&grid.data[1..5], &[255, 255, 255, 255]);
    assert_eq!(&grid.data[11..15], &[0, 0, 0, 255]);
    assert_eq!(&grid.data[16..20], &[0, 0, 0, 0]);
    let names: Vec<&str> = grid.fields.iter().map(|f| f.name.as_str()).collect();
    assert_eq!(names, ["occupancy", "red", "green", "blue", "alpha"]);
}

#[test]
fn a_kept_back_map_is_flushed_on_request_once() {
    let mut w = WellKnown::new(options(true));
    assert!(w.flush_map().is_empty(), "nothing kept back yet");
    assert!(!w.grid(&header(10 * SECOND), &CELLS).is_empty());
    assert!(w.grid(&header(10 * SECOND + 7), &CELLS).is_empty());
    let flushed = w.flush_map();
    assert!(flushed.iter().any(|o| o.channel == Channel::Ros2Map));
    assert!(flushed.iter().all(|o| o.stamp_ns == 10 * SECOND + 7));
    assert!(w.flush_map().is_empty(), "given once");
    assert!(w.finish().is_empty(), "nor again at the end");
}

#[test]
fn maps_come_at_most_once_a_period_and_the_last_one_at_the_end() {
    let mut w = WellKnown::new(options(false));
    // A fixed head: each map brings the sensor's transform from the snapshot.
    assert_eq!(
        channels(&w.grid(&header(10 * SECOND), &CELLS)),
        [
            Channel::FoxgloveMap,
            Channel::FoxgloveTransform,
            Channel::FoxgloveTransform
        ]
    );
    assert!(w.grid(&header(11 * SECOND), &CELLS).is_empty());
    assert!(w.grid(&header(11 * SECOND + 5), &CELLS).is_empty());
    let out = w.grid(&header(12 * SECOND), &CELLS);
    assert_eq!(out[0].stamp_ns, 12 * SECOND);
    assert!(w.grid(&header(13 * SECOND), &CELLS).is_empty());
    let end = w.finish();
    assert_eq!(end[0].channel, Channel::FoxgloveMap);
    assert_eq!(end[0].stamp_ns, 13 * SECOND, "the newest kept snapshot");
    assert!(w.finish().is_empty(), "given once");
    assert!(
        w.grid(&header(20 * SECOND), &CELLS[1..]).is_empty(),
        "cells missing"
    );
}

#[test]
fn with_a_pose_source_transforms_follow_it_at_most_twenty_a_second() {
    let mut w = WellKnown::new(options(true));
    let pose = |stamp_ns| Pose2D {
        stamp_ns,
        x_m: 1.0,
        y_m: -2.0,
        theta_rad: std::f32::consts::FRAC_PI_2,
        layout_version: 1,
    };
    let out = w.pose(&pose(SECOND));
    assert_eq!(
        channels(&out),
        [
            Channel::FoxgloveTransform,
            Channel::FoxgloveTransform,
            Channel::Ros2Transform
        ]
    );
    let t = FrameTransform::decode(&out[1].data[..]).unwrap();
    assert_eq!(
        (t.parent_frame_id.as_str(), t.child_frame_id.as_str()),
        ("odom", "sonar")
    );
    let q = t.rotation.unwrap();
    assert!((q.z - 0.5f64.sqrt()).abs() < 1e-6 && (q.w - 0.5f64.sqrt()).abs() < 1e-6);
    assert_eq!(t.translation.unwrap().y, -2.0);
    assert!(w.pose(&pose(SECOND + 49_000_000)).is_empty());
    assert_eq!(w.pose(&pose(SECOND + 50_000_000)).len(), 3);
    // A beam comes after the latest transform again, on Foxglove's channel only (tf2 warns of a
    // repeated stamp on ROS 2's), so a client that connected since gets it first.
    let beam = w.reading(&Reading {
        host_stamp_ns: SECOND + 70_000_000,
        distance_m: 1.0,
        ..Reading::default()
    });
    assert_eq!(
        channels(&beam),
        [
            Channel::FoxgloveTransform,
            Channel::FoxgloveTransform,
            Channel::FoxgloveBeam
        ]
    );
    assert!(
        beam[..2].iter().all(|o| o.stamp_ns == SECOND + 50_000_000),
        "the pose's own stamp"
    );
    // The map no longer brings a transform of its own.
    assert_eq!(
        channels(&w.grid(&header(2 * SECOND), &CELLS)),
        [Channel::FoxgloveMap, Channel::Ros2Map]
    );
}

#[test]
fn a_sweep_becomes_a_scan_when_the_next_begins_and_the_last_at_the_end() {
    let mut w = WellKnown::new(options(false));
    let reading = |sweep_id, angle_deg| Reading {
        sweep_id,
        angle_deg,
        distance_m: 1.0,
        host_stamp_ns: 5,
        ..Reading::default()
    };
    // The first reading's beam, after the sensor's transform (a fixed head before its first
    // map: at the origin); the others come within the beam period (the same stamp).
    let first = w.reading(&reading(1, 0.0));
    assert_eq!(
        channels(&first),
        [
            Channel::FoxgloveTransform,
            Channel::FoxgloveTransform,
            Channel::FoxgloveBeam
        ]
    );
    let t = FrameTransform::decode(&first[1].data[..]).unwrap();
    assert_eq!(
        (t.parent_frame_id.as_str(), t.child_frame_id.as_str()),
        ("odom", "sonar")
    );
    assert_eq!(t.translation.unwrap().x, 0.0);
    assert!(w.reading(&reading(1, 6.0)).is_empty());
    // A scan, too, comes after the sensor's transforms: a live client that connected since gets
    // them first.
    let out = w.reading(&reading(2, 6.0));
    assert_eq!(
        channels(&out),
        [
            Channel::FoxgloveTransform,
            Channel::FoxgloveTransform,
            Channel::FoxgloveScan
        ]
    );
    let scan = LaserScan::decode(&out[2].data[..]).unwrap();
    assert_eq!(scan.frame_id, SENSOR_FRAME);
    assert_eq!(scan.ranges, [f64::from(1.0f32); 2]);
    assert!((scan.end_angle - 6f64.to_radians()).abs() < 1e-9);
    assert_eq!(channels(&w.finish()), [Channel::FoxgloveScan]);
}

#[test]
fn features_become_lines_cubes_and_spheres() {
    let record = |kind, x| FeatureRecord {
        kind,
        x_m: x,
        segment_ax_m: f32::NAN,
        segment_ay_m: f32::NAN,
        segment_bx_m: f32::NAN,
        segment_by_m: f32::NAN,
        flags: feature_flags::CONFIRMED,
        ..FeatureRecord::default()
    };
    let mut wall = record(feature_kind::PLANE, 1.0);
    (
        wall.segment_ax_m,
        wall.segment_ay_m,
        wall.segment_bx_m,
        wall.segment_by_m,
    ) = (1.0, -1.0, 1.0, 1.0);
    // Heard from one place only: drawn translucent.
    let tentative = |r: FeatureRecord| FeatureRecord { flags: 0, ..r };
    let records = [
        wall,
        record(feature_kind::CORNER, 2.0),
        record(feature_kind::POINT, 3.0),
        record(feature_kind::PLANE, 4.0), // without extent: not drawn
        tentative(FeatureRecord { x_m: 5.0, ..wall }),
        tentative(record(feature_kind::POINT, 6.0)),
    ];
    let mut w = WellKnown::new(options(false));
    let out = w.features(&FeaturesHeader::default(), &records);
    let scene = SceneUpdate::decode(&out[0].data[..]).unwrap();
    let entity = &scene.entities[0];
    assert_eq!(entity.id, "features");
    assert_eq!(
        entity.lines.len(),
        2,
        "confirmed walls, then tentative ones"
    );
    let alpha = |c: Option<Color>| c.unwrap().a;
    for (line, a) in entity.lines.iter().zip([1.0, 0.35]) {
        assert_eq!(line.points.len(), 2);
        assert_eq!(alpha(line.color), a);
    }
    assert_eq!(entity.cubes.len(), 1);
    assert_eq!(alpha(entity.cubes[0].color), 1.0);
    assert_eq!(entity.spheres.len(), 2);
    assert_eq!(entity.spheres[0].pose.unwrap().position.unwrap().x, 3.0);
    assert_eq!(alpha(entity.spheres[0].color), 1.0);
    assert_eq!(alpha(entity.spheres[1].color), 0.35);
}

#[test]
fn channel_specs_carry_foxglove_s_protobuf_schemas_and_ros2_definitions() {
    let grid = Channel::FoxgloveMap.spec();
    assert_eq!(grid.schema_name, "foxglove.Grid");
    assert_eq!(grid.schema_encoding, "protobuf");
    assert_eq!(grid.message_encoding, "protobuf");
    assert!(!grid.schema.is_empty());
    let map = Channel::Ros2Map.spec();
    assert_eq!(map.schema_name, "nav_msgs/msg/OccupancyGrid");
    assert_eq!(
        (map.schema_encoding.as_str(), map.message_encoding.as_str()),
        ("ros2msg", "cdr")
    );
    assert_eq!(WellKnown::new(options(false)).channels(), Channel::FOXGLOVE);
    assert_eq!(WellKnown::new(options(true)).channels().len(), 8);
}

#[test]
fn a_reading_s_beam_is_a_cone_to_its_range_at_most_ten_a_second() {
    let mut w = WellKnown::new(options(false));
    let reading = |stamp_ms: u64, flags| Reading {
        angle_deg: 90.0,
        beam_half_angle_deg: 15.0,
        distance_m: 1.5,
        max_range_m: 4.0,
        flags,
        host_stamp_ns: stamp_ms * 1_000_000,
        ..Reading::default()
    };
    let beams = |out: Vec<Output>| -> Vec<SceneUpdate> {
        out.iter()
            .filter(|o| o.channel == Channel::FoxgloveBeam)
            .map(|o| SceneUpdate::decode(&o.data[..]).unwrap())
            .collect()
    };
    let first = beams(w.reading(&reading(1000, 0)));
    assert_eq!(first.len(), 1);
    let entity = &first[0].entities[0];
    assert_eq!(
        (entity.id.as_str(), entity.frame_id.as_str()),
        ("beam", SENSOR_FRAME)
    );
    let outline = &entity.lines[0].points;
    assert_eq!(outline.len(), foxglove_msgs::BEAM_ARC_POINTS + 2);
    assert_eq!((outline[0].x, outline[0].y), (0.0, 0.0), "from the sensor");
    let arc = &outline[1..outline.len() - 1];
    for p in arc {
        assert!(
            (p.x.hypot(p.y) - 1.5).abs() < 1e-6,
            "at the echo's range: {p:?}"
        );
    }
    let bearing = |p: &foxglove::messages::Point3| p.y.atan2(p.x).to_degrees();
    assert!((bearing(&arc[0]) - 75.0).abs() < 1e-6);
    assert!((bearing(&arc[arc.len() - 1]) - 105.0).abs() < 1e-6);
    assert_eq!(
        entity.triangles[0].points.len(),
        3 * (foxglove_msgs::BEAM_ARC_POINTS - 1),
        "a fan of triangles fills it"
    );

    assert!(
        beams(w.reading(&reading(1099, 0))).is_empty(),
        "within 100 ms"
    );
    let silent = beams(w.reading(&reading(1100, flags::NO_ECHO)));
    let p = silent[0].entities[0].lines[0].points[1];
    assert!(
        (p.x.hypot(p.y) - 4.0).abs() < 1e-6,
        "no echo: to the maximum range"
    );
}

/// The (parent, child, x, y, θ) of a FrameTransform.
fn decoded(data: &[u8]) -> (String, String, f64, f64, f64) {
    let t = FrameTransform::decode(data).unwrap();
    let p = t.translation.unwrap();
    let q = t.rotation.unwrap();
    (
        t.parent_frame_id,
        t.child_frame_id,
        p.x,
        p.y,
        2.0 * q.z.atan2(q.w),
    )
}

#[test]
fn the_tree_is_map_odom_sonar_and_map_odom_is_the_latest_correction() {
    let mut w = WellKnown::new(options(true));
    let pose = |stamp_ns| Pose2D {
        stamp_ns,
        x_m: 2.0,
        y_m: 1.0,
        theta_rad: 0.5,
        layout_version: 1,
    };
    // Identity until a correction is known.
    let out = w.pose(&pose(SECOND));
    let (parent, child, x, y, theta) = decoded(&out[0].data);
    assert_eq!((parent.as_str(), child.as_str()), ("map", "odom"));
    assert_eq!((x, y, theta), (0.0, 0.0, 0.0));
    assert_eq!(out[0].stamp_ns, SECOND, "at the sensor's stamp");

    // A SLAM estimate sets it; a revision of an earlier sweep does not.
    w.slam_correction(&SlamCorrection {
        stamp_ns: SECOND,
        state: slam_state::FIX,
        correction_x_m: 0.25,
        correction_y_m: -0.5,
        correction_theta_rad: 0.1,
        ..SlamCorrection::default()
    });
    w.slam_correction(&SlamCorrection {
        stamp_ns: SECOND / 2,
        state: slam_state::REVISED,
        correction_x_m: 9.0,
        ..SlamCorrection::default()
    });
    let out = w.pose(&pose(2 * SECOND));
    let (parent, child, x, y, theta) = decoded(&out[0].data);
    assert_eq!((parent.as_str(), child.as_str()), ("map", "odom"));
    assert!((x - 0.25).abs() < 1e-6 && (y + 0.5).abs() < 1e-6 && (theta - 0.1).abs() < 1e-6);
    let (parent, child, x, ..) = decoded(&out[1].data);
    assert_eq!((parent.as_str(), child.as_str(), x), ("odom", "sonar", 2.0));
    assert!(out[..2].iter().all(|o| o.stamp_ns == 2 * SECOND));
    // ROS 2: both in one TFMessage, map → odom first.
    assert_eq!(out[2].channel, Channel::Ros2Transform);
    assert_eq!(
        out[2].data,
        ros2::tf_message(&[
            Transform::correction(
                2 * SECOND,
                Correction {
                    x: f64::from(0.25f32),
                    y: f64::from(-0.5f32),
                    theta: f64::from(0.1f32),
                }
            ),
            Transform::sensor(2 * SECOND, 2.0, 1.0, 0.5),
        ])
    );

    // A correction that is not a number is left out.
    w.correction(3 * SECOND, f64::NAN, 0.0, 0.0);
    let out = w.pose(&pose(3 * SECOND));
    let (_, _, x, ..) = decoded(&out[0].data);
    assert!((x - 0.25).abs() < 1e-6);

    // The fusion's localised pose: the correction carries its odometry pose onto it.
    let localized = LocalizedPose {
        stamp_ns: 3 * SECOND,
        x_m: 1.5,
        y_m: 2.5,
        theta_rad: 0.8,
        odometry_x_m: 2.0,
        odometry_y_m: 1.0,
        odometry_theta_rad: 0.5,
        ..LocalizedPose::default()
    };
    w.localized_pose(&localized);
    let out = w.pose(&pose(4 * SECOND));
    let (_, _, x, y, theta) = decoded(&out[0].data);
    let c = Correction { x, y, theta };
    let (px, py) = c.apply(2.0, 1.0);
    assert!(
        (px - 1.5).abs() < 1e-5 && (py - 2.5).abs() < 1e-5,
        "{px} {py}"
    );
    assert!((theta - 0.3).abs() < 1e-5);
}

#[test]
fn a_fixed_head_keeps_the_grid_pose_below_an_identity_map_to_odom() {
    let mut w = WellKnown::new(options(false));
    let out = w.grid(&header(SECOND), &CELLS);
    let (parent, child, x, y, theta) = decoded(&out[1].data);
    assert_eq!((parent.as_str(), child.as_str()), ("map", "odom"));
    assert_eq!((x, y, theta), (0.0, 0.0, 0.0));
    let (parent, child, x, y, _) = decoded(&out[2].data);
    assert_eq!((parent.as_str(), child.as_str()), ("odom", "sonar"));
    assert_eq!((x, y), (f64::from(0.5f32), f64::from(0.25f32)));
}

#[test]
fn a_correction_between_two_poses_carries_one_onto_the_other() {
    let c = Correction::between((1.0, -2.0, 2.5), (-0.5, 3.0, -1.0));
    let (x, y) = c.apply(-0.5, 3.0);
    assert!((x - 1.0).abs() < 1e-12 && (y + 2.0).abs() < 1e-12);
    assert!((c.theta - 3.5).abs() < 1e-12);
    assert_eq!(
        Correction::between((1.0, 2.0, 0.3), (1.0, 2.0, 0.3)).apply(4.0, 5.0),
        (4.0, 5.0)
    );
}

#[test]
fn a_beam_repeats_the_transforms_as_they_were_given_out_and_a_fixed_head_is_not_corrected() {
    let mut w = WellKnown::new(options(false));
    w.pose(&Pose2D {
        stamp_ns: SECOND,
        x_m: 1.0,
        layout_version: 1,
        ..Pose2D::default()
    });
    // A correction after the pose: the beam's repeat keeps the pair of the pose's stamp.
    w.correction(SECOND, 0.5, 0.0, 0.0);
    let beam = w.reading(&Reading {
        host_stamp_ns: SECOND + 1,
        distance_m: 1.0,
        ..Reading::default()
    });
    let (parent, _, x, ..) = decoded(&beam[0].data);
    assert_eq!((parent.as_str(), x), ("map", 0.0));

    // A fixed head's pose is the fusion's, already in the map: no correction below it.
    let mut fixed = WellKnown::new(options(false));
    fixed.correction(SECOND, 0.5, 0.0, 0.0);
    let out = fixed.grid(&header(SECOND), &CELLS);
    let (parent, _, x, ..) = decoded(&out[1].data);
    assert_eq!((parent.as_str(), x), ("map", 0.0));
}
