//! A scenario file as written: the TOML tables, with the places of their values for error messages.

use std::collections::BTreeMap;

use serde::Deserialize;
use toml::Spanned;

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawScenario {
    pub(super) chart: Spanned<String>,
    pub(super) pou: Option<Spanned<String>>,
    pub(super) name: Option<String>,
    pub(super) until: Option<Spanned<String>>,
    pub(super) seed: Option<u64>,
    #[serde(default)]
    pub(super) run: RawRun,
    #[serde(default)]
    pub(super) network: RawNetwork,
    #[serde(default)]
    pub(super) agents: Vec<Spanned<RawAgent>>,
    #[serde(default)]
    pub(super) actions: BTreeMap<String, Spanned<RawAction>>,
    #[serde(default)]
    pub(super) inputs: Vec<Spanned<RawInput>>,
    #[serde(default)]
    pub(super) faults: Vec<Spanned<RawFault>>,
    #[serde(default)]
    pub(super) expect: Vec<Spanned<RawExpect>>,
    #[serde(default)]
    pub(super) commands: Vec<Spanned<RawCommand>>,
}

/// `[[commands]]`: what an operator sends with `baton ctl`, at a time or when a condition holds.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawCommand {
    pub(super) command: Spanned<String>,
    pub(super) target: Option<Spanned<toml::Value>>,
    pub(super) agent: Option<String>,
    pub(super) step: Option<String>,
    #[serde(rename = "for")]
    pub(super) lasting: Option<Spanned<String>>,
    pub(super) reason: Option<String>,
    pub(super) by: Option<String>,
    pub(super) to: Option<Spanned<String>>,
    pub(super) at: Option<Spanned<String>>,
    pub(super) when: Option<Spanned<String>>,
    pub(super) after: Option<Spanned<String>>,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub(super) struct RawRun {
    pub(super) on_agent_loss: Option<Spanned<String>>,
    pub(super) journal: Option<bool>,
    pub(super) cycle_ms: Option<Spanned<u64>>,
    pub(super) stay: Option<bool>,
}

#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub(super) struct RawNetwork {
    pub(super) delay: Option<Spanned<String>>,
    pub(super) drop: Option<Spanned<f64>>,
    pub(super) duplicate: Option<Spanned<f64>>,
    pub(super) reorder: Option<bool>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawAgent {
    pub(super) name: String,
    #[serde(default)]
    pub(super) roles: Vec<String>,
    pub(super) start: Option<Spanned<String>>,
    pub(super) skills: Option<Vec<String>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawAction {
    pub(super) duration: Option<Spanned<toml::Value>>,
    pub(super) outcomes: Option<Vec<Spanned<String>>>,
    #[serde(default)]
    pub(super) hang: bool,
    pub(super) message: Option<String>,
    #[serde(default)]
    pub(super) writes: BTreeMap<String, toml::Value>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawInput {
    pub(super) at: Option<Spanned<String>>,
    pub(super) when: Option<Spanned<String>>,
    pub(super) after: Option<Spanned<String>>,
    pub(super) set: BTreeMap<String, toml::Value>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawFault {
    pub(super) kill: Option<String>,
    pub(super) restart: Option<String>,
    pub(super) cut: Option<String>,
    pub(super) heal: Option<String>,
    pub(super) link: Option<String>,
    pub(super) crash_coordinator: Option<bool>,
    pub(super) at: Option<Spanned<String>>,
    pub(super) when: Option<Spanned<String>>,
    pub(super) after: Option<Spanned<String>>,
    pub(super) jitter: Option<Spanned<String>>,
    pub(super) heal_after: Option<Spanned<String>>,
    pub(super) down: Option<Spanned<String>>,
    /// `for`, how long a link's faults last.
    #[serde(rename = "for")]
    pub(super) lasting: Option<Spanned<String>>,
    pub(super) delay: Option<Spanned<String>>,
    pub(super) drop: Option<Spanned<f64>>,
    pub(super) duplicate: Option<Spanned<f64>>,
    pub(super) reorder: Option<bool>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
pub(super) struct RawExpect {
    pub(super) reached: Option<String>,
    pub(super) on: Option<String>,
    pub(super) by: Option<Spanned<String>>,
    pub(super) order: Option<Vec<String>>,
    pub(super) value: Option<BTreeMap<String, toml::Value>>,
    pub(super) at: Option<Spanned<String>>,
    pub(super) always: Option<Spanned<String>>,
    pub(super) never: Option<Spanned<String>>,
    pub(super) ends_by: Option<Spanned<String>>,
    pub(super) alarms: Option<Vec<String>>,
    pub(super) state: Option<Spanned<String>>,
    pub(super) states: Option<Vec<Spanned<String>>>,
    pub(super) modes: Option<Vec<Spanned<String>>>,
    pub(super) once_per_epoch: Option<String>,
}
