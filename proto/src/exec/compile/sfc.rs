//! The SFC itself: actions and their associations with steps (qualifiers, durations, indicators), and transitions.

use std::collections::HashMap;

use crate::exec::compile::nested::with_q;
use crate::exec::compile::typing::{bool_literal, Ty};
use crate::exec::eval::{eval, is_constant, NoEnv};
use crate::exec::program::{
    ActionId, ActionInfo, Assoc, CExpr, DurationSrc, Once, StepId, StepParts, TransitionInfo, TransitionParts, VarInfo,
};
use crate::front::diag::{Diagnostic, Span};
use crate::front::model::{Action, Association, Duration, Ident, Qualifier, Step};
use crate::limits::{NESTING_DEPTH_MAX, SUPERVISION_MS_MAX};
use crate::types::{Type, Value};

use super::Compiler;

impl<'a> Compiler<'a> {
    /// Declared actions, and the chart element behind each.
    pub(super) fn declare_actions(&mut self) -> (Vec<ActionInfo>, Vec<&'a Action>) {
        let chart = self.chart;
        let mut actions = Vec::new();
        let mut sources = Vec::new();
        for action in &chart.actions {
            if self.actions.contains_key(&action.name.key()) {
                self.error(action.name.span, format!("action `{}` is declared twice", action.name.name));
                continue;
            }
            self.actions.insert(action.name.key(), ActionId(actions.len() as u32));
            sources.push(action);
            actions.push(ActionInfo {
                name: action.name.name.clone(),
                body: Vec::new(),
                once: None,
                bool_var: None,
                pragmas: action.pragmas.clone(),
            });
        }
        (actions, sources)
    }

    pub(super) fn associate(
        &mut self,
        vars: &[VarInfo],
        sources: &[&Step],
        steps: &mut [StepParts],
        actions: &mut Vec<ActionInfo>,
    ) {
        for (parts, step) in steps.iter_mut().zip(sources) {
            let mut assocs = Vec::with_capacity(step.associations.len());
            for a in &step.associations {
                let Some(action) = self.action_for(a, vars, actions) else { continue };
                let duration = self.duration(a, vars);
                let mut indicators = Vec::new();
                for ind in &a.indicators {
                    match self.vars.get(&ind.key()) {
                        Some(&v) if vars[v.index()].ty == Type::Bool => indicators.push(v),
                        Some(&v) => {
                            let message =
                                format!("indicator variable `{}` must be BOOL, not {}", ind.name, vars[v.index()].ty);
                            self.error(ind.span, message);
                        }
                        None if self.chart.broken.var(&ind.key()) => {}
                        None => {
                            let hint = self.var_hint(&ind.name);
                            self.error(ind.span, format!("undeclared indicator variable `{}`{hint}", ind.name))
                        }
                    }
                }
                assocs.push((Assoc { action, qualifier: a.qualifier, duration }, indicators));
            }
            parts.associations = assocs;
        }
        // An action associated only as entry actions (or only as exit actions) runs once each time: no final
        // scan, and before the others of its cycle.
        let mut kinds: Vec<Option<Option<Once>>> = vec![None; actions.len()];
        for (assoc, _) in steps.iter().flat_map(|p| &p.associations) {
            let kind = match assoc.qualifier {
                Qualifier::Entry => Some(Once::Entry),
                Qualifier::Exit => Some(Once::Exit),
                Qualifier::Active => Some(Once::Active),
                _ => None,
            };
            let slot = &mut kinds[assoc.action.index()];
            *slot = Some(match *slot {
                None => kind,
                Some(k) if k == kind => kind,
                Some(_) => None,
            });
        }
        for (a, kind) in actions.iter_mut().zip(kinds) {
            a.once = kind.flatten();
        }
    }

    /// The action an association names: a declared action, or a boolean action named after a BOOL variable.
    pub(super) fn action_for(
        &mut self,
        a: &Association,
        vars: &[VarInfo],
        actions: &mut Vec<ActionInfo>,
    ) -> Option<ActionId> {
        if let Some(&id) = self.actions.get(&a.action.key()) {
            return Some(id);
        }
        // An action of a function block instance (CODESYS's step actions name them, `Crane.Init`): run as a call of
        // it, under this association's qualifier.
        if let Some((instance, action)) = a.action.name.rsplit_once('.').filter(|(i, _)| self.user_at(i).is_some()) {
            let call = self.instance_action_call(&a.action, instance, action, &[], vars)?;
            let id = ActionId(actions.len() as u32);
            self.actions.insert(a.action.key(), id);
            actions.push(ActionInfo {
                name: a.action.name.clone(),
                body: with_q(std::slice::from_ref(&call), CExpr::ActionQ(id)).unwrap_or_else(|| vec![call]),
                once: None,
                bool_var: None,
                pragmas: Vec::new(),
            });
            return Some(id);
        }
        match self.vars.get(&a.action.key()) {
            Some(&v) if vars[v.index()].ty == Type::Bool => {
                let id = ActionId(actions.len() as u32);
                self.actions.insert(a.action.key(), id);
                actions.push(ActionInfo {
                    name: vars[v.index()].name.clone(),
                    body: Vec::new(),
                    once: None,
                    bool_var: Some(v),
                    pragmas: Vec::new(),
                });
                Some(id)
            }
            Some(&v) => {
                let message = format!(
                    "`{}` has no ACTION body and is a {} variable: a boolean action needs a BOOL variable",
                    a.action.name,
                    vars[v.index()].ty
                );
                self.error(a.action.span, message);
                None
            }
            None if self.chart.broken.action(&a.action.key()) || self.chart.broken.var(&a.action.key()) => None,
            None => {
                self.error(
                    a.action.span,
                    format!(
                        "unknown action `{}`{}: declare it with `ACTION {}: … END_ACTION` or as a BOOL variable",
                        a.action.name,
                        self.action_hint(&a.action.name),
                        a.action.name
                    ),
                );
                None
            }
        }
    }

    pub(super) fn duration(&mut self, a: &Association, vars: &[VarInfo]) -> Option<DurationSrc> {
        match (&a.duration, a.qualifier.is_timed()) {
            (None, true) => {
                let message = format!(
                    "qualifier {:?} needs a duration, such as `{}({:?}, T#1s)`",
                    a.qualifier, a.action.name, a.qualifier
                );
                self.error(a.qualifier_span, message);
                None
            }
            (None, false) => None,
            (Some(Duration::Literal { ms, span }), _) => {
                if *ms < 0 {
                    self.error(*span, "a duration must not be negative");
                }
                Some(DurationSrc::Ms((*ms).max(0)))
            }
            (Some(Duration::Var(name)), _) => match self.vars.get(&name.key()) {
                Some(&v) if vars[v.index()].ty == Type::Time => Some(DurationSrc::Var(v)),
                Some(&v) => {
                    let message = format!("duration variable `{}` must be TIME, not {}", name.name, vars[v.index()].ty);
                    self.error(name.span, message);
                    None
                }
                None => {
                    if !self.chart.broken.var(&name.key()) {
                        let hint = self.var_hint(&name.name);
                        self.error(name.span, format!("undeclared variable `{}`{hint}", name.name));
                    }
                    None
                }
            },
        }
    }

    pub(super) fn step_list(&mut self, list: &[Ident]) -> Option<Vec<StepId>> {
        let mut ids = Vec::with_capacity(list.len());
        let mut ok = true;
        for name in list {
            match self.steps.get(&name.key()) {
                Some(&id) if ids.contains(&id) => {
                    self.error(name.span, format!("step `{}` appears twice in this list", name.name));
                    ok = false;
                }
                Some(&id) => ids.push(id),
                None => {
                    if !self.chart.broken.step(&name.key()) {
                        let hint = self.step_hint(&name.name);
                        self.error(name.span, format!("unknown step `{}`{hint}", name.name));
                    }
                    ok = false;
                }
            }
        }
        ok.then_some(ids)
    }

    pub(super) fn transitions(&mut self, vars: &[VarInfo], out: &mut Vec<TransitionParts>) -> bool {
        let chart = self.chart;
        let mut names: HashMap<String, Span> = HashMap::new();
        let mut net_ok = true;
        for t in &chart.transitions {
            if let Some(name) = &t.name {
                if names.insert(name.key(), name.span).is_some() {
                    self.error(name.span, format!("transition `{}` is declared twice", name.name));
                }
            }
            let sources = self.step_list(&t.from);
            let targets = self.step_list(&t.to);
            let outer = std::mem::take(&mut self.hoisted);
            let (condition, ty) = bool_literal(self.expr(&t.condition, vars));
            let hoisted = std::mem::replace(&mut self.hoisted, outer);
            if ty != Ty::Bool && ty != Ty::Err {
                self.error(t.condition.span, format!("a transition condition must be BOOL, found {}", ty.name()));
            } else if ty == Ty::Bool
                && is_constant(&condition)
                && eval(&condition, &NoEnv) == Ok(Value::Bool(false))
                && !self.chart.broken.conditions.contains(&t.condition.span)
            {
                let name = t.display_name();
                self.diags.push(Diagnostic::warning(
                    t.condition.span,
                    format!("transition `{name}` can never clear: its condition is always FALSE"),
                ));
            }
            let (Some(sources), Some(targets)) = (sources, targets) else {
                net_ok = false;
                continue;
            };
            // The function calls in the condition run when it is judged.
            let calls = hoisted;
            let depth = crate::exec::program::condition_depth(&calls, &condition, &mut self.depth_memo);
            if depth > NESTING_DEPTH_MAX {
                self.too_deep(t.condition.span, &format!("the condition of transition `{}`", t.display_name()), depth);
            }
            let info = TransitionInfo { name: t.display_name(), condition, pragmas: t.pragmas.clone() };
            out.push(TransitionParts { info, calls, sources, targets, rank: 0 });
        }
        // Clearing order: explicit priorities first, lower number first, then declaration order.
        if net_ok {
            let mut order: Vec<usize> = (0..out.len()).collect();
            order.sort_by_key(|&i| match chart.transitions[i].priority {
                Some((p, _)) => (0, p, i),
                None => (1, 0, i),
            });
            for (rank, i) in order.into_iter().enumerate() {
                out[i].rank = rank as u32;
            }
        }
        net_ok
    }

    /// `{min_ms := T#200ms}` (or `200`) after `STEP name:`: the step's minimum time, as S7-GRAPH and CODESYS
    /// supervise it — before it, no transition out of the step clears; `{max_ms := T#5s}` its maximum time, past
    /// which it is faulted. 0 without it.
    pub(super) fn supervision_of(&mut self, step: &Step, key: &str) -> u64 {
        let mut min_ms = 0;
        for pragma in &step.pragmas {
            let crate::front::pragma::Pragma::Pairs(pairs) = crate::front::pragma::read(&pragma.text) else {
                continue;
            };
            for (_, value) in pairs.iter().filter(|(k, _)| k == key) {
                match value.as_f64() {
                    Some(ms) if ms.fract() == 0.0 && (0.0..=SUPERVISION_MS_MAX as f64).contains(&ms) => {
                        min_ms = ms as u64;
                    }
                    _ => self.error(
                        pragma.span,
                        format!(
                            "`{key}` of step `{}` needs a duration or whole milliseconds, at most a year, such as \
                             `{key} := T#200ms`",
                            step.name.name
                        ),
                    ),
                }
            }
        }
        min_ms
    }
}
