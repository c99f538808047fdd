//! The feature evaluation: `sonar-features` on the simulated scenes over target bearings, seeds
//! and sweeps, against the scenes' truth, next to the two grid presets on the same runs.
//!
//! Every scene is run **rotated** about the sensor by each bearing of the settings (by default
//! every 0.375° from 0° to 5.625°: four phases of the 1.5° ping grid, sixteen of the 6° reading
//! grid), with each seed; a figure is reported as its median and its worst case over all those
//! runs, never for one favourable bearing. The runs are the pipeline's own (the simulated device,
//! the driver's decoder, [`crate::pipeline::capture`]); the features come from the readings' raw
//! pings through [`FeatureMap::update`], one sweep at a time, the sensor at the origin.
//!
//! Truth: a post's **echo point** (its surface nearest the sensor, where a point feature is
//! placed), the scene's concave vertices (corners) and wall ends (edges, also point targets), and
//! each wall's normal form (bearing and length of the perpendicular from the sensor) when the
//! perpendicular's foot lies on it. A feature **matches** a truth element of its kind within
//! [`MATCH_M`] (planes: [`PLANE_MATCH_DEG`] and [`MATCH_M`]); a feature that matches nothing, or
//! an element already matched, is **false**. A wall or corner is **expected** when the scan's
//! pings reach its bearing (a wall's foot, a corner's vertex) in the line of sight: those are the
//! ones whose errors are reported, and missing one counts.
//!
//! The reported uncertainty is checked by each matched feature's squared Mahalanobis error (2
//! degrees of freedom: position for points and corners; normal angle and distance for planes):
//! honest uncertainties put 68 % of them within 2.30 and 95 % within 5.99.

use anyhow::{Context, Result};
use nalgebra::{Isometry2, Matrix2, Point2, Vector2};
use sonar_common::ipc::Reading;
use sonar_features::{EchoPhysics, FeatureConfig, FeatureKind, FeatureMap, RangeOffset, Sweep};
use sonar_fusion::Preset;
use sonar_sim::{Post, Scene, Vec2, Wall};

use crate::metrics::{apparent_width, gap_between};
use crate::pipeline::{Head, Maps, ProfileChoice, Scan, capture_with, two_posts};
use crate::report::{GAP_DEPTH_M, WIDTH_WINDOW_M};

/// A feature lies on a truth element within this distance.
pub const MATCH_M: f64 = 0.10;
/// A plane matches a wall within this angle (and [`MATCH_M`] in distance).
pub const PLANE_MATCH_DEG: f64 = 5.0;
/// Two posts count as resolved when each has its own point feature within this (the position
/// aim's worst case) and no other point feature lies within [`CROWD_M`] of either.
pub const RESOLVED_M: f64 = 0.05;
/// See [`RESOLVED_M`].
pub const CROWD_M: f64 = 0.25;
/// χ² with 2 degrees of freedom at 68.3 % (the 1σ ellipse) and at 95 %.
pub const CHI2_1SIGMA: f64 = 2.30;
pub const CHI2_95: f64 = 5.99;

/// How the feature evaluation is run.
#[derive(Debug, Clone, PartialEq)]
pub struct FeatureSettings {
    /// Rotations of every scene about the sensor, degrees.
    pub bearings_deg: Vec<f64>,
    pub seeds: Vec<u64>,
    /// Complete sweeps per run.
    pub sweeps: u32,
    /// Centre spacings of the two-post scenes, millimetres.
    pub spacings_mm: Vec<u32>,
    /// Noise levels of the robustness runs ([`evaluate_levels`]).
    pub levels: Vec<NoiseLevel>,
    /// Centre spacings of the two-post scenes in the robustness runs, millimetres.
    pub level_spacings_mm: Vec<u32>,
    /// The simulated sensor every scene is heard through (the paper head and the simulator's
    /// default echoes without one), and the features set for it as its owner would set them.
    pub profile: ProfileChoice,
    /// The sensor's range offset measured as its owner measures it (`--feature-calibrate`,
    /// [`crate::calibration`]), taken off every range the features see; the grids' figures
    /// stay uncalibrated.
    pub calibrated: Option<RangeOffset>,
}

/// `scene` turned by `deg` counter-clockwise about the sensor, everything else kept.
pub fn rotated(scene: &Scene, deg: f64) -> Result<Scene> {
    let (s, c) = deg.to_radians().sin_cos();
    let turn = |p: Vec2| Vec2::new(c * p.x - s * p.y, s * p.x + c * p.y);
    Ok(scene.moved(&format!("{}@{deg}°", scene.name), turn)?)
}

/// `scene` with the sensor standing at `at` (in the scene's frame) instead of its origin.
pub fn shifted(scene: &Scene, at: Vec2) -> Result<Scene> {
    moved(
        scene,
        &format!("{}+({:.2},{:.2})", scene.name, at.x, at.y),
        |p: Vec2| p - at,
    )
}

/// `scene` with every wall end and post centre moved by `turn`, everything else kept.
fn moved(scene: &Scene, name: &str, turn: impl Fn(Vec2) -> Vec2) -> Result<Scene> {
    let walls = scene
        .walls()
        .iter()
        .map(|w| Wall {
            a: turn(w.a),
            b: turn(w.b),
            surface: w.surface,
        })
        .collect();
    let posts = scene
        .posts()
        .iter()
        .map(|p| Post {
            centre: turn(p.centre),
            radius: p.radius,
            surface: p.surface,
        })
        .collect();
    let mut out = Scene::new(name, walls, posts)?;
    out.description = scene.description.clone();
    out.scan = scene.scan;
    out.echo = scene.echo;
    out.noise = scene.noise;
    Ok(out)
}

/// A 1.4 m wall slanted 45° across the view, 1.1–2.1 m away: the foot of the sensor's
/// perpendicular misses it, so no ping returns from it, and its ends are too faint to hear.
/// Nothing should be reported.
pub fn slanted_wall() -> Result<Scene> {
    let wall = Wall {
        a: Vec2::new(1.0, -0.5),
        b: Vec2::new(2.0, 0.5),
        surface: sonar_sim::Surface::Hard,
    };
    let mut scene = Scene::new("slanted-wall", vec![wall], vec![])?;
    scene.description = "a wall slanted 45° across the view, never at normal incidence".into();
    scene.scan = Some(sonar_sim::SuggestedScan::Local {
        from_deg: -45.0,
        to_deg: 45.0,
    });
    Ok(scene)
}

/// An L-shaped room around the sensor (2.8 m × 2.6 m less a 1.2 m × 1.2 m corner): five concave
/// corners, one convex (an edge, a point target), walls 0.6–1.8 m away.
pub fn l_room() -> Result<Scene> {
    let corners = [
        Vec2::new(-1.0, -1.0),
        Vec2::new(1.8, -1.0),
        Vec2::new(1.8, 0.4),
        Vec2::new(0.6, 0.4),
        Vec2::new(0.6, 1.6),
        Vec2::new(-1.0, 1.6),
    ];
    let walls = (0..corners.len())
        .map(|i| Wall {
            a: corners[i],
            b: corners[(i + 1) % corners.len()],
            surface: sonar_sim::Surface::Hard,
        })
        .collect();
    let mut scene = Scene::new("l-room", walls, vec![])?;
    scene.description = "an L-shaped room, five concave corners and a convex one".into();
    scene.scan = Some(sonar_sim::SuggestedScan::Full);
    Ok(scene)
}

/// Where the sensor stands in the square room for the off-centre runs: the nearest wall 0.5 m
/// away, then two others.
pub const OFF_CENTRE: [(f64, f64); 3] = [(0.15, -0.7), (-0.6, 0.45), (0.55, 0.55)];

/// The simulated sensor's noise: Gaussian range noise σ = `sigma_m` + `fraction` × range on top
/// of the simulator's own (the detector's late cycles, rare transients), and a share `dropout` of
/// pings that hear nothing.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NoiseLevel {
    pub sigma_m: f64,
    pub fraction: f64,
    pub dropout: f64,
}

impl NoiseLevel {
    /// The simulator's own noise only.
    pub const NONE: Self = Self {
        sigma_m: 0.0,
        fraction: 0.0,
        dropout: 0.0,
    };

    /// `MM[+PCT%][/DROP%]`: σ in millimetres, the share of the range in percent, the pings lost
    /// in percent (`10+1%/2%`: σ = 1 cm + 1 % of the range, 2 % of the pings lost).
    pub fn parse(s: &str) -> Result<Self, String> {
        let bad = || format!("{s:?}: expected MM[+PCT%][/DROP%], e.g. 3, 10+1% or 10+1%/2%");
        let (noise, drop) = s.trim().split_once('/').unwrap_or((s.trim(), "0%"));
        let (mm, pct) = noise.split_once('+').unwrap_or((noise, "0%"));
        let percent = |v: &str| -> Result<f64, String> {
            v.trim()
                .strip_suffix('%')
                .unwrap_or(v.trim())
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite() && (0.0..100.0).contains(x))
                .map(|x| x / 100.0)
                .ok_or_else(bad)
        };
        let mm: f64 = mm.trim().parse().map_err(|_| bad())?;
        if !(mm.is_finite() && (0.0..=200.0).contains(&mm)) {
            return Err(bad());
        }
        Ok(Self {
            sigma_m: mm / 1000.0,
            fraction: percent(pct)?,
            dropout: percent(drop)?,
        })
    }

    /// As written on the command line and in the tables.
    pub fn label(&self) -> String {
        let mut out = if *self == Self::NONE {
            "simulator's own".to_owned()
        } else {
            format!("σ = {:.0} mm", self.sigma_m * 1000.0)
        };
        if self.fraction > 0.0 {
            out += &format!(" + {:.1} %", self.fraction * 100.0);
        }
        if self.dropout > 0.0 {
            out += &format!(", {:.0} % dropouts", self.dropout * 100.0);
        }
        out
    }

    /// `scene` with this noise: its range noise replaced (a sensor profile's jitter, dropouts and
    /// transients kept), or its own with [`Self::NONE`].
    fn on(&self, scene: &Scene) -> Scene {
        let mut out = scene.clone();
        if *self == Self::NONE {
            return out;
        }
        out.noise.range_sigma_m = self.sigma_m;
        out.noise.range_sigma_fraction = self.fraction;
        out
    }

    /// Loses a share `dropout` of the pings of `readings` (seeded: the same runs lose the same
    /// pings).
    fn drop_pings(&self, readings: &mut [Reading], seed: u64) {
        if self.dropout <= 0.0 {
            return;
        }
        let mut state = seed ^ 0x9e37_79b9_7f4a_7c15;
        for r in readings {
            let n = usize::from(r.ping_count).min(r.echo_us.len());
            for us in &mut r.echo_us[..n] {
                // SplitMix64: uniform in [0, 1) from the top 53 bits.
                state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
                let mut z = state;
                z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
                z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
                z ^= z >> 31;
                let uniform = (z >> 11) as f64 / (1u64 << 53) as f64;
                if uniform < self.dropout {
                    *us = 0;
                }
            }
        }
    }
}

/// The paper's obstacle scene with a post `radius_m` thick instead of 2.5 cm: a 10 cm post is
/// heard over a cone as wide as two 5 cm posts 20 cm apart, which one viewpoint cannot tell
/// apart (see `docs/features.md`).
pub fn thick_post(radius_m: f64) -> Result<Scene> {
    let obstacle = Scene::builtin("obstacle")?;
    let posts = obstacle
        .posts()
        .iter()
        .map(|p| Post {
            radius: radius_m,
            ..*p
        })
        .collect();
    let name = format!("post-{:.0}cm", 200.0 * radius_m);
    let mut scene = Scene::new(&name, obstacle.walls().to_vec(), posts)?;
    scene.scan = obstacle.scan;
    Ok(scene)
}

/// The feature maps of one capture: after its first sweep and after all.
#[derive(Debug)]
pub struct FeatureMaps {
    pub first: FeatureMap,
    pub all: FeatureMap,
}

/// Runs `readings` (several sweeps, in order) through the feature pipeline set up with `cfg`,
/// one sweep at a time.
pub fn feature_maps(readings: &[Reading], cfg: FeatureConfig) -> Result<FeatureMaps> {
    let mut all = FeatureMap::new(cfg).context("setting up the feature map")?;
    let mut first = None;
    for sweep in readings.chunk_by(|a, b| a.sweep_id == b.sweep_id) {
        all.update(&Sweep::from_readings(sweep, &cfg), &Isometry2::identity());
        if first.is_none() {
            first = Some(all.clone());
        }
    }
    Ok(FeatureMaps {
        first: first.unwrap_or_else(|| all.clone()),
        all,
    })
}

/// A wall in normal form as seen from the sensor.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WallTruth {
    /// Its index in the scene's walls.
    pub wall: usize,
    pub normal_deg: f64,
    pub distance_m: f64,
    /// The scan's pings reach its foot's bearing, in the line of sight.
    pub expected: bool,
    /// Its ends.
    pub a: Vec2,
    pub b: Vec2,
}

/// What a scene holds, in the terms features are measured in.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Truth {
    /// Echo points of the posts.
    pub posts: Vec<Vec2>,
    /// Wall ends and convex joints: point targets too.
    pub edges: Vec<Vec2>,
    /// Concave vertices, with whether they are expected.
    pub corners: Vec<(Vec2, bool)>,
    pub walls: Vec<WallTruth>,
}

/// Bearing span of the scan's pings, degrees: the outermost reading centres ± 2.25°.
fn ping_span(scan: Scan) -> (f64, f64) {
    let sensor = sonar_common::sensor::SensorConfig::default();
    let half = f64::from(sensor.step_deg) * (f64::from(sensor.pings_per_reading) - 1.0) / 2.0;
    let centres = sensor.reading_centres_deg();
    let (from, to) = match scan {
        Scan::Full => (f64::NEG_INFINITY, f64::INFINITY),
        Scan::Local { from_deg, to_deg } => (from_deg, to_deg),
    };
    let inside: Vec<f64> = centres
        .iter()
        .map(|&c| f64::from(c))
        .filter(|c| (from..=to).contains(c))
        .collect();
    let lo = inside.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = inside.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    (lo - half, hi + half)
}

impl Truth {
    pub fn of(scene: &Scene, scan: Scan) -> Self {
        let (lo, hi) = ping_span(scan);
        let reached = |p: Vec2| {
            let b = p.angle_deg();
            (lo..=hi).contains(&b) && !crosses_a_wall(scene.walls(), p)
        };
        let corner_max = scene.echo.corner_max_opening_deg;
        let mut truth = Truth {
            posts: scene
                .posts()
                .iter()
                .map(|p| p.centre * (1.0 - p.radius / p.centre.norm()))
                .collect(),
            ..Truth::default()
        };
        for v in scene.vertices() {
            if v.opening_deg < 179.0 && v.opening_deg <= corner_max {
                truth.corners.push((v.at, reached(v.at)));
            } else if v.opening_deg > 181.0 {
                truth.edges.push(v.at);
            }
        }
        for (index, w) in scene.walls().iter().enumerate() {
            let e = w.b - w.a;
            let t = -w.a.dot(e) / e.dot(e);
            if (0.0..=1.0).contains(&t) {
                let foot = w.a + e * t;
                truth.walls.push(WallTruth {
                    wall: index,
                    normal_deg: foot.angle_deg(),
                    distance_m: foot.norm(),
                    expected: reached(foot),
                    a: w.a,
                    b: w.b,
                });
            }
        }
        truth
    }
}

/// Whether the path from the sensor to `p` crosses a wall before reaching it.
fn crosses_a_wall(walls: &[Wall], p: Vec2) -> bool {
    let reach = 1.0 - 0.01 / p.norm();
    walls.iter().any(|w| {
        let e = w.b - w.a;
        let denom = p.cross(e);
        if denom.abs() < 1e-12 {
            return false;
        }
        let s = w.a.cross(e) / denom;
        let u = w.a.cross(p) / denom;
        s > 1e-9 && s < reach && (0.0..=1.0).contains(&u)
    })
}

/// Wall error: normal angle and perpendicular distance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WallError {
    pub angle_deg: f64,
    pub distance_m: f64,
}

/// How a plane's segment lies on its true wall.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SegmentFit {
    /// Share of the wall's length the segment covers.
    pub coverage: f64,
    /// How far the segment reaches beyond the wall's ends, metres (0 inside).
    pub overreach_m: f64,
}

impl SegmentFit {
    /// The segment `a`–`b` against the wall `wall` (both on nearly the same line).
    pub fn of(a: Point2<f64>, b: Point2<f64>, wall: &WallTruth) -> Self {
        let (wa, wb) = (point(wall.a), point(wall.b));
        let length = (wb - wa).norm();
        let dir = (wb - wa) / length;
        let (ta, tb) = ((a - wa).dot(&dir), (b - wa).dot(&dir));
        let (lo, hi) = (ta.min(tb), ta.max(tb));
        Self {
            coverage: ((hi.min(length) - lo.max(0.0)) / length).max(0.0),
            overreach_m: (-lo).max(hi - length).max(0.0),
        }
    }
}

/// A feature map measured against the truth.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Scored {
    /// Per post: distance of its point feature from the echo point; `None` if none matched.
    pub posts: Vec<Option<f64>>,
    /// Per expected corner: position error.
    pub corners: Vec<Option<f64>>,
    /// Per expected wall.
    pub walls: Vec<Option<WallError>>,
    /// Per expected wall found: its segment's fit.
    pub segments: Vec<SegmentFit>,
    /// Features matching nothing (or a truth already matched): kind and position.
    pub false_features: Vec<(FeatureKind, Point2<f64>)>,
    /// Point features within [`CROWD_M`] of a post other than the one matched to it.
    pub crowding: usize,
    /// Squared Mahalanobis error of every matched feature, by kind.
    pub mahalanobis2: Vec<(FeatureKind, f64)>,
    /// Every feature's error beside its reported σ (RMS over the two axes): kind, error, σ.
    pub error_vs_sigma: Vec<(FeatureKind, f64, f64)>,
}

fn point(v: Vec2) -> Point2<f64> {
    Point2::new(v.x, v.y)
}

/// Squared Mahalanobis distance of the error `e` under covariance `c`.
fn mahalanobis2(e: Vector2<f64>, c: Matrix2<f64>) -> Option<f64> {
    c.try_inverse().map(|inv| (e.transpose() * inv * e)[(0, 0)])
}

/// Scores `map` against `truth`; `support` (occupied grid cells) lets the planes' segments grow.
pub fn score(map: &FeatureMap, truth: &Truth, support: &[Point2<f64>]) -> Scored {
    let mut out = Scored::default();
    let features: Vec<&sonar_features::Feature> = map.features().collect();
    let segments = map.segments(support);
    let mut used = vec![false; features.len()];
    // Points: posts first (their errors are reported), then edges.
    let nearest = |target: Point2<f64>, kind: FeatureKind, used: &mut Vec<bool>| {
        let best = features
            .iter()
            .enumerate()
            .filter(|(i, f)| !used[*i] && f.kind() == kind)
            .map(|(i, f)| (i, (f.position() - target).norm()))
            .filter(|(_, d)| *d <= MATCH_M)
            .min_by(|a, b| a.1.total_cmp(&b.1));
        if let Some((i, _)) = best {
            used[i] = true;
        }
        best
    };
    let record = |out: &mut Scored, i: usize, target: Point2<f64>| {
        let f = &features[i];
        let e = f.position() - target;
        let c = f.covariance();
        if let Some(d2) = mahalanobis2(e, c) {
            out.mahalanobis2.push((f.kind(), d2));
        }
        out.error_vs_sigma
            .push((f.kind(), e.norm(), (c.trace() / 2.0).sqrt()));
    };
    for &p in &truth.posts {
        let m = nearest(point(p), FeatureKind::Point, &mut used);
        if let Some((i, _)) = m {
            record(&mut out, i, point(p));
        }
        out.posts.push(m.map(|(_, d)| d));
    }
    for &e in &truth.edges {
        nearest(point(e), FeatureKind::Point, &mut used);
    }
    for &(c, expected) in &truth.corners {
        let m = nearest(point(c), FeatureKind::Corner, &mut used);
        if let Some((i, _)) = m {
            record(&mut out, i, point(c));
        }
        if expected {
            out.corners.push(m.map(|(_, d)| d));
        }
    }
    for w in &truth.walls {
        let best = features
            .iter()
            .enumerate()
            .filter(|(i, f)| !used[*i] && f.kind() == FeatureKind::Plane)
            .filter_map(|(i, f)| {
                let angle = sonar_features::wrap_deg(f.normal_deg()? - w.normal_deg);
                let distance = f.distance_m()? - w.distance_m;
                (angle.abs() <= PLANE_MATCH_DEG && distance.abs() <= MATCH_M).then_some((
                    i,
                    WallError {
                        angle_deg: angle,
                        distance_m: distance,
                    },
                ))
            })
            .min_by(|a, b| {
                let cost = |e: &WallError| {
                    e.angle_deg.abs() / PLANE_MATCH_DEG + e.distance_m.abs() / MATCH_M
                };
                cost(&a.1).total_cmp(&cost(&b.1))
            });
        if let Some((i, e)) = best {
            used[i] = true;
            let f = &features[i];
            if let Some(seg) = segments.iter().find(|g| g.plane_id == f.id())
                && w.expected
            {
                out.segments.push(SegmentFit::of(seg.a, seg.b, w));
            }
            if let (Some(sa), Some(sd)) = (f.normal_sigma_deg(), f.distance_sigma_m()) {
                let d2 = (e.angle_deg / sa).powi(2) + (e.distance_m / sd).powi(2);
                out.mahalanobis2.push((FeatureKind::Plane, d2));
                // Angle error as the distance it makes one metre along the wall.
                let along = e.angle_deg.to_radians();
                out.error_vs_sigma.push((
                    FeatureKind::Plane,
                    (along.powi(2) + e.distance_m.powi(2)).sqrt() / 2f64.sqrt(),
                    ((sa.to_radians().powi(2) + sd.powi(2)) / 2.0).sqrt(),
                ));
            }
        }
        if w.expected {
            out.walls.push(best.map(|(_, e)| e));
        }
    }
    for (f, u) in features.iter().zip(&used) {
        if !u {
            out.false_features.push((f.kind(), f.position()));
        }
    }
    out.crowding = features
        .iter()
        .zip(&used)
        .filter(|(f, u)| {
            !**u && f.kind() == FeatureKind::Point
                && truth
                    .posts
                    .iter()
                    .any(|&p| (f.position() - point(p)).norm() <= CROWD_M)
        })
        .count();
    out
}

impl Scored {
    /// Both posts (of a two-post scene) resolved as two point features.
    pub fn resolves_posts(&self) -> bool {
        self.posts.len() >= 2
            && self
                .posts
                .iter()
                .all(|e| e.is_some_and(|e| e <= RESOLVED_M))
            && self.crowding == 0
    }
}

/// What the grid presets make of a post scene.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct GridFigures {
    /// Apparent width of the first post, per preset (`paper`, `recommended`); `None` = not
    /// detected.
    pub width_m: [Option<f64>; 2],
    /// Gap between the first two posts shown, per preset.
    pub gap: [Option<bool>; 2],
}

const PRESETS: [Preset; 2] = [Preset::Paper, Preset::Recommended];

fn grid_figures(scene: &Scene, readings: &[Reading]) -> Result<GridFigures> {
    let mut out = GridFigures::default();
    for (k, preset) in PRESETS.into_iter().enumerate() {
        let map = Maps::fuse(readings, preset)?.probability();
        let posts = scene.posts();
        if let Some(p) = posts.first() {
            out.width_m[k] =
                apparent_width(&map, p.centre, p.radius, WIDTH_WINDOW_M).map(|w| w.width_m);
        }
        if let [a, b, ..] = posts {
            out.gap[k] =
                gap_between(&map, a.centre, b.centre, a.radius, GAP_DEPTH_M).map(|g| g.resolved);
        }
    }
    Ok(out)
}

/// One run: a scene at one bearing with one seed.
#[derive(Debug, Clone, PartialEq)]
pub struct Run {
    pub bearing_deg: f64,
    pub seed: u64,
    /// After the first sweep and after all.
    pub first: Scored,
    pub all: Scored,
    /// For post scenes.
    pub grid: Option<GridFigures>,
}

/// Every run of one scene family.
#[derive(Debug, Clone, PartialEq)]
pub struct Family {
    pub name: String,
    pub runs: Vec<Run>,
}

/// What a family of runs takes from the grid presets.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum GridUse {
    None,
    /// The presets' figures for posts.
    Figures,
    /// The recommended preset's occupied cells as support for the planes' segments.
    Support,
}

/// The recommended preset's occupied cell centres.
fn occupied_cells(readings: &[Reading]) -> Result<Vec<Point2<f64>>> {
    let map = Maps::fuse(readings, Preset::Recommended)?.probability();
    let n = map.geometry().cells_per_side();
    Ok((0..n)
        .flat_map(|y| (0..n).map(move |x| (x, y)))
        .filter(|&(x, y)| map.is_occupied(x, y))
        .map(|(x, y)| point(map.centre(x, y)))
        .collect())
}

/// Runs `base` at every bearing and seed.
fn family(name: &str, base: &Scene, settings: &FeatureSettings, grid: GridUse) -> Result<Family> {
    family_at(name, base, settings, grid, NoiseLevel::NONE)
}

/// Runs `base` with `level`'s noise at every bearing and seed.
fn family_at(
    name: &str,
    base: &Scene,
    settings: &FeatureSettings,
    grid: GridUse,
    level: NoiseLevel,
) -> Result<Family> {
    let mut runs = Vec::new();
    let mut base = base.clone();
    if let Some(profile) = settings.profile.0 {
        base.set_profile(profile);
    }
    let mut cfg = scene_feature_config(&base);
    if let Some(c) = settings.calibrated {
        cfg.range_offset_m = c.offset_m;
        cfg.range_offset_sigma_m = c.sigma_m;
    }
    let head = Head::of(&base);
    for &bearing in &settings.bearings_deg {
        let scene = level.on(&rotated(&base, bearing)?);
        let scan = Scan::for_scene(&scene);
        let truth = Truth::of(&scene, scan);
        for &seed in &settings.seeds {
            let mut cap = capture_with(scene.clone(), head, scan, settings.sweeps, seed)
                .with_context(|| format!("simulating {} at {bearing}° with seed {seed}", name))?;
            level.drop_pings(&mut cap.readings, seed);
            let maps = feature_maps(&cap.readings, cfg)?;
            let support = match grid {
                GridUse::Support => occupied_cells(&cap.readings)?,
                GridUse::None | GridUse::Figures => Vec::new(),
            };
            runs.push(Run {
                bearing_deg: bearing,
                seed,
                // The grid of all sweeps would not match the map of the first.
                first: score(&maps.first, &truth, &[]),
                all: score(&maps.all, &truth, &support),
                grid: match grid {
                    GridUse::Figures => Some(grid_figures(&scene, &cap.readings)?),
                    GridUse::None | GridUse::Support => None,
                },
            });
        }
    }
    tracing::info!(scene = name, runs = runs.len(), "features done");
    Ok(Family {
        name: name.to_owned(),
        runs,
    })
}

/// The whole feature evaluation.
#[derive(Debug, Clone, PartialEq)]
pub struct FeatureResults {
    pub post: Family,
    /// Per spacing (mm).
    pub spacings: Vec<(u32, Family)>,
    pub room: Family,
    pub corner: Family,
    pub slanted: Family,
    /// A 10 cm post where the 5 cm one stood.
    pub thick_post: Family,
}

pub fn evaluate(settings: &FeatureSettings) -> Result<FeatureResults> {
    let post = family(
        "obstacle",
        &Scene::builtin("obstacle")?,
        settings,
        GridUse::Figures,
    )?;
    let spacings = settings
        .spacings_mm
        .iter()
        .map(|&mm| {
            let scene = two_posts(f64::from(mm) / 1000.0)?;
            Ok((
                mm,
                family(&scene.name.clone(), &scene, settings, GridUse::Figures)?,
            ))
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(FeatureResults {
        post,
        spacings,
        room: family("room", &Scene::builtin("room")?, settings, GridUse::Support)?,
        corner: family(
            "corner",
            &Scene::builtin("corner")?,
            settings,
            GridUse::Support,
        )?,
        slanted: family("slanted-wall", &slanted_wall()?, settings, GridUse::None)?,
        thick_post: family("thick-post", &thick_post(0.05)?, settings, GridUse::None)?,
    })
}

/// The features of one noise level on every scene family of the robustness runs.
#[derive(Debug, Clone, PartialEq)]
pub struct LevelResults {
    pub level: NoiseLevel,
    /// The 5 cm post at 1 m.
    pub post: Family,
    /// Per spacing (mm).
    pub spacings: Vec<(u32, Family)>,
    /// The square room, sensor at its centre.
    pub room: Family,
    /// The square room, the sensor at each of [`OFF_CENTRE`] (all in one family).
    pub off_centre: Family,
    pub l_room: Family,
    pub corner: Family,
    pub slanted: Family,
}

impl LevelResults {
    /// Every scene family, named.
    pub fn families(&self) -> Vec<&Family> {
        let mut out = vec![&self.post];
        out.extend(self.spacings.iter().map(|(_, f)| f));
        out.extend([
            &self.room,
            &self.off_centre,
            &self.l_room,
            &self.corner,
            &self.slanted,
        ]);
        out
    }
}

/// The robustness runs: every level of `settings.levels` on the post, the two posts at
/// `level_spacings_mm`, the square room with the sensor at its centre and off it, the L room,
/// the corner and the slanted wall, scored against each scene's truth (no grid).
pub fn evaluate_levels(settings: &FeatureSettings) -> Result<Vec<LevelResults>> {
    settings
        .levels
        .iter()
        .map(|&level| {
            let run =
                |name: &str, scene: &Scene| family_at(name, scene, settings, GridUse::None, level);
            let room = Scene::builtin("room")?;
            let mut off_centre = Family {
                name: "room, off-centre".into(),
                runs: Vec::new(),
            };
            for (x, y) in OFF_CENTRE {
                let f = run("room, off-centre", &shifted(&room, Vec2::new(x, y))?)?;
                off_centre.runs.extend(f.runs);
            }
            let spacings = settings
                .level_spacings_mm
                .iter()
                .map(|&mm| {
                    let scene = two_posts(f64::from(mm) / 1000.0)?;
                    Ok((mm, run(&scene.name.clone(), &scene)?))
                })
                .collect::<Result<Vec<_>>>()?;
            tracing::info!(level = %level.label(), "noise level done");
            Ok(LevelResults {
                level,
                post: run("obstacle", &Scene::builtin("obstacle")?)?,
                spacings,
                room: run("room", &room)?,
                off_centre,
                l_room: run("l-room", &l_room()?)?,
                corner: run("corner", &Scene::builtin("corner")?)?,
                slanted: run("slanted-wall", &slanted_wall()?)?,
            })
        })
        .collect()
}

/// The features' echo physics for a sensor the simulator plays with `echo` and `noise` (its
/// profile's beam, cut-off, gain, threshold and the threshold's jitter): what a robot builder
/// who measured that sensor's cones would set in `[features.echo]`. The simulator's defaults
/// give [`EchoPhysics::default`].
pub fn feature_physics(
    echo: &sonar_sim::EchoParams,
    noise: &sonar_sim::NoiseParams,
) -> EchoPhysics {
    EchoPhysics {
        threshold_jitter_db: noise.threshold_jitter_db,
        beam_6db_half_angle_deg: echo.beam_6db_half_angle_deg,
        specular_cutoff_deg: echo.specular_cutoff_deg,
        absorption_db_per_m: echo.absorption_db_per_m,
        tvg_db_per_m: echo.tvg_db_per_m,
        tvg_max_range_m: echo.tvg_max_range_m,
        threshold_db: echo.threshold_db,
        corner_loss_db: echo.corner_loss_db,
        ..EchoPhysics::default()
    }
}

/// The features' settings for the head and echoes of `scene` (its sensor profile's, or the
/// paper head's and the simulator's defaults without one): what a robot builder configures for
/// the sensor they own (`[features]`, `[features.echo]`).
pub fn scene_feature_config(scene: &Scene) -> FeatureConfig {
    FeatureConfig {
        sensor: crate::pipeline::Head::of(scene).sensor,
        echo: feature_physics(&scene.echo, &scene.noise),
        ..FeatureConfig::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use sonar_common::sensor::SensorConfig;
    use sonar_features::Reflector;
    use sonar_features::classify::Observation;
    use sonar_sim::{EchoModel, EchoParams, Target};

    fn model(walls: Vec<Wall>, posts: Vec<Post>) -> EchoModel {
        let scene = Scene::new("test", walls, posts).unwrap();
        EchoModel::new(scene, SensorConfig::default(), 1).unwrap()
    }

    /// Half-angle (0.05° steps) up to which the simulator's first echo comes from `target`.
    fn simulated_cone(m: &EchoModel, target: Target, centre_deg: f64) -> f64 {
        let mut off = 0.0;
        while m
            .first_echo(centre_deg + off + 0.05)
            .is_some_and(|e| e.target == target)
        {
            off += 0.05;
        }
        off
    }

    /// The heads in `examples/` a robot builder starts from are the simulator's profiles, as
    /// the evaluation configures the features for them: a profile that changes changes them.
    #[test]
    fn the_example_heads_are_the_profiles_the_evaluation_hears() {
        for (file, profile) in [
            (
                include_str!("../../examples/srf05-head.toml"),
                sonar_sim::SensorProfile::Srf05,
            ),
            (
                include_str!("../../examples/hc-sr04-head.toml"),
                sonar_sim::SensorProfile::HcSr04,
            ),
            (
                include_str!("../../examples/nxt-head.toml"),
                sonar_sim::SensorProfile::Nxt,
            ),
        ] {
            let table: toml::Table = toml::from_str(file).unwrap();
            let example: FeatureConfig = table["features"].clone().try_into().unwrap();
            let mut scene = Scene::builtin("room").unwrap();
            scene.set_profile(profile);
            let heard = scene_feature_config(&scene);
            assert_eq!(example.echo, heard.echo, "{profile}");
            assert_eq!(example.sensor, heard.sensor, "{profile}");
        }
    }

    #[test]
    fn the_feature_physics_defaults_are_the_simulators() {
        let f = EchoPhysics::default();
        let e = EchoParams::default();
        assert_eq!(feature_physics(&e, &sonar_sim::NoiseParams::default()), f);
        assert_eq!(
            (f.beam_6db_half_angle_deg, f.specular_cutoff_deg),
            (e.beam_6db_half_angle_deg, e.specular_cutoff_deg)
        );
        assert_eq!(
            (f.absorption_db_per_m, f.tvg_db_per_m, f.tvg_max_range_m),
            (e.absorption_db_per_m, e.tvg_db_per_m, e.tvg_max_range_m)
        );
        assert_eq!(
            (f.threshold_db, f.corner_loss_db),
            (e.threshold_db, e.corner_loss_db)
        );
        assert_eq!(f.point_radius_m, crate::pipeline::POST_RADIUS_M);

        // And the cones the library expects are the ones the simulator produces.
        let beam = f64::from(SensorConfig::default().beam_half_angle_deg);
        for radius in [0.025, 0.05] {
            for centre in [0.6, 1.0, 1.5, 2.0] {
                let post = Post {
                    centre: Vec2::new(centre, 0.0),
                    radius,
                    surface: sonar_sim::Surface::Hard,
                };
                let sim = simulated_cone(&model(vec![], vec![post]), Target::Post(0), 0.0);
                let lib = f
                    .cone_half_angle_deg(
                        Reflector::Cylinder { radius_m: radius },
                        centre - radius,
                        beam,
                    )
                    .unwrap_or(0.0);
                assert!(
                    (sim - lib).abs() < 0.06,
                    "{radius} m post at {centre} m: {sim} vs {lib}"
                );
            }
        }
        let wall = Wall {
            a: Vec2::new(1.5, -5.0),
            b: Vec2::new(1.5, 5.0),
            surface: sonar_sim::Surface::Hard,
        };
        let sim = simulated_cone(&model(vec![wall], vec![]), Target::Wall(0), 0.0);
        let lib = f.cone_half_angle_deg(Reflector::Plane, 1.5, beam).unwrap();
        assert!((sim - lib).abs() < 0.06, "wall: {sim} vs {lib}");
        // A corner of two short walls (whose feet miss them), 1.2 m ahead.
        let arm = |y: f64| Wall {
            a: Vec2::new(1.2, 0.0),
            b: Vec2::new(0.9, y),
            surface: sonar_sim::Surface::Hard,
        };
        let corner = model(vec![arm(0.3), arm(-0.3)], vec![]);
        let sim = simulated_cone(&corner, Target::Corner(0), 0.0);
        let lib = f.cone_half_angle_deg(Reflector::Corner, 1.2, beam).unwrap();
        assert!((sim - lib).abs() < 0.06, "corner: {sim} vs {lib}");
    }

    #[test]
    fn a_rotated_scene_turns_every_wall_and_post() {
        let two = two_posts(0.3).unwrap();
        let turned = rotated(&two, 90.0).unwrap();
        let p = turned.posts()[0].centre;
        assert!(
            (p.x + 0.15).abs() < 1e-12 && (p.y - 1.0).abs() < 1e-12,
            "{p:?}"
        );
        assert!((turned.walls()[0].a.y - 2.0).abs() < 1e-12);
        assert_eq!((turned.scan, turned.echo), (two.scan, two.echo));
    }

    #[test]
    fn the_slanted_wall_and_its_ends_return_nothing() {
        let scene = slanted_wall().unwrap();
        let m = EchoModel::new(scene, SensorConfig::default(), 1).unwrap();
        for k in 0..=200 {
            let aim = -50.0 + 0.5 * f64::from(k);
            assert_eq!(m.first_echo(aim), None, "{aim}°");
        }
    }

    #[test]
    fn the_truth_of_the_paper_scenes() {
        let room = Scene::builtin("room").unwrap();
        let t = Truth::of(&room, Scan::Full);
        assert_eq!(t.corners.iter().filter(|c| c.1).count(), 4);
        // The wall behind the head (normal at 180°) lies outside the pings' ±149.25°.
        assert_eq!(t.walls.iter().filter(|w| w.expected).count(), 3);
        let corner = Scene::builtin("corner").unwrap();
        let t = Truth::of(&corner, Scan::for_scene(&corner));
        assert_eq!((t.corners.len(), t.edges.len(), t.walls.len()), (1, 2, 2));
        let obstacle = Scene::builtin("obstacle").unwrap();
        let t = Truth::of(&obstacle, Scan::for_scene(&obstacle));
        assert!((t.posts[0].x - 0.975).abs() < 1e-12);
    }

    #[test]
    fn a_segment_is_measured_along_its_wall() {
        let wall = WallTruth {
            wall: 0,
            normal_deg: 0.0,
            distance_m: 1.0,
            expected: true,
            a: Vec2::new(1.0, -1.0),
            b: Vec2::new(1.0, 1.0),
        };
        let fit = SegmentFit::of(Point2::new(1.0, 1.1), Point2::new(1.0, 0.0), &wall);
        assert!((fit.coverage - 0.5).abs() < 1e-12);
        assert!((fit.overreach_m - 0.1).abs() < 1e-12);
    }

    fn observation(kind: FeatureKind, range_m: f64, bearing_deg: f64) -> Observation {
        Observation {
            kind,
            range_m,
            bearing_deg,
            range_sigma_random_m: 0.001,
            range_sigma_systematic_m: 0.002,
            bearing_sigma_deg: 0.3,
            bearing_sigma_random_deg: 0.0,
            rcd: 0,
            whole: true,
            also_plane: false,
            also_corner: false,
            pair_centre_deg: None,
        }
    }

    #[test]
    fn scoring_matches_each_truth_once_and_counts_the_rest_as_false() {
        let scene = Scene::builtin("obstacle").unwrap();
        let truth = Truth::of(&scene, Scan::for_scene(&scene));
        let mut map = FeatureMap::new(FeatureConfig::default()).unwrap();
        let obs = [
            // The post, 0.5° off (0.85 cm); a second point 7 cm beside it (two points within
            // 5 cm are merged as one target); the wall; a corner where there is none.
            observation(FeatureKind::Point, 0.975, 0.5),
            observation(FeatureKind::Point, 0.975, 4.6),
            observation(FeatureKind::Plane, 2.002, -0.4),
            observation(FeatureKind::Corner, 1.5, 20.0),
        ];
        map.merge(
            &obs,
            &Sweep::default(),
            &Isometry2::identity(),
            &nalgebra::Matrix3::zeros(),
        );
        let s = score(&map, &truth, &[]);
        let post = s.posts[0].unwrap();
        assert!((post - 0.975 * 0.5f64.to_radians()).abs() < 1e-3, "{post}");
        assert_eq!(s.walls.len(), 1);
        let wall = s.walls[0].unwrap();
        assert!((wall.angle_deg + 0.4).abs() < 1e-9 && (wall.distance_m - 0.002).abs() < 1e-9);
        // The wall was seen at its foot only: a point of it.
        assert_eq!(s.segments.len(), 1);
        assert!(s.segments[0].coverage < 1e-9 && s.segments[0].overreach_m == 0.0);
        let kinds: Vec<FeatureKind> = s.false_features.iter().map(|f| f.0).collect();
        assert_eq!(kinds, [FeatureKind::Point, FeatureKind::Corner]);
        assert_eq!(s.crowding, 1);
        assert!(!s.resolves_posts());
        // Post and wall errors measured against their reported uncertainty.
        assert_eq!(s.mahalanobis2.len(), 2);
        assert!(s.mahalanobis2.iter().all(|(_, d2)| *d2 < CHI2_95));
    }
}
