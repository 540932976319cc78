//! What an operator does to a running engine, and what supervises its steps: steps held and released (their times
//! standing still), a step's maximum time and its acknowledgement, and the whole chart ended (`abort`).

use std::sync::Arc;

use crate::exec::env::Env;
use crate::exec::program::{StepId, TransitionId};

use super::mode::Mode;
use super::{ActionState, Engine, EventKind, InputError, TransitionScope};

impl Engine {
    /// How transitions clear from now on. Permits given in another mode are withdrawn.
    pub fn set_mode(&mut self, mode: Mode) {
        if self.mode != mode {
            self.mode = mode;
            self.permits.iter_mut().for_each(|p| *p = false);
            self.waiting.iter_mut().for_each(|w| *w = false);
            self.mutations += 1;
            self.gen += 1;
        }
    }

    pub fn mode(&self) -> Mode {
        self.mode
    }

    /// Lets transition `t` clear once: in step mode when its condition is TRUE, in manual mode whatever its
    /// condition (a force). It clears in the next cycle in which its sources are active (and not held).
    pub fn permit(&mut self, t: TransitionId) {
        if let Some(p) = self.permits.get_mut(t.index()) {
            *p = true;
            self.mutations += 1;
            self.gen += 1;
        }
    }

    /// Why active step `s` waits: its time, hold, fault and minimum time, and for each outgoing transition this
    /// engine judges, the FALSE parts of its condition and the sources not active yet.
    pub fn why(&self, s: StepId) -> crate::exec::why::StepWhy {
        let program = Arc::clone(&self.program);
        let st = &self.steps[s.index()];
        let t_now = self.step_t(s).max(0) as u64;
        let min = program.steps[s.index()].min_ms;
        let transitions = program
            .outgoing(s)
            .iter()
            .filter(|t| self.scope.transitions[t.index()] != TransitionScope::Remote)
            .map(|&t| crate::exec::why::TransitionWhy {
                name: program.transitions[t.index()].name.clone(),
                false_parts: crate::exec::why::false_parts(
                    &program,
                    &program.transitions[t.index()].condition,
                    self,
                    8,
                ),
                missing: program
                    .sources(t)
                    .iter()
                    .filter(|x| !self.steps[x.index()].active)
                    .map(|x| program.steps[x.index()].name.clone())
                    .collect(),
                waiting_confirm: self.waiting[t.index()],
            })
            .collect();
        crate::exec::why::StepWhy {
            step: program.steps[s.index()].name.clone(),
            agent: None,
            active_ms: t_now,
            held: st.held_at.is_some(),
            faulted: st.overrun_unacked,
            min_left_ms: min.saturating_sub(t_now),
            skills: Vec::new(),
            transitions,
        }
    }

    /// The transitions whose condition is TRUE and which wait for a confirmation (step mode), in id order.
    pub fn waiting(&self) -> impl Iterator<Item = TransitionId> + '_ {
        self.waiting.iter().enumerate().filter(|(_, w)| **w).map(|(i, _)| TransitionId(i as u32))
    }

    /// Step supervision, at the start of a cycle: an active step that runs here and has been active longer than
    /// its `max_ms` is faulted, once per activation.
    pub(super) fn supervise(&mut self) {
        for i in 0..self.active.len() {
            let s = self.active[i];
            let max = self.program.steps[s.index()].max_ms;
            if max == 0 || !self.scope.runs_actions[s.index()] || self.steps[s.index()].overrun {
                continue;
            }
            if self.step_t(s) > max as i64 {
                let st = &mut self.steps[s.index()];
                st.overrun = true;
                st.overrun_unacked = true;
                // What it waits for at this moment, before this cycle's transitions (its recovery among them)
                // move on: kept with the alarm (S7-GRAPH's CRIT_FLT).
                let why = self.why(s);
                // One kept per step at most, whether or not anyone takes it (`baton sim` does not).
                self.overrun_why.retain(|(x, _)| *x != s);
                self.overrun_why.push((s, why));
                self.push(EventKind::Overrun(s));
            }
        }
    }

    /// Why step `s` waited when it passed its maximum time (`EventKind::Overrun`), taken once.
    pub fn take_overrun_why(&mut self, s: StepId) -> Option<crate::exec::why::StepWhy> {
        let at = self.overrun_why.iter().position(|(x, _)| *x == s)?;
        Some(self.overrun_why.swap_remove(at).1)
    }

    /// An operator acknowledged step `s`'s supervision fault: its outgoing transitions may clear again (`S.overrun`
    /// stays TRUE until the step is left). False if the step has no fault waiting.
    pub fn acknowledge_overrun(&mut self, s: StepId) -> bool {
        let Some(st) = self.steps.get_mut(s.index()) else { return false };
        if !(st.active && st.overrun_unacked) {
            return false;
        }
        st.overrun_unacked = false;
        self.gen += 1;
        self.mutations += 1;
        true
    }

    /// Whether step `s` is faulted and waits for an acknowledgement.
    pub fn overrun_waits(&self, s: StepId) -> bool {
        self.steps.get(s.index()).is_some_and(|st| st.active && st.overrun_unacked)
    }

    /// Holds step `s` from `now_ms` (`held`), or releases it. While a held step is active, none of its outgoing
    /// transitions clears, and its time (`S.T`), its timed qualifiers (L, D, DS) and the stored timers (SD, SL) of
    /// its actions stand still; its actions' bodies go on running. A held step that becomes active (a token arriving
    /// at it) is held from then. On release its time goes on from where it stood.
    pub fn set_held(&mut self, now_ms: u64, s: StepId, held: bool) {
        let Some(&was) = self.held.get(s.index()) else { return };
        if was == held {
            return;
        }
        self.held[s.index()] = held;
        let now = now_ms.max(self.now_ms);
        let program = Arc::clone(&self.program);
        let state = &mut self.steps[s.index()];
        if held {
            if state.active {
                state.held_at = Some(now);
            }
            for assoc in program.associations(s) {
                let f = &mut self.frozen_at[assoc.action.index()];
                if f.is_none() && self.steps[s.index()].active {
                    *f = Some(now);
                }
            }
        } else {
            if let Some(at) = state.held_at.take() {
                state.activated_ms += now - at;
            }
            for assoc in program.associations(s) {
                let a = assoc.action.index();
                // Still frozen while another held step uses it.
                let still = (0..program.steps.len()).map(|i| StepId(i as u32)).any(|o| {
                    o != s
                        && self.held[o.index()]
                        && self.steps[o.index()].active
                        && program.associations(o).iter().any(|x| x.action == assoc.action)
                });
                if let (Some(at), false) = (self.frozen_at[a], still) {
                    self.frozen_at[a] = None;
                    let st = &mut self.actions[a];
                    let shift = |x: &mut Option<(u64, i64)>| {
                        if let Some((start, _)) = x {
                            *start += now - at;
                        }
                    };
                    shift(&mut st.stored_sd);
                    shift(&mut st.stored_sl);
                }
            }
        }
        self.mutations += 1;
        self.gen += 1;
        self.xq_gen = self.gen;
    }

    /// Ends the chart at `now_ms` (an operator's abort or stop): every active step is left, every stored qualifier
    /// reset, and the actions whose Q falls get their final scan; nothing becomes active. Events as for a cycle.
    pub fn abort(&mut self, now_ms: u64) -> Result<(), InputError> {
        self.advance(now_ms)?;
        self.gen += 1;
        while let Some(&s) = self.active.last() {
            self.deactivate(s);
        }
        for a in &mut self.actions {
            let q = a.q;
            *a = ActionState { q, ..ActionState::default() };
        }
        self.frozen_at.iter_mut().for_each(|f| *f = None);
        self.control_actions(false);
        self.deactivated.clear();
        self.cycle += 1;
        Ok(())
    }

    /// Whether step `s` is held (`set_held`).
    pub fn is_held(&self, s: StepId) -> bool {
        self.held.get(s.index()).copied().unwrap_or(false)
    }
}
