//! `sonar-eval`: runs the evaluation and writes the pictures and the tables.

use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{Context, Result};
use clap::Parser;
use sonar_eval::image;
use sonar_eval::report::{self, Settings};
use sonar_sim::{BUILTIN_NAMES, Scene};
use tracing::info;

/// Evaluates the basic and probability maps on the paper's four scenes (Figs. 8–11: room,
/// corner, obstacle, two-obstacles) and on two 5 cm posts at a range of spacings.
///
/// Everything runs in this process on the simulator's virtual clock: the simulated device writes
/// protocol lines, the driver's decoder turns them into readings, the fusion library builds the
/// maps with the `paper` and `recommended` presets. Same seed and sweeps, same figures.
///
/// Writes <OUT>/<scene>.png for each scene (basic | probability | actual setup; top row the
/// `paper` preset, bottom row `recommended`) and prints the figures as Markdown tables on
/// standard output (or to --report). Progress goes to standard error (level from RUST_LOG).
///
/// Example:
///   cargo run -p sonar-eval --release -- --out docs/results
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
    /// Write the Markdown tables to this file instead of standard output.
    #[arg(long)]
    report: Option<PathBuf>,
}

fn main() -> ExitCode {
    let args = Args::parse();
    sonar_common::init_tracing();
    sonar_common::report_exit("sonar-eval", run(args))
}

/// Spacings of the two-post sweep, whole millimetres, increasing.
#[derive(Debug, Clone, PartialEq, Eq)]
struct Spacings(Vec<u32>);

/// `FROM..TO:STEP[,FROM..TO:STEP…]` in cm, or `none`.
fn parse_spacings(s: &str) -> Result<Spacings, String> {
    if s.trim() == "none" {
        return Ok(Spacings(Vec::new()));
    }
    let mut out: Vec<u32> = Vec::new();
    for part in s.split(',') {
        let bad = || format!("expected FROM..TO:STEP in cm (e.g. 10..80:2), got {part:?}");
        let (range, step) = part.split_once(':').ok_or_else(bad)?;
        let (from, to) = range.split_once("..").ok_or_else(bad)?;
        let num = |v: &str| v.trim().parse::<f64>().map_err(|_| bad());
        let (from, to, step) = (num(from)?, num(to)?, num(step)?);
        if !(from > 5.0 && from <= to && to <= 200.0) {
            return Err(format!(
                "spacings must satisfy 5 cm < FROM <= TO <= 200 cm (the posts are 5 cm wide), \
                 got {part:?}"
            ));
        }
        if !(step > 0.0 && step.is_finite()) {
            return Err(format!(
                "the step must be a positive number of cm, got {part:?}"
            ));
        }
        let mm = |cm: f64| (cm * 10.0).round() as u32;
        let step = mm(step).max(1) as usize;
        out.extend((mm(from)..=mm(to)).step_by(step));
    }
    out.sort_unstable();
    out.dedup();
    Ok(Spacings(out))
}

fn run(args: Args) -> Result<()> {
    let settings = Settings {
        sweeps: args.sweeps,
        seed: args.seed,
        spacings_mm: args.spacings.0,
        scale: usize::from(args.scale),
    };
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
    let text = report::markdown(&settings, &scenes, &sweep);
    match &args.report {
        Some(path) => std::fs::write(path, &text)
            .with_context(|| format!("writing the report {}", path.display()))?,
        None => std::io::stdout()
            .lock()
            .write_all(text.as_bytes())
            .context("writing the report to standard output")?,
    }
    Ok(())
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
    fn the_command_line_parses() {
        let a = Args::try_parse_from(["sonar-eval", "--out", "x", "--sweeps", "4"]).unwrap();
        assert_eq!((a.sweeps, a.seed, a.scale), (4, 1, 3));
        assert!(Args::try_parse_from(["sonar-eval", "--sweeps", "0"]).is_err());
    }
}
