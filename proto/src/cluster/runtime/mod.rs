//! The pure halves of a distributed run: the coordinator's and the agent's state machines. The Zenoh hosts in
//! `baton-coordinator` and `baton-agent` feed them decoded messages and the time, and carry out what they
//! output; a simulation can drive them just as well, in one thread.
//!
//! `runtime/coordinator.rs`, `runtime/agent.rs`: the two halves of a distributed run as pure state machines (an agent
//! sets its engine's grid when it plans its first cycle or takes its first token, whichever comes first, so that step
//! times and timers are floored to the grid its cycles run on; the coordinator publishes changed variables before a
//! dispatch, so that the dispatch's values carry an update number of their own) (`handle_*` in, `poll_output` and
//! `poll_timeout` out): token creation and dispatch, agent choice, report sequencing and acknowledgement (an agent
//! numbers no new report past `REPORTS_UNACKED_MAX` unacknowledged, and coalesces what waits), mirroring, variable
//! ownership, skill start/stop, resend with backoff, the cycle grid (cycles only when needed, reactions after every
//! input), what happens to the tokens of a lost agent (`LossPolicy`: pause, reassign in a new epoch after the fence
//! margin, fail), agent conflicts (two processes under one name) and the agent's lease fence (`handle_contact`).
//! `runtime/mod.rs` has `VarWrites`, which write of each variable was applied last (writer, process, update number),
//! and `VarsResend`, the one schedule on which the coordinator and an agent publish their last variable update again. A
//! dispatch and a join carry the current value of every variable the agent reads or writes, so a restarted agent starts
//! from the chart's values (`AgentRun::seeded`: a process publishes nothing before it has them). An agent applies an
//! update only from the variable's one writer, in the process `Peers` names, and parks (bounded by
//! `PARKED_UPDATE_BYTES_MAX`) one from a process not named yet. The coordinator decides before it journals:
//! `classify_report`/`admit_report`, `admit_vars`, `admit_devices` and `check_set` say what would apply, and only that
//! becomes a record; reports held ahead of a gap are bounded by count and by `REPORTS_AHEAD_BYTES_MAX`.
//!
//! # Rules the runtimes keep
//!
//! - A token's reports apply once each, in sequence order; its messages carry its id and epoch; whatever is malformed,
//!   stale, duplicated or from the wrong sender is counted and dropped, never applied. A report of an older epoch (the
//!   segment was reassigned) is answered with `ToAgent::Drop`, so its agent stops the old run.
//!
//! - A token goes back to an agent in the same epoch only if it is the same process (`AgentInfo::incarnation`): a
//!   restarted agent lost the segment's progress, so the segment starts again in a new epoch — even if the coordinator
//!   never saw the old process go.
//!
//! - A name is one process: commands go to `baton/agent/<name>/<incarnation>/cmd`, reports and variable updates carry
//!   their process, and a name two processes answer to gets nothing dispatched. Sequence numbers belong to a process: a
//!   variable's last applied write is kept with its writer's incarnation (`VarWrites`), one entry per variable, so a
//!   peer cannot grow it.
//!
//! - The coordinator is deterministic: the same records (`journal::Record`) at the same times give the same situation,
//!   tokens and trace. A cycle that changed nothing is not recorded (only the last of a series, before the next record,
//!   to carry the time): it leaves the coordinator as it was but for its clock, and activation times come from the
//!   cycle grid, not from the cycles that ran. So it must never iterate a `HashMap (clippy refuses it in `proto`)`
//!   where order shows (it sorts ids first), never read a clock or a random source, and every input goes through
//!   `journal::apply`. The simulation checks after each crash that the replay rebuilt the trace exactly.
//!
//! - A coordinator that restarts trusts nothing it knew about agents until each answers (`recovering`): a token is kept
//!   by an agent that lists it (same incarnation, same epoch), sent again to one that lacks it, restarted in a new
//!   epoch on one that restarted, and an agent silent for its lease after the restart is lost.
//!
//! - Agents remember finished tokens with their epoch: a dispatch of that epoch or older is a duplicate, a newer one
//!   runs.

pub mod agent;
pub mod alarms;
pub mod coordinator;
pub mod packml;

use std::collections::VecDeque;

use uuid::Uuid;

use crate::limits::RETIRED_INCARNATIONS_MAX;

/// Finished tokens, by id: up to `FINISHED_TOKENS_REMEMBERED` random ids, one in and one out per token, where an
/// ordered map's walk down cold nodes was a tenth of a round trip's own work (issue 36). Hashed, so looked up only;
/// whatever lists them (a snapshot) sorts them first.
#[allow(clippy::disallowed_types, reason = "looked up only: a snapshot lists the tokens in id order")]
pub(crate) type FinishedTokens<V> = std::collections::HashMap<crate::cluster::wire::TokenId, V>;

/// After its variables changed, a writer (the coordinator, an agent) publishes them again, as of the same update,
/// after these doubling delays: an update lost on the way (a link that broke and came back within a lease) would
/// leave a reader waiting for ever for a value. Readers take a value they have already as a duplicate.
const VARS_RESEND_FIRST_MS: u64 = 200;
const VARS_RESEND_MAX_MS: u64 = 3_200;

/// When a writer's last variable update is published again (`VARS_RESEND_FIRST_MS`, doubling up to
/// `VARS_RESEND_MAX_MS`); a new update starts the series over.
#[derive(Default, serde::Serialize, serde::Deserialize)]
pub(crate) struct VarsResend {
    at_ms: Option<u64>,
    backoff_ms: u64,
}

impl VarsResend {
    /// A new update went out at `now_ms`.
    pub(crate) fn start(&mut self, now_ms: u64) {
        self.backoff_ms = VARS_RESEND_FIRST_MS;
        self.at_ms = Some(now_ms + VARS_RESEND_FIRST_MS);
    }

    /// Whether the update is due again at `now_ms`; if it is, the next time is planned (none past the largest
    /// delay).
    pub(crate) fn due(&mut self, now_ms: u64) -> bool {
        if self.at_ms.is_none_or(|t| t > now_ms) {
            return false;
        }
        self.backoff_ms *= 2;
        self.at_ms = (self.backoff_ms <= VARS_RESEND_MAX_MS).then_some(now_ms + self.backoff_ms);
        true
    }

    pub(crate) fn at_ms(&self) -> Option<u64> {
        self.at_ms
    }
}

/// The writer name the coordinator publishes its variables under.
pub const COORDINATOR: &str = "coordinator";

/// Which write of each variable was applied last — by which writer, which process of it (incarnation), and
/// which of its numbered updates — so that a duplicated or late value never overwrites a newer one, and a
/// restarted writer, whose numbers start again, is heard at once. One entry per variable: what a peer sends
/// cannot grow it.
#[derive(serde::Serialize, serde::Deserialize)]
pub(crate) struct VarWrites {
    last: Vec<Option<VarWrite>>,
    /// Processes replaced by a newer one of the same name: whatever they still send is late.
    retired: VecDeque<(String, Uuid)>,
}

#[derive(Clone, PartialEq, serde::Serialize, serde::Deserialize)]
struct VarWrite {
    writer: String,
    incarnation: Uuid,
    seq: u64,
}

impl VarWrites {
    pub(crate) fn new(vars: usize) -> VarWrites {
        VarWrites { last: vec![None; vars], retired: VecDeque::new() }
    }

    /// Whether it was made for a program of `vars` variables (a restored snapshot).
    pub(crate) fn fits(&self, vars: usize) -> bool {
        self.last.len() == vars
    }

    /// Whether a value of variable `var` in update `seq` of `writer`'s process `incarnation` is newer than the
    /// one applied; if it is, it becomes the one applied. A write of another process of the same writer
    /// retires the older process. A `relay` (a value another process wrote, passed on) never replaces a
    /// value its writer sent directly.
    pub(crate) fn accept(&mut self, var: usize, writer: &str, incarnation: Uuid, seq: u64, relay: bool) -> bool {
        if self.is_retired(writer, incarnation) {
            return false;
        }
        let Some(slot) = self.last.get(var) else { return false };
        if let Some(last) = slot {
            if last.writer == writer && last.incarnation == incarnation && seq <= last.seq {
                return false;
            }
            if relay && last.writer != writer {
                return false;
            }
            if last.writer == writer && last.incarnation != incarnation {
                let old = (last.writer.clone(), last.incarnation);
                self.retire(old.0, old.1);
            }
        }
        self.last[var] = Some(VarWrite { writer: writer.to_string(), incarnation, seq });
        true
    }

    /// Whether `accept` would take this write, without taking it.
    pub(crate) fn would_accept(&self, var: usize, writer: &str, incarnation: Uuid, seq: u64) -> bool {
        if self.is_retired(writer, incarnation) {
            return false;
        }
        match self.last.get(var) {
            None => false,
            Some(Some(last)) => !(last.writer == writer && last.incarnation == incarnation && seq <= last.seq),
            Some(None) => true,
        }
    }

    /// Whether `writer`'s process `incarnation` was replaced by a newer one.
    pub(crate) fn is_retired(&self, writer: &str, incarnation: Uuid) -> bool {
        self.retired.iter().any(|(w, i)| w == writer && *i == incarnation)
    }

    /// `writer`'s process `incarnation` was replaced: its late values are refused.
    pub(crate) fn retire(&mut self, writer: String, incarnation: Uuid) {
        if self.is_retired(&writer, incarnation) {
            return;
        }
        if self.retired.len() >= RETIRED_INCARNATIONS_MAX {
            self.retired.pop_front();
        }
        self.retired.push_back((writer, incarnation));
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, serde::Serialize, serde::Deserialize)]
pub enum Level {
    Info,
    Warn,
    Error,
}
