//! Skills: what a skill that an action started says back — done, failed, an output value, stopped — set on the
//! association's indicators.

use std::sync::Arc;

use crate::cluster::runtime::agent::tokens::action_token;
use crate::cluster::runtime::Level;
use crate::cluster::wire::AgentEventKind;
use crate::exec::engine::Input;
use crate::exec::program::{ActionId, VarId};
use crate::exec::trace::TraceEvent;
use crate::types::Value;

use super::AgentRun;

impl AgentRun {
    /// A skill finished: its action's indicator variables say so (first: done, second: fault).
    pub fn handle_skill_result(&mut self, now_ms: u64, action: ActionId, result: Result<(), String>) {
        self.catch_up(now_ms);
        if !self.running_skills.remove(&action) {
            return;
        }
        let ok = result.is_ok();
        self.set_indicators(action, Some(ok), Some(!ok));
        let kind = match result {
            Ok(()) => AgentEventKind::SkillDone { action: action.0 },
            Err(message) => AgentEventKind::SkillFault { action: action.0, message },
        };
        self.record(action_token(&self.action_segments, &self.by_segment, action), kind);
        self.settle();
    }

    /// A part of a running skill's answer (a feedback, the result before it is reported done): the value goes to
    /// the variable its binding's `outputs[output]` names, converted to the variable's type as `*_TO_*` does.
    /// A skill that no longer runs writes nothing: its action's Q fell, and the chart has moved on.
    pub fn handle_skill_output(&mut self, now_ms: u64, action: ActionId, output: usize, value: Value) {
        self.catch_up(now_ms);
        if !self.running_skills.contains(&action) {
            return;
        }
        let Some(var) = self.layout.skills[action.index()].as_ref().and_then(|b| b.outputs.get(output)).map(|o| o.var)
        else {
            return;
        };
        let what = format!("skill of action `{}`", self.program.actions[action.index()].name);
        self.write_from_device(var, value, what);
    }

    /// A skill stopped because its action's Q fell has ended its own way (a ROS 2 goal cancelled, a cancel
    /// method called): said in the log, since the chart no longer waits for it.
    /// `result` says how: `Ok` with what the device answered, or `Err` with why the stop failed.
    pub fn handle_skill_stopped(&mut self, action: ActionId, result: Result<String, String>) {
        let name = self.program.actions[action.index()].name.clone();
        let (level, message) = match &result {
            Ok(how) => (Level::Info, format!("skill of action `{name}` stopped: {how}")),
            Err(why) => (Level::Warn, format!("skill of action `{name}` did not stop cleanly: {why}")),
        };
        self.log(level, message);
        let token = action_token(&self.action_segments, &self.by_segment, action);
        let said = match result {
            Ok(how) => how,
            Err(why) => format!("it did not stop cleanly: {why}"),
        };
        self.note(TraceEvent::SkillStopped, &name, token, Some(said));
    }

    /// Says that the skill of `action` is cancelled, and why (`the run was aborted`), in the log at `level` and
    /// in the trace. The caller has removed it from the running skills and asked the host to stop it.
    pub(super) fn say_cancelled(&mut self, level: Level, action: ActionId, why: &str) {
        let name = self.program.actions[action.index()].name.clone();
        self.log(level, format!("skill of action `{name}` cancelled: {why}"));
        let token = action_token(&self.action_segments, &self.by_segment, action);
        self.note(TraceEvent::SkillCancel, &name, token, Some(why.to_string()));
    }

    /// Sets the indicators of `action`'s associations on the active steps: the first to `done`, the second
    /// to `fault` (where given).
    pub(super) fn set_indicators(&mut self, action: ActionId, done: Option<bool>, fault: Option<bool>) {
        let program = Arc::clone(&self.program);
        let mut sets: Vec<(VarId, bool)> = Vec::new();
        for &s in self.engine.active_steps() {
            for (assoc, inds) in program.associations(s).iter().zip(program.indicators(s)) {
                if assoc.action != action {
                    continue;
                }
                if let (Some(&v), Some(b)) = (inds.first(), done) {
                    sets.push((v, b));
                }
                if let (Some(&v), Some(b)) = (inds.get(1), fault) {
                    sets.push((v, b));
                }
            }
        }
        for (v, b) in sets {
            let _ = self.engine.handle(Input::Set(v, Value::Bool(b)));
        }
    }
}
