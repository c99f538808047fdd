//! The expected widths: over which angle a reflector is heard, from the echo model's physics.
//!
//! A ping hears a reflector when the echo's level reaches the detection threshold. On the axis the
//! level exceeds the threshold by a margin that depends on the reflector and its range; off the
//! axis the round-trip beam takes 6 dB · (θ / b₆)² of it, so the reflector is heard within the
//! **effective cone** θ ≤ b₆ · √(margin / 6 dB), never beyond the beam's half-angle, and a flat
//! wall never beyond the specular cut-off (it returns only from the foot of the perpendicular).
//! A region of constant depth is the run of pings whose axes fall inside that cone; its width is
//! the cone's full width, to within one step of the stepper.

use serde::{Deserialize, Serialize};

/// The physics of the echo, as far as the widths of regions of constant depth depend on it.
///
/// The same model as the simulator's echo model (`simulator/src/echo.rs`, `EchoParams`), with the
/// same defaults, so that the cones this crate expects are the cones the simulator produces; on a
/// real sensor, measure them (a wall, a corner and a post at a few ranges) and set these. Levels in
/// dB, 0 dB being a hard flat wall 0.5 m ahead on the axis:
///
/// ```text
/// margin(r) = spreading(reflector, r) − 2·α·r + tvg·min(r, tvg_max) − threshold   (on the axis)
/// cone half-angle = b₆ · √(margin / 6 dB)   (round-trip beam −6 dB at b₆, falling as θ²)
/// ```
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EchoPhysics {
    /// Off-axis angle where the round-trip beam is 6 dB down: 27° (sensor-facts: ≈ 55° full
    /// width at −6 dB).
    pub beam_6db_half_angle_deg: f64,
    /// Largest incidence at which a flat wall still returns (sensor-facts: a card read correctly
    /// to ≈ 25–30°; the simulator uses 28°). A wall is heard by every ping aimed within this of
    /// its normal, and by no other.
    pub specular_cutoff_deg: f64,
    /// Air absorption at 40 kHz, one way (ISO 9613-1, 20 °C, 50 % RH).
    pub absorption_db_per_m: f64,
    /// The receiver's gain ramp per metre of range (fitted in the simulator to sensor-facts'
    /// calibration points).
    pub tvg_db_per_m: f64,
    /// Range after which the gain ramp holds.
    pub tvg_max_range_m: f64,
    /// Detection threshold (fitted: a 5 cm post at 1 m is heard within ≈ ±13°).
    pub threshold_db: f64,
    /// A concave corner returns this much less than a flat wall at its range (finite aperture).
    pub corner_loss_db: f64,
    /// Radius of the reference point target, the one whose effective cone tells one target from
    /// two: 2.5 cm, the paper's small obstacles. A thicker post is heard over a wider cone and
    /// is reported as two targets (see the crate docs).
    pub point_radius_m: f64,
    /// How much less than a hard wall a flat surface may return and still be taken for a wall:
    /// 8 dB, a thin board (sensor-facts: a PING))) hears flat cardboard within ≈ 10° at 1.14 m,
    /// where its beam reaches a hard wall's specular cut-off; raise it for weaker surfaces).
    /// Where the beam, not the cut-off, bounds a wall's cone (a narrow-beam sensor, a far wall),
    /// a weaker wall is heard over a narrower run than a hard one; a region seen whole between
    /// the two widths is a plane ([`EchoPhysics::weakest_plane_cone_half_angle_deg`]). 0 takes
    /// only hard walls' widths.
    pub weakest_plane_db: f64,
    /// How far the detection threshold moves from ping to ping, ± dB (uniform): a real
    /// sensor's amplitude jitter (about ±1 dB). A cone's edge then lies anywhere between the
    /// cones of the margin less and more the jitter, independently in every sweep; near the
    /// limit of a target's range, where the margin is a dB or two, that is degrees
    /// ([`EchoPhysics::edge_jitter_sigma_deg`]). 0 (the simulator's default echoes) takes every
    /// edge where the margin puts it.
    pub threshold_jitter_db: f64,
}

impl Default for EchoPhysics {
    fn default() -> Self {
        Self {
            beam_6db_half_angle_deg: 27.0,
            specular_cutoff_deg: 28.0,
            absorption_db_per_m: 1.3,
            tvg_db_per_m: 11.0,
            tvg_max_range_m: 2.0,
            threshold_db: -15.0,
            corner_loss_db: 3.0,
            point_radius_m: 0.025,
            weakest_plane_db: 8.0,
            threshold_jitter_db: 0.0,
        }
    }
}

/// Level drop at [`EchoPhysics::beam_6db_half_angle_deg`].
const BEAM_REFERENCE_DB: f64 = 6.0;

/// The three reflector shapes the model knows.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Reflector {
    /// A flat wall: a mirror, heard only at normal incidence within the specular cut-off.
    Plane,
    /// A concave corner: a retro-reflector, heard from anywhere in the beam, a little weaker than
    /// a wall at its range.
    Corner,
    /// A vertical cylinder (a post, or an edge, which diffracts like a thin one): curved in one
    /// plane, so its echo spreads by a further radius / range.
    Cylinder { radius_m: f64 },
}

impl EchoPhysics {
    /// Spreading loss: a flat mirror images the transducer 2r away (0 dB at 0.5 m); a cylinder
    /// of radius a loses a further 10·log₁₀(a/r); a corner returns like a wall, less its loss.
    fn spreading_db(&self, reflector: Reflector, range_m: f64) -> f64 {
        let plane = -20.0 * (2.0 * range_m).log10();
        match reflector {
            Reflector::Plane => plane,
            Reflector::Corner => plane - self.corner_loss_db,
            Reflector::Cylinder { radius_m } => plane + 10.0 * (radius_m / range_m).log10(),
        }
    }

    /// How far above the detection threshold the echo of `reflector` at `range_m` arrives on the
    /// beam axis, dB: spreading, absorption both ways, the receiver's gain ramp.
    pub fn axis_margin_db(&self, reflector: Reflector, range_m: f64) -> f64 {
        self.spreading_db(reflector, range_m) - 2.0 * self.absorption_db_per_m * range_m
            + self.tvg_db_per_m * range_m.min(self.tvg_max_range_m)
            - self.threshold_db
    }

    /// Half-angle of the effective cone in which `reflector` at `range_m` is heard, degrees;
    /// `None` when it is not heard even on the axis.
    pub fn cone_half_angle_deg(
        &self,
        reflector: Reflector,
        range_m: f64,
        beam_half_angle_deg: f64,
    ) -> Option<f64> {
        let margin = self.axis_margin_db(reflector, range_m);
        if !(range_m > 0.0 && margin >= 0.0) {
            return None;
        }
        let cone = self.beam_6db_half_angle_deg * (margin / BEAM_REFERENCE_DB).sqrt();
        let cone = cone.min(beam_half_angle_deg);
        Some(match reflector {
            Reflector::Plane => cone.min(self.specular_cutoff_deg),
            Reflector::Corner | Reflector::Cylinder { .. } => cone,
        })
    }

    /// Half-angle of the cone of the weakest wall ([`EchoPhysics::weakest_plane_db`] below a hard
    /// one) at `range_m`, degrees; `None` when it is not heard even on the axis.
    pub fn weakest_plane_cone_half_angle_deg(
        &self,
        range_m: f64,
        beam_half_angle_deg: f64,
    ) -> Option<f64> {
        let weaker = Self {
            threshold_db: self.threshold_db + self.weakest_plane_db,
            ..*self
        };
        weaker.cone_half_angle_deg(Reflector::Plane, range_m, beam_half_angle_deg)
    }

    /// σ of the edge of `reflector`'s cone at `range_m` from sweep to sweep, degrees: with the
    /// threshold anywhere within ± [`EchoPhysics::threshold_jitter_db`], the edge lies anywhere
    /// between the cones of the margin less and more the jitter (taken as uniform between them).
    pub fn edge_jitter_sigma_deg(
        &self,
        reflector: Reflector,
        range_m: f64,
        beam_half_angle_deg: f64,
    ) -> f64 {
        let jitter = self.threshold_jitter_db;
        if jitter <= 0.0 {
            return 0.0;
        }
        let cone = |by_db: f64| {
            self.cone_with_threshold_moved_deg(reflector, range_m, beam_half_angle_deg, by_db)
        };
        (cone(-jitter) - cone(jitter)) / 12f64.sqrt()
    }

    /// Half-angle of `reflector`'s cone at `range_m` with the detection threshold moved by
    /// `by_db` (down by the jitter: the widest it is heard in any sweep; up: the cone every
    /// sweep keeps), degrees; 0 where it is not heard even on the axis.
    pub fn cone_with_threshold_moved_deg(
        &self,
        reflector: Reflector,
        range_m: f64,
        beam_half_angle_deg: f64,
        by_db: f64,
    ) -> f64 {
        Self {
            threshold_db: self.threshold_db + by_db,
            ..*self
        }
        .cone_half_angle_deg(reflector, range_m, beam_half_angle_deg)
        .unwrap_or(0.0)
    }

    /// The widest region of constant depth one target can make at `range_m`, degrees: a wall's
    /// or a corner's cone, or the union of two reference points' (see [`mod@crate::classify`]).
    pub fn widest_region_deg(&self, range_m: f64, beam_half_angle_deg: f64) -> f64 {
        let cone = |r: Reflector| {
            self.cone_half_angle_deg(r, range_m, beam_half_angle_deg)
                .unwrap_or(0.0)
        };
        2.0 * cone(Reflector::Plane)
            .max(cone(Reflector::Corner))
            .max(2.0 * cone(self.reference_point()))
    }

    /// The reference point target (a post of [`EchoPhysics::point_radius_m`]).
    pub fn reference_point(&self) -> Reflector {
        Reflector::Cylinder {
            radius_m: self.point_radius_m,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const BEAM: f64 = 30.0;

    fn cone(reflector: Reflector, r: f64) -> Option<f64> {
        EchoPhysics::default().cone_half_angle_deg(reflector, r, BEAM)
    }

    #[test]
    fn the_weakest_wall_is_narrower_only_where_the_beam_bounds_a_walls_cone() {
        let wide = EchoPhysics::default();
        // Near, the cut-off bounds a hard wall and an 8 dB weaker one alike ...
        assert_eq!(
            wide.weakest_plane_cone_half_angle_deg(1.0, BEAM),
            Some(28.0)
        );
        // ... farther, the weaker one is heard over less of the beam, and far not at all.
        let at_3_m = wide.weakest_plane_cone_half_angle_deg(3.0, BEAM).unwrap();
        assert!(at_3_m < 27.0, "{at_3_m}");
        assert_eq!(
            wide.cone_half_angle_deg(Reflector::Plane, 3.0, BEAM),
            Some(28.0)
        );
        assert_eq!(wide.weakest_plane_cone_half_angle_deg(20.0, BEAM), None);
        // A narrow beam bounds every wall's cone: the weaker one is narrower at any range.
        let narrow = EchoPhysics {
            beam_6db_half_angle_deg: 6.0,
            threshold_db: -24.0,
            ..wide
        };
        for r in [0.5, 1.0, 2.0] {
            let hard = narrow
                .cone_half_angle_deg(Reflector::Plane, r, BEAM)
                .unwrap();
            let weak = narrow.weakest_plane_cone_half_angle_deg(r, BEAM).unwrap();
            assert!(weak < hard - 1.0, "{r}: {weak} {hard}");
        }
        let same = EchoPhysics {
            weakest_plane_db: 0.0,
            ..narrow
        };
        assert_eq!(
            same.weakest_plane_cone_half_angle_deg(1.0, BEAM),
            same.cone_half_angle_deg(Reflector::Plane, 1.0, BEAM)
        );
    }

    #[test]
    fn a_5_cm_post_at_1_m_is_heard_within_13_degrees() {
        let post = EchoPhysics::default().reference_point();
        // Its near face is 0.975 m away (sensor-facts: ±10–15°; the simulator: ±13.4°).
        let h = cone(post, 0.975).unwrap();
        assert!((h - 13.4).abs() < 0.05, "{h}");
        // Farther, fainter, narrower; beyond ≈ 2.2 m not heard at all.
        let h2 = cone(post, 2.0).unwrap();
        assert!(h2 > 8.0 && h2 < 10.0, "{h2}");
        assert_eq!(cone(post, 2.5), None);
        // A thicker post is heard over a wider cone.
        let thick = cone(Reflector::Cylinder { radius_m: 0.05 }, 0.975).unwrap();
        assert!(thick > h + 3.0, "{thick}");
    }

    #[test]
    fn a_cones_edge_jitters_most_near_the_limit_of_its_targets_range() {
        let steady = EchoPhysics::default();
        let post = steady.reference_point();
        assert_eq!(steady.edge_jitter_sigma_deg(post, 1.0, BEAM), 0.0);
        let jittery = EchoPhysics {
            threshold_jitter_db: 1.0,
            ..steady
        };
        let near = jittery.edge_jitter_sigma_deg(post, 0.5, BEAM);
        let far = jittery.edge_jitter_sigma_deg(post, 2.0, BEAM);
        assert!(near > 0.0 && far > 2.0 * near, "{near} {far}");
        // A wall's cone held at the specular cut-off either way does not move.
        assert_eq!(
            jittery.edge_jitter_sigma_deg(Reflector::Plane, 1.0, BEAM),
            0.0
        );
        // Beyond the range where even the lowered threshold hears it: nothing to jitter.
        assert_eq!(jittery.edge_jitter_sigma_deg(post, 5.0, BEAM), 0.0);
    }

    #[test]
    fn walls_stop_at_the_cutoff_and_corners_fill_the_beam() {
        for r in [0.5, 1.2, 2.0, 3.5] {
            assert_eq!(cone(Reflector::Plane, r), Some(28.0), "{r}");
        }
        assert_eq!(cone(Reflector::Corner, 1.7), Some(30.0));
        // At 4 m the corner's echo no longer fills the beam.
        let far = cone(Reflector::Corner, 4.0).unwrap();
        assert!(far < 30.0 && far > 20.0, "{far}");
        // Near, two posts' union is the widest; from 1.2 m on, a corner's cone.
        let p = EchoPhysics::default();
        assert!(p.widest_region_deg(0.5, BEAM) > 100.0);
        assert_eq!(p.widest_region_deg(1.7, BEAM), 60.0);
    }
}
