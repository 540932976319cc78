//! Each run's history as the console keeps it: the records the coordinator publishes live (`keys::trace`) that
//! are history (`run::feed::is_history`), and, for a run under way when the console first sees it, what the
//! coordinator kept before (`keys::history`). Each entry gets a number of the console's own, so that a page asks
//! only for what is new (`GET /api/runs/{run}/history?after=N`); a record heard twice (live, then in a history
//! answer; or replayed by a coordinator that took the run over) is kept once.

use std::collections::{BTreeMap, BTreeSet, VecDeque};

use baton_proto::cluster::wire::{self, RunId};
use baton_proto::exec::trace::TraceRecord;

use crate::run::feed::{is_history, HISTORY_MAX};

/// The largest history answer read: `HISTORY_MAX` records with long messages.
pub const HISTORY_BYTES_MAX: usize = 8 * baton_proto::limits::MESSAGE_BYTES_MAX;

#[derive(Clone, Debug, serde::Serialize)]
pub struct Entry {
    /// The console's number for it: later entries have larger ones.
    pub seq: u64,
    /// When it happened, by the console's clock (for a record from before the console heard the run, worked out
    /// from the run's clock).
    pub unix_ms: u64,
    #[serde(flatten)]
    pub record: TraceRecord,
}

#[derive(Default)]
struct RunHistory {
    entries: VecDeque<Entry>,
    /// The records kept, as JSON: a record heard again is not kept twice.
    seen: BTreeSet<String>,
    /// Whether the coordinator was asked for what it kept before.
    asked: bool,
}

#[derive(Default)]
pub struct Histories {
    runs: BTreeMap<RunId, RunHistory>,
    last_seq: u64,
}

impl Histories {
    /// Keeps the history records among `records` of run `run`, each at the Unix time `unix_ms` gives it; returns
    /// whether any was new.
    pub fn add(&mut self, run: RunId, records: Vec<TraceRecord>, unix_ms: impl Fn(&TraceRecord) -> u64) -> bool {
        let history = self.runs.entry(run).or_default();
        let mut added = false;
        for record in records.into_iter().filter(|r| is_history(r.event)) {
            let key = serde_json::to_string(&record).unwrap_or_default();
            if !history.seen.insert(key) {
                continue;
            }
            self.last_seq += 1;
            history.entries.push_back(Entry { seq: self.last_seq, unix_ms: unix_ms(&record), record });
            if history.entries.len() > HISTORY_MAX {
                if let Some(old) = history.entries.pop_front() {
                    history.seen.remove(&serde_json::to_string(&old.record).unwrap_or_default());
                }
            }
            added = true;
        }
        added
    }

    /// Whether run `run` is new to the console, its coordinator yet to be asked for its history (from now on, it is
    /// taken as asked).
    pub fn first_sight(&mut self, run: RunId) -> bool {
        let history = self.runs.entry(run).or_default();
        !std::mem::replace(&mut history.asked, true)
    }

    /// Every run's coordinator is to be asked for its history again: records may have gone by unheard while the
    /// console had no router (what it heard already is kept once).
    pub fn ask_again(&mut self) {
        self.runs.values_mut().for_each(|h| h.asked = false);
    }

    /// Run `run`'s entries numbered after `after`, oldest first by the run's clock.
    pub fn after(&self, run: RunId, after: u64) -> Vec<Entry> {
        let mut entries: Vec<Entry> = self
            .runs
            .get(&run)
            .map(|h| h.entries.iter().filter(|e| e.seq > after).cloned().collect())
            .unwrap_or_default();
        entries.sort_by_key(|e| (e.record.t_ms, e.seq));
        entries
    }

    pub fn last_seq(&self) -> u64 {
        self.last_seq
    }

    /// Forgets the runs not in `live` whose history was never asked for (runs the console saw only in passing
    /// keep nothing); the histories of runs that ended stay, to be read, up to `RUNS_KEPT` of them.
    pub fn forget_beyond(&mut self, live: &BTreeSet<RunId>) {
        let ended: Vec<RunId> = self.runs.keys().filter(|r| !live.contains(r)).copied().collect();
        for run in ended.iter().take(ended.len().saturating_sub(RUNS_KEPT)) {
            self.runs.remove(run);
        }
    }
}

/// Ended runs whose history the console keeps.
const RUNS_KEPT: usize = 16;

/// A history answer's records; an answer that is not one is said as the error.
pub fn decode_answer(bytes: &[u8]) -> Result<Vec<TraceRecord>, String> {
    wire::decode_with_limit(bytes, HISTORY_BYTES_MAX).map_err(|e| e.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;
    use baton_proto::exec::trace::TraceEvent;

    fn rec(t_ms: u64, event: TraceEvent, name: &str) -> TraceRecord {
        TraceRecord::new(t_ms, event, name)
    }

    #[test]
    fn keeps_history_once_in_the_runs_order() {
        let run = RunId(uuid::Uuid::from_u128(1));
        let mut h = Histories::default();
        // Heard live: a state change and a step's activation (not history).
        assert!(h.add(run, vec![rec(500, TraceEvent::State, "held"), rec(510, TraceEvent::Activate, "S1")], |_| 9));
        // The coordinator's answer, asked later: older records, and the one already heard.
        assert!(h.add(run, vec![rec(100, TraceEvent::Command, "hold"), rec(500, TraceEvent::State, "held")], |_| 9));
        assert!(!h.add(run, vec![rec(500, TraceEvent::State, "held")], |_| 9));
        let all = h.after(run, 0);
        let names: Vec<&str> = all.iter().map(|e| e.record.name.as_str()).collect();
        assert_eq!(names, ["hold", "held"]);
        // Only what is numbered after a page's last entry.
        let last = all.iter().map(|e| e.seq).max().unwrap_or(0);
        assert!(h.add(run, vec![rec(900, TraceEvent::Command, "unhold")], |_| 9));
        assert_eq!(h.after(run, last).len(), 1);
        assert!(h.first_sight(run));
        assert!(!h.first_sight(run));
    }

    #[test]
    fn keeps_at_most_its_limit() {
        let run = RunId(uuid::Uuid::from_u128(2));
        let mut h = Histories::default();
        let many = (0..HISTORY_MAX as u64 + 10).map(|t| rec(t, TraceEvent::Command, "hold")).collect();
        h.add(run, many, |_| 0);
        let kept = h.after(run, 0);
        assert_eq!(kept.len(), HISTORY_MAX);
        assert_eq!(kept[0].record.t_ms, 10, "the oldest go first");
    }
}
