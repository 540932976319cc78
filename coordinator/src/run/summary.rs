//! What a run did, as `baton run --summary` writes it and `baton run` prints it.

use std::collections::BTreeMap;

use serde::Serialize;

/// What `baton run` prints at the end, and writes with `--summary FILE`.
#[derive(Serialize)]
pub struct Summary {
    pub chart: String,
    pub run: String,
    /// How the run ended, as its PackML state: `complete`, `stopped` or `aborted` (`execute` for a run that
    /// failed or reached a terminal situation without its end recorded).
    pub state: String,
    pub duration_ms: u64,
    pub tokens_dispatched: u64,
    pub tokens_returned: u64,
    pub messages_dropped: u64,
    /// Per step: how many times it was active and for how long in all.
    pub steps: BTreeMap<String, StepTime>,
    /// Final values of the chart's variables.
    pub vars: BTreeMap<String, String>,
    /// The process went away (SIGTERM with a journal) and left the run as it stands, for its journal to resume:
    /// `state` is where it stood.
    pub left: bool,
    /// The coordinator lost its election (`--election`) and stopped acting: it may stand again.
    #[serde(skip)]
    pub deposed: bool,
    /// With `--journal`: records written and transactions committed by this process.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub journal: Option<crate::journal::JournalStats>,
}

#[derive(Serialize, serde::Deserialize, Default, Clone, Copy)]
pub struct StepTime {
    pub activations: u64,
    pub active_ms: u64,
}

impl Summary {
    pub fn print(&self) {
        match self.state.as_str() {
            _ if self.left => println!(
                "chart `{}` left in state {} after {} ms, for its journal to resume",
                self.chart, self.state, self.duration_ms
            ),
            "stopped" | "aborted" => {
                println!("chart `{}` was {} after {} ms", self.chart, self.state, self.duration_ms)
            }
            _ => println!("chart `{}` finished in {} ms", self.chart, self.duration_ms),
        }
        println!(
            "tokens: {} dispatched, {} returned; {} message(s) dropped",
            self.tokens_dispatched, self.tokens_returned, self.messages_dropped
        );
        println!("{:<24} {:>11} {:>14}", "step", "activations", "active ms");
        for (name, t) in &self.steps {
            println!("{name:<24} {:>11} {:>14}", t.activations, t.active_ms);
        }
        let vars: Vec<String> = self.vars.iter().map(|(k, v)| format!("{k} = {v}")).collect();
        println!("variables: {}", vars.join(", "));
        if let Some(j) = &self.journal {
            println!(
                "journal: {} records in {} commits ({:.0} µs each on average), {} snapshots",
                j.records, j.commits, j.commit_us, j.snapshots
            );
        }
    }
}
