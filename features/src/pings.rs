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
//!
//! A reading's pose is the one at its stamp, its last ping's instant (the head stamps a reading
//! when its last echo is in, the echo's time of flight after the ping: at most 23 ms at 4 m, and
//! the sensor's time-out without an echo; a stamp a whole ping interval late put every ping on
//! the move where the robot was 50–60 ms later, `docs/results.md`, "Readings stamped when their
//! echo is in"); its earlier pings were taken one ping interval apart before it, while the robot
//! moved on. Each ping is placed at the pose of
//! its own instant, interpolated between the readings' poses ([`ReadingPoses`]): a robot turning at
//! 45°/s turns 2.7° between two pings (60 ms), so a reading's first ping taken at its last one's
//! pose would be 8° off where it was aimed, and the edge of a wall's region with it.

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
    ///
    /// Bearings are given within `window_deg` of the normal, whatever the heading the robot
    /// gained (a robot that turned 90° during the sweep brings pings to 230° and to −130° alike).
    /// A robot turning the way the head turns spreads its pings wider than the head's step (at
    /// 45°/s against the head's 25°/s, 4.2° instead of 1.5°): the sweep's step is then the widest
    /// spacing of one reading's pings in the window, so that such pings stay neighbours rather
    /// than gaps and a region's width is known to that step.
    pub fn facing<'a>(
        readings: impl IntoIterator<Item = (&'a Reading, Isometry2<f64>)>,
        normal_deg: f64,
        window_deg: f64,
        cfg: &FeatureConfig,
    ) -> Self {
        let mut sweep = Self::brought_to_reference(readings, Some((normal_deg, window_deg)), cfg);
        sweep.pings.retain_mut(|p| {
            let off = crate::geometry::wrap_deg(p.bearing_deg - normal_deg);
            p.bearing_deg = normal_deg + off;
            off.abs() <= window_deg
        });
        sweep.circular = false;
        sweep.sort();
        sweep
    }

    /// `facing`: the normal along which each range is moved, and the window of bearings around
    /// it whose pings' spacing sets the step.
    fn brought_to_reference<'a>(
        readings: impl IntoIterator<Item = (&'a Reading, Isometry2<f64>)>,
        facing: Option<(f64, f64)>,
        cfg: &FeatureConfig,
    ) -> Self {
        let normal_deg = facing.map(|(normal, _)| normal);
        let in_window = |p: &Ping| {
            facing.is_some_and(|(normal, window)| {
                crate::geometry::wrap_deg(p.bearing_deg - normal).abs() <= window
            })
        };
        let mut widest_spacing_deg: f64 = 0.0;
        let readings: Vec<(&Reading, Isometry2<f64>)> = readings.into_iter().collect();
        let reading_poses = ReadingPoses::of(&readings);
        let mut pings = Vec::new();
        let mut pairs = Vec::new();
        let mut per_angle = Vec::new();
        let mut skipped = 0;
        for &(r, pose) in &readings {
            match placed_pings(r, cfg) {
                Placed::Raw(p) => {
                    let first = pings.len();
                    let count = usize::from(r.ping_count).min(r.echo_us.len());
                    pings.extend(p.enumerate().map(|(j, ping)| {
                        let own = reading_poses.ping_pose(r, &pose, j, count);
                        at_reference(ping, &own, normal_deg)
                    }));
                    pairs.extend(neighbour_pairs(&pings[first..]));
                    for w in pings[first..].windows(2) {
                        if in_window(&w[0]) && in_window(&w[1]) {
                            widest_spacing_deg = widest_spacing_deg.max(
                                crate::geometry::wrap_deg(w[1].bearing_deg - w[0].bearing_deg)
                                    .abs(),
                            );
                        }
                    }
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
            cfg.step_deg().max(widest_spacing_deg)
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

/// The poses of a sweep's readings in time, for placing each ping at its own instant.
///
/// A reading's stamp is its last ping's instant (`Reading::host_stamp_ns`), and the head takes a
/// reading's pings one after another over the time since the reading before: on the move, ping
/// j of P was taken (P − 1 − j) ping intervals before its reading's pose, where one interval is
/// the readings' period (the median time between consecutive stamps) over P. Each ping's pose is
/// the readings' poses interpolated to its instant (extrapolated from the first two before the
/// first reading). At a turn of 45°/s with 60 ms between pings, a reading's first ping is 8° off
/// the pose of its stamp; placed there, a wall's region ends several degrees early or late, and a
/// wall placed from one natural end is that far off.
struct ReadingPoses {
    /// Stamp (ns) and pose of each reading, in order of time.
    poses: Vec<(u64, Isometry2<f64>)>,
    /// Time between readings, ns; 0 when it cannot be told (fewer than two stamps).
    period_ns: f64,
}

impl ReadingPoses {
    fn of(readings: &[(&Reading, Isometry2<f64>)]) -> Self {
        let mut poses: Vec<(u64, Isometry2<f64>)> = readings
            .iter()
            .map(|(r, pose)| (r.host_stamp_ns, *pose))
            .collect();
        poses.sort_by_key(|(t, _)| *t);
        let mut periods: Vec<u64> = poses
            .windows(2)
            .map(|w| w[1].0 - w[0].0)
            .filter(|&d| d > 0)
            .collect();
        periods.sort_unstable();
        let period_ns = periods.get(periods.len() / 2).map_or(0.0, |&d| d as f64);
        Self { poses, period_ns }
    }

    /// The pose of ping `j` of the `count` of `reading` (taken at `pose`).
    fn ping_pose(
        &self,
        reading: &Reading,
        pose: &Isometry2<f64>,
        j: usize,
        count: usize,
    ) -> Isometry2<f64> {
        let before = (count.saturating_sub(1 + j)) as f64 * self.period_ns / count.max(1) as f64;
        if before <= 0.0 || self.poses.len() < 2 {
            return *pose;
        }
        let t = reading.host_stamp_ns as f64 - before;
        // The two readings around the instant, or the first two before the first one.
        let after = self
            .poses
            .partition_point(|(s, _)| (*s as f64) < t)
            .clamp(1, self.poses.len() - 1);
        let ((t0, p0), (t1, p1)) = (self.poses[after - 1], self.poses[after]);
        if t1 <= t0 {
            return *pose;
        }
        let f = (t - t0 as f64) / (t1 - t0) as f64;
        let turn = crate::geometry::wrap_rad(p1.rotation.angle() - p0.rotation.angle());
        Isometry2::new(
            p0.translation.vector + (p1.translation.vector - p0.translation.vector) * f,
            p0.rotation.angle() + turn * f,
        )
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

    /// Readings of a head turning counter-clockwise from −50° to 52° in 6° readings, 60 ms
    /// between pings (the last at the reading's stamp), on a robot turning clockwise in place at
    /// 45°/s from 90° left of the reference: from the reference the pings go clockwise, 1.2°
    /// apart, from 42° to −44°. A wall 1 m ahead of the reference is heard by every ping within the 28°
    /// cut-off of its normal, each at its own instant's heading. Each reading with the robot's
    /// pose at its stamp, and each ping's true bearing from the reference, sorted.
    pub(crate) fn turning_in_place() -> (Vec<(Reading, Isometry2<f64>)>, Vec<f64>) {
        turning_in_place_at(-45.0, 90.0, 0.0)
    }

    /// [`turning_in_place`] with the robot turning at `rate_deg_per_s` (counter-clockwise
    /// positive) from `start_deg` of the reference and the wall's normal at `wall_deg` of it;
    /// the head still counter-clockwise, from −50° to 52°. Turning counter-clockwise at 45°/s
    /// the pings go 4.2° apart instead of 1.5°.
    pub(crate) fn turning_in_place_at(
        rate_deg_per_s: f64,
        start_deg: f64,
        wall_deg: f64,
    ) -> (Vec<(Reading, Isometry2<f64>)>, Vec<f64>) {
        let ping_ns = 60_000_000u64;
        let rate_deg_per_ns = rate_deg_per_s / 1e9;
        let mut readings = Vec::new();
        let mut bearings = Vec::new();
        for k in 0..18u64 {
            let centre = -50.0 + 6.0 * k as f64;
            let stamp = 1_000_000_000 + 4 * ping_ns * k;
            let ranges: Vec<f64> = (0..4)
                .map(|j| {
                    let instant = stamp - (3 - j) * ping_ns;
                    let heading = start_deg + rate_deg_per_ns * (instant as f64 - 1e9);
                    let bearing = centre + 1.5 * (j as f64 - 1.5) + heading;
                    bearings.push(bearing);
                    if crate::geometry::wrap_deg(bearing - wall_deg).abs() <= 28.0 {
                        1.0
                    } else {
                        0.0
                    }
                })
                .collect();
            let mut r = reading(centre as f32, 1, &ranges);
            r.host_stamp_ns = stamp;
            let heading = start_deg + rate_deg_per_ns * (stamp as f64 - 1e9);
            readings.push((r, Isometry2::rotation(heading.to_radians())));
        }
        bearings.sort_by(f64::total_cmp);
        (readings, bearings)
    }

    #[test]
    fn pings_taken_while_turning_are_placed_at_their_own_instants() {
        let cfg = FeatureConfig::default();
        let (readings, truth) = turning_in_place();
        let s = Sweep::from_readings_at(readings.iter().map(|(r, p)| (r, *p)), &cfg);
        let bearings: Vec<f64> = s.pings().iter().map(|p| p.bearing_deg).collect();
        // At the reading's pose a reading's first ping would be 8.1° off (three intervals of
        // 2.7° turned); at its own instant, where it was aimed.
        assert_eq!(bearings.len(), truth.len());
        assert!(
            bearings
                .iter()
                .zip(&truth)
                .all(|(b, t)| (b - t).abs() < 1e-6),
            "{bearings:?} against {truth:?}"
        );
        // The wall's pings are those within its cut-off, and heard at 1 m.
        assert!(s.pings().iter().all(|p| match p.range_m {
            Some(r) => p.bearing_deg.abs() <= 28.0 + 1e-6 && (r - 1.0).abs() < 1e-3,
            None => p.bearing_deg.abs() > 28.0 - 1e-6,
        }));
        // Readings without stamps (or all at one instant) keep every ping at their pose.
        let unstamped: Vec<(Reading, Isometry2<f64>)> = readings
            .iter()
            .map(|(r, p)| {
                (
                    Reading {
                        host_stamp_ns: 0,
                        ..*r
                    },
                    *p,
                )
            })
            .collect();
        let at_readings = Sweep::from_readings_at(unstamped.iter().map(|(r, p)| (r, *p)), &cfg);
        let first =
            readings[1].1.rotation.angle().to_degrees() + f64::from(readings[1].0.angle_deg) - 2.25;
        assert!(
            at_readings
                .pings()
                .iter()
                .any(|p| (p.bearing_deg - first).abs() < 1e-6)
        );
    }

    #[test]
    fn pings_facing_a_normal_lie_around_it_at_the_spacing_the_turn_gave_them() {
        let cfg = FeatureConfig::default();
        // Turning counter-clockwise with the head from 100° to 294° of the reference: the pose's
        // heading crosses ±180° on the way, and the pings go 4.2° apart.
        let (readings, _) = turning_in_place_at(45.0, 100.0, 180.0);
        let normal = -160.0;
        let s = Sweep::facing(readings.iter().map(|(r, p)| (r, *p)), normal, 45.0, &cfg);
        let bearings: Vec<f64> = s.pings().iter().map(|p| p.bearing_deg).collect();
        assert!(bearings.len() > 15, "{bearings:?}");
        assert!(
            bearings.iter().all(|b| (b - normal).abs() <= 45.0),
            "{bearings:?}"
        );
        assert!(bearings.windows(2).all(|w| w[0] <= w[1]), "{bearings:?}");
        // One step is the pings' own spacing, so that neighbours are no gap.
        assert!((s.step_deg() - 4.2).abs() < 0.01, "{}", s.step_deg());
        assert!(
            (1..s.pings().len()).all(|i| !s.gap_before(i)),
            "{bearings:?}"
        );
        // Turning against the head the pings are closer than a step: the head's step stands.
        let (against, _) = turning_in_place();
        let s = Sweep::facing(against.iter().map(|(r, p)| (r, *p)), 0.0, 45.0, &cfg);
        assert_eq!(s.step_deg(), cfg.step_deg());
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
