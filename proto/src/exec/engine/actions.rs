//! The engine's actions: each cycle, what every active step's associations ask of each action (its qualifiers,
//! IEC 61131-3 Table 56), the action's Q and its body run — and a skill's start resets its indicators.

use std::sync::Arc;

use crate::exec::eval;
use crate::exec::program::{ActionId, Program, VarId};
use crate::front::model::Qualifier;
use crate::types::Value;

use super::{Demand, Engine, EventKind, FaultSource};

impl Engine {
    /// A skill starts: the indicators of the action's associations on active steps go FALSE, so that no
    /// transition takes an earlier run's result for this one's.
    pub(super) fn reset_indicators(&mut self, a: ActionId) {
        let program = Arc::clone(&self.program);
        for i in 0..self.active.len() {
            let s = self.active[i];
            for (assoc, inds) in program.associations(s).iter().zip(program.indicators(s)) {
                if assoc.action == a {
                    for &v in inds.iter().take(2) {
                        self.store(v, Value::Bool(false));
                    }
                }
            }
        }
    }

    pub(super) fn demand(&mut self, a: ActionId) -> &mut Demand {
        let i = a.index();
        if self.demand_stamp[i] != self.cycle {
            self.demand_stamp[i] = self.cycle;
            self.demand[i] = Demand::default();
            self.judged.push(a);
        }
        &mut self.demand[i]
    }

    /// Step (e): compute every concerned action's Q, then run the bodies. In a reaction (`partial`), only the
    /// actions of steps just made active or just left are concerned, and a body runs only where Q rises (its
    /// first scan) or falls (its last): the others run in the next cycle, as they would have anyway.
    pub(super) fn control_actions(&mut self, partial: bool) {
        let program = Arc::clone(&self.program);
        self.judged.clear();
        if partial {
            let fresh = self.active.iter().any(|&s| self.steps[s.index()].activated_cycle == self.cycle);
            if !fresh && self.deactivated.is_empty() {
                return;
            }
        }
        let stamp = self.cycle;
        self.demand_actions(&program, stamp);
        let mut judged = std::mem::take(&mut self.judged);
        judged.sort_unstable();
        if !partial {
            self.live.clear();
        }
        // Stored qualifiers started between cycles count from the last cycle, like the steps' times.
        let now = if partial { self.grid_floor(self.now_ms) } else { self.now_ms };
        let (changes, reset_vars) = self.judge_actions(&program, &judged, partial, stamp, now);
        self.run_actions(&program, changes, reset_vars, partial);
        self.judged = judged;
    }

    /// What the associations of the active steps, the steps just left and the actions still live (stored, or
    /// timing) ask of each action this cycle (`demand`), marking those a step touched now with `stamp`.
    fn demand_actions(&mut self, program: &Program, stamp: u64) {
        for i in 0..self.active.len() {
            let s = self.active[i];
            if !self.scope.runs_actions[s.index()] {
                continue;
            }
            let state = self.steps[s.index()];
            let elapsed = (state.held_at.unwrap_or(self.now_ms) - state.activated_ms) as i64;
            let just_activated = state.activated_cycle == self.cycle;
            for assoc in program.associations(s) {
                let dur = eval::duration_ms(assoc.duration, self);
                if just_activated {
                    self.touched[assoc.action.index()] = stamp;
                }
                let d = self.demand(assoc.action);
                match assoc.qualifier {
                    Qualifier::N | Qualifier::Active => d.direct = true,
                    Qualifier::R => d.reset = true,
                    Qualifier::S => d.set_s = true,
                    Qualifier::L => d.direct |= elapsed < dur,
                    Qualifier::D => d.direct |= elapsed >= dur,
                    Qualifier::P | Qualifier::P1 | Qualifier::Entry => d.direct |= just_activated,
                    Qualifier::P0 | Qualifier::Exit => {}
                    Qualifier::SD => d.set_sd = Some(d.set_sd.map_or(dur, |x| x.min(dur))),
                    Qualifier::DS => d.set_ds |= elapsed >= dur,
                    Qualifier::SL => d.set_sl = Some(d.set_sl.map_or(dur, |x| x.min(dur))),
                }
            }
        }
        for i in 0..self.deactivated.len() {
            let s = self.deactivated[i];
            if !self.scope.runs_actions[s.index()] {
                continue;
            }
            for assoc in program.associations(s) {
                self.touched[assoc.action.index()] = stamp;
                let d = self.demand(assoc.action);
                if matches!(assoc.qualifier, Qualifier::P0 | Qualifier::Exit) {
                    d.direct = true;
                }
            }
        }
        for i in 0..self.live.len() {
            let a = self.live[i];
            self.demand(a);
        }
    }

    /// Each judged action's Q from what is asked of it and what it stored: (action, Q before, Q now) in action
    /// order, and the Boolean actions an active R association resets (their variable reads FALSE, on or not
    /// before). In a reaction (`partial`), only the actions a step touched now (`stamp`).
    fn judge_actions(
        &mut self,
        program: &Program,
        judged: &[ActionId],
        partial: bool,
        stamp: u64,
        now: u64,
    ) -> (Vec<(ActionId, bool, bool)>, Vec<VarId>) {
        // (action, Q before, Q now), in action order.
        let mut changes: Vec<(ActionId, bool, bool)> = Vec::with_capacity(judged.len());
        // Boolean actions an active R association resets this cycle: their variable reads FALSE, on or not before.
        let mut reset_vars = Vec::new();
        for &a in judged {
            if partial && self.touched[a.index()] != stamp {
                continue;
            }
            let d = self.demand[a.index()];
            let st = &mut self.actions[a.index()];
            let was = *st;
            if d.reset {
                // Reset dominates: R clears every stored qualifier, even one set in the same cycle.
                st.stored_s = false;
                st.stored_sd = None;
                st.stored_ds = false;
                st.stored_sl = None;
            } else {
                st.stored_s |= d.set_s;
                st.stored_ds |= d.set_ds;
                if st.stored_sd.is_none() {
                    st.stored_sd = d.set_sd.map(|dur| (now, dur));
                }
                if st.stored_sl.is_none() {
                    st.stored_sl = d.set_sl.map(|dur| (now, dur));
                }
            }
            let at = self.frozen_at[a.index()].unwrap_or(self.now_ms);
            let since = |start: u64| at.saturating_sub(start) as i64;
            let q = d.direct
                || st.stored_s
                || st.stored_ds
                || st.stored_sd.is_some_and(|(start, dur)| since(start) >= dur)
                || st.stored_sl.is_some_and(|(start, dur)| since(start) < dur);
            let before = st.q;
            st.q = q;
            let live = st.live();
            if *st != was {
                self.mutations += 1;
            }
            if !partial {
                if live {
                    self.live.push(a);
                }
            } else if live && !self.live.contains(&a) {
                self.live.push(a);
            } else if !live {
                self.live.retain(|&x| x != a);
            }
            if d.reset && !q {
                reset_vars.extend(program.actions[a.index()].bool_var);
            }
            changes.push((a, before, q));
        }
        (changes, reset_vars)
    }

    /// Tells the changes of Q, sets the Boolean actions' variables, and runs the bodies that run this cycle.
    fn run_actions(
        &mut self,
        program: &Program,
        mut changes: Vec<(ActionId, bool, bool)>,
        reset_vars: Vec<VarId>,
        partial: bool,
    ) {
        for &(a, before, q) in &changes {
            if q && !before {
                self.push(EventKind::ActionOn(a));
            } else if before && !q {
                self.push(EventKind::ActionOff(a));
            }
            if q != before {
                self.xq_gen = self.gen;
            }
        }
        // A body runs while Q is TRUE, and once more with Q = FALSE in the cycle Q falls; in a reaction only
        // where Q changed. An entry or exit action runs once, and a main step action while its step is active, with
        // no final scan; exit actions run first, then entry actions, then main step actions, then the others
        // (CODESYS's order).
        let once = |a: ActionId| program.actions[a.index()].once;
        let runs = |a: ActionId, before: bool, q: bool| {
            let final_scan = before && !q;
            (if partial { q != before } else { q || before }) && !(final_scan && once(a).is_some())
        };
        if changes.iter().any(|&(a, _, _)| once(a).is_some()) {
            changes.sort_by_key(|&(a, _, _)| (once(a).map_or(3, |o| o as u8), a));
        }
        // Boolean actions' variables follow Q before any body runs, so that every body sees this cycle's Qs; an
        // overriding reset (R) writes FALSE even to one that was off (IEC: the variable is the action's Q).
        for var in reset_vars {
            self.store(var, Value::Bool(false));
        }
        for &(a, before, q) in &changes {
            if let (Some(var), true) = (program.actions[a.index()].bool_var, runs(a, before, q)) {
                self.store(var, Value::Bool(q));
            }
            if q && !before && self.scope.skill_actions[a.index()] {
                self.reset_indicators(a);
            }
        }
        for &(a, before, q) in &changes {
            if !runs(a, before, q) {
                continue;
            }
            let action = &program.actions[a.index()];
            if let Err(fault) = eval::run(&action.body, self) {
                self.push(EventKind::Fault(FaultSource::Action(a), fault));
            }
        }
    }
}
