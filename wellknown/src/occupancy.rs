//! A map cell as ROS's occupancy value, which both message families carry.

use sonar_common::ipc::CELL_UNKNOWN;

/// A cell as ROS's occupancy: −1 never observed, else the probability in percent (0–100), rounded
/// half up from the cell's `p · 254`.
pub fn occupancy(cell: u8) -> i8 {
    if cell == CELL_UNKNOWN {
        -1
    } else {
        ((u32::from(cell) * 100 + 127) / 254) as i8
    }
}
