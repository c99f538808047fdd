//! How the pings of one 6° group become one time of flight.
//!
//! The paper averages four pings per 6° to suppress transients. A plain mean fails in two ways that a
//! single-sonar mapper meets all the time (`../shared/docs/sensor-facts.md`):
//! - a spurious short echo drags the mean towards the sensor;
//! - near the edge of a small object's effective cone some pings hear the object and others the wall
//!   behind it, and their mean is a range where nothing is (a phantom).
//!
//! So the policy is: drop pings with no echo, drop echoes outside the sensor's range, then keep the
//! *dominant cluster* — the largest set of echoes whose ranges lie within a tolerance of each other
//! (ties go to the nearest cluster: the first echo is the physically meaningful one, and the safer one
//! for obstacle avoidance) — and average only that. The cluster must have at least
//! `min_agreeing_pings` members, otherwise the reading is flagged `NO_ECHO`: one lone echo among four
//! pings is as likely a transient as a target. The raw pings always travel with the reading, so a
//! consumer can apply its own policy.

use sonar_common::ipc::flags;
use sonar_common::sensor::SensorConfig;

/// Parameters of the ping-combination policy.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PingPolicy {
    /// Echoes within this distance of each other belong to one cluster (absolute part).
    pub cluster_tolerance_m: f32,
    /// …or within this fraction of the range, whichever is larger.
    pub cluster_tolerance_rel: f32,
    /// Fewest pings that must agree for a range; capped at the number of pings.
    pub min_agreeing_pings: u8,
}

impl Default for PingPolicy {
    fn default() -> Self {
        Self {
            // Three wavelengths of jitter (≈ 8.7 mm each at 40 kHz) plus the makers' 3–4 cm accuracy
            // make 3 cm the smallest spread that still separates an object from the wall behind it.
            cluster_tolerance_m: 0.03,
            cluster_tolerance_rel: 0.03,
            min_agreeing_pings: 2,
        }
    }
}

/// The outcome for one group of pings.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Combined {
    /// Mean echo time of the accepted pings (µs); for `OUT_OF_RANGE`, of the out-of-range echoes;
    /// 0 with `NO_ECHO`.
    pub tof_us: f32,
    pub distance_m: f32,
    pub pings_used: u8,
    /// `NO_ECHO`, `OUT_OF_RANGE`, `PINGS_REJECTED` bits.
    pub flags: u32,
}

/// Applies the policy to raw echo times (µs, 0 = no echo).
pub fn combine_pings(echo_us: &[u32], sensor: &SensorConfig, policy: &PingPolicy) -> Combined {
    let mut in_range = [0f32; sonar_common::ipc::MAX_PINGS];
    let mut n_in = 0;
    let (mut far_sum, mut n_far) = (0f32, 0u8);
    for &t in echo_us.iter().take(in_range.len()) {
        if t == 0 || t > sensor.echo_timeout_us {
            continue;
        }
        let range = sensor.range_m(t as f32);
        if range < sensor.min_range_m || range > sensor.max_range_m {
            far_sum += t as f32;
            n_far += 1;
        } else {
            in_range[n_in] = t as f32;
            n_in += 1;
        }
    }
    let in_range = &mut in_range[..n_in];
    in_range.sort_by(f32::total_cmp);

    let (start, len) = dominant_cluster(in_range, sensor, policy);
    let needed = usize::from(policy.min_agreeing_pings.max(1)).min(echo_us.len().max(1));
    if len == 0 || len < needed {
        let rejected = if n_in > 0 { flags::PINGS_REJECTED } else { 0 };
        if n_in == 0 && n_far > 0 {
            let tof_us = far_sum / f32::from(n_far);
            return Combined {
                tof_us,
                distance_m: sensor.range_m(tof_us),
                pings_used: n_far,
                flags: flags::OUT_OF_RANGE
                    | if usize::from(n_far) < echo_us.len() {
                        flags::PINGS_REJECTED
                    } else {
                        0
                    },
            };
        }
        return Combined {
            tof_us: 0.0,
            distance_m: 0.0,
            pings_used: 0,
            flags: flags::NO_ECHO | rejected,
        };
    }
    let cluster = &in_range[start..start + len];
    let tof_us = cluster.iter().sum::<f32>() / len as f32;
    Combined {
        tof_us,
        distance_m: sensor.range_m(tof_us),
        pings_used: len as u8,
        flags: if len < echo_us.len() {
            flags::PINGS_REJECTED
        } else {
            0
        },
    }
}

/// Largest window of sorted echo times whose ranges span at most the tolerance; the nearest on ties.
fn dominant_cluster(
    sorted_us: &[f32],
    sensor: &SensorConfig,
    policy: &PingPolicy,
) -> (usize, usize) {
    let mut best = (0, 0);
    for start in 0..sorted_us.len() {
        let near = sensor.range_m(sorted_us[start]);
        let tolerance = policy
            .cluster_tolerance_m
            .max(policy.cluster_tolerance_rel * near);
        let len = sorted_us[start..]
            .iter()
            .take_while(|&&t| sensor.range_m(t) - near <= tolerance)
            .count();
        if len > best.1 {
            best = (start, len);
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    fn us(range_m: f32) -> u32 {
        SensorConfig::default().echo_time_us(range_m).round() as u32
    }

    fn combine(echo: &[u32]) -> Combined {
        combine_pings(echo, &SensorConfig::default(), &PingPolicy::default())
    }

    #[test]
    fn four_agreeing_pings_are_averaged() {
        let c = combine(&[us(1.00), us(1.01), us(0.99), us(1.00)]);
        assert_eq!(c.flags, 0);
        assert_eq!(c.pings_used, 4);
        assert!((c.distance_m - 1.0).abs() < 2e-3, "{c:?}");
    }

    #[test]
    fn a_spurious_short_echo_is_rejected_not_averaged() {
        let c = combine(&[us(2.0), us(0.31), us(2.01), us(1.99)]);
        assert_eq!(c.flags, flags::PINGS_REJECTED);
        assert_eq!(c.pings_used, 3);
        assert!((c.distance_m - 2.0).abs() < 5e-3, "{c:?}");
    }

    #[test]
    fn mixed_object_and_wall_pings_never_give_a_phantom_between_them() {
        let c = combine(&[us(1.0), us(2.0), us(1.0), us(2.0)]);
        // Tie between the post and the wall: the nearest wins, and nothing lies at 1.5 m.
        assert!((c.distance_m - 1.0).abs() < 5e-3, "{c:?}");
        let c = combine(&[us(1.0), us(2.0), us(2.0), us(2.0)]);
        assert!((c.distance_m - 2.0).abs() < 5e-3, "{c:?}");
    }

    #[test]
    fn no_echo_and_too_few_agreeing_pings() {
        let c = combine(&[0, 0, 0, 0]);
        assert_eq!(c.flags, flags::NO_ECHO);
        let c = combine(&[0, 0, 0, us(1.5)]);
        assert_eq!(c.flags, flags::NO_ECHO | flags::PINGS_REJECTED);
        let c = combine(&[0, us(1.5), 0, us(1.51)]);
        assert_eq!(c.flags, flags::PINGS_REJECTED);
        assert_eq!(c.pings_used, 2);
    }

    #[test]
    fn echoes_beyond_max_range_are_out_of_range_not_obstacles() {
        let c = combine(&[us(4.5), us(4.6), 0, 0]);
        assert_eq!(c.flags, flags::OUT_OF_RANGE | flags::PINGS_REJECTED);
        assert!(c.distance_m > 4.0);
    }

    #[test]
    fn a_single_ping_reading_needs_only_itself() {
        let c = combine(&[us(0.5)]);
        assert_eq!(c.flags, 0);
        assert_eq!(c.pings_used, 1);
    }
}
