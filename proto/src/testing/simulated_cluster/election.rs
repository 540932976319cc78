//! Standby coordinators in the simulation: the run's election (`SimCluster::stand_by`), its terms, and the pause
//! that fools every lease. The active coordinator's term is on every command and coordinator value it sends
//! (`wire::encode_termed`); each takeover — after a crash, or after a pause outlasted the lease — is a new election,
//! won at a higher term, by a process that resumes from the durable journal. A paused coordinator keeps what it
//! was about to send (its records were durable, so the journal has them) and sends it when it wakes, at its old
//! term, not knowing it was replaced: each agent that heard the new term must refuse it. Watched: no agent process
//! ever takes a message of a lower term after one of a higher term (`violations`), and the refusals are counted.
//!
//! The active coordinator can also be cut from the store (`cut_coordinator_from_store_at`: etcd unreachable, or
//! without a quorum): its writes wait, and with them everything they led to (write-ahead). A cut that heals before
//! the coordinator's own deadline — two thirds into its lease — lets the writes through at its term, and the run goes
//! on. One that outlasts it: the coordinator stops acting, what waited is never durable and never sent, and a
//! standby takes over from the store when the lease ends — the last third of the lease with nobody acting.

use std::collections::BTreeMap;

use crate::cluster::runtime::coordinator::CoordOutput;
use crate::cluster::wire;

use super::{Cut, Election, ElectionStats, Packet, SimCluster};

impl SimCluster {
    /// Coordinators stand by for this run: the first wins the election at term 1, and each takeover (a crash, or a
    /// pause past `lease_ms`) is won by a standby at the next term, `lease_ms` after the active one stopped.
    pub fn stand_by(&mut self, lease_ms: u64) {
        self.election = Some(Election {
            lease_ms,
            term: 1,
            pauses: Vec::new(),
            zombies: Vec::new(),
            taken: BTreeMap::new(),
            refused: 0,
            takeovers: 0,
            late_messages: 0,
            cuts: Vec::new(),
            cut: None,
            cuts_healed: 0,
            cuts_outlasted: 0,
        });
    }

    /// The active coordinator is cut from the store at the first moment from `t_ms` on when it has something to
    /// write or send, for `cut_ms`. Needs `stand_by`.
    pub fn cut_coordinator_from_store_at(&mut self, t_ms: u64, cut_ms: u64) {
        let e = self.election.as_mut().expect("a cut from the store is of a coordinator that has standbys: stand_by");
        e.cuts.push((t_ms, cut_ms));
        e.cuts.sort_unstable();
    }

    /// Whether a cut from the store holds `records` and what the coordinator asked for — one under way, or one that
    /// begins now. (Not durable, nothing of it leaves.)
    pub(super) fn held_by_store(&mut self, records: &mut Vec<Vec<u8>>) -> bool {
        let now = self.now_ms;
        let has_output = self.coordinator.has_output();
        let Some(e) = self.election.as_mut() else { return false };
        if e.cut.is_none() {
            let due = e.cuts.first().is_some_and(|c| c.0 <= now);
            if !due || self.down_until.is_some() || (records.is_empty() && !has_output) {
                return false;
            }
            let (_, cut_ms) = e.cuts.remove(0);
            let deadline = now + e.lease_ms * 2 / 3;
            e.cut = Some(Cut { heals: now + cut_ms, deadline, records: Vec::new(), outputs: Vec::new() });
        }
        let cut = e.cut.as_mut().expect("one under way");
        cut.records.append(records);
        while let Some(out) = self.coordinator.poll_output() {
            cut.outputs.push(out);
        }
        true
    }

    /// Whether a cut from the store holds what the coordinator did: nothing of it is durable, nor done, yet.
    pub(super) fn cut_under_way(&self) -> bool {
        self.election.as_ref().is_some_and(|e| e.cut.is_some())
    }

    /// The cut under way heals (the writes go through, at the term the coordinator still holds, and what they led
    /// to leaves), or the coordinator's deadline comes first (it stops acting; a standby wins when the lease ends).
    pub(super) fn store_due(&mut self) {
        let now = self.now_ms;
        let Some(e) = self.election.as_mut() else { return };
        let Some(cut) = e.cut.as_ref() else { return };
        if cut.heals <= now && cut.heals < cut.deadline {
            let cut = e.cut.take().expect("checked");
            e.cuts_healed += 1;
            self.journal.extend(cut.records);
            let term = self.term();
            for out in cut.outputs {
                self.emit(out, term);
            }
            // What the coordinator took meanwhile, and anything since, goes the usual way.
            self.flush_coordinator();
        } else if cut.deadline <= now {
            // Stopped acting: what waited for the store was never acknowledged, and dies with the coordinator's
            // acting; the standby resumes from the store.
            e.cut = None;
            e.cuts_outlasted += 1;
            let rest = e.lease_ms - e.lease_ms * 2 / 3;
            self.coordinator.take_records();
            while self.coordinator.poll_output().is_some() {}
            self.down_until = Some(now + rest);
        }
    }

    /// The active coordinator pauses (a GC pause, a frozen VM) at the first moment from `t_ms` on when it has
    /// something to send — its records durable, its messages not sent — for `pause_ms`. Past its lease a standby
    /// takes over; the paused one wakes and sends what it held, at its old term. Needs `stand_by`.
    pub fn pause_coordinator_at(&mut self, t_ms: u64, pause_ms: u64) {
        let e = self.election.as_mut().expect("a pause is of a coordinator that has standbys: stand_by first");
        assert!(pause_ms > e.lease_ms, "a pause shorter than the lease is not a failover");
        e.pauses.push((t_ms, pause_ms));
        e.pauses.sort_unstable();
    }

    /// What the election did so far (`None` without standbys).
    pub fn election(&self) -> Option<ElectionStats> {
        self.election.as_ref().map(|e| ElectionStats {
            term: e.term,
            takeovers: e.takeovers,
            late_messages: e.late_messages,
            refused: e.refused,
            cuts_healed: e.cuts_healed,
            cuts_outlasted: e.cuts_outlasted,
        })
    }

    /// The active coordinator's term: 0 without an election.
    pub(super) fn term(&self) -> u64 {
        self.election.as_ref().map_or(0, |e| e.term)
    }

    /// A standby takes over: a new election, won at the next term.
    pub(super) fn new_term(&mut self) {
        if let Some(e) = self.election.as_mut() {
            e.term += 1;
            e.takeovers += 1;
        }
    }

    /// Pauses the active coordinator if a pause is due and it has something to send: its messages are kept for
    /// when it wakes, its standby takes over when its lease runs out. Whether it paused.
    pub(super) fn pause_if_due(&mut self) -> bool {
        let now = self.now_ms;
        let Some(e) = self.election.as_ref() else { return false };
        let due = e.pauses.first().is_some_and(|p| p.0 <= now);
        if !due || self.down_until.is_some() || !self.coordinator.has_output() {
            return false;
        }
        let term = e.term;
        let mut held = Vec::new();
        while let Some(out) = self.coordinator.poll_output() {
            held.extend(self.packet(out, term));
        }
        let e = self.election.as_mut().expect("checked");
        let (_, pause_ms) = e.pauses.remove(0);
        e.zombies.push((now + pause_ms, held));
        e.zombies.sort_by_key(|z| z.0);
        let lease_ms = e.lease_ms;
        self.outputs_lost = true;
        self.down_until = Some(now + lease_ms);
        true
    }

    /// The message a coordinator's output puts on the network, at `term`: commands and values only (its trace and
    /// log stay in its process).
    pub(super) fn packet(&self, out: CoordOutput, term: u64) -> Option<Packet> {
        match out {
            CoordOutput::Send { agent, incarnation, msg } => {
                let i = self.agents.iter().position(|a| a.name == agent).expect("known agent");
                Some(Packet::ToAgent(i, incarnation, wire::encode_termed(&msg, term)))
            }
            CoordOutput::Vars(update) => Some(Packet::Vars(None, wire::encode_termed(&update, term))),
            _ => None,
        }
    }

    /// Paused coordinators that wake now send what they held; the next write to the journal would tell them they
    /// were replaced (its condition on their term fails), so they send nothing more.
    pub(super) fn wake_zombies(&mut self) {
        let now = self.now_ms;
        loop {
            let Some(e) = self.election.as_mut() else { return };
            if e.zombies.first().is_none_or(|z| z.0 > now) {
                return;
            }
            let (_, held) = e.zombies.remove(0);
            e.late_messages += held.len() as u64;
            for packet in held {
                self.send(packet);
            }
        }
    }

    /// When the next pause, wake-up, cut, heal or deadline is due.
    pub(super) fn election_due_ms(&self) -> Option<u64> {
        let e = self.election.as_ref()?;
        let cut = e.cut.as_ref().map(|c| c.heals.min(c.deadline));
        [e.pauses.first().map(|p| p.0), e.zombies.first().map(|z| z.0), e.cuts.first().map(|c| c.0), cut]
            .into_iter()
            .flatten()
            .min()
    }

    /// Agent `i`'s process took (`taken`) or refused a message of `term`: a taken one of a lower term than one it
    /// took before is a violation — two coordinators' commands both accepted.
    pub(super) fn note_term(&mut self, i: usize, term: u64, taken: bool) {
        let process = (i, self.agents[i].restarts);
        let now = self.now_ms;
        let name = self.agents[i].name.clone();
        let Some(e) = self.election.as_mut() else { return };
        if !taken {
            e.refused += 1;
            return;
        }
        let highest = e.taken.entry(process).or_insert(term);
        if term < *highest {
            let was = *highest;
            self.violations.push(format!(
                "at {now} ms `{name}` took a message of coordinator term {term} after one of term {was}"
            ));
        } else {
            *highest = term;
        }
    }
}
