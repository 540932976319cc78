//! Operators' commands as an agent carries them out: a token held (nothing of it clears or starts, its times stand
//! still, its running skills finish or, where the action says `{hold := 'cancel'}`, are cancelled) and confirmed
//! held once nothing of it runs; released; the run's mode and the transitions confirmed or forced in it; a step's
//! supervision fault acknowledged; and a run aborted (every skill cancelled, every action's final scan, every token
//! forgotten).

use std::collections::BTreeSet;
use std::sync::Arc;

use crate::cluster::layout::SegmentId;
use crate::cluster::runtime::Level;
use crate::cluster::wire::{AgentEventKind, RunId, TokenId};
use crate::exec::engine::RemoteInput;
use crate::exec::program::{ActionId, StepId};

use super::{AgentOutput, AgentRun};

impl AgentRun {
    /// `ToAgent::Hold`: holds the token (`held`) or releases it. A repeat changes nothing but says again what
    /// this agent already confirmed, in case the confirmation was lost with its report.
    pub fn handle_hold(&mut self, now_ms: u64, token: TokenId, epoch: u32, held: bool) {
        self.catch_up(now_ms);
        let Some(h) = self.tokens.get_mut(&token).filter(|h| h.epoch == epoch && !h.done) else {
            self.dropped += 1;
            return;
        };
        if h.held != held {
            h.held = held;
            h.held_said = None;
            let segment = h.segment;
            for s in self.layout.segments[segment.index()].steps.clone() {
                self.engine.set_held(self.now_ms, s, held);
            }
            if held {
                self.cancel_on_hold(token);
            } else {
                if let Some(entry) = self.tokens.get_mut(&token).and_then(|h| h.pending_entry.take()) {
                    if let Err(e) = self.engine.handle_remote(self.now_ms, RemoteInput::Activate(entry)) {
                        self.log(Level::Error, format!("token {token} released but its entry step refused: {e}"));
                    }
                }
                self.restart_cancelled(segment);
            }
        }
        self.confirm_holds();
        self.settle();
    }

    /// Cancels the running skills of `token` whose binding says `{hold := 'cancel'}`: their indicators say
    /// neither done nor failed, so the step runs the skill again when released.
    fn cancel_on_hold(&mut self, token: TokenId) {
        let Some(segment) = self.tokens.get(&token).map(|h| h.segment) else { return };
        let cancel: Vec<ActionId> = self
            .running_skills
            .iter()
            .copied()
            .filter(|a| self.action_segments[a.index()].contains(&segment))
            .filter(|a| {
                self.layout.skills[a.index()]
                    .as_ref()
                    .and_then(|b| b.params.get("hold"))
                    .is_some_and(|p| p.as_str().is_some_and(|t| t.eq_ignore_ascii_case("cancel")))
            })
            .collect();
        for a in cancel {
            self.running_skills.remove(&a);
            self.outbox.push_back(AgentOutput::StopSkill { action: a });
            self.say_cancelled(Level::Info, a, "its token is held");
            self.cancelled_on_hold.insert(a);
        }
    }

    /// The skills cancelled by a hold start again when their token is released, if their action is still on.
    fn restart_cancelled(&mut self, segment: SegmentId) {
        let again: Vec<ActionId> = self
            .cancelled_on_hold
            .iter()
            .copied()
            .filter(|a| self.action_segments[a.index()].contains(&segment))
            .collect();
        for a in again {
            self.cancelled_on_hold.remove(&a);
            let on = crate::exec::env::Env::action_q(&self.engine, a);
            if let (true, Some(binding)) = (on, self.layout.skills[a.index()].clone()) {
                self.running_skills.insert(a);
                self.skill_started.insert(a, self.now_ms);
                let name = self.program.actions[a.index()].name.clone();
                self.outbox.push_back(AgentOutput::StartSkill { action: a, name, binding });
            }
        }
    }

    /// Says `Held` for each held token nothing of which runs any more, and `Released` for each released one, once
    /// per change.
    pub(super) fn confirm_holds(&mut self) {
        let ids: Vec<TokenId> = self.tokens.keys().copied().collect();
        for id in ids {
            let h = &self.tokens[&id];
            if h.done || h.held_said == Some(h.held) {
                continue;
            }
            let segment = h.segment;
            let running = self.running_skills.iter().any(|a| self.action_segments[a.index()].contains(&segment));
            if h.held && running {
                continue;
            }
            let kind = if h.held { AgentEventKind::Held } else { AgentEventKind::Released };
            if let Some(h) = self.tokens.get_mut(&id) {
                h.held_said = Some(h.held);
            }
            self.record(Some(id), kind);
        }
    }

    /// `ToAgent::Abort`: every skill of the run is cancelled, every step left with its actions' final scan, every
    /// token forgotten; a dispatch of this run that comes later is refused.
    pub fn handle_abort(&mut self, now_ms: u64) {
        self.catch_up(now_ms);
        if self.aborted {
            return;
        }
        self.aborted = true;
        // Said as it is here: a stop ends the run after its motions finished, and an agent that held nothing of it
        // has nothing to warn of (`ToAgent::Abort` ends a stopped run's segments too).
        let (skills, tokens) = (self.running_skills.len(), self.tokens.len());
        match (skills, tokens) {
            (0, 0) => self.log(Level::Info, "the run ended: nothing of it was running here".to_string()),
            (0, n) => self.log(Level::Info, format!("the run ended: its {n} token(s) here forgotten")),
            (k, n) => self.log(
                Level::Warn,
                format!("the run was aborted: {k} skill(s) cancelled and its {n} token(s) here forgotten"),
            ),
        }
        for a in std::mem::take(&mut self.running_skills) {
            self.outbox.push_back(AgentOutput::StopSkill { action: a });
            self.say_cancelled(Level::Warn, a, "the run was aborted");
        }
        if let Err(e) = self.engine.abort(self.now_ms) {
            self.log(Level::Error, format!("abort refused: {e}"));
        }
        self.drain_engine();
        let ids: Vec<TokenId> = self.tokens.keys().copied().collect();
        for id in ids {
            if let Some(h) = self.tokens.remove(&id) {
                self.remember_finished(id, h.epoch);
            }
        }
        self.by_segment.clear();
        self.next_cycle_ms = None;
        self.send_outputs();
    }

    /// `ToAgent::AckOverrun`: an operator acknowledged a step's supervision fault. Said back each time (the
    /// coordinator sends it again until it hears).
    pub fn handle_ack_overrun(&mut self, now_ms: u64, token: TokenId, epoch: u32, step: u32) {
        self.catch_up(now_ms);
        let s = StepId(step);
        let ours = self
            .tokens
            .get(&token)
            .is_some_and(|h| h.epoch == epoch && !h.done && self.layout.segments[h.segment.index()].steps.contains(&s));
        if !ours {
            self.dropped += 1;
            return;
        }
        self.engine.acknowledge_overrun(s);
        self.record(Some(token), AgentEventKind::OverrunAcknowledged { step });
        self.settle();
    }

    /// `ToAgent::Gate`: the run's mode, and a transition of this token confirmed (step mode) or forced (manual
    /// mode). Said back with the number, each time (the coordinator sends it again until it hears).
    pub fn handle_gate(
        &mut self,
        now_ms: u64,
        token: TokenId,
        epoch: u32,
        mode: crate::exec::engine::Mode,
        permit: Option<u32>,
        seq: u64,
    ) {
        self.catch_up(now_ms);
        let Some(segment) = self.tokens.get(&token).filter(|h| h.epoch == epoch && !h.done).map(|h| h.segment) else {
            self.dropped += 1;
            return;
        };
        self.engine.set_mode(mode);
        if let Some(t) = permit {
            let program = Arc::clone(&self.program);
            let ours = (t as usize) < program.transitions.len()
                && self.layout.agent_judges(&program, crate::exec::program::TransitionId(t)) == Some(segment);
            if !ours {
                self.dropped += 1;
                return;
            }
            self.engine.permit(crate::exec::program::TransitionId(t));
        }
        self.record(Some(token), AgentEventKind::Gated { seq });
        self.settle();
    }

    /// Says which of this agent's transitions wait for a confirmation (step mode), when that changed.
    pub(super) fn report_waiting(&mut self) {
        let now: BTreeSet<u32> = self.engine.waiting().map(|t| t.0).collect();
        if now == self.waiting_said {
            return;
        }
        let program = Arc::clone(&self.program);
        let changed: Vec<(u32, bool)> = now
            .difference(&self.waiting_said)
            .map(|&t| (t, true))
            .chain(self.waiting_said.difference(&now).map(|&t| (t, false)))
            .collect();
        for (t, waiting) in changed {
            let token = self
                .layout
                .agent_judges(&program, crate::exec::program::TransitionId(t))
                .and_then(|g| self.by_segment.get(&g).copied());
            self.record(token, AgentEventKind::Waiting { transition: t, waiting });
        }
        self.waiting_said = now;
    }

    /// Why this agent's active steps wait: what its engine judges of them, and their skills still running.
    pub fn why(&self) -> Vec<crate::exec::why::StepWhy> {
        let mut out: Vec<crate::exec::why::StepWhy> = self
            .engine
            .active_steps()
            .iter()
            .map(|&s| {
                let mut why = self.engine.why(s);
                why.agent = Some(self.name.clone());
                why.skills = self.skills_of(s);
                why
            })
            .collect();
        out.sort_by(|a, b| a.step.cmp(&b.step));
        out
    }

    /// The skills of step `s`'s actions still running here, and for how long.
    pub(super) fn skills_of(&self, s: StepId) -> Vec<crate::exec::why::SkillWhy> {
        self.program
            .associations(s)
            .iter()
            .filter(|a| self.running_skills.contains(&a.action))
            .map(|a| crate::exec::why::SkillWhy {
                action: self.program.actions[a.action.index()].name.clone(),
                running_ms: self.now_ms.saturating_sub(self.skill_started.get(&a.action).copied().unwrap_or(0)),
            })
            .collect()
    }

    /// Whether the token that `action`'s skill belongs to is held here.
    pub(super) fn skill_held(&self, action: ActionId) -> bool {
        super::tokens::action_token(&self.action_segments, &self.by_segment, action)
            .and_then(|t| self.tokens.get(&t))
            .is_some_and(|h| h.held)
    }

    /// How many skills this agent started while their branch was held (the runtime's promise: none).
    pub fn started_while_held(&self) -> u64 {
        self.started_while_held
    }

    /// The run's id.
    pub fn run_id(&self) -> RunId {
        self.run
    }

    /// Whether the run was aborted here.
    pub fn is_aborted(&self) -> bool {
        self.aborted
    }
}
