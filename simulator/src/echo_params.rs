//! The echo model's settings: its physics (`[echo]` in a scene file) and its noise (`[noise]`),
//! with their defaults and checks. Their own module so that a scene and a sensor profile can hold
//! them without depending on the model that uses them (`crate::echo`).

use serde::{Deserialize, Serialize};

/// Physical parameters of the echo model; `[echo]` in a scene file. Defaults from
/// `shared/docs/sensor-facts.md` where it has a number, fitted to its calibration points otherwise.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EchoParams {
    /// Carrier frequency: the SRF05 sends 8 cycles at 40 kHz (sensor-facts, paper §II.A.1). Sets
    /// the wavelength (8.6 mm at 20 °C) for the jitter and the Fresnel zones.
    pub frequency_hz: f64,
    /// Angle off axis where the round-trip beam is 6 dB down: 27° (sensor-facts: ≈ 55° full width).
    pub beam_6db_half_angle_deg: f64,
    /// Largest incidence at which a flat wall still returns: sensor-facts' bench measurement read a
    /// card correctly up to ≈ 25–30°; 28° lets a wall be heard to ±25° off its normal with margin.
    pub specular_cutoff_deg: f64,
    /// Air absorption, one way: 1.3 dB/m at 40 kHz, 20 °C, 50 % RH (ISO 9613-1).
    pub absorption_db_per_m: f64,
    /// Receiver gain ramp per metre of range (fitted: see the module docs).
    pub tvg_db_per_m: f64,
    /// Range after which the gain ramp holds.
    pub tvg_max_range_m: f64,
    /// Detection threshold (fitted: a 5 cm post at 1 m is heard within ≈ ±13°).
    pub threshold_db: f64,
    /// Loss of a concave corner against a flat wall at the same range (finite aperture).
    pub corner_loss_db: f64,
    /// Concave joints up to this opening act as corners; wider ones are shallow bends.
    pub corner_max_opening_deg: f64,
    /// An edge scatters like a cylinder of this radius: weak, heard only near.
    pub edge_radius_m: f64,
    /// Extra loss of a soft surface (fabric, foam) against a hard one.
    pub soft_loss_db: f64,
    /// Loss of a thin board ([`Surface::Board`]: a shelf, a skirting, a cardboard panel lower
    /// than the beam is tall) against a wall that fills the beam: a low target strength. Its ends
    /// return nothing (a board seen edge-on is silent).
    pub board_loss_db: f64,
    /// Loss of a rough surface's mirror echo against a smooth wall's ([`Surface::Rough`]): part
    /// of the sound it scatters instead of mirroring.
    pub rough_specular_loss_db: f64,
    /// Level of a rough surface's scattered echo met square on, against a flat mirror's at 0.5 m
    /// (0 dB). Each point of it in the beam scatters back by Lambert's law (its level falls as
    /// 20·log10 of the cosine of its incidence), and the patch the beam lights grows with range,
    /// so it falls as −30·log10(2r) where a mirror's falls as −20·log10(2r). Not fitted to a
    /// measurement (none is at hand): −6 dB lets a rough wall be heard on the beam's axis 30° off
    /// square to about 2.4 m through the `srf05` profile, 45° off to 1.8 m, 60° off to 1.2 m.
    pub rough_diffuse_db: f64,
    /// Double-bounce ghosts: a ping that leaves by one wall, meets a second and comes back by
    /// the first (the path of two mirror images, S → A → B → S) returns a late phantom from where
    /// no surface is, in corners that are not square and between a wall and a board or partition
    /// at a slant. Off by default (the figures of `docs/results.md` were made without).
    pub double_bounce: bool,
    /// Loss of such a ghost against a flat wall at the same path length (two imperfect mirrors).
    pub double_bounce_loss_db: f64,
    /// What the sensor's own processing adds to every range it reports, metres (−0.03: a sensor
    /// that reads 3 cm short). 0 for the raw SRF05 echo line.
    pub range_bias_m: f64,
    /// The step of the ranges the sensor reports, metres (0.01: whole centimetres); 0 for the raw
    /// echo line's continuous time.
    pub range_step_m: f64,
}

impl Default for EchoParams {
    fn default() -> Self {
        Self {
            frequency_hz: 40_000.0,
            beam_6db_half_angle_deg: 27.0,
            specular_cutoff_deg: 28.0,
            absorption_db_per_m: 1.3,
            tvg_db_per_m: 11.0,
            tvg_max_range_m: 2.0,
            threshold_db: -15.0,
            corner_loss_db: 3.0,
            corner_max_opening_deg: 120.0,
            edge_radius_m: 0.01,
            soft_loss_db: 12.0,
            board_loss_db: 8.0,
            rough_specular_loss_db: 3.0,
            rough_diffuse_db: -6.0,
            double_bounce: false,
            double_bounce_loss_db: 6.0,
            range_bias_m: 0.0,
            range_step_m: 0.0,
        }
    }
}

/// Noise of the ranging; `[noise]` in a scene file.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NoiseParams {
    /// The detector fires on the first to the `1 + late_cycles_max`-th cycle of the echo, each late
    /// cycle adding one period (half a wavelength of range): 2 gives sensor-facts' jitter of about
    /// one wavelength (0–8.6 mm).
    pub late_cycles_max: u32,
    /// Share of pings ended early by a transient (sensor-facts: rare spurious short readings).
    pub spurious_probability: f64,
    /// Standard deviation of a zero-mean Gaussian added to every ping's range, m, at any range:
    /// the jitter of real SRF05/HC-SR04 readings (about a centimetre, sensor-facts) that the
    /// late-cycle model alone does not make. 0 (the default) keeps the noise of the late cycles only.
    pub range_sigma_m: f64,
    /// The part of that deviation that grows with range, as a share of the range (0.01: 1 %).
    pub range_sigma_fraction: f64,
    /// Amplitude jitter: each ping's detection threshold moves by a uniform draw in ± this many
    /// dB (1: the issue's ±1 dB), so a target near the edge of its effective cone or range is
    /// heard by some pings and not others. 0 (the default) keeps the threshold fixed.
    pub threshold_jitter_db: f64,
    /// Share of pings that report no echo whatever is there (a lost burst, a missed edge of the
    /// echo line). 0 by default.
    pub dropout_probability: f64,
}

impl Default for NoiseParams {
    fn default() -> Self {
        Self {
            late_cycles_max: 2,
            spurious_probability: 0.005,
            range_sigma_m: 0.0,
            range_sigma_fraction: 0.0,
            threshold_jitter_db: 0.0,
            dropout_probability: 0.0,
        }
    }
}

fn require(ok: bool, what: &str) -> Result<(), String> {
    if ok { Ok(()) } else { Err(what.to_owned()) }
}

impl EchoParams {
    pub fn validate(&self) -> Result<(), String> {
        let p = self;
        require(
            p.frequency_hz.is_finite() && p.frequency_hz > 0.0,
            "echo.frequency_hz must be > 0",
        )?;
        require(
            p.beam_6db_half_angle_deg > 0.0 && p.beam_6db_half_angle_deg < 90.0,
            "echo.beam_6db_half_angle_deg must be in (0, 90)",
        )?;
        require(
            p.specular_cutoff_deg >= 0.0 && p.specular_cutoff_deg <= 90.0,
            "echo.specular_cutoff_deg must be in [0, 90]",
        )?;
        for (value, name) in [
            (p.absorption_db_per_m, "echo.absorption_db_per_m"),
            (p.tvg_db_per_m, "echo.tvg_db_per_m"),
            (p.tvg_max_range_m, "echo.tvg_max_range_m"),
            (p.corner_loss_db, "echo.corner_loss_db"),
            (p.soft_loss_db, "echo.soft_loss_db"),
            (p.board_loss_db, "echo.board_loss_db"),
            (p.rough_specular_loss_db, "echo.rough_specular_loss_db"),
            (p.double_bounce_loss_db, "echo.double_bounce_loss_db"),
            (p.range_step_m, "echo.range_step_m"),
        ] {
            require(
                value.is_finite() && value >= 0.0,
                &format!("{name} must be >= 0"),
            )?;
        }
        require(
            p.rough_diffuse_db.is_finite(),
            "echo.rough_diffuse_db must be a number",
        )?;
        require(
            p.threshold_db.is_finite(),
            "echo.threshold_db must be a number",
        )?;
        require(
            p.corner_max_opening_deg > 0.0 && p.corner_max_opening_deg < 180.0,
            "echo.corner_max_opening_deg must be in (0, 180)",
        )?;
        require(
            p.range_bias_m.is_finite() && p.range_bias_m.abs() <= 0.5,
            "echo.range_bias_m must be within ±0.5 m",
        )?;
        require(
            p.edge_radius_m.is_finite() && p.edge_radius_m > 0.0,
            "echo.edge_radius_m must be > 0",
        )
    }

    /// The range the sensor reports for a measured `range_m`: its bias added, rounded to its
    /// step. Only called when the profile has either.
    pub(crate) fn processed_range(&self, range_m: f64) -> f64 {
        let biased = range_m + self.range_bias_m;
        if self.range_step_m > 0.0 {
            (biased / self.range_step_m).round() * self.range_step_m
        } else {
            biased
        }
    }
}

impl NoiseParams {
    /// The Gaussian range noise's deviation at `range_m`.
    pub fn range_sigma_at(&self, range_m: f64) -> f64 {
        self.range_sigma_m + self.range_sigma_fraction * range_m
    }

    pub fn validate(&self) -> Result<(), String> {
        require(
            (0.0..=1.0).contains(&self.spurious_probability),
            "noise.spurious_probability must be in [0, 1]",
        )?;
        require(
            self.range_sigma_m.is_finite() && self.range_sigma_m >= 0.0,
            "noise.range_sigma_m must be >= 0",
        )?;
        require(
            self.range_sigma_fraction.is_finite() && self.range_sigma_fraction >= 0.0,
            "noise.range_sigma_fraction must be >= 0",
        )?;
        require(
            self.threshold_jitter_db.is_finite()
                && (0.0..=20.0).contains(&self.threshold_jitter_db),
            "noise.threshold_jitter_db must be in [0, 20]",
        )?;
        require(
            (0.0..=1.0).contains(&self.dropout_probability),
            "noise.dropout_probability must be in [0, 1]",
        )
    }
}
