//! The robot that carries the head: a path of waypoints driven on the simulated clock, and the
//! wheel odometry it would report. Pure, like the firmware: time comes in as a number.
//!
//! - [`Trajectory`]: the pose as a pure function of *motion time*: drive straight from waypoint to
//!   waypoint at [`RobotSpec::speed_mps`], turn in place at each one at
//!   [`RobotSpec::turn_rate_dps`] the shorter way; with `loop` back to the first and round again.
//! - [`Robot`]: motion time from the simulator's clock. Scan-while-driving: they are the same.
//!   Stop-and-scan: a small state machine that halts at the start and at every waypoint reached
//!   until the head has completed one sweep *begun after the stop* (the sweep under way on arrival
//!   was partly taken on the move), then drives on; motion time is the clock less the time stood.
//!   A head that does not scan keeps a stop-and-scan robot waiting.
//! - [`Odometry`]: dead reckoning from the true motion between two samples, as wheel encoders
//!   measure it (the increment in the robot's frame), with a scale error on distance, a heading
//!   drift per metre driven and white noise per step, seeded.
//! - [`Rover`]: the three on the simulator's µs clock, sampled at the pose rate.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use serde::Deserialize;

use crate::geometry::{Pose, Vec2, angle_diff_rad, rotate};

/// Waypoints closer than this give no heading between them.
const MIN_LEG_M: f64 = 1e-3;

/// How the robot combines driving and scanning; `mode` in `[robot]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Mode {
    /// Drive to a waypoint, stop, let the head complete one full sweep, drive on.
    StopAndScan,
    /// Drive on continuously; every ping is taken from wherever the robot is at that instant.
    #[default]
    ScanWhileDriving,
}

/// The `[robot]` table of a scene.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RobotSpec {
    /// Metres; the robot starts at the first, heading towards the second.
    pub waypoints: Vec<Vec2>,
    #[serde(default = "default_speed_mps")]
    pub speed_mps: f64,
    #[serde(default = "default_turn_rate_dps")]
    pub turn_rate_dps: f64,
    #[serde(default)]
    pub mode: Mode,
    /// After the last waypoint, back to the first and round again.
    #[serde(default, rename = "loop")]
    pub looped: bool,
}

fn default_speed_mps() -> f64 {
    0.2
}

fn default_turn_rate_dps() -> f64 {
    45.0
}

impl RobotSpec {
    /// Checks what [`Trajectory`] relies on: at least two finite waypoints, consecutive ones apart
    /// (also the closing pair with `loop`), positive finite rates.
    pub fn validate(&self) -> Result<(), String> {
        let n = self.waypoints.len();
        if n < 2 {
            return Err(format!(
                "robot.waypoints: need at least 2 (start and where it heads), got {n}"
            ));
        }
        if let Some(i) = self.waypoints.iter().position(|w| !w.is_finite()) {
            return Err(format!(
                "robot.waypoints[{}]: coordinate is not a finite number",
                i + 1
            ));
        }
        for (name, value) in [
            ("speed_mps", self.speed_mps),
            ("turn_rate_dps", self.turn_rate_dps),
        ] {
            if !(value.is_finite() && value > 0.0) {
                return Err(format!("robot.{name} must be a number > 0, got {value}"));
            }
        }
        for (i, pair) in self.waypoints.windows(2).enumerate() {
            if (pair[1] - pair[0]).norm() < MIN_LEG_M {
                return Err(format!(
                    "robot.waypoints[{}] and [{}] coincide: no heading between them",
                    i + 1,
                    i + 2
                ));
            }
        }
        if self.looped && (self.waypoints[0] - self.waypoints[n - 1]).norm() < MIN_LEG_M {
            return Err(
                "robot.waypoints: with loop = true the robot returns to the first waypoint by \
                 itself; leave out the repeated last one"
                    .into(),
            );
        }
        Ok(())
    }

    /// The straight legs the robot drives, the closing one of a loop included.
    pub fn legs(&self) -> impl Iterator<Item = (Vec2, Vec2)> + '_ {
        let n = self.waypoints.len();
        let closing = usize::from(self.looped);
        (0..n - 1 + closing).map(move |i| (self.waypoints[i], self.waypoints[(i + 1) % n]))
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Leg {
    Drive { from: Vec2, to: Vec2, heading: f64 },
    Turn { at: Vec2, from: f64, by: f64 },
}

#[derive(Debug, Clone, Copy, PartialEq)]
struct TimedLeg {
    leg: Leg,
    start_s: f64,
    duration_s: f64,
}

/// The robot's pose as a pure function of motion time (seconds driving or turning).
#[derive(Debug, Clone, PartialEq)]
pub struct Trajectory {
    legs: Vec<TimedLeg>,
    /// One pass: every leg once (with `loop`, the period).
    period_s: f64,
    looped: bool,
    /// Motion time of each arrival at a waypoint within one pass.
    arrivals_s: Vec<f64>,
}

impl Trajectory {
    /// The path of a validated spec ([`RobotSpec::validate`]).
    pub fn new(spec: &RobotSpec) -> Self {
        let turn_rate = spec.turn_rate_dps.to_radians();
        let drives: Vec<(Vec2, Vec2, f64)> = spec
            .legs()
            .map(|(from, to)| (from, to, (to - from).angle_deg().to_radians()))
            .collect();
        let mut legs = Vec::new();
        let mut arrivals_s = Vec::new();
        let mut t = 0.0;
        let mut push = |leg: Leg, duration_s: f64, t: &mut f64| {
            legs.push(TimedLeg {
                leg,
                start_s: *t,
                duration_s,
            });
            *t += duration_s;
        };
        for (i, &(from, to, heading)) in drives.iter().enumerate() {
            push(
                Leg::Drive { from, to, heading },
                (to - from).norm() / spec.speed_mps,
                &mut t,
            );
            arrivals_s.push(t);
            // At the waypoint, turn towards the next leg; a loop's last turn faces the first leg
            // again, so that every pass starts as the first did.
            let next = match drives.get(i + 1) {
                Some(next) => Some(next.2),
                None if spec.looped => Some(drives[0].2),
                None => None,
            };
            if let Some(next) = next {
                let by = angle_diff_rad(next, heading);
                push(
                    Leg::Turn {
                        at: to,
                        from: heading,
                        by,
                    },
                    by.abs() / turn_rate,
                    &mut t,
                );
            }
        }
        Self {
            legs,
            period_s: t,
            looped: spec.looped,
            arrivals_s,
        }
    }

    /// Motion time of one pass over the waypoints (the period with `loop`).
    pub fn pass_s(&self) -> f64 {
        self.period_s
    }

    /// Pose after `t_s` seconds of motion: the start before 0, the end after the last leg.
    pub fn pose_at(&self, t_s: f64) -> Pose {
        let t = if self.looped && t_s > self.period_s {
            t_s.rem_euclid(self.period_s)
        } else {
            t_s.max(0.0)
        };
        let leg = self
            .legs
            .iter()
            .find(|l| t < l.start_s + l.duration_s)
            .map(|l| (l.leg, (t - l.start_s) / l.duration_s))
            // Past the end (or a loop exactly at its period): where the last leg ends.
            .or_else(|| self.legs.last().map(|l| (l.leg, 1.0)));
        match leg {
            Some((Leg::Drive { from, to, heading }, f)) => Pose {
                at: from + (to - from) * f,
                heading_rad: heading,
            },
            Some((Leg::Turn { at, from, by }, f)) => Pose {
                at,
                heading_rad: angle_diff_rad(from + by * f, 0.0),
            },
            None => Pose::default(),
        }
    }

    /// Motion time of the `k`-th stop of a stop-and-scan robot: 0 (the start), then each arrival
    /// at a waypoint, pass after pass with `loop`; `None` past the last waypoint otherwise.
    pub fn stop_s(&self, k: usize) -> Option<f64> {
        let Some(j) = k.checked_sub(1) else {
            return Some(0.0);
        };
        let per_pass = self.arrivals_s.len();
        if self.looped {
            Some((j / per_pass) as f64 * self.period_s + self.arrivals_s[j % per_pass])
        } else {
            self.arrivals_s.get(j).copied()
        }
    }
}

/// A stop-and-scan robot standing at a stop.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Wait {
    /// Motion time of the stop.
    motion_s: f64,
    /// Clock time it arrived.
    since_s: f64,
    /// A sweep has begun since it arrived: the one whose end releases it.
    sweep_begun: bool,
}

/// The robot on the simulator's clock (seconds of simulated time).
#[derive(Debug, Clone, PartialEq)]
pub struct Robot {
    trajectory: Trajectory,
    mode: Mode,
    /// Clock time spent standing at stops so far.
    stood_s: f64,
    next_stop: usize,
    wait: Option<Wait>,
}

impl Robot {
    pub fn new(spec: &RobotSpec) -> Self {
        Self {
            trajectory: Trajectory::new(spec),
            mode: spec.mode,
            stood_s: 0.0,
            next_stop: 0,
            wait: None,
        }
    }

    /// Moves the robot to clock time `t_s` (never earlier than the last call) and returns its pose.
    pub fn advance(&mut self, t_s: f64) -> Pose {
        if self.mode == Mode::ScanWhileDriving {
            return self.trajectory.pose_at(t_s);
        }
        if let Some(wait) = self.wait {
            return self.trajectory.pose_at(wait.motion_s);
        }
        let motion_s = t_s - self.stood_s;
        match self.trajectory.stop_s(self.next_stop) {
            Some(stop) if motion_s >= stop => {
                self.wait = Some(Wait {
                    motion_s: stop,
                    since_s: stop + self.stood_s,
                    sweep_begun: false,
                });
                self.trajectory.pose_at(stop)
            }
            _ => self.trajectory.pose_at(motion_s),
        }
    }

    /// Whether a stop-and-scan robot is standing for its sweep.
    pub fn is_waiting(&self) -> bool {
        self.wait.is_some()
    }

    /// The head began a sweep.
    pub fn sweep_started(&mut self) {
        if let Some(wait) = &mut self.wait {
            wait.sweep_begun = true;
        }
    }

    /// The head ended a sweep at clock time `t_s`: one begun during the stop releases the robot.
    pub fn sweep_ended(&mut self, t_s: f64) {
        if let Some(wait) = self.wait.take_if(|w| w.sweep_begun) {
            self.stood_s += (t_s - wait.since_s).max(0.0);
            self.next_stop += 1;
        }
    }
}

/// Errors of the wheel odometry; `[odometry]` in a scene file, or the `--odom-*` flags.
#[derive(Debug, Clone, Copy, PartialEq, Default, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OdometryParams {
    /// Fraction by which distance is misreported: 0.03 reports every metre driven as 1.03 m (a
    /// wheel radius 3 % larger than the software assumes).
    pub scale_error: f64,
    /// Heading error gained per metre driven, degrees, counter-clockwise positive (unequal wheels).
    pub heading_drift_deg_per_m: f64,
    /// Standard deviation of white noise on the distance of each step that moves, metres.
    pub noise_m: f64,
    /// Standard deviation of white noise on the heading change of each step that moves, degrees.
    pub noise_deg: f64,
}

impl OdometryParams {
    pub fn validate(&self) -> Result<(), String> {
        if !(self.scale_error.is_finite() && self.scale_error > -1.0) {
            return Err(format!(
                "odometry.scale_error must be a number > -1, got {}",
                self.scale_error
            ));
        }
        if !self.heading_drift_deg_per_m.is_finite() {
            return Err("odometry.heading_drift_deg_per_m must be a number".into());
        }
        for (name, value) in [("noise_m", self.noise_m), ("noise_deg", self.noise_deg)] {
            if !(value.is_finite() && value >= 0.0) {
                return Err(format!("odometry.{name} must be >= 0, got {value}"));
            }
        }
        Ok(())
    }
}

/// Dead reckoning from the true motion, with [`OdometryParams`]' errors.
#[derive(Debug, Clone)]
pub struct Odometry {
    params: OdometryParams,
    rng: ChaCha8Rng,
    truth: Pose,
    estimate: Pose,
}

impl Odometry {
    /// Starts at the true pose: the robot is put down where it knows it stands.
    pub fn new(params: OdometryParams, start: Pose, seed: u64) -> Self {
        Self {
            params,
            rng: ChaCha8Rng::seed_from_u64(seed),
            truth: start,
            estimate: start,
        }
    }

    fn gaussian(&mut self, sigma: f64) -> f64 {
        // No draw without noise, so that zero errors reproduce the truth exactly.
        if sigma > 0.0 {
            let z: f64 = StandardNormal.sample(&mut self.rng);
            sigma * z
        } else {
            0.0
        }
    }

    /// One step: the robot is now at `truth`; returns the odometry's estimate.
    pub fn update(&mut self, truth: Pose) -> Pose {
        let p = self.params;
        // What the encoders measure: the motion in the robot's frame at the previous pose.
        let local = rotate(truth.at - self.truth.at, -self.truth.heading_rad);
        let turned = angle_diff_rad(truth.heading_rad, self.truth.heading_rad);
        self.truth = truth;
        let distance = local.norm();
        if distance == 0.0 && turned == 0.0 {
            // Wheels that do not turn count nothing: a robot standing still does not drift.
            return self.estimate;
        }
        let reported = if distance > 0.0 {
            let noisy = distance * (1.0 + p.scale_error) + self.gaussian(p.noise_m);
            local * (noisy / distance)
        } else {
            local
        };
        let heading_noise = self.gaussian(p.noise_deg.to_radians());
        let turned = turned + p.heading_drift_deg_per_m.to_radians() * distance + heading_noise;
        self.estimate.at = self.estimate.at + rotate(reported, self.estimate.heading_rad);
        self.estimate.heading_rad = angle_diff_rad(self.estimate.heading_rad + turned, 0.0);
        self.estimate
    }
}

/// A pose sample: the truth and what the odometry reports at simulated time `t_us`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PoseSample {
    pub t_us: u64,
    pub truth: Pose,
    pub odometry: Pose,
}

/// Robot and odometry on the simulator's µs clock, sampled at a fixed rate of simulated time.
#[derive(Debug, Clone)]
pub struct Rover {
    robot: Robot,
    odometry: Odometry,
    period_us: u64,
    next_sample_us: u64,
}

impl Rover {
    /// `rate_hz`: samples per simulated second (> 0); `seed` fixes the odometry's noise.
    pub fn new(spec: &RobotSpec, odometry: OdometryParams, rate_hz: f64, seed: u64) -> Self {
        let mut robot = Robot::new(spec);
        let start = robot.advance(0.0);
        Self {
            robot,
            odometry: Odometry::new(odometry, start, seed),
            period_us: ((1e6 / rate_hz).round() as u64).max(1),
            next_sample_us: 0,
        }
    }

    /// Moves to simulated time `now_us` through every sample instant up to it, handing each
    /// sample to `sample`; returns the true pose at `now_us`, where the head pings from.
    pub fn advance(&mut self, now_us: u64, mut sample: impl FnMut(PoseSample)) -> Pose {
        while self.next_sample_us <= now_us {
            let t_us = self.next_sample_us;
            let truth = self.robot.advance(t_us as f64 / 1e6);
            let odometry = self.odometry.update(truth);
            sample(PoseSample {
                t_us,
                truth,
                odometry,
            });
            self.next_sample_us += self.period_us;
        }
        self.robot.advance(now_us as f64 / 1e6)
    }

    /// The head began a sweep.
    pub fn sweep_started(&mut self) {
        self.robot.sweep_started();
    }

    /// The head ended a sweep at simulated time `now_us`.
    pub fn sweep_ended(&mut self, now_us: u64) {
        self.robot.sweep_ended(now_us as f64 / 1e6);
    }
}

#[cfg(test)]
mod tests {
    use std::f64::consts::{FRAC_PI_2, PI};

    use super::*;

    fn spec(waypoints: &[[f64; 2]], mode: Mode, looped: bool) -> RobotSpec {
        RobotSpec {
            waypoints: waypoints.iter().map(|&w| w.into()).collect(),
            speed_mps: 0.2,
            turn_rate_dps: 45.0,
            mode,
            looped,
        }
    }

    fn close(a: Pose, b: Pose) -> bool {
        (a.at - b.at).norm() < 1e-9 && angle_diff_rad(a.heading_rad, b.heading_rad).abs() < 1e-9
    }

    #[track_caller]
    fn assert_pose(got: Pose, x: f64, y: f64, heading_deg: f64) {
        let want = Pose::new(x, y, heading_deg.to_radians());
        assert!(close(got, want), "got {got:?}, want {want:?}");
    }

    /// 1 m east, then 1 m north: 5 s, a 2 s turn of 90°, 5 s.
    fn ell(mode: Mode, looped: bool) -> RobotSpec {
        spec(&[[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]], mode, looped)
    }

    #[test]
    fn drives_straight_and_turns_in_place() {
        let t = Trajectory::new(&ell(Mode::ScanWhileDriving, false));
        assert_pose(t.pose_at(-1.0), 0.0, 0.0, 0.0);
        assert_pose(t.pose_at(0.0), 0.0, 0.0, 0.0);
        assert_pose(t.pose_at(2.5), 0.5, 0.0, 0.0);
        assert_pose(t.pose_at(5.0), 1.0, 0.0, 0.0);
        // 45°/s: half the turn after 1 s, in place.
        assert_pose(t.pose_at(6.0), 1.0, 0.0, 45.0);
        assert_pose(t.pose_at(7.0), 1.0, 0.0, 90.0);
        assert_pose(t.pose_at(9.5), 1.0, 0.5, 90.0);
        assert!((t.pass_s() - 12.0).abs() < 1e-12);
        // No loop: it stays at the end.
        assert_pose(t.pose_at(12.0), 1.0, 1.0, 90.0);
        assert_pose(t.pose_at(100.0), 1.0, 1.0, 90.0);
    }

    #[test]
    fn turns_the_shorter_way() {
        // East then south-west-ish: a right turn of 135°, through −45° and −90°.
        let t = Trajectory::new(&spec(
            &[[0.0, 0.0], [1.0, 0.0], [0.0, -1.0]],
            Mode::ScanWhileDriving,
            false,
        ));
        assert_pose(t.pose_at(6.0), 1.0, 0.0, -45.0);
        assert_pose(t.pose_at(8.0), 1.0, 0.0, -135.0);
        // Back along the same line: a half turn, 4 s.
        let back = Trajectory::new(&spec(
            &[[0.0, 0.0], [1.0, 0.0], [0.0, 0.0]],
            Mode::ScanWhileDriving,
            false,
        ));
        assert!((back.pass_s() - 14.0).abs() < 1e-12);
        assert!((back.pose_at(9.0).heading_rad.abs() - PI).abs() < 1e-9);
    }

    #[test]
    fn a_loop_closes_and_repeats() {
        // A 1 m square: 4 × (5 s + 2 s) = 28 s a pass; the last turn faces east again.
        let square = spec(
            &[[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]],
            Mode::ScanWhileDriving,
            true,
        );
        let t = Trajectory::new(&square);
        assert!((t.pass_s() - 28.0).abs() < 1e-12);
        assert_pose(t.pose_at(21.0 + 2.5), 0.0, 0.5, -90.0);
        assert_pose(t.pose_at(27.0), 0.0, 0.0, -45.0);
        for k in 0..3 {
            let p = k as f64 * 28.0;
            assert_pose(t.pose_at(p + 2.5), 0.5, 0.0, 0.0);
            assert_pose(t.pose_at(p + 14.0 + 2.5), 0.5, 1.0, 180.0);
        }
        assert_eq!(t.stop_s(0), Some(0.0));
        assert_eq!(t.stop_s(1), Some(5.0));
        assert_eq!(t.stop_s(4), Some(26.0));
        assert_eq!(t.stop_s(5), Some(33.0));
        let once = Trajectory::new(&ell(Mode::StopAndScan, false));
        assert_eq!(once.stop_s(2), Some(12.0));
        assert_eq!(once.stop_s(3), None);
    }

    #[test]
    fn scan_while_driving_follows_the_clock() {
        let mut r = Robot::new(&ell(Mode::ScanWhileDriving, false));
        r.sweep_started();
        r.sweep_ended(1.0);
        assert_pose(r.advance(2.5), 0.5, 0.0, 0.0);
        assert!(!r.is_waiting());
        assert_pose(r.advance(9.5), 1.0, 0.5, 90.0);
    }

    #[test]
    fn stop_and_scan_waits_for_one_whole_sweep_at_each_stop() {
        let mut r = Robot::new(&ell(Mode::StopAndScan, false));
        // At the start it stands until a sweep begun there has ended.
        assert_pose(r.advance(0.0), 0.0, 0.0, 0.0);
        assert!(r.is_waiting());
        r.sweep_ended(1.0); // the end of a sweep begun before: not enough
        assert_pose(r.advance(3.0), 0.0, 0.0, 0.0);
        r.sweep_started();
        assert_pose(r.advance(10.0), 0.0, 0.0, 0.0);
        r.sweep_ended(12.0);
        assert!(!r.is_waiting());
        // 12 s stood: motion time is the clock less 12 s.
        assert_pose(r.advance(14.5), 0.5, 0.0, 0.0);
        // Arrives at the second waypoint at 17 s and waits there, even when the clock jumps.
        assert_pose(r.advance(30.0), 1.0, 0.0, 0.0);
        assert!(r.is_waiting());
        r.sweep_started();
        r.sweep_ended(40.0);
        // Stood 23 s more (since 17 s): the turn starts at 40 s.
        assert_pose(r.advance(41.0), 1.0, 0.0, 45.0);
        assert_pose(r.advance(42.0 + 2.5), 1.0, 0.5, 90.0);
        // The last waypoint is a stop too; after its sweep the robot stays there.
        assert_pose(r.advance(100.0), 1.0, 1.0, 90.0);
        assert!(r.is_waiting());
        r.sweep_started();
        r.sweep_ended(110.0);
        assert!(!r.is_waiting());
        assert_pose(r.advance(200.0), 1.0, 1.0, 90.0);
        assert!(!r.is_waiting());
    }

    #[test]
    fn stop_and_scan_in_a_loop_stops_at_the_start_each_round() {
        let mut r = Robot::new(&spec(
            &[[0.0, 0.0], [1.0, 0.0], [1.0, 1.0]],
            Mode::StopAndScan,
            true,
        ));
        let mut clock = 0.0;
        let mut stops = Vec::new();
        // A sweep every 12 s; record where the robot stands for each.
        while stops.len() < 5 {
            let pose = r.advance(clock);
            if r.is_waiting() {
                stops.push(pose.at);
                r.sweep_started();
                clock += 12.0;
                r.sweep_ended(clock);
            } else {
                clock += 0.05;
            }
        }
        let want = [[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 0.0], [1.0, 0.0]];
        for (got, want) in stops.iter().zip(want) {
            assert!((*got - want.into()).norm() < 1e-9, "{stops:?}");
        }
    }

    #[test]
    fn invalid_paths_are_clear_errors() {
        let cases = [
            (spec(&[[0.0, 0.0]], Mode::StopAndScan, false), "at least 2"),
            (
                spec(&[[0.0, 0.0], [f64::NAN, 1.0]], Mode::StopAndScan, false),
                "waypoints[2]: coordinate is not a finite number",
            ),
            (
                spec(&[[0.0, 0.0], [0.0, 0.0]], Mode::StopAndScan, false),
                "coincide",
            ),
            (
                spec(
                    &[[0.0, 0.0], [1.0, 0.0], [0.0, 0.0]],
                    Mode::StopAndScan,
                    true,
                ),
                "leave out the repeated last one",
            ),
        ];
        for (s, want) in cases {
            let err = s.validate().unwrap_err();
            assert!(err.contains(want), "{err}");
        }
        let mut s = ell(Mode::ScanWhileDriving, false);
        s.speed_mps = 0.0;
        assert!(s.validate().unwrap_err().contains("speed_mps must be"));
        s.speed_mps = 0.2;
        s.turn_rate_dps = f64::INFINITY;
        assert!(s.validate().unwrap_err().contains("turn_rate_dps must be"));
        let bad = OdometryParams {
            noise_m: -1.0,
            ..Default::default()
        };
        assert!(bad.validate().unwrap_err().contains("noise_m"));
        let bad = OdometryParams {
            scale_error: -1.0,
            ..Default::default()
        };
        assert!(bad.validate().unwrap_err().contains("scale_error"));
    }

    /// The true poses of a square loop at 20 Hz, and the odometry's for `params`.
    fn run(params: OdometryParams, seed: u64, seconds: u64) -> Vec<PoseSample> {
        let square = spec(
            &[[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]],
            Mode::ScanWhileDriving,
            true,
        );
        let mut rover = Rover::new(&square, params, 20.0, seed);
        let mut samples = Vec::new();
        rover.advance(seconds * 1_000_000, |s| samples.push(s));
        samples
    }

    #[test]
    fn odometry_without_errors_is_the_truth() {
        let samples = run(OdometryParams::default(), 1, 60);
        assert_eq!(samples.len(), 60 * 20 + 1);
        assert_eq!(samples[1].t_us, 50_000);
        for s in &samples {
            assert!(close(s.truth, s.odometry), "{s:?}");
        }
    }

    #[test]
    fn a_scale_error_lengthens_the_distance_reported() {
        let params = OdometryParams {
            scale_error: 0.03,
            ..Default::default()
        };
        // First leg only (5 s east): 1 m driven, 1.03 m reported, straight on.
        let samples = run(params, 1, 5);
        let last = samples.last().unwrap();
        assert_pose(last.truth, 1.0, 0.0, 0.0);
        assert_pose(last.odometry, 1.03, 0.0, 0.0);
        // Turning in place is not scaled: after the turn the heading is still right.
        let samples = run(params, 1, 7);
        assert_pose(samples.last().unwrap().odometry, 1.03, 0.0, 90.0);
    }

    #[test]
    fn heading_drift_accumulates_per_metre_driven() {
        let params = OdometryParams {
            heading_drift_deg_per_m: 2.0,
            ..Default::default()
        };
        let samples = run(params, 1, 60);
        for s in samples.iter().step_by(20) {
            // Along the square the distance driven is known from the truth: 0.2 m/s while driving.
            let driven = driven_by(s.t_us as f64 / 1e6);
            let error = angle_diff_rad(s.odometry.heading_rad, s.truth.heading_rad).to_degrees();
            assert!((error - 2.0 * driven).abs() < 1e-6, "{s:?}: {error}°");
        }
        // Turned by the drift, the estimate leaves the true path sideways (to the left).
        let end_of_first_leg = &samples[100];
        assert!(end_of_first_leg.odometry.at.y > 0.0);
    }

    /// Metres driven after `t` s on the 1 m square (5 s per side, 2 s per corner).
    fn driven_by(t: f64) -> f64 {
        let rounds = (t / 7.0).floor();
        rounds * 1.0 + ((t - rounds * 7.0).min(5.0)) * 0.2
    }

    #[test]
    fn noise_is_seeded_and_white() {
        let params = OdometryParams {
            noise_m: 0.001,
            noise_deg: 0.1,
            ..Default::default()
        };
        let a = run(params, 7, 30);
        let b = run(params, 7, 30);
        let c = run(params, 8, 30);
        assert_eq!(a, b);
        assert_ne!(a, c);
        let off = |s: &[PoseSample]| {
            let last = s.last().unwrap();
            (last.odometry.at - last.truth.at).norm()
        };
        assert!(off(&a) > 0.0 && off(&a) < 1.0, "{}", off(&a));
        // A robot that stands still reports no motion: no noise either.
        let mut odometry = Odometry::new(params, Pose::new(1.0, 2.0, FRAC_PI_2), 3);
        for _ in 0..100 {
            assert_eq!(
                odometry.update(Pose::new(1.0, 2.0, FRAC_PI_2)),
                Pose::new(1.0, 2.0, FRAC_PI_2)
            );
        }
    }
}
