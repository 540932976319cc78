//! Standby coordinators in the simulation: the run's election (`SimCluster::stand_by`), its terms, and the pause
//! that fools every lease. The active coordinator's term is on every command and coordinator value it sends
//! (`wire::encode_termed`); each takeover — after a crash, or after a pause outlasted the lease — is a new election,
//! won at a higher term, by a process that resumes from the durable journal. A paused coordinator keeps what it
//! was about to send (its records were durable, so the journal has them) and sends it when it wakes, at its old
//! term, not knowing it was replaced: each agent that heard the new term must refuse it. Watched: no agent process
//! ever takes a message of a lower term after one of a higher term (`violations`), and the refusals are counted.

use std::collections::BTreeMap;

use crate::cluster::runtime::coordinator::CoordOutput;
use crate::cluster::wire;

use super::{Election, ElectionStats, Packet, SimCluster};

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
        });
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

    /// When the next pause or wake-up is due.
    pub(super) fn election_due_ms(&self) -> Option<u64> {
        let e = self.election.as_ref()?;
        [e.pauses.first().map(|p| p.0), e.zombies.first().map(|z| z.0)].into_iter().flatten().min()
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
