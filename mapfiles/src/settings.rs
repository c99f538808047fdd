//! Display names of the fusion settings a snapshot header carries as codes
//! (`GridHeader::model`, `rule`, `preset`), for file metadata and the viewer.

use sonar_common::ipc::{model_code, preset_code, rule_code};

pub const MODELS: &[(u32, &str)] = &[
    (model_code::PAPER, "paper"),
    (model_code::LOG_ODDS, "log-odds"),
    (model_code::SMOOTH, "smooth"),
];
pub const RULES: &[(u32, &str)] = &[
    (rule_code::BAYES, "Bayes"),
    (rule_code::LOG_ODDS, "log-odds"),
    (rule_code::DEMPSTER_SHAFER, "Dempster-Shafer"),
    (rule_code::HIMM, "HIMM"),
];
/// "custom" is what the engine reports after a model or rule change.
pub const PRESETS: &[(u32, &str)] = &[
    (preset_code::PAPER, "paper"),
    (preset_code::RECOMMENDED, "recommended"),
    (preset_code::CUSTOM, "custom"),
];

/// The name of `code` in `table`, or "#code" for one this program does not know.
pub fn setting_name(table: &[(u32, &str)], code: u32) -> String {
    table
        .iter()
        .find(|(c, _)| *c == code)
        .map_or_else(|| format!("#{code}"), |(_, n)| (*n).to_owned())
}
