//! `sonar-eval`: runs the evaluation and writes the pictures and the tables.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::Parser;
use sonar_eval::features::{self, FeatureSettings};
use sonar_eval::motion::{self, MotionSettings};
use sonar_eval::report::{self, Settings};
use sonar_eval::slam;
use sonar_eval::suite::{self, SuiteArgs, SuiteSettings};
use sonar_eval::{calibration, feature_report, image, pipeline};
use sonar_sim::{BUILTIN_NAMES, Scene};
use tracing::info;

/// Evaluates the basic and probability maps on the paper's four scenes (Figs. 8–11: room,
/// corner, obstacle, two-obstacles) and on two 5 cm posts at a range of spacings.
///
/// Everything runs in this process on the simulator's virtual clock: the simulated device writes
/// protocol lines, the driver's decoder turns them into readings, the fusion library builds the
/// maps with the `paper` and `recommended` presets. Same seed and sweeps, same figures.
///
/// Then evaluates the features of `sonar-features` (walls, corners, posts from the raw pings)
/// on the same scenes rotated to every --feature-bearings, with every --feature-seeds, next to
/// the two grid presets on the same runs: a 5 cm post, two posts at --feature-spacings, the room,
/// the corner, a slanted wall and a 10 cm post.
///
/// Last, drives the tour scenes (corridor, room-tour) with a drifting odometry (3 % scale, 2°/m;
/// --motion-scale-error and --motion-heading-drift set others) for --motion-metres with every
/// --motion-seeds, and fuses each tour at the true poses, at the odometry, and at the odometry
/// corrected by sonar localisation.
///
/// Writes <OUT>/<scene>.png for each scene (basic | probability | actual setup; top row the
/// `paper` preset, bottom row `recommended`), <OUT>/<scene>-motion.png for each tour scene (the
/// first seed's maps: true poses | odometry | localised | actual setup), and prints the figures
/// as Markdown tables on standard output (or to --report). Progress goes to standard error
/// (level from RUST_LOG).
///
/// With --suite, runs the generated scene suite instead and nothing else: generated rooms and
/// corridors scanned from 1, 3 and 8 viewpoints with every sensor profile and seed, the maps of
/// every --suite-fusion and the features scored against the scenes' true surfaces.
///
/// With --slam, runs the SLAM evaluation instead and nothing else: generated tours (hallways,
/// a ring corridor, a long corridor, an office, the built-in corridor and room tour) driven with a
/// drifting odometry, each given to sonar-slam and to today's localisation, every sweep's pose
/// scored against the truth (docs/results.md, "SLAM").
///
/// Examples:
///   cargo run -p sonar-eval --release -- --out docs/results
///   cargo run -p sonar-eval --release -- --slam --slam-layouts 4..8:1 --slam-seeds 1..3:1 --report slam.md
///   cargo run -p sonar-eval --release -- --suite --suite-scenes 50 --suite-fusion recommended,mine.toml
#[derive(Debug, Parser)]
#[command(version, verbatim_doc_comment)]
struct Args {
    /// Directory for the PNG pictures (created if missing).
    #[arg(long, default_value = "docs/results")]
    out: PathBuf,
    /// Complete sweeps per scene (a local sweep goes one way across the segment; a full sweep
    /// from limit to limit).
    #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u32).range(1..=1000))]
    sweeps: u32,
    /// Seed of the simulated echo noise.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Centre spacings of the two-post sweep (two 5 cm posts 1 m ahead, wall at 2 m), in cm:
    /// comma-separated ranges FROM..TO:STEP, or `none`.
    #[arg(long, default_value = "10..80:2,90..200:10", value_parser = parse_spacings)]
    spacings: Spacings,
    /// Pixels per 2 cm grid cell in the pictures.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u16).range(1..=8))]
    scale: u16,
    /// Write the Markdown tables to this file instead of standard output; a relative path is
    /// taken inside --out, beside the pictures (an absolute one as it is).
    #[arg(long)]
    report: Option<PathBuf>,
    /// Rotations of every scene for the feature evaluation, degrees: comma-separated values or
    /// ranges FROM..TO:STEP, or `none` to skip it. The default covers a 6° reading period at
    /// 0.375°, four phases of the 1.5° ping grid.
    #[arg(long, default_value = "0..5.625:0.375", value_parser = parse_bearings)]
    feature_bearings: Values,
    /// Seeds of the feature evaluation: comma-separated values or ranges FROM..TO:STEP.
    #[arg(long, default_value = "1..3:1", value_parser = parse_seeds)]
    feature_seeds: Values,
    /// Centre spacings of the feature evaluation's two-post scenes, in cm (as --spacings).
    #[arg(long, default_value = "10..70:5", value_parser = parse_spacings)]
    feature_spacings: Spacings,
    /// Only the feature evaluation (no pictures, no grid tables of the paper's scenes, no tours).
    #[arg(long, conflicts_with = "motion_only")]
    features_only: bool,
    /// Noise levels of the features' robustness runs (post, two posts, square room centred and
    /// off-centre, L room, corner, slanted wall): comma-separated MM[+PCT%][/DROP%], Gaussian σ
    /// per ping in mm plus a share of the range, and the pings lost (`10+1%/2%`), or `none`.
    #[arg(long, default_value = "0,3,10,10+1%,10+1%/2%", value_parser = parse_levels)]
    feature_noise: Levels,
    /// Centre spacings of the two-post scenes in the robustness runs, in cm (as --spacings).
    #[arg(long, default_value = "10,20,30,40,60", value_parser = parse_spacings)]
    feature_level_spacings: Spacings,
    /// Of the feature evaluation, only the robustness runs under noise.
    #[arg(long, conflicts_with = "motion_only")]
    feature_levels_only: bool,
    /// The simulated sensor the feature evaluation hears its scenes through: a simulator profile
    /// (srf05, hc-sr04, nxt), each with its own head, echoes and noise, the features set for it
    /// as its owner would, or default (the paper's head and the simulator's default echoes).
    /// The noise levels replace a profile's range noise and keep its jitter and dropouts.
    #[arg(long, default_value = "default")]
    feature_profile: pipeline::ProfileChoice,
    /// Calibrate the feature evaluation's sensor first, as `sonar calibrate-range` does (three
    /// sweeps of the built-in room's wall 1.2 m ahead), and take the measured range offset off
    /// every range the features see (the grids' figures stay uncalibrated).
    #[arg(long)]
    feature_calibrate: bool,
    /// Seeds of the motion evaluation (the tour scenes driven with a drifting odometry, fused at
    /// the true poses, the odometry's, and the odometry's with localisation): comma-separated
    /// values or ranges FROM..TO:STEP, or `none` to skip it.
    #[arg(long, default_value = "1..10:1", value_parser = parse_seeds)]
    motion_seeds: Values,
    /// Length of each tour of the motion evaluation, metres driven.
    #[arg(long, default_value_t = 20.0, value_parser = parse_metres)]
    motion_metres: f64,
    /// The odometry's scale error in the motion evaluation (0.03: it reports 3 % more than
    /// driven; negative: less).
    #[arg(long, default_value_t = 0.03, value_parser = parse_scale_error, allow_hyphen_values = true)]
    motion_scale_error: f64,
    /// The odometry's heading drift in the motion evaluation, degrees per metre driven (negative:
    /// clockwise).
    #[arg(long, default_value_t = 2.0, value_parser = parse_heading_drift, allow_hyphen_values = true)]
    motion_heading_drift: f64,
    /// Only the motion evaluation.
    #[arg(long)]
    motion_only: bool,
    #[command(flatten)]
    suite: SuiteArgs,
    /// Runs the SLAM evaluation instead and nothing else: generated tours (--slam-tours) of every
    /// --slam-layouts, driven with every --slam-seeds at every --slam-odometry level, each given
    /// to sonar-slam and to today's localisation, every sweep's pose scored against the truth.
    #[arg(long)]
    slam: bool,
    /// Tours of the SLAM evaluation: comma-separated hallway, hallway-driving, loop,
    /// long-corridor, office, open-hall, corridor, room-tour.
    #[arg(
        long,
        default_value = "hallway,hallway-driving,loop,long-corridor,office,open-hall,corridor,room-tour",
        value_parser = parse_families
    )]
    slam_tours: Families,
    /// Sensors every SLAM tour is heard through: comma-separated simulator profiles (srf05,
    /// hc-sr04, nxt) or default (the simulator without a profile); the SLAM and the localisation
    /// are told each one's head and echo cones.
    #[arg(long, default_value = "default", value_delimiter = ',')]
    slam_profiles: Vec<pipeline::ProfileChoice>,
    /// Share of every SLAM tour's walls made rough, 0 to 1 (brick, full shelves: they scatter
    /// sound back from wherever they are met), each wall drawn from its layout; 0, the
    /// default, leaves every wall smooth.
    #[arg(long, default_value_t = 0.0, value_name = "SHARE")]
    slam_rough: f64,
    /// Layout seeds of the SLAM evaluation's generated tours (as --motion-seeds).
    #[arg(long, default_value = "4..8:1", value_parser = parse_seeds)]
    slam_layouts: Values,
    /// Run seeds of the SLAM evaluation: echo and odometry noise, and the signs of the
    /// odometry's errors.
    #[arg(long, default_value = "1..3:1", value_parser = parse_seeds)]
    slam_seeds: Values,
    /// Odometry levels of the SLAM evaluation: comma-separated good (1 %, 0.5°/m), medium (3 %,
    /// 2°/m), poor (5 %, 3°/m).
    #[arg(long, default_value = "medium,poor", value_parser = parse_levels_odometry)]
    slam_odometry: OdometryLevels,
    /// The SLAM's settings (the `SlamConfig` fields as TOML, e.g. `range_sigma_floor_m = 0.005`);
    /// unset fields keep their defaults.
    #[arg(long, default_value = "")]
    slam_config: String,
}

/// Tours of the SLAM evaluation.
#[derive(Debug, Clone, PartialEq)]
struct Families(Vec<slam::Family>);

fn parse_families(s: &str) -> Result<Families, String> {
    s.split(',')
        .map(|name| {
            let name = name.trim();
            slam::Family::parse(name).ok_or_else(|| format!("unknown tour {name:?}"))
        })
        .collect::<Result<_, _>>()
        .map(Families)
}

/// Odometry levels of the SLAM evaluation.
#[derive(Debug, Clone, PartialEq)]
struct OdometryLevels(Vec<slam::OdometryLevel>);

fn parse_levels_odometry(s: &str) -> Result<OdometryLevels, String> {
    s.split(',')
        .map(|name| match name.trim() {
            "good" => Ok(slam::OdometryLevel::GOOD),
            "medium" => Ok(slam::OdometryLevel::MEDIUM),
            "poor" => Ok(slam::OdometryLevel::POOR),
            other => Err(format!(
                "unknown odometry level {other:?} (good, medium, poor)"
            )),
        })
        .collect::<Result<_, _>>()
        .map(OdometryLevels)
}

fn main() -> ExitCode {
    let args = Args::parse();
    sonar_common::init_tracing();
    sonar_common::report_exit("sonar-eval", run(args))
}

/// Spacings of the two-post sweep, whole millimetres, increasing.
#[derive(Debug, Clone, PartialEq, Eq)]
struct Spacings(Vec<u32>);

/// Noise levels of the features' robustness runs.
#[derive(Debug, Clone, PartialEq)]
struct Levels(Vec<features::NoiseLevel>);

fn parse_levels(s: &str) -> Result<Levels, String> {
    if s.trim() == "none" {
        return Ok(Levels(Vec::new()));
    }
    s.split(',')
        .map(features::NoiseLevel::parse)
        .collect::<Result<_, _>>()
        .map(Levels)
}

/// Numbers from the command line, in the order given.
#[derive(Debug, Clone, PartialEq)]
struct Values(Vec<f64>);

/// `V|FROM..TO:STEP[,…]`, or `none` (empty); every value checked by `ok` (whose message says
/// what is allowed).
fn parse_values(s: &str, ok: impl Fn(f64) -> Result<(), String>) -> Result<Vec<f64>, String> {
    if s.trim() == "none" {
        return Ok(Vec::new());
    }
    let mut out = Vec::new();
    for part in s.split(',') {
        let bad = || format!("expected a number or FROM..TO:STEP, got {part:?}");
        let num = |v: &str| v.trim().parse::<f64>().map_err(|_| bad());
        let Some((range, step)) = part.split_once(':') else {
            let v = num(part)?;
            ok(v)?;
            out.push(v);
            continue;
        };
        let (from, to) = range.split_once("..").ok_or_else(bad)?;
        let (from, to, step) = (num(from)?, num(to)?, num(step)?);
        if !(step > 0.0 && step.is_finite()) {
            return Err(format!("the step must be a positive number, got {part:?}"));
        }
        if from > to {
            return Err(format!("FROM must not exceed TO, got {part:?}"));
        }
        ok(from)?;
        ok(to)?;
        // Whole steps, with a little slack for decimal steps such as 0.375.
        let n = ((to - from) / step + 1e-9).floor() as usize;
        out.extend((0..=n).map(|k| from + step * k as f64));
    }
    Ok(out)
}

/// `FROM..TO:STEP[,FROM..TO:STEP…]` in cm, or `none`.
fn parse_spacings(s: &str) -> Result<Spacings, String> {
    let cm = parse_values(s, |v| {
        if v > 5.0 && v <= 200.0 {
            Ok(())
        } else {
            Err(format!(
                "spacings must lie in (5, 200] cm (the posts are 5 cm wide), got {v}"
            ))
        }
    })?;
    let mut mm: Vec<u32> = cm.iter().map(|v| (v * 10.0).round() as u32).collect();
    mm.sort_unstable();
    mm.dedup();
    Ok(Spacings(mm))
}

/// Bearings in degrees, within ±180.
fn parse_bearings(s: &str) -> Result<Values, String> {
    parse_values(s, |v| {
        if (-180.0..=180.0).contains(&v) {
            Ok(())
        } else {
            Err(format!("bearings must lie within ±180°, got {v}"))
        }
    })
    .map(Values)
}

/// Seeds: whole numbers ≥ 0.
fn parse_seeds(s: &str) -> Result<Values, String> {
    parse_values(s, |v| {
        if v >= 0.0 && v.fract() == 0.0 && v < 2f64.powi(53) {
            Ok(())
        } else {
            Err(format!("seeds are whole numbers >= 0, got {v}"))
        }
    })
    .map(Values)
}

/// A tour's length: more than 0 and at most 1 km.
fn parse_metres(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v > 0.0 && v <= 1000.0 => Ok(v),
        _ => Err(format!("expected metres in (0, 1000], got {s:?}")),
    }
}

fn parse_scale_error(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v > -0.5 && v < 0.5 => Ok(v),
        _ => Err(format!("expected a scale error in (-0.5, 0.5), got {s:?}")),
    }
}

fn parse_heading_drift(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(v) if v.abs() <= 45.0 => Ok(v),
        _ => Err(format!(
            "expected degrees per metre in [-45, 45], got {s:?}"
        )),
    }
}

fn run(args: Args) -> Result<()> {
    if args.slam {
        let settings = slam::SlamSettings {
            families: args.slam_tours.0,
            profiles: args.slam_profiles,
            layouts: args.slam_layouts.0.iter().map(|&s| s as u64).collect(),
            seeds: args.slam_seeds.0.iter().map(|&s| s as u64).collect(),
            levels: args.slam_odometry.0,
            config: toml::from_str(&args.slam_config)
                .with_context(|| format!("--slam-config {:?}", args.slam_config))?,
            rough_share: args.slam_rough,
        };
        let runs = slam::evaluate(&settings)?;
        let text = slam::markdown(&settings, &runs);
        return write_report(&args.out, args.report.as_deref(), &text);
    }
    if args.suite.suite {
        let settings = SuiteSettings::from_args(&args.suite)?;
        let runs = suite::evaluate(&settings)?;
        let text = suite::markdown(&settings, &runs);
        return write_report(&args.out, args.report.as_deref(), &text);
    }
    let settings = Settings {
        sweeps: args.sweeps,
        seed: args.seed,
        spacings_mm: args.spacings.0,
        scale: usize::from(args.scale),
    };
    let mut text = String::new();
    if !args.features_only && !args.feature_levels_only && !args.motion_only {
        std::fs::create_dir_all(&args.out)
            .with_context(|| format!("creating the output directory {}", args.out.display()))?;
        let mut scenes = Vec::new();
        for name in BUILTIN_NAMES {
            let scene = Scene::builtin(name).with_context(|| format!("loading scene {name}"))?;
            let (result, picture) = report::evaluate_scene(&scene, &settings)?;
            let path = args.out.join(format!("{name}.png"));
            image::write_png(&picture, &path)?;
            info!(scene = name, picture = %path.display(), readings = result.readings, "scene done");
            scenes.push(result);
        }
        let sweep = report::spacing_sweep(&settings)?;
        text += &report::markdown(&settings, &scenes, &sweep);
    }
    if !args.feature_bearings.0.is_empty() && !args.motion_only {
        let feature_settings = FeatureSettings {
            bearings_deg: args.feature_bearings.0,
            seeds: args.feature_seeds.0.iter().map(|&s| s as u64).collect(),
            sweeps: args.sweeps,
            spacings_mm: args.feature_spacings.0,
            levels: args.feature_noise.0,
            level_spacings_mm: args.feature_level_spacings.0,
            profile: args.feature_profile,
            calibrated: if args.feature_calibrate {
                // Measured as the suite's --suite-calibrate measures it, the profile's own noise.
                let sensor = suite::SensorChoice {
                    profile: args.feature_profile,
                    noise: None,
                    calibrated: None,
                };
                sensor.calibrate(calibration::SEED)?.calibrated
            } else {
                None
            },
        };
        if !args.feature_levels_only {
            let results = features::evaluate(&feature_settings)?;
            if !text.is_empty() {
                text.push('\n');
            }
            text += &feature_report::markdown(&feature_settings, &results);
        }
        if !feature_settings.levels.is_empty() {
            let levels = features::evaluate_levels(&feature_settings)?;
            if !text.is_empty() {
                text.push('\n');
            }
            text += &feature_report::levels_markdown(&feature_settings, &levels);
        }
    }
    if !args.motion_seeds.0.is_empty() && !args.features_only && !args.feature_levels_only {
        let mut motion_settings = MotionSettings::drifting(
            args.motion_seeds.0.iter().map(|&s| s as u64).collect(),
            args.motion_metres,
            usize::from(args.scale),
        );
        motion_settings.odometry.scale_error = args.motion_scale_error;
        motion_settings.odometry.heading_drift_deg_per_m = args.motion_heading_drift;
        let scenes = motion::evaluate(&motion_settings)?;
        std::fs::create_dir_all(&args.out)
            .with_context(|| format!("creating the output directory {}", args.out.display()))?;
        for scene in &scenes {
            if let Some(picture) = &scene.picture {
                let path = args.out.join(format!("{}-motion.png", scene.name));
                image::write_png(picture, &path)?;
                info!(scene = scene.name, picture = %path.display(), "tour pictured");
            }
        }
        if !text.is_empty() {
            text.push('\n');
        }
        text += &motion::markdown(&motion_settings, &scenes);
    }
    write_report(&args.out, args.report.as_deref(), &text)
}

/// Writes the tables to `report` (inside `out` unless absolute), or to standard output.
fn write_report(out: &Path, report: Option<&Path>, text: &str) -> Result<()> {
    match report.map(|r| report_path(out, r)) {
        Some(path) => {
            std::fs::create_dir_all(out)
                .with_context(|| format!("creating the output directory {}", out.display()))?;
            std::fs::write(&path, text)
                .with_context(|| format!("writing the report {}", path.display()))?;
            info!(report = %path.display(), "report written");
        }
        None => std::io::stdout()
            .lock()
            .write_all(text.as_bytes())
            .context("writing the report to standard output")?,
    }
    Ok(())
}

/// Where `--report` goes: inside `out` unless it is absolute.
fn report_path(out: &Path, report: &Path) -> PathBuf {
    out.join(report)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn spacings_are_whole_millimetres_and_checked() {
        let p = |s| parse_spacings(s).map(|v| v.0);
        assert_eq!(p("10..14:2").unwrap(), [100, 120, 140]);
        assert_eq!(p("10..11:2.5").unwrap(), [100]);
        assert_eq!(
            p("10..14:2, 13..13.5:0.5").unwrap(),
            [100, 120, 130, 135, 140]
        );
        assert_eq!(p("none").unwrap(), Vec::<u32>::new());
        assert_eq!(p("12").unwrap(), [120]);
        for bad in [
            "4..80:2",
            "30..20:2",
            "10..20:-1",
            "10..20",
            "ten..20:2",
            "10..300:5",
        ] {
            assert!(p(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn bearings_and_seeds_take_values_and_decimal_ranges() {
        let b = |s| parse_bearings(s).map(|v| v.0);
        assert_eq!(b("0..1.5:0.375").unwrap(), [0.0, 0.375, 0.75, 1.125, 1.5]);
        assert_eq!(b("0, 4.5, -3").unwrap(), [0.0, 4.5, -3.0]);
        assert_eq!(b("none").unwrap(), Vec::<f64>::new());
        assert!(b("0..200:1").is_err());
        let seeds = |s| parse_seeds(s).map(|v| v.0);
        assert_eq!(seeds("1..3:1").unwrap(), [1.0, 2.0, 3.0]);
        assert!(seeds("1.5").is_err() && seeds("-1").is_err());
    }

    #[test]
    fn the_tours_odometry_errors_are_checked_and_may_be_negative() {
        let args = Args::try_parse_from([
            "sonar-eval",
            "--motion-scale-error",
            "-0.03",
            "--motion-heading-drift",
            "-2",
        ])
        .unwrap();
        assert_eq!(
            (args.motion_scale_error, args.motion_heading_drift),
            (-0.03, -2.0)
        );
        assert!(parse_scale_error("0.5").is_err() && parse_scale_error("x").is_err());
        assert!(parse_heading_drift("90").is_err() && parse_heading_drift("NaN").is_err());
    }

    #[test]
    fn a_relative_report_goes_beside_the_pictures() {
        let out = Path::new("docs/results");
        assert_eq!(
            report_path(out, Path::new("motion.md")),
            Path::new("docs/results/motion.md")
        );
        assert_eq!(
            report_path(out, Path::new("/tmp/motion.md")),
            Path::new("/tmp/motion.md")
        );
    }

    #[test]
    fn the_command_line_parses() {
        let a = Args::try_parse_from(["sonar-eval", "--out", "x", "--sweeps", "4"]).unwrap();
        assert_eq!((a.sweeps, a.seed, a.scale), (4, 1, 3));
        assert_eq!(a.feature_bearings.0.len(), 16);
        assert_eq!(a.feature_seeds.0, [1.0, 2.0, 3.0]);
        assert_eq!(a.feature_spacings.0.len(), 13);
        assert!(!a.features_only && !a.motion_only);
        assert_eq!(a.feature_profile, pipeline::ProfileChoice(None));
        assert!(!a.feature_calibrate);
        let a = Args::try_parse_from([
            "sonar-eval",
            "--feature-profile",
            "hc-sr04",
            "--feature-calibrate",
        ])
        .unwrap();
        assert!(a.feature_calibrate);
        assert_eq!(
            a.feature_profile,
            pipeline::ProfileChoice(Some(sonar_sim::SensorProfile::HcSr04))
        );
        assert!(Args::try_parse_from(["sonar-eval", "--feature-profile", "srf04"]).is_err());
        assert_eq!((a.motion_seeds.0.len(), a.motion_metres), (10, 20.0));
        assert!(Args::try_parse_from(["sonar-eval", "--sweeps", "0"]).is_err());
        assert!(Args::try_parse_from(["sonar-eval", "--motion-metres", "0"]).is_err());
        assert!(Args::try_parse_from(["sonar-eval", "--motion-only", "--features-only"]).is_err());
        let a = Args::try_parse_from(["sonar-eval", "--slam"]).unwrap();
        assert!(a.slam);
        assert_eq!(a.slam_tours.0.len(), 8);
        assert_eq!(
            a.slam_odometry.0,
            [slam::OdometryLevel::MEDIUM, slam::OdometryLevel::POOR]
        );
        assert_eq!(a.slam_profiles, [pipeline::ProfileChoice(None)]);
        let a = Args::try_parse_from([
            "sonar-eval",
            "--slam",
            "--slam-tours",
            "loop, office",
            "--slam-odometry",
            "good",
            "--slam-profiles",
            "nxt,default",
        ])
        .unwrap();
        assert_eq!(
            a.slam_profiles,
            [
                pipeline::ProfileChoice(Some(sonar_sim::SensorProfile::Nxt)),
                pipeline::ProfileChoice(None)
            ]
        );
        assert_eq!(a.slam_tours.0, [slam::Family::Loop, slam::Family::Office]);
        assert_eq!(a.slam_odometry.0, [slam::OdometryLevel::GOOD]);
        for bad in [
            ["--slam-tours", "maze"],
            ["--slam-odometry", "perfect"],
            ["--slam-profiles", "srf04"],
        ] {
            assert!(Args::try_parse_from(["sonar-eval", "--slam", bad[0], bad[1]]).is_err());
        }
    }
}
