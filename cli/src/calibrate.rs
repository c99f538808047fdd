//! `sonar calibrate-range`: the sensor's range offset, measured on a wall at a known distance.
//!
//! It listens to `sonar/readings` like any consumer, groups them by sweep, and hands each whole
//! sweep to [`sonar_features::WallSightings`] ([`sonar_features::wall_in_sweep`]); after
//! `--sweeps` sightings of one wall, [`sonar_features::range_offset`] gives the offset, printed
//! as the `[features]` lines to put in the pipeline's configuration (the fusion's, and the
//! SLAM's unless `[slam.features]` sets its own). The first sweep it sees is left out: it
//! joined it somewhere in the middle. The first whole sweep also shows how the head steps
//! ([`head_as_read`]), and each wall's region how wide the sensor hears a wall: both are
//! checked against the configuration and printed as lines to set when they differ.

use std::fmt::Write as _;
use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use iceoryx2::prelude::*;
use iceoryx2::service::ipc::Service as Ipc;
use sonar_common::ipc::{self, IpcError, Reading, flags};
use sonar_features::calibrate::{expected_half_width_deg, head_step_deg};
use sonar_features::{FeatureConfig, RangeOffset, WallSighting, WallSightings};
use sonar_fusion::FusionFile;

/// How often it looks for new readings.
const POLL: Duration = Duration::from_millis(20);

/// Sweeps without a wall seen whole, per sweep asked for, before it gives up.
const TRIES_PER_SWEEP: usize = 3;

/// What `calibrate-range` is told.
#[derive(Debug, Clone, clap::Args)]
pub struct Settings {
    /// The wall's perpendicular distance from the head's turning axis, metres: measure it square
    /// to the wall (where the software places the sensor, so the transducer's place on the arm
    /// is measured with the sensor's own lateness).
    #[arg(long, value_name = "M")]
    pub wall_distance: f64,
    /// Sweeps that saw the wall to measure over.
    #[arg(long, value_name = "N", default_value_t = 3, value_parser = clap::value_parser!(u32).range(1..=100))]
    pub sweeps: u32,
    /// Bearing of the wall's normal in the sensor's frame, degrees (0 = the head's forward axis,
    /// counter-clockwise): the wall whose normal lies within 10° of it, or else the region seen
    /// whole there even when the configured cones call it no wall (a head not yet described).
    /// Without it, the nearest wall the sweep saw whole.
    #[arg(long, value_name = "DEG", allow_hyphen_values = true)]
    pub bearing: Option<f64>,
    /// The pipeline's configuration file: its `[features]` table says how the head's pings lie
    /// and what echoes its sensor hears (`[features.sensor]`, `[features.echo]`); without it the
    /// SRF05 on the paper's stepper.
    #[arg(long, value_name = "FILE")]
    pub config: Option<PathBuf>,
    /// Give up when no reading arrives for this long, seconds.
    #[arg(long, value_name = "S", default_value_t = 10.0)]
    pub timeout: f64,
}

/// Measures the offset from the readings on `node` and prints it.
pub fn run(node: &Node<Ipc>, settings: &Settings) -> Result<()> {
    anyhow::ensure!(
        settings.wall_distance.is_finite() && settings.wall_distance > 0.0,
        "--wall-distance must be a positive distance in metres, got {}",
        settings.wall_distance
    );
    anyhow::ensure!(
        settings.timeout.is_finite() && settings.timeout > 0.0,
        "--timeout must be a positive number of seconds, got {}",
        settings.timeout
    );
    let file = FusionFile::read(settings.config.as_deref())?;
    let configured = file.features.config;
    // The head as its readings show it, from the first whole sweep on.
    let mut cfg: Option<FeatureConfig> = None;
    let readings = ipc::readings_service(node)?
        .subscriber_builder()
        .create()
        .map_err(|e| IpcError::new(format!("subscribe to {}", ipc::READINGS_SERVICE), e))?;
    eprintln!(
        "keep the head still, facing the wall {:.3} m away with nothing nearer; measuring over {} sweeps",
        settings.wall_distance, settings.sweeps
    );
    let wanted = settings.sweeps as usize;
    let timeout = Duration::from_secs_f64(settings.timeout);
    let mut collector = Collector::default();
    let mut sightings = WallSightings::default();
    let mut looked_at = 0;
    let mut last_reading = Instant::now();
    while sightings.sightings().len() < wanted {
        let mut finished = Vec::new();
        while let Some(sample) = readings
            .receive()
            .map_err(|e| IpcError::new(format!("receive from {}", ipc::READINGS_SERVICE), e))?
        {
            last_reading = Instant::now();
            finished.extend(collector.push(*sample.payload()));
        }
        for (sweep_id, sweep_readings) in finished {
            let cfg = *cfg.get_or_insert_with(|| head_as_read(&configured, &sweep_readings));
            looked_at += 1;
            match sightings.look(&sweep_readings, &cfg, settings.bearing)? {
                Some(wall) => eprintln!("sweep {sweep_id}: {}", sighting_line(&wall)),
                None => eprintln!(
                    "sweep {sweep_id}: no wall seen whole ({} readings)",
                    sweep_readings.len()
                ),
            }
            if sightings.sightings().len() == wanted {
                break;
            }
            if looked_at >= TRIES_PER_SWEEP * wanted {
                bail!(
                    "{} of {looked_at} sweeps saw a wall whole: face one flat wall, square, with \
                     nothing nearer in the head's sweep; give its normal's bearing (--bearing, \
                     0 = ahead) to take the region heard there whatever the configured cones, \
                     or the head's description (--config) if it is not the paper's SRF05",
                    sightings.sightings().len()
                );
            }
        }
        if last_reading.elapsed() > timeout {
            bail!(
                "no reading for {:.0} s: is sonar-driver running, the head scanning, with the \
                 same --iox-* settings? (`sonar hz readings`)",
                settings.timeout
            );
        }
        if node.wait(POLL).is_err() {
            bail!("interrupted before {wanted} sweeps saw the wall");
        }
    }
    let offset = sightings
        .offset(settings.wall_distance)
        .context("measuring the range offset")?;
    let head = Head::of(
        &configured,
        &cfg.unwrap_or(configured),
        sightings.sightings(),
    );
    print!("{}", result_text(&offset, settings.wall_distance, &head));
    Ok(())
}

/// Spacings of the head's step and the configured one further apart than this share are a
/// different head (the readings' spacing is exact: the stepper's).
const STEP_MISMATCH: f64 = 0.1;

/// `configured` with the head's step and pings per reading as `readings` (one sweep) show them,
/// when they differ from the configured ones (said on stderr): pings placed at the wrong angles
/// break every region, and no wall is found.
fn head_as_read(configured: &FeatureConfig, readings: &[Reading]) -> FeatureConfig {
    // One range per angle (a hobby sketch, an imported log): the features take such a sweep's
    // step from its spacing themselves.
    if readings.iter().all(|r| r.flags & flags::NO_RAW_PINGS != 0) {
        return *configured;
    }
    let Some((step, pings)) = head_step_deg(readings) else {
        return *configured;
    };
    let said = f64::from(configured.sensor.step_deg);
    if (step - said).abs() <= STEP_MISMATCH * said && pings == configured.sensor.pings_per_reading {
        return *configured;
    }
    eprintln!(
        "the readings lie {:.2}° apart with {pings} pings each: the head steps {step:.2}°, the \
         configuration says {said:.2}° and {} pings ([features.sensor]); measuring with the head's",
        step * f64::from(pings),
        configured.sensor.pings_per_reading
    );
    let mut cfg = *configured;
    cfg.sensor.step_deg = step as f32;
    cfg.sensor.pings_per_reading = pings;
    cfg
}

/// What the sweeps showed of the head against its configuration.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Head {
    /// The range offset configured now.
    configured_offset_m: f64,
    /// The head's step and pings per reading as read, if they differ from the configured ones.
    step: Option<(f32, u8)>,
    /// The wall's half-width as heard (mean over the sweeps) and as the configured cones expect
    /// at its distance.
    half_width_deg: (f64, Option<f64>),
    /// The step the measurement ran with, degrees.
    step_deg: f64,
    /// Whether the configured cones took the wall for one in every sweep.
    classified: bool,
}

impl Head {
    fn of(configured: &FeatureConfig, used: &FeatureConfig, sightings: &[WallSighting]) -> Self {
        let n = sightings.len().max(1) as f64;
        let distance = sightings.iter().map(|s| s.distance_m).sum::<f64>() / n;
        let step_changed = used.sensor.step_deg != configured.sensor.step_deg
            || used.sensor.pings_per_reading != configured.sensor.pings_per_reading;
        Self {
            configured_offset_m: configured.range_offset_m,
            step: step_changed.then_some((used.sensor.step_deg, used.sensor.pings_per_reading)),
            half_width_deg: (
                sightings.iter().map(|s| s.half_width_deg).sum::<f64>() / n,
                expected_half_width_deg(used, distance),
            ),
            step_deg: f64::from(used.sensor.step_deg),
            classified: sightings.iter().all(|s| s.classified),
        }
    }

    /// Whether the wall's width is not the configured cones': more than a step apart, or not
    /// taken for a wall by them.
    fn width_differs(&self) -> bool {
        let (heard, expected) = self.half_width_deg;
        !self.classified || expected.is_none_or(|e| (heard - e).abs() > self.step_deg)
    }
}

/// A sweep's wall, for the progress lines.
fn sighting_line(wall: &WallSighting) -> String {
    format!(
        "wall at {:.3} m ± {:.3}, its normal at {:.1}°, heard over ±{:.1}°, {} pings{}",
        wall.distance_m,
        wall.sigma_m,
        wall.normal_deg,
        wall.half_width_deg,
        wall.pings,
        if wall.classified {
            ""
        } else {
            " (not a wall to the configured cones: taken as the region at --bearing)"
        }
    )
}

/// The result, and the lines that set it in a configuration file.
fn result_text(offset: &RangeOffset, wall_distance: f64, head: &Head) -> String {
    // The uncertainty to configure: the measurement's, but not below a millimetre (a wall is
    // never flat and square to better than that).
    let sigma = offset.sigma_m.max(0.001);
    let (heard, expected) = head.half_width_deg;
    let mut text = format!(
        "range offset {:+.4} m (σ {:.4} m) over {} sweeps of the wall at {:.3} m, its normal at \
         {:.1}° (currently configured: {:+.4} m)\n\
         the wall answered over ±{heard:.1}° about its normal; the configured cones expect {}\n",
        offset.offset_m,
        offset.sigma_m,
        offset.sweeps,
        wall_distance,
        offset.normal_deg,
        head.configured_offset_m,
        expected.map_or_else(|| "none at this range".to_owned(), |e| format!("±{e:.1}°")),
    );
    text.push_str(
        "put in the pipeline's configuration file (sonar-fusion and sonar-slam read it there, \
         unless [slam.features] sets its own):\n",
    );
    let _ = write!(
        text,
        "[features]\nrange_offset_m = {:.4}\nrange_offset_sigma_m = {sigma:.4}\n",
        offset.offset_m
    );
    if let Some((step, pings)) = head.step {
        let _ = write!(
            text,
            "[features.sensor]\nstep_deg = {step:.2}\npings_per_reading = {pings}\n"
        );
    }
    // A comment, so that it pastes anywhere: the file may have a [slam] table already.
    let _ = writeln!(
        text,
        "# and under [slam], the range bias the SLAM estimates known as well: \
         range_bias_sigma_m = {sigma:.4}"
    );
    if head.width_differs() {
        // A wall heard squarely and near answers over the specular cut-off, unless the beam is
        // narrower (docs/features.md, "Another sensor's cones").
        let _ = write!(
            text,
            "[features.echo]\nspecular_cutoff_deg = {heard:.1}   # the wall's cone as heard; if \
             the beam is narrower, set its cone instead (docs/features.md, \"Another sensor's \
             cones\")\n"
        );
    }
    text
}

/// Readings grouped by sweep as they arrive: a sweep is whole once a reading of another arrives.
/// The first sweep is dropped (joined in its middle).
#[derive(Debug, Default)]
struct Collector {
    current: Option<u32>,
    readings: Vec<Reading>,
    first_seen: bool,
}

impl Collector {
    /// Adds `reading`; the sweep it finished, if it did, with its id.
    fn push(&mut self, reading: Reading) -> Option<(u32, Vec<Reading>)> {
        let finished = match self.current {
            Some(id) if id != reading.sweep_id => {
                let readings = std::mem::take(&mut self.readings);
                let whole = std::mem::replace(&mut self.first_seen, true);
                whole.then_some((id, readings))
            }
            _ => None,
        };
        self.current = Some(reading.sweep_id);
        self.readings.push(reading);
        finished
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn reading(seq: u64, sweep_id: u32) -> Reading {
        Reading {
            seq,
            sweep_id,
            ..Reading::default()
        }
    }

    #[test]
    fn sweeps_are_whole_once_the_next_begins_and_the_first_is_left_out() {
        let mut c = Collector::default();
        let ids = [7, 7, 8, 8, 8, 9, 10];
        let finished: Vec<(u32, usize)> = ids
            .iter()
            .enumerate()
            .filter_map(|(seq, &id)| c.push(reading(seq as u64, id)))
            .map(|(id, readings)| (id, readings.len()))
            .collect();
        // Sweep 7 was joined in its middle; 8 and 9 are whole; 10 is not finished yet.
        assert_eq!(finished, vec![(8, 3), (9, 1)]);
    }

    #[test]
    fn the_result_says_what_to_configure() {
        let offset = RangeOffset {
            offset_m: -0.0298,
            sigma_m: 0.0029,
            sweeps: 3,
            normal_deg: 1.5,
        };
        let cfg = FeatureConfig::default();
        let wall = |half_width_deg: f64, classified: bool| WallSighting {
            distance_m: 0.97,
            sigma_m: 0.001,
            normal_deg: 1.5,
            pings: 12,
            half_width_deg,
            classified,
        };
        // The head as configured, its wall as wide as the cones expect: the offset alone.
        let head = Head::of(&cfg, &cfg, &[wall(28.2, true)]);
        let text = result_text(&offset, 1.0, &head);
        assert!(!text.contains("[features.sensor]") && !text.contains("[features.echo]"));
        assert!(text.contains("range_offset_m = -0.0298\n"), "{text}");
        assert!(text.contains("range_offset_sigma_m = 0.0029\n"), "{text}");
        assert!(text.contains("[features]\n"), "{text}");
        // The lines parse as the pipeline's configuration and set the offset for the fusion and
        // for sonar-slam.
        let toml_part = &text[text.find("\n[features]\n").expect("a table")..];
        let file: FusionFile = toml::from_str(toml_part).expect("a valid configuration");
        assert_eq!(file.features.config.range_offset_m, -0.0298);
        assert_eq!(file.features.config.range_offset_sigma_m, 0.0029);
        #[derive(serde::Deserialize)]
        struct WithSlam {
            slam: sonar_slam::SlamSection,
        }
        let table: toml::Table = toml::from_str(toml_part).expect("valid TOML");
        let slam: WithSlam = sonar_slam::section::with_pipeline_features(table)
            .try_into()
            .expect("a valid [slam] table");
        assert_eq!(slam.slam.config.features.range_offset_m, -0.0298);
        assert_eq!(slam.slam.config.features.range_offset_sigma_m, 0.0029);
        // The SLAM's range bias, said in a comment: its key set under [slam] as it says.
        let hint = text
            .lines()
            .find(|l| l.starts_with("# and under [slam]"))
            .expect("the SLAM's line");
        let key = &hint[hint.find("range_bias_sigma_m").expect("its key")..];
        let slam: WithSlam = toml::from_str(&format!("[slam]\n{key}\n")).expect("a [slam] table");
        assert_eq!(slam.slam.config.range_bias_sigma_m, 0.0029);

        // A head stepping 3° with two pings a reading, its walls heard over ±20°, described as
        // the paper's: the lines say so, and set as they say, the description is the head's.
        let mut read = cfg;
        read.sensor.step_deg = 3.0;
        read.sensor.pings_per_reading = 2;
        let head = Head::of(&cfg, &read, &[wall(20.3, false), wall(19.9, false)]);
        let text = result_text(&offset, 1.0, &head);
        assert!(
            text.contains("[features.sensor]\nstep_deg = 3.00\npings_per_reading = 2\n"),
            "{text}"
        );
        assert!(text.contains("specular_cutoff_deg = 20.1"), "{text}");
        let toml_part = &text[text.find("\n[features]\n").expect("a table")..];
        let file: FusionFile = toml::from_str(toml_part).expect("a valid configuration");
        assert_eq!(file.features.config.sensor.step_deg, 3.0);
        assert_eq!(file.features.config.sensor.pings_per_reading, 2);
        assert!((file.features.config.echo.specular_cutoff_deg - 20.1).abs() < 1e-9);
    }

    #[test]
    fn a_head_stepping_otherwise_than_configured_is_measured_as_it_steps() {
        let configured = FeatureConfig::default();
        let readings: Vec<Reading> = (0..10u64)
            .map(|i| Reading {
                seq: i,
                sweep_id: 1,
                angle_deg: -90.0 + 6.0 * i as f32,
                ping_count: 2,
                ..Reading::default()
            })
            .collect();
        let used = head_as_read(&configured, &readings);
        assert_eq!(used.sensor.step_deg, 3.0);
        assert_eq!(used.sensor.pings_per_reading, 2);
        // The paper's head (four pings 1.5° apart, readings 6° apart) is left as configured.
        let paper: Vec<Reading> = readings
            .iter()
            .map(|r| Reading {
                ping_count: 4,
                ..*r
            })
            .collect();
        assert_eq!(head_as_read(&configured, &paper), configured);
        // One range per angle: the features take its step from the spacing.
        let per_angle: Vec<Reading> = readings
            .iter()
            .map(|r| Reading {
                ping_count: 1,
                flags: flags::NO_RAW_PINGS,
                ..*r
            })
            .collect();
        assert_eq!(head_as_read(&configured, &per_angle), configured);
    }
}
