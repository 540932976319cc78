//! A run that stays at its end (`baton run --stay`): Complete, Stopped and Aborted wait for PackML's `clear` and
//! `reset` instead of ending the process, and `reset` starts the chart again from its initial steps as a new run
//! (a new run id, so that no agent mistakes it for the one that ended) in the same journal. And agents that could
//! not be told of an abort: each is told when it is heard from again.

use std::sync::Arc;

use crate::cluster::runtime::packml::State;
use crate::cluster::runtime::Level;
use crate::cluster::wire::{RunId, ToAgent};
use crate::exec::trace::{TraceEvent, TraceRecord};

use super::state::{AgentState, TokenIds};
use super::Coordinator;

impl Coordinator {
    /// The run stays at its end for `clear` and `reset` (a journal record, so that a replay stays too).
    pub fn handle_stay(&mut self) {
        self.stays = true;
    }

    /// Whether the run stays at its end (`handle_stay`).
    pub fn stays(&self) -> bool {
        self.stays
    }

    /// A `reset` was taken: the host makes the new run (`new_run`) and journals it.
    pub fn wants_new_run(&self) -> bool {
        self.stays && self.run_state == State::Resetting
    }

    /// The commands legal now: the table's, but for `clear` and `reset` in a run that does not stay at its end.
    pub fn available(&self) -> Vec<crate::cluster::runtime::packml::Command> {
        use crate::cluster::runtime::packml::Command;
        let mut legal = self.run_state.available();
        if !self.stays {
            legal.retain(|c| !matches!(c, Command::Reset | Command::Clear));
        }
        legal
    }

    /// Whether the chart runs now: not before `start`, not once the run ended (a run that stays has its chart's
    /// last situation, or nothing, until `reset`).
    pub(super) fn chart_runs(&self) -> bool {
        !matches!(
            self.run_state,
            State::Idle | State::Complete | State::Stopped | State::Aborted | State::Clearing | State::Resetting
        )
    }

    /// A run that stays completes by itself once its chart reached a terminal situation (one that does not stay
    /// completes at its `End` record, the last thing `baton run` writes).
    pub(super) fn complete_if_done(&mut self) {
        if self.stays && self.run_state == State::Execute && self.failure.is_none() && self.is_terminal() {
            self.change_state(State::Completing);
            if let Some(done) = State::Completing.when_done() {
                self.change_state(done);
            }
        }
    }

    /// The run that follows a `reset`: the same chart from its initial steps, run `run`, waiting in Idle for
    /// `start`. What belongs to the cell rather than to the run goes on: the agents known and their processes, the
    /// loss policy, the cycle period, the mode, and the alarms still standing (an alarm stays until acknowledged).
    /// What the ended run asked for and nobody took yet comes first in the new run's outputs.
    pub fn new_run(&mut self, now_ms: u64, run: RunId, new_token: TokenIds) -> Coordinator {
        let mut next =
            Coordinator::new(Arc::clone(&self.program), Arc::clone(&self.layout), run, self.hash.clone(), new_token);
        next.outbox = std::mem::take(&mut self.outbox);
        next.now_ms = self.now_ms.max(now_ms);
        next.cycle_ms = self.cycle_ms;
        next.policy = self.policy;
        next.stays = true;
        next.started_ms = next.now_ms;
        next.stats = self.stats;
        next.alarms = std::mem::take(&mut self.alarms);
        next.device_alarms = std::mem::take(&mut self.device_alarms);
        next.skill_alarms = std::mem::take(&mut self.skill_alarms);
        next.untold = std::mem::take(&mut self.untold);
        next.engine.set_mode(self.engine.mode());
        next.engine.begin_at(next.now_ms);
        for (name, a) in &self.agents {
            let mut fresh = AgentState::new(a.incarnation, a.lease_ms);
            fresh.roles = a.roles.clone();
            fresh.alive = a.alive;
            fresh.conflict = a.conflict;
            fresh.devices_down = a.devices_down.clone();
            fresh.devices_seq = a.devices_seq;
            fresh.skills = a.skills.clone();
            next.agents.insert(name.clone(), fresh);
        }
        next.run_state = State::Resetting;
        let mut rec = TraceRecord::new(next.now_ms, TraceEvent::NewRun, &self.program.name);
        rec.message = Some(run.key());
        next.trace(rec);
        next.change_state(State::Idle);
        // The initial situation, as a run that waits for `start` shows it.
        next.drain_engine();
        let chart = &self.program.name;
        next.log(Level::Info, format!("reset: run {} starts chart `{chart}` again from its initial steps", run.key()));
        next.refresh_peers();
        // Agents that bind variables take part from the start, as when they join.
        let binders: Vec<String> = next
            .agents
            .iter()
            .filter(|(n, a)| a.alive && next.layout.io.iter().any(|b| &b.agent == *n))
            .map(|(n, _)| n.clone())
            .collect();
        for name in binders {
            let msg = next.join_msg(&name);
            next.send(name, msg);
        }
        next
    }

    /// An agent that could not be told of the abort of a run (this one, or the one before a `reset`) was heard from:
    /// it is told now, and its alarm's cause is gone.
    pub(super) fn tell_of_end(&mut self, agent: &str) {
        let Some((run, alarms)) = self.untold.remove(agent) else { return };
        self.send(agent.to_string(), ToAgent::Abort { run });
        self.log(Level::Info, format!("agent `{agent}` is back and told that run {} was aborted", run.key()));
        let mut rec = TraceRecord::new(self.now_ms, TraceEvent::Told, agent);
        rec.agent = Some(agent.to_string());
        rec.message = Some(format!("run {} was aborted", run.key()));
        self.trace(rec);
        for id in alarms {
            let changes = self.alarms.cause_gone(id);
            self.alarm_changes(changes);
        }
    }

    /// Agents that were holding tokens of the run when it ended and could not be told: they still may run their
    /// segments, until they hear of it.
    pub fn untold_agents(&self) -> impl Iterator<Item = &str> {
        self.untold.keys().map(String::as_str)
    }
}
