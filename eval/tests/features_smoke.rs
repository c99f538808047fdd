//! A brief run of the feature evaluation, as `sonar-eval` does it, on two bearings, one seed and
//! two sweeps: the whole chain (simulated head, driver's decoder, features, grid presets,
//! report) works and the aims hold on this small sample.

use sonar_eval::feature_report::{self, When};
use sonar_eval::features::{FeatureSettings, NoiseLevel, evaluate, evaluate_levels};
use sonar_eval::pipeline::ProfileChoice;

#[test]
fn the_feature_evaluation_runs_and_meets_its_aims_on_a_small_sample() {
    let settings = FeatureSettings {
        bearings_deg: vec![0.0, 2.625],
        seeds: vec![1],
        sweeps: 2,
        spacings_mm: vec![200, 400],
        levels: Vec::new(),
        level_spacings_mm: Vec::new(),
        profile: ProfileChoice(None),
        calibrated: None,
    };
    let r = evaluate(&settings).unwrap();
    let (post, missed) = feature_report::post_errors(&r.post, When::All);
    assert_eq!(missed, 0);
    assert!(post.unwrap().worst <= 0.05, "{post:?}");
    for (mm, f) in &r.spacings {
        assert_eq!(feature_report::resolved(f), (2, 2), "{mm} mm");
    }
    for f in [&r.room, &r.corner] {
        let (angle, distance, missed) = feature_report::wall_errors(f, When::All);
        assert_eq!(missed, 0, "{}", f.name);
        assert!(angle.unwrap().worst <= 2.0 && distance.unwrap().worst <= 0.02);
        let (corner, missed) = feature_report::corner_errors(f, When::All);
        assert_eq!(missed, 0);
        assert!(corner.unwrap().worst <= 0.03);
    }
    assert_eq!(
        feature_report::false_features(&r.slanted, When::All)
            .unwrap()
            .worst,
        0.0
    );
    let md = feature_report::markdown(&settings, &r);
    for needle in [
        "### Features over bearings and seeds",
        "| 5 cm post at 1 m",
        "| 40 cm | 2 of 2 |",
        "| slanted wall | 0 / 0 | 0 / 0 | – |",
        "| grid, `recommended` preset: apparent width |",
        "| single post (point) |",
    ] {
        assert!(md.contains(needle), "{needle} missing from\n{md}");
    }
}

/// The robustness runs at a hobby sensor's noise (σ = 1 cm + 1 % of the range), briefly: the
/// issue's aims on the post and two posts 20 cm apart, and the square room with the sensor off
/// its centre and the L room found whole, on two bearings, one seed, three sweeps (what one sweep
/// of two from a place heard is withheld, and a faint wall may be heard by one of two only).
#[test]
fn the_features_hold_at_a_hobby_sensors_noise_on_a_small_sample() {
    let settings = FeatureSettings {
        bearings_deg: vec![0.0, 2.625],
        seeds: vec![1],
        sweeps: 3,
        spacings_mm: Vec::new(),
        levels: vec![NoiseLevel::parse("10+1%").unwrap()],
        level_spacings_mm: vec![200],
        profile: ProfileChoice(None),
        calibrated: None,
    };
    let levels = evaluate_levels(&settings).unwrap();
    let l = &levels[0];
    let (post, missed) = feature_report::post_errors(&l.post, When::All);
    assert_eq!(missed, 0);
    assert!(post.unwrap().worst <= 0.02, "{post:?}");
    assert_eq!(feature_report::resolved(&l.spacings[0].1), (2, 2));
    for f in [&l.room, &l.off_centre, &l.l_room] {
        let (_, _, missed) = feature_report::wall_errors(f, When::All);
        let (_, corners_missed) = feature_report::corner_errors(f, When::All);
        // The L room's corner 4 cm behind the foot of its wall (1.4σ at that range) may be
        // missed in a run of two sweeps.
        let allowed = usize::from(f.name == "l-room");
        assert!(
            missed == 0 && corners_missed <= allowed,
            "{}: {missed} walls, {corners_missed} corners missed",
            f.name
        );
    }
    let md = feature_report::levels_markdown(&settings, &levels);
    assert!(
        md.contains("| σ = 10 mm + 1.0 % | room, off-centre |"),
        "{md}"
    );
}
