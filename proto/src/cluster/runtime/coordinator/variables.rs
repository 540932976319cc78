//! Variables: the values an agent writes, taken from the writer's current process only, and the coordinator's own
//! values published to the agents that read them.

use std::collections::BTreeSet;

use crate::cluster::runtime::{Level, COORDINATOR};
use crate::cluster::wire::{VarUpdate, VarValue};
use crate::exec::engine::Input;

use super::{CoordOutput, Coordinator};

impl Coordinator {
    pub(super) fn publish_vars(&mut self) {
        let mut changed = Vec::new();
        for (i, &v) in self.owned.iter().enumerate() {
            let value = self.engine.value(v);
            if self.published[i].as_ref() != Some(&value) {
                self.published[i] = Some(value.clone());
                changed.push(VarValue::new(v, value));
            }
        }
        if !changed.is_empty() {
            self.vars_seq += 1;
            let update = VarUpdate {
                run: self.run,
                from: COORDINATOR.to_string(),
                incarnation: uuid::Uuid::nil(),
                seq: self.vars_seq,
                vars: changed,
            };
            self.outbox.push_back(CoordOutput::Vars(update));
            self.vars_resend.start(self.now_ms);
        }
    }

    /// Publishes every owned value again, as of the last update, when that is due (`VARS_RESEND_FIRST_MS`).
    pub(super) fn resend_vars(&mut self) {
        if !self.vars_resend.due(self.now_ms) {
            return;
        }
        let vars = self.owned.iter().map(|&v| VarValue::new(v, self.engine.value(v))).collect();
        let update = VarUpdate {
            run: self.run,
            from: COORDINATOR.to_string(),
            incarnation: uuid::Uuid::nil(),
            seq: self.vars_seq,
            vars,
        };
        self.outbox.push_back(CoordOutput::Vars(update));
    }

    /// Values from `agent`'s process `incarnation`, as of its update `seq`: each applies unless a newer write of
    /// the variable was applied already.
    pub(super) fn apply_agent_vars(
        &mut self,
        agent: &str,
        incarnation: uuid::Uuid,
        seq: u64,
        vars: &[VarValue],
    ) -> bool {
        let mut applied = false;
        let mut refused: BTreeSet<u32> = BTreeSet::new();
        for vv in vars {
            let Some((var, value)) = vv.resolve(&self.program) else {
                refused.insert(vv.var);
                continue;
            };
            if !self.serves(agent, &self.layout.writer[var.index()]) {
                refused.insert(vv.var);
                continue;
            }
            if !self.var_writes.accept(var.index(), agent, incarnation, seq, false) {
                continue;
            }
            applied = true;
            if let Err(e) = self.engine.handle(Input::Set(var, value)) {
                self.log(Level::Warn, format!("value from `{agent}` refused: {e}"));
            }
        }
        if !refused.is_empty() {
            self.drop_msg(format!(
                "`{agent}` sent {} variable value(s) it does not write, or of the wrong type",
                refused.len()
            ));
        }
        applied
    }

    /// The part of an agent's variable update that would apply: its values of variables it writes, that fit
    /// their types and are newer than those applied, each variable once (its first value, as `handle_vars` takes
    /// it). `None` when nothing would: then nothing is journaled, whatever the update weighs.
    pub(super) fn admit_vars(&self, update: &VarUpdate) -> Option<Vec<VarValue>> {
        if update.from == COORDINATOR || update.run != self.run {
            return None;
        }
        let agent = self.agents.get(&update.from)?;
        if agent.incarnation != update.incarnation {
            return None;
        }
        let mut seen = BTreeSet::new();
        let kept: Vec<VarValue> = update
            .vars
            .iter()
            .filter(|vv| {
                vv.resolve(&self.program).is_some_and(|(var, _)| {
                    self.serves(&update.from, &self.layout.writer[var.index()])
                        && self.var_writes.would_accept(var.index(), &update.from, update.incarnation, update.seq)
                        && seen.insert(var)
                })
            })
            .cloned()
            .collect();
        (!kept.is_empty()).then_some(kept)
    }

    /// A variable update published by an agent (also sent to agents that read it).
    pub(super) fn handle_vars(&mut self, now_ms: u64, update: VarUpdate) {
        self.advance(now_ms);
        if update.from == COORDINATOR {
            return;
        }
        if update.run != self.run {
            return self.drop_msg(format!("variable update from `{}` for another run dropped", update.from));
        }
        let Some(agent) = self.agents.get(&update.from) else {
            return self.drop_msg(format!("variable update from unknown agent `{}` dropped", update.from));
        };
        if agent.incarnation != update.incarnation {
            return self.drop_msg(format!(
                "variable update from `{}` dropped: it comes from another process than the agent's current one",
                update.from
            ));
        }
        // An update that changes nothing (every value older than one applied) is not journaled: it must not move
        // the engine either, or a replay would differ.
        if self.apply_agent_vars(&update.from, update.incarnation, update.seq, &update.vars) {
            self.settle();
        }
    }
}
