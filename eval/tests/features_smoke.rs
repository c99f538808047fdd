//! A brief run of the feature evaluation, as `sonar-eval` does it, on two bearings, one seed and
//! two sweeps: the whole chain (simulated head, driver's decoder, features, grid presets,
//! report) works and the aims hold on this small sample.

use sonar_eval::feature_report::{self, When};
use sonar_eval::features::{FeatureSettings, evaluate};

#[test]
fn the_feature_evaluation_runs_and_meets_its_aims_on_a_small_sample() {
    let settings = FeatureSettings {
        bearings_deg: vec![0.0, 2.625],
        seeds: vec![1],
        sweeps: 2,
        spacings_mm: vec![200, 400],
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
