//! The colour code of the probability map, after the paper's Fig. 7: blue (certainly free) through
//! a pale even-odds colour to red (certainly occupied), and a dark neutral grey for cells no reading
//! has reached. The terminal viewer, every picture file and the evaluation's figures use
//! [`probability_rgb`] (through [`cell_rgb`] for snapshot cells), so a saved map looks like the
//! screen.

use sonar_common::ipc::decode_probability;

/// Never-observed cells: a dark neutral grey, unlike any colour of the probability scale.
pub const UNKNOWN_RGB: [u8; 3] = [48, 48, 48];
/// p = 0.
pub const FREE_RGB: [u8; 3] = [25, 85, 200];
/// p = 0.5.
pub const EVEN_RGB: [u8; 3] = [225, 225, 205];
/// p = 1.
pub const OCCUPIED_RGB: [u8; 3] = [205, 25, 25];

/// The colour of the features overlay (the viewer's and the PNG's): green, a hue the colour code
/// (blue, pale, red, grey) never uses, bright enough for dark and light cells alike.
pub const FEATURE_RGB: [u8; 3] = [60, 255, 60];

/// The colour of *tentative* features, heard from one place only (no
/// [`CONFIRMED`](sonar_common::ipc::feature_flags::CONFIRMED) flag): amber, apart from the
/// confirmed ones' green and from the colour code's hues, because such a feature may be a phantom.
pub const TENTATIVE_FEATURE_RGB: [u8; 3] = [255, 176, 0];

/// The colour of an occupancy probability (clamped to 0..=1): linear from [`FREE_RGB`] to
/// [`EVEN_RGB`] to [`OCCUPIED_RGB`]; [`UNKNOWN_RGB`] for `None`, a never-observed cell.
pub fn probability_rgb(p: Option<f32>) -> [u8; 3] {
    let Some(p) = p else {
        return UNKNOWN_RGB;
    };
    let p = p.clamp(0.0, 1.0);
    let (from, to, t) = if p <= 0.5 {
        (FREE_RGB, EVEN_RGB, p * 2.0)
    } else {
        (EVEN_RGB, OCCUPIED_RGB, (p - 0.5) * 2.0)
    };
    std::array::from_fn(|i| {
        (f32::from(from[i]) + (f32::from(to[i]) - f32::from(from[i])) * t).round() as u8
    })
}

/// The colour of a snapshot cell value: [`probability_rgb`] of its decoded probability.
pub fn cell_rgb(cell: u8) -> [u8; 3] {
    probability_rgb(decode_probability(cell))
}

#[cfg(test)]
mod tests {
    use super::*;
    use sonar_common::ipc::CELL_UNKNOWN;

    #[test]
    fn probabilities_run_free_to_occupied_and_none_is_unknown() {
        assert_eq!(probability_rgb(Some(0.0)), FREE_RGB);
        assert_eq!(probability_rgb(Some(0.5)), EVEN_RGB);
        assert_eq!(probability_rgb(Some(1.0)), OCCUPIED_RGB);
        assert_eq!(probability_rgb(Some(-0.3)), FREE_RGB);
        assert_eq!(probability_rgb(Some(1.7)), OCCUPIED_RGB);
        assert_eq!(probability_rgb(None), UNKNOWN_RGB);
        let dist = |a: [u8; 3], b: [u8; 3]| {
            a.iter()
                .zip(b)
                .map(|(&x, y)| (i32::from(x) - i32::from(y)).abs())
                .sum::<i32>()
        };
        // No probability is drawn anywhere near the unknown grey.
        for i in 0..=100 {
            let p = i as f32 / 100.0;
            let c = probability_rgb(Some(p));
            assert!(dist(c, UNKNOWN_RGB) > 150, "p = {p} {c:?}");
        }
    }

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
