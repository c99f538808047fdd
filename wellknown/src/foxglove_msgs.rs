//! The pipeline's payloads as Foxglove's well-known messages (`foxglove::messages`, protobuf).

use foxglove::Encode;
use foxglove::messages::{
    Color, CubePrimitive, FrameTransform, Grid, LaserScan, LinePrimitive, PackedElementField,
    Point3, Pose, Quaternion, SceneEntity, SceneUpdate, SpherePrimitive, Timestamp,
    TriangleListPrimitive, Vector2, Vector3, line_primitive, packed_element_field::NumericType,
};
use sonar_common::ipc::{
    FeatureRecord, FeaturesHeader, GridHeader, Reading, decode_probability, feature_kind,
};

use crate::frame::{MAP_FRAME, SENSOR_FRAME, Transform, yaw_quaternion};
use crate::occupancy::occupancy;
use crate::scan::Scan;
use crate::schema::SchemaParts;

/// The schema of a Foxglove message type as its SDK defines it.
pub(crate) fn schema<T: Encode>() -> SchemaParts {
    let (name, encoding, data) = T::get_schema()
        .map(|s| (s.name, s.encoding, s.data.into_owned()))
        .unwrap_or_default();
    (name, encoding, data, T::get_message_encoding())
}

/// Protobuf bytes of a message.
pub fn encode<T: Encode>(message: &T) -> Vec<u8> {
    let mut buf = Vec::with_capacity(message.encoded_len().unwrap_or(64));
    // A Vec grows as needed: encoding into it cannot run out of room.
    if let Err(e) = message.encode(&mut buf) {
        unreachable!("protobuf encoding into a Vec failed: {e}");
    }
    buf
}

/// ns since the Unix epoch as Foxglove's timestamp (saturating in 2106).
pub fn timestamp(stamp_ns: u64) -> Timestamp {
    let sec = u32::try_from(stamp_ns / 1_000_000_000).unwrap_or(u32::MAX);
    Timestamp::new_checked(sec, (stamp_ns % 1_000_000_000) as u32).unwrap_or(Timestamp::MAX)
}

fn planar_pose(x: f64, y: f64, theta: f64) -> Pose {
    let (z, w) = yaw_quaternion(theta);
    Pose {
        position: Some(Vector3 { x, y, z: 0.0 }),
        orientation: Some(Quaternion {
            x: 0.0,
            y: 0.0,
            z,
            w,
        }),
    }
}

/// Bytes per cell of the map: `occupancy` (int8: −1 unknown, 0–100) and `red`, `green`, `blue`,
/// `alpha` (uint8), so Foxglove draws it in colour without settings (its 3D panel picks the RGBA
/// fields by itself): free white, occupied black, grey between, as ROS maps look; never-observed
/// cells transparent.
pub const GRID_CELL_STRIDE: u32 = 5;

/// The grey of a cell (`None`: transparent).
fn cell_grey(cell: u8) -> Option<u8> {
    decode_probability(cell).map(|p| (255.0 * (1.0 - p.clamp(0.0, 1.0))).round() as u8)
}

/// The map as `foxglove.Grid` in frame `map`, row 0 at the lowest y as in the snapshot.
pub fn grid(header: &GridHeader, cells: &[u8]) -> Grid {
    let field = |name: &str, offset: u32, kind: NumericType| PackedElementField {
        name: name.into(),
        offset,
        r#type: kind as i32,
    };
    let mut data = Vec::with_capacity(cells.len() * GRID_CELL_STRIDE as usize);
    for &cell in cells {
        data.push(occupancy(cell) as u8);
        match cell_grey(cell) {
            Some(g) => data.extend([g, g, g, 255]),
            None => data.extend([0, 0, 0, 0]),
        }
    }
    Grid {
        timestamp: Some(timestamp(header.stamp_ns)),
        frame_id: MAP_FRAME.into(),
        pose: Some(planar_pose(
            f64::from(header.origin_x_m),
            f64::from(header.origin_y_m),
            0.0,
        )),
        column_count: header.width,
        cell_size: Some(Vector2 {
            x: f64::from(header.resolution_m),
            y: f64::from(header.resolution_m),
        }),
        row_stride: header.width * GRID_CELL_STRIDE,
        cell_stride: GRID_CELL_STRIDE,
        fields: vec![
            field("occupancy", 0, NumericType::Int8),
            field("red", 1, NumericType::Uint8),
            field("green", 2, NumericType::Uint8),
            field("blue", 3, NumericType::Uint8),
            field("alpha", 4, NumericType::Uint8),
        ],
        data: data.into(),
    }
}

/// A sweep as `foxglove.LaserScan` in frame `sonar`.
pub fn laser_scan(scan: &Scan) -> LaserScan {
    LaserScan {
        timestamp: Some(timestamp(scan.stamp_ns)),
        frame_id: SENSOR_FRAME.into(),
        pose: Some(planar_pose(0.0, 0.0, 0.0)),
        start_angle: scan.start_rad,
        end_angle: scan.end_rad(),
        ranges: scan.ranges.clone(),
        intensities: Vec::new(),
    }
}

/// A transform as `foxglove.FrameTransform`.
pub fn frame_transform(t: &Transform) -> FrameTransform {
    let pose = planar_pose(t.x, t.y, t.theta);
    FrameTransform {
        timestamp: Some(timestamp(t.stamp_ns)),
        parent_frame_id: t.parent.into(),
        child_frame_id: t.child.into(),
        translation: pose.position,
        rotation: pose.orientation,
    }
}

/// A colour without transparency.
const fn opaque(r: f64, g: f64, b: f64) -> Color {
    Color { r, g, b, a: 1.0 }
}

const WALL: Color = opaque(0.95, 0.55, 0.1);
const CORNER: Color = opaque(0.2, 0.8, 0.3);
const POST: Color = opaque(0.2, 0.6, 1.0);
/// Opacity of a feature heard from one place only (tentative: it may be a phantom).
const TENTATIVE_ALPHA: f64 = 0.35;

/// `color` as a feature `r` is drawn: opaque when confirmed, translucent when tentative.
fn feature_color(color: Color, r: &FeatureRecord) -> Color {
    if r.is_confirmed() {
        color
    } else {
        Color {
            a: TENTATIVE_ALPHA,
            ..color
        }
    }
}
/// Edge of a corner's cube and diameter of a post's sphere, metres.
const MARKER_SIZE: f64 = 0.08;
/// Thickness of a wall's line, metres.
const WALL_THICKNESS: f64 = 0.03;

/// Lines of one colour and thickness (metres) in the entity's frame.
fn line(
    kind: line_primitive::Type,
    thickness: f64,
    points: Vec<Point3>,
    color: Color,
) -> LinePrimitive {
    LinePrimitive {
        r#type: kind as i32,
        pose: Some(planar_pose(0.0, 0.0, 0.0)),
        thickness,
        scale_invariant: false,
        points,
        color: Some(color),
        colors: Vec::new(),
        indices: Vec::new(),
    }
}

/// A features snapshot as one `foxglove.SceneUpdate` entity `features` in frame `map` (replacing the
/// previous snapshot's): walls as line segments, corners as cubes, posts as spheres; those heard
/// from one place only (tentative) translucent.
pub fn features(header: &FeaturesHeader, records: &[FeatureRecord]) -> SceneUpdate {
    let size = Some(Vector3 {
        x: MARKER_SIZE,
        y: MARKER_SIZE,
        z: MARKER_SIZE,
    });
    let at = |r: &FeatureRecord| Some(planar_pose(f64::from(r.x_m), f64::from(r.y_m), 0.0));
    let point = |x: f32, y: f32| Point3 {
        x: f64::from(x),
        y: f64::from(y),
        z: 0.0,
    };
    // Confirmed walls, then tentative ones: one line list each (a list has one colour).
    let mut walls = [Vec::new(), Vec::new()];
    let mut cubes = Vec::new();
    let mut spheres = Vec::new();
    for r in records {
        match r.kind {
            feature_kind::PLANE => {
                let ends = [
                    r.segment_ax_m,
                    r.segment_ay_m,
                    r.segment_bx_m,
                    r.segment_by_m,
                ];
                if ends.iter().all(|v| v.is_finite()) {
                    let list = &mut walls[usize::from(!r.is_confirmed())];
                    list.push(point(r.segment_ax_m, r.segment_ay_m));
                    list.push(point(r.segment_bx_m, r.segment_by_m));
                }
            }
            feature_kind::CORNER => cubes.push(CubePrimitive {
                pose: at(r),
                size,
                color: Some(feature_color(CORNER, r)),
            }),
            feature_kind::POINT => spheres.push(SpherePrimitive {
                pose: at(r),
                size,
                color: Some(feature_color(POST, r)),
            }),
            _ => {}
        }
    }
    let tentative_wall = Color {
        a: TENTATIVE_ALPHA,
        ..WALL
    };
    let lines = walls
        .into_iter()
        .zip([WALL, tentative_wall])
        .filter(|(points, _)| !points.is_empty())
        .map(|(points, color)| {
            line(
                line_primitive::Type::LineList,
                WALL_THICKNESS,
                points,
                color,
            )
        })
        .collect();
    SceneUpdate {
        deletions: Vec::new(),
        entities: vec![SceneEntity {
            timestamp: Some(timestamp(header.stamp_ns)),
            frame_id: MAP_FRAME.into(),
            id: "features".into(),
            lines,
            cubes,
            spheres,
            ..SceneEntity::default()
        }],
    }
}

/// A beam that heard an echo: outline, and its inside more transparent.
const BEAM_ECHO: Color = opaque(1.0, 0.8, 0.1);
/// A beam that heard nothing (drawn out to the maximum range).
const BEAM_SILENT: Color = opaque(0.6, 0.6, 0.6);
const BEAM_FILL_ALPHA: f64 = 0.25;
/// Points on a beam's arc, its two edges included.
pub const BEAM_ARC_POINTS: usize = 9;
/// Thickness of a beam's outline, metres.
const BEAM_THICKNESS: f64 = 0.01;

/// A reading's beam as one `foxglove.SceneUpdate` entity `beam` in frame `sonar` (replacing the
/// previous reading's): the cone of `beam_half_angle_deg` either side of its bearing, out to the
/// echo's range (yellow), or to the maximum range when it heard nothing (grey); the outline as a
/// line strip from the sensor along the arc and back, the inside as a translucent fan of triangles.
pub fn beam(reading: &Reading) -> SceneUpdate {
    let echo = reading.is_valid_range();
    let (range, color) = if echo {
        (reading.distance_m, BEAM_ECHO)
    } else {
        (reading.max_range_m, BEAM_SILENT)
    };
    let range = f64::from(range);
    let centre = f64::from(reading.angle_deg).to_radians();
    let half = f64::from(reading.beam_half_angle_deg).to_radians();
    let origin = Point3::default();
    let arc: Vec<Point3> = (0..BEAM_ARC_POINTS)
        .map(|i| {
            let a = centre - half + 2.0 * half * i as f64 / (BEAM_ARC_POINTS - 1) as f64;
            Point3 {
                x: range * a.cos(),
                y: range * a.sin(),
                z: 0.0,
            }
        })
        .collect();
    let outline = std::iter::once(origin)
        .chain(arc.iter().copied())
        .chain(std::iter::once(origin))
        .collect();
    let fan = arc.windows(2).flat_map(|w| [origin, w[0], w[1]]).collect();
    SceneUpdate {
        deletions: Vec::new(),
        entities: vec![SceneEntity {
            timestamp: Some(timestamp(reading.host_stamp_ns)),
            frame_id: SENSOR_FRAME.into(),
            id: "beam".into(),
            lines: vec![line(
                line_primitive::Type::LineStrip,
                BEAM_THICKNESS,
                outline,
                color,
            )],
            triangles: vec![TriangleListPrimitive {
                pose: Some(planar_pose(0.0, 0.0, 0.0)),
                points: fan,
                color: Some(Color {
                    a: BEAM_FILL_ALPHA,
                    ..color
                }),
                colors: Vec::new(),
                indices: Vec::new(),
            }],
            ..SceneEntity::default()
        }],
    }
}
