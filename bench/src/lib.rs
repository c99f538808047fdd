//! What the benchmark program and its examples share: the synthetic readings `sonar-bench
//! throughput` offers (sweeps of 50, −147° … 147° in 6° steps, forth and back, walls 1.5–3.5 m
//! away, every reading at its own range), which `examples/bench_readings.rs` fuses in one process
//! for instruction counts.

use sonar_common::ipc::{LAYOUT_VERSION, Reading};

/// A reading the driver could have published: reading `seq` of the synthetic room, stamped
/// `host_stamp_ns`.
pub fn synthetic_reading(seq: u64, host_stamp_ns: u64) -> Reading {
    let sweep = seq / 50;
    let index = (seq % 50) as f32;
    let (angle_deg, direction) = if sweep.is_multiple_of(2) {
        (-147.0 + 6.0 * index, 1)
    } else {
        (147.0 - 6.0 * index, -1)
    };
    let distance_m = 1.5 + ((angle_deg + 150.0) % 20.0) / 10.0;
    Reading {
        seq,
        host_stamp_ns,
        layout_version: LAYOUT_VERSION,
        sweep_id: sweep as u32,
        angle_deg,
        beam_half_angle_deg: 30.0,
        tof_us: distance_m * 2.0 / 343.0 * 1e6,
        distance_m,
        speed_of_sound_mps: 343.0,
        min_range_m: 0.03,
        max_range_m: 4.0,
        direction,
        mode: 1,
        ping_count: 4,
        pings_used: 4,
        ..Reading::default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn synthetic_sweeps_go_forth_and_back_within_range() {
        let first = synthetic_reading(0, 0);
        let last = synthetic_reading(49, 0);
        let back = synthetic_reading(50, 0);
        assert_eq!(
            (first.angle_deg, last.angle_deg, back.angle_deg),
            (-147.0, 147.0, 147.0)
        );
        assert_eq!((first.sweep_id, back.sweep_id), (0, 1));
        assert_eq!((first.direction, back.direction), (1, -1));
        for seq in 0..100 {
            let r = synthetic_reading(seq, 0);
            assert!((1.5..=3.5).contains(&r.distance_m), "{r:?}");
        }
    }
}
