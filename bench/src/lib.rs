//! What the benchmark program and its examples share: the synthetic readings `sonar-bench
//! throughput` offers (sweeps of 50, −147° … 147° in 6° steps, forth and back, walls 1.5–3.5 m
//! away, every reading at its own range), which `examples/bench_readings.rs` fuses in one process
//! for instruction counts; and those of a robot driving round a circle in a square room
//! ([`moving_pose`], [`room_reading`]), where no sweep repeats another.

use sonar_common::ipc::{LAYOUT_VERSION, Pose2D, Reading, flags};

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

/// The moving robot drives this far per sweep of 50 readings, metres …
pub const MOVING_STEP_M: f64 = 0.1;
/// … round a circle of this radius about the room's centre, metres …
pub const MOVING_RADIUS_M: f64 = 1.5;
/// … in a square room of walls this far from its centre, metres.
pub const ROOM_HALF_SIDE_M: f64 = 3.0;

/// The moving robot's pose while it takes reading `seq`, stamped `stamp_ns`: sweep `seq / 50` of
/// the circle, heading along it.
pub fn moving_pose(seq: u64, stamp_ns: u64) -> Pose2D {
    let angle = (seq / 50) as f64 * MOVING_STEP_M / MOVING_RADIUS_M;
    Pose2D {
        stamp_ns,
        x_m: (MOVING_RADIUS_M * angle.cos()) as f32,
        y_m: (MOVING_RADIUS_M * angle.sin()) as f32,
        theta_rad: (angle + std::f64::consts::FRAC_PI_2) as f32,
        layout_version: LAYOUT_VERSION,
    }
}

/// Reading `seq` of the moving robot ([`moving_pose`]): the bearings of [`synthetic_reading`],
/// the range to the square room's walls along the beam's axis (no echo beyond 4 m).
pub fn room_reading(seq: u64, host_stamp_ns: u64) -> Reading {
    let pose = moving_pose(seq, host_stamp_ns);
    let mut reading = synthetic_reading(seq, host_stamp_ns);
    let bearing = f64::from(pose.theta_rad) + f64::from(reading.angle_deg).to_radians();
    let (dx, dy) = (bearing.cos(), bearing.sin());
    // Along the axis, the nearest wall: x = ±h or y = ±h, whichever the ray meets first.
    let to_wall = |position: f32, direction: f64| {
        if direction.abs() < 1e-9 {
            f64::INFINITY
        } else {
            (ROOM_HALF_SIDE_M.copysign(direction) - f64::from(position)) / direction
        }
    };
    let distance = to_wall(pose.x_m, dx).min(to_wall(pose.y_m, dy));
    if distance > f64::from(reading.max_range_m) {
        reading.flags |= flags::NO_ECHO;
        reading.distance_m = 0.0;
        reading.tof_us = 0.0;
    } else {
        reading.distance_m = distance as f32;
        reading.tof_us = reading.distance_m * 2.0 / reading.speed_of_sound_mps * 1e6;
    }
    reading
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

    #[test]
    fn the_moving_robot_hears_the_room_walls_from_a_new_place_each_sweep() {
        // Sweep 0 from (1.5, 0) heading +y: the reading at -87° looks along about +x, 1.5 m to
        // the wall x = 3; the one at +3° along about +y, to y = 3.
        let pose = moving_pose(0, 0);
        assert_eq!((pose.x_m, pose.y_m), (1.5, 0.0));
        let east = room_reading(10, 0);
        assert_eq!(east.angle_deg, -87.0);
        let expected = 1.5 / (3.0f64.to_radians()).cos();
        assert!(
            (f64::from(east.distance_m) - expected).abs() < 1e-4,
            "{east:?}"
        );
        let north = room_reading(25, 0);
        assert_eq!(north.angle_deg, 3.0);
        let expected = 3.0 / (3.0f64.to_radians()).cos();
        assert!(
            (f64::from(north.distance_m) - expected).abs() < 1e-4,
            "{north:?}"
        );
        // Beyond 4 m (the far corner's way): no echo.
        assert!((0..50).any(|seq| room_reading(seq, 0).has(flags::NO_ECHO)));
        // The next sweep is taken 10 cm on.
        let next = moving_pose(50, 0);
        let moved = f64::from((next.x_m - pose.x_m).hypot(next.y_m - pose.y_m));
        assert!((moved - MOVING_STEP_M).abs() < 1e-3, "{moved}");
    }
}
