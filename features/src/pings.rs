//! The raw pings of one sweep, each at its own angle.
//!
//! A [`Reading`] carries the echo times of its pings in the order the head took them
//! (`docs/protocol.md`, "Geometry of a reading"): ping j of P sits at
//! centre + (j − (P − 1)/2) · step **in the direction of motion**, so −2.25°, −0.75°, +0.75°,
//! +2.25° going counter-clockwise and the reverse going clockwise. Both directions sample the same
//! angles. A [`Sweep`] holds the pings of one sweep sorted by bearing, so that everything after it
//! is the same whichever way the head turned.
//!
//! # Sweeps taken on the move
//!
//! A robot that scans while it drives takes each reading from its own pose.
//! [`Sweep::from_readings_at`] brings every ping to the sweep's reference pose (its first
//! reading's, say) before anything else looks at them: the bearing turns by the heading the sensor
//! has gained, and the range becomes the echo's position projected on the beam's direction from
//! the reference, i.e. the range grows by the sensor's displacement along the beam. That is exact
//! for a wall heard square on and first order for everything else: what it drops is the
//! displacement across the beam, which shifts a point target's bearing by (offset / range), never
//! a wall's (a wall is heard around its normal from anywhere in front of it). Bearings stay on the
//! stepper's grid (turned as a whole), so the widths of the regions of constant depth keep the
//! meaning the classification gives them.

use nalgebra::{Isometry2, Vector2};
use sonar_common::ipc::{Reading, flags};

use crate::config::FeatureConfig;
use crate::error::FeatureError;
use crate::noise::PingPair;

/// One ping: where the head pointed, and the range of the first echo it heard.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ping {
    /// Bearing of the beam axis, degrees counter-clockwise from the sensor's forward axis.
    pub bearing_deg: f64,
    /// Range of the first echo, metres; `None` for no echo (or one outside the sensor's range).
    pub range_m: Option<f64>,
}

/// The pings of one sweep (one pass in one direction), sorted by bearing.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Sweep {
    pings: Vec<Ping>,
    step_deg: f64,
    skipped_readings: usize,
    /// Neighbouring pings of one reading that both heard something: the noise's evidence.
    pairs: Vec<PingPair>,
    range_quantum_m: Option<f64>,
    /// A full circle (a continuous head's revolution): its last ping is next to its first.
    circular: bool,
}

/// Two neighbouring pings farther apart than this many steps have lost readings between them.
const GAP_STEPS: f64 = 1.5;

impl Sweep {
    /// The pings of `readings` (one sweep's, in any order). A reading with one range per angle
    /// (`NO_RAW_PINGS`: the hobby dialect, imported logs; or a single ping) is one ping on its
    /// axis, and a sweep of them has the step of their spacing. Readings whose pings cannot be
    /// placed are skipped and counted ([`Sweep::skipped_readings`]): several pings but no
    /// direction of motion, or no angle.
    pub fn from_readings<'a>(
        readings: impl IntoIterator<Item = &'a Reading>,
        cfg: &FeatureConfig,
    ) -> Self {
        Self::from_readings_at(
            readings.into_iter().map(|r| (r, Isometry2::identity())),
            cfg,
        )
    }

    /// The pings of one sweep's readings, each reading with the sensor's pose when it was taken
    /// relative to the sweep's reference pose: every ping brought to the reference (module docs,
    /// "Sweeps taken on the move"). A ping whose range would end up behind the reference has none.
    pub fn from_readings_at<'a>(
        readings: impl IntoIterator<Item = (&'a Reading, Isometry2<f64>)>,
        cfg: &FeatureConfig,
    ) -> Self {
        Self::brought_to_reference(readings, None, cfg)
    }

    /// The pings of a sweep taken on the move that would have heard a wall whose normal points
    /// along `normal_deg` (in the reference's frame): those aimed within `window_deg` of it, each
    /// range plus the displacement of its pose from the reference **along that normal** — the
    /// distance to such a wall changes by exactly that, wherever in the cone the ping pointed.
    /// Under the right normal a wall's pings have one range again, as from one place, and its
    /// region of constant depth is whole; under another they spread as the robot drove along it.
    pub fn facing<'a>(
        readings: impl IntoIterator<Item = (&'a Reading, Isometry2<f64>)>,
        normal_deg: f64,
        window_deg: f64,
        cfg: &FeatureConfig,
    ) -> Self {
        let mut sweep = Self::brought_to_reference(readings, Some(normal_deg), cfg);
        sweep
            .pings
            .retain(|p| crate::geometry::wrap_deg(p.bearing_deg - normal_deg).abs() <= window_deg);
        sweep.circular = false;
        sweep
    }

    fn brought_to_reference<'a>(
        readings: impl IntoIterator<Item = (&'a Reading, Isometry2<f64>)>,
        normal_deg: Option<f64>,
        cfg: &FeatureConfig,
    ) -> Self {
        let mut pings = Vec::new();
        let mut pairs = Vec::new();
        let mut per_angle = Vec::new();
        let mut skipped = 0;
        for (r, pose) in readings {
            match placed_pings(r, cfg) {
                Placed::Raw(p) => {
                    let first = pings.len();
                    pings.extend(p.map(|ping| at_reference(ping, &pose, normal_deg)));
                    pairs.extend(neighbour_pairs(&pings[first..]));
                }
                Placed::PerAngle(ping) => per_angle.push(at_reference(ping, &pose, normal_deg)),
                Placed::Unknown => skipped += 1,
            }
        }
        // One range per angle: the step is the head's own (its readings' spacing), and neighbours
        // in bearing are the noise's evidence, as for pings placed without readings.
        let step_deg = if pings.is_empty() && per_angle.len() > 1 {
            per_angle_step_deg(&per_angle).unwrap_or(cfg.step_deg())
        } else {
            cfg.step_deg()
        };
        let per_angle_pairs = pings.is_empty() && !per_angle.is_empty();
        pings.extend(per_angle);
        let mut sweep = Self {
            pings,
            step_deg,
            skipped_readings: skipped,
            pairs,
            range_quantum_m: None,
            circular: false,
        };
        sweep.sort();
        if per_angle_pairs {
            sweep.pairs.extend(sweep.pairs_in_bearing());
        }
        sweep.range_quantum_m = whole_centimetres(&sweep.pings).then_some(CENTIMETRE_M);
        sweep
    }

    /// A sweep from pings already placed (tests, other sources). Bearings must be finite, ranges
    /// finite and positive, `step_deg` positive.
    pub fn from_pings(pings: Vec<Ping>, step_deg: f64) -> Result<Self, FeatureError> {
        if !(step_deg.is_finite() && step_deg > 0.0) {
            return Err(FeatureError::Config(format!(
                "the step between pings must be > 0, got {step_deg}"
            )));
        }
        if let Some((index, p)) = pings.iter().enumerate().find(|(_, p)| {
            !p.bearing_deg.is_finite() || p.range_m.is_some_and(|r| !(r.is_finite() && r > 0.0))
        }) {
            return Err(FeatureError::BadPing {
                index,
                bearing_deg: p.bearing_deg,
                range_m: p.range_m,
            });
        }
        let mut sweep = Self {
            pings,
            step_deg,
            skipped_readings: 0,
            pairs: Vec::new(),
            range_quantum_m: None,
            circular: false,
        };
        sweep.sort();
        // Without readings, neighbours in bearing stand in for a reading's pings.
        sweep.pairs = sweep.pairs_in_bearing();
        sweep.range_quantum_m = whole_centimetres(&sweep.pings).then_some(CENTIMETRE_M);
        Ok(sweep)
    }

    /// Neighbours in bearing with no readings lost between them.
    fn pairs_in_bearing(&self) -> Vec<PingPair> {
        (1..self.pings.len())
            .filter(|&i| !self.gap_before(i))
            .flat_map(|i| neighbour_pairs(&self.pings[i - 1..=i]))
            .collect()
    }

    /// Sorts the pings by bearing. A head that turned a full circle has no scan end: the circle
    /// is cut between the two neighbouring echoes that differ most in range (a ping that heard
    /// nothing may be a dropout inside a region), so that no region of constant depth is cut in
    /// two, and the bearings after the cut are continued past 360°.
    fn sort(&mut self) {
        self.pings
            .sort_by(|a, b| a.bearing_deg.total_cmp(&b.bearing_deg));
        let n = self.pings.len();
        if n < 3 {
            return;
        }
        let span = self.pings[n - 1].bearing_deg - self.pings[0].bearing_deg;
        if span + 1.5 * self.step_deg < 360.0 {
            return;
        }
        let jump = |i: usize| match (self.pings[(i + n - 1) % n].range_m, self.pings[i].range_m) {
            (Some(a), Some(b)) => (a - b).abs(),
            _ => 0.0,
        };
        let cut = (0..n)
            .max_by(|&i, &j| jump(i).total_cmp(&jump(j)))
            .unwrap_or(0);
        self.pings.rotate_left(cut);
        self.circular = true;
        let start = self.pings[0].bearing_deg;
        for p in &mut self.pings {
            while p.bearing_deg < start {
                p.bearing_deg += 360.0;
            }
        }
    }

    pub fn pings(&self) -> &[Ping] {
        &self.pings
    }

    pub fn step_deg(&self) -> f64 {
        self.step_deg
    }

    /// Neighbouring pings of one reading that both heard something, for the noise estimate
    /// ([`crate::noise`]); for pings placed without readings, neighbours in bearing.
    pub fn pairs(&self) -> &[PingPair] {
        &self.pairs
    }

    /// Readings left out because their pings' angles are unknown.
    pub fn skipped_readings(&self) -> usize {
        self.skipped_readings
    }

    /// Whether the pings go round the full circle (a continuous head's revolution, cut where
    /// neighbouring ranges differ most): past the last ping comes the first, there is no scan
    /// end.
    pub fn is_circular(&self) -> bool {
        self.circular
    }

    /// The ranges' resolution when every one is a whole number of it (1 cm: a sensor or a
    /// sketch that reports whole centimetres), whose rounding alone is noise of quantum/√12.
    pub fn range_quantum_m(&self) -> Option<f64> {
        self.range_quantum_m
    }

    /// Whether readings are missing between ping `i − 1` and ping `i` (lost lines): then neither
    /// knows what its neighbour would have heard.
    pub fn gap_before(&self, i: usize) -> bool {
        i > 0
            && i < self.pings.len()
            && self.pings[i].bearing_deg - self.pings[i - 1].bearing_deg > GAP_STEPS * self.step_deg
    }

    /// The ping aimed within half a step of `bearing_deg` (compared modulo 360°), if any.
    pub fn ping_at(&self, bearing_deg: f64) -> Option<&Ping> {
        self.pings
            .iter()
            .map(|p| {
                (
                    crate::geometry::wrap_deg(p.bearing_deg - bearing_deg).abs(),
                    p,
                )
            })
            .filter(|(off, _)| *off <= self.step_deg / 2.0 + 1e-9)
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .map(|(_, p)| p)
    }
}

/// `ping`, taken at `pose` (relative to the reference), as seen from the reference: bearing turned
/// by the pose's heading, range plus the pose's displacement along `along_deg` (the beam's axis
/// when `None`).
fn at_reference(ping: Ping, pose: &Isometry2<f64>, along_deg: Option<f64>) -> Ping {
    let bearing_deg = ping.bearing_deg + pose.rotation.angle().to_degrees();
    let (sin, cos) = along_deg.unwrap_or(bearing_deg).to_radians().sin_cos();
    let along = pose.translation.vector.dot(&Vector2::new(cos, sin));
    Ping {
        bearing_deg,
        range_m: ping.range_m.map(|r| r + along).filter(|r| *r > 0.0),
    }
}

/// Every two neighbouring pings (in the order given) that both heard something.
fn neighbour_pairs(pings: &[Ping]) -> impl Iterator<Item = PingPair> + '_ {
    pings
        .windows(2)
        .filter_map(|w| Some(PingPair::of(w[0].range_m?, w[1].range_m?)))
}

/// Where the pings of one reading go.
enum Placed<I> {
    /// Raw pings at their own angles.
    Raw(I),
    /// One range per angle (the hobby dialect, an imported log, a head that combines its pings):
    /// one ping on the reading's axis.
    PerAngle(Ping),
    /// Several pings whose angles are unknown (no direction of motion), or no angle at all.
    Unknown,
}

/// The pings of one reading at their angles.
fn placed_pings(r: &Reading, cfg: &FeatureConfig) -> Placed<impl Iterator<Item = Ping>> {
    let n = usize::from(r.ping_count).min(r.echo_us.len());
    let direction = f64::from(r.direction.signum());
    let finite_positive = |v: f32| (v.is_finite() && v > 0.0).then_some(f64::from(v));
    let speed = finite_positive(r.speed_of_sound_mps).unwrap_or_else(|| cfg.speed_of_sound_mps());
    let min = f64::from(r.min_range_m)
        .max(0.0)
        .min(f64::from(cfg.sensor.max_range_m));
    let max = finite_positive(r.max_range_m).unwrap_or(f64::from(cfg.sensor.max_range_m));
    // 0 µs is no echo; an echo outside [min, max] is set aside as the driver does.
    let range_of = move |us: u32| {
        let range = speed * f64::from(us) * 1e-6 / 2.0;
        (us > 0 && (min..=max).contains(&range)).then_some(range)
    };
    let step = cfg.step_deg();
    let centre = f64::from(r.angle_deg);
    let middle = (n as f64 - 1.0) / 2.0;
    let raw = r.echo_us[..n].iter().enumerate().map(move |(j, &us)| Ping {
        bearing_deg: centre + direction * step * (j as f64 - middle),
        range_m: range_of(us),
    });
    if !r.angle_deg.is_finite() {
        Placed::Unknown
    } else if r.has(flags::NO_RAW_PINGS) || n <= 1 {
        let range_m = if n == 1 {
            range_of(r.echo_us[0])
        } else {
            (r.is_valid_range() && r.distance_m.is_finite() && r.distance_m > 0.0)
                .then_some(f64::from(r.distance_m))
        };
        Placed::PerAngle(Ping {
            bearing_deg: centre,
            range_m,
        })
    } else if direction == 0.0 {
        Placed::Unknown
    } else {
        Placed::Raw(raw)
    }
}

/// The step of a head that gives one range per angle: the median spacing of its bearings
/// (duplicates and lost readings aside, the spacing it was driven at).
fn per_angle_step_deg(pings: &[Ping]) -> Option<f64> {
    let mut bearings: Vec<f64> = pings.iter().map(|p| p.bearing_deg).collect();
    bearings.sort_by(f64::total_cmp);
    let mut spacings: Vec<f64> = bearings
        .windows(2)
        .map(|w| w[1] - w[0])
        .filter(|d| *d > 1e-3)
        .collect();
    if spacings.is_empty() {
        return None;
    }
    spacings.sort_by(f64::total_cmp);
    Some(spacings[spacings.len() / 2])
}

const CENTIMETRE_M: f64 = 0.01;

/// Fewest ranges that show a sensor's whole centimetres: by chance, eight ranges all fall within
/// 1 mm of one (1 chance in 5⁸).
const QUANTUM_EVIDENCE: usize = 8;

/// Whether every range is a whole number of centimetres (to within 1 mm: the echo times a driver
/// synthesises from centimetres are whole microseconds, 0.17 mm).
fn whole_centimetres(pings: &[Ping]) -> bool {
    let ranges = pings.iter().filter_map(|p| p.range_m);
    let mut count = 0;
    for r in ranges {
        let cm = r / CENTIMETRE_M;
        if (cm - cm.round()).abs() * CENTIMETRE_M > 1e-3 {
            return false;
        }
        count += 1;
    }
    count >= QUANTUM_EVIDENCE
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// A reading centred at `centre_deg`, moving in `direction`, with these ranges (metres; 0 =
    /// no echo) in the order the head took them.
    pub(crate) fn reading(centre_deg: f32, direction: i8, ranges_m: &[f64]) -> Reading {
        let cfg = FeatureConfig::default();
        let v = cfg.speed_of_sound_mps();
        let mut r = Reading {
            angle_deg: centre_deg,
            direction,
            ping_count: ranges_m.len() as u8,
            speed_of_sound_mps: v as f32,
            min_range_m: cfg.sensor.min_range_m,
            max_range_m: cfg.sensor.max_range_m,
            ..Reading::default()
        };
        for (slot, &m) in r.echo_us.iter_mut().zip(ranges_m) {
            *slot = (2.0 * m / v * 1e6).round() as u32;
        }
        r
    }

    #[test]
    fn pings_sit_at_their_own_angles_in_either_direction() {
        let cfg = FeatureConfig::default();
        let ranges = [1.0, 1.1, 1.2, 1.3];
        let ccw = Sweep::from_readings(&[reading(3.0, 1, &ranges)], &cfg);
        let cw = Sweep::from_readings(&[reading(3.0, -1, &ranges)], &cfg);
        let bearings = |s: &Sweep| s.pings().iter().map(|p| p.bearing_deg).collect::<Vec<_>>();
        assert_eq!(bearings(&ccw), [0.75, 2.25, 3.75, 5.25]);
        assert_eq!(bearings(&cw), [0.75, 2.25, 3.75, 5.25]);
        let range_at = |s: &Sweep, b: f64| s.ping_at(b).unwrap().range_m.unwrap();
        // Counter-clockwise the first ping is the lowest angle; clockwise the highest.
        assert!((range_at(&ccw, 0.75) - 1.0).abs() < 1e-3);
        assert!((range_at(&cw, 0.75) - 1.3).abs() < 1e-3);
        assert!((range_at(&cw, 5.25) - 1.0).abs() < 1e-3);
    }

    #[test]
    fn pings_taken_on_the_move_are_brought_to_the_reference_pose() {
        let cfg = FeatureConfig::default();
        let r = |centre: f32, range: f64| reading(centre, 1, &[range; 4]);
        // A wall 1 m ahead of the reference: the first reading is taken at the reference, the
        // second 20 cm nearer the wall and turned 3° left (the wall's foot 0.8 m away), the third
        // 30 cm to the left (its foot 1 m away).
        let nearer = Isometry2::new(Vector2::new(0.2, 0.0), 3.0_f64.to_radians());
        let aside = Isometry2::translation(0.0, 0.3);
        let s = Sweep::from_readings_at(
            [
                (&r(-6.0, 1.0), Isometry2::identity()),
                (&r(-3.0, 0.8), nearer),
                (&r(6.0, 1.0), aside),
            ],
            &cfg,
        );
        let placed: Vec<(f64, f64)> = s
            .pings()
            .iter()
            .map(|p| (p.bearing_deg, p.range_m.unwrap()))
            .collect();
        // Bearings: the turned reading's pings sit 3° further on, still on the 1.5° grid.
        let bearings: Vec<f64> = placed.iter().map(|p| p.0).collect();
        let grid: Vec<f64> = (0..12).map(|k| -8.25 + 1.5 * f64::from(k)).collect();
        assert!(
            bearings
                .iter()
                .zip(&grid)
                .all(|(b, g)| (b - g).abs() < 1e-9),
            "{bearings:?}"
        );
        for &(bearing, range) in &placed {
            let (sin, cos) = bearing.to_radians().sin_cos();
            let expected = if bearing < -3.0 {
                1.0
            } else if bearing < 3.0 {
                0.8 + 0.2 * cos
            } else {
                1.0 + 0.3 * sin
            };
            assert!((range - expected).abs() < 5e-4, "{placed:?}");
        }
        // Approached square on, the wall keeps its constant depth: within 1 mm of 1 m.
        assert!(
            placed[..8].iter().all(|p| (p.1 - 1.0).abs() < 1e-3),
            "{placed:?}"
        );
        // The identity pose is the plain sweep.
        let plain = r(0.0, 1.0);
        assert_eq!(
            Sweep::from_readings_at([(&plain, Isometry2::identity())], &cfg),
            Sweep::from_readings(&[plain], &cfg)
        );
        // A ping whose range lands behind the reference has none.
        let behind =
            Sweep::from_readings_at([(&r(0.0, 0.5), Isometry2::translation(-1.0, 0.0))], &cfg);
        assert!(behind.pings().iter().all(|p| p.range_m.is_none()));
    }

    #[test]
    fn no_echo_and_out_of_range_pings_have_no_range() {
        let cfg = FeatureConfig::default();
        // 5 m is past the 4 m maximum, 1 cm short of the 3 cm minimum.
        let r = reading(0.0, 1, &[0.0, 1.0, 5.0, 0.01]);
        let s = Sweep::from_readings(&[r], &cfg);
        let ranges: Vec<bool> = s.pings().iter().map(|p| p.range_m.is_some()).collect();
        assert_eq!(ranges, [false, true, false, false]);
    }

    #[test]
    fn readings_without_placeable_pings_are_skipped() {
        let cfg = FeatureConfig::default();
        let mut hobby = reading(0.0, 1, &[1.0]);
        hobby.flags |= flags::NO_RAW_PINGS;
        let unknown = reading(6.0, 0, &[1.0, 1.0, 1.0, 1.0]);
        let single = reading(12.0, 0, &[1.0]);
        let mut no_angle = reading(18.0, 1, &[1.0]);
        no_angle.angle_deg = f32::NAN;
        let s = Sweep::from_readings(&[hobby, unknown, single, no_angle], &cfg);
        assert_eq!(s.skipped_readings(), 2);
        let bearings: Vec<f64> = s.pings().iter().map(|p| p.bearing_deg).collect();
        assert_eq!(
            bearings,
            [0.0, 12.0],
            "one range per angle, on the reading's axis"
        );
    }

    /// A hobby head: one whole-centimetre range per angle, 3° apart, one reading lost.
    fn per_angle_readings(
        centres: impl Iterator<Item = f32>,
        cm: impl Fn(f32) -> f64,
    ) -> Vec<Reading> {
        centres
            .map(|c| {
                let mut r = reading(c, 1, &[cm(c) / 100.0]);
                r.flags |= flags::NO_RAW_PINGS;
                r
            })
            .collect()
    }

    #[test]
    fn per_angle_readings_give_one_ping_each_at_the_heads_own_step() {
        let cfg = FeatureConfig::default();
        let readings = per_angle_readings(
            (0..30).filter(|&k| k != 7).map(|k| -45.0 + 3.0 * k as f32),
            |c| 120.0 + (c.abs() / 10.0).floor() as f64,
        );
        let s = Sweep::from_readings(&readings, &cfg);
        assert_eq!(s.skipped_readings(), 0);
        assert_eq!(s.pings().len(), 29);
        assert_eq!(
            s.step_deg(),
            3.0,
            "the head's spacing, not the stepper's 1.5°"
        );
        // The lost reading is a gap; neighbours in bearing are the noise's pairs.
        assert!(s.gap_before(7) && !s.gap_before(8));
        assert_eq!(s.pairs().len(), 27);
        assert_eq!(s.range_quantum_m(), Some(0.01), "whole centimetres");
        // Ranges that are not whole centimetres have no quantum.
        let fine = per_angle_readings((0..30).map(|k| 3.0 * k as f32), |c| {
            120.0 + 0.37 * f64::from(c)
        });
        assert_eq!(Sweep::from_readings(&fine, &cfg).range_quantum_m(), None);
    }

    #[test]
    fn a_full_circle_is_cut_where_the_range_jumps_most() {
        let cfg = FeatureConfig::default();
        // A continuous head at 5°, angles −175…180; a target at 2 m from −20° to +20°, 1.2 m
        // elsewhere but 3 m from 100° to 130° and nothing at −100° (a dropout): the circle is cut
        // at the largest jump between echoes (3 m → 1.2 m at 135°), not at ±180°.
        let readings = per_angle_readings((0..72).map(|k| -175.0 + 5.0 * k as f32), |c| {
            if c.abs() <= 20.0 {
                200.0
            } else if c == -100.0 {
                0.0
            } else if (100.0..=130.0).contains(&c) {
                300.0
            } else {
                120.0
            }
        });
        let s = Sweep::from_readings(&readings, &cfg);
        let bearings: Vec<f64> = s.pings().iter().map(|p| p.bearing_deg).collect();
        assert_eq!(bearings[0], 135.0);
        assert_eq!(*bearings.last().unwrap(), 130.0 + 360.0);
        assert!(s.is_circular());
        assert!(
            bearings
                .windows(2)
                .all(|w| (w[1] - w[0] - 5.0).abs() < 1e-9)
        );
        // A half circle is left as it is.
        let half = per_angle_readings((0..36).map(|k| -90.0 + 5.0 * k as f32), |_| 120.0);
        let half = Sweep::from_readings(&half, &cfg);
        assert_eq!(half.pings()[0].bearing_deg, -90.0);
        assert!(!half.is_circular());
    }

    #[test]
    fn gaps_and_bad_pings() {
        let p = |b: f64| Ping {
            bearing_deg: b,
            range_m: Some(1.0),
        };
        let s = Sweep::from_pings(vec![p(3.0), p(0.0), p(1.5), p(7.5)], 1.5).unwrap();
        assert!(!s.gap_before(1) && !s.gap_before(2) && s.gap_before(3));
        assert_eq!(s.ping_at(7.0).map(|p| p.bearing_deg), Some(7.5));
        assert_eq!(s.ping_at(5.0), None);
        assert!(Sweep::from_pings(vec![p(f64::NAN)], 1.5).is_err());
        let bad_range = Ping {
            bearing_deg: 0.0,
            range_m: Some(-1.0),
        };
        assert!(matches!(
            Sweep::from_pings(vec![p(0.0), bad_range], 1.5),
            Err(FeatureError::BadPing { index: 1, .. })
        ));
        assert!(Sweep::from_pings(vec![], 0.0).is_err());
    }
}
