//! Everything a fusion engine is set up with, its two presets, and their validation.

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};
use sonar_common::sensor::SensorConfig;

use crate::model::{EchoPlacement, ModelConfig, PaperModel, SmoothModel};
use crate::observation::Limits;
use crate::radar::RadarConfig;
use crate::rule::{LogOddsRule, RuleConfig};

use crate::config_error::check;
pub use crate::config_error::{ConfigError, UnknownName};

/// Most cells per side of a grid (and of the fast kernel's cone stencil): 4096² = 16.8 M cells,
/// which keeps the largest per-cell state (Dempster–Shafer's two f32 masses) at 128 MiB and the
/// stencil at the same.
pub const MAX_CELLS_PER_SIDE: usize = 4096;

/// The probability grid: square, centred on (`centre_x_m`, `centre_y_m`) of the world (the
/// sensor's start, or the odometry's origin, by default). A robot that drives needs a grid over
/// where it goes: its extent is fixed, so a tour's area is given here.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct GridConfig {
    /// Cells per side.
    pub cells: u32,
    /// Cell edge, metres.
    pub resolution_m: f32,
    /// World position of the grid's centre, metres.
    pub centre_x_m: f32,
    pub centre_y_m: f32,
}

impl Default for GridConfig {
    /// 400 × 400 cells of 2 cm: ±4 m, the sensor's whole range around it.
    fn default() -> Self {
        Self {
            cells: 400,
            resolution_m: 0.02,
            centre_x_m: 0.0,
            centre_y_m: 0.0,
        }
    }
}

/// Upper bounds on the readings: the cone the fast kernel prepares for. Readings with a wider beam
/// or a longer range are fused as if they had these.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SensorLimits {
    pub beam_half_angle_deg: f32,
    pub max_range_m: f32,
}

impl Default for SensorLimits {
    /// The paper's ±30° and the SRF05's 4 m (`sonar_common::sensor::SensorConfig`).
    fn default() -> Self {
        let s = SensorConfig::default();
        Self {
            beam_half_angle_deg: s.beam_half_angle_deg,
            max_range_m: s.max_range_m,
        }
    }
}

impl SensorLimits {
    pub(crate) fn limits(&self) -> Limits {
        Limits {
            half_angle: self.beam_half_angle_deg.to_radians(),
            max_range: self.max_range_m,
        }
    }
}

/// The two ready-made configurations.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Preset {
    /// The paper exactly as written: eqs. 1–3 with eq. 6, readings without an echo ignored.
    Paper,
    /// What we recommend: the smooth model with clamped log-odds; see the crate documentation.
    Recommended,
}

impl Preset {
    pub const ALL: [Preset; 2] = [Preset::Paper, Preset::Recommended];
    const NAMES: [&'static str; 2] = ["paper", "recommended"];

    pub fn name(self) -> &'static str {
        Self::NAMES[self as usize]
    }

    /// The `sonar_common::ipc::preset_code` of this preset.
    pub fn code(self) -> u32 {
        use sonar_common::ipc::preset_code;
        match self {
            Preset::Paper => preset_code::PAPER,
            Preset::Recommended => preset_code::RECOMMENDED,
        }
    }

    /// The preset with this `sonar_common::ipc::preset_code` (`CUSTOM` has none).
    pub fn from_code(code: u32) -> Option<Self> {
        Self::ALL.into_iter().find(|p| p.code() == code)
    }
}

impl fmt::Display for Preset {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Preset {
    type Err = UnknownName;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|p| p.name() == s)
            .ok_or_else(|| UnknownName::new("preset", s, &Self::NAMES))
    }
}

/// Everything the fusion engine is set up with. `Default` is [`Preset::Recommended`].
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FusionConfig {
    pub grid: GridConfig,
    pub sensor: SensorLimits,
    pub model: ModelConfig,
    pub rule: RuleConfig,
    /// Fuse readings without an echo as free space up to the maximum range (never an obstacle).
    /// The paper ignores them.
    pub clear_on_no_echo: bool,
    /// The basic method's angle bins.
    pub radar: RadarConfig,
}

impl Default for FusionConfig {
    fn default() -> Self {
        Self::preset(Preset::Recommended)
    }
}

impl FusionConfig {
    /// Takes `preset`'s model, rule and clearing, keeping the grid, sensor and radar: what
    /// `--preset` does on top of a configuration file.
    pub fn use_preset(&mut self, preset: Preset) {
        let p = Self::preset(preset);
        self.model = p.model;
        self.rule = p.rule;
        self.clear_on_no_echo = p.clear_on_no_echo;
    }

    pub fn preset(preset: Preset) -> Self {
        let (model, rule, clear_on_no_echo) = match preset {
            Preset::Paper => (
                ModelConfig::Paper(PaperModel::default()),
                RuleConfig::Bayes,
                false,
            ),
            // No-echo readings are not cleared: a wall met beyond the specular cut-off is silent,
            // and clearing through it erased half the visible walls in `docs/results.md`. Echoes
            // are placed by region of constant depth with every part of
            // `examples/region-map-weak-echoes.toml`: on the generated suite's `report` split at least
            // the recall, and more precision at a lower median error, than each reading's own echo
            // for every profile at 1, 3 and 8 viewpoints (`docs/fusion.md`, "tenth round"). A
            // stretch of wall between two patches is refused only where a reading that would have
            // heard it at its foot heard farther ("thirteenth round": more recall, as much
            // precision or more, and fewer runs whose recall fell, on both splits). A reflector
            // heard whole from two bearings is drawn as a point ("seventeenth round": more
            // precision for every profile, at most 0.02 less recall). A weak echo a wall drawn in
            // its lobe explains, off that wall's line, is taken back ("eighteenth round": more
            // precision and less error from 3 and 8 viewpoints, recall within 0.01). A whole
            // region at two walls' corner is drawn as a point, patches of one wall from several
            // viewpoints lie on the line through their feet, and a stretch refuted later is taken
            // back only around the refuting foot ("nineteenth round": less error for every
            // profile, more precision for three, and view 1's walls no longer lost as
            // viewpoints are added, for up to 0.02 less recall). A region's patch reaches at most
            // half a metre along its wall ("twenty-ninth round": more precision for every
            // profile on both splits, mean recall within 0.005).
            Preset::Recommended => (
                ModelConfig::Smooth(SmoothModel {
                    echo_placement: EchoPlacement::Region,
                    region_one_end: true,
                    region_one_end_free: true,
                    region_corners: true,
                    region_corner_walls: true,
                    region_weak_echo_log_odds: 0.3,
                    region_weak_echo_half_width_m: 0.02,
                    region_weak_echo_withdrawn: true,
                    region_weak_echo_explained: true,
                    region_weak_echo_at_reflector: true,
                    region_masked_free: true,
                    region_small_cutters_free: true,
                    region_stretch_foot_check: true,
                    region_corner_walls_foot_check: true,
                    region_points: true,
                    region_corner_points: true,
                    region_lines_through_feet: true,
                    region_stretch_withdrawn_at_feet: true,
                    region_half_width_m: 0.5,
                    ..SmoothModel::default()
                }),
                RuleConfig::LogOdds(LogOddsRule::default()),
                false,
            ),
        };
        Self {
            grid: GridConfig::default(),
            sensor: SensorLimits::default(),
            model,
            rule,
            clear_on_no_echo,
            radar: RadarConfig::default(),
        }
    }

    /// The preset this configuration is, if it is one (the `preset` field of a snapshot header).
    pub fn matching_preset(&self) -> Option<Preset> {
        Preset::ALL.into_iter().find(|&p| *self == Self::preset(p))
    }

    /// Side of the square around the sensor's cell that the fast kernel's row spans (and a parked
    /// sensor's stencil) cover, in cells: the farthest reach of any reading, both ways, plus a
    /// cell of margin each side.
    pub(crate) fn stencil_side(&self) -> usize {
        let reach = self.model.max_reach(self.sensor.max_range_m);
        let radius = (f64::from(reach) / f64::from(self.grid.resolution_m)).ceil() + 1.0;
        // Saturating float-to-int conversion: an absurd range yields an absurd side, rejected.
        2 * (radius as usize) + 1
    }

    pub fn validate(&self) -> Result<(), ConfigError> {
        let res = self.grid.resolution_m;
        if !(res.is_finite() && res > 0.0) {
            return Err(ConfigError::InvalidResolution(res));
        }
        if self.grid.cells == 0 || self.grid.cells as usize > MAX_CELLS_PER_SIDE {
            return Err(ConfigError::GridSize {
                cells: self.grid.cells,
                max: MAX_CELLS_PER_SIDE,
            });
        }
        for (name, value) in [
            ("grid.centre_x_m", self.grid.centre_x_m),
            ("grid.centre_y_m", self.grid.centre_y_m),
        ] {
            check(name, value, value.is_finite(), "a finite number of metres")?;
        }
        let s = &self.sensor;
        check(
            "sensor.beam_half_angle_deg",
            s.beam_half_angle_deg,
            s.beam_half_angle_deg > 0.0 && s.beam_half_angle_deg < 90.0,
            "in (0, 90) degrees",
        )?;
        check(
            "sensor.max_range_m",
            s.max_range_m,
            s.max_range_m > 0.0 && s.max_range_m.is_finite(),
            "a positive number of metres",
        )?;
        self.model.validate()?;
        self.rule.validate()?;
        self.radar.validate()?;
        let side = self.stencil_side();
        if side > MAX_CELLS_PER_SIDE {
            return Err(ConfigError::StencilTooLarge {
                max_range_m: s.max_range_m,
                resolution_m: res,
                side,
                max: MAX_CELLS_PER_SIDE,
            });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{AlphaSign, ModelKind};
    use crate::rule::{HimmRule, RuleKind};

    #[test]
    fn presets_are_valid_and_recognised() {
        for p in Preset::ALL {
            let cfg = FusionConfig::preset(p);
            assert_eq!(cfg.validate(), Ok(()));
            assert_eq!(cfg.matching_preset(), Some(p));
            assert_eq!(p.name().parse::<Preset>(), Ok(p));
            assert_eq!(Preset::from_code(p.code()), Some(p));
        }
        assert_eq!(
            FusionConfig::default(),
            FusionConfig::preset(Preset::Recommended)
        );
        let paper = FusionConfig::preset(Preset::Paper);
        assert_eq!(paper.model.kind(), ModelKind::Paper);
        assert_eq!(paper.rule.kind(), RuleKind::Bayes);
        assert!(!paper.clear_on_no_echo);
        let custom = FusionConfig {
            clear_on_no_echo: true,
            ..FusionConfig::default()
        };
        assert_eq!(custom.matching_preset(), None);
        assert!("papers".parse::<Preset>().is_err());
    }

    #[test]
    fn invalid_configurations_say_what_is_wrong() {
        let base = FusionConfig::default();
        for res in [0.0, -0.02, f32::NAN] {
            let cfg = FusionConfig {
                grid: GridConfig {
                    resolution_m: res,
                    ..base.grid
                },
                ..base
            };
            assert!(matches!(
                cfg.validate(),
                Err(ConfigError::InvalidResolution(_))
            ));
        }
        for cells in [0, 5000] {
            let cfg = FusionConfig {
                grid: GridConfig { cells, ..base.grid },
                ..base
            };
            assert!(matches!(cfg.validate(), Err(ConfigError::GridSize { .. })));
        }
        let far = FusionConfig {
            grid: GridConfig {
                centre_x_m: f32::INFINITY,
                ..base.grid
            },
            ..base
        };
        assert!(matches!(
            far.validate(),
            Err(ConfigError::InvalidParameter {
                name: "grid.centre_x_m",
                ..
            })
        ));
        let fine = FusionConfig {
            grid: GridConfig {
                cells: 400,
                resolution_m: 0.001,
                ..base.grid
            },
            ..base
        };
        assert!(matches!(
            fine.validate(),
            Err(ConfigError::StencilTooLarge { .. })
        ));
        let bad_rule = FusionConfig {
            rule: RuleConfig::Himm(HimmRule {
                max_count: 255,
                ..Default::default()
            }),
            ..base
        };
        let err = bad_rule.validate().unwrap_err();
        assert_eq!(
            err.to_string(),
            "rule.max_count = 255 is invalid: expected in 1..=254"
        );
        let bad_model = FusionConfig {
            model: ModelConfig::Paper(PaperModel {
                max_occupied: 0.3,
                ..Default::default()
            }),
            ..base
        };
        assert!(matches!(
            bad_model.validate(),
            Err(ConfigError::InvalidParameter {
                name: "model.max_occupied",
                ..
            })
        ));
    }

    /// `docs/fusion.md` writes both presets out as `[fusion]` tables of a pipeline configuration
    /// file; they must parse, and be the presets.
    #[test]
    fn the_presets_written_out_in_docs_fusion_md_are_the_presets() {
        #[derive(Deserialize)]
        struct File {
            fusion: FusionConfig,
        }
        let doc = include_str!("../../docs/fusion.md");
        let blocks: Vec<FusionConfig> = doc
            .split("```toml")
            .skip(1)
            .map(|b| b.split("```").next().unwrap())
            .map(|b| toml::from_str::<File>(b).unwrap().fusion)
            .collect();
        assert_eq!(
            blocks,
            [
                FusionConfig::preset(Preset::Paper),
                FusionConfig::preset(Preset::Recommended)
            ]
        );
    }

    /// The region maps of `examples/` parse and validate, and differ only in the weak echoes (and
    /// the previous preset's, in the corner walls' foot check; the confirmed corners', in which
    /// patches are followed to corners).
    #[test]
    fn the_example_region_maps_parse() {
        #[derive(Deserialize)]
        struct File {
            fusion: FusionConfig,
        }
        let parse = |text: &str| {
            let config = toml::from_str::<File>(text).unwrap().fusion;
            config.validate().unwrap();
            match config.model {
                ModelConfig::Smooth(m) => m,
                other => panic!("{other:?}"),
            }
        };
        let precise = parse(include_str!("../../examples/region-map.toml"));
        let weak = parse(include_str!("../../examples/region-map-weak-echoes.toml"));
        assert!(precise.region_corner_walls && precise.region_one_end && precise.region_corners);
        assert_eq!(precise.region_weak_echo_log_odds, 0.0);
        assert!(!precise.region_weak_echo_withdrawn && !precise.region_masked_free);
        assert!(!precise.region_small_cutters_free);
        assert_eq!(
            weak,
            crate::model::SmoothModel {
                region_one_end_free: true,
                region_weak_echo_log_odds: 0.3,
                region_weak_echo_withdrawn: true,
                region_masked_free: true,
                region_small_cutters_free: true,
                ..precise
            }
        );
        let points = parse(include_str!(
            "../../examples/region-map-weak-echo-points.toml"
        ));
        assert_eq!(
            points,
            crate::model::SmoothModel {
                region_weak_echo_half_width_m: 0.02,
                ..weak
            }
        );
        let fewer_walls = parse(include_str!("../../examples/region-map-fewer-walls.toml"));
        let ModelConfig::Smooth(preset) = FusionConfig::preset(Preset::Recommended).model else {
            panic!("the recommended preset's model is the smooth one");
        };
        assert_eq!(
            preset,
            crate::model::SmoothModel {
                region_corner_walls_foot_check: true,
                region_points: true,
                region_weak_echo_explained: true,
                region_weak_echo_half_width_m: 0.02,
                region_weak_echo_at_reflector: true,
                region_corner_points: true,
                region_lines_through_feet: true,
                region_stretch_withdrawn_at_feet: true,
                region_half_width_m: 0.5,
                ..fewer_walls
            }
        );
        let confirmed = parse(include_str!(
            "../../examples/region-map-confirmed-corners.toml"
        ));
        assert_eq!(
            confirmed,
            crate::model::SmoothModel {
                region_corner_walls_confirmed: true,
                ..preset
            }
        );
        let narrow = parse(include_str!("../../examples/region-map-narrow-beam.toml"));
        assert_eq!(
            narrow,
            crate::model::SmoothModel {
                region_hidden_unknown: true,
                region_hidden_behind_walls: true,
                ..confirmed
            }
        );
    }

    #[test]
    fn toml_round_trip_and_partial_files() {
        let cfg = FusionConfig {
            model: ModelConfig::Paper(PaperModel {
                alpha: AlphaSign::Signed,
                ..Default::default()
            }),
            ..FusionConfig::default()
        };
        let text = toml::to_string(&cfg).unwrap();
        assert_eq!(toml::from_str::<FusionConfig>(&text).unwrap(), cfg);

        let partial: FusionConfig = toml::from_str(
            r#"
            clear_on_no_echo = false
            [grid]
            resolution_m = 0.01
            [model]
            kind = "paper"
            tolerance = 0.1
            [rule]
            kind = "bayes"
            "#,
        )
        .unwrap();
        assert_eq!(partial.grid.cells, 400);
        assert_eq!(partial.grid.resolution_m, 0.01);
        assert_eq!(
            partial.model,
            ModelConfig::Paper(PaperModel {
                tolerance: 0.1,
                ..Default::default()
            })
        );
        assert_eq!(partial.rule, RuleConfig::Bayes);

        for bad in [
            "[model]\nkind = \"ros\"",
            "[model]\nkind = \"paper\"\ntolerence = 0.1",
            "[grid]\nsize = 3",
        ] {
            assert!(toml::from_str::<FusionConfig>(bad).is_err(), "{bad}");
        }
    }
}
