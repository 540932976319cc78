//! The run's mode across machines: `auto` (conditions clear transitions), `step` (a TRUE transition waits for
//! `confirm`) and `manual` (transitions clear only by `force`, steps switched by `activate` and `deactivate`).
//!
//! The coordinator's engine takes the mode at once; each token out on an agent is told (`ToAgent::Gate`, numbered
//! per token, sent again until the agent says `Gated`), and so is every token dispatched later (the mode rides on
//! the dispatch). A confirmation or a force of a transition an agent judges goes to that token's agent the same way.
//! A manual change of the active steps is made only if the chart could reach the situation it leaves by itself
//! (`analysis::is_reachable`): never two tokens on a step, half a simultaneous branch, or a token stranded.

use std::sync::Arc;

use crate::cluster::runtime::packml::State;
use crate::cluster::wire::{ToAgent, TokenId};
use crate::exec::analysis;
use crate::exec::engine::{Mode, RemoteInput};
use crate::exec::program::{StepId, TransitionId};
use crate::exec::trace::{TraceEvent, TraceRecord};

use super::Coordinator;

const GATE_RESEND_FIRST_MS: u64 = 200;
const GATE_RESEND_MAX_MS: u64 = 2_000;

impl Coordinator {
    /// The run's mode.
    pub fn mode(&self) -> Mode {
        self.engine.mode()
    }

    /// `mode auto|step|manual`: legal while the run executes, is held or suspended.
    pub(super) fn mode_command(&mut self, target: Option<&str>) -> Result<String, String> {
        let names: Vec<&str> = Mode::ALL.iter().map(|m| m.name()).collect();
        let mode = target.and_then(Mode::from_name).ok_or_else(|| format!("mode takes one of {}", names.join(", ")))?;
        if !matches!(self.run_state, State::Execute | State::Held | State::Suspended | State::Idle) {
            return Err(format!(
                "the mode changes only while the run executes, is held or suspended; it is {}",
                self.run_state.name()
            ));
        }
        if mode == self.engine.mode() {
            return Err(format!("the run is in {} mode already", mode.name()));
        }
        self.engine.set_mode(mode);
        let rec = TraceRecord::new(self.now_ms, TraceEvent::Mode, mode.name());
        self.trace(rec);
        let ids: Vec<TokenId> = self.tokens.keys().copied().collect();
        for id in ids {
            self.send_gate(id, None);
        }
        Ok(format!("the run is in {} mode", mode.name()))
    }

    /// `confirm [TRANSITION]` (step mode): lets a waiting transition clear. Without a name, the one waiting.
    pub(super) fn confirm_command(&mut self, target: Option<&str>) -> Result<String, String> {
        if self.engine.mode() != Mode::Step {
            return Err(format!("confirm is for step mode; the run is in {} mode", self.engine.mode().name()));
        }
        let waiting: Vec<TransitionId> = self.waiting_transitions();
        let names = |ts: &[TransitionId]| {
            let n: Vec<&str> = ts.iter().map(|t| self.program.transitions[t.index()].name.as_str()).collect();
            if n.is_empty() {
                "none".to_string()
            } else {
                n.join(", ")
            }
        };
        let t = match target {
            Some(name) => self.transition_named(name)?,
            None if waiting.len() == 1 => waiting[0],
            None => return Err(format!("say which transition to confirm; waiting: {}", names(&waiting))),
        };
        if !waiting.contains(&t) {
            return Err(format!(
                "`{}` does not wait for a confirmation (its condition is FALSE or its step is not active); waiting: {}",
                self.program.transitions[t.index()].name,
                names(&waiting)
            ));
        }
        self.permit(t);
        Ok(format!("`{}` confirmed", self.program.transitions[t.index()].name))
    }

    /// `force TRANSITION` (manual mode): clears it whatever its condition, once its sources are active.
    pub(super) fn force_command(&mut self, target: Option<&str>) -> Result<String, String> {
        if self.engine.mode() != Mode::Manual {
            return Err(format!("force is for manual mode; the run is in {} mode", self.engine.mode().name()));
        }
        let t = self.transition_named(target.unwrap_or(""))?;
        let inactive: Vec<&str> = self
            .program
            .sources(t)
            .iter()
            .filter(|s| !self.engine.is_active(**s))
            .map(|s| self.program.steps[s.index()].name.as_str())
            .collect();
        if !inactive.is_empty() {
            return Err(format!(
                "`{}` cannot clear: its step(s) {} are not active",
                self.program.transitions[t.index()].name,
                inactive.join(", ")
            ));
        }
        self.permit(t);
        Ok(format!("`{}` forced", self.program.transitions[t.index()].name))
    }

    /// `activate STEP` / `deactivate STEP` (manual mode): only to a situation the chart could reach by itself.
    pub(super) fn switch_command(&mut self, activate: bool, target: Option<&str>) -> Result<String, String> {
        let s = self.manual_step(target)?;
        let (off, on) = if activate { (None, Some(s)) } else { (Some(s), None) };
        self.switch(off, on)
    }

    /// `move FROM TO`: the token of step FROM goes to step TO at once — one change, checked as one (a token moved
    /// along its branch passes through no situation without it).
    pub(super) fn move_command(&mut self, from: Option<&str>, to: Option<&str>) -> Result<String, String> {
        if to.is_none() {
            return Err("move names two steps: `move FROM TO`".to_string());
        }
        let (from, to) = (self.manual_step(from)?, self.manual_step(to)?);
        if from == to {
            return Err("a token moved to its own step stays where it is".to_string());
        }
        self.switch(Some(from), Some(to))
    }

    /// The step an operator names in manual mode.
    fn manual_step(&self, name: Option<&str>) -> Result<StepId, String> {
        if self.engine.mode() != Mode::Manual {
            return Err(format!("steps are switched in manual mode; the run is in {} mode", self.engine.mode().name()));
        }
        let name = name.unwrap_or("");
        self.program.step_by_name(name).ok_or_else(|| format!("chart `{}` has no step `{name}`", self.program.name))
    }

    /// Deactivates `off` and activates `on` (either may be absent) as one change, if the chart could reach the
    /// resulting situation by itself.
    fn switch(&mut self, off: Option<StepId>, on: Option<StepId>) -> Result<String, String> {
        let program = Arc::clone(&self.program);
        let name = |s: StepId| program.steps[s.index()].name.clone();
        if let Some(s) = on.filter(|&s| self.engine.is_active(s)) {
            return Err(format!("`{}` holds a token already: a second one is refused", name(s)));
        }
        if let Some(s) = off.filter(|&s| !self.engine.is_active(s)) {
            return Err(format!("`{}` is not active", name(s)));
        }
        let mut situation: Vec<StepId> = self.engine.active_steps().to_vec();
        situation.retain(|&x| Some(x) != off);
        situation.extend(on);
        let mut names: Vec<&str> = situation.iter().map(|s| self.program.steps[s.index()].name.as_str()).collect();
        names.sort_unstable();
        match analysis::is_reachable(&self.program, &situation) {
            Some(true) => {}
            Some(false) => {
                return Err(format!(
                    "the chart could never reach the steps {{{}}} by itself — that would leave half a \
                     simultaneous branch, strand a token, or start a branch twice",
                    names.join(", ")
                ))
            }
            None => return Err("the chart is too large to prove the change safe".to_string()),
        }
        if let Some(s) = off {
            if let Some(g) = self.layout.segment_of[s.index()] {
                let still = self.layout.segments[g.index()].steps.iter().any(|&x| x != s && self.engine.is_active(x));
                if still {
                    return Err(format!(
                        "`{}` runs on an agent with other steps of its branch: deactivate those first",
                        name(s)
                    ));
                }
                if let Some(id) = self.by_segment[g.index()] {
                    self.take_back(id, s);
                }
            }
            self.engine.handle_remote(self.now_ms, RemoteInput::Deactivate(s)).map_err(|e| e.to_string())?;
        }
        if let Some(s) = on {
            self.engine.handle_remote(self.now_ms, RemoteInput::Activate(s)).map_err(|e| e.to_string())?;
        }
        self.drain_engine();
        Ok(match (off, on) {
            (Some(a), Some(b)) => format!("the token of `{}` moved to `{}`", name(a), name(b)),
            (Some(a), None) => format!("`{}` deactivated", name(a)),
            (None, Some(b)) => format!("`{}` activated", name(b)),
            (None, None) => "nothing to switch".to_string(),
        })
    }

    /// A token taken back by an operator (its only active step, `step`, deactivated): its agent drops it, and it
    /// is gone (`withdraw`).
    fn take_back(&mut self, id: TokenId, step: StepId) {
        let Some(tok) = self.tokens.remove(&id) else { return };
        self.by_segment[tok.segment.index()] = None;
        self.waiting.retain(|w| *w != id);
        let mut rec = TraceRecord::new(self.now_ms, TraceEvent::Withdraw, &self.program.steps[step.index()].name);
        rec.agent = tok.agent.clone();
        rec.token = Some(id.to_string());
        rec.epoch = Some(tok.epoch);
        self.trace(rec);
        if let Some(agent) = tok.agent {
            if let Some(a) = self.agents.get_mut(&agent) {
                a.tokens = a.tokens.saturating_sub(1);
            }
            self.send(agent, ToAgent::Drop { run: self.run, token: id, epoch: tok.epoch });
        }
    }

    fn transition_named(&self, name: &str) -> Result<TransitionId, String> {
        self.program.transition_by_name(name).ok_or_else(|| {
            format!("chart `{}` has no transition `{name}` (`baton check --names` lists them)", self.program.name)
        })
    }

    /// The transitions waiting for a confirmation: the coordinator's own and those its agents said.
    pub fn waiting_transitions(&self) -> Vec<TransitionId> {
        let mut all: Vec<TransitionId> = self.engine.waiting().collect();
        all.extend(self.agent_waiting.iter().copied());
        all.sort_unstable();
        all.dedup();
        all
    }

    /// Lets `t` clear once: here, or on the agent of the token whose segment judges it.
    fn permit(&mut self, t: TransitionId) {
        match self.layout.agent_judges(&self.program, t).and_then(|g| self.by_segment[g.index()]) {
            Some(id) => self.send_gate(id, Some(t.0)),
            None => self.engine.permit(t),
        }
    }

    /// Tells a token's agent the mode (and a permit), numbered; sent again until it says `Gated`.
    pub(super) fn send_gate(&mut self, id: TokenId, permit: Option<u32>) {
        let mode = self.engine.mode();
        let now = self.now_ms;
        let Some(tok) = self.tokens.get_mut(&id) else { return };
        let gate = &mut tok.gate;
        gate.seq += 1;
        gate.permit = permit;
        gate.resend_at_ms = now + GATE_RESEND_FIRST_MS;
        gate.backoff_ms = GATE_RESEND_FIRST_MS;
        let (seq, epoch) = (gate.seq, tok.epoch);
        let Some(agent) = tok.agent.clone() else { return };
        self.send(agent, ToAgent::Gate { run: self.run, token: id, epoch, mode, permit, seq });
    }

    pub(super) fn gated(&mut self, id: TokenId, seq: u64) {
        if let Some(tok) = self.tokens.get_mut(&id) {
            tok.gate.confirmed = tok.gate.confirmed.max(seq);
        }
    }

    pub(super) fn resend_gates(&mut self) {
        let now = self.now_ms;
        let mode = self.engine.mode();
        let due: Vec<TokenId> = self
            .tokens
            .iter()
            .filter(|(_, t)| t.gate.confirmed < t.gate.seq && t.gate.resend_at_ms <= now && t.agent.is_some())
            .map(|(id, _)| *id)
            .collect();
        for id in due {
            let Some(tok) = self.tokens.get_mut(&id) else { continue };
            tok.gate.backoff_ms = (tok.gate.backoff_ms * 2).min(GATE_RESEND_MAX_MS);
            tok.gate.resend_at_ms = now + tok.gate.backoff_ms;
            let (epoch, permit, seq) = (tok.epoch, tok.gate.permit, tok.gate.seq);
            let Some(agent) = tok.agent.clone() else { continue };
            self.send(agent, ToAgent::Gate { run: self.run, token: id, epoch, mode, permit, seq });
        }
    }

    pub(super) fn next_gate_resend_ms(&self) -> Option<u64> {
        self.tokens
            .values()
            .filter(|t| t.gate.confirmed < t.gate.seq && t.agent.is_some())
            .map(|t| t.gate.resend_at_ms)
            .min()
    }
}
