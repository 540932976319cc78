//! Charts nested in a POU's actions (actions written in SFC), the chart's and its function blocks' alike, lowered
//! to `CStmt::Chart`s.
//!
//! Nested charts: an action written in SFC gets its state as variables (`declare_nested`: `started`, each step's `X`,
//! `since`, `last`, the `Q` and `stored` of each action it controls), one set per POU — per instance for a function
//! block's, so that two instances of a block run their charts apart. Its body becomes one `CStmt::Chart(NestedChart)`:
//! the chart's own (`nested_charts`, the charts it controls first, so that each carries its controlled actions'
//! compiled bodies; a cycle is an error), a block's as the instance's action is first compiled (`block_chart`, where
//! a cycle is an action calling itself). `S.X` of a nested step is its variable, `S.T` a `CExpr::NestedT`; a name
//! that charts of several actions have is `Action.S.X` outside them. Where the action is associated with a step,
//! the chart carries that action's Q (`with_q`), and the action's final run resets it; `eval::scan` runs one scan;
//! `walk_body` reports every variable it may write, so the layout sees the chart's state as written where its action
//! runs.

use std::collections::HashMap;
use std::sync::Arc;

use crate::exec::compile::typing::{bool_literal, Ty};
use crate::exec::program::{
    ActionId, ActionInfo, CExpr, CStmt, DurationSrc, NestedAction, NestedChart, NestedStep, NestedTransition, VarId,
    VarInfo,
};
use crate::front::model::{Action, Association, Ident, Qualifier, Sfc, SfcFlags, Step, VarSection};
use crate::limits::NESTING_DEPTH_MAX;
use crate::types::Type;

use super::Compiler;

/// A nested chart's body, where its action is associated with a step: the chart's Q is that association's, so that
/// the action's final run resets it. A body that is a call of an instance's action written in SFC (`inst.A`) gets it
/// too; any other is the body itself (`None`), shared where it was.
pub(super) fn with_q(body: &[CStmt], q: CExpr) -> Option<Vec<CStmt>> {
    match body {
        [CStmt::Chart(chart)] => {
            let mut chart = chart.clone();
            chart.q = Some(q);
            Some(vec![CStmt::Chart(chart)])
        }
        [CStmt::UserFb(call)] => {
            let mut call = call.clone();
            call.body = Arc::new(with_q(&call.body, q)?);
            Some(vec![CStmt::UserFb(call)])
        }
        _ => None,
    }
}

/// What a nested chart's association runs: a boolean action's variable, or a body.
pub(super) enum Targets<'x> {
    /// The chart's actions, by id.
    Chart(&'x mut Vec<ActionInfo>),
    /// Instance `u`'s block's actions, BOOL variables and its instances' actions.
    Block(usize),
}

impl<'a> Compiler<'a> {
    /// The state of every nested chart of a POU as variables, `prefix` before their names (a user instance's
    /// path and a dot; nothing for the chart's): `started`, each step's `X`, `since` and `last`, and the `Q` and
    /// `stored` of each action it controls (`X` and `Q` can be watched, the rest is hidden). A nested step may not
    /// have the name of a step of the POU's own chart, nor two of one chart one name; the charts of two actions
    /// may (CODESYS), and are then told apart as `Action.S`.
    pub(super) fn declare_nested(
        &mut self,
        charts: &[(&'a Ident, &'a Sfc)],
        prefix: &str,
        pou_steps: &[Step],
        vars: &mut Vec<VarInfo>,
    ) {
        let add = |vars: &mut Vec<VarInfo>, name: String, ty: Type, hidden: bool| {
            let id = VarId(vars.len() as u32);
            let init = ty.default_value();
            vars.push(VarInfo { name, ty, init, constant: false, section: VarSection::Local, hidden });
            id
        };
        let mut bare: HashMap<String, ([VarId; 3], Vec<String>)> = HashMap::new();
        for &(name, sfc) in charts {
            let parent = name.key();
            if self.nested.started.contains_key(&parent) {
                continue; // an action declared twice, reported with the actions
            }
            let started = add(vars, format!("{prefix}{}.started", name.name), Type::Bool, true);
            self.nested.started.insert(parent.clone(), started);
            for step in &sfc.steps {
                let key = step.name.key();
                let own = format!("{parent}.{key}");
                if self.nested.steps.contains_key(&own) || pou_steps.iter().any(|s| s.name.key() == key) {
                    self.error(step.name.span, format!("step `{}` is declared twice", step.name.name));
                    continue;
                }
                let base = format!("{prefix}{}.{}", name.name, step.name.name);
                let x = add(vars, format!("{base}.X"), Type::Bool, false);
                let since = add(vars, format!("{base}.since"), Type::Time, true);
                let last = add(vars, format!("{base}.last"), Type::Time, true);
                self.nested.steps.insert(own, [x, since, last]);
                let entry = bare.entry(key).or_insert(([x, since, last], Vec::new()));
                entry.1.push(name.name.clone());
            }
            for a in sfc.steps.iter().flat_map(|s| &s.associations) {
                let key = a.action.key();
                if key == parent || self.nested.controlled.contains_key(&(parent.clone(), key.clone())) {
                    continue; // itself: reported when the chart is compiled
                }
                let base = format!("{prefix}{}.{}", name.name, a.action.name);
                let q = add(vars, format!("{base}.Q"), Type::Bool, false);
                let stored = add(vars, format!("{base}.stored"), Type::Bool, true);
                self.nested.controlled.insert((parent.clone(), key.clone()), (q, stored));
                self.nested.controllers.entry(key).or_default().push(name.name.clone());
            }
        }
        for (key, (ids, owners)) in bare {
            if owners.len() == 1 {
                self.nested.steps.insert(key, ids);
            } else {
                self.nested.shared.insert(key, owners);
            }
        }
    }

    /// Compiles every nested chart of the chart into its action's body (`CStmt::Chart`), those it controls first,
    /// so that a chart's controlled actions carry their own compiled bodies; a chart that controls itself, directly
    /// or through others, is an error. An action associated with one of the chart's steps is not also controlled
    /// by a nested chart: CODESYS refuses one action on two levels.
    pub(super) fn nested_charts(
        &mut self,
        sources: &[&'a Action],
        parent_steps: &[&'a Step],
        vars: &[VarInfo],
        actions: &mut Vec<ActionInfo>,
    ) {
        for step in parent_steps {
            for a in &step.associations {
                if let Some(owner) = self.nested.controllers.get(&a.action.key()).and_then(|o| o.first()) {
                    let message = format!(
                        "action `{}` is controlled by the chart of action `{owner}`, and so cannot be associated with \
                         step `{}` too: an action runs on one level",
                        a.action.name, step.name.name
                    );
                    self.error(a.action.span, message);
                }
            }
        }
        // Charts in an order where each comes after those it controls (Kahn's, linear in the charts and their
        // associations), so that a chart's controlled actions carry their compiled bodies; each chart is as deep
        // as the deepest it controls plus one, bounded like any nesting.
        let charts: Vec<(usize, &'a Action)> =
            sources.iter().enumerate().filter(|(_, a)| a.sfc.is_some()).map(|(i, a)| (i, *a)).collect();
        let index: HashMap<String, usize> = charts.iter().enumerate().map(|(k, (_, a))| (a.name.key(), k)).collect();
        let mut children: Vec<Vec<usize>> = vec![Vec::new(); charts.len()];
        let mut parents: Vec<Vec<usize>> = vec![Vec::new(); charts.len()];
        for (k, (_, a)) in charts.iter().enumerate() {
            let sfc = a.sfc.as_ref().expect("a nested chart");
            for assoc in sfc.steps.iter().flat_map(|s| &s.associations) {
                if let Some(&c) = index.get(&assoc.action.key()).filter(|&&c| c != k) {
                    if !children[k].contains(&c) {
                        children[k].push(c);
                        parents[c].push(k);
                    }
                }
            }
        }
        let mut waiting: Vec<usize> = children.iter().map(Vec::len).collect();
        let mut ready: std::collections::VecDeque<usize> = (0..charts.len()).filter(|&k| waiting[k] == 0).collect();
        let mut depth = vec![0usize; charts.len()];
        let mut done = vec![false; charts.len()];
        while let Some(k) = ready.pop_front() {
            done[k] = true;
            let (id, action) = charts[k];
            depth[k] = 1 + children[k].iter().map(|&c| depth[c]).max().unwrap_or(0);
            if depth[k] > NESTING_DEPTH_MAX {
                // Said once, of the chart where the nesting goes past the limit, not of every chart around it.
                if depth[k] > NESTING_DEPTH_MAX + 1 {
                    continue_parents(&parents[k], &mut waiting, &mut ready);
                    continue;
                }
                let message = format!(
                    "the chart of action `{}` holds charts nested more than {NESTING_DEPTH_MAX} levels deep",
                    action.name.name
                );
                self.error(action.name.span, message);
            } else if let Some(sfc) = &action.sfc {
                if let Some(mut chart) = self.nested_chart(&action.name, sfc, vars, &mut Targets::Chart(actions)) {
                    // Where a step of the chart runs it, its final run resets it.
                    chart.q = Some(CExpr::ActionQ(ActionId(id as u32)));
                    actions[id].body = vec![CStmt::Chart(Box::new(chart))];
                }
            }
            continue_parents(&parents[k], &mut waiting, &mut ready);
        }
        fn continue_parents(parents: &[usize], waiting: &mut [usize], ready: &mut std::collections::VecDeque<usize>) {
            for &p in parents {
                waiting[p] -= 1;
                if waiting[p] == 0 {
                    ready.push_back(p);
                }
            }
        }
        // What is left controls itself, through the actions it names: each is still compiled, for its other
        // errors, but runs nothing.
        for (k, &(_, a)) in charts.iter().enumerate().filter(|(k, _)| !done[*k]) {
            let _ = k;
            let message = format!(
                "the chart of action `{}` controls itself, through the actions it names: nested charts must form a tree",
                a.name.name
            );
            self.error(a.name.span, message);
            if let Some(sfc) = &a.sfc {
                self.nested_chart(&a.name, sfc, vars, &mut Targets::Chart(actions));
            }
        }
    }

    /// The chart of action `name` of user instance `u` (the current scope), compiled the first time it is needed:
    /// a call scans it, a step's association gives it its Q. A chart that runs itself, directly or through
    /// others, is an action calling itself (`within_action`, as for an action in ST).
    pub(super) fn block_chart(
        &mut self,
        u: usize,
        name: &Ident,
        sfc: &Sfc,
        vars: &[VarInfo],
    ) -> Option<Arc<Vec<CStmt>>> {
        let key = format!("{}#{}", self.users[u].def.name.key(), name.key());
        let chart = self.within_action(&key, name, |c| c.nested_chart(name, sfc, vars, &mut Targets::Block(u)))??;
        Some(Arc::new(vec![CStmt::Chart(Box::new(chart))]))
    }

    /// What an association in a nested chart runs: (the boolean action's variable, the body).
    fn target(
        &mut self,
        a: &Association,
        vars: &[VarInfo],
        targets: &mut Targets,
    ) -> Option<(Option<VarId>, Arc<Vec<CStmt>>)> {
        let u = match targets {
            Targets::Chart(actions) => {
                let id = self.action_for(a, vars, actions)?;
                let info = &actions[id.index()];
                return Some((info.bool_var, Arc::new(info.body.clone())));
            }
            Targets::Block(u) => *u,
        };
        let def = self.users[u].def;
        if def.actions.iter().any(|x| x.name.key() == a.action.key()) {
            return Some((None, self.fb_action_body(u, &a.action, vars)?));
        }
        if let Some((instance, action)) = a.action.name.rsplit_once('.') {
            let call = self.instance_action_call(&a.action, instance, action, &[], vars)?;
            return Some((None, Arc::new(vec![call])));
        }
        match self.vars.get(&a.action.key()) {
            Some(&v) if vars[v.index()].ty == Type::Bool => Some((Some(v), Arc::new(Vec::new()))),
            Some(&v) => {
                let message = format!(
                    "`{}` is no action of `{}` and is a {} variable: a boolean action needs a BOOL variable",
                    a.action.name,
                    def.name.name,
                    vars[v.index()].ty
                );
                self.error(a.action.span, message);
                None
            }
            None => {
                let names = def.actions.iter().map(|x| x.name.name.as_str());
                let hint = crate::front::pragma::did_you_mean(&a.action.name, names);
                let message = format!(
                    "unknown action `{}`{hint}: function block `{}` has no action or BOOL variable of that name",
                    a.action.name, def.name.name
                );
                self.error(a.action.span, message);
                None
            }
        }
    }

    pub(super) fn nested_chart(
        &mut self,
        name: &Ident,
        sfc: &Sfc,
        vars: &[VarInfo],
        targets: &mut Targets,
    ) -> Option<NestedChart> {
        let parent = name.key();
        let started = *self.nested.started.get(&parent)?;
        let outer = self.nested.current.replace(parent.clone());
        let chart = self.nested_chart_in(name, sfc, started, vars, targets);
        self.nested.current = outer;
        chart
    }

    fn nested_chart_in(
        &mut self,
        name: &Ident,
        sfc: &Sfc,
        started: VarId,
        vars: &[VarInfo],
        targets: &mut Targets,
    ) -> Option<NestedChart> {
        let parent = name.key();
        let index: HashMap<String, usize> = sfc.steps.iter().enumerate().map(|(i, s)| (s.name.key(), i)).collect();
        let mut steps = Vec::with_capacity(sfc.steps.len());
        for s in &sfc.steps {
            let [x, since, last] = *self.nested.steps.get(&format!("{parent}.{}", s.name.key()))?;
            steps.push(NestedStep { initial: s.initial, x, since, last });
        }
        if !sfc.steps.iter().any(|s| s.initial) {
            let message =
                format!("the chart of action `{}` has no initial step: declare one with `INITIAL_STEP`", name.name);
            self.error(name.span, message);
        }
        let list = |c: &mut Self, names: &[Ident]| -> Option<Vec<usize>> {
            let mut out = Vec::with_capacity(names.len());
            for n in names {
                match index.get(&n.key()) {
                    Some(&i) if !out.contains(&i) => out.push(i),
                    Some(_) => c.error(n.span, format!("step `{}` appears twice in this list", n.name)),
                    None => {
                        let message = format!("unknown step `{}` in the chart of action `{}`", n.name, name.name);
                        c.error(n.span, message);
                        return None;
                    }
                }
            }
            Some(out)
        };
        let mut transitions = Vec::with_capacity(sfc.transitions.len());
        for (i, t) in sfc.transitions.iter().enumerate() {
            let (sources, targets) = (list(self, &t.from), list(self, &t.to));
            let outer = std::mem::take(&mut self.hoisted);
            let (condition, ty) = bool_literal(self.expr(&t.condition, vars));
            let hoisted = std::mem::replace(&mut self.hoisted, outer);
            if ty != Ty::Bool && ty != Ty::Err {
                self.error(t.condition.span, format!("a transition condition must be BOOL, found {}", ty.name()));
            }
            let calls = hoisted;
            let rank = match t.priority {
                Some((p, _)) => (0, p, i),
                None => (1, 0, i),
            };
            if let (Some(sources), Some(targets)) = (sources, targets) {
                transitions.push((rank, NestedTransition { sources, targets, calls, condition }));
            }
        }
        // Clearing order: explicit priorities first, lower number first, then declaration order.
        transitions.sort_by_key(|(rank, _)| *rank);
        let controlled = self.nested_actions(name, sfc, vars, targets);
        // CODESYS's SFC flags, where the POU declares them as BOOLs and the chart uses them.
        let flags = sfc
            .flags
            .unwrap_or(SfcFlags { init: self.vars.contains_key("SFCINIT"), reset: self.vars.contains_key("SFCRESET") });
        let flag = |c: &Self, used: bool, key: &str| {
            c.vars.get(key).copied().filter(|v| used && vars.get(v.index()).is_some_and(|v| v.ty == Type::Bool))
        };
        Some(NestedChart {
            started,
            q: None,
            init: flag(self, flags.init, "SFCINIT"),
            reset: flag(self, flags.reset, "SFCRESET"),
            steps,
            transitions: transitions.into_iter().map(|(_, t)| t).collect(),
            actions: controlled,
        })
    }

    /// The actions a nested chart's steps control, with their associations, checked (SD, DS and SL, indicators
    /// and the chart's own action refused).
    fn nested_actions(
        &mut self,
        name: &Ident,
        sfc: &Sfc,
        vars: &[VarInfo],
        targets: &mut Targets,
    ) -> Vec<NestedAction> {
        let parent = name.key();
        let mut controlled: Vec<NestedAction> = Vec::new();
        let mut of_action: HashMap<String, usize> = HashMap::new();
        for (si, s) in sfc.steps.iter().enumerate() {
            for a in &s.associations {
                if matches!(a.qualifier, Qualifier::SD | Qualifier::DS | Qualifier::SL) {
                    let message = format!(
                        "qualifier {:?} in the chart of action `{}` is not supported: a nested chart takes N, S, R, P, \
                         P0, P1, L and D",
                        a.qualifier, name.name
                    );
                    self.error(a.qualifier_span, message);
                    continue;
                }
                if let Some(ind) = a.indicators.first() {
                    let message =
                        format!("indicator variables in the chart of action `{}` are not supported", name.name);
                    self.error(ind.span, message);
                }
                if a.action.key() == parent {
                    let message = format!("the chart of action `{}` cannot control that action itself", name.name);
                    self.error(a.action.span, message);
                    continue;
                }
                let key = a.action.key();
                let k = match of_action.get(&key) {
                    Some(&k) => k,
                    None => {
                        let Some((bool_var, body)) = self.target(a, vars, targets) else { continue };
                        let Some(&(q, stored)) = self.nested.controlled.get(&(parent.clone(), key.clone())) else {
                            continue;
                        };
                        // A chart it holds is reset by this association's end.
                        let body = with_q(&body, CExpr::Var(q)).map_or(body, Arc::new);
                        // Whether it has a final run follows from all its associations, below.
                        let final_run = true;
                        controlled.push(NestedAction {
                            q,
                            stored,
                            bool_var,
                            body,
                            final_run,
                            associations: Vec::new(),
                        });
                        of_action.insert(key, controlled.len() - 1);
                        controlled.len() - 1
                    }
                };
                let duration = self.duration(a, vars);
                controlled[k].associations.push((si, a.qualifier, duration));
            }
        }
        // CODESYS's step actions (main, entry, exit) have no final run; an action with any other association has.
        for a in &mut controlled {
            let step_action = |&(_, q, _): &(usize, Qualifier, Option<DurationSrc>)| {
                matches!(q, Qualifier::Active | Qualifier::Entry | Qualifier::Exit)
            };
            a.final_run = !a.associations.iter().all(step_action);
        }
        controlled
    }
}
