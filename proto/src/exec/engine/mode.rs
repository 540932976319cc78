//! The engine's `Mode`: how a chart's transitions clear (`operator.rs` carries out what each mode allows).

use serde::{Deserialize, Serialize};

/// How a chart's transitions clear: by their conditions (`auto`); only once an operator confirms one whose
/// condition is TRUE (`step`, S7-GRAPH's TAP, CODESYS's tip mode); or only when an operator forces one, whatever
/// its condition, with steps switched by hand (`manual`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Mode {
    #[default]
    Auto,
    Step,
    Manual,
}

impl Mode {
    pub const ALL: [Mode; 3] = [Mode::Auto, Mode::Step, Mode::Manual];

    /// Its name in the trace, the status and `baton ctl mode`.
    pub fn name(self) -> &'static str {
        match self {
            Mode::Auto => "auto",
            Mode::Step => "step",
            Mode::Manual => "manual",
        }
    }

    pub fn from_name(name: &str) -> Option<Mode> {
        Mode::ALL.into_iter().find(|m| m.name().eq_ignore_ascii_case(name))
    }
}
