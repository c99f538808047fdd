//! The feature map: targets merged across sweeps and scan directions, refined when seen again,
//! fading when they stop being confirmed.
//!
//! Each sweep's [`Observation`]s are moved into the map's frame with the sensor's pose for the
//! sweep: points and corners as a position (x, y), planes in normal form (angle φ of the normal,
//! distance d from the map's origin). An observation refines the feature of its kind whose
//! estimate it matches (squared Mahalanobis distance under [`MergeConfig::gate_chi2`], each
//! feature refined at most once per sweep, the closest pairs first); otherwise it starts a new one.
//!
//! **Refinement** is a Kalman update of the estimate. Its covariance is kept in two parts because
//! the two kinds of error behave differently: the pings' jitter is independent from sweep to
//! sweep and averages out (the Kalman update of that part), but the bearing's quantisation repeats
//! in every sweep taken from the same place — the pings fall on the same angles whichever way the
//! head turns — so that part is the average of the observations' (it does not shrink). Reported
//! covariance = random part + systematic part. From a moving robot the quantisation differs from
//! place to place, and the figure is then on the safe side.
//!
//! **Fading**: a feature not confirmed by a sweep loses confidence only when the sweep had a ping
//! aimed at it (within half a step of its bearing, the plane's normal) that heard **farther or
//! nothing**: a target there would have been heard on its axis. A nearer echo hides it (no
//! change), and so does the same range without a classified region (something is still there).
//! Confirmation moves the confidence towards 1, a miss multiplies it by
//! [`MergeConfig::miss_factor`], and a feature below [`MergeConfig::remove_below`] is removed.
//! Each feature remembers where it was first seen from and whether every sighting came from
//! that one place ([`ONE_PLACE_M`]): sightings from one place repeat one view and its misreading,
//! so a point seen from one place only and missed by a ping from elsewhere, no farther from it,
//! is removed at once (a post returns the same echo from every side). A ping that heard nothing
//! misses only a feature that would have answered it: within the sensor's reach, and where the
//! echo model hears that kind of target on the axis.
//!
//! **Publication**: what one sweep heard and another sweep from the same place did not is a
//! candidate, kept (merged with, faded, matched by [`FeatureMap::localize`]) but not published:
//! [`FeatureMap::features`], its segments and summaries hold the features two sweeps or more
//! heard, or the only sweep their place had (one revolution, a robot on the move);
//! [`FeatureMap::tracked`] every one. Most of what one sweep heard and the next from its place did
//! not is that sweep's misreading. Nor is a point published that one place alone heard over a
//! region as wide as a wall's ([`Feature::may_be_a_wall`]): from there a post and a wall's foot
//! answer alike, and another place tells them.

use std::collections::VecDeque;

use nalgebra::{Isometry2, Matrix2, Matrix2x3, Matrix3, Point2, Vector2, Vector3};

use crate::classify::{Classification, CutRegions, Observation, classify, classify_with};
use crate::config::{FeatureConfig, MergeConfig};
use crate::error::FeatureError;
use crate::feature::{FOOT_SPACING_M, Feature, FeatureKind};
use crate::noise::{NoiseLog, NoiseModel};
use crate::physics::Reflector;
use crate::pings::Sweep;
use crate::rcd::{Gate, Rcd, extract};
use crate::segment::{Segment, segments};
use sonar_common::ipc::Reading;

/// Smallest bearing σ used for the independent part, so its covariance stays invertible (without
/// amplitude jitter the bearing has no error independent between sweeps taken from one place).
const BEARING_FLOOR_DEG: f64 = 0.01;

/// An observation in the map's frame.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Placed {
    kind: FeatureKind,
    mean: Vector2<f64>,
    random: Matrix2<f64>,
    systematic: Matrix2<f64>,
    ray_deg: f64,
    /// Plane: the sensor's foot along the line.
    foot: f64,
    /// Where the sensor stood.
    from: Vector2<f64>,
    /// A point whose region was as wide as a wall's there ([`Observation::also_plane`]).
    also_plane: bool,
    /// A plane whose region a corner's echo would fill as well ([`Observation::also_corner`]).
    also_corner: bool,
    /// One of two points split from a region one thicker post would fill: where that post's
    /// near face would lie ([`Observation::pair_centre_deg`]), in the map's frame.
    pair_centre: Option<Vector2<f64>>,
}

/// Sightings taken within this of each other are from one place: the same view of the same
/// surfaces, so that whatever one of them misread, the others misread alike. A viewpoint of the
/// generated suite is one place; a robot scanning on the move makes a new one every 20 cm.
pub(crate) const ONE_PLACE_M: f64 = 0.2;

/// Whether sightings taken at `a` and `b` are from one place ([`ONE_PLACE_M`]).
fn one_place(a: Vector2<f64>, b: Vector2<f64>) -> bool {
    (a - b).norm() <= ONE_PLACE_M
}

/// What [`FeatureMap::walls_on_the_move`] makes of a region as wide as both a post's cone and a
/// wall's region ([`Observation::also_plane`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NearRegions {
    /// Left out: the caller merges what it is given as walls, and a post beside the path would
    /// become one.
    LeftOut,
    /// Taken for a wall too: for a caller that admits a wall only once another viewpoint places
    /// it alike (a post's "wall" turns with the viewpoint, a wall's stays). In a hallway of
    /// 1–1.4 m the side walls are such regions.
    AsWalls,
}

/// Normal directions tried for the walls of a sweep on the move, degrees apart.
const MOVING_NORMAL_STEP_DEG: f64 = 2.0;
/// Pings within this of a tried normal are looked at: a wall is heard within its specular cut-off
/// (28°) of its normal; the rest of the window shows where its region ends.
const MOVING_WINDOW_DEG: f64 = 45.0;

/// Step of the numerical Jacobians of a placement, metres and radians.
const STEP: f64 = 1e-6;

impl Placed {
    /// `o` placed at the pose `x` = (x, y, θ), and the Jacobian of its mean with respect to `x`:
    /// taken numerically, so that every kind is placed by the one function that merges it.
    pub(crate) fn with_jacobian(o: &Observation, x: &Vector3<f64>) -> (Self, Matrix2x3<f64>) {
        let at = Self::new(o, &crate::geometry::vector_pose(x));
        let mut j = Matrix2x3::zeros();
        for k in 0..3 {
            let mut moved = *x;
            moved[k] += STEP;
            let mut d = Self::new(o, &crate::geometry::vector_pose(&moved)).mean - at.mean;
            if o.kind == FeatureKind::Plane {
                // The plane's angle is wrapped: a step never crosses more than a tiny arc.
                d.x = crate::geometry::wrap_rad(d.x);
            }
            j.set_column(k, &(d / STEP));
        }
        (at, j)
    }

    /// Covariance of the observation in the map's coordinates, both parts.
    pub(crate) fn covariance(&self) -> Matrix2<f64> {
        self.random + self.systematic
    }

    pub(crate) fn new(o: &Observation, pose: &Isometry2<f64>) -> Self {
        let theta = pose.rotation.angle();
        let t = pose.translation.vector;
        let beta = o.bearing_deg.to_radians();
        let random = Matrix2::from_diagonal(&Vector2::new(
            o.range_sigma_random_m.powi(2),
            BEARING_FLOOR_DEG
                .hypot(o.bearing_sigma_random_deg)
                .to_radians()
                .powi(2),
        ));
        let systematic = Matrix2::from_diagonal(&Vector2::new(
            o.range_sigma_systematic_m.powi(2),
            o.bearing_sigma_deg.to_radians().powi(2),
        ));
        match o.kind {
            FeatureKind::Point | FeatureKind::Corner => {
                let local = Point2::new(o.range_m * beta.cos(), o.range_m * beta.sin());
                let world = pose * local;
                // (r, β) → (x, y), then rotated into the map.
                let j = pose.rotation.to_rotation_matrix().matrix()
                    * Matrix2::new(
                        beta.cos(),
                        -o.range_m * beta.sin(),
                        beta.sin(),
                        o.range_m * beta.cos(),
                    );
                let pair_centre = o.pair_centre_deg.map(|deg| {
                    let c = deg.to_radians();
                    (pose * Point2::new(o.range_m * c.cos(), o.range_m * c.sin())).coords
                });
                Self {
                    kind: o.kind,
                    mean: world.coords,
                    random: j * random * j.transpose(),
                    systematic: j * systematic * j.transpose(),
                    ray_deg: crate::geometry::wrap_deg((beta + theta).to_degrees()),
                    foot: 0.0,
                    from: t,
                    also_plane: o.also_plane,
                    also_corner: false,
                    pair_centre,
                }
            }
            FeatureKind::Plane => {
                // Normal form in the map: φ = β + θ, d = d_s + t·n(φ); a negative d turns the
                // normal round.
                let phi = beta + theta;
                let n = Vector2::new(phi.cos(), phi.sin());
                let d = o.range_m + t.dot(&n);
                let sign = if d < 0.0 { -1.0 } else { 1.0 };
                let phi_map = if d < 0.0 {
                    phi + std::f64::consts::PI
                } else {
                    phi
                };
                let dn = Vector2::new(-phi.sin(), phi.cos());
                // (β, d_s) → (φ, d)
                let j = Matrix2::new(1.0, 0.0, sign * t.dot(&dn), sign);
                let swap = |m: Matrix2<f64>| Matrix2::new(m[(1, 1)], 0.0, 0.0, m[(0, 0)]);
                let along = Vector2::new(-phi_map.sin(), phi_map.cos());
                Self {
                    kind: o.kind,
                    mean: Vector2::new(crate::geometry::wrap_rad(phi_map), d.abs()),
                    random: j * swap(random) * j.transpose(),
                    systematic: j * swap(systematic) * j.transpose(),
                    ray_deg: crate::geometry::wrap_deg(phi.to_degrees()),
                    foot: t.dot(&along),
                    from: t,
                    also_plane: false,
                    also_corner: o.also_corner,
                    pair_centre: None,
                }
            }
        }
    }
}

/// What one sweep did to the map.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct SweepReport {
    /// The sweep's regions of constant depth.
    pub rcds: Vec<Rcd>,
    /// Their classes and the targets they gave.
    pub classification: Classification,
    /// Features started by this sweep.
    pub added: usize,
    /// Features refined.
    pub refined: usize,
    /// Features that lost confidence (aimed at, not heard).
    pub missed: usize,
    /// Features removed.
    pub removed: usize,
    /// Point or corner features merged into another (one post seen from two places, one corner
    /// heard as two).
    pub merged: usize,
}

/// The feature map.
#[derive(Debug, Clone)]
pub struct FeatureMap {
    cfg: FeatureConfig,
    features: Vec<Feature>,
    next_id: u64,
    sweeps: u64,
    /// Pairs of pings of the last sweeps merged: the sensor's noise ([`crate::noise`]).
    noise: NoiseLog,
    /// The last [`PAST_SWEEPS`] sweeps merged, each with its pose and range gate: what the places
    /// before a feature's own heard where it is.
    past: VecDeque<PastSweep>,
}

/// A sweep merged into the map, where it was taken and how far its ranges may be off.
#[derive(Debug, Clone)]
struct PastSweep {
    sweep: Sweep,
    pose: Isometry2<f64>,
    gate: Gate,
}

/// Sweeps remembered for [`point_outweighed`]: the places of the last minutes of a robot's
/// tour (two sweeps a place in the generated suite, so its eight places and more).
const PAST_SWEEPS: usize = 32;

/// Pings from elsewhere that aimed at a point heard from one place only and heard past it — with
/// none from elsewhere that heard anything at its range — that outweigh the place that heard it.
const OUTWEIGHING_MISSES: usize = 2;

impl FeatureMap {
    pub fn new(cfg: FeatureConfig) -> Result<Self, FeatureError> {
        cfg.validate()?;
        Ok(Self {
            cfg,
            features: Vec::new(),
            next_id: 1,
            sweeps: 0,
            noise: NoiseLog::default(),
            past: VecDeque::new(),
        })
    }

    pub fn config(&self) -> &FeatureConfig {
        &self.cfg
    }

    /// The features the map publishes, in order of creation ([`Feature::published`]): those two
    /// sweeps or more heard, or the only sweep of their place, but for a point one place alone
    /// heard as wide as a wall. What one sweep heard and another from its place did not, and such
    /// a point, are candidates, kept to merge later sightings with and to [`Self::localize`]
    /// against, but not published.
    pub fn features(&self) -> impl Iterator<Item = &Feature> {
        self.features.iter().filter(|f| f.published())
    }

    /// Every feature tracked, the candidates too.
    pub fn tracked(&self) -> &[Feature] {
        &self.features
    }

    /// Sweeps merged so far.
    pub fn sweeps(&self) -> u64 {
        self.sweeps
    }

    /// The range noise estimated from the sweeps merged so far and `sweep`'s pings.
    /// Ranges in whole units of a quantum (whole centimetres) are never known better than the
    /// rounding's quantum/√12, however often neighbouring ones agree.
    pub fn noise(&self, sweep: &Sweep) -> NoiseModel {
        let mut model = self.noise.model_with(sweep.pairs(), &self.cfg.noise);
        if let Some(quantum) = sweep.range_quantum_m() {
            model.floor_m = model.floor_m.max(quantum / 12f64.sqrt());
        }
        model
    }

    fn gate(&self, sweep: &Sweep) -> Gate {
        Gate::new(self.noise(sweep), &self.cfg)
    }

    /// Takes `sweep`'s neighbouring pings into the range-noise estimate without merging
    /// anything: for a consumer that only extracts observations ([`Self::observe`],
    /// [`Self::walls_on_the_move`]) and keeps its own landmarks (the SLAM).
    pub fn learn_noise(&mut self, sweep: &Sweep) {
        self.noise.add(sweep.pairs(), &self.cfg.noise);
    }

    /// Forgets every feature and the sweeps remembered with their poses (the sweep count, feature
    /// ids and the noise estimate go on): a map started again may stand in another frame.
    pub fn clear(&mut self) {
        self.features.clear();
        self.past.clear();
    }

    /// A sweep's regions of constant depth and what they are, in the sensor's frame: what
    /// [`Self::localize`] matches and [`Self::merge`] merges.
    pub fn observe(&self, sweep: &Sweep) -> (Vec<Rcd>, Classification) {
        let rcds = extract(sweep, &self.cfg, &self.gate(sweep));
        let classification = classify(&rcds, &self.cfg);
        (rcds, classification)
    }

    /// The walls of a sweep taken on the move, each reading with its pose relative to the
    /// sweep's reference at its stamp (its pings each at their own instant, [`Sweep::facing`]):
    /// for every normal direction in steps of [`MOVING_NORMAL_STEP_DEG`], the
    /// pings facing it compensated for the motion along it ([`Sweep::facing`]), and a plane found
    /// there whose own normal agrees with the one assumed (within half a step). Regions of
    /// constant depth from the pings as they were taken break up on the move — a wall's foot
    /// slides along it with the robot — so this is how such a sweep sees walls. Points and
    /// corners are not looked for: their range changes with the motion in a direction the beam
    /// does not tell.
    ///
    /// One wall is often found under several normals a few degrees apart: a wrong normal spreads
    /// the ranges a little, and a region may still pass as whole, only narrower, with its
    /// middle off the wall's normal (a hallway's end wall, 5° off, from a robot that turned into
    /// it). Under the right normal all of the wall's pings agree, so of the planes at one range
    /// whose normals lie within the specular cut-off of each other (from one place such walls
    /// share their pings) the one kept is whole if any is, and of those the one whose region
    /// holds the most pings.
    ///
    /// A region as wide as both a post's cone and a wall's region (a wall within about 0.6 m,
    /// abeam in a hallway) is a point to the classifier unless a corner beside it says otherwise
    /// ([`Observation::also_plane`]); `near_regions` says whether such a region whose middle
    /// lies on the normal is taken for a wall too.
    pub fn walls_on_the_move(
        &self,
        readings: &[(Reading, Isometry2<f64>)],
        near_regions: NearRegions,
    ) -> Vec<Observation> {
        // (whole, pings in its region, range tolerance, the plane), every normal's.
        let mut found: Vec<(bool, u32, f64, Observation)> = Vec::new();
        let steps = (360.0 / MOVING_NORMAL_STEP_DEG).round() as usize;
        for k in 0..steps {
            let normal = -180.0 + MOVING_NORMAL_STEP_DEG * k as f64;
            let sweep = Sweep::facing(
                readings.iter().map(|(r, pose)| (r, *pose)),
                normal,
                MOVING_WINDOW_DEG,
                &self.cfg,
            );
            // One noise estimate per direction (the gate), for the regions and the check below.
            let gate = self.gate(&sweep);
            let rcds = extract(&sweep, &self.cfg, &gate);
            for o in classify_with(&rcds, &self.cfg, CutRegions::Untold).observations {
                let agrees = crate::geometry::wrap_deg(o.bearing_deg - normal).abs()
                    <= MOVING_NORMAL_STEP_DEG / 2.0;
                let wall = o.kind == FeatureKind::Plane
                    || o.also_plane && near_regions == NearRegions::AsWalls;
                if wall && agrees {
                    let pings = rcds.get(o.rcd).map_or(0, |r| r.pings);
                    let o = Observation {
                        kind: FeatureKind::Plane,
                        also_plane: false,
                        also_corner: false,
                        ..o
                    };
                    found.push((o.whole, pings, gate.tolerance_at(o.range_m), o));
                }
            }
        }
        // Whole first, then the most pings; a stable sort keeps the normals' order on ties.
        found.sort_by_key(|f| std::cmp::Reverse((f.0, f.1)));
        let same_wall_deg = self.cfg.echo.specular_cutoff_deg;
        let mut walls: Vec<Observation> = Vec::new();
        for (_, _, tolerance, o) in found {
            let known = walls.iter().any(|w| {
                crate::geometry::wrap_deg(w.bearing_deg - o.bearing_deg).abs() <= same_wall_deg
                    && (w.range_m - o.range_m).abs() <= tolerance
            });
            if !known {
                walls.push(o);
            }
        }
        walls
    }

    /// The whole pipeline for one sweep taken at `pose` (the sensor in the map's frame, taken as
    /// exact): regions of constant depth, classification, merging and fading.
    pub fn update(&mut self, sweep: &Sweep, pose: &Isometry2<f64>) -> SweepReport {
        let (rcds, classification) = self.observe(sweep);
        let mut report = self.merge(&classification.observations, sweep, pose, &Matrix3::zeros());
        report.rcds = rcds;
        report.classification = classification;
        report
    }

    /// Merges one sweep's observations (taken at `pose`, known to within `pose_covariance` of
    /// x, y, θ), and fades the features `sweep` aimed at without hearing them. The report's `rcds`
    /// and `classification` are left empty.
    ///
    /// The pose's uncertainty goes into each observation's independent part: a wall first seen
    /// from a pose known only across the corridor is known as little along it, weighs as little
    /// in a fix, and gives way to a sighting from a better known pose (the pose's error differs
    /// from sweep to sweep, so it averages out like the pings' jitter).
    pub fn merge(
        &mut self,
        observations: &[Observation],
        sweep: &Sweep,
        pose: &Isometry2<f64>,
        pose_covariance: &Matrix3<f64>,
    ) -> SweepReport {
        self.sweeps += 1;
        let stamp = self.sweeps;
        let x = crate::geometry::pose_vector(pose);
        let placed: Vec<Placed> = observations
            .iter()
            .map(|o| {
                let (mut z, j) = Placed::with_jacobian(o, &x);
                z.random += j * pose_covariance * j.transpose();
                z
            })
            .collect();
        let gate = self.cfg.merge.gate_chi2;
        // Every admissible pair, closest first; each side used once.
        let mut pairs: Vec<(f64, usize, usize)> = Vec::new();
        for (i, z) in placed.iter().enumerate() {
            for (j, f) in self.features.iter().enumerate() {
                if let Some(d2) = mahalanobis2(f, z).filter(|&d2| d2 <= gate) {
                    pairs.push((d2, i, j));
                }
            }
        }
        pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
        let mut obs_used = vec![false; placed.len()];
        let mut feature_used = vec![false; self.features.len()];
        let mut report = SweepReport::default();
        for (_, i, j) in pairs {
            if obs_used[i] || feature_used[j] {
                continue;
            }
            obs_used[i] = true;
            feature_used[j] = true;
            refine(&mut self.features[j], &placed[i], stamp, &self.cfg.merge);
            report.refined += 1;
        }
        let gate = self.gate(sweep);
        self.noise.add(sweep.pairs(), &self.cfg.noise);
        let merge_cfg = self.cfg.merge;
        for (f, used) in self.features.iter_mut().zip(&feature_used) {
            if !*used && fade(f, sweep, pose, &gate, &self.cfg) {
                report.missed += 1;
            }
        }
        // This sweep's place: a feature from within one place of it could have been heard again.
        let here = pose.translation.vector;
        for f in &mut self.features {
            if one_place(f.seen_from, here) {
                f.place_sweeps += 1;
            }
        }
        for (z, _) in placed.iter().zip(&obs_used).filter(|(_, used)| !**used) {
            // This sweep and the remembered ones from its place.
            let place_sweeps = 1 + self
                .past
                .iter()
                .filter(|p| one_place(p.pose.translation.vector, z.from))
                .count();
            self.features.push(Feature {
                id: self.next_id,
                kind: z.kind,
                mean: z.mean,
                weights: z.random + z.systematic,
                random: z.random,
                systematic: z.systematic,
                confidence: merge_cfg.initial_confidence,
                times_seen: 1,
                first_seen: stamp,
                last_seen: stamp,
                ray_deg: z.ray_deg,
                feet: (z.foot, z.foot),
                feet_heard: if z.kind == FeatureKind::Plane {
                    vec![z.foot]
                } else {
                    Vec::new()
                },
                seen_from: z.from,
                one_place: true,
                may_be_plane: z.also_plane,
                may_be_corner: z.also_corner,
                pair_centre: z.pair_centre,
                place_sweeps: u32::try_from(place_sweeps).unwrap_or(u32::MAX),
            });
            self.next_id += 1;
            report.added += 1;
        }
        for (kept, merged) in same_targets(&self.features, &merge_cfg) {
            let other = self.features[merged].clone();
            let f = &mut self.features[kept];
            f.absorb_sightings(&other);
            f.one_place &= other.one_place && one_place(other.seen_from, f.seen_from);
            f.may_be_plane &= other.may_be_plane;
            f.may_be_corner &= other.may_be_corner;
            f.pair_centre = f.pair_centre.filter(|_| other.pair_centre.is_some());
            self.features[merged].confidence = 0.0;
            report.merged += 1;
        }
        for post in thick_posts(&self.features) {
            let mut kept = self.features[post.kept].clone();
            for &i in &post.merged {
                kept.absorb_sightings(&self.features[i]);
            }
            // The near faces from the two places lie up to the post's diameter apart: the
            // midpoint is off the nearest face by up to half of that, whichever it is.
            let spread = Matrix2::identity() * (post.apart_m / 2.0).powi(2);
            kept.mean = post.at;
            kept.weights += spread;
            kept.systematic += spread;
            kept.one_place = false;
            kept.pair_centre = None;
            kept.may_be_plane = false;
            self.features[post.kept] = kept;
            for &i in &post.merged {
                self.features[i].confidence = 0.0;
            }
            report.merged += post.merged.len();
        }
        self.past.push_back(PastSweep {
            sweep: sweep.clone(),
            pose: *pose,
            gate,
        });
        if self.past.len() > PAST_SWEEPS {
            self.past.pop_front();
        }
        for f in &mut self.features {
            if point_outweighed(f, &self.past, &self.cfg) {
                f.confidence = 0.0;
            }
        }
        let points_at_corners = points_at_corners(&self.features);
        let mut on_walls = points_on_confirmed_walls(&self.features);
        on_walls.extend(corners_on_confirmed_walls(&self.features));
        for f in self
            .features
            .iter_mut()
            .filter(|f| on_walls.contains(&f.id))
        {
            f.confidence = 0.0;
        }
        for f in self.features.iter_mut() {
            if points_at_corners.contains(&f.id) {
                f.kind = FeatureKind::Corner;
            }
        }
        let mut explained = explained_by_corners(&self.features, &self.cfg);
        explained.extend(heard_through_walls(&self.features));
        explained.extend(explained_by_posts(&self.features, &self.cfg));
        for f in self
            .features
            .iter_mut()
            .filter(|f| explained.contains(&f.id))
        {
            f.confidence = 0.0;
        }
        let before = self.features.len();
        self.features
            .retain(|f| f.confidence >= merge_cfg.remove_below);
        report.removed = before - self.features.len() - report.merged;
        report
    }

    /// The partial planes as segments; `support` are points known to be occupied (the grid's
    /// occupied cells, in the map's frame) that let a plane grow beyond its feet.
    pub fn segments(&self, support: &[Point2<f64>]) -> Vec<Segment> {
        let published: Vec<&Feature> = self.features().collect();
        segments(&published, support, &self.cfg.segments)
    }

    /// Every feature as one flat record, its segment attached: what a fixed-size publication
    /// record carries.
    pub fn summaries(&self, support: &[Point2<f64>]) -> Vec<FeatureSummary> {
        let segments = self.segments(support);
        self.features()
            .map(|f| {
                let p = f.position();
                let c = f.covariance();
                FeatureSummary {
                    id: f.id,
                    kind: f.kind,
                    x: p.x,
                    y: p.y,
                    cov_xx: c[(0, 0)],
                    cov_xy: c[(0, 1)],
                    cov_yy: c[(1, 1)],
                    angle_deg: f.normal_deg().unwrap_or(f.ray_deg),
                    angle_sigma_deg: f.normal_sigma_deg(),
                    confidence: f.confidence,
                    times_seen: f.times_seen,
                    last_seen: f.last_seen,
                    confirmed: f.confirmed(),
                    segment: segments
                        .iter()
                        .find(|s| s.plane_id == f.id)
                        .map(|s| [s.a, s.b]),
                }
            })
            .collect()
    }
}

/// One feature flattened for publication: every field a fixed-size record needs (`Option`s map to
/// NaN, the kind to a small integer).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FeatureSummary {
    pub id: u64,
    pub kind: FeatureKind,
    /// [`Feature::position`].
    pub x: f64,
    pub y: f64,
    /// [`Feature::covariance`].
    pub cov_xx: f64,
    pub cov_xy: f64,
    pub cov_yy: f64,
    /// Plane: its normal's direction; point, corner: the sensor's ray at the latest sighting.
    pub angle_deg: f64,
    /// Plane: σ of the normal's direction.
    pub angle_sigma_deg: Option<f64>,
    pub confidence: f64,
    pub times_seen: u32,
    pub last_seen: u64,
    /// [`Feature::confirmed`]: heard from two places or more (otherwise tentative).
    pub confirmed: bool,
    /// Plane: end points of its segment.
    pub segment: Option<[Point2<f64>; 2]>,
}

/// Difference observation − feature, the plane's angle wrapped.
pub(crate) fn innovation(f: &Feature, z: &Placed) -> Vector2<f64> {
    let mut v = z.mean - f.mean;
    if f.kind == FeatureKind::Plane {
        v.x = crate::geometry::wrap_rad(v.x);
    }
    v
}

/// Squared Mahalanobis distance between a feature and an observation of the same kind.
fn mahalanobis2(f: &Feature, z: &Placed) -> Option<f64> {
    if f.kind != z.kind {
        return None;
    }
    let v = innovation(f, z);
    let s = f.covariance_own() + z.random + z.systematic;
    s.try_inverse().map(|inv| (v.transpose() * inv * v)[(0, 0)])
}

/// The Kalman update of `f` by `z`.
fn refine(f: &mut Feature, z: &Placed, stamp: u64, cfg: &MergeConfig) {
    let v = innovation(f, z);
    let r = z.random + z.systematic;
    let Some(inv) = (f.weights + r).try_inverse() else {
        return;
    };
    let k = f.weights * inv;
    let i_k = Matrix2::identity() - k;
    f.mean += k * v;
    if f.kind == FeatureKind::Plane {
        f.mean.x = crate::geometry::wrap_rad(f.mean.x);
    }
    f.weights = i_k * f.weights;
    // Joseph form: the random part of the estimate under the gains actually used.
    f.random = i_k * f.random * i_k.transpose() + k * z.random * k.transpose();
    f.times_seen += 1;
    f.systematic += (z.systematic - f.systematic) / f64::from(f.times_seen);
    f.confidence += cfg.confirm_gain * (1.0 - f.confidence);
    f.last_seen = stamp;
    f.ray_deg = z.ray_deg;
    f.one_place &= one_place(z.from, f.seen_from);
    f.may_be_plane &= z.also_plane;
    f.may_be_corner &= z.also_corner;
    if f.kind == FeatureKind::Plane {
        f.feet = (f.feet.0.min(z.foot), f.feet.1.max(z.foot));
        f.hear_foot(z.foot);
    }
    if z.pair_centre.is_none() {
        // Heard as a point on its own: a post there, not half of a thicker one's region.
        f.pair_centre = None;
    }
}

/// Fades `f`, which `sweep` (taken at `pose`) did not confirm, by what the sweep heard where it
/// is; whether the sweep counted against it.
fn fade(
    f: &mut Feature,
    sweep: &Sweep,
    pose: &Isometry2<f64>,
    gate: &Gate,
    cfg: &FeatureConfig,
) -> bool {
    let heard = heard_at(f, sweep, pose, gate, cfg);
    let mut missed = true;
    match heard {
        // A post or corner seen once and not again by the next sweep that heard
        // something where it is: one sweep's misreading of what is there (a wall's echo
        // taken for a post, a wall's end for a corner). Not a wall: the pings on its
        // normal hear it in every sweep, but its region is often cut short by a post or
        // a lost ping (on the tune split, 2829 -> 2769 walls found per viewpoint for
        // 0.73 -> 0.69 false features, srf05).
        Some(Heard::There) if f.times_seen == 1 && f.kind != FeatureKind::Plane => {
            f.confidence = 0.0;
        }
        Some(Heard::Past) if refuted_from_elsewhere(f, pose) => f.confidence = 0.0,
        Some(Heard::Past) => f.confidence *= cfg.merge.miss_factor,
        Some(Heard::There | Heard::Nearer) | None => missed = false,
    }
    if foot_heard_off_normal(f, sweep, pose, gate, cfg) {
        f.confidence = 0.0;
        missed = true;
    }
    missed
}

/// Whether a ping from `pose` aimed at the point feature `f` that heard farther or nothing
/// refutes it outright: `f` was seen from one place only (its sightings are one view repeated,
/// which count as one), and `pose` stands elsewhere, no farther from it (up to
/// [`NO_FARTHER_M`]). A post is round: it returns the same echo whichever side it is seen from,
/// and one heard from a place is heard from nearer (its echo only weakens with range); a ping on
/// its axis from there that hears past it says it is not there. Not a corner (heard only from
/// inside its opening) and not a wall (heard only along its normal).
fn refuted_from_elsewhere(f: &Feature, pose: &Isometry2<f64>) -> bool {
    let here = pose.translation.vector;
    let at = f.position().coords;
    f.kind == FeatureKind::Point
        && f.one_place
        && !one_place(here, f.seen_from)
        && (at - here).norm() <= (at - f.seen_from).norm() + NO_FARTHER_M
}

/// Whether the places that aimed at the point feature `f`, heard from one place only, outweigh
/// that place: [`OUTWEIGHING_MISSES`] sweeps or more among `past` (the sweeps remembered, before
/// and after its own), from elsewhere and no farther from it than its own place (up to
/// [`NO_FARTHER_M`]), whose pings aimed at it heard farther or nothing, and none from elsewhere
/// that heard anything at its range. A post returns the same echo from every side and is heard
/// from nearer, so a ping from there that heard past it is evidence against it; but a weak post
/// is not heard by every ping aimed at it (a lost echo, the edge of its range), so one such ping
/// does not outweigh the place that heard it; two do. A ping that heard something at its range
/// may have heard the post in a region not classified as one: no evidence against it. (A sweep
/// after its own that misses it from elsewhere removes it at once: [`refuted_from_elsewhere`].)
fn point_outweighed(f: &Feature, past: &VecDeque<PastSweep>, cfg: &FeatureConfig) -> bool {
    if f.kind != FeatureKind::Point || !f.one_place {
        return false;
    }
    let at = f.position().coords;
    let own_range = (at - f.seen_from).norm();
    let mut misses = 0;
    for p in past {
        let here = p.pose.translation.vector;
        if one_place(here, f.seen_from) {
            continue;
        }
        match heard_at(f, &p.sweep, &p.pose, &p.gate, cfg) {
            Some(Heard::There) => return false,
            Some(Heard::Past) if (at - here).norm() <= own_range + NO_FARTHER_M => misses += 1,
            Some(Heard::Past | Heard::Nearer) | None => {}
        }
    }
    misses >= OUTWEIGHING_MISSES
}

/// Point features heard from one place only that lie on a wall heard from two places or more:
/// on its line (within three σ of both estimates across it) and within the stretch where the
/// sensor's perpendiculars met it (its feet). There a wall returned its echo along its normal, so
/// what one place took for a post there is a piece of that wall's region cut short (by a lost
/// ping, a post beside it); a real post stands out of the wall's line by its radius at least, and
/// a wall's end lies at the end of that stretch, not inside it. Not a corner: two walls meeting in
/// a T have their corners inside the stretch of the wall they meet (on the tune split the same
/// rule for corners lost 3–9 corners a profile).
///
/// Also a point that may be a wall ([`Feature::may_be_plane`]: its region was as wide as a
/// wall's there, near the sensor) on the line of a wall heard from elsewhere, anywhere along it:
/// what one place could not tell, another did (a board heard square from afar and as a "post"
/// from close by; on the tune split's arenas of boards the `srf05` scene maps' false features
/// 2.48 → 1.28, no wall, corner or post lost in the rooms or the arenas).
fn points_on_confirmed_walls(features: &[Feature]) -> Vec<u64> {
    features
        .iter()
        .filter(|p| p.kind == FeatureKind::Point && p.one_place)
        .filter(|p| {
            features.iter().any(|wall| {
                let heard_elsewhere = !one_place(wall.seen_from, p.seen_from);
                on_line(wall, p).is_some_and(|foot| {
                    within_feet(wall, foot) || p.may_be_plane && heard_elsewhere
                })
            })
        })
        .map(|p| p.id)
        .collect()
}

/// Corner features heard from one place only that lie on a wall heard from two places or more,
/// within its feet (as [`points_on_confirmed_walls`]), where no other wall of the map passes
/// (within [`CORNER_LINE_M`], at [`CROSSING_DEG`] or more to it): a corner is where two walls
/// meet, and a region of that wall cut short, or with a narrow beam a weaker wall's region as
/// wide as a hard corner's, was taken for one. A T's corner has the other wall through it. (On
/// the tune split no corner was lost, and the scene maps' false features fell by 0.08–0.23 a
/// scene in the rooms.)
fn corners_on_confirmed_walls(features: &[Feature]) -> Vec<u64> {
    let walls: Vec<&Feature> = features
        .iter()
        .filter(|f| f.kind == FeatureKind::Plane)
        .collect();
    features
        .iter()
        .filter(|c| c.kind == FeatureKind::Corner && c.one_place)
        .filter(|c| {
            let at = c.position().coords;
            walls.iter().any(|wall| {
                // Only for a wall it lies on: the other walls are looked through after.
                let another_through = || {
                    walls.iter().any(|w| {
                        w.id != wall.id && lines_cross(wall, w) && off_line(w, at) <= CORNER_LINE_M
                    })
                };
                on_line(wall, c).is_some_and(|foot| within_feet(wall, foot)) && !another_through()
            })
        })
        .map(|c| c.id)
        .collect()
}

/// Where `f` lies along `wall` (the coordinate of its foot, as [`Feature::feet`]) if it lies on
/// the wall's line: within three σ of both estimates across it.
fn on_line(wall: &Feature, f: &Feature) -> Option<f64> {
    let along = wall.direction()?;
    let n = wall.normal();
    let at = f.position().coords;
    let across_sigma =
        (wall.covariance_own()[(1, 1)] + (n.transpose() * f.covariance() * n)[(0, 0)]).sqrt();
    (off_line(wall, at) <= 3.0 * across_sigma).then(|| along.dot(&at))
}

/// How far `at` lies from `wall`'s line.
fn off_line(wall: &Feature, at: Vector2<f64>) -> f64 {
    (wall.normal().dot(&at) - wall.mean.y).abs()
}

/// Whether two walls' lines cross at [`CROSSING_DEG`] or more.
fn lines_cross(a: &Feature, b: &Feature) -> bool {
    a.normal().perp(&b.normal()).abs() >= CROSSING_DEG.to_radians().sin()
}

/// Whether `foot` lies where a wall heard from two places or more was met by the sensor's
/// perpendiculars.
fn within_feet(wall: &Feature, foot: f64) -> bool {
    !wall.one_place && (wall.feet.0..=wall.feet.1).contains(&foot)
}

/// A place is no farther from a feature than another up to this: the ranges' errors.
const NO_FARTHER_M: f64 = 0.05;

/// What a sweep heard where a feature is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Heard {
    /// Something nearer: the feature is hidden.
    Nearer,
    /// Something at the feature's range.
    There,
    /// Farther, or nothing where a target there would have been heard on its axis.
    Past,
}

/// What `sweep`, taken at `pose`, heard on the ping aimed at the feature; `None` if it aimed none
/// at it (or stands behind a plane), or heard nothing where the feature would not have answered
/// either (beyond the sensor's reach, or where even the feature's echo on the axis falls under
/// the threshold: a corner 4 m off).
fn heard_at(
    f: &Feature,
    sweep: &Sweep,
    pose: &Isometry2<f64>,
    gate: &Gate,
    cfg: &FeatureConfig,
) -> Option<Heard> {
    let inverse = pose.inverse();
    let (bearing_deg, range) = match f.kind {
        FeatureKind::Point | FeatureKind::Corner => {
            let local = inverse * f.position();
            (local.y.atan2(local.x).to_degrees(), local.coords.norm())
        }
        FeatureKind::Plane => {
            let n = f.normal();
            let d = f.mean.y - pose.translation.vector.dot(&n);
            if d <= 0.0 {
                // The sensor stands behind the wall's line.
                return None;
            }
            let phi = f.mean.x - pose.rotation.angle();
            (phi.to_degrees(), d)
        }
    };
    // How far the feature's own range may be off: a plane's distance σ, a position's total σ.
    let sigma = match f.kind {
        FeatureKind::Plane => f.covariance_own()[(1, 1)].sqrt(),
        FeatureKind::Point | FeatureKind::Corner => f.covariance().trace().sqrt(),
    };
    heard(
        sweep,
        bearing_deg,
        range,
        gate.tolerance_at(range) + 3.0 * sigma,
        cfg.range_offset_m,
        || answers_at(f.kind, range, cfg),
    )
}

/// Whether a target of `kind` would answer a ping aimed at it from `range_m`: within the
/// sensor's reach, and its echo on the axis above the threshold (the reference post for a point).
fn answers_at(kind: FeatureKind, range_m: f64, cfg: &FeatureConfig) -> bool {
    let reflector = match kind {
        FeatureKind::Point => cfg.echo.reference_point(),
        FeatureKind::Plane => Reflector::Plane,
        FeatureKind::Corner => Reflector::Corner,
    };
    range_m <= f64::from(cfg.sensor.max_range_m)
        && cfg
            .echo
            .cone_half_angle_deg(
                reflector,
                range_m,
                f64::from(cfg.sensor.beam_half_angle_deg),
            )
            .is_some()
}

/// What `sweep` heard on its ping at `bearing_deg` about a target at `range` (± `margin`); a
/// ping that heard nothing is evidence only where the target `answers` (asked only then).
fn heard(
    sweep: &Sweep,
    bearing_deg: f64,
    range: f64,
    margin: f64,
    range_offset_m: f64,
    answers: impl FnOnce() -> bool,
) -> Option<Heard> {
    let ping = sweep.ping_at(bearing_deg)?;
    match ping.range_m.map(|r| r - range_offset_m) {
        None => answers().then_some(Heard::Past),
        Some(r) if r > range + margin => Some(Heard::Past),
        Some(r) if r < range - margin => Some(Heard::Nearer),
        Some(_) => Some(Heard::There),
    }
}

/// The foot of a plane seen from one place (its feet within `tolerance` of each other), if any.
fn single_foot(f: &Feature, tolerance: f64) -> Option<Vector2<f64>> {
    let along = f.direction()?;
    let (lo, hi) = f.feet;
    (f.kind == FeatureKind::Plane && hi - lo <= tolerance)
        .then(|| f.normal() * f.mean.y + along * (lo + hi) / 2.0)
}

/// Whether `sweep`, taken at `pose` beyond the specular cut-off of a plane seen from one place,
/// heard something at the plane's foot: a wall does not return an echo from there, a corner's
/// vertex, a post or a wall's end does — the plane was their echo taken for a wall.
fn foot_heard_off_normal(
    f: &Feature,
    sweep: &Sweep,
    pose: &Isometry2<f64>,
    gate: &Gate,
    cfg: &FeatureConfig,
) -> bool {
    let Some(foot) = single_foot(f, cfg.segments.corner_tolerance_m) else {
        return false;
    };
    let to_sensor = pose.translation.vector - foot;
    let off_normal = to_sensor.angle(&-f.normal()).to_degrees();
    if off_normal <= cfg.echo.specular_cutoff_deg {
        return false;
    }
    let local = pose.inverse() * Point2::from(foot);
    let range = local.coords.norm();
    let sigma = f.covariance().trace().sqrt();
    heard(
        sweep,
        local.y.atan2(local.x).to_degrees(),
        range,
        gate.tolerance_at(range) + 3.0 * sigma,
        cfg.range_offset_m,
        || false,
    ) == Some(Heard::There)
}

/// A plane seen from one place is a corner's echo when its foot lies this close to a corner (one
/// of the map's, or where it crosses another such plane): the foot of a corner's echo taken for
/// a wall is the vertex up to the bearing's error of its region's centre (a degree or two, a few
/// centimetres at 2 m).
const EXPLAINED_M: f64 = 0.10;
/// Two planes cross at a corner only at this angle or more (a corner's echoes taken for walls
/// from two places have normals that differ by the angle between the places, seen from it).
const CROSSING_DEG: f64 = 10.0;

/// Point features where two of the map's walls meet in a concave corner: on both lines (within
/// three σ across each and [`CORNER_LINE_M`], the walls at [`CROSSING_DEG`] or more to each
/// other, at least one heard from two places: two phantom walls heard from one place may cross
/// at a post), each wall running from there into the other's front (the side it was heard from),
/// as a room's corner does and a box's outer edge does not. A corner heard over fewer pings than
/// its cone, as one between two thin boards is (each bounce loses a board's strength), is as
/// narrow as a post's and was taken for one; a post stands clear of the walls by its radius at
/// least.
fn points_at_corners(features: &[Feature]) -> Vec<u64> {
    let walls: Vec<&Feature> = features
        .iter()
        .filter(|f| f.kind == FeatureKind::Plane)
        .collect();
    let on_both = |w: &Feature, p: &Feature| {
        on_line(w, p).is_some() && off_line(w, p.position().coords) <= CORNER_LINE_M
    };
    // The side of `w` it was heard from, and where it runs from `at` (towards its feet).
    let front = |w: &Feature, q: Vector2<f64>| {
        let n = w.normal();
        (n.dot(&q) - w.mean.y).signum() == (n.dot(&w.seen_from) - w.mean.y).signum()
    };
    let runs = |w: &Feature, at: Vector2<f64>| {
        let along = w.direction().unwrap_or_default();
        let middle = (w.feet.0 + w.feet.1) / 2.0 - along.dot(&at);
        (middle.abs() > CORNER_STEP_M).then(|| along * middle.signum())
    };
    features
        .iter()
        .filter(|p| p.kind == FeatureKind::Point)
        .filter(|p| {
            let at = p.position().coords;
            walls.iter().enumerate().any(|(i, a)| {
                on_both(a, p)
                    && walls[i + 1..].iter().any(|b| {
                        let confirmed = !a.one_place || !b.one_place;
                        lines_cross(a, b)
                            && confirmed
                            && on_both(b, p)
                            && runs(a, at).zip(runs(b, at)).is_some_and(|(ua, ub)| {
                                front(b, at + ua * CORNER_STEP_M)
                                    && front(a, at + ub * CORNER_STEP_M)
                            })
                    })
            })
        })
        .map(|p| p.id)
        .collect()
}

/// A target heard through a wall lies at least this far behind its line (more than a corner's or
/// a wall's end's error across it).
const BEHIND_WALL_M: f64 = 0.10;

/// Posts and corners heard from one place only that lie behind a wall heard from two places or
/// more, as seen from that place: the wall's line crosses the way from the place to the target
/// within [`FOOT_SPACING_M`] of a foot where the wall was heard, the target
/// [`BEHIND_WALL_M`] or more behind it. Sound does not pass through a wall at any angle, so no
/// echo came from there straight: it came round by two walls (a double bounce in a corner,
/// heard late and so farther off along the ray). Only where a foot shows the wall stands: between
/// two feet a wall may have a doorway, through which targets are heard.
fn heard_through_walls(features: &[Feature]) -> Vec<u64> {
    let walls: Vec<&Feature> = features
        .iter()
        .filter(|w| w.kind == FeatureKind::Plane && !w.one_place)
        .collect();
    features
        .iter()
        .filter(|f| f.one_place && f.kind != FeatureKind::Plane)
        .filter(|f| {
            let from = f.seen_from;
            let at = f.position().coords;
            walls.iter().any(|w| {
                let (n, d) = (w.normal(), w.mean.y);
                let (side_from, side_at) = (n.dot(&from) - d, n.dot(&at) - d);
                if side_from * side_at >= 0.0 || side_at.abs() < BEHIND_WALL_M {
                    return false;
                }
                let crossing = from + (at - from) * (side_from / (side_from - side_at));
                let along = w.direction().unwrap_or_default().dot(&crossing);
                w.foot_near(along, FOOT_SPACING_M)
            })
        })
        .map(|f| f.id)
        .collect()
}

/// A step along a wall from a corner, to tell which side of the other wall it runs into.
const CORNER_STEP_M: f64 = 0.05;
/// A point at a corner lies on both walls' lines within three σ, and within this however
/// uncertain a wall: a post stands clear of a wall by its radius (a generated scene's by 15 cm).
const CORNER_LINE_M: f64 = 0.05;

/// Planes seen from one place only (their feet within [`SegmentConfig::corner_tolerance_m`] of
/// each other) whose foot lies on a corner: one of the map's corners, where the plane crosses
/// another such plane, or on the line of a plane seen from two places or more (at
/// [`CROSSING_DEG`] or more to it, within the tolerance and the foot's error along its own
/// line; from one other place will do for a plane that may be a corner's echo,
/// [`Feature::may_be_corner`]): where two walls meet. From where it
/// was heard, a corner's vertex is the nearest point of a line across the ray: its echo looks
/// like a wall's, with the vertex as the foot, and from two places it looks like two walls whose
/// feet are where they cross. A real wall's foot lies on it, at a corner only when heard from
/// along the other wall.
///
/// [`SegmentConfig::corner_tolerance_m`]: crate::config::SegmentConfig::corner_tolerance_m
fn explained_by_corners(features: &[Feature], cfg: &FeatureConfig) -> Vec<u64> {
    let tolerance = cfg.segments.corner_tolerance_m;
    let beam_cos = f64::from(cfg.sensor.beam_half_angle_deg).to_radians().cos();
    let corners: Vec<&Feature> = features
        .iter()
        .filter(|f| f.kind == FeatureKind::Corner)
        .collect();
    // Planes seen from one place, with their foot.
    let single: Vec<(&Feature, Vector2<f64>)> = features
        .iter()
        .filter_map(|f| Some((f, single_foot(f, tolerance)?)))
        .collect();
    let mut explained = Vec::new();
    for &(plane, foot) in &single {
        let (n, d) = (plane.normal(), plane.mean.y);
        let sigma = plane.covariance_own()[(1, 1)].sqrt();
        // The plane's distance error and `c`'s along the unit vector `u`, together.
        let with_corner = |c: &Feature, u: Vector2<f64>| {
            (sigma.powi(2) + (u.transpose() * c.covariance() * u)[(0, 0)]).sqrt()
        };
        // A corner first heard along another ray than the plane.
        let heard_elsewhere = |c: &Feature| {
            crate::geometry::wrap_deg(c.ray_deg - plane.ray_deg).abs() > cfg.merge.post_turn_deg
        };
        // The vertex lies on the line (its echo's range is the plane's distance), up to both
        // ranges' errors; along it, up to the bearing's.
        let at_corner = corners.iter().any(|c| {
            let v = c.position().coords;
            heard_elsewhere(c)
                && (v - foot).norm() <= EXPLAINED_M
                && (n.dot(&v) - d).abs() <= 3.0 * with_corner(c, n)
        });
        let crossing = single.iter().any(|&(other, other_foot)| {
            let (m, e) = (other.normal(), other.mean.y);
            let sin = n.perp(&m);
            if other.id == plane.id || sin.abs() < CROSSING_DEG.to_radians().sin() {
                return false;
            }
            // n·x = d and m·x = e.
            let x = Vector2::new(d * m.y - e * n.y, n.x * e - m.x * d) / sin;
            (x - foot).norm() <= EXPLAINED_M && (x - other_foot).norm() <= EXPLAINED_M
        });
        // A plane's foot on the line of a wall seen from two places or more (a corner's echo
        // taken for a wall turns with the place it is heard from, so it is not confirmed from
        // elsewhere), the two at an angle: its "wall" would meet that one at its foot, which a
        // sensor hears as a wall only from the other wall's line when they meet at a right
        // angle; a corner's vertex is where two walls meet. (Any other plane, or one first seen
        // from elsewhere, cost walls on the tune split: 3155 -> 3146 of 3519 per viewpoint,
        // 674 -> 673 of 933 per scene, hc-sr04 and srf05.) A plane one place heard over a region
        // a corner's echo fills as well ([`Feature::may_be_corner`]) is a corner's echo on the
        // line of a wall heard from any other place: there one place's guess meets another's
        // sighting (a wall from one place only, taken for a corner's wall whatever the plane,
        // removed boards from the arenas where a board's end was heard as a wall). Along its own
        // line the foot is known only to the bearing's error times the range, so it is on the
        // other line within the tolerance and that error's share across it.
        let bearing_sigma = plane.covariance_own()[(0, 0)].sqrt();
        let along_sigma = (foot - plane.seen_from).norm() * bearing_sigma;
        let on_a_wall = features.iter().any(|other| {
            let told_by = !other.one_place
                || plane.may_be_corner
                    && plane.one_place
                    && !one_place(other.seen_from, plane.seen_from);
            let sin = n.perp(&other.normal()).abs();
            other.kind == FeatureKind::Plane
                && told_by
                && lines_cross(plane, other)
                && (other.normal().dot(&foot) - other.mean.y).abs()
                    <= tolerance + 3.0 * along_sigma * sin
        });
        // A plane one place heard over a region a corner's echo fills as well, with a corner two
        // places heard at the plane's own range from that place and within the beam of its
        // normal: the corner's echo, its bearing placed off the vertex (a region running to the
        // sweep's limit is placed a lobe in from its natural end, and a corner answers over a
        // wider lobe than the one learnt; the vertex may lie beyond the limit). A wall's corner
        // on the plane's line off its foot lies farther than the plane's range, as every point of
        // a wall but its foot does.
        let range = d - n.dot(&plane.seen_from);
        let corner_at_range = plane.may_be_corner
            && corners.iter().any(|c| {
                let to = c.position().coords - plane.seen_from;
                let towards = to.normalize();
                !c.one_place
                    && heard_elsewhere(c)
                    && (to.norm() - range).abs() <= 3.0 * with_corner(c, towards)
                    && towards.dot(&n) >= beam_cos
            });
        if at_corner || crossing || on_a_wall || corner_at_range {
            explained.push(plane.id);
        }
    }
    explained
}

/// Planes and corners heard from one place only that lie on a post heard from two places or
/// more (a plane's foot, a corner's vertex within [`EXPLAINED_M`] of it): the post's echo, taken
/// for a wall where its region was as wide as a wall's (near the sensor, a narrow beam) or for a
/// corner where a wall's line met its range. A real wall or corner there would stand behind the
/// post, at another range from the place that heard it.
fn explained_by_posts(features: &[Feature], cfg: &FeatureConfig) -> Vec<u64> {
    let posts: Vec<Vector2<f64>> = features
        .iter()
        .filter(|f| f.kind == FeatureKind::Point && !f.one_place && f.confidence > 0.0)
        .map(|f| f.position().coords)
        .collect();
    features
        .iter()
        .filter(|f| f.one_place)
        .filter_map(|f| match f.kind {
            FeatureKind::Plane => Some((f.id, single_foot(f, cfg.segments.corner_tolerance_m)?)),
            FeatureKind::Corner => Some((f.id, f.position().coords)),
            FeatureKind::Point => None,
        })
        .filter(|(_, at)| posts.iter().any(|p| (p - at).norm() <= EXPLAINED_M))
        .map(|(id, _)| id)
        .collect()
}

/// The near faces of one post seen from two places lie no farther apart than its diameter: a
/// post whose region two places split in two, with the split's centres this close, is one post
/// up to this thick.
const THICK_POST_M: f64 = 0.15;
/// Two points split from one region share its centre (to rounding; a sweep later from the same
/// place refines them without moving it).
const SAME_REGION_M: f64 = 0.02;

/// One thick post found from the points two places split its region into.
struct ThickPost {
    /// The feature that becomes the post.
    kept: usize,
    /// The others, merged into it.
    merged: Vec<usize>,
    /// Between the two places' region centres (each the near face seen from there).
    at: Vector2<f64>,
    /// How far apart those were.
    apart_m: f64,
}

/// Points split in two from one region ([`Feature::pair_centre`]) at two places whose regions'
/// centres agree within [`THICK_POST_M`]: one thick post, not two pairs. Two posts close
/// together are split alike from every place and their points merge as each place confirms
/// them (so the second place's sightings start no pair of their own); a thick post's points
/// stand a half-cone to either side of the line of sight, so each place's pair lies across its
/// own ray, elsewhere, while the centres of both regions lie on the post. (The paper's
/// obstacle, a 10 cm post, heard from one place: two points; from two, one.)
fn thick_posts(features: &[Feature]) -> Vec<ThickPost> {
    let paired: Vec<(usize, Vector2<f64>)> = features
        .iter()
        .enumerate()
        .filter(|(_, f)| f.kind == FeatureKind::Point && f.confidence > 0.0)
        .filter_map(|(i, f)| Some((i, f.pair_centre?)))
        .collect();
    let mut taken = vec![false; features.len()];
    let mut posts = Vec::new();
    for &(i, ca) in &paired {
        for &(j, cb) in &paired {
            let (a, b) = (&features[i], &features[j]);
            if j <= i
                || taken[i]
                || taken[j]
                || one_place(a.seen_from, b.seen_from)
                || (ca - cb).norm() > THICK_POST_M
            {
                continue;
            }
            let group: Vec<usize> = paired
                .iter()
                .filter(|&&(k, c)| {
                    !taken[k]
                        && ((c - ca).norm() <= SAME_REGION_M || (c - cb).norm() <= SAME_REGION_M)
                })
                .map(|&(k, _)| k)
                .collect();
            for &k in &group {
                taken[k] = true;
            }
            let kept = group
                .iter()
                .copied()
                .max_by_key(|&k| features[k].times_seen)
                .unwrap_or(i);
            posts.push(ThickPost {
                kept,
                merged: group.into_iter().filter(|&k| k != kept).collect(),
                at: (ca + cb) / 2.0,
                apart_m: (ca - cb).norm(),
            });
        }
    }
    // A pair whose region's centre a point heard whole from elsewhere lies on: that point is
    // the post, whose region that place heard a step or two narrower (places that split it
    // alike merged their sightings into the first pair's two points, leaving no second pair to
    // agree with).
    for (s, single) in features.iter().enumerate() {
        if single.kind != FeatureKind::Point
            || single.confidence <= 0.0
            || single.pair_centre.is_some()
            || taken[s]
        {
            continue;
        }
        let at = single.position().coords;
        let Some(&(_, centre)) = paired.iter().find(|&&(k, c)| {
            !taken[k]
                && !one_place(features[k].seen_from, single.seen_from)
                && (c - at).norm() <= THICK_POST_M
        }) else {
            continue;
        };
        let merged: Vec<usize> = paired
            .iter()
            .filter(|&&(k, c)| !taken[k] && (c - centre).norm() <= SAME_REGION_M)
            .map(|&(k, _)| k)
            .collect();
        for &k in merged.iter().chain([&s]) {
            taken[k] = true;
        }
        posts.push(ThickPost {
            kept: s,
            merged,
            at: (centre + at) / 2.0,
            apart_m: (centre - at).norm(),
        });
    }
    posts
}

/// Whether two point features heard from one place only, the same place, lie within the gate of
/// each other under both their covariances: one target whose sightings fell in two groups. A
/// faint post's region breaks into pieces under the amplitude jitter, two of them in one sweep,
/// and a sweep refines a feature once: the second piece starts a feature of its own a few
/// degrees off, which the post's later sightings do not reach ([`refine`] gates each sighting,
/// not the features against each other). Without jitter a point's bearing is known to a fraction
/// of a step, and two posts a few centimetres apart stay two.
fn one_view_alike(a: &Feature, b: &Feature, gate_chi2: f64) -> bool {
    a.one_place
        && b.one_place
        && one_place(a.seen_from, b.seen_from)
        && (a.covariance_own() + b.covariance_own())
            .try_inverse()
            .is_some_and(|inv| {
                let d = a.mean - b.mean;
                (d.transpose() * inv * d)[(0, 0)] <= gate_chi2
            })
}

/// Point features seen from different directions (their latest rays more than
/// [`MergeConfig::post_turn_deg`] apart) within [`MergeConfig::post_spread_m`] of each other:
/// one post, whose echo point (its surface nearest the sensor) moves round it with the sensor;
/// two point features within [`MergeConfig::one_point_m`] whatever their rays: one thick post
/// or wall end heard as two points; and two corner features within
/// [`MergeConfig::one_corner_m`]: one corner heard as two vertices. Each pair as (kept, merged
/// into it): the one seen more often is kept.
fn same_targets(features: &[Feature], cfg: &MergeConfig) -> Vec<(usize, usize)> {
    let mut pairs = Vec::new();
    let mut taken = vec![false; features.len()];
    for i in 0..features.len() {
        for j in i + 1..features.len() {
            let (a, b) = (&features[i], &features[j]);
            if taken[i] || taken[j] || a.kind != b.kind || a.kind == FeatureKind::Plane {
                continue;
            }
            let turned = crate::geometry::wrap_deg(a.ray_deg - b.ray_deg).abs();
            let apart = (a.mean - b.mean).norm();
            let one = match a.kind {
                FeatureKind::Point => {
                    (turned > cfg.post_turn_deg && apart <= cfg.post_spread_m)
                        || apart <= cfg.one_point_m
                        || one_view_alike(a, b, cfg.gate_chi2)
                }
                FeatureKind::Corner => apart <= cfg.one_corner_m,
                FeatureKind::Plane => false,
            };
            if one {
                taken[i] = true;
                taken[j] = true;
                pairs.push(if a.times_seen >= b.times_seen {
                    (i, j)
                } else {
                    (j, i)
                });
            }
        }
    }
    pairs
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pings::tests::reading;
    use sonar_common::ipc::Reading;
    use std::f64::consts::{FRAC_PI_2, FRAC_PI_4};

    /// Readings of one sweep from -45° to 45° (pings -47.25° … 47.25°) in `direction`, each ping
    /// hearing `range_at(bearing)` (0 = nothing).
    fn sweep_readings(direction: i8, range_at: impl Fn(f64) -> f64) -> Vec<Reading> {
        let mut centres: Vec<f32> = (0..16).map(|k| -45.0 + 6.0 * k as f32).collect();
        if direction < 0 {
            centres.reverse();
        }
        centres
            .into_iter()
            .map(|c| {
                let offsets = [-2.25, -0.75, 0.75, 2.25];
                let ranges: Vec<f64> = offsets
                    .iter()
                    .map(|o| range_at(f64::from(c) + f64::from(direction) * o))
                    .collect();
                reading(c, direction, &ranges)
            })
            .collect()
    }

    /// A post at `bearing` heard within ±13.4° at 0.975 m (its near face), and a wall 2 m away
    /// facing the sensor, within its cut-off.
    fn post_scene(bearing: f64) -> impl Fn(f64) -> f64 {
        move |b: f64| {
            if (b - bearing).abs() <= 13.4 {
                0.975
            } else if b.abs() <= 28.0 {
                2.0
            } else {
                0.0
            }
        }
    }

    fn map() -> FeatureMap {
        FeatureMap::new(FeatureConfig::default()).unwrap()
    }

    fn update(m: &mut FeatureMap, readings: &[Reading]) -> SweepReport {
        let sweep = Sweep::from_readings(readings, m.config());
        m.update(&sweep, &Isometry2::identity())
    }

    fn of_kind(m: &FeatureMap, kind: FeatureKind) -> Vec<&Feature> {
        m.tracked().iter().filter(|f| f.kind() == kind).collect()
    }

    /// Driving along x at 5 cm per reading past a wall `distance_m` to the left while the head
    /// turns from 45° to 135°: every ping within the cut-off of the wall's normal hears it, each
    /// from its own place.
    fn passing_a_wall(distance_m: f64) -> Vec<(Reading, Isometry2<f64>)> {
        (0..16)
            .map(|k| {
                let centre = 45.0 + 6.0 * k as f32;
                let ranges: Vec<f64> = [-2.25, -0.75, 0.75, 2.25]
                    .iter()
                    .map(|o| {
                        let axis = f64::from(centre) + o;
                        if (axis - 90.0).abs() <= 28.0 {
                            distance_m
                        } else {
                            0.0
                        }
                    })
                    .collect();
                let pose = Isometry2::translation(0.05 * f64::from(k), 0.0);
                (reading(centre, 1, &ranges), pose)
            })
            .collect()
    }

    #[test]
    fn a_wall_close_abeam_on_the_move_is_a_wall_only_when_asked() {
        // At 0.45 m a wall's region is as wide as a post's cone: a point to the classifier.
        let readings = passing_a_wall(0.45);
        let m = map();
        let at_wall = |near_regions| -> Vec<Observation> {
            m.walls_on_the_move(&readings, near_regions)
                .into_iter()
                .filter(|o| (o.range_m - 0.45).abs() < 0.01)
                .collect()
        };
        assert!(at_wall(NearRegions::LeftOut).is_empty());
        let walls = at_wall(NearRegions::AsWalls);
        assert_eq!(walls.len(), 1, "{walls:?}");
        let wall = &walls[0];
        assert_eq!(wall.kind, FeatureKind::Plane);
        assert!(!wall.also_plane && wall.whole, "{wall:?}");
        assert!((wall.bearing_deg - 90.0).abs() < 1.0, "{wall:?}");
    }

    #[test]
    fn a_wall_passed_on_the_move_is_found_under_its_own_normal() {
        let readings = passing_a_wall(0.8);
        let m = map();
        let near = |o: &Observation| {
            o.kind == FeatureKind::Plane
                && (o.bearing_deg - 90.0).abs() < 1.0
                && (o.range_m - 0.8).abs() < 0.01
        };
        // Brought to the first pose along each ping's own axis, the wall's ranges spread by
        // centimetres from one end of its cone to the other: no wall there.
        let (_, along_axes) = m.observe(&Sweep::from_readings_at(
            readings.iter().map(|(r, p)| (r, *p)),
            m.config(),
        ));
        assert!(!along_axes.observations.iter().any(near), "{along_axes:?}");
        // Under the wall's own normal the ranges are one again.
        let walls = m.walls_on_the_move(&readings, NearRegions::LeftOut);
        assert_eq!(walls.iter().filter(|o| near(o)).count(), 1, "{walls:?}");
    }

    #[test]
    fn a_wall_seen_while_turning_is_placed_from_each_pings_own_heading() {
        // Turning in place at 45°/s while the head turns the other way: a reading's pings span
        // 8.1° of the robot's heading. The wall 1 m ahead of the reference is found square on
        // and whole. (With every ping at its reading's pose, each reading's pings land up to
        // 8.1° from where they were aimed, and no wall is found there at all.)
        let (readings, _) = crate::pings::tests::turning_in_place();
        let walls = map().walls_on_the_move(&readings, NearRegions::LeftOut);
        let wall = walls
            .iter()
            .find(|o| o.kind == FeatureKind::Plane && (o.range_m - 1.0).abs() < 0.01)
            .unwrap_or_else(|| panic!("{walls:?}"));
        assert!(wall.whole, "{wall:?}");
        assert!(wall.bearing_deg.abs() < 1.0, "{wall:?}");
        assert!(
            walls
                .iter()
                .all(|o| o == wall || (o.range_m - 1.0).abs() >= 0.01),
            "one wall, once: {walls:?}"
        );
    }

    #[test]
    fn a_wall_seen_while_turning_with_the_head_is_found_whole() {
        // Turning counter-clockwise at 45°/s with the head: the pings go 4.2° apart, more than
        // the head's step. A wall 1 m from the reference is found whole and square on, once:
        // ahead of it (the turn from −100° to 94°), and behind it while the turn crosses ±180°
        // of the reference's heading (from 100° to 294°).
        for (start, wall_deg) in [(-100.0, 0.0), (100.0, 180.0)] {
            let (readings, _) = crate::pings::tests::turning_in_place_at(45.0, start, wall_deg);
            let walls = map().walls_on_the_move(&readings, NearRegions::LeftOut);
            let at_wall: Vec<&Observation> = walls
                .iter()
                .filter(|o| (o.range_m - 1.0).abs() < 0.01)
                .collect();
            assert_eq!(at_wall.len(), 1, "start {start}: {walls:?}");
            let wall = at_wall[0];
            assert!(wall.kind == FeatureKind::Plane && wall.whole, "{wall:?}");
            assert!(
                crate::geometry::wrap_deg(wall.bearing_deg - wall_deg).abs() < 2.0,
                "start {start}: {wall:?}"
            );
        }
    }

    #[test]
    fn a_post_whose_bearing_jitters_from_sweep_to_sweep_is_one_feature_averaged() {
        // A post near the limit of its range, 1 m ahead: the amplitude jitter moves its
        // region's edges, so each sweep's bearing lies anywhere within a few degrees.
        let bearings = [-3.0, 3.5, -1.5, 2.0, 0.5, -2.5, 3.0, 1.0];
        let merged = |random_deg: f64| {
            let mut m = map();
            for b in bearings {
                m.merge(
                    &[point_sighting(1.0, b, random_deg)],
                    &Sweep::default(),
                    &Isometry2::identity(),
                    &Matrix3::zeros(),
                );
            }
            m
        };
        let m = merged(2.5);
        let points = of_kind(&m, FeatureKind::Point);
        assert_eq!(points.len(), 1);
        let mean_deg = bearings.iter().sum::<f64>() / bearings.len() as f64;
        let p = points[0].position();
        assert!((p.y.atan2(p.x).to_degrees() - mean_deg).abs() < 0.5, "{p}");
        assert_eq!(points[0].times_seen(), bearings.len() as u32);
        // Taken for the step's error alone, repeated in every sweep, the sightings disagree.
        assert!(of_kind(&merged(0.0), FeatureKind::Point).len() > 1);
    }

    #[test]
    fn two_pieces_of_one_faint_posts_region_in_one_sweep_are_one_post() {
        // The amplitude jitter broke the post's region in two: two points 7° apart at 1 m from
        // one sweep, each bearing known to ±3° from sweep to sweep.
        let points = |random_deg: f64| {
            let mut m = map();
            m.merge(
                &[
                    point_sighting(1.0, -3.0, random_deg),
                    point_sighting(1.0, 4.0, random_deg),
                ],
                &Sweep::default(),
                &Isometry2::identity(),
                &Matrix3::zeros(),
            );
            of_kind(&m, FeatureKind::Point).len()
        };
        assert_eq!(points(3.0), 1);
        // Bearings known to a fraction of a step: two posts 12 cm apart.
        assert_eq!(points(0.0), 2);
    }

    /// The two points one place split a region into, `range_m` away about `centre_deg` (in the
    /// sensor's frame), a half-cone of `half_deg` in from the region's ends.
    fn split_in_two(range_m: f64, centre_deg: f64, half_deg: f64) -> [Observation; 2] {
        [-1.0, 1.0].map(|side| Observation {
            pair_centre_deg: Some(centre_deg),
            ..point_sighting(range_m, centre_deg + side * half_deg, 0.0)
        })
    }

    /// A point seen whole `range_m` away at `bearing_deg`, its bearing known to 0.3° from the
    /// step and to `random_deg` from sweep to sweep.
    fn point_sighting(range_m: f64, bearing_deg: f64, random_deg: f64) -> Observation {
        Observation {
            kind: FeatureKind::Point,
            range_m,
            bearing_deg,
            range_sigma_random_m: 0.002,
            range_sigma_systematic_m: 0.002,
            bearing_sigma_deg: 0.3,
            bearing_sigma_random_deg: random_deg,
            rcd: 0,
            whole: true,
            also_plane: false,
            also_corner: false,
            pair_centre_deg: None,
        }
    }

    #[test]
    fn a_thick_post_split_in_two_from_two_places_is_one_post_and_two_posts_stay_two() {
        let merge = |m: &mut FeatureMap, obs: &[Observation], pose: Isometry2<f64>| {
            m.merge(obs, &Sweep::default(), &pose, &Matrix3::zeros());
        };
        let from_a = Isometry2::identity();
        let from_b = Isometry2::new(Vector2::new(1.0, -1.0), FRAC_PI_2);
        // A 10 cm post at (1, 0): its near face 0.95 m from either place, its region split
        // into two points 6° to either side of the line of sight, across that line.
        let mut m = map();
        merge(&mut m, &split_in_two(0.95, 0.0, 6.0), from_a);
        assert_eq!(
            of_kind(&m, FeatureKind::Point).len(),
            2,
            "one place: two points"
        );
        merge(&mut m, &split_in_two(0.95, 0.0, 6.0), from_b);
        let posts = of_kind(&m, FeatureKind::Point);
        assert_eq!(posts.len(), 1, "{posts:?}");
        let p = posts[0].position();
        assert!((p - Point2::new(0.975, -0.025)).norm() < 0.01, "{p}");
        assert!(!posts[0].one_place && posts[0].times_seen() == 4);
        // Its σ covers the post's radius: the midpoint is up to that from either near face.
        assert!(
            posts[0].covariance().trace().sqrt() >= 0.05,
            "{:?}",
            posts[0]
        );

        // Two 5 cm posts at (1, ±0.1): from (2, 0) facing back, the same two points.
        let mut m = map();
        let split = (0.1f64).atan().to_degrees();
        merge(&mut m, &split_in_two(1.0, 0.0, split), from_a);
        let from_c = Isometry2::new(Vector2::new(2.0, 0.0), std::f64::consts::PI);
        merge(&mut m, &split_in_two(1.0, 0.0, split), from_c);
        let posts = of_kind(&m, FeatureKind::Point);
        assert_eq!(posts.len(), 2, "{posts:?}");
        assert!(posts.iter().all(|p| !p.one_place));
    }

    #[test]
    fn a_thick_post_split_in_two_from_one_place_and_heard_whole_from_another_is_one_post() {
        let merge = |m: &mut FeatureMap, obs: &[Observation], pose: Isometry2<f64>| {
            m.merge(obs, &Sweep::default(), &pose, &Matrix3::zeros());
        };
        // A 10 cm post at (1, 0), heard wide from the origin and split in two 9° to either side
        // (near face at 0.95 m), heard whole from (1, -1) facing it (near face 0.95 m away, at
        // (1, -0.05)), 12 cm from either point of the pair.
        let from_b = Isometry2::new(Vector2::new(1.0, -1.0), FRAC_PI_2);
        let mut m = map();
        merge(&mut m, &split_in_two(0.95, 0.0, 9.0), Isometry2::identity());
        merge(&mut m, &[point_sighting(0.95, 0.0, 0.0)], from_b);
        let posts = of_kind(&m, FeatureKind::Point);
        assert_eq!(posts.len(), 1, "{posts:?}");
        let p = posts[0].position();
        assert!((p - Point2::new(0.975, -0.025)).norm() < 0.01, "{p}");
        assert!(!posts[0].one_place && posts[0].times_seen() == 3);
        // Heard whole 20 cm off the pair's centre: another post, the pair stays.
        let mut m = map();
        merge(&mut m, &split_in_two(0.95, 0.0, 9.0), Isometry2::identity());
        merge(
            &mut m,
            &[point_sighting(0.95, 0.0, 0.0)],
            Isometry2::new(Vector2::new(1.2, -1.0), FRAC_PI_2),
        );
        assert_eq!(of_kind(&m, FeatureKind::Point).len(), 3);
    }

    #[test]
    fn a_post_seen_in_both_directions_is_one_feature_refined() {
        let mut m = map();
        let truth = Point2::new(
            0.975 * 2f64.to_radians().cos(),
            0.975 * 2f64.to_radians().sin(),
        );
        let first = update(&mut m, &sweep_readings(1, post_scene(2.0)));
        assert_eq!((first.added, first.refined), (2, 0), "{first:?}");
        for k in 0..5 {
            let dir = if k % 2 == 0 { -1 } else { 1 };
            let r = update(&mut m, &sweep_readings(dir, post_scene(2.0)));
            assert_eq!((r.added, r.refined, r.missed), (0, 2, 0), "{r:?}");
        }
        let posts = of_kind(&m, FeatureKind::Point);
        assert_eq!(posts.len(), 1);
        let p = posts[0];
        assert_eq!(p.times_seen(), 6);
        assert!(p.one_place, "six sweeps from one place");
        assert!(p.confidence() > 0.95);
        let err = (p.position() - truth).norm();
        assert!(err < 0.015, "{err}");
        // The bearing's quantisation repeats in every sweep: the reported uncertainty does not
        // shrink below one sweep's.
        let sigma_across = (p.covariance().trace()).sqrt();
        assert!(sigma_across > 0.003, "{sigma_across}");
        let walls = of_kind(&m, FeatureKind::Plane);
        assert_eq!(walls.len(), 1);
        assert!((walls[0].distance_m().unwrap() - 2.0).abs() < 0.003);
        assert!(walls[0].normal_deg().unwrap().abs() < 0.8);
    }

    #[test]
    fn a_post_that_is_taken_away_fades_and_is_removed() {
        let mut m = map();
        for _ in 0..3 {
            update(&mut m, &sweep_readings(1, post_scene(0.0)));
        }
        let id = of_kind(&m, FeatureKind::Point)[0].id();
        // Now the pings at the post's bearing hear the wall behind.
        let empty = |b: f64| if b.abs() <= 28.0 { 2.0 } else { 0.0 };
        let mut confidences = Vec::new();
        let mut removed = false;
        for _ in 0..8 {
            let r = update(&mut m, &sweep_readings(-1, empty));
            match m.tracked().iter().find(|f| f.id() == id) {
                Some(f) => {
                    assert_eq!(r.missed, 1);
                    confidences.push(f.confidence());
                }
                None => {
                    removed = true;
                    break;
                }
            }
        }
        assert!(removed, "{confidences:?}");
        assert!(confidences.windows(2).all(|w| w[1] < w[0]));
        // The wall stays.
        assert_eq!(of_kind(&m, FeatureKind::Plane).len(), 1);
    }

    #[test]
    fn a_hidden_feature_does_not_fade_and_one_outside_the_sweep_neither() {
        let mut m = map();
        update(&mut m, &sweep_readings(1, post_scene(0.0)));
        // Something nearer stands in front of the post: no evidence against it.
        let nearer = |b: f64| if b.abs() <= 20.0 { 0.5043 } else { 0.0 };
        let r = update(&mut m, &sweep_readings(1, nearer));
        assert_eq!(r.missed, 0);
        // A sweep elsewhere says nothing about it.
        let elsewhere = Sweep::from_pings(
            vec![crate::pings::Ping {
                bearing_deg: 90.0,
                range_m: None,
            }],
            1.5,
        )
        .unwrap();
        let r = m.update(&elsewhere, &Isometry2::identity());
        assert_eq!(r.missed, 0);
    }

    #[test]
    fn features_are_placed_with_the_pose() {
        let mut m = map();
        // The sensor stands at (1, 2) turned 90°: its 0° looks along the map's +y.
        let pose = Isometry2::new(Vector2::new(1.0, 2.0), std::f64::consts::FRAC_PI_2);
        let sweep = Sweep::from_readings(&sweep_readings(1, post_scene(0.0)), m.config());
        m.update(&sweep, &pose);
        let post = of_kind(&m, FeatureKind::Point)[0];
        assert!((post.position() - Point2::new(1.0, 2.975)).norm() < 0.015);
        let wall = of_kind(&m, FeatureKind::Plane)[0];
        assert!((wall.normal_deg().unwrap() - 90.0).abs() < 0.8);
        assert!((wall.distance_m().unwrap() - 4.0).abs() < 0.003);
        // The same wall seen from the far side of the origin: a negative distance turns the normal
        // round, and the feet extend along the line.
        let pose = Isometry2::new(Vector2::new(-0.5, 2.0), std::f64::consts::FRAC_PI_2);
        let sweep = Sweep::from_readings(&sweep_readings(1, post_scene(0.0)), m.config());
        let r = m.update(&sweep, &pose);
        assert_eq!(r.refined, 1, "the wall (the post moved with the sensor)");
        let wall = of_kind(&m, FeatureKind::Plane)[0];
        let (a, b) = wall.feet();
        assert!((b - a - 1.5).abs() < 1e-6, "{a} {b}");
    }

    #[test]
    fn a_post_seen_once_and_not_again_where_something_is_heard_is_removed() {
        // The second sweep hears a wall at the post's range: no post there after all.
        let wall_at_post = |b: f64| if b.abs() <= 28.0 { 0.975 } else { 0.0 };
        let mut m = map();
        update(&mut m, &sweep_readings(1, post_scene(0.0)));
        assert_eq!(of_kind(&m, FeatureKind::Point).len(), 1);
        update(&mut m, &sweep_readings(-1, wall_at_post));
        assert!(
            of_kind(&m, FeatureKind::Point).is_empty(),
            "{:?}",
            m.tracked()
        );
        // Seen twice, it stays.
        let mut m = map();
        update(&mut m, &sweep_readings(1, post_scene(0.0)));
        update(&mut m, &sweep_readings(-1, post_scene(0.0)));
        update(&mut m, &sweep_readings(1, wall_at_post));
        assert_eq!(of_kind(&m, FeatureKind::Point).len(), 1);
    }

    #[test]
    fn one_post_seen_from_two_places_is_one_feature() {
        let mut m = map();
        update(&mut m, &sweep_readings(1, post_scene(0.0)));
        update(&mut m, &sweep_readings(-1, post_scene(0.0)));
        // From 1 m to the right, turned to face it: its echo point 6 cm from the first one's.
        let pose = Isometry2::new(Vector2::new(1.03, -1.0), std::f64::consts::FRAC_PI_2);
        let sweep = Sweep::from_readings(&sweep_readings(1, post_scene(0.0)), m.config());
        let r = m.update(&sweep, &pose);
        assert_eq!((r.added, r.merged), (2, 1), "{r:?}");
        let posts = of_kind(&m, FeatureKind::Point);
        assert_eq!(posts.len(), 1, "{posts:?}");
        assert_eq!(posts[0].times_seen(), 3);
        assert!(!posts[0].one_place, "seen from two places");
        assert!(posts[0].confirmed());
        // Two points 8 cm apart seen along rays 5° apart (two posts from one place) stay two;
        // 4 cm apart they are one target heard as two points.
        let cfg = MergeConfig::default();
        let a = feature(1, FeatureKind::Point, Vector2::new(1.0, 0.0), 0.0);
        let b = feature(2, FeatureKind::Point, Vector2::new(1.0, 0.08), 5.0);
        assert!(same_targets(&[a.clone(), b.clone()], &cfg).is_empty());
        let near = feature(2, FeatureKind::Point, Vector2::new(1.0, 0.04), 2.0);
        assert_eq!(same_targets(&[a.clone(), near], &cfg), vec![(0, 1)]);
        let b = feature(2, FeatureKind::Point, Vector2::new(1.0, 0.08), 90.0);
        assert_eq!(same_targets(&[a.clone(), b], &cfg), vec![(0, 1)]);
        // Two corners 3 cm apart are one; 8 cm apart, two; a corner and a point are two targets.
        let c = |id, x| feature(id, FeatureKind::Corner, Vector2::new(x, 0.0), 1.0);
        assert_eq!(same_targets(&[c(1, 1.0), c(2, 1.03)], &cfg), vec![(0, 1)]);
        assert!(same_targets(&[c(1, 1.0), c(2, 1.08)], &cfg).is_empty());
        assert!(same_targets(&[a, c(2, 1.03)], &cfg).is_empty());
    }

    #[test]
    fn a_point_as_wide_as_a_wall_heard_from_one_place_is_published_once_another_place_hears_it() {
        // A post 40 cm ahead (its centre at (0.425, 0)) fills ±28°, as a wall's foot there would:
        // from one place a post or a wall.
        let near_post = |b: f64| if b.abs() <= 28.0 { 0.4 } else { 0.0 };
        let mut m = map();
        update(&mut m, &sweep_readings(1, near_post));
        update(&mut m, &sweep_readings(-1, near_post));
        let points = of_kind(&m, FeatureKind::Point);
        assert_eq!(points.len(), 1, "{:?}", m.tracked());
        assert!(points[0].may_be_a_wall() && points[0].times_seen() == 2);
        assert_eq!(m.features().count(), 0, "withheld: {:?}", m.tracked());
        // From 42.5 cm to the side, turned to face it: the same near face, so a post.
        let pose = Isometry2::new(Vector2::new(0.425, -0.425), FRAC_PI_2);
        let sweep = Sweep::from_readings(&sweep_readings(1, near_post), m.config());
        m.update(&sweep, &pose);
        let published: Vec<&Feature> = m.features().collect();
        assert_eq!(published.len(), 1, "{:?}", m.tracked());
        assert!(published[0].kind() == FeatureKind::Point && published[0].confirmed());
    }

    #[test]
    fn a_post_seen_from_one_place_and_missed_from_nearer_elsewhere_is_removed() {
        let seen_twice = || {
            let mut m = map();
            update(&mut m, &sweep_readings(1, post_scene(0.0)));
            update(&mut m, &sweep_readings(-1, post_scene(0.0)));
            assert_eq!(of_kind(&m, FeatureKind::Point).len(), 1);
            m
        };
        let nothing = Sweep::from_readings(&sweep_readings(1, |_| 0.0), &FeatureConfig::default());
        let posts_after = |pose: Isometry2<f64>| {
            let mut m = seen_twice();
            m.update(&nothing, &pose);
            of_kind(&m, FeatureKind::Point)
                .iter()
                .map(|f| f.confidence())
                .collect::<Vec<_>>()
        };
        // From 0.42 m nearer, off to the side (the post 24° to the right): its ping heard
        // nothing, so the post is not there.
        assert!(
            posts_after(Isometry2::translation(0.3, 0.3)).is_empty(),
            "refuted from elsewhere"
        );
        // From the same place the miss only fades it: that view may just have missed it.
        let same_place = posts_after(Isometry2::identity());
        assert_eq!(same_place.len(), 1);
        assert!(same_place[0] < 0.75, "{same_place:?}");
        // From farther away a post may be too weak to hear: a miss fades it too.
        assert_eq!(posts_after(Isometry2::translation(-0.5, 0.0)).len(), 1);
    }

    #[test]
    fn a_post_heard_from_one_place_where_two_pings_from_nearer_heard_past_it_is_removed() {
        // Sweeps from (0.3, 0), 0.3 m nearer the post the origin then hears at (0.975, 0), each
        // hearing `there` on every ping; then the origin's sweep: the posts left.
        let posts_after = |sweeps: &[&dyn Fn(f64) -> f64], from: Isometry2<f64>| {
            let mut m = map();
            for (k, there) in sweeps.iter().enumerate() {
                let direction = if k % 2 == 0 { 1 } else { -1 };
                let sweep = Sweep::from_readings(&sweep_readings(direction, there), m.config());
                m.update(&sweep, &from);
            }
            update(&mut m, &sweep_readings(1, post_scene(0.0)));
            of_kind(&m, FeatureKind::Point).len()
        };
        let nearer = Isometry2::translation(0.3, 0.0);
        let nothing = |_: f64| 0.0;
        // Two pings from nearer heard nothing where it stands: the one place is outweighed.
        assert_eq!(posts_after(&[&nothing, &nothing], nearer), 0);
        // One such ping may have lost a weak post's echo.
        assert_eq!(posts_after(&[&nothing], nearer), 1);
        // Something heard at its range from there (a wall across the ray): the post may have
        // been in that region; no evidence against it.
        let something = |b: f64| if b.abs() <= 28.0 { 0.675 } else { 0.0 };
        assert_eq!(posts_after(&[&nothing, &something, &nothing], nearer), 1);
        // From farther away a post may be too weak to hear.
        let farther = Isometry2::translation(-0.5, 0.0);
        assert_eq!(posts_after(&[&nothing, &nothing], farther), 1);
        // From the same place the misses are the one view's.
        assert_eq!(posts_after(&[&nothing, &nothing], Isometry2::identity()), 1);
    }

    #[test]
    fn a_point_from_one_place_inside_a_confirmed_wall_is_that_wall() {
        // A wall along y = 2 (normal 90°, 2 m from the origin) heard along its normal from x = -1
        // to x = 1, from two places.
        let mut wall = feature(1, FeatureKind::Plane, Vector2::new(FRAC_PI_2, 2.0), 90.0);
        wall.feet = (-1.0, 1.0);
        wall.one_place = false;
        let point = |x: f64, y: f64| feature(2, FeatureKind::Point, Vector2::new(x, y), 80.0);
        let on_walls = |p: Feature, w: &Feature| points_on_confirmed_walls(&[w.clone(), p]);
        // On its line inside the stretch: the wall's echo taken for a post.
        assert_eq!(on_walls(point(0.3, 2.001), &wall), vec![2]);
        // A post standing 2 cm out of the line (1 mm estimates): a post.
        assert!(on_walls(point(0.3, 1.98), &wall).is_empty());
        // Past the stretch's end (where the wall may end): a wall's end.
        assert!(on_walls(point(1.05, 2.0), &wall).is_empty());
        // The point heard from two places: confirmed on its own.
        let mut confirmed = point(0.3, 2.0);
        confirmed.one_place = false;
        assert!(on_walls(confirmed, &wall).is_empty());
        // The wall heard from one place only: it may be a corner's echo itself.
        let mut tentative = wall.clone();
        tentative.one_place = true;
        assert!(on_walls(point(0.3, 2.0), &tentative).is_empty());
    }

    /// A corner from one place on a wall heard from two, inside the stretch where that wall was
    /// heard, with no other wall through it: a piece of the wall taken for a corner. A T's corner
    /// (another wall through it) stays.
    #[test]
    fn a_corner_from_one_place_inside_a_confirmed_wall_with_no_wall_through_it_is_that_wall() {
        let mut wall = feature(1, FeatureKind::Plane, Vector2::new(FRAC_PI_2, 2.0), 90.0);
        wall.feet = (-1.0, 1.0);
        wall.one_place = false;
        let corner = |x: f64| feature(2, FeatureKind::Corner, Vector2::new(x, 2.001), 70.0);
        let removed = |fs: &[Feature]| corners_on_confirmed_walls(fs);
        assert_eq!(removed(&[wall.clone(), corner(0.3)]), vec![2]);
        // Past the stretch heard: where the wall may meet another.
        assert!(removed(&[wall.clone(), corner(1.2)]).is_empty());
        // A T: a wall along x = 0.3 ends on it there.
        let through = feature(3, FeatureKind::Plane, Vector2::new(0.0, 0.3), 0.0);
        assert!(removed(&[wall.clone(), corner(0.3), through]).is_empty());
        // Heard from two places: a corner in its own right.
        let mut confirmed = corner(0.3);
        confirmed.one_place = false;
        assert!(removed(&[wall.clone(), confirmed]).is_empty());
        // The wall heard from one place only.
        let mut tentative = wall.clone();
        tentative.one_place = true;
        assert!(removed(&[tentative, corner(0.3)]).is_empty());
    }

    /// A point where two walls meet in a concave corner is that corner (a faint corner, heard over
    /// fewer pings than its cone); not at a box's outer edge, not on two walls only one place
    /// heard, not off either line.
    #[test]
    fn a_point_where_two_walls_meet_in_a_concave_corner_is_that_corner() {
        // A room's corner at (1, 2): a wall along y = 2 running to x < 1, and one along x = 1
        // running to y < 2, both heard from the origin (inside).
        let mut top = feature(1, FeatureKind::Plane, Vector2::new(FRAC_PI_2, 2.0), 90.0);
        top.feet = (-0.5, 0.5);
        let mut side = feature(2, FeatureKind::Plane, Vector2::new(0.0, 1.0), 0.0);
        side.feet = (0.5, 1.5);
        side.one_place = false;
        let point = |x: f64, y: f64| feature(3, FeatureKind::Point, Vector2::new(x, y), 60.0);
        let at =
            |p: Feature, a: &Feature, b: &Feature| points_at_corners(&[a.clone(), b.clone(), p]);
        assert_eq!(at(point(0.999, 1.999), &top, &side), vec![3]);
        // 10 cm off the side wall's line: a post near the corner.
        assert!(at(point(0.9, 1.999), &top, &side).is_empty());
        // Neither wall heard from two places: two phantoms may cross anywhere.
        let mut tentative = side.clone();
        tentative.one_place = true;
        assert!(at(point(0.999, 1.999), &top, &tentative).is_empty());
        // A box's outer edge: the same two lines heard from outside (above and to the right),
        // each face running away from the other's front: a point there is the edge.
        let mut above = top.clone();
        above.seen_from = Vector2::new(0.0, 3.0);
        let mut right = side.clone();
        right.seen_from = Vector2::new(2.0, 1.0);
        assert!(at(point(1.0, 2.0), &above, &right).is_empty());
    }

    /// A point whose region was as wide as a wall's there (near the sensor, where one place
    /// cannot tell a post from a wall) on the line of a wall heard from elsewhere is that wall,
    /// wherever along the line: the wall need not be confirmed, nor its feet reach the point
    /// (a board heard square from afar and near from its end).
    #[test]
    fn a_point_that_may_be_a_wall_on_a_wall_heard_elsewhere_is_that_wall() {
        let mut wall = feature(1, FeatureKind::Plane, Vector2::new(FRAC_PI_2, 2.0), 90.0);
        wall.feet = (-1.0, -0.8);
        wall.seen_from = Vector2::new(-0.9, 0.0);
        let mut near = feature(2, FeatureKind::Point, Vector2::new(0.6, 2.001), 80.0);
        near.seen_from = Vector2::new(0.6, 1.5);
        near.may_be_plane = true;
        let on_walls =
            |p: &Feature, w: &Feature| points_on_confirmed_walls(&[w.clone(), p.clone()]);
        assert_eq!(on_walls(&near, &wall), vec![2]);
        // Off the line by 2 cm (1 mm estimates): a post before the wall.
        let mut before = near.clone();
        before.mean.y = 1.98;
        assert!(on_walls(&before, &wall).is_empty());
        // A region only as wide as a post's: a post on the line (in a doorway) stays.
        let mut post = near.clone();
        post.may_be_plane = false;
        assert!(on_walls(&post, &wall).is_empty());
        // The wall heard from where the point was: the same region, no second opinion.
        let mut same_place = wall.clone();
        same_place.seen_from = near.seen_from;
        assert!(on_walls(&near, &same_place).is_empty());
    }

    /// A feature of `kind` at `mean` ((x, y), or (φ, d) for a plane), known to 1 mm (1 mrad), last
    /// seen along `ray_deg`.
    fn feature(id: u64, kind: FeatureKind, mean: Vector2<f64>, ray_deg: f64) -> Feature {
        let c = Matrix2::identity() * 1e-6;
        Feature {
            id,
            kind,
            mean,
            weights: c,
            random: c,
            systematic: Matrix2::zeros(),
            confidence: 0.5,
            times_seen: 2,
            first_seen: 1,
            last_seen: 2,
            ray_deg,
            feet: (0.0, 0.0),
            feet_heard: Vec::new(),
            seen_from: Vector2::zeros(),
            one_place: true,
            may_be_plane: false,
            may_be_corner: false,
            pair_centre: None,
            place_sweeps: 2,
        }
    }

    #[test]
    fn a_wall_heard_from_one_place_with_a_corner_at_its_foot_is_that_corner() {
        let cfg = FeatureConfig::default();
        // A wall 2 m ahead heard from the origin (its foot at (2, 0)), and a corner there seen
        // from elsewhere: the corner's echo taken for a wall.
        let wall = feature(1, FeatureKind::Plane, Vector2::new(0.0, 2.0), 0.0);
        let corner = |at: Vector2<f64>, ray_deg| feature(2, FeatureKind::Corner, at, ray_deg);
        let explained = |c| explained_by_corners(&[wall.clone(), c], &cfg);
        assert_eq!(explained(corner(Vector2::new(2.0, 0.04), 60.0)), vec![1]);
        // Seen along the same ray: nothing tells them apart.
        assert!(explained(corner(Vector2::new(2.0, 0.04), 1.0)).is_empty());
        // Behind the wall's line: a wall's foot near a corner.
        assert!(explained(corner(Vector2::new(2.04, 0.0), 60.0)).is_empty());
        // Two such walls heard from two places, crossing at both feet: one corner.
        let other = feature(3, FeatureKind::Plane, Vector2::new(FRAC_PI_4, 2.0), 45.0);
        let mut crossing = other.clone();
        crossing.feet = (-(2.0 * 2f64.sqrt() - 2.0), -(2.0 * 2f64.sqrt() - 2.0));
        // Foot of `other` from its own place: the point of its line nearest the map's origin
        // moved along the line to where it crosses the first wall.
        let at = crossing.normal() * 2.0 + crossing.direction().unwrap() * crossing.feet.0;
        let mut first = wall.clone();
        first.feet = (at.y, at.y);
        assert_eq!(explained_by_corners(&[first, crossing], &cfg), vec![1, 3]);
    }

    #[test]
    fn a_wall_or_corner_heard_from_one_place_on_a_post_two_places_heard_is_that_posts_echo() {
        let cfg = FeatureConfig::default();
        let mut post = feature(1, FeatureKind::Point, Vector2::new(1.0, 0.0), 0.0);
        post.one_place = false;
        // A wall 1 m ahead heard from one place with its foot at the post, and one 20 cm behind.
        let wall = |id: u64, d: f64| feature(id, FeatureKind::Plane, Vector2::new(0.0, d), 0.0);
        let corner = feature(4, FeatureKind::Corner, Vector2::new(1.05, 0.0), 0.0);
        let features = [post.clone(), wall(2, 1.0), wall(3, 1.2), corner];
        assert_eq!(explained_by_posts(&features, &cfg), vec![2, 4]);
        // A post heard from one place only explains nothing.
        let mut features = features;
        features[0].one_place = true;
        assert!(explained_by_posts(&features, &cfg).is_empty());
    }

    #[test]
    fn a_plane_whose_foot_lies_on_another_plane_is_a_corner_echo() {
        let cfg = FeatureConfig::default();
        // A wall 2 m ahead (x = 2) heard from one place with its foot at (2, 0.5), where the
        // line of a wall seen from two places (y = 0.5) meets it: the two walls' corner.
        let mut wall = feature(1, FeatureKind::Plane, Vector2::new(0.0, 2.0), 0.0);
        wall.feet = (0.5, 0.5);
        let across = |d: f64| {
            let mut f = feature(2, FeatureKind::Plane, Vector2::new(FRAC_PI_2, d), 90.0);
            f.feet = (-1.0, 0.0);
            f.one_place = false;
            f
        };
        assert_eq!(
            explained_by_corners(&[wall.clone(), across(0.5)], &cfg),
            vec![1]
        );
        // The other plane heard from one place only: it may be a corner's echo itself, or an
        // oblique junction heard along both normals.
        let mut one_place = across(0.5);
        one_place.one_place = true;
        assert!(explained_by_corners(&[wall.clone(), one_place], &cfg).is_empty());
        // The other line 10 cm from its foot: a wall of its own.
        assert!(explained_by_corners(&[wall.clone(), across(0.6)], &cfg).is_empty());
        // A plane nearly parallel through the foot is the same wall, not a corner.
        let parallel = feature(2, FeatureKind::Plane, Vector2::new(0.05, 2.0), 0.0);
        assert!(explained_by_corners(&[wall, parallel], &cfg).is_empty());
    }

    #[test]
    fn a_plane_that_may_be_a_corners_echo_is_one_on_the_line_of_a_wall_another_place_heard() {
        let cfg = FeatureConfig::default();
        // A wall 2 m ahead (x = 2) heard from the origin with its foot at (2, 0.5), and a wall
        // y = d heard from one place only, 1 m off the first.
        let mut plane = feature(1, FeatureKind::Plane, Vector2::new(0.0, 2.0), 0.0);
        plane.feet = (0.5, 0.5);
        let across = |d: f64, from: Vector2<f64>| {
            let mut f = feature(2, FeatureKind::Plane, Vector2::new(FRAC_PI_2, d), 90.0);
            f.seen_from = from;
            f
        };
        let elsewhere = Vector2::new(1.0, 0.0);
        // A region a wall's cone alone holds: the other place's guess does not tell.
        assert!(explained_by_corners(&[plane.clone(), across(0.5, elsewhere)], &cfg).is_empty());
        // One a corner's would hold as well: that wall's corner, heard from inside it.
        plane.may_be_corner = true;
        assert_eq!(
            explained_by_corners(&[plane.clone(), across(0.5, elsewhere)], &cfg),
            vec![1]
        );
        // The other wall heard from the same place: one view's guesses, no second opinion.
        let same_place = Vector2::new(0.1, 0.0);
        assert!(explained_by_corners(&[plane.clone(), across(0.5, same_place)], &cfg).is_empty());
        // The other line 8 cm from the foot: off it for a bearing known to 1 mrad, on it for one
        // known to 1° (the foot 3.6 cm along its line at 2 m).
        assert!(explained_by_corners(&[plane.clone(), across(0.58, elsewhere)], &cfg).is_empty());
        plane.random[(0, 0)] = 1f64.to_radians().powi(2);
        assert_eq!(
            explained_by_corners(&[plane, across(0.58, elsewhere)], &cfg),
            vec![1]
        );
    }

    #[test]
    fn a_plane_that_may_be_a_corners_echo_with_a_corner_at_its_range_is_that_corner() {
        let cfg = FeatureConfig::default();
        // A plane 2 m ahead of the origin (x = 2, its foot at (2, 0)) heard from the origin over
        // a region a corner's echo fills as well.
        let mut plane = feature(1, FeatureKind::Plane, Vector2::new(0.0, 2.0), 0.0);
        plane.may_be_corner = true;
        // A corner heard from two places, first along another ray, `dist` from the origin at
        // `deg` off the plane's normal.
        let corner = |deg: f64, dist: f64, one_place: bool| {
            let (s, c) = deg.to_radians().sin_cos();
            let mut f = feature(2, FeatureKind::Corner, Vector2::new(c, s) * dist, 60.0);
            f.one_place = one_place;
            f
        };
        // At the plane's range 12° off its normal (42 cm along its line from its foot): the
        // plane was that corner's echo.
        assert_eq!(
            explained_by_corners(&[plane.clone(), corner(12.0, 2.0, false)], &cfg),
            vec![1]
        );
        // On the plane's line 12° off, as a true wall's own corner beyond its foot: 2/cos 12° =
        // 2.045 m away, farther than the plane.
        let on_the_line = 2.0 / 12f64.to_radians().cos();
        assert!(
            explained_by_corners(&[plane.clone(), corner(12.0, on_the_line, false)], &cfg)
                .is_empty()
        );
        // Outside the beam (±30°), or heard from one place only: no.
        assert!(explained_by_corners(&[plane.clone(), corner(35.0, 2.0, false)], &cfg).is_empty());
        assert!(explained_by_corners(&[plane.clone(), corner(12.0, 2.0, true)], &cfg).is_empty());
        // A plane over a region a wall's cone alone holds: kept.
        plane.may_be_corner = false;
        assert!(explained_by_corners(&[plane, corner(12.0, 2.0, false)], &cfg).is_empty());
    }

    #[test]
    fn a_target_one_place_heard_behind_where_a_wall_was_heard_is_a_double_bounce() {
        // A wall x = 1 heard from two places, one of its feet at (1, 0); targets heard from the
        // origin.
        let mut wall = feature(1, FeatureKind::Plane, Vector2::new(0.0, 1.0), 0.0);
        wall.one_place = false;
        wall.feet_heard = vec![0.0];
        let corner = |x: f64, y: f64| feature(2, FeatureKind::Corner, Vector2::new(x, y), 0.0);
        let through =
            |wall: &Feature, target: Feature| heard_through_walls(&[wall.clone(), target]);
        // A corner 2 m out, straight through the foot: its echo came round.
        assert_eq!(through(&wall, corner(2.0, 0.05)), vec![2]);
        // A post too.
        let post = feature(2, FeatureKind::Point, Vector2::new(2.0, 0.05), 0.0);
        assert_eq!(through(&wall, post), vec![2]);
        // The way crosses the line 25 cm from the foot: there may be a doorway.
        assert!(through(&wall, corner(2.0, 0.5)).is_empty());
        // 5 cm behind the line: the wall's own corner, placed a little deep.
        assert!(through(&wall, corner(1.05, 0.0)).is_empty());
        // The wall heard from one place only: it may be a corner's echo itself.
        let mut one_place = wall.clone();
        one_place.one_place = true;
        assert!(through(&one_place, corner(2.0, 0.05)).is_empty());
        // A corner two places heard stays whatever a wall says.
        let mut confirmed = corner(2.0, 0.05);
        confirmed.one_place = false;
        assert!(through(&wall, confirmed).is_empty());
    }

    #[test]
    fn a_plane_keeps_one_foot_for_each_stretch_it_was_heard_on() {
        let mut wall = feature(1, FeatureKind::Plane, Vector2::new(0.0, 1.0), 0.0);
        for foot in [0.0, 0.04, 0.5, 0.52, -0.3] {
            wall.hear_foot(foot);
        }
        assert_eq!(wall.feet_heard, vec![-0.3, 0.0, 0.5]);
        assert!(wall.foot_near(0.55, 0.1) && wall.foot_near(-0.25, 0.1));
        assert!(!wall.foot_near(0.25, 0.1) && !wall.foot_near(0.7, 0.1));
    }

    #[test]
    fn a_ping_that_heard_nothing_misses_only_what_would_have_answered_it() {
        let m = map();
        let cfg = *m.config();
        // A corner 2 m ahead of where it was heard, and sweeps that heard nothing at all.
        let corner = feature(1, FeatureKind::Corner, Vector2::new(2.0, 0.0), 0.0);
        let silent = Sweep::from_readings(&sweep_readings(1, |_| 0.0), &cfg);
        let gate = m.gate(&silent);
        let confidence_after = |x: f64| {
            let mut f = corner.clone();
            let missed = fade(
                &mut f,
                &silent,
                &Isometry2::translation(x, 0.0),
                &gate,
                &cfg,
            );
            (missed, f.confidence)
        };
        // From 1.5 m it would have answered: a miss.
        let (missed, confidence) = confidence_after(0.5);
        assert!(missed && confidence < corner.confidence);
        // From 5 m, beyond the sensor's 4 m, nothing could have answered: no evidence.
        assert_eq!(confidence_after(-3.0), (false, corner.confidence));
        // Heard past it from there, it is still a miss.
        let past = Sweep::from_readings(&sweep_readings(1, |_| 3.9), &cfg);
        let mut f = corner.clone();
        assert!(fade(
            &mut f,
            &past,
            &Isometry2::translation(1.0, 0.0),
            &gate,
            &cfg
        ));
    }

    #[test]
    fn summaries_carry_what_a_record_needs_and_what_one_sweep_of_two_heard_is_not_published() {
        let mut m = map();
        update(&mut m, &sweep_readings(1, post_scene(0.0)));
        // The only sweep of its place: published.
        assert_eq!(m.summaries(&[]).len(), 2);
        // A second sweep from there hears the wall but not the post: the post, heard by one
        // sweep of two, is a candidate, kept but not published.
        let wall_only = |b: f64| if b.abs() <= 28.0 { 2.0 } else { 0.0 };
        update(&mut m, &sweep_readings(-1, wall_only));
        assert_eq!(m.tracked().len(), 2);
        let s = m.summaries(&[]);
        assert_eq!(s.len(), 1);
        assert_eq!(s[0].kind, FeatureKind::Plane);
        // Heard again, it is published.
        update(&mut m, &sweep_readings(1, post_scene(0.0)));
        let s = m.summaries(&[]);
        assert_eq!(s.len(), 2);
        let wall = s.iter().find(|s| s.kind == FeatureKind::Plane).unwrap();
        assert!(wall.angle_sigma_deg.is_some() && wall.segment.is_some());
        let post = s.iter().find(|s| s.kind == FeatureKind::Point).unwrap();
        assert!(post.angle_sigma_deg.is_none() && post.segment.is_none());
        assert!(post.cov_xx > 0.0 && post.cov_yy > 0.0);
        assert_eq!((post.times_seen, post.last_seen), (2, 3));
        assert!(!post.confirmed, "heard from one place: tentative");
        // Clearing forgets the features; sweeps and ids go on.
        m.clear();
        assert!(m.tracked().is_empty());
        update(&mut m, &sweep_readings(1, post_scene(0.0)));
        assert_eq!(m.sweeps(), 4);
        assert!(
            m.tracked()
                .iter()
                .all(|f| f.id() > 2 && f.first_seen() == 4)
        );
    }
}
