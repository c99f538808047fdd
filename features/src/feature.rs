//! A feature of the map: its kind and its estimate (mean, covariance in two parts, confidence,
//! sightings). The map ([`crate::map`]) merges observations into it; the classification and the
//! segments read it.

use nalgebra::{Matrix2, Point2, Vector2};

/// A wall heard at a foot stands within this of it, and two feet closer than this are noted as
/// one ([`Feature::feet_heard`]).
pub(crate) const FOOT_SPACING_M: f64 = 0.10;

/// What kind of target a feature is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum FeatureKind {
    /// A post, pillar, table leg or wall edge: a small convex target.
    Point,
    /// A concave corner.
    Corner,
    /// A wall (a partial plane).
    Plane,
}

/// A feature of the map.
#[derive(Debug, Clone, PartialEq)]
pub struct Feature {
    pub(crate) id: u64,
    pub(crate) kind: FeatureKind,
    /// Point, corner: (x, y). Plane: (φ in radians, d).
    pub(crate) mean: Vector2<f64>,
    /// Covariance of the Kalman recursion, which weighs each observation.
    pub(crate) weights: Matrix2<f64>,
    /// Covariance of the part of the error that averages out.
    pub(crate) random: Matrix2<f64>,
    /// Covariance of the part that repeats from sweep to sweep (mean over the observations).
    pub(crate) systematic: Matrix2<f64>,
    pub(crate) confidence: f64,
    pub(crate) times_seen: u32,
    pub(crate) first_seen: u64,
    pub(crate) last_seen: u64,
    /// Direction of the sensor's ray to the feature at its last sighting, degrees.
    pub(crate) ray_deg: f64,
    /// Plane: where the sensor's own perpendicular met the line, along the line (coordinate along
    /// the direction 90° counter-clockwise of the normal, from the foot of the map origin's
    /// perpendicular): the extent of direct evidence.
    pub(crate) feet: (f64, f64),
    /// Plane: the feet themselves, in the coordinate of [`Self::feet`], in order, one for each
    /// stretch of [`FOOT_SPACING_M`] where a sensor's perpendicular met it: where the
    /// wall is known to stand (between two feet it may have a doorway).
    pub(crate) feet_heard: Vec<f64>,
    /// Where the sensor stood at the first sighting, in the map's frame.
    pub(crate) seen_from: Vector2<f64>,
    /// Whether every sighting was taken within [`crate::map::ONE_PLACE_M`] of
    /// [`Self::seen_from`]: the same view repeated, whose misreading repeats with it.
    pub(crate) one_place: bool,
    /// A point every sighting of which was a region as wide as a wall's would be there
    /// ([`crate::Observation::also_plane`]): one place could not tell it from a wall.
    pub(crate) may_be_plane: bool,
    /// A plane every sighting of which was a region a corner's echo would fill as well
    /// ([`crate::Observation::also_corner`]): one place could not tell it from a corner's vertex.
    pub(crate) may_be_corner: bool,
    /// A point every sighting of which was one of two points split from a region that one
    /// thicker post would fill too ([`crate::Observation::pair_centre_deg`]): where that post's
    /// near face would lie, as first seen.
    pub(crate) pair_centre: Option<Vector2<f64>>,
    /// Sweeps merged from within [`crate::map::ONE_PLACE_M`] of [`Self::seen_from`], from the
    /// remembered ones before its first sighting on: how often its place could have heard it.
    pub(crate) place_sweeps: u32,
}

impl Feature {
    /// Takes `other`'s sightings into this one's count, confidence and first and last sweeps:
    /// the two were one target.
    pub(crate) fn absorb_sightings(&mut self, other: &Feature) {
        for &foot in &other.feet_heard {
            self.hear_foot(foot);
        }
        self.times_seen += other.times_seen;
        self.place_sweeps = self.place_sweeps.max(other.place_sweeps);
        self.confidence = self.confidence.max(other.confidence);
        self.first_seen = self.first_seen.min(other.first_seen);
        self.last_seen = self.last_seen.max(other.last_seen);
    }

    /// Notes a plane's foot at `foot` (along its line), unless one within
    /// [`FOOT_SPACING_M`] is noted already.
    pub(crate) fn hear_foot(&mut self, foot: f64) {
        if !self.foot_near(foot, FOOT_SPACING_M) {
            let at = self.feet_heard.partition_point(|&f| f < foot);
            self.feet_heard.insert(at, foot);
        }
    }

    /// Whether a plane was heard at a foot within `within` of `along` (along its line).
    pub(crate) fn foot_near(&self, along: f64, within: f64) -> bool {
        let at = self.feet_heard.partition_point(|&f| f < along);
        let near = |i: usize| {
            self.feet_heard
                .get(i)
                .is_some_and(|f| (f - along).abs() <= within)
        };
        near(at) || at.checked_sub(1).is_some_and(near)
    }

    pub fn id(&self) -> u64 {
        self.id
    }

    pub fn kind(&self) -> FeatureKind {
        self.kind
    }

    /// Point: the echo point (the target's surface nearest the sensor). Corner: the vertex.
    /// Plane: the foot of the perpendicular from the map's origin.
    pub fn position(&self) -> Point2<f64> {
        match self.kind {
            FeatureKind::Plane => Point2::from(self.normal() * self.mean.y),
            FeatureKind::Point | FeatureKind::Corner => Point2::from(self.mean),
        }
    }

    /// The estimate in its own coordinates: (x, y), or (φ, d) for a plane.
    pub(crate) fn mean_own(&self) -> Vector2<f64> {
        self.mean
    }

    /// Reported covariance of the estimate in its own coordinates: (x, y), or (φ, d) for a plane.
    pub(crate) fn covariance_own(&self) -> Matrix2<f64> {
        self.random + self.systematic
    }

    /// Covariance of [`Feature::position`], m².
    pub fn covariance(&self) -> Matrix2<f64> {
        let p = self.covariance_own();
        match self.kind {
            FeatureKind::Point | FeatureKind::Corner => p,
            FeatureKind::Plane => {
                // foot = d·n(φ): ∂/∂φ = d·n'(φ), ∂/∂d = n(φ).
                let n = self.normal();
                let j = Matrix2::new(-n.y * self.mean.y, n.x, n.x * self.mean.y, n.y);
                j * p * j.transpose()
            }
        }
    }

    /// Unit normal of a plane (meaningless for other kinds).
    pub(crate) fn normal(&self) -> Vector2<f64> {
        Vector2::new(self.mean.x.cos(), self.mean.x.sin())
    }

    /// Plane: direction of its normal from the map's origin towards the wall, degrees.
    pub fn normal_deg(&self) -> Option<f64> {
        (self.kind == FeatureKind::Plane).then(|| self.mean.x.to_degrees())
    }

    /// Plane: σ of the normal's direction, degrees.
    pub fn normal_sigma_deg(&self) -> Option<f64> {
        (self.kind == FeatureKind::Plane).then(|| self.covariance_own()[(0, 0)].sqrt().to_degrees())
    }

    /// Plane: perpendicular distance from the map's origin, metres.
    pub fn distance_m(&self) -> Option<f64> {
        (self.kind == FeatureKind::Plane).then_some(self.mean.y)
    }

    /// Plane: σ of that distance, metres.
    pub fn distance_sigma_m(&self) -> Option<f64> {
        (self.kind == FeatureKind::Plane).then(|| self.covariance_own()[(1, 1)].sqrt())
    }

    /// Plane: direction along its line (the normal turned 90° counter-clockwise).
    pub(crate) fn direction(&self) -> Option<Vector2<f64>> {
        (self.kind == FeatureKind::Plane).then(|| {
            let n = self.normal();
            Vector2::new(-n.y, n.x)
        })
    }

    /// Plane: the extent along its line over which the sensor's perpendiculars met it.
    pub(crate) fn feet(&self) -> (f64, f64) {
        self.feet
    }

    /// In [0, 1]: how well recent sweeps confirmed it.
    pub fn confidence(&self) -> f64 {
        self.confidence
    }

    /// Sweeps that observed it.
    pub fn times_seen(&self) -> u32 {
        self.times_seen
    }

    /// Sweep numbers (from 1, counted by the map) of its first and latest sighting.
    pub fn first_seen(&self) -> u64 {
        self.first_seen
    }

    pub fn last_seen(&self) -> u64 {
        self.last_seen
    }

    /// Direction of the sensor's ray to the target at its latest sighting, degrees (for a plane,
    /// the normal as the sensor saw it).
    pub fn ray_deg(&self) -> f64 {
        self.ray_deg
    }

    /// Whether the map publishes it: two sweeps or more heard it, or its place has had one sweep
    /// only (a scan of one revolution, a robot on the move). What one sweep alone heard where
    /// another sweep from the same place did not hear it again is most often that sweep's
    /// misreading (a lost ping cutting a wall's region into a post's, a corner's echo at a
    /// sweep's end): the map keeps it as a candidate and does not publish it
    /// ([`crate::FeatureMap::features`]).
    ///
    /// Nor a point that only one place heard, over a region as wide as a wall's would be at its
    /// range ([`Self::may_be_a_wall`]): from one place a wall's foot answers so too, and a board
    /// heard square from close by was such a post in every sweep of its place. Another place
    /// tells: a post answers it at the same spot, a wall at that place's own foot.
    pub fn published(&self) -> bool {
        (self.times_seen >= 2 || self.place_sweeps < 2) && !self.may_be_a_wall()
    }

    /// A point heard from one place only, every sighting a region as wide as a wall's would be
    /// there (near the sensor a post's cone is as wide as a wall's): a post or the foot of a
    /// wall, which one viewpoint cannot tell apart (Leonard & Durrant-Whyte).
    pub fn may_be_a_wall(&self) -> bool {
        self.kind == FeatureKind::Point && self.one_place && self.may_be_plane
    }

    /// Whether it was heard from two places or more (sightings more than 20 cm apart):
    /// **confirmed**. A feature heard from one place only is
    /// **tentative**: every sighting repeats one view, and whatever that view misread (a corner's
    /// echo taken for a wall, a wall's echo for a post) they misread alike, so only another place
    /// can tell it from a true target. Most false features of a scene's map are tentative
    /// (`docs/results.md`, "Confirmed and tentative features"); so are the true ones only one
    /// place heard.
    pub fn confirmed(&self) -> bool {
        !self.one_place
    }
}
