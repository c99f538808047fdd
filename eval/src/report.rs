//! The evaluation itself: every scene through the pipeline and both presets, its figures, its
//! picture, and the spacing sweep; rendered as Markdown.

use std::fmt::Write as _;

use anyhow::{Context, Result};
use sonar_common::ipc::Reading;
use sonar_common::sensor::SensorConfig;
use sonar_fusion::Preset;
use sonar_sim::{Post, Scene};

use crate::image::{self, Canvas, Window};
use crate::metrics::{
    Gap, MapView, Visibility, WallFit, Width, apparent_width, gap_between, passing_readings,
    peak_near, wall_fit,
};
use crate::pipeline::{Maps, Scan, capture, two_posts};

/// A post's occupied region is followed this far in range from the post's centre.
pub const WIDTH_WINDOW_M: f64 = 0.25;
/// The gap test looks this far in front of and behind the posts' near faces.
pub const GAP_DEPTH_M: f64 = 0.05;
/// A wall sample is covered by an occupied cell centre within this many cells.
pub const COVER_TOLERANCE_CELLS: f64 = 2.0;
/// Margin around the scene in the pictures: enough to show the room's corner arcs (1.7 m from the
/// sensor, 0.5 m beyond its walls).
const PICTURE_MARGIN_M: f64 = 0.6;

/// How a run is set up.
#[derive(Debug, Clone, PartialEq)]
pub struct Settings {
    /// Complete sweeps per scene.
    pub sweeps: u32,
    /// Seed of the simulator's echo noise.
    pub seed: u64,
    /// Centre spacings of the two-post sweep, millimetres.
    pub spacings_mm: Vec<u32>,
    /// Pixels per grid cell in the pictures.
    pub scale: usize,
}

/// A way of drawing the map.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method {
    /// The paper's basic method: the latest range per 6° bin drawn as an arc across the beam.
    Basic,
    /// The probability method with a fusion preset.
    Probability(Preset),
}

impl Method {
    pub const ALL: [Method; 3] = [
        Method::Basic,
        Method::Probability(Preset::Paper),
        Method::Probability(Preset::Recommended),
    ];

    pub fn label(self) -> String {
        match self {
            Method::Basic => "basic".into(),
            Method::Probability(p) => format!("probability, `{p}` preset"),
        }
    }

    pub fn short(self) -> &'static str {
        match self {
            Method::Basic => "basic",
            Method::Probability(Preset::Paper) => "paper",
            Method::Probability(Preset::Recommended) => "recommended",
        }
    }
}

/// The three maps of one capture.
#[derive(Debug)]
pub struct MethodMaps {
    pub basic: MapView,
    pub paper: MapView,
    pub recommended: MapView,
}

impl MethodMaps {
    /// Fuses the readings with both presets; the basic raster is the same for both (one radar
    /// array per reading angle), taken from the `paper` mapper.
    pub fn build(readings: &[Reading]) -> Result<Self> {
        let paper = Maps::fuse(readings, Preset::Paper)?;
        let recommended = Maps::fuse(readings, Preset::Recommended)?;
        let beam = readings.first().map_or_else(
            || SensorConfig::default().beam_half_angle_deg,
            |r| r.beam_half_angle_deg,
        );
        Ok(Self {
            basic: paper.basic(beam),
            paper: paper.probability(),
            recommended: recommended.probability(),
        })
    }

    pub fn get(&self, method: Method) -> &MapView {
        match method {
            Method::Basic => &self.basic,
            Method::Probability(Preset::Paper) => &self.paper,
            Method::Probability(Preset::Recommended) => &self.recommended,
        }
    }
}

/// The figures of one method on one scene.
#[derive(Debug, Clone, PartialEq)]
pub struct MethodResult {
    pub method: Method,
    /// Apparent width of each post, in the scene's order.
    pub widths: Vec<Option<Width>>,
    /// Highest value near each post.
    pub peaks: Vec<Option<f32>>,
    /// The gap between the first two posts, if the scene has two.
    pub gap: Option<Gap>,
    pub walls: WallFit,
}

/// One scene's run.
#[derive(Debug, Clone)]
pub struct SceneResult {
    pub name: String,
    pub scan: Scan,
    pub readings: usize,
    pub simulated_s: f64,
    /// Angle and range (`None` = no echo) of the readings of the first sweep, in sweep order.
    pub first_sweep: Vec<(f32, Option<f32>)>,
    pub posts: Vec<Post>,
    /// Readings (all sweeps) aimed between the first two posts that heard past them.
    pub passing: Option<usize>,
    pub methods: Vec<MethodResult>,
}

/// The figures of every method on `maps` against `scene`'s truth.
pub fn measure(scene: &Scene, scan: Scan, maps: &MethodMaps) -> Vec<MethodResult> {
    let sensor = SensorConfig::default();
    let (from_deg, to_deg) = scan.reach_deg(&sensor);
    let visibility = Visibility {
        from_deg,
        to_deg,
        max_range_m: f64::from(sensor.max_range_m),
    };
    Method::ALL
        .iter()
        .map(|&method| {
            let map = maps.get(method);
            let posts = scene.posts();
            MethodResult {
                method,
                widths: posts
                    .iter()
                    .map(|p| apparent_width(map, p.centre, p.radius, WIDTH_WINDOW_M))
                    .collect(),
                peaks: posts
                    .iter()
                    .map(|p| peak_near(map, p.centre, p.radius))
                    .collect(),
                gap: match posts {
                    [a, b, ..] => gap_between(map, a.centre, b.centre, a.radius, GAP_DEPTH_M),
                    _ => None,
                },
                walls: wall_fit(
                    map,
                    scene.walls(),
                    |p| scene.distance_to_surface(p),
                    visibility,
                    COVER_TOLERANCE_CELLS,
                ),
            }
        })
        .collect()
}

/// Runs one scene and draws its picture.
pub fn evaluate_scene(scene: &Scene, settings: &Settings) -> Result<(SceneResult, Canvas)> {
    let scan = Scan::for_scene(scene);
    let cap = capture(scene.clone(), scan, settings.sweeps, settings.seed)
        .with_context(|| format!("simulating scene {}", scene.name))?;
    let maps =
        MethodMaps::build(&cap.readings).with_context(|| format!("fusing scene {}", scene.name))?;
    let methods = measure(scene, scan, &maps);
    let first = cap.readings.first().map(|r| r.sweep_id);
    let result = SceneResult {
        name: scene.name.clone(),
        scan,
        readings: cap.readings.len(),
        simulated_s: cap.duration_s,
        first_sweep: cap
            .readings
            .iter()
            .filter(|r| Some(r.sweep_id) == first)
            .map(|r| (r.angle_deg, r.is_valid_range().then_some(r.distance_m)))
            .collect(),
        posts: scene.posts().to_vec(),
        passing: passing(scene, &cap.readings),
        methods,
    };
    Ok((result, picture(scene, &maps, settings.scale)))
}

/// Basic | probability | actual setup, one row for the `paper` preset and one for the
/// recommended one.
pub fn picture(scene: &Scene, maps: &MethodMaps, scale: usize) -> Canvas {
    let g = maps.basic.geometry();
    let window = Window::around(scene, g, PICTURE_MARGIN_M);
    let basic = image::map_panel(&maps.basic, window, scale, image::basic_rgb);
    let truth = image::truth_panel(scene, g, window, scale);
    let rows: Vec<Vec<Canvas>> = [&maps.paper, &maps.recommended]
        .into_iter()
        .map(|p| {
            vec![
                basic.clone(),
                image::map_panel(p, window, scale, image::probability_rgb),
                truth.clone(),
            ]
        })
        .collect();
    image::compose(&rows, Some(1))
}

/// Readings aimed between the scene's first two posts that reached at least [`PASSING_BEYOND_M`]
/// past them.
fn passing(scene: &Scene, readings: &[Reading]) -> Option<usize> {
    match scene.posts() {
        [a, b, ..] => Some(passing_readings(
            readings,
            a.centre,
            b.centre,
            PASSING_BEYOND_M,
        )),
        _ => None,
    }
}

/// A reading aimed between two posts passed them if its range reaches this far past them.
pub const PASSING_BEYOND_M: f64 = 0.2;

/// One spacing of the two-post sweep.
#[derive(Debug, Clone, PartialEq)]
pub struct SpacingResult {
    pub spacing_mm: u32,
    /// Per method in [`Method::ALL`] order.
    pub gaps: Vec<Option<Gap>>,
    /// Readings that passed between the posts, of all readings.
    pub passing: usize,
    pub readings: usize,
}

/// Two 5 cm posts at 1 m, wall at 2 m, for every spacing of the settings.
pub fn spacing_sweep(settings: &Settings) -> Result<Vec<SpacingResult>> {
    settings
        .spacings_mm
        .iter()
        .map(|&mm| {
            let s = f64::from(mm) / 1000.0;
            let scene = two_posts(s)?;
            let scan = Scan::for_scene(&scene);
            let cap = capture(scene.clone(), scan, settings.sweeps, settings.seed)
                .with_context(|| format!("simulating two posts {mm} mm apart"))?;
            let maps = MethodMaps::build(&cap.readings)?;
            let results = measure(&scene, scan, &maps);
            tracing::info!(spacing_mm = mm, "spacing done");
            Ok(SpacingResult {
                spacing_mm: mm,
                gaps: results.iter().map(|r| r.gap).collect(),
                passing: passing(&scene, &cap.readings).unwrap_or(0),
                readings: cap.readings.len(),
            })
        })
        .collect()
}

/// The smallest spacing resolved by method `k`, and the smallest from which every larger
/// spacing of the sweep is resolved too.
pub fn smallest_resolved(sweep: &[SpacingResult], k: usize) -> (Option<u32>, Option<u32>) {
    let ok = |r: &SpacingResult| r.gaps[k].is_some_and(|g| g.resolved);
    let first = sweep.iter().find(|r| ok(r)).map(|r| r.spacing_mm);
    let from = sweep
        .iter()
        .rposition(|r| !ok(r))
        .map_or(sweep.first(), |i| sweep.get(i + 1))
        .map(|r| r.spacing_mm);
    (first, from)
}

fn cm(m: f64) -> String {
    format!("{:.1} cm", m * 100.0)
}

fn width_cell(w: Option<Width>, peak: Option<f32>) -> String {
    let peak = peak.map_or("–".into(), |p| format!("{p:.2}"));
    match w {
        Some(w) => format!("{} (peak {peak})", cm(w.width_m)),
        None => format!("not detected (peak {peak})"),
    }
}

fn gap_cell(g: Option<Gap>) -> String {
    match g {
        None => "posts overlap".into(),
        Some(g) => format!(
            "{} (min {:.2} at {:+.1}°)",
            if g.resolved { "yes" } else { "no" },
            g.min_score,
            g.bearing_deg
        ),
    }
}

fn scan_text(scan: Scan) -> String {
    match scan {
        Scan::Full => "full scan".into(),
        Scan::Local { from_deg, to_deg } => format!("local scan {from_deg}°…{to_deg}°"),
    }
}

/// The figures as Markdown tables.
pub fn markdown(settings: &Settings, scenes: &[SceneResult], sweep: &[SpacingResult]) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "Seed {}, {} complete sweeps per scene, grid 400 × 400 cells of 2 cm.\n",
        settings.seed, settings.sweeps
    );
    for sc in scenes {
        let _ = writeln!(
            s,
            "### {} ({}, {} readings, {:.0} s simulated)\n",
            sc.name,
            scan_text(sc.scan),
            sc.readings,
            sc.simulated_s
        );
        if !sc.posts.is_empty() {
            let _ = write!(s, "| method |");
            for (i, p) in sc.posts.iter().enumerate() {
                let _ = write!(
                    s,
                    " post {} at ({:.2}, {:+.2}): width (peak p) |",
                    i + 1,
                    p.centre.x,
                    p.centre.y
                );
            }
            let two = sc.posts.len() >= 2;
            if two {
                let _ = write!(s, " gap resolved (least ray maximum, bearing) |");
            }
            let _ = writeln!(s);
            let _ = writeln!(
                s,
                "|{}",
                "---|".repeat(1 + sc.posts.len() + usize::from(two))
            );
            for m in &sc.methods {
                let _ = write!(s, "| {} |", m.method.label());
                for (w, p) in m.widths.iter().zip(&m.peaks) {
                    let _ = write!(s, " {} |", width_cell(*w, *p));
                }
                if two {
                    let _ = write!(s, " {} |", gap_cell(m.gap));
                }
                let _ = writeln!(s);
            }
            if let Some(n) = sc.passing {
                let _ = writeln!(
                    s,
                    "\nReadings aimed between the posts that heard past them: {n} of {}.",
                    sc.readings
                );
            }
            let _ = writeln!(s);
        }
        let _ = writeln!(
            s,
            "| method | occupied cells | of which behind a wall | distance to truth: median / p90 \
             | median, cells in front of the walls | visible walls covered | visible walls marked \
             free |"
        );
        let _ = writeln!(s, "|---|---|---|---|---|---|---|");
        for m in &sc.methods {
            let w = &m.walls;
            let dist = match (w.median_distance_m, w.p90_distance_m) {
                (Some(a), Some(b)) => format!("{} / {}", cm(a), cm(b)),
                _ => "–".into(),
            };
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {} | {:.0} % of {:.2} m | {:.0} % |",
                m.method.label(),
                w.occupied_cells,
                w.behind_walls,
                dist,
                w.median_in_front_m.map_or("–".into(), cm),
                w.coverage * 100.0,
                w.visible_m,
                w.marked_free * 100.0
            );
        }
        let _ = writeln!(s, "\nFirst sweep, angle → range:");
        let list: Vec<String> = sc
            .first_sweep
            .iter()
            .map(|(a, r)| match r {
                Some(r) => format!("{a:+.0}° {r:.3}"),
                None => format!("{a:+.0}° –"),
            })
            .collect();
        let _ = writeln!(s, "{}\n", list.join(", "));
    }
    if !sweep.is_empty() {
        let _ = writeln!(
            s,
            "### Spacing sweep: two 5 cm posts at 1 m, wall at 2 m, local scan −45°…45°\n"
        );
        let _ = writeln!(
            s,
            "| centre spacing | gap between faces | readings passing between | basic | paper | \
             recommended |"
        );
        let _ = writeln!(s, "|---|---|---|---|---|---|");
        for r in sweep {
            let _ = write!(
                s,
                "| {:.1} cm | {:.1} cm |",
                f64::from(r.spacing_mm) / 10.0,
                f64::from(r.spacing_mm) / 10.0 - 5.0
            );
            let _ = write!(s, " {} of {} |", r.passing, r.readings);
            for g in &r.gaps {
                let _ = write!(s, " {} |", gap_cell(*g));
            }
            let _ = writeln!(s);
        }
        let _ = writeln!(s);
        for (k, m) in Method::ALL.iter().enumerate() {
            let (first, from) = smallest_resolved(sweep, k);
            let show = |v: Option<u32>| {
                v.map_or("none in the sweep".into(), |mm| {
                    format!("{:.1} cm", f64::from(mm) / 10.0)
                })
            };
            let _ = writeln!(
                s,
                "- {}: smallest resolved spacing {}; resolved at every spacing from {}",
                m.short(),
                show(first),
                show(from)
            );
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn result(mm: u32, resolved: [bool; 3]) -> SpacingResult {
        SpacingResult {
            spacing_mm: mm,
            passing: 0,
            readings: 0,
            gaps: resolved
                .iter()
                .map(|&r| {
                    Some(Gap {
                        min_score: if r { 0.3 } else { 0.7 },
                        bearing_deg: 0.0,
                        resolved: r,
                    })
                })
                .collect(),
        }
    }

    #[test]
    fn smallest_resolved_spacing_and_the_start_of_the_resolved_run() {
        let sweep = [
            result(100, [false, false, true]),
            result(150, [false, true, false]),
            result(200, [false, true, true]),
            result(250, [false, true, true]),
        ];
        assert_eq!(smallest_resolved(&sweep, 0), (None, None));
        assert_eq!(smallest_resolved(&sweep, 1), (Some(150), Some(150)));
        assert_eq!(smallest_resolved(&sweep, 2), (Some(100), Some(200)));
        let all = [result(100, [true; 3]), result(150, [true; 3])];
        assert_eq!(smallest_resolved(&all, 0), (Some(100), Some(100)));
    }

    #[test]
    fn the_basic_raster_is_the_same_whichever_preset_fuses() {
        let scene = Scene::builtin("obstacle").unwrap();
        let cap = capture(scene.clone(), Scan::for_scene(&scene), 2, 1).unwrap();
        let paper = Maps::fuse(&cap.readings, Preset::Paper).unwrap();
        let rec = Maps::fuse(&cap.readings, Preset::Recommended).unwrap();
        let (a, b) = (paper.basic(30.0), rec.basic(30.0));
        let n = a.geometry().cells_per_side();
        let mut arcs = 0;
        for y in 0..n {
            for x in 0..n {
                assert_eq!(a.value(x, y), b.value(x, y));
                arcs += usize::from(a.is_occupied(x, y));
            }
        }
        assert!(arcs > 100);
    }

    #[test]
    fn markdown_lists_every_method_of_every_scene() {
        let settings = Settings {
            sweeps: 2,
            seed: 5,
            spacings_mm: vec![200, 400],
            scale: 1,
        };
        let scene = Scene::builtin("two-obstacles").unwrap();
        let (res, _picture) = evaluate_scene(&scene, &settings).unwrap();
        assert_eq!(res.readings, 32);
        assert_eq!(res.methods.len(), 3);
        assert!(
            res.methods
                .iter()
                .all(|m| m.widths.len() == 2 && m.gap.is_some())
        );
        let sweep = spacing_sweep(&settings).unwrap();
        assert_eq!(sweep.len(), 2);
        let md = markdown(&settings, &[res], &sweep);
        for needle in [
            "Seed 5, 2 complete sweeps",
            "### two-obstacles",
            "| basic |",
            "`paper` preset",
            "`recommended` preset",
            "| 20.0 cm | 15.0 cm | ",
            "Readings aimed between the posts that heard past them",
            "- recommended: smallest resolved spacing",
        ] {
            assert!(md.contains(needle), "{needle} missing from\n{md}");
        }
    }
}
