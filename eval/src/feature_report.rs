//! The feature evaluation's figures: medians and worst cases over every bearing and seed, the
//! aims' verdicts, and the grid presets on the same runs; rendered as Markdown.

use std::fmt::Write as _;

use sonar_features::FeatureKind;

use crate::features::{
    CHI2_1SIGMA, CHI2_95, CROWD_M, Family, FeatureResults, FeatureSettings, LevelResults,
    RESOLVED_M, Run, Scored,
};

/// Median and worst of a set of figures (worst = largest).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Spread {
    pub median: f64,
    pub worst: f64,
    pub count: usize,
}

impl Spread {
    /// `None` for no values.
    pub fn of(values: impl IntoIterator<Item = f64>) -> Option<Self> {
        let mut v: Vec<f64> = values.into_iter().collect();
        if v.is_empty() {
            return None;
        }
        v.sort_by(f64::total_cmp);
        let n = v.len();
        let median = if n % 2 == 1 {
            v[n / 2]
        } else {
            (v[n / 2 - 1] + v[n / 2]) / 2.0
        };
        Some(Self {
            median,
            worst: v[n - 1],
            count: n,
        })
    }
}

/// Which map of a run: after its first sweep, or after all.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum When {
    First,
    All,
}

fn scored(run: &Run, when: When) -> &Scored {
    match when {
        When::First => &run.first,
        When::All => &run.all,
    }
}

/// Position errors of the posts (matched ones), and how many were missed.
pub fn post_errors(family: &Family, when: When) -> (Option<Spread>, usize) {
    let all = family
        .runs
        .iter()
        .flat_map(|r| scored(r, when).posts.iter());
    let missed = all.clone().filter(|e| e.is_none()).count();
    (Spread::of(all.flatten().copied()), missed)
}

/// Wall angle (absolute, degrees) and distance (absolute, metres) errors of the expected walls,
/// and how many of them were missed.
pub fn wall_errors(family: &Family, when: When) -> (Option<Spread>, Option<Spread>, usize) {
    let all = family
        .runs
        .iter()
        .flat_map(|r| scored(r, when).walls.iter());
    let missed = all.clone().filter(|e| e.is_none()).count();
    let found: Vec<_> = all.flatten().collect();
    (
        Spread::of(found.iter().map(|e| e.angle_deg.abs())),
        Spread::of(found.iter().map(|e| e.distance_m.abs())),
        missed,
    )
}

/// Coverage of their walls (worst = least) and overreach (worst = most) of the expected walls'
/// segments after all sweeps.
pub fn segment_fits(family: &Family) -> (Option<Spread>, Option<Spread>) {
    let fits = || family.runs.iter().flat_map(|r| r.all.segments.iter());
    let coverage = Spread::of(fits().map(|f| -f.coverage)).map(|s| Spread {
        median: -s.median,
        worst: -s.worst,
        count: s.count,
    });
    (coverage, Spread::of(fits().map(|f| f.overreach_m)))
}

/// Position errors of the expected corners, and how many were missed.
pub fn corner_errors(family: &Family, when: When) -> (Option<Spread>, usize) {
    let all = family
        .runs
        .iter()
        .flat_map(|r| scored(r, when).corners.iter());
    let missed = all.clone().filter(|e| e.is_none()).count();
    (Spread::of(all.flatten().copied()), missed)
}

/// False features per run.
pub fn false_features(family: &Family, when: When) -> Option<Spread> {
    Spread::of(
        family
            .runs
            .iter()
            .map(|r| scored(r, when).false_features.len() as f64),
    )
}

/// Runs (after all sweeps) that resolve both posts, of all runs.
pub fn resolved(family: &Family) -> (usize, usize) {
    let ok = family
        .runs
        .iter()
        .filter(|r| r.all.resolves_posts())
        .count();
    (ok, family.runs.len())
}

/// Runs whose map shows the gap, per grid preset (`paper`, `recommended`), of all runs.
pub fn grid_gaps(family: &Family) -> [(usize, usize); 2] {
    [0, 1].map(|k| {
        let ok = family
            .runs
            .iter()
            .filter(|r| r.grid.is_some_and(|g| g.gap[k] == Some(true)))
            .count();
        (ok, family.runs.len())
    })
}

/// The post's apparent width per grid preset, and how often it was not detected.
pub fn grid_widths(family: &Family) -> [(Option<Spread>, usize); 2] {
    [0, 1].map(|k| {
        let widths = family
            .runs
            .iter()
            .filter_map(|r| r.grid.map(|g| g.width_m[k]));
        let missed = widths.clone().filter(Option::is_none).count();
        (Spread::of(widths.flatten()), missed)
    })
}

/// The smallest spacing from which every larger spacing of the sweep passes `ok` in every run.
pub fn resolved_from(spacings: &[(u32, Family)], ok: impl Fn(&Family) -> bool) -> Option<u32> {
    let last_bad = spacings.iter().rposition(|(_, f)| !ok(f));
    match last_bad {
        None => spacings.first().map(|(mm, _)| *mm),
        Some(i) => spacings.get(i + 1).map(|(mm, _)| *mm),
    }
}

/// Honesty of the reported uncertainty for one kind of feature in a group of scenes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Honesty {
    pub features: usize,
    pub median_error_m: f64,
    pub median_sigma_m: f64,
    /// √(mean d² / 2): 1 when the reported σ is the actual RMS error, below 1 when it is larger.
    pub rms_normalised: f64,
    /// Share within the 1σ ellipse (ideal 68 %) and the 95 % one.
    pub within_1sigma: f64,
    pub within_95: f64,
}

/// Over every run of `families` (after all sweeps), features of `kind`; `None` if there are none.
pub fn honesty(families: &[&Family], kind: FeatureKind) -> Option<Honesty> {
    let scores = || families.iter().flat_map(|f| f.runs.iter().map(|r| &r.all));
    let d2: Vec<f64> = scores()
        .flat_map(|s| s.mahalanobis2.iter())
        .filter(|(k, _)| *k == kind)
        .map(|(_, d)| *d)
        .collect();
    let pairs: Vec<(f64, f64)> = scores()
        .flat_map(|s| s.error_vs_sigma.iter())
        .filter(|(k, _, _)| *k == kind)
        .map(|(_, e, s)| (*e, *s))
        .collect();
    let n = d2.len();
    let share = |limit: f64| d2.iter().filter(|&&d| d <= limit).count() as f64 / n as f64;
    Some(Honesty {
        features: n,
        median_error_m: Spread::of(pairs.iter().map(|p| p.0))?.median,
        median_sigma_m: Spread::of(pairs.iter().map(|p| p.1))?.median,
        rms_normalised: (d2.iter().sum::<f64>() / n as f64 / 2.0).sqrt(),
        within_1sigma: share(CHI2_1SIGMA),
        within_95: share(CHI2_95),
    })
}

fn cm(m: f64) -> String {
    format!("{:.1} cm", m * 100.0)
}

fn spread_cm(s: Option<Spread>) -> String {
    s.map_or("–".into(), |s| {
        format!("{} / {}", cm(s.median), cm(s.worst))
    })
}

/// Feature errors are millimetres: two decimals of a centimetre.
fn fine_cm(m: f64) -> String {
    format!("{:.2} cm", m * 100.0)
}

fn spread_fine(s: Option<Spread>) -> String {
    s.map_or("–".into(), |s| {
        format!("{} / {}", fine_cm(s.median), fine_cm(s.worst))
    })
}

fn spread_deg(s: Option<Spread>) -> String {
    s.map_or("–".into(), |s| {
        format!("{:.2}° / {:.2}°", s.median, s.worst)
    })
}

fn verdict(ok: bool) -> &'static str {
    if ok { "**met**" } else { "**missed**" }
}

fn mm_cm(mm: u32) -> String {
    format!("{:.0} cm", f64::from(mm) / 10.0)
}

fn list_deg(v: &[f64]) -> String {
    v.iter()
        .map(|b| format!("{b}°"))
        .collect::<Vec<_>>()
        .join(", ")
}

/// The feature evaluation as Markdown.
pub fn markdown(settings: &FeatureSettings, r: &FeatureResults) -> String {
    let mut s = String::new();
    let runs = settings.bearings_deg.len() * settings.seeds.len();
    let _ = writeln!(
        s,
        "### Features over bearings and seeds\n\nEvery scene rotated about the sensor by {} \
         ({} bearings) × seeds {:?} = {runs} runs per scene, {} complete sweeps each; \
         median / worst over all runs.\n",
        list_deg(&settings.bearings_deg),
        settings.bearings_deg.len(),
        settings.seeds,
        settings.sweeps,
    );
    s += &profile_note(settings);

    // The aims.
    let (post_all, post_missed) = post_errors(&r.post, When::All);
    let (post_first, _) = post_errors(&r.post, When::First);
    let post_ok = post_all.is_some_and(|p| p.median <= 0.03 && p.worst <= 0.05) && post_missed == 0;
    let spacing_ok = |f: &Family| {
        let (ok, n) = resolved(f);
        ok == n
    };
    let from = resolved_from(&r.spacings, spacing_ok);
    let at_40 = r
        .spacings
        .iter()
        .find(|(mm, _)| *mm == 400)
        .map(|(_, f)| resolved(f));
    let two_ok = from.is_some_and(|mm| mm <= 300) && at_40.is_some_and(|(ok, n)| ok == n);
    let walls = [&r.room, &r.corner].map(|f| wall_errors(f, When::All));
    let corners = [&r.room, &r.corner].map(|f| corner_errors(f, When::All));
    let slanted = false_features(&r.slanted, When::All);
    let slanted_ok = slanted.is_some_and(|f| f.worst == 0.0);

    let _ = writeln!(
        s,
        "| aim | measured (median / worst) | verdict |\n|---|---|---|"
    );
    let _ = writeln!(
        s,
        "| 5 cm post at 1 m: position error ≤ 3 cm median, ≤ 5 cm worst | {} after {} sweeps \
         ({} after one); missed in {post_missed} of {runs} runs | {} |",
        spread_fine(post_all),
        settings.sweeps,
        spread_fine(post_first),
        verdict(post_ok)
    );
    let _ = writeln!(
        s,
        "| two 5 cm posts at 1 m as two point features: at ≤ 30 cm spacing, at 40 cm in every \
         run | every run from {} on{} | {} |",
        from.map_or("no spacing of the sweep".into(), mm_cm),
        at_40.map_or(String::new(), |(ok, n)| format!(
            "; 40 cm: {ok} of {n} runs"
        )),
        verdict(two_ok)
    );
    for ((name, (angle, dist, missed)), (corner, corner_missed)) in
        ["room", "corner"].iter().zip(&walls).zip(&corners)
    {
        let _ = writeln!(
            s,
            "| {name}: walls' angle ≤ 2°, perpendicular distance ≤ 2 cm; corners ≤ 3 cm | walls \
             {} and {} (missed {missed}); corners {} (missed {corner_missed}) | {} |",
            spread_deg(*angle),
            spread_fine(*dist),
            spread_fine(*corner),
            verdict(
                *missed == 0
                    && *corner_missed == 0
                    && angle.is_some_and(|a| a.worst <= 2.0)
                    && dist.is_some_and(|d| d.worst <= 0.02)
                    && corner.is_some_and(|c| c.worst <= 0.03)
            )
        );
    }
    let _ = writeln!(
        s,
        "| slanted wall: no feature | {} false features per run | {} |\n",
        slanted.map_or("–".into(), |f| format!(
            "{:.0} / {:.0}",
            f.median, f.worst
        )),
        verdict(slanted_ok)
    );

    // Partial planes.
    let _ = writeln!(
        s,
        "Partial planes: each found wall's segment (from the feet of the perpendiculars to the \
         corners on its line, grown through the `recommended` grid's occupied cells), against the \
         true wall:\n\n| scene | share of the wall covered (median / least) | reach beyond the \
         wall's ends (median / most) |\n|---|---|---|"
    );
    for f in [&r.room, &r.corner] {
        let (coverage, overreach) = segment_fits(f);
        let _ = writeln!(
            s,
            "| {} | {} | {} |",
            f.name,
            coverage.map_or("–".into(), |c| format!(
                "{:.0} % / {:.0} %",
                c.median * 100.0,
                c.worst * 100.0
            )),
            spread_fine(overreach)
        );
    }
    let _ = writeln!(s);

    // Two posts, per spacing, features against both grid presets.
    let _ = writeln!(
        s,
        "Two 5 cm posts 1 m ahead, wall at 2 m (runs where the features resolve both posts: a \
         point feature within {} of each, none other within {} of either; the grid presets: \
         runs whose map shows the gap, as in the spacing sweep):\n",
        cm(RESOLVED_M),
        cm(CROWD_M)
    );
    let _ = writeln!(
        s,
        "| centre spacing | features: both resolved | features: position error | false features \
         | `paper`: gap shown | `recommended`: gap shown |\n|---|---|---|---|---|---|"
    );
    for (mm, f) in &r.spacings {
        let (ok, n) = resolved(f);
        let [paper, rec] = grid_gaps(f);
        let _ = writeln!(
            s,
            "| {} | {ok} of {n} | {} | {} | {} of {} | {} of {} |",
            mm_cm(*mm),
            spread_fine(post_errors(f, When::All).0),
            false_features(f, When::All).map_or("–".into(), |x| format!(
                "{:.0} / {:.0}",
                x.median, x.worst
            )),
            paper.0,
            paper.1,
            rec.0,
            rec.1
        );
    }
    let grid_from = |k: usize| {
        resolved_from(&r.spacings, |f| {
            let g = grid_gaps(f)[k];
            g.0 == g.1
        })
    };
    let show = |v: Option<u32>| v.map_or("none of the sweep".into(), mm_cm);
    let _ = writeln!(
        s,
        "\nResolved in every run from: features {}, `paper` {}, `recommended` {}.\n",
        show(from),
        show(grid_from(0)),
        show(grid_from(1))
    );

    // The single post: features against the grid presets.
    let [paper_w, rec_w] = grid_widths(&r.post);
    let width = |(w, missed): (Option<Spread>, usize)| {
        format!("{} (not detected in {missed})", spread_cm(w))
    };
    let _ = writeln!(
        s,
        "The 5 cm post at 1 m in front of the wall: the grid presets' apparent width (as in \
         the scene tables) and the point feature's position error, on the same runs:\n\n\
         | method | median / worst |\n|---|---|\n\
         | grid, `paper` preset: apparent width | {} |\n\
         | grid, `recommended` preset: apparent width | {} |\n\
         | features: position error of the point feature | {} |\n",
        width(paper_w),
        width(rec_w),
        spread_fine(post_all)
    );

    // Per bearing: the grid's width depends on where the post falls on the 6° reading grid.
    let _ = writeln!(
        s,
        "The same per bearing (median over the seeds):\n\n| bearing | `paper` width | \
         `recommended` width | features: position error |\n|---|---|---|---|"
    );
    for &b in &settings.bearings_deg {
        let runs: Vec<&Run> = r
            .post
            .runs
            .iter()
            .filter(|run| run.bearing_deg == b)
            .collect();
        let width = |k: usize| {
            Spread::of(
                runs.iter()
                    .filter_map(|run| run.grid.and_then(|g| g.width_m[k])),
            )
            .map_or("–".into(), |w| cm(w.median))
        };
        let error = Spread::of(
            runs.iter()
                .filter_map(|run| run.all.posts.first().copied().flatten()),
        )
        .map_or("–".into(), |e| fine_cm(e.median));
        let _ = writeln!(s, "| {b}° | {} | {} | {error} |", width(0), width(1));
    }
    let _ = writeln!(s);

    // False features.
    let _ = writeln!(
        s,
        "False features per run (a feature that matches nothing in the scene, or a second one on \
         the same thing):\n\n| scene | after one sweep | after {} sweeps | what they were |\n\
         |---|---|---|---|",
        settings.sweeps
    );
    let mut families: Vec<(&str, &Family)> = vec![
        ("obstacle (post)", &r.post),
        ("room", &r.room),
        ("corner", &r.corner),
        ("slanted wall", &r.slanted),
        ("thick post (10 cm at 1 m)", &r.thick_post),
    ];
    let two: Vec<(String, &Family)> = r
        .spacings
        .iter()
        .map(|(mm, f)| (format!("two posts {}", mm_cm(*mm)), f))
        .collect();
    families.extend(two.iter().map(|(n, f)| (n.as_str(), *f)));
    for (name, f) in &families {
        let kinds: std::collections::BTreeMap<String, usize> = f
            .runs
            .iter()
            .flat_map(|r| r.all.false_features.iter())
            .fold(Default::default(), |mut m, (k, _)| {
                *m.entry(format!("{k:?}").to_lowercase()).or_default() += 1;
                m
            });
        let what = if kinds.is_empty() {
            "–".to_owned()
        } else {
            kinds
                .iter()
                .map(|(k, n)| format!("{n} {k}"))
                .collect::<Vec<_>>()
                .join(", ")
        };
        let fmt = |x: Option<Spread>| {
            x.map_or("–".into(), |x| {
                format!("{:.0} / {:.0}", x.median, x.worst)
            })
        };
        let _ = writeln!(
            s,
            "| {name} | {} | {} | {what} |",
            fmt(false_features(f, When::First)),
            fmt(false_features(f, When::All))
        );
    }

    // Honesty.
    let _ = writeln!(
        s,
        "\nReported uncertainty against the actual error, every matched feature of every run \
         after {} sweeps (d² = squared Mahalanobis error with 2 degrees of freedom: position for \
         points and corners, normal angle and distance for planes; the error and σ columns are \
         RMS over the two axes, a plane's angle counted as the offset it makes 1 m along the \
         wall):\n\n| features | n | median error | median reported σ | √(mean d²/2) (ideal 1) \
         | within the 1σ ellipse (ideal 68 %) | within the 95 % ellipse |\n\
         |---|---|---|---|---|---|---|",
        settings.sweeps
    );
    let two: Vec<&Family> = r.spacings.iter().map(|(_, f)| f).collect();
    let groups: [(&str, Vec<&Family>, FeatureKind); 4] = [
        ("single post (point)", vec![&r.post], FeatureKind::Point),
        ("two posts (points)", two, FeatureKind::Point),
        (
            "walls of room and corner (planes)",
            vec![&r.room, &r.corner],
            FeatureKind::Plane,
        ),
        (
            "corners of room and corner",
            vec![&r.room, &r.corner],
            FeatureKind::Corner,
        ),
    ];
    for (name, families, kind) in &groups {
        if let Some(h) = honesty(families, *kind) {
            let _ = writeln!(
                s,
                "| {name} | {} | {} | {} | {:.2} | {:.0} % | {:.0} % |",
                h.features,
                fine_cm(h.median_error_m),
                fine_cm(h.median_sigma_m),
                h.rms_normalised,
                h.within_1sigma * 100.0,
                h.within_95 * 100.0
            );
        }
    }
    s
}

/// Mean false features per run of a family.
pub fn mean_false_features(family: &Family) -> f64 {
    let n = family.runs.len().max(1) as f64;
    family
        .runs
        .iter()
        .map(|r| r.all.false_features.len() as f64)
        .sum::<f64>()
        / n
}

/// Found of expected (after all sweeps): walls and corners.
fn found(all: impl Iterator<Item = bool>) -> (usize, usize) {
    all.fold((0, 0), |(f, n), ok| (f + usize::from(ok), n + 1))
}

/// The robustness runs as Markdown: per noise level the posts, the rooms and the aims of issue 23.
/// Which sensor the scenes were heard through, when not the simulator's default: a paragraph.
fn profile_note(settings: &FeatureSettings) -> String {
    let mut s = settings.profile.0.map_or_else(String::new, |p| {
        format!(
            "Heard through the simulator's `{}` profile: its head, echoes and noise (amplitude \
             jitter, dropouts, ghosts), the features set for its echoes as its owner would set \
             them; a noise level replaces its range noise and keeps the rest.",
            p.name()
        )
    });
    if let Some(c) = settings.calibrated {
        if !s.is_empty() {
            s.push(' ');
        }
        s += &format!(
            "Calibrated first as `sonar calibrate-range` does (the built-in room's wall 1.2 m \
             ahead): {:+.1} mm (σ {:.1} mm) taken off every range the features see.",
            c.offset_m * 1000.0,
            c.sigma_m * 1000.0
        );
    }
    if !s.is_empty() {
        s += "\n\n";
    }
    s
}

pub fn levels_markdown(settings: &FeatureSettings, levels: &[LevelResults]) -> String {
    let mut s = String::new();
    let runs = settings.bearings_deg.len() * settings.seeds.len();
    let _ = writeln!(
        s,
        "### Features under sensor noise\n\nEvery scene rotated by {} × seeds {:?} ({runs} runs; \
         the off-centre room {} runs, {} sensor positions), {} sweeps each, at each noise level: \
         Gaussian range noise per ping on top of the simulator's own, and dropouts (pings that \
         hear nothing); scored against each scene's true geometry, median / worst over the runs.\n",
        list_deg(&settings.bearings_deg),
        settings.seeds,
        runs * crate::features::OFF_CENTRE.len(),
        crate::features::OFF_CENTRE.len(),
        settings.sweeps,
    );
    s += &profile_note(settings);
    let _ = write!(
        s,
        "| noise | 5 cm post at 1 m: error (missed) | two posts resolved at"
    );
    for mm in &settings.level_spacings_mm {
        let _ = write!(s, " {} |", mm_cm(*mm));
    }
    let _ = writeln!(
        s,
        " false features per scene (mean over all scenes) | aims |"
    );
    let _ = writeln!(
        s,
        "|---|---|{}---|---|",
        "---|".repeat(settings.level_spacings_mm.len())
    );
    for l in levels {
        let (post, missed) = post_errors(&l.post, When::All);
        let _ = write!(
            s,
            "| {} | {} ({missed}) |",
            l.level.label(),
            spread_fine(post)
        );
        for (_, f) in &l.spacings {
            let (ok, n) = resolved(f);
            let _ = write!(s, " {ok} of {n} |");
        }
        let families = l.families();
        let mean_false = families.iter().map(|f| mean_false_features(f)).sum::<f64>()
            / families.len().max(1) as f64;
        let at_20 = l
            .spacings
            .iter()
            .find(|(mm, _)| *mm == 200)
            .map(|(_, f)| resolved(f));
        let aims = [
            post.is_some_and(|p| p.worst <= 0.02) && missed == 0,
            at_20.is_some_and(|(ok, n)| ok * 10 >= n * 9),
            mean_false <= 1.0,
        ];
        let _ = writeln!(
            s,
            " {mean_false:.2} | post ≤ 2 cm worst: {}; two at 20 cm ≥ 90 %: {}; ≤ 1 false: {} |",
            verdict(aims[0]),
            verdict(aims[1]),
            verdict(aims[2])
        );
    }
    let _ = writeln!(
        s,
        "\nWalls, corners and false features per scene and noise level (found of expected after \
         all sweeps; errors of the found ones: walls' normal angle and perpendicular distance, \
         corners' position):\n\n| noise | scene | walls found | wall angle | wall distance | \
         corners found | corner error | false features per run (mean / worst) | what they were |\n\
         |---|---|---|---|---|---|---|---|---|"
    );
    for l in levels {
        for f in [&l.room, &l.off_centre, &l.l_room, &l.corner, &l.slanted] {
            let (angle, dist, _) = wall_errors(f, When::All);
            let walls = found(
                f.runs
                    .iter()
                    .flat_map(|r| r.all.walls.iter().map(Option::is_some)),
            );
            let corners = found(
                f.runs
                    .iter()
                    .flat_map(|r| r.all.corners.iter().map(Option::is_some)),
            );
            let (corner, _) = corner_errors(f, When::All);
            let kinds: std::collections::BTreeMap<String, usize> = f
                .runs
                .iter()
                .flat_map(|r| r.all.false_features.iter())
                .fold(Default::default(), |mut m, (k, _)| {
                    *m.entry(format!("{k:?}").to_lowercase()).or_default() += 1;
                    m
                });
            let what = kinds
                .iter()
                .map(|(k, n)| format!("{n} {k}"))
                .collect::<Vec<_>>()
                .join(", ");
            let worst = false_features(f, When::All).map_or(0.0, |x| x.worst);
            let _ = writeln!(
                s,
                "| {} | {} | {} of {} | {} | {} | {} of {} | {} | {:.2} / {worst:.0} | {} |",
                l.level.label(),
                f.name,
                walls.0,
                walls.1,
                spread_deg(angle),
                spread_fine(dist),
                corners.0,
                corners.1,
                spread_fine(corner),
                mean_false_features(f),
                if what.is_empty() { "–".into() } else { what }
            );
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::features::{GridFigures, WallError};

    fn run(posts: &[Option<f64>], gap: [Option<bool>; 2]) -> Run {
        let scored = Scored {
            posts: posts.to_vec(),
            walls: vec![Some(WallError {
                angle_deg: -0.5,
                distance_m: 0.001,
            })],
            ..Scored::default()
        };
        Run {
            bearing_deg: 0.0,
            seed: 1,
            first: scored.clone(),
            all: scored,
            grid: Some(GridFigures {
                width_m: [Some(0.4), None],
                gap,
            }),
        }
    }

    fn family(runs: Vec<Run>) -> Family {
        Family {
            name: "x".into(),
            runs,
        }
    }

    #[test]
    fn spreads_are_medians_and_worst_cases() {
        let s = Spread::of([3.0, 1.0, 2.0, 10.0]).unwrap();
        assert_eq!((s.median, s.worst, s.count), (2.5, 10.0, 4));
        assert_eq!(Spread::of([]), None);
    }

    #[test]
    fn figures_over_runs() {
        let f = family(vec![
            run(&[Some(0.01), Some(0.02)], [Some(false), Some(true)]),
            run(&[Some(0.01), None], [Some(false), Some(true)]),
        ]);
        let (errors, missed) = post_errors(&f, When::All);
        assert_eq!((errors.unwrap().worst, missed), (0.02, 1));
        assert_eq!(resolved(&f), (1, 2));
        assert_eq!(grid_gaps(&f), [(0, 2), (2, 2)]);
        let [paper, rec] = grid_widths(&f);
        assert_eq!((paper.0.unwrap().median, paper.1), (0.4, 0));
        assert_eq!((rec.0, rec.1), (None, 2));
        let (angle, _, missed) = wall_errors(&f, When::First);
        assert_eq!((angle.unwrap().worst, missed), (0.5, 0));
    }

    #[test]
    fn resolved_from_is_the_start_of_the_last_good_stretch() {
        let ok = |b: bool| family(vec![run(&[Some(if b { 0.01 } else { 0.2 }); 2], [None; 2])]);
        let sweep = vec![
            (100, ok(true)),
            (200, ok(false)),
            (300, ok(true)),
            (400, ok(true)),
        ];
        assert_eq!(resolved_from(&sweep, |f| resolved(f).0 == 1), Some(300));
        assert_eq!(
            resolved_from(&sweep[2..], |f| resolved(f).0 == 1),
            Some(300)
        );
        assert_eq!(resolved_from(&sweep[..2], |f| resolved(f).0 == 1), None);
    }
}
