//! Scenes: the walls and posts around the sensor, loaded from TOML or JSON, plus the built-in scenes
//! after the paper's Figs. 8–11.
//!
//! Without a `[robot]` the sensor stands at the origin and its 0° axis is +x; angles grow
//! counter-clockwise. A file:
//!
//! ```toml
//! name = "obstacle"                      # optional, default: the file stem
//! description = "..."                    # optional
//! scan = { mode = "local", from_deg = -45, to_deg = 45 }   # optional: the scan this scene is for
//!
//! [[segments]]                           # a wall, metres
//! from = [2.0, -1.5]
//! to = [2.0, 1.5]
//! surface = "hard"                       # optional: "hard" (default), "soft", "board" (thin) or "rough"
//!
//! [[polygons]]                           # a closed chain of walls (a room, a box)
//! points = [[1.2, 1.2], [-1.2, 1.2], [-1.2, -1.2], [1.2, -1.2]]
//!
//! [[circles]]                            # a post or cylinder
//! centre = [1.0, 0.0]
//! radius = 0.025
//!
//! profile = "srf05"                     # optional: a sensor profile (crate::profile) whose
//!                                        # echo and noise the [echo] and [noise] below amend
//! [echo]                                 # optional: any field of EchoParams
//! threshold_db = -15.0
//! [noise]                                # optional: any field of NoiseParams
//! spurious_probability = 0.0
//!
//! [robot]                                # optional: the head rides a robot along a path
//! waypoints = [[-0.6, -0.6], [0.6, -0.6], [0.6, 0.6]]   # metres, at least 2; starts at the
//!                                        # first, heading towards the second
//! speed_mps = 0.2                        # optional, default 0.2
//! turn_rate_dps = 45                     # optional, default 45: turns in place at a waypoint
//! mode = "scan-while-driving"            # default; or "stop-and-scan": stop at the start and
//!                                        # at each waypoint for one full sweep of the head
//! loop = false                           # optional: back to the first waypoint, round again
//!
//! [odometry]                             # optional, needs [robot]: errors of the reported pose
//! scale_error = 0.03                     # distance reported 3 % long
//! heading_drift_deg_per_m = 0.5          # heading error per metre driven, CCW positive
//! noise_m = 0.001                        # white noise per step (pose sample), metres
//! noise_deg = 0.05                       # and degrees
//! ```
//!
//! With a `[robot]`, angle 0 of the head points along the robot's heading and each ping is taken
//! from the pose of its own instant (see [`crate::robot`]). The path must not cross a wall or
//! run through a post.
//!
//! Corners and edges are not written in the file: they are found from the geometry. Wall ends that
//! coincide (within 1 mm), or lie on another wall, are joined; at each joint the sensor looks into one
//! wedge of free space between two walls, whose opening angle tells a concave corner (a room corner
//! seen from inside, a retro-reflector) from a convex edge (a box corner seen from outside) or a
//! straight joint. A wall end joined to nothing is an edge. Which wedge that is depends on where
//! the sensor stands ([`Joint::seen_from`]): where one wall ends on another, the sensor sees a
//! straight joint from one side and a corner from the other.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::echo_params::{EchoParams, NoiseParams};
use crate::geometry::{Vec2, distance_to_segment, segments_intersect};
use crate::profile::SensorProfile;
use crate::robot::{OdometryParams, RobotSpec};

/// Ends closer than this are one joint; shorter walls are rejected as degenerate.
pub const JOIN_TOLERANCE_M: f64 = 1e-3;

/// What a surface is made of, which sets how much of the incident sound it returns.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Surface {
    /// Plaster, wood, glass, cardboard, metal: acoustically hard, smooth at 40 kHz (the reference).
    #[default]
    Hard,
    /// Curtains, foam, upholstery: absorb part of the sound ([`EchoParams::soft_loss_db`]).
    Soft,
    /// A thin board (a shelf, a skirting, a panel lower than the beam is tall): hard but a small
    /// target ([`EchoParams::board_loss_db`]), and its ends return nothing: edge-on it is silent.
    Board,
    /// Brick, stone, a full bookshelf, a radiator, ribbed panels: hard but rough at 40 kHz (its
    /// relief deeper than half the 8.6 mm wavelength), so it scatters as well as mirrors: every
    /// part of it in the beam sends some sound back, however it is met
    /// ([`EchoParams::rough_diffuse_db`]), and its mirror echo is weaker
    /// ([`EchoParams::rough_specular_loss_db`]).
    Rough,
}

/// A flat wall between two points.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Wall {
    pub a: Vec2,
    pub b: Vec2,
    pub surface: Surface,
}

/// A vertical cylinder (post, pipe, table leg).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Post {
    pub centre: Vec2,
    pub radius: f64,
    pub surface: Surface,
}

/// A wall end or a meeting of walls, as seen from the sensor.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Vertex {
    pub at: Vec2,
    /// Opening of the wedge of free space the sensor looks into here, degrees: below 180 a concave
    /// corner, 180 a straight joint, above 180 a convex edge (360 at a free wall end).
    pub opening_deg: f64,
    /// Surfaces of the two walls bounding that wedge (the same wall twice at a free end).
    pub surfaces: [Surface; 2],
}

/// The scan a scene was made for (a hint to whoever starts the driver; the device obeys commands).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(tag = "mode", rename_all = "lowercase", deny_unknown_fields)]
pub enum SuggestedScan {
    Full,
    Local { from_deg: f64, to_deg: f64 },
}

/// Why a scene could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    #[error("cannot read scene file {path}: {source}")]
    Read {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("scene file {0} must end in .toml or .json")]
    Extension(PathBuf),
    #[error("unknown scene {0:?}: neither a built-in scene ({names}) nor a file", names = BUILTIN_NAMES.join(", "))]
    Unknown(String),
    #[error("invalid scene {origin}: {message}")]
    Invalid { origin: String, message: String },
}

/// A wall end or meeting of walls with the walls leaving it: a [`Vertex`] once the sensor's
/// position picks the wedge it looks into.
#[derive(Debug, Clone, PartialEq)]
pub struct Joint {
    pub at: Vec2,
    /// Direction (degrees) and surface of each wall leaving the joint.
    arms: Vec<(f64, Surface)>,
}

/// Scene files shipped with the crate, compiled in so `--scene room` needs no files at run time.
const BUILTIN: [(&str, &str); 6] = [
    ("room", include_str!("../scenes/room.toml")),
    ("corner", include_str!("../scenes/corner.toml")),
    ("obstacle", include_str!("../scenes/obstacle.toml")),
    (
        "two-obstacles",
        include_str!("../scenes/two-obstacles.toml"),
    ),
    ("room-tour", include_str!("../scenes/room-tour.toml")),
    ("corridor", include_str!("../scenes/corridor.toml")),
];

/// Names of the built-in scenes.
pub const BUILTIN_NAMES: [&str; 6] = [
    "room",
    "corner",
    "obstacle",
    "two-obstacles",
    "room-tour",
    "corridor",
];

/// A validated scene: geometry plus the echo and noise parameters to simulate it with.
#[derive(Debug, Clone)]
pub struct Scene {
    pub name: String,
    pub description: String,
    pub scan: Option<SuggestedScan>,
    /// The sensor this scene is heard through, if it names one (its echo and noise are then the
    /// profile's, amended by the file's `[echo]` and `[noise]`).
    pub profile: Option<SensorProfile>,
    pub echo: EchoParams,
    pub noise: NoiseParams,
    /// The robot carrying the head; `None`: the head stands at the origin.
    pub robot: Option<RobotSpec>,
    /// Errors of the robot's odometry (all 0 by default).
    pub odometry: OdometryParams,
    walls: Vec<Wall>,
    posts: Vec<Post>,
    joints: Vec<Joint>,
    vertices: Vec<Vertex>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SceneFile {
    name: Option<String>,
    #[serde(default)]
    description: String,
    scan: Option<SuggestedScan>,
    #[serde(default)]
    segments: Vec<SegmentSpec>,
    #[serde(default)]
    polygons: Vec<PolygonSpec>,
    #[serde(default)]
    circles: Vec<CircleSpec>,
    profile: Option<SensorProfile>,
    #[serde(default)]
    echo: EchoParams,
    #[serde(default)]
    noise: NoiseParams,
    robot: Option<RobotSpec>,
    odometry: Option<OdometryParams>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct SegmentSpec {
    from: Vec2,
    to: Vec2,
    #[serde(default)]
    surface: Surface,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct PolygonSpec {
    points: Vec<Vec2>,
    #[serde(default)]
    surface: Surface,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct CircleSpec {
    centre: Vec2,
    radius: f64,
    #[serde(default)]
    surface: Surface,
}

impl Scene {
    /// A scene from walls and posts around a head fixed at the origin, with default echo and noise
    /// parameters.
    pub fn new(name: &str, walls: Vec<Wall>, posts: Vec<Post>) -> Result<Self, SceneError> {
        Self::build(name, walls, posts, None)
    }

    /// As [`Scene::new`], with the head on `robot` (validated here), whose path must stay clear
    /// of the walls and posts.
    fn build(
        name: &str,
        walls: Vec<Wall>,
        posts: Vec<Post>,
        robot: Option<RobotSpec>,
    ) -> Result<Self, SceneError> {
        let invalid = |message: String| SceneError::Invalid {
            origin: name.to_owned(),
            message,
        };
        for (i, w) in walls.iter().enumerate() {
            if !(w.a.is_finite() && w.b.is_finite()) {
                return Err(invalid(format!(
                    "wall {}: coordinate is not a finite number",
                    i + 1
                )));
            }
            if (w.b - w.a).norm() < JOIN_TOLERANCE_M {
                return Err(invalid(format!(
                    "wall {}: zero length (from {:?} to {:?})",
                    i + 1,
                    <[f64; 2]>::from(w.a),
                    <[f64; 2]>::from(w.b)
                )));
            }
        }
        for (i, p) in posts.iter().enumerate() {
            if !p.centre.is_finite() || !p.radius.is_finite() || p.radius <= 0.0 {
                return Err(invalid(format!(
                    "circle {}: needs a finite centre and a radius > 0, got radius {}",
                    i + 1,
                    p.radius
                )));
            }
            if robot.is_none() && p.centre.norm() <= p.radius {
                return Err(invalid(format!(
                    "circle {}: the sensor at the origin lies inside it",
                    i + 1
                )));
            }
        }
        if let Some(robot) = &robot {
            robot.validate().map_err(&invalid)?;
            for (k, (from, to)) in robot.legs().enumerate() {
                let n = robot.waypoints.len();
                let leg = format!(
                    "robot: the path from waypoint {} to {}",
                    k + 1,
                    (k + 1) % n + 1
                );
                if let Some(i) = walls
                    .iter()
                    .position(|w| segments_intersect(from, to, w.a, w.b))
                {
                    return Err(invalid(format!("{leg} crosses wall {}", i + 1)));
                }
                if let Some(i) = posts
                    .iter()
                    .position(|p| distance_to_segment(from, to, p.centre) <= p.radius)
                {
                    return Err(invalid(format!("{leg} runs through circle {}", i + 1)));
                }
            }
        }
        let joints = find_joints(&walls);
        let origin = Vec2::default();
        let vertices = joints.iter().filter_map(|j| j.seen_from(origin)).collect();
        Ok(Self {
            name: name.to_owned(),
            description: String::new(),
            scan: None,
            profile: None,
            echo: EchoParams::default(),
            noise: NoiseParams::default(),
            robot,
            odometry: OdometryParams::default(),
            walls,
            posts,
            joints,
            vertices,
        })
    }

    /// A built-in scene ([`BUILTIN_NAMES`]) or else a `.toml`/`.json` file.
    pub fn resolve(name_or_path: &str) -> Result<Self, SceneError> {
        match BUILTIN.iter().find(|(name, _)| *name == name_or_path) {
            Some((name, text)) => Self::from_toml_str(text, name),
            None if Path::new(name_or_path).exists() => Self::load(Path::new(name_or_path)),
            None => Err(SceneError::Unknown(name_or_path.to_owned())),
        }
    }

    /// A built-in scene by name.
    pub fn builtin(name: &str) -> Result<Self, SceneError> {
        let (name, text) = BUILTIN
            .iter()
            .find(|(n, _)| *n == name)
            .ok_or_else(|| SceneError::Unknown(name.to_owned()))?;
        Self::from_toml_str(text, name)
    }

    /// Loads a scene file, TOML or JSON by its extension.
    pub fn load(path: &Path) -> Result<Self, SceneError> {
        let text = std::fs::read_to_string(path).map_err(|source| SceneError::Read {
            path: path.to_owned(),
            source,
        })?;
        let stem = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        let origin = path.display().to_string();
        let file: SceneFile = match path.extension().and_then(|e| e.to_str()) {
            Some("toml") => toml_file(&text).map_err(|e| parse_error(&origin, e))?,
            Some("json") => json_file(&text).map_err(|e| parse_error(&origin, e))?,
            _ => return Err(SceneError::Extension(path.to_owned())),
        };
        Self::from_file(file, &stem, &origin)
    }

    /// Parses TOML text; `default_name` names the scene if the text does not.
    pub fn from_toml_str(text: &str, default_name: &str) -> Result<Self, SceneError> {
        let file = toml_file(text).map_err(|e| parse_error(default_name, e))?;
        Self::from_file(file, default_name, default_name)
    }

    /// Parses JSON text; `default_name` names the scene if the text does not.
    pub fn from_json_str(text: &str, default_name: &str) -> Result<Self, SceneError> {
        let file = json_file(text).map_err(|e| parse_error(default_name, e))?;
        Self::from_file(file, default_name, default_name)
    }

    fn from_file(file: SceneFile, default_name: &str, origin: &str) -> Result<Self, SceneError> {
        let invalid = |message: String| SceneError::Invalid {
            origin: origin.to_owned(),
            message,
        };
        let mut walls: Vec<Wall> = file
            .segments
            .iter()
            .map(|s| Wall {
                a: s.from,
                b: s.to,
                surface: s.surface,
            })
            .collect();
        for (i, p) in file.polygons.iter().enumerate() {
            if p.points.len() < 3 {
                return Err(invalid(format!(
                    "polygon {}: needs at least 3 points, got {}",
                    i + 1,
                    p.points.len()
                )));
            }
            let n = p.points.len();
            walls.extend((0..n).map(|k| Wall {
                a: p.points[k],
                b: p.points[(k + 1) % n],
                surface: p.surface,
            }));
        }
        let posts = file
            .circles
            .iter()
            .map(|c| Post {
                centre: c.centre,
                radius: c.radius,
                surface: c.surface,
            })
            .collect();
        file.echo.validate().map_err(&invalid)?;
        file.noise.validate().map_err(&invalid)?;
        if let Some(SuggestedScan::Local { from_deg, to_deg }) = file.scan
            && !(-180.0 <= from_deg && from_deg < to_deg && to_deg <= 180.0)
        {
            return Err(invalid(format!(
                "scan: need -180 <= from_deg < to_deg <= 180, got {from_deg}..{to_deg}"
            )));
        }
        if file.robot.is_none() && file.odometry.is_some() {
            return Err(invalid(
                "[odometry] needs a [robot]: a head fixed at the origin has none".into(),
            ));
        }
        let odometry = file.odometry.unwrap_or_default();
        odometry.validate().map_err(&invalid)?;
        let name = file.name.unwrap_or_else(|| default_name.to_owned());
        let mut scene = Self::build(&name, walls, posts, file.robot).map_err(|e| match e {
            SceneError::Invalid { message, .. } => invalid(message),
            other => other,
        })?;
        scene.description = file.description;
        scene.scan = file.scan;
        scene.profile = file.profile;
        scene.echo = file.echo;
        scene.noise = file.noise;
        scene.odometry = odometry;
        Ok(scene)
    }

    /// Hears the scene through `profile`: its echo and noise replace the scene's.
    pub fn set_profile(&mut self, profile: SensorProfile) {
        self.profile = Some(profile);
        self.echo = profile.echo();
        self.noise = profile.noise();
    }

    /// Every wall, polygon sides included: the ground truth of flat surfaces.
    pub fn walls(&self) -> &[Wall] {
        &self.walls
    }

    /// Every post: the ground truth of round obstacles.
    pub fn posts(&self) -> &[Post] {
        &self.posts
    }

    /// Wall ends and joints as seen from a sensor at the origin (corners and edges): the ground
    /// truth of a fixed head.
    pub fn vertices(&self) -> &[Vertex] {
        &self.vertices
    }

    /// Every wall end and joint, to be seen from wherever the sensor stands.
    pub fn joints(&self) -> &[Joint] {
        &self.joints
    }

    /// Distance from `p` to the nearest surface, metres (0 inside a post, which is solid): rasterise
    /// the truth by marking the cells whose centre lies within half a cell of a surface.
    pub fn distance_to_surface(&self, p: Vec2) -> f64 {
        distance_to_surfaces(&self.walls, &self.posts, p)
    }

    /// This scene with each wall's surface as `surface` says (given the wall as it is), every
    /// other part of it, the robot's tour included, kept.
    pub fn with_surfaces(
        &self,
        mut surface: impl FnMut(&Wall) -> Surface,
    ) -> Result<Scene, SceneError> {
        let walls = self
            .walls
            .iter()
            .map(|w| Wall {
                surface: surface(w),
                ..*w
            })
            .collect();
        let rebuilt = Scene::new(&self.name, walls, self.posts.clone())?;
        Ok(Scene {
            walls: rebuilt.walls,
            joints: rebuilt.joints,
            vertices: rebuilt.vertices,
            ..self.clone()
        })
    }

    /// This scene with every wall and post moved by `map` (a rigid motion: turned about the
    /// sensor, or into another frame), named `name`; description, suggested scan, profile, echo
    /// and noise kept. A robot's tour is not moved with it and is dropped.
    pub fn moved(&self, name: &str, map: impl Fn(Vec2) -> Vec2) -> Result<Scene, SceneError> {
        let walls = self
            .walls
            .iter()
            .map(|w| Wall {
                a: map(w.a),
                b: map(w.b),
                ..*w
            })
            .collect();
        let posts = self
            .posts
            .iter()
            .map(|p| Post {
                centre: map(p.centre),
                ..*p
            })
            .collect();
        let mut out = Scene::new(name, walls, posts)?;
        out.description = self.description.clone();
        out.scan = self.scan;
        out.profile = self.profile;
        out.echo = self.echo;
        out.noise = self.noise;
        Ok(out)
    }
}

/// A TOML scene file. With a `profile`, the profile's echo and noise fill what the file's
/// `[echo]` and `[noise]` leave out (read a second time, as a table, only then).
fn toml_file(text: &str) -> Result<SceneFile, String> {
    let file: SceneFile = toml::from_str(text).map_err(|e| e.to_string())?;
    let Some(profile) = file.profile else {
        return Ok(file);
    };
    let mut table: toml::Table = toml::from_str(text).map_err(|e| e.to_string())?;
    for (section, defaults) in [
        ("echo", toml::Table::try_from(profile.echo())),
        ("noise", toml::Table::try_from(profile.noise())),
    ] {
        let defaults = defaults.map_err(|e| e.to_string())?;
        if let Some(t) = table
            .entry(section)
            .or_insert_with(|| toml::Table::new().into())
            .as_table_mut()
        {
            for (k, v) in defaults {
                t.entry(k).or_insert(v);
            }
        }
    }
    table.try_into().map_err(|e: toml::de::Error| e.to_string())
}

/// A JSON scene file, as [`toml_file`].
fn json_file(text: &str) -> Result<SceneFile, String> {
    let file: SceneFile = serde_json::from_str(text).map_err(|e| e.to_string())?;
    let Some(profile) = file.profile else {
        return Ok(file);
    };
    let mut value: serde_json::Value = serde_json::from_str(text).map_err(|e| e.to_string())?;
    for (section, defaults) in [
        ("echo", serde_json::to_value(profile.echo())),
        ("noise", serde_json::to_value(profile.noise())),
    ] {
        let serde_json::Value::Object(defaults) = defaults.map_err(|e| e.to_string())? else {
            continue;
        };
        if let Some(t) = value
            .as_object_mut()
            .map(|o| o.entry(section).or_insert_with(|| serde_json::json!({})))
            .and_then(|v| v.as_object_mut())
        {
            for (k, v) in defaults {
                t.entry(k).or_insert(v);
            }
        }
    }
    serde_json::from_value(value).map_err(|e| e.to_string())
}

fn parse_error(origin: &str, e: impl std::fmt::Display) -> SceneError {
    SceneError::Invalid {
        origin: origin.to_owned(),
        message: e.to_string().trim_end().to_owned(),
    }
}

/// Finds every wall end and joint and the walls leaving it.
fn find_joints(walls: &[Wall]) -> Vec<Joint> {
    let near = |p: Vec2, q: Vec2| (p - q).norm() < JOIN_TOLERANCE_M;
    let mut points: Vec<Vec2> = Vec::new();
    for p in walls.iter().flat_map(|w| [w.a, w.b]) {
        if !points.iter().any(|&q| near(p, q)) {
            points.push(p);
        }
    }
    points
        .into_iter()
        .map(|p| {
            // The walls leaving p ("arms"): from a wall end, towards the other end; through a wall's
            // interior (a T-junction), both ways.
            let mut arms: Vec<(f64, Surface)> = Vec::new();
            for w in walls {
                let (at_a, at_b) = (near(w.a, p), near(w.b, p));
                if at_a || (!at_b && distance_to_segment(w.a, w.b, p) < JOIN_TOLERANCE_M) {
                    arms.push(((w.b - p).angle_deg(), w.surface));
                }
                if at_b || (!at_a && distance_to_segment(w.a, w.b, p) < JOIN_TOLERANCE_M) {
                    arms.push(((w.a - p).angle_deg(), w.surface));
                }
            }
            Joint { at: p, arms }
        })
        .collect()
}

impl Joint {
    /// The joint as a sensor at `sensor` sees it: the wedge of free space it looks into; `None`
    /// when the sensor stands on it.
    pub fn seen_from(&self, sensor: Vec2) -> Option<Vertex> {
        let p = self.at;
        if (p - sensor).norm() < JOIN_TOLERANCE_M {
            return None;
        }
        // The wedge containing the direction to the sensor is bounded by the nearest arm on
        // each side of it.
        let to_sensor = (sensor - p).angle_deg();
        let gap = |from: f64, to: f64| {
            let g = (to - from).rem_euclid(360.0);
            if g == 0.0 { 360.0 } else { g }
        };
        let nearest = |ccw: bool| {
            self.arms
                .iter()
                .map(|&(deg, s)| {
                    let g = if ccw {
                        gap(to_sensor, deg)
                    } else {
                        gap(deg, to_sensor)
                    };
                    (g, s)
                })
                .fold(
                    (360.0, Surface::Hard),
                    |best, x| {
                        if x.0 < best.0 { x } else { best }
                    },
                )
        };
        let (ccw_gap, ccw_surface) = nearest(true);
        let (cw_gap, cw_surface) = nearest(false);
        Some(Vertex {
            at: p,
            opening_deg: (ccw_gap + cw_gap).min(360.0),
            surfaces: [cw_surface, ccw_surface],
        })
    }
}

/// Distance from `p` to the nearest of `walls` and `posts`, metres (0 inside a post, which is solid).
pub fn distance_to_surfaces(walls: &[Wall], posts: &[Post], p: Vec2) -> f64 {
    let walls = walls.iter().map(|w| distance_to_segment(w.a, w.b, p));
    let posts = posts
        .iter()
        .map(|c| ((p - c.centre).norm() - c.radius).max(0.0));
    walls.chain(posts).fold(f64::INFINITY, f64::min)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::Mode;

    #[test]
    fn builtin_scenes_load_and_match_the_paper() {
        for name in BUILTIN_NAMES {
            let scene = Scene::resolve(name).unwrap();
            assert_eq!(scene.name, name);
            assert!(!scene.description.is_empty());
            assert!(scene.scan.is_some());
        }
        let room = Scene::builtin("room").unwrap();
        assert_eq!(room.walls().len(), 4);
        assert_eq!(room.scan, Some(SuggestedScan::Full));
        // Four concave 90° corners seen from inside, 1.70 m away.
        assert_eq!(room.vertices().len(), 4);
        for v in room.vertices() {
            assert!((v.opening_deg - 90.0).abs() < 1e-9, "{v:?}");
            assert!((v.at.norm() - 1.2 * 2f64.sqrt()).abs() < 1e-9);
        }
        let obstacle = Scene::builtin("obstacle").unwrap();
        assert_eq!(obstacle.posts().len(), 1);
        assert!((obstacle.distance_to_surface(Vec2::default()) - 0.975).abs() < 1e-9);
        let two = Scene::builtin("two-obstacles").unwrap();
        assert_eq!(two.posts().len(), 2);
        assert!(matches!(two.scan, Some(SuggestedScan::Local { .. })));
    }

    #[test]
    fn corners_and_edges_are_found_from_the_geometry() {
        let corner = Scene::builtin("corner").unwrap();
        let mut openings: Vec<f64> = corner.vertices().iter().map(|v| v.opening_deg).collect();
        openings.sort_by(f64::total_cmp);
        // The joint ahead is a concave 90° corner; the two far wall ends are free edges.
        assert!((openings[0] - 90.0).abs() < 1e-9, "{openings:?}");
        assert_eq!(&openings[1..], &[360.0, 360.0]);

        // A box seen from outside: its near vertices are convex edges (270° of free space).
        let text = "[[polygons]]\npoints = [[1, -0.2], [1.4, -0.2], [1.4, 0.2], [1, 0.2]]\n";
        let boxed = Scene::from_toml_str(text, "box").unwrap();
        let near: Vec<&Vertex> = boxed.vertices().iter().filter(|v| v.at.x < 1.2).collect();
        assert_eq!(near.len(), 2);
        for v in near {
            assert!((v.opening_deg - 270.0).abs() < 1e-9, "{v:?}");
        }

        // A T-junction: a wall ending on another wall makes two 90° corners, one of them facing us.
        let text = "[[segments]]\nfrom = [1, -1]\nto = [1, 1]\n[[segments]]\nfrom = [1, 0.3]\nto = [0.5, 0.3]\n";
        let t = Scene::from_toml_str(text, "tee").unwrap();
        let joint = t
            .vertices()
            .iter()
            .find(|v| (v.at - Vec2::new(1.0, 0.3)).norm() < 1e-9)
            .unwrap();
        assert!((joint.opening_deg - 90.0).abs() < 1e-9, "{joint:?}");
    }

    #[test]
    fn with_surfaces_changes_the_walls_and_their_joints_and_keeps_the_rest() {
        let tour = Scene::builtin("room-tour").unwrap();
        assert!(tour.robot.is_some());
        let rough = tour.with_surfaces(|_| Surface::Rough).unwrap();
        assert!(rough.walls().iter().all(|w| w.surface == Surface::Rough));
        assert_eq!(rough.walls().len(), tour.walls().len());
        assert_eq!(rough.robot, tour.robot);
        assert_eq!(
            (rough.name.as_str(), rough.scan),
            (tour.name.as_str(), tour.scan)
        );
        let seen = |s: &Scene| {
            s.joints()
                .iter()
                .filter_map(|j| j.seen_from(Vec2::new(0.0, 0.0)))
                .flat_map(|v| v.surfaces)
                .collect::<Vec<_>>()
        };
        assert!(!seen(&rough).is_empty());
        assert!(seen(&rough).iter().all(|&s| s == Surface::Rough));
    }

    #[test]
    fn json_and_toml_describe_the_same_scene() {
        let json = r#"{"name": "j", "scan": {"mode": "local", "from_deg": -30, "to_deg": 30},
            "segments": [{"from": [2, -1], "to": [2, 1], "surface": "soft"}],
            "circles": [{"centre": [1, 0], "radius": 0.025}],
            "echo": {"threshold_db": -20}, "noise": {"spurious_probability": 0}}"#;
        let scene = Scene::from_json_str(json, "x").unwrap();
        assert_eq!(scene.name, "j");
        assert_eq!(scene.walls()[0].surface, Surface::Soft);
        assert_eq!(scene.echo.threshold_db, -20.0);
        assert_eq!(scene.echo.frequency_hz, EchoParams::default().frequency_hz);
        assert_eq!(scene.profile, None);
        // A profile fills what the file's [echo] and [noise] leave out, in both formats.
        let toml_text = "profile = \"hc-sr04\"\n[echo]\nthreshold_db = -20\n";
        let json_text = r#"{"profile": "hc-sr04", "echo": {"threshold_db": -20}}"#;
        for profiled in [
            Scene::from_toml_str(toml_text, "p").unwrap(),
            Scene::from_json_str(json_text, "p").unwrap(),
        ] {
            let scene = profiled;
            assert_eq!(scene.profile, Some(SensorProfile::HcSr04));
            assert_eq!(scene.echo.threshold_db, -20.0);
            let profile = SensorProfile::HcSr04.echo();
            assert_eq!(
                scene.echo.beam_6db_half_angle_deg,
                profile.beam_6db_half_angle_deg
            );
            assert_eq!(scene.noise, SensorProfile::HcSr04.noise());
        }
        let bad = Scene::from_toml_str("profile = \"srf04\"\n", "p").unwrap_err();
        assert!(bad.to_string().contains("unknown variant `srf04`"), "{bad}");
        assert_eq!(
            scene.scan,
            Some(SuggestedScan::Local {
                from_deg: -30.0,
                to_deg: 30.0
            })
        );

        let dir = std::env::temp_dir().join(format!("sonar-sim-scene-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("mine.json");
        std::fs::write(&path, json).unwrap();
        assert_eq!(
            Scene::resolve(path.to_str().unwrap())
                .unwrap()
                .posts()
                .len(),
            1
        );
        let txt = dir.join("mine.txt");
        std::fs::write(&txt, json).unwrap();
        assert!(matches!(Scene::load(&txt), Err(SceneError::Extension(_))));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn robot_scenes_load_with_their_tours() {
        let tour = Scene::builtin("room-tour").unwrap();
        let robot = tour.robot.as_ref().unwrap();
        assert_eq!(robot.waypoints.len(), 4);
        assert!(robot.looped);
        assert_eq!(robot.mode, Mode::ScanWhileDriving);
        assert!(tour.odometry.scale_error > 0.0);
        let corridor = Scene::builtin("corridor").unwrap();
        assert_eq!(corridor.robot.as_ref().unwrap().mode, Mode::StopAndScan);
        // Where the rooms' partition meets the corridor wall: a straight joint from the corridor,
        // a 90° corner from inside a room.
        let tee = corridor
            .joints()
            .iter()
            .find(|j| (j.at - Vec2::new(3.0, 0.6)).norm() < 1e-9)
            .unwrap();
        let from_corridor = tee.seen_from(Vec2::new(1.5, 0.0)).unwrap();
        let from_room = tee.seen_from(Vec2::new(1.5, 2.1)).unwrap();
        assert!((from_corridor.opening_deg - 180.0).abs() < 1e-9);
        assert!((from_room.opening_deg - 90.0).abs() < 1e-9);
        // No robot: the head at the origin, nothing to report.
        assert!(Scene::builtin("room").unwrap().robot.is_none());
    }

    fn error_of(toml_text: &str) -> String {
        match Scene::from_toml_str(toml_text, "bad") {
            Ok(_) => panic!("accepted: {toml_text}"),
            Err(e) => e.to_string(),
        }
    }

    #[test]
    fn bad_files_are_clear_errors() {
        let cases = [
            ("wall = 1\n", "unknown field `wall`"),
            (
                "[[segments]]\nfrom = [0, 1]\nto = [1, 1]\ncolour = \"red\"\n",
                "unknown field `colour`",
            ),
            ("[echo]\nthreshold = 3\n", "unknown field `threshold`"),
            (
                "[[segments]]\nfrom = [1, 1]\nto = [1, 1]\n",
                "wall 1: zero length",
            ),
            (
                "[[circles]]\ncentre = [1, 0]\nradius = -0.1\n",
                "circle 1: needs a finite centre and a radius > 0",
            ),
            (
                "[[circles]]\ncentre = [0.1, 0]\nradius = 0.2\n",
                "lies inside it",
            ),
            (
                "[[polygons]]\npoints = [[1, 0], [1, 1]]\n",
                "polygon 1: needs at least 3 points, got 2",
            ),
            (
                "[[segments]]\nfrom = [nan, 1]\nto = [1, 1]\n",
                "not a finite number",
            ),
            (
                "[[segments]]\nfrom = [1]\nto = [1, 1]\n",
                "invalid length 1",
            ),
            ("[echo]\nthreshold_db = nan\n", "threshold_db"),
            (
                "[noise]\nspurious_probability = 2\n",
                "spurious_probability",
            ),
            (
                "scan = { mode = \"sideways\" }\n",
                "unknown variant `sideways`",
            ),
            (
                "scan = { mode = \"local\", from_deg = 30, to_deg = -30 }\n",
                "scan: need",
            ),
            ("[robot]\nwaypoints = [[0, 0]]\n", "need at least 2"),
            (
                "[robot]\nwaypoints = [[0, 0], [1, 0]]\nspeed_mps = -1\n",
                "robot.speed_mps must be a number > 0, got -1",
            ),
            (
                "[robot]\nwaypoints = [[0, 0], [1, 0]]\nturn_rate_dps = 0\n",
                "robot.turn_rate_dps must be a number > 0",
            ),
            (
                "[robot]\nwaypoints = [[0, 0], [inf, 0]]\n",
                "robot.waypoints[2]: coordinate is not a finite number",
            ),
            (
                "[robot]\nwaypoints = [[0, 0], [1, 0]]\nmode = \"teleport\"\n",
                "unknown variant `teleport`",
            ),
            (
                "[robot]\nwaypoints = [[0, 0], [1, 0]]\nspeed = 1\n",
                "unknown field `speed`",
            ),
            (
                "[[segments]]\nfrom = [2, -1]\nto = [2, 1]\n[robot]\nwaypoints = [[0, 0], [1, 0], [3, 0]]\n",
                "robot: the path from waypoint 2 to 3 crosses wall 1",
            ),
            (
                "[[circles]]\ncentre = [1, 1]\nradius = 0.1\n[robot]\nwaypoints = [[0, 0], [2, 0], [2, 2]]\nloop = true\n",
                "robot: the path from waypoint 3 to 1 runs through circle 1",
            ),
            (
                "[odometry]\nscale_error = 0.1\n",
                "[odometry] needs a [robot]",
            ),
            (
                "[robot]\nwaypoints = [[0, 0], [1, 0]]\n[odometry]\nnoise_deg = -1\n",
                "odometry.noise_deg must be >= 0",
            ),
        ];
        for (text, expected) in cases {
            let err = error_of(text);
            assert!(err.contains(expected), "{text:?} gave {err:?}");
            assert!(err.starts_with("invalid scene bad: "), "{err}");
        }
        assert!(
            Scene::resolve("no-such-scene")
                .unwrap_err()
                .to_string()
                .contains("neither a built-in scene (room, corner")
        );
    }
}
