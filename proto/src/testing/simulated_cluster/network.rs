//! The simulated network between the coordinator and its agents: what each process sends goes out as packets, each
//! meeting the faults of its link (lost, duplicated, delayed, reordered), and what arrives is given to its process
//! — the coordinator's records made durable first, as the host does.

use std::sync::Arc;

use uuid::Uuid;

use crate::cluster::journal::Journaled;
use crate::cluster::runtime::agent::AgentOutput;
use crate::cluster::runtime::coordinator::CoordOutput;
use crate::cluster::wire::{self, ToAgent, VarUpdate};
use crate::testing::simulated_cluster::skills::{motion, SimSkill, SkillStart};

use super::{Faults, Packet, SimCluster};

impl SimCluster {
    /// The faults a packet meets now: its agent's link's, while they last, else the run's.
    pub(super) fn faults_for(&self, packet: &Packet) -> Faults {
        let agent = match packet {
            Packet::ToAgent(i, _, _) | Packet::Report(i, _) | Packet::Vars(Some(i), _) => Some(*i),
            Packet::Vars(None, _) => None,
        };
        let now = self.now_ms;
        agent
            .and_then(|i| self.links.iter().find(|l| l.agent == i && l.from_ms <= now && now < l.until_ms))
            .map_or(self.faults, |l| l.faults)
    }

    pub(super) fn send(&mut self, packet: Packet) {
        self.messages += 1;
        if let Some(captured) = self.captured.as_mut() {
            captured.push(match &packet {
                Packet::ToAgent(_, _, b) => (0, b.clone()),
                Packet::Report(_, b) => (1, b.clone()),
                Packet::Vars(_, b) => (2, b.clone()),
            });
        }
        if self.calm_from_ms.is_some_and(|t| self.now_ms >= t) {
            self.faults = Faults::default();
        }
        let faults = self.faults_for(&packet);
        if self.chance(faults.loss) {
            return;
        }
        let delay = if faults.delay_ms_max > 0 { self.random() % (faults.delay_ms_max + 1) } else { 0 };
        let copy = match &packet {
            Packet::ToAgent(i, inc, b) => Packet::ToAgent(*i, *inc, b.clone()),
            Packet::Report(i, b) => Packet::Report(*i, b.clone()),
            Packet::Vars(i, b) => Packet::Vars(*i, b.clone()),
        };
        self.net.push((self.now_ms + delay, packet));
        if self.chance(faults.duplicate) {
            let later = self.now_ms + delay + self.random() % 5;
            self.net.push((later, copy));
        }
    }

    pub(super) fn deliver(&mut self) {
        loop {
            let ready: Vec<usize> = (0..self.net.len()).filter(|&i| self.net[i].0 <= self.now_ms).collect();
            if ready.is_empty() {
                return;
            }
            let pick =
                if self.faults.reorder { ready[(self.random() % ready.len() as u64) as usize] } else { ready[0] };
            let (_, packet) = self.net.remove(pick);
            match packet {
                Packet::ToAgent(i, _, _) if !self.agents[i].reachable => {}
                // A command for a process that is gone reaches nobody.
                Packet::ToAgent(i, incarnation, _) if incarnation != Uuid::from_u128(self.agents[i].restarts) => {}
                Packet::ToAgent(i, _, bytes) => {
                    let (term, msg) = wire::decode_termed::<ToAgent>(&bytes).expect("coordinator sends valid messages");
                    // Only a dispatch starts a segment: what the agent held before it, to see what it started.
                    let before = matches!(msg, ToAgent::Dispatch { .. }).then(|| self.agents[i].run.held());
                    // Of a run the agent no longer runs (one before a `reset`): it forgot that run. The chart is
                    // the one every agent was given, so no dispatch is of another version.
                    match self.agents[i].run.handle_message(self.now_ms, term, msg) {
                        Ok(()) => self.note_term(i, term, true),
                        Err(crate::cluster::runtime::agent::NotTaken::StaleTerm) => {
                            self.note_term(i, term, false);
                            continue;
                        }
                        Err(_) => continue,
                    }
                    if let Some(before) = before {
                        // A segment started here: never twice in one epoch, on any agent.
                        for h in self.agents[i].run.held() {
                            if !before.contains(&h) && !self.started.insert((h.token, h.epoch)) {
                                let (now, name) = (self.now_ms, self.agents[i].name.clone());
                                self.violations.push(format!(
                                    "at {now} ms token {} started a second time in epoch {} (on `{name}`)",
                                    h.token, h.epoch
                                ));
                            }
                        }
                    }
                }
                // A coordinator that is down hears nothing.
                Packet::Report(..) | Packet::Vars(..) if self.down_until.is_some() => {}
                Packet::Report(i, bytes) => {
                    let sender = self.agents[i].name.clone();
                    self.coordinator.report(self.now_ms, &sender, &bytes).expect("agents send valid reports");
                }
                Packet::Vars(_, bytes) => {
                    let (term, update): (u64, VarUpdate) = wire::decode_termed(&bytes).expect("valid update");
                    self.coordinator.vars(self.now_ms, &update.from, &bytes).expect("valid update");
                    let now = self.now_ms;
                    let from_coordinator = update.from == crate::cluster::runtime::COORDINATOR;
                    for i in 0..self.agents.len() {
                        if !self.agents[i].reachable {
                            continue;
                        }
                        let (_, refused_before) = self.agents[i].run.term();
                        self.agents[i].run.handle_vars(now, term, &update);
                        let (_, refused_after) = self.agents[i].run.term();
                        if from_coordinator && self.agents[i].run.run() == update.run {
                            self.note_term(i, term, refused_after == refused_before);
                        }
                    }
                }
            }
            self.flush_coordinator();
        }
    }

    /// Makes the coordinator's records durable, then carries out what it asked for — unless it dies in between.
    pub(super) fn flush_coordinator(&mut self) {
        let mut records = self.coordinator.take_records();
        if self.held_by_store(&mut records) {
            return;
        }
        self.journal.extend(records);
        if self.pause_if_due() {
            return;
        }
        let due = self.crashes_after_journal.first().is_some_and(|c| c.0 <= self.now_ms);
        if due && self.down_until.is_none() && self.coordinator.has_output() {
            let (_, down_ms) = self.crashes_after_journal.remove(0);
            while self.coordinator.poll_output().is_some() {}
            self.outputs_lost = true;
            self.down_until = Some(self.now_ms + down_ms);
            return;
        }
        let term = self.term();
        while let Some(out) = self.coordinator.poll_output() {
            self.emit(out, term);
        }
        let since = self.snapshots.last().map_or(0, |(at, _)| *at);
        if self.down_until.is_none() && self.journal.len() >= since.saturating_add(self.snapshot_every) {
            if let Some(bytes) = self.coordinator.snapshot(serde_json::Value::Null) {
                // A quiet cycle it recorded first goes before it.
                let records = self.coordinator.take_records();
                self.journal.extend(records);
                // The run goes on with the coordinator the snapshot restores: whatever it failed to keep would
                // show in what the run does. And it must be the same to the byte.
                let (program, layout) = (Arc::clone(&self.program), Arc::clone(&self.layout));
                let (mut restored, _) = Journaled::restore(program, layout, &bytes).expect("a snapshot restores");
                restored.watch(self.watched.clone());
                let again = restored.snapshot(serde_json::Value::Null).expect("nothing pending");
                assert!(again == bytes, "seed {}: a restored coordinator's snapshot differs", self.seed);
                self.coordinator = restored;
                self.snapshots.push((self.journal.len(), bytes));
            }
        }
    }

    /// Carries out what the coordinator asked for, at `term`: a message onto the network, a question to an agent, a
    /// trace record into the trace.
    pub(super) fn emit(&mut self, out: CoordOutput, term: u64) {
        match out {
            out @ (CoordOutput::Send { .. } | CoordOutput::Vars(_)) => {
                let packet = self.packet(out, term).expect("a command or a value is a message");
                self.send(packet);
            }
            CoordOutput::Ask { agent, incarnation } => {
                // The question and its answer cross the network as the reports would: the answer's reports
                // arrive as reports (with the faults of the agent's link).
                let i = self.agents.iter().position(|a| a.name == agent).expect("known agent");
                let a = &self.agents[i];
                if a.alive && a.reachable && incarnation == Uuid::from_u128(a.restarts) {
                    for r in a.run.pending_reports(crate::limits::PENDING_LISTED_MAX) {
                        self.send(Packet::Report(i, wire::encode(&r)));
                    }
                }
            }
            CoordOutput::Trace(rec) => self.trace.push(rec),
            CoordOutput::Log { .. } => {}
        }
    }

    pub(super) fn flush_agent(&mut self, i: usize) {
        while let Some(out) = self.agents[i].run.poll_output() {
            // Cut off, what it says is lost (its unacknowledged reports are resent once it is back); its skills
            // are its own business and go on.
            let reachable = self.agents[i].reachable;
            match out {
                AgentOutput::Report(r) if reachable => self.send(Packet::Report(i, wire::encode(&r))),
                AgentOutput::Vars(u) if reachable => self.send(Packet::Vars(Some(i), wire::encode(&u))),
                AgentOutput::Report(_) | AgentOutput::Vars(_) => {}
                AgentOutput::StartSkill { action, name, binding } => {
                    // A held branch starts nothing: not its entry's skills, not a timed qualifier's.
                    if self.agents[i].run.started_while_held() > self.agents[i].held_starts {
                        self.agents[i].held_starts = self.agents[i].run.started_while_held();
                        let (now, agent) = (self.now_ms, self.agents[i].name.clone());
                        self.violations
                            .push(format!("by {now} ms `{agent}` started `{name}` while its branch was held"));
                    }
                    let random = self.random();
                    let skill = match self.skill_model.as_mut() {
                        Some(model) => {
                            model(SkillStart { agent: &self.agents[i].name, action: &name, binding: &binding, random })
                        }
                        None => motion(&binding, random),
                    };
                    let entry = match skill {
                        SimSkill::Finish { after_ms, result, writes } => Some((self.now_ms + after_ms, result, writes)),
                        SimSkill::Hang => None,
                    };
                    self.agents[i].skills.insert(action, entry);
                }
                AgentOutput::StopSkill { action } => {
                    self.agents[i].skills.remove(&action);
                }
                // The simulated cells have no devices.
                AgentOutput::Log { .. }
                | AgentOutput::Trace(_)
                | AgentOutput::Output { .. }
                | AgentOutput::Devices(_) => {}
            }
        }
    }
}
