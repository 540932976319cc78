//! The net's reconstruction: an SFC body's elements, and each transition's source and target steps, walked back and
//! forward through divergences, convergences, macro steps and jumps.

use std::collections::{HashMap, HashSet};

use roxmltree::Node;

use crate::front::diag::Span;
use crate::front::model::{
    Action, Association, Broken, Chart, Expr, ExprKind, Ident, MacroStep, Qualifier, Step, Stmt, Transition,
};
use crate::front::plcopen::xml::{child, children, flag, is, local_id};
use crate::limits::{NESTING_DEPTH_MAX, XML_CONNECTIONS_WALKED_MAX};

use super::{
    Elements, ReadTransition, Reader, CODESYS_ACTIVE_ACTION, CODESYS_ENTRY_ACTION, CODESYS_EXIT_ACTION,
    CODESYS_SFC_ELEMENT, COMPUTE_BLOCKS,
};

impl Reader<'_> {
    /// A body's elements by `localId`; `structural` names the kinds whose inputs are SFC arcs, for `consumers`.
    pub(super) fn elements<'a, 'i>(&mut self, body: Node<'a, 'i>, structural: &[&str]) -> Elements<'a, 'i> {
        let mut by_id = HashMap::new();
        let mut consumers: HashMap<u64, Vec<u64>> = HashMap::new();
        let mut index = HashMap::new();
        let mut connectors = HashMap::new();
        for (i, el) in body.children().filter(Node::is_element).enumerate() {
            let kind = el.tag_name().name();
            if kind == "connector" {
                if let Some(name) = el.attribute("name") {
                    connectors.entry(name.trim().to_ascii_uppercase()).or_insert(el);
                }
            }
            let Some(raw) = el.attribute("localId") else {
                if !matches!(kind, "comment" | "addData" | "documentation") {
                    self.error(self.tag_span(el), format!("`<{kind}>` has no `localId`"));
                }
                continue;
            };
            let Ok(id) = raw.trim().parse::<u64>() else {
                self.error(self.attr_span(el, "localId"), format!("`localId` `{raw}` is not a number"));
                continue;
            };
            match by_id.entry(id) {
                std::collections::hash_map::Entry::Occupied(_) => {
                    let message = format!("duplicate `localId` {id}: two elements have it");
                    self.error(self.attr_span(el, "localId"), message);
                    continue;
                }
                std::collections::hash_map::Entry::Vacant(slot) => slot.insert(el),
            };
            index.insert(id, i);
        }
        // Arcs of the chart, checked once all ids are known.
        for el in body.children().filter(|n| structural.contains(&n.tag_name().name())) {
            let id = local_id(el);
            for (from, _, at) in self.connections(el) {
                if by_id.contains_key(&from) {
                    if let Some(id) = id {
                        consumers.entry(from).or_default().push(id);
                    }
                } else {
                    self.dangling(at, from);
                }
            }
        }
        Elements { by_id, connectors, consumers, index }
    }

    /// The connections into an element: `connectionPointIn/connection` (and v1.0's bare `connection`), as
    /// (source id, formal parameter, span).
    pub(super) fn connections(&mut self, n: Node) -> Vec<(u64, Option<String>, Span)> {
        let points = children(n, "connectionPointIn").flat_map(|p| children(p, "connection"));
        let bare = children(n, "connection");
        let mut out = Vec::new();
        for c in points.chain(bare).collect::<Vec<_>>() {
            match c.attribute("refLocalId").map(|r| r.trim().parse::<u64>()) {
                Some(Ok(id)) => out.push((id, c.attribute("formalParameter").map(str::to_string), self.tag_span(c))),
                Some(Err(_)) => self.error(self.attr_span(c, "refLocalId"), "`refLocalId` is not a number"),
                None => self.error(self.tag_span(c), "`<connection>` has no `refLocalId`"),
            }
        }
        out
    }

    /// Reads the SFC body into the chart; returns each transition's `localId`, in the chart's order.
    pub(super) fn sfc(
        &mut self,
        sfc: Node,
        named_transitions: &HashMap<String, Node>,
        chart: &mut Chart,
    ) -> Vec<Option<u64>> {
        const STRUCTURAL: [&str; 8] = [
            "step",
            "macroStep",
            "jumpStep",
            "transition",
            "selectionDivergence",
            "selectionConvergence",
            "simultaneousDivergence",
            "simultaneousConvergence",
        ];
        let elements = self.elements(sfc, &STRUCTURAL);
        self.references.clear();
        for t in children(sfc, "transition") {
            if let Some(name) =
                child(t, "condition").and_then(|c| child(c, "reference")).and_then(|r| r.attribute("name"))
            {
                *self.references.entry(name.trim().to_ascii_uppercase()).or_default() += 1;
            }
        }
        // Macro steps first: the steps and transitions of each one's body join the chart, and the macro step
        // stands for the body's entry step where a transition leads to it and its exit step where one leaves it.
        let mut macros = HashMap::new();
        let mut macro_names = HashMap::new();
        let mut macro_transitions = Vec::new();
        for el in children(sfc, "macroStep") {
            let span = self.tag_span(el);
            let Some(body) = child(el, "body").and_then(|b| child(b, "SFC")) else {
                self.error(span, "a macro step without an SFC `<body>`: Baton expands a macro step's body in place");
                match el.attribute("name") {
                    Some(n) => chart.broken.steps.push(n.to_ascii_uppercase()),
                    None => chart.broken.unnamed_step = true,
                }
                continue;
            };
            if self.macro_depth >= NESTING_DEPTH_MAX {
                self.error(span, format!("macro steps nested more than {NESTING_DEPTH_MAX} levels deep"));
                continue;
            }
            let references = std::mem::take(&mut self.references);
            let mut inner = Chart::empty(chart.name.clone(), chart.kind, span);
            self.macro_depth += 1;
            self.sfc(body, named_transitions, &mut inner);
            self.macro_depth -= 1;
            self.references = references;
            let Some((entry, exit)) = self.macro_ends(&mut inner, span) else { continue };
            if let Some(id) = local_id(el) {
                macros.insert(id, (entry.clone(), exit));
            }
            if let Some(name) = el.attribute("name").map(str::trim).filter(|n| !n.is_empty()) {
                macro_names.insert(name.to_ascii_uppercase(), entry.clone());
                let steps = inner.steps.iter().map(|s| s.name.clone()).collect();
                let name = Ident { name: name.to_string(), span };
                chart.macros.push(MacroStep { name, steps, entry });
            }
            chart.macros.append(&mut inner.macros);
            chart.steps.append(&mut inner.steps);
            chart.actions.append(&mut inner.actions);
            chart.broken.steps.append(&mut inner.broken.steps);
            chart.broken.actions.append(&mut inner.broken.actions);
            macro_transitions.append(&mut inner.transitions);
        }
        self.macros = macros;
        self.macro_names = macro_names;
        let mut step_of_id: HashMap<u64, usize> = HashMap::new();
        let mut transitions = Vec::new();
        let mut inline_count = 0;
        let mut pending_blocks = Vec::new();
        for (i, el) in sfc.children().filter(Node::is_element).enumerate() {
            match el.tag_name().name() {
                "step" => {
                    let Some(name) = self.ident_attr(el, "name") else {
                        chart.broken.unnamed_step = true;
                        continue;
                    };
                    if let Some(id) = local_id(el) {
                        step_of_id.insert(id, chart.steps.len());
                    }
                    let mut step = Step {
                        name,
                        initial: flag(el, "initialStep"),
                        associations: Vec::new(),
                        pragmas: self.documentation_pragmas(el),
                        span: self.tag_span(el),
                    };
                    self.codesys_step_actions(el, &mut step);
                    chart.steps.push(step);
                }
                "transition" => {
                    if let Some(t) = self.transition(el, i, &elements, named_transitions, &mut chart.broken) {
                        transitions.push(t);
                    }
                }
                "actionBlock" => pending_blocks.push(el),
                _ => {}
            }
        }
        for block in pending_blocks {
            self.action_block(block, &elements, &step_of_id, &mut inline_count, chart);
        }
        transitions.sort_by(|a, b| {
            a.order.0.cmp(&b.order.0).then(a.order.1.total_cmp(&b.order.1)).then(a.order.2.cmp(&b.order.2))
        });
        let mut ids: Vec<Option<u64>> = transitions.iter().map(|t| t.local_id).collect();
        chart.transitions = transitions.into_iter().map(|t| t.transition).collect();
        // A macro body's transitions have ids of their own body: they take no part in Baton's order data.
        ids.extend(macro_transitions.iter().map(|_| None));
        chart.transitions.append(&mut macro_transitions);
        ids
    }

    /// The blocks (and edge contacts) wired into the POU's conditions, as Beremiz compiles them for matiec and so
    /// as OpenPLC runs them: every call once (an instance read by several conditions too), in an action
    /// `COMPUTE_FUNCTION_BLOCKS` held stored (S) by the first initial step, so that they run every cycle, after
    /// the transitions are judged, whichever step is active; a condition reads what they computed in the cycle
    /// before.
    pub(super) fn compute_blocks(&mut self, chart: &mut Chart) {
        let calls = std::mem::take(&mut self.condition_calls);
        let mut seen = HashSet::new();
        let body: Vec<Stmt> = calls
            .into_iter()
            .filter(|c| match c {
                Stmt::Call { callee, .. } => seen.insert(callee.key()),
                _ => true,
            })
            .collect();
        if body.is_empty() {
            return;
        }
        let Some(step) = chart.steps.iter_mut().find(|s| s.initial) else { return };
        let name = Ident { name: COMPUTE_BLOCKS.to_string(), span: step.span };
        step.associations.push(Association::stored(name.clone(), step.span));
        chart.actions.push(Action { name, body, sfc: None, pragmas: Vec::new(), span: step.span });
    }

    /// A macro step's entry step (its body's initial step, or else the one no transition of the body leads to)
    /// and its exit step (the one no transition of the body leaves); the entry step stops being initial.
    pub(super) fn macro_ends(&mut self, inner: &mut Chart, span: Span) -> Option<(Ident, Ident)> {
        // The names transitions lead to and leave, gathered once: linear in the body, not steps × transitions.
        let targets: HashSet<String> = inner.transitions.iter().flat_map(|t| t.to.iter().map(Ident::key)).collect();
        let sources: HashSet<String> = inner.transitions.iter().flat_map(|t| t.from.iter().map(Ident::key)).collect();
        let led_to = |s: &Step| targets.contains(&s.name.key());
        let left = |s: &Step| sources.contains(&s.name.key());
        let entries: Vec<usize> = match inner.steps.iter().filter(|s| s.initial).count() {
            0 => (0..inner.steps.len()).filter(|&i| !led_to(&inner.steps[i])).collect(),
            _ => (0..inner.steps.len()).filter(|&i| inner.steps[i].initial).collect(),
        };
        let exits: Vec<usize> = (0..inner.steps.len()).filter(|&i| !left(&inner.steps[i])).collect();
        let (&[entry], &[exit]) = (entries.as_slice(), exits.as_slice()) else {
            let message = format!(
                "a macro step's body must begin with one step and end with one (found {} entry and {} exit steps)",
                entries.len(),
                exits.len()
            );
            self.error(span, message);
            return None;
        };
        inner.steps[entry].initial = false;
        Some((inner.steps[entry].name.clone(), inner.steps[exit].name.clone()))
    }

    /// A step's actions as CODESYS and TwinCAT attach them in vendor data: the active action (N), the entry action
    /// and the exit action.
    pub(super) fn codesys_step_actions(&mut self, step_node: Node, step: &mut Step) {
        let attributes = child(step_node, "addData")
            .into_iter()
            .flat_map(|a| children(a, "data"))
            .filter(|d| d.attribute("name") == Some(CODESYS_SFC_ELEMENT))
            .flat_map(|d| children(d, "attributes"))
            .flat_map(|a| children(a, "attribute"));
        for a in attributes {
            let qualifier = match a.attribute("guid") {
                Some(CODESYS_ACTIVE_ACTION) => Qualifier::Active,
                Some(CODESYS_ENTRY_ACTION) => Qualifier::Entry,
                Some(CODESYS_EXIT_ACTION) => Qualifier::Exit,
                _ => continue,
            };
            let Some(text_node) = a.first_child().filter(Node::is_text) else { continue };
            let raw = &self.src[text_node.range()];
            let name = raw.trim();
            if name.is_empty() {
                continue;
            }
            let start = text_node.range().start + (raw.len() - raw.trim_start().len());
            let span = Span::new(start, start + name.len());
            let action = Ident { name: text_node.text().unwrap_or(name).trim().to_string(), span };
            if !step.associations.iter().any(|x| x.action.key() == action.key() && x.qualifier == qualifier) {
                step.associations.push(Association {
                    action,
                    qualifier,
                    qualifier_span: span,
                    duration: None,
                    indicators: Vec::new(),
                    span,
                });
            }
        }
    }

    pub(super) fn transition(
        &mut self,
        el: Node,
        doc_index: usize,
        elements: &Elements,
        named: &HashMap<String, Node>,
        broken: &mut Broken,
    ) -> Option<ReadTransition> {
        let span = self.tag_span(el);
        self.visits = 0;
        let inputs = self.connections(el);
        if inputs.is_empty() {
            self.error(span, "transition with no input: connect it to the step it leaves");
            return None;
        }
        let mut from = Vec::new();
        let mut ok = true;
        let mut divergence = None;
        for (id, _, at) in &inputs {
            if elements.by_id.get(id).is_some_and(|d| is(d, "selectionDivergence")) {
                divergence = elements.index.get(id).copied();
            }
            ok &= self.sources(elements, *id, *at, &mut from, 0);
        }
        let mut to = Vec::new();
        if let Some(id) = local_id(el) {
            ok &= self.targets(elements, id, span, &mut to, 0);
        }
        if ok && to.is_empty() {
            self.error(span, "transition with no output: connect a step, a jump or a divergence after it");
            ok = false;
        }
        self.calls.clear();
        self.called.clear();
        self.edges.clear();
        let (condition, pragmas) = self.condition(el, elements, named);
        let calls = std::mem::take(&mut self.calls);
        self.condition_calls.extend(calls);
        let priority = match el.attribute("priority").map(|p| p.trim().parse::<u32>()) {
            Some(Ok(p)) => Some((p, self.attr_span(el, "priority"))),
            Some(Err(_)) => {
                self.error(self.attr_span(el, "priority"), "a transition's priority must be a non-negative integer");
                None
            }
            None => None,
        };
        if !ok {
            return None;
        }
        // A broken condition keeps its transition (as never clearing), so that the net around it is checked.
        let condition = condition.unwrap_or_else(|| {
            broken.conditions.push(span);
            Expr { kind: ExprKind::Bool(false), span }
        });
        let x = child(el, "position").and_then(|p| p.attribute("x")).and_then(|x| x.trim().parse::<f64>().ok());
        // A transition whose condition is a named transition of the POU takes its name, unless another uses it too.
        let reference = child(el, "condition").and_then(|c| child(c, "reference"));
        let name = reference.and_then(|r| {
            let name = r.attribute("name")?.trim();
            let once = self.references.get(&name.to_ascii_uppercase()).copied() == Some(1);
            once.then(|| Ident { name: name.to_string(), span: self.attr_span(r, "name") })
        });
        Some(ReadTransition {
            local_id: local_id(el),
            transition: Transition { name, priority, from, to, condition, pragmas, span, arc_span: span },
            order: (divergence.unwrap_or(doc_index), x.unwrap_or(0.0), doc_index),
        })
    }

    pub(super) fn too_deep(&mut self, depth: usize, span: Span) -> bool {
        // Shared inputs make a wired network a DAG whose expression can be exponentially larger than the file:
        // the walk has a budget.
        self.visits += 1;
        if self.visits == XML_CONNECTIONS_WALKED_MAX {
            let message = format!(
                "more than {XML_CONNECTIONS_WALKED_MAX} connections followed for one transition or network: too large, or in a loop"
            );
            self.error(span, message);
        }
        if self.visits >= XML_CONNECTIONS_WALKED_MAX {
            return true;
        }
        if depth > NESTING_DEPTH_MAX {
            let message = format!("connections nested more than {NESTING_DEPTH_MAX} deep, or in a loop");
            self.error(span, message);
            return true;
        }
        false
    }

    /// The steps a transition leaves, walking back from element `id`.
    pub(super) fn sources(
        &mut self,
        elements: &Elements,
        id: u64,
        at: Span,
        out: &mut Vec<Ident>,
        depth: usize,
    ) -> bool {
        if self.too_deep(depth, at) {
            return false;
        }
        let Some(&n) = elements.by_id.get(&id) else {
            self.dangling(at, id);
            return false;
        };
        match n.tag_name().name() {
            "step" => match self.step_ident(n) {
                Some(name) => {
                    out.push(name);
                    true
                }
                None => false,
            },
            "macroStep" => match self.macros.get(&id) {
                Some((_, exit)) => {
                    out.push(exit.clone());
                    true
                }
                None => false,
            },
            "selectionDivergence" | "simultaneousConvergence" => {
                let inputs = self.connections(n);
                if inputs.is_empty() {
                    let message = format!("`<{}>` has no input", n.tag_name().name());
                    self.error(self.tag_span(n), message);
                    return false;
                }
                let mut ok = true;
                for (from, _, span) in inputs {
                    ok &= self.sources(elements, from, span, out, depth + 1);
                }
                ok
            }
            other => {
                let message = format!(
                    "a transition's input must be a step, a selection divergence or a simultaneous convergence, not `<{other}>` (element {id})"
                );
                self.error(at, message);
                false
            }
        }
    }

    /// The steps a transition activates, walking forward from element `id`.
    pub(super) fn targets(
        &mut self,
        elements: &Elements,
        id: u64,
        at: Span,
        out: &mut Vec<Ident>,
        depth: usize,
    ) -> bool {
        if self.too_deep(depth, at) {
            return false;
        }
        let mut ok = true;
        for c in elements.consumers.get(&id).into_iter().flatten() {
            let n = elements.by_id[c];
            match n.tag_name().name() {
                "step" => match self.step_ident(n) {
                    Some(name) => out.push(name),
                    None => ok = false,
                },
                "jumpStep" => match self.ident_attr(n, "targetName") {
                    Some(target) => match self.macro_names.get(&target.key()) {
                        Some(entry) => out.push(Ident { name: entry.name.clone(), span: target.span }),
                        None => out.push(target),
                    },
                    None => ok = false,
                },
                "macroStep" => match self.macros.get(c) {
                    Some((entry, _)) => out.push(entry.clone()),
                    None => ok = false,
                },
                "selectionConvergence" | "simultaneousDivergence" => {
                    let before = out.len();
                    ok &= self.targets(elements, *c, self.tag_span(n), out, depth + 1);
                    if ok && out.len() == before {
                        let message =
                            format!("`<{}>` leads nowhere: nothing is connected after it", n.tag_name().name());
                        self.error(self.tag_span(n), message);
                        ok = false;
                    }
                }
                "transition" => {
                    let span = self.tag_span(n);
                    self.error(span, "two transitions in a row: a step must stand between them");
                    ok = false;
                }
                other => {
                    let message = format!("`<{other}>` cannot follow a transition");
                    self.error(self.tag_span(n), message);
                    ok = false;
                }
            }
        }
        ok
    }
}
