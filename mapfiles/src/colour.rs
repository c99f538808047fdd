//! The colour code of the probability map, after the paper's Fig. 7: blue (certainly free) through
//! a pale even-odds colour to red (certainly occupied), and a dark neutral grey for cells no reading
//! has reached. The terminal viewer and every picture file use [`cell_rgb`], so a saved map looks
//! like the screen.

use sonar_common::ipc::{CELL_PROBABILITY_SCALE, CELL_UNKNOWN};

/// Never-observed cells: a dark neutral grey, unlike any colour of the probability scale.
pub const UNKNOWN_RGB: [u8; 3] = [48, 48, 48];
/// p = 0.
pub const FREE_RGB: [u8; 3] = [25, 85, 200];
/// p = 0.5.
pub const EVEN_RGB: [u8; 3] = [225, 225, 205];
/// p = 1.
pub const OCCUPIED_RGB: [u8; 3] = [205, 25, 25];

/// The colour of a snapshot cell value: linear from [`FREE_RGB`] to [`EVEN_RGB`] to
/// [`OCCUPIED_RGB`], and [`UNKNOWN_RGB`] for never observed.
pub fn cell_rgb(cell: u8) -> [u8; 3] {
    if cell == CELL_UNKNOWN {
        return UNKNOWN_RGB;
    }
    let p = f32::from(cell) / CELL_PROBABILITY_SCALE;
    let (from, to, t) = if p <= 0.5 {
        (FREE_RGB, EVEN_RGB, p * 2.0)
    } else {
        (EVEN_RGB, OCCUPIED_RGB, (p - 0.5) * 2.0)
    };
    std::array::from_fn(|i| {
        (f32::from(from[i]) + (f32::from(to[i]) - f32::from(from[i])) * t).round() as u8
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_scale_runs_from_blue_to_red_and_unknown_stands_apart() {
        assert_eq!(cell_rgb(0), FREE_RGB);
        assert_eq!(cell_rgb(127), EVEN_RGB);
        assert_eq!(cell_rgb(254), OCCUPIED_RGB);
        assert_eq!(cell_rgb(CELL_UNKNOWN), UNKNOWN_RGB);
        let blueness = |v: u8| {
            let [r, _, b] = cell_rgb(v);
            i32::from(b) - i32::from(r)
        };
        for v in 1..=254u8 {
            assert!(blueness(v) <= blueness(v - 1), "at {v}");
            assert_ne!(cell_rgb(v), UNKNOWN_RGB);
        }
    }
}
