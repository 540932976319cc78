//! Charts nested in a chart's function blocks: their steps, transitions and actions, lowered to the program's nested
//! charts.
//!
//! Nested charts: an action written in SFC gets its state as variables (`declare_nested`: `started`, each step's `X`,
//! `since`, `last`, each controlled action's `Q` and `stored`), and its body becomes one `CStmt::Chart(NestedChart)`
//! (`nested_charts`, the charts it controls first, so that each carries its controlled actions' compiled bodies; a
//! cycle is an error). `S.X` of a nested step is its variable, `S.T` a `CExpr::NestedT`. `eval::scan` runs one scan;
//! `walk_body` reports every variable it may write, so the layout sees the chart's state as written where its action
//! runs.

use super::*;

impl<'a> Compiler<'a> {
    /// The state of every nested chart (an action written in SFC) as variables: `started`, each step's `X`,
    /// `since` and `last`, and the `Q` and `stored` of each action it controls (`X` and `Q` can be watched, the rest
    /// is hidden). A nested step's name is one of the POU's, as CODESYS has it: two steps of one name are an error
    /// wherever they are.
    pub(super) fn declare_nested(&mut self, vars: &mut Vec<VarInfo>) {
        let chart = self.chart;
        let add = |vars: &mut Vec<VarInfo>, name: String, ty: Type, hidden: bool| {
            let id = VarId(vars.len() as u32);
            let init = ty.default_value();
            vars.push(VarInfo { name, ty, init, constant: false, section: VarSection::Local, hidden });
            id
        };
        for action in &chart.actions {
            let Some(sfc) = &action.sfc else { continue };
            let parent = action.name.key();
            if self.started.contains_key(&parent) {
                continue; // an action declared twice, reported with the actions
            }
            let started = add(vars, format!("{}.started", action.name.name), Type::Bool, true);
            self.started.insert(parent.clone(), started);
            for step in &sfc.steps {
                let key = step.name.key();
                if self.nested_steps.contains_key(&key) || chart.steps.iter().any(|s| s.name.key() == key) {
                    self.error(step.name.span, format!("step `{}` is declared twice", step.name.name));
                    continue;
                }
                let base = format!("{}.{}", action.name.name, step.name.name);
                let x = add(vars, format!("{base}.X"), Type::Bool, false);
                let since = add(vars, format!("{base}.since"), Type::Time, true);
                let last = add(vars, format!("{base}.last"), Type::Time, true);
                self.nested_steps.insert(key, [x, since, last]);
            }
            for a in sfc.steps.iter().flat_map(|s| &s.associations) {
                let key = a.action.key();
                if key == parent {
                    continue; // reported when the chart is compiled
                }
                match self.controlled.get(&key) {
                    Some((other, _, _)) if *other != parent => {
                        let message = format!(
                            "action `{}` is controlled by the chart of action `{other}` already: an action has one chart",
                            a.action.name
                        );
                        self.error(a.action.span, message);
                    }
                    Some(_) => {}
                    None => {
                        let base = format!("{}.{}", action.name.name, a.action.name);
                        let q = add(vars, format!("{base}.Q"), Type::Bool, false);
                        let stored = add(vars, format!("{base}.stored"), Type::Bool, true);
                        self.controlled.insert(key, (parent.clone(), q, stored));
                    }
                }
            }
        }
    }

    /// Compiles every nested chart into its action's body (`CStmt::Chart`), those it controls first, so that a
    /// chart's controlled actions carry their own compiled bodies; a chart that controls itself, directly or
    /// through others, is an error.
    pub(super) fn nested_charts(
        &mut self,
        sources: &[&'a Action],
        parent_steps: &[&'a Step],
        vars: &[VarInfo],
        actions: &mut Vec<ActionInfo>,
    ) {
        for step in parent_steps {
            for a in &step.associations {
                if let Some((owner, _, _)) = self.controlled.get(&a.action.key()) {
                    let message = format!(
                        "action `{}` is controlled by the chart of action `{owner}`, and so cannot be associated with \
                         step `{}` too: an action has one chart",
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
            } else if let Some(chart) = self.nested_chart(action, vars, actions) {
                actions[id].body = vec![CStmt::Chart(Box::new(chart))];
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
            self.nested_chart(a, vars, actions);
        }
    }

    pub(super) fn nested_chart(
        &mut self,
        action: &Action,
        vars: &[VarInfo],
        actions: &mut Vec<ActionInfo>,
    ) -> Option<NestedChart> {
        let sfc = action.sfc.as_ref()?;
        let parent = action.name.key();
        let started = *self.started.get(&parent)?;
        let index: HashMap<String, usize> = sfc.steps.iter().enumerate().map(|(i, s)| (s.name.key(), i)).collect();
        let mut steps = Vec::with_capacity(sfc.steps.len());
        for s in &sfc.steps {
            let [x, since, last] = *self.nested_steps.get(&s.name.key())?;
            steps.push(NestedStep { initial: s.initial, x, since, last });
        }
        if !sfc.steps.iter().any(|s| s.initial) {
            let message = format!(
                "the chart of action `{}` has no initial step: declare one with `INITIAL_STEP`",
                action.name.name
            );
            self.error(action.name.span, message);
        }
        let list = |c: &mut Self, names: &[Ident]| -> Option<Vec<usize>> {
            let mut out = Vec::with_capacity(names.len());
            for n in names {
                match index.get(&n.key()) {
                    Some(&i) if !out.contains(&i) => out.push(i),
                    Some(_) => c.error(n.span, format!("step `{}` appears twice in this list", n.name)),
                    None => {
                        let message =
                            format!("unknown step `{}` in the chart of action `{}`", n.name, action.name.name);
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
        let mut controlled: Vec<NestedAction> = Vec::new();
        let mut of_action: HashMap<ActionId, usize> = HashMap::new();
        for (si, s) in sfc.steps.iter().enumerate() {
            for a in &s.associations {
                if matches!(a.qualifier, Qualifier::SD | Qualifier::DS | Qualifier::SL) {
                    let message = format!(
                        "qualifier {:?} in the chart of action `{}` is not supported: a nested chart takes N, S, R, P, \
                         P0, P1, L and D",
                        a.qualifier, action.name.name
                    );
                    self.error(a.qualifier_span, message);
                    continue;
                }
                if let Some(ind) = a.indicators.first() {
                    let message =
                        format!("indicator variables in the chart of action `{}` are not supported", action.name.name);
                    self.error(ind.span, message);
                }
                if a.action.key() == parent {
                    self.error(
                        a.action.span,
                        format!("the chart of action `{}` cannot control that action itself", action.name.name),
                    );
                    continue;
                }
                let Some(id) = self.action_for(a, vars, actions) else { continue };
                let duration = self.duration(a, vars);
                let Some(&(_, q, stored)) = self.controlled.get(&a.action.key()) else { continue };
                let k = *of_action.entry(id).or_insert_with(|| {
                    let info = &actions[id.index()];
                    controlled.push(NestedAction {
                        q,
                        stored,
                        bool_var: info.bool_var,
                        body: Arc::new(info.body.clone()),
                        associations: Vec::new(),
                    });
                    controlled.len() - 1
                });
                controlled[k].associations.push((si, a.qualifier, duration));
            }
        }
        Some(NestedChart {
            started,
            steps,
            transitions: transitions.into_iter().map(|(_, t)| t).collect(),
            actions: controlled,
        })
    }
}
