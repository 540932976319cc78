//! The pure halves of a distributed run: the coordinator's and the agent's state machines. The Zenoh shells in
//! `baton-coordinator` and `baton-agent` feed them decoded messages and the time, and carry out what they
//! output; a simulation can drive them just as well, in one thread.

pub mod agent;
pub mod coordinator;

use std::collections::VecDeque;

use uuid::Uuid;

use crate::limits::RETIRED_INCARNATIONS_MAX;

/// After its variables changed, a writer (the coordinator, an agent) publishes them again, as of the same update,
/// after these doubling delays: an update lost on the way (a link that broke and came back within a lease) would
/// leave a reader waiting for ever for a value. Readers take a value they have already as a duplicate.
const VARS_RESEND_FIRST_MS: u64 = 200;
const VARS_RESEND_MAX_MS: u64 = 3_200;

/// When a writer's last variable update is published again (`VARS_RESEND_FIRST_MS`, doubling up to
/// `VARS_RESEND_MAX_MS`); a new update starts the series over.
#[derive(Default)]
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
pub(crate) struct VarWrites {
    last: Vec<Option<VarWrite>>,
    /// Processes replaced by a newer one of the same name: whatever they still send is late.
    retired: VecDeque<(String, Uuid)>,
}

#[derive(Clone, PartialEq)]
struct VarWrite {
    writer: String,
    incarnation: Uuid,
    seq: u64,
}

impl VarWrites {
    pub(crate) fn new(vars: usize) -> VarWrites {
        VarWrites { last: vec![None; vars], retired: VecDeque::new() }
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

#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Level {
    Info,
    Warn,
    Error,
}
