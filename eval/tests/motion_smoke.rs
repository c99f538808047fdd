//! A short tour of the motion evaluation, as `sonar-eval` runs it: the corridor's first 4 m
//! (stop-and-scan), one seed, the drifting odometry. The whole chain (the simulator's robot
//! carrying the head, the driver's decoder, the fusion engine and the feature tracker with and
//! without localisation, the report) works, and localisation holds the pose within the issue's
//! 5 cm and 2° while the odometry drifts off. The whole tours' figures: the motion section of
//! `docs/results.md`.

use sonar_eval::motion::{self, MotionSettings, Placement};

#[test]
fn a_short_corridor_tour_is_localised_within_5_cm_and_2_degrees() {
    let mut settings = MotionSettings::drifting(vec![1], 4.0, 1);
    settings.scenes = vec!["corridor".into()];
    let scenes = motion::evaluate(&settings).unwrap();
    let run = &scenes[0].runs[0];
    assert!(run.driven_m >= 4.0, "{}", run.driven_m);
    let worst = |p: Placement| {
        let f = run.get(p).unwrap();
        let position = f
            .sweeps
            .iter()
            .map(|s| s.error.position_m)
            .fold(0.0, f64::max);
        let heading = f
            .sweeps
            .iter()
            .map(|s| s.error.heading_deg)
            .fold(0.0, f64::max);
        (position, heading, f)
    };
    let (truth_m, truth_deg, truth) = worst(Placement::Truth);
    let (odometry_m, odometry_deg, _) = worst(Placement::Odometry);
    let (localized_m, localized_deg, localized) = worst(Placement::Localized);
    // The true poses are what the engine interpolates: no error to speak of.
    assert!(
        truth_m < 1e-3 && truth_deg < 0.01,
        "{truth_m} m, {truth_deg}°"
    );
    // 3 % and 2°/m over 4 m: the odometry is off by centimetres and degrees.
    assert!(
        odometry_m > 0.05 && odometry_deg > 2.0,
        "{odometry_m} m, {odometry_deg}°"
    );
    assert!(localized.fixes > 0);
    assert!(
        localized_m < 0.05 && localized_deg < 2.0,
        "{localized_m} m, {localized_deg}°"
    );
    assert!(truth.walls.median_distance_m.is_some() && truth.walls.coverage > 0.0);

    let md = motion::markdown(&settings, &scenes);
    for needle in [
        "### Motion and localisation on the tour scenes",
        "| localisation keeps every sweep's pose within 5 cm and 2° | corridor |",
        "| odometry + localisation |",
        "The odometry's drift learnt by the end of the tour, per seed:",
    ] {
        assert!(md.contains(needle), "{needle} missing from\n{md}");
    }
}
