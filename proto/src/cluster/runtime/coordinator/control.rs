//! Control from outside: `baton set` (an input, checked and applied) and `baton status`.

use std::sync::Arc;

use crate::cluster::layout::Placement;
use crate::cluster::runtime::packml::State;
use crate::cluster::wire::{
    StatusAgent, StatusAlarm, StatusDevice, StatusReport, StatusStep, StatusToken, StatusValue,
};
use crate::exec::engine::Input;
use crate::exec::program::VarId;
use crate::exec::trace::{TraceEvent, TraceRecord};
use crate::front::json_value;
use crate::types::Value;

use super::Coordinator;

impl Coordinator {
    /// `baton set NAME=VALUE`: sets an input (a variable no action writes) before the next cycle.
    pub fn handle_set(&mut self, now_ms: u64, name: &str, value: &serde_json::Value) -> Result<String, String> {
        self.handle_set_by(now_ms, name, value, "")
    }

    /// `handle_set` of a request `by` someone (the trace says who; nobody when empty).
    pub fn handle_set_by(
        &mut self,
        now_ms: u64,
        name: &str,
        value: &serde_json::Value,
        by: &str,
    ) -> Result<String, String> {
        self.advance(now_ms);
        let (var, v) = self.check_set(name, value)?;
        let program = Arc::clone(&self.program);
        let info = &program.vars[var.index()];
        let shown = info.ty.show(&v);
        self.engine.handle(Input::Set(var, v)).map_err(|e| e.to_string())?;
        let mut rec = TraceRecord::new(self.now_ms, TraceEvent::Set, &info.name);
        rec.message = Some(shown.clone());
        rec.by = (!by.is_empty()).then(|| by.to_string());
        self.trace(rec);
        self.settle();
        Ok(format!("{} := {shown}", info.name))
    }

    /// Whether `baton set NAME=VALUE` would apply; why not, if not (then it is not journaled).
    pub fn check_set(&self, name: &str, value: &serde_json::Value) -> Result<(VarId, Value), String> {
        let var = self
            .program
            .var_by_name(name)
            .ok_or_else(|| format!("chart `{}` has no variable `{name}`", self.program.name))?;
        let info = &self.program.vars[var.index()];
        if !self.layout.settable[var.index()] {
            let why = if info.constant {
                "it is a CONSTANT".to_string()
            } else {
                format!("the chart writes it on {}", self.layout.writer[var.index()])
            };
            return Err(format!("`{}` cannot be set: {why}", info.name));
        }
        let v = json_value::parse(&info.ty, value)
            .ok_or_else(|| format!("`{}` is {}, and {value} is not a {} value", info.name, info.ty, info.ty))?;
        Ok((var, v))
    }

    pub fn status(&self) -> StatusReport {
        let mut active_steps: Vec<StatusStep> = self
            .engine
            .active_steps()
            .iter()
            .map(|&s| StatusStep {
                name: self.program.steps[s.index()].name.clone(),
                placement: self.layout.placement[s.index()].to_string(),
                agent: self.holder(s).map(str::to_string),
                active_ms: crate::exec::env::Env::step_t(&self.engine, s).max(0) as u64,
            })
            .collect();
        active_steps.sort_by(|a, b| a.name.cmp(&b.name));
        let mut tokens: Vec<StatusToken> = self
            .tokens
            .iter()
            .map(|(id, t)| StatusToken {
                token: *id,
                epoch: t.epoch,
                entry: self.program.steps[t.entry.index()].name.clone(),
                at: self.segment_at(t.segment).map(str::to_string).collect(),
                agent: t.agent.clone(),
                since_ms: t.dispatched_ms,
                paused: t.paused,
                held: t.hold,
                held_confirmed: t.hold && t.hold_ok,
            })
            .collect();
        tokens.sort_by_key(|t| (t.since_ms, t.token));
        let agents = self
            .agents
            .iter()
            .filter(|(_, a)| a.alive)
            .map(|(name, a)| StatusAgent {
                name: name.clone(),
                roles: a.roles.clone(),
                tokens: a.tokens,
                devices_down: a
                    .devices_down
                    .iter()
                    .map(|(b, why)| {
                        let binding = &self.layout.io[*b as usize];
                        StatusDevice { var: binding.name.clone(), device: binding.device(), message: why.clone() }
                    })
                    .collect(),
                skills: a.skills.as_ref().map(|s| s.iter().cloned().collect()),
            })
            .collect();
        StatusReport {
            run: self.run,
            chart: self.program.name.clone(),
            hash: self.hash.clone(),
            t_ms: self.now_ms,
            started_ms: self.started_ms,
            // The host reads the wall clock (the core has none).
            unix_ms: 0,
            active_steps,
            tokens,
            agents,
            state: self.run_state,
            available: self.available(),
            alarms: self.alarms.announced(self.now_ms).map(status_alarm).collect(),
            shelved: self.alarms.shelved(self.now_ms).map(status_alarm).collect(),
            held: self.partial_holds(),
            mode: self.engine.mode(),
            waiting: self
                .waiting_transitions()
                .into_iter()
                .map(|t| self.program.transitions[t.index()].name.clone())
                .collect(),
            why: self.why(),
            messages_dropped: self.stats.dropped,
            values: self
                .program
                .vars
                .iter()
                .enumerate()
                .filter(|(_, v)| !v.constant && !v.hidden)
                .map(|(i, v)| StatusValue { name: v.name.clone(), value: self.value(VarId(i as u32)).to_string() })
                .collect(),
            // The host says where its recording is served (the core knows nothing of Rerun).
            rerun: None,
        }
    }

    /// Why the coordinator's own active steps wait, and the convergences it judges (the agents say why theirs do).
    pub fn why(&self) -> Vec<crate::exec::why::StepWhy> {
        let mut out: Vec<crate::exec::why::StepWhy> = self
            .engine
            .active_steps()
            .iter()
            .filter(|&&s| {
                self.layout.placement[s.index()] == Placement::Coordinator
                    || self.program.outgoing(s).iter().any(|&t| self.layout.agent_judges(&self.program, t).is_none())
            })
            .map(|&s| {
                let mut why = self.engine.why(s);
                why.agent = self.holder(s).map(str::to_string);
                why
            })
            .filter(|w| w.agent.is_none() || !w.transitions.is_empty())
            .collect();
        out.sort_by(|a, b| a.step.cmp(&b.step));
        out
    }

    /// `baton run --wait-start`: the run waits in Idle, its chart not started, until an operator's `start`.
    pub fn handle_wait_start(&mut self) {
        if self.run_state == State::Execute && self.engine.now_ms() == 0 {
            self.change_state(State::Idle);
        }
    }

    /// The run's PackML state.
    pub fn run_state(&self) -> State {
        self.run_state
    }

    /// The run ends (the host's last record): a chart that reached a terminal situation, without a failure,
    /// goes Completing and, with nothing left to finish, Complete; each change is a `state` trace record.
    pub fn handle_end(&mut self, now_ms: u64, failure: Option<&str>) {
        self.advance(now_ms);
        if failure.is_none() && self.is_terminal() && self.run_state == State::Execute {
            self.change_state(State::Completing);
            if let Some(done) = State::Completing.when_done() {
                self.change_state(done);
            }
        }
    }

    pub(super) fn change_state(&mut self, to: State) {
        self.run_state = to;
        let rec = TraceRecord::new(self.now_ms, TraceEvent::State, to.name());
        self.trace(rec);
    }
}

fn status_alarm(a: &crate::cluster::runtime::alarms::Alarm) -> StatusAlarm {
    StatusAlarm {
        id: a.id.0,
        source: a.source.clone(),
        message: a.message.clone(),
        state: a.state(),
        raised_ms: a.raised_ms,
        shelved_until_ms: a.shelved_until_ms,
        shelf: a.shelved_by.clone(),
    }
}
