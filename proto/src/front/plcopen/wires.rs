//! LD and FBD networks as expressions and assignments: contacts, coils, blocks and their wires, for conditions and
//! action bodies.

use std::collections::HashMap;

use roxmltree::Node;

use crate::front::diag::{Diagnostic, Span};
use crate::front::model::{
    Action, Arg, Association, BinOp, Chart, Duration, Expr, ExprKind, Ident, Pragma, Qualifier, Stmt, UnOp, VarDecl,
    VarSection,
};
use crate::front::parser::{Fragment, FragmentKind};
use crate::front::plcopen::xml::{child, children, flag, is, local_id};
use crate::limits::NESTING_DEPTH_MAX;

use super::{Elements, Reader};

pub(super) fn not(e: Expr) -> Expr {
    let span = e.span;
    Expr { kind: ExprKind::Unary(UnOp::Not, Box::new(e)), span }
}

pub(super) fn binary(op: BinOp, a: Expr, b: Expr) -> Expr {
    let span = a.span.to(b.span);
    Expr { kind: ExprKind::Binary(op, Box::new(a), Box::new(b)), span }
}

impl Reader<'_> {
    /// An LD or FBD network as assignments: each coil and output variable, in execution order, gets what is
    /// wired to it.
    pub(super) fn network_statements(&mut self, body: Node) -> Option<Vec<Stmt>> {
        let elements = self.elements(body, &[]);
        let instance = |c: &Node| is(c, "block") && c.attribute("instanceName").is_some();
        let mut outputs: Vec<Node> =
            body.children().filter(|c| is(c, "coil") || is(c, "outVariable") || instance(c)).collect();
        outputs.sort_by_key(|n| n.attribute("executionOrderId").and_then(|e| e.parse::<u64>().ok()).unwrap_or(0));
        let mut out = Vec::new();
        let mut ok = true;
        self.calls.clear();
        self.called.clear();
        self.edges.clear();
        for n in outputs {
            if instance(&n) {
                // A block runs where it stands in the execution order, unless what it feeds needed it first.
                self.visits = 0;
                ok &= self.fb_call(&elements, n, 0).is_some();
                out.append(&mut self.calls);
                continue;
            }
            let target_node = if is(&n, "coil") { child(n, "variable") } else { child(n, "expression") };
            let target = match target_node.and_then(|t| self.expr_text(t)) {
                Some(Expr { kind: ExprKind::Name(id), .. }) => id,
                Some(other) => {
                    self.error(other.span, "a coil or output variable must name a variable");
                    ok = false;
                    continue;
                }
                None => {
                    if target_node.is_none() {
                        self.error(self.tag_span(n), "a coil or output variable without a variable");
                    }
                    ok = false;
                    continue;
                }
            };
            self.visits = 0;
            let Some(mut value) = self.wired(&elements, n, 0).and_then(|e| self.bounded(e, self.tag_span(n))) else {
                ok = false;
                continue;
            };
            if flag(n, "negated") {
                value = not(value);
            }
            out.append(&mut self.calls);
            let span = self.tag_span(n);
            let target = Expr { span: target.span, kind: ExprKind::Name(target) };
            let stmt = match n.attribute("storage") {
                Some("set") | Some("reset") => {
                    let to = n.attribute("storage") == Some("set");
                    let assign = Stmt::Assign { target, value: Expr { kind: ExprKind::Bool(to), span }, span };
                    Stmt::If { branches: vec![(value, vec![assign])], otherwise: Vec::new(), span }
                }
                _ => Stmt::Assign { target, value, span },
            };
            out.push(stmt);
        }
        ok.then_some(out)
    }

    /// A transition's condition: inline ST, a named transition's body, or LD/FBD logic wired to it.
    pub(super) fn condition(
        &mut self,
        el: Node,
        elements: &Elements,
        named: &HashMap<String, Node>,
    ) -> (Option<Expr>, Vec<Pragma>) {
        let Some(cond) = child(el, "condition") else {
            self.error(self.tag_span(el), "transition without a `<condition>`");
            return (None, Vec::new());
        };
        let mut pragmas = Vec::new();
        let expr = if let Some(inline) = child(cond, "inline") {
            match inline.first_element_child() {
                Some(st) if is(&st, "ST") => {
                    let (fragment, found) = self.fragment(st, FragmentKind::Expr);
                    pragmas = found;
                    match fragment {
                        Some(Fragment::Expr(e)) => Some(e),
                        _ => None,
                    }
                }
                Some(other) => {
                    self.unsupported_language(other);
                    None
                }
                None => {
                    self.error(self.tag_span(inline), "an inline condition without a body");
                    None
                }
            }
        } else if let Some(reference) = child(cond, "reference") {
            self.named_condition(reference, named)
        } else if child(cond, "connectionPointIn").is_some() || child(cond, "connection").is_some() {
            self.wired(elements, cond, 0).and_then(|e| self.bounded(e, self.tag_span(cond)))
        } else {
            self.error(self.tag_span(cond), "an empty `<condition>`: expected inline ST, a reference or a connection");
            None
        };
        let expr = if flag(cond, "negated") { expr.map(not) } else { expr };
        (expr, pragmas)
    }

    pub(super) fn unsupported_language(&mut self, body: Node) {
        let message = match body.tag_name().name() {
            "IL" => "Instruction List conditions are not supported: write the condition in ST".to_string(),
            other => format!("`<{other}>` bodies are not supported here"),
        };
        self.error(self.tag_span(body), message);
    }

    /// The body of a named transition, `pou/transitions/transition@name`.
    pub(super) fn named_condition(&mut self, reference: Node, named: &HashMap<String, Node>) -> Option<Expr> {
        let name = self.ident_attr(reference, "name")?;
        let Some(&t) = named.get(&name.key()) else {
            self.error(name.span, format!("no transition named `{}` in this POU's `<transitions>`", name.name));
            return None;
        };
        let Some(body) = child(t, "body").and_then(|b| b.first_element_child()) else {
            self.error(self.tag_span(t), format!("transition `{}` has no body", name.name));
            return None;
        };
        match body.tag_name().name() {
            "ST" => match self.fragment(body, FragmentKind::TransitionBody).0 {
                Some(Fragment::Expr(e)) => Some(e),
                _ => None,
            },
            "LD" | "FBD" => {
                let elements = self.elements(body, &[]);
                // The network's result is the coil or output variable named after the transition.
                let result = body.children().find(|n| {
                    let target = if is(n, "coil") {
                        child(*n, "variable")
                    } else if is(n, "outVariable") {
                        child(*n, "expression")
                    } else {
                        None
                    };
                    target.and_then(|t| t.text()).is_some_and(|t| t.trim().eq_ignore_ascii_case(&name.name))
                });
                let Some(result) = result else {
                    let message = format!(
                        "the LD/FBD body of transition `{}` assigns no coil or output variable named `{}`",
                        name.name, name.name
                    );
                    self.error(self.tag_span(body), message);
                    return None;
                };
                let value = self.wired(&elements, result, 0)?;
                let value = self.bounded(value, self.tag_span(result))?;
                Some(if flag(result, "negated") { not(value) } else { value })
            }
            _ => {
                self.unsupported_language(body);
                None
            }
        }
    }

    /// What is wired into element `n`: the OR of its connections (parallel LD branches join by OR).
    pub(super) fn wired(&mut self, elements: &Elements, n: Node, depth: usize) -> Option<Expr> {
        let span = self.tag_span(n);
        if self.too_deep(depth, span) {
            return None;
        }
        let inputs = self.connections(n);
        if inputs.is_empty() {
            self.error(span, format!("nothing is connected to `<{}>`", n.tag_name().name()));
            return None;
        }
        let mut branches = Vec::with_capacity(inputs.len());
        for (id, formal, at) in inputs {
            branches.push(self.output_of(elements, id, formal.as_deref(), at, depth + 1)?);
        }
        // Parallel branches as a balanced OR: a rung of 30,000 parallel contacts is 15 levels deep, not 30,000.
        Some(Expr::balanced(BinOp::Or, branches))
    }

    /// Wired logic turned into an expression is bounded like any other: deeper than the nesting limit is an error
    /// at the element it feeds, never a tree that a walk over it cannot hold.
    pub(super) fn bounded(&mut self, e: Expr, at: Span) -> Option<Expr> {
        if e.height() - 1 > NESTING_DEPTH_MAX {
            let message = format!(
                "the logic wired into this element nests more than {NESTING_DEPTH_MAX} levels deep (contacts in \
                 series, blocks feeding blocks): split it with intermediate variables"
            );
            self.error(at, message);
            return None;
        }
        Some(e)
    }

    /// The value of element `id`'s output (`formal` names which, for a block).
    pub(super) fn output_of(
        &mut self,
        elements: &Elements,
        id: u64,
        formal: Option<&str>,
        at: Span,
        depth: usize,
    ) -> Option<Expr> {
        if self.too_deep(depth, at) {
            return None;
        }
        let Some(&n) = elements.by_id.get(&id) else {
            self.dangling(at, id);
            return None;
        };
        let span = self.tag_span(n);
        match n.tag_name().name() {
            "inVariable" | "inOutVariable" => {
                let Some(expression) = child(n, "expression") else {
                    self.error(span, "a variable block without an `<expression>`");
                    return None;
                };
                let e = self.expr_text(expression)?;
                Some(if flag(n, "negated") { not(e) } else { e })
            }
            "leftPowerRail" => Some(Expr { kind: ExprKind::Bool(true), span }),
            "contact" => {
                let Some(variable) = child(n, "variable") else {
                    self.error(span, "a contact without a `<variable>`");
                    return None;
                };
                let var = self.expr_text(variable)?;
                let var = if flag(n, "negated") { not(var) } else { var };
                // A transition-sensing contact is read as Beremiz compiles it: an implicit R_TRIG (rising) or F_TRIG
                // (falling) instance of the POU, `R_TRIG1`, `F_TRIG2`…, called with the contact's variable where the
                // rung is evaluated, and read as its Q (so with the standard blocks' start-up behaviour).
                let var = match n.attribute("edge") {
                    Some(edge @ ("rising" | "falling")) => {
                        let id = local_id(n).unwrap_or(0);
                        let ident = |name: &str| Ident { name: name.to_string(), span };
                        let name = match self.edges.get(&id) {
                            Some(name) => name.clone(),
                            None => {
                                let fb = if edge == "rising" { "R_TRIG" } else { "F_TRIG" };
                                let taken = |c: &Self, name: &str| {
                                    let key = name.to_ascii_uppercase();
                                    c.names.contains(&key) || c.implicit.iter().any(|d| d.name.key() == key)
                                };
                                let mut i = 1;
                                while taken(self, &format!("{fb}{i}")) {
                                    i += 1;
                                }
                                let name = format!("{fb}{i}");
                                self.implicit.push(VarDecl {
                                    name: ident(&name),
                                    section: VarSection::Local,
                                    constant: false,
                                    type_name: ident(fb),
                                    init: None,
                                    members: Vec::new(),
                                    array: None,
                                    pragmas: Vec::new(),
                                    address: None,
                                });
                                let clk =
                                    Arg { name: Some(ident("CLK")), output: false, negated: false, value: var, span };
                                self.calls.push(Stmt::Call { callee: ident(&name), args: vec![clk], span });
                                self.edges.insert(id, name.clone());
                                name
                            }
                        };
                        Expr { kind: ExprKind::Field(ident(&name), ident("Q")), span }
                    }
                    _ => var,
                };
                let input = self.wired(elements, n, depth)?;
                Some(match input.kind {
                    ExprKind::Bool(true) => var,
                    _ => binary(BinOp::And, input, var),
                })
            }
            // A coil passes its input on to what follows it on the rung.
            "coil" => self.wired(elements, n, depth),
            "block" => self.block(elements, n, formal, depth),
            "continuation" => {
                let name = n.attribute("name").unwrap_or_default();
                match elements.connectors.get(&name.trim().to_ascii_uppercase()) {
                    Some(&c) => self.wired(elements, c, depth),
                    None => {
                        self.error(span, format!("continuation `{name}` has no connector of that name"));
                        None
                    }
                }
            }
            other => {
                self.error(at, format!("`<{other}>` (element {id}) cannot feed a condition or a coil"));
                None
            }
        }
    }

    /// The call of a function block instance drawn as a block, queued in `calls` once (after the calls its inputs
    /// need): its instance.
    pub(super) fn fb_call(&mut self, elements: &Elements, n: Node, depth: usize) -> Option<Ident> {
        let span = self.tag_span(n);
        let name = n.attribute("instanceName").unwrap_or_default().trim().to_string();
        let instance = Ident { name, span: self.attr_span(n, "instanceName") };
        if local_id(n).is_some_and(|id| !self.called.insert(id)) {
            return Some(instance);
        }
        if child(n, "inOutVariables").is_some_and(|v| v.children().any(|c| is(&c, "variable"))) {
            self.error(span, format!("in-out parameters of block `{}` are not supported yet", instance.name));
            return None;
        }
        let mut args = Vec::new();
        for v in child(n, "inputVariables").into_iter().flat_map(|i| children(i, "variable")) {
            let Some(formal) = v.attribute("formalParameter") else {
                self.error(self.tag_span(v), "a block input without a `formalParameter`");
                return None;
            };
            // An input left unconnected keeps its value, as in a call that does not name it.
            if self.connections(v).is_empty() {
                continue;
            }
            let e = self.wired(elements, v, depth)?;
            let e = self.bounded(e, self.tag_span(v))?;
            let value = if flag(v, "negated") { not(e) } else { e };
            let name = Ident { name: formal.trim().to_string(), span: self.tag_span(v) };
            args.push(Arg { name: Some(name), output: false, negated: false, span: value.span, value });
        }
        self.calls.push(Stmt::Call { callee: instance.clone(), args, span });
        Some(instance)
    }

    /// A standard function drawn as an FBD block, as an expression.
    pub(super) fn block(&mut self, elements: &Elements, n: Node, formal: Option<&str>, depth: usize) -> Option<Expr> {
        let span = self.tag_span(n);
        let type_name = n.attribute("typeName").unwrap_or_default().to_ascii_uppercase();
        if n.attribute("instanceName").is_some() {
            let instance = self.fb_call(elements, n, depth)?;
            let Some(output) = formal.filter(|f| !f.trim().is_empty()) else {
                self.error(span, format!("connect a named output of block `{}` (such as `Q`)", instance.name));
                return None;
            };
            let field = Ident { name: output.trim().to_string(), span };
            return Some(Expr { kind: ExprKind::Field(instance, field), span });
        }
        if formal.is_some_and(|f| !f.is_empty() && !f.eq_ignore_ascii_case("OUT")) {
            self.error(span, format!("block `{type_name}` has no output `{}`", formal.unwrap_or_default()));
            return None;
        }
        let mut args = Vec::new();
        let mut formals = Vec::new();
        for v in child(n, "inputVariables").into_iter().flat_map(|i| children(i, "variable")) {
            if v.attribute("formalParameter").is_some_and(|f| f.eq_ignore_ascii_case("EN")) {
                continue;
            }
            let e = self.wired(elements, v, depth)?;
            args.push(if flag(v, "negated") { not(e) } else { e });
            formals.push(
                v.attribute("formalParameter").map(|f| Ident { name: f.trim().to_string(), span: self.tag_span(v) }),
            );
        }
        /// How a standard function's inputs combine.
        enum Shape {
            /// Extensible: `a op b op c …`.
            Fold(BinOp),
            /// Extensible comparison: `a op b AND b op c …`.
            Chain(BinOp),
            /// Exactly two inputs.
            Pair(BinOp),
            Not,
            Move,
        }
        let shape = match type_name.as_str() {
            "AND" => Shape::Fold(BinOp::And),
            "OR" => Shape::Fold(BinOp::Or),
            "XOR" => Shape::Fold(BinOp::Xor),
            "ADD" => Shape::Fold(BinOp::Add),
            "MUL" => Shape::Fold(BinOp::Mul),
            "SUB" => Shape::Pair(BinOp::Sub),
            "DIV" => Shape::Pair(BinOp::Div),
            "MOD" => Shape::Pair(BinOp::Mod),
            "NE" => Shape::Pair(BinOp::Ne),
            "GT" => Shape::Chain(BinOp::Gt),
            "GE" => Shape::Chain(BinOp::Ge),
            "EQ" => Shape::Chain(BinOp::Eq),
            "LE" => Shape::Chain(BinOp::Le),
            "LT" => Shape::Chain(BinOp::Lt),
            "NOT" => Shape::Not,
            "MOVE" => Shape::Move,
            _ => {
                // Any other standard function, as a call with its formal parameters (the compiler types it).
                let formal = formals.iter().all(|f| f.is_some());
                let args = args
                    .into_iter()
                    .zip(formals)
                    .map(|(value, name)| Arg {
                        name: name.filter(|_| formal),
                        output: false,
                        negated: false,
                        span,
                        value,
                    })
                    .collect();
                let callee = Ident { name: type_name, span: self.attr_span(n, "typeName") };
                return Some(Expr { kind: ExprKind::Call(callee, args), span });
            }
        };
        let inputs = match shape {
            Shape::Pair(_) => Some(2),
            Shape::Not | Shape::Move => Some(1),
            Shape::Fold(_) | Shape::Chain(_) => None,
        };
        match inputs {
            Some(k) if args.len() != k => {
                self.error(span, format!("block `{type_name}` takes {k} input(s), not {}", args.len()));
                return None;
            }
            None if args.len() < 2 => {
                self.error(span, format!("block `{type_name}` needs at least 2 connected input(s)"));
                return None;
            }
            _ => {}
        }
        let mut args = args.into_iter();
        let result = match shape {
            Shape::Fold(op) if op.associative() => Some(Expr::balanced(op, args.collect())),
            Shape::Fold(op) => args.reduce(|a, b| binary(op, a, b)),
            Shape::Chain(op) => {
                let args: Vec<Expr> = args.collect();
                let pairs: Vec<Expr> = args.windows(2).map(|w| binary(op, w[0].clone(), w[1].clone())).collect();
                Some(Expr::balanced(BinOp::And, pairs))
            }
            Shape::Pair(op) => args.next().zip(args.next()).map(|(a, b)| binary(op, a, b)),
            Shape::Not => args.next().map(not),
            Shape::Move => args.next(),
        };
        result.map(|e| Expr { span, ..e })
    }

    pub(super) fn action_block(
        &mut self,
        block: Node,
        elements: &Elements,
        step_of_id: &HashMap<u64, usize>,
        inline_count: &mut usize,
        chart: &mut Chart,
    ) {
        let span = self.tag_span(block);
        let inputs = self.connections(block);
        let step = match inputs.as_slice() {
            [(id, _, at)] => match step_of_id.get(id) {
                Some(&s) => s,
                None if elements.by_id.contains_key(id) => {
                    self.error(*at, format!("an action block must hang from a step; element {id} is not one"));
                    return;
                }
                None => {
                    self.dangling(*at, *id);
                    return;
                }
            },
            _ => {
                self.error(span, "an action block must be connected to exactly one step");
                return;
            }
        };
        for a in children(block, "action") {
            let a_span = self.tag_span(a);
            let qualifier_text = a.attribute("qualifier").map(str::trim).filter(|q| !q.is_empty()).unwrap_or("N");
            let Some(qualifier) = Qualifier::from_word(qualifier_text) else {
                self.error(self.attr_span(a, "qualifier"), format!("unknown action qualifier `{qualifier_text}`"));
                continue;
            };
            let qualifier_span = if a.has_attribute("qualifier") { self.attr_span(a, "qualifier") } else { a_span };
            let duration = match a.attribute("duration").map(str::trim) {
                Some(d) if !d.is_empty() => match self.expr_attr(a, "duration") {
                    Some(Expr { kind: ExprKind::Time(ms), span }) => Some(Duration::Literal { ms, span }),
                    Some(Expr { kind: ExprKind::Name(id), .. }) => Some(Duration::Var(id)),
                    Some(e) => {
                        self.error(e.span, "an action's duration must be a TIME literal or a TIME variable");
                        continue;
                    }
                    None => continue,
                },
                // CODESYS and TwinCAT write `duration=""` on every qualifier.
                _ if qualifier.is_timed() => {
                    let message = format!("qualifier {qualifier_text} without a duration: taken as T#0s");
                    self.diags.push(Diagnostic::warning(qualifier_span, message));
                    Some(Duration::Literal { ms: 0, span: qualifier_span })
                }
                _ => None,
            };
            let indicators = match a.attribute("indicator").map(str::trim) {
                // Baton writes a skill's done and fault indicators as `done, fault`.
                Some(i) if !i.is_empty() => {
                    let span = self.attr_span(a, "indicator");
                    i.split(',')
                        .map(str::trim)
                        .filter(|n| !n.is_empty())
                        .map(|n| Ident { name: n.to_string(), span })
                        .collect()
                }
                _ => Vec::new(),
            };
            let action = if let Some(reference) = child(a, "reference") {
                let Some(name) = self.ident_attr(reference, "name") else { continue };
                name
            } else if let Some(inline) = child(a, "inline") {
                // Named as Beremiz and matiec name inline actions, so that a chart's textual twin matches.
                *inline_count += 1;
                let step_name = chart.steps[step].name.name.to_ascii_uppercase();
                let name = Ident { name: format!("{step_name}_INLINE{inline_count}"), span: self.tag_span(inline) };
                let (body, pragmas) = match inline.first_element_child() {
                    Some(b) => self.body_statements(b),
                    None => (Some(Vec::new()), Vec::new()),
                };
                if body.is_none() {
                    chart.broken.actions.push(name.key());
                }
                chart.steps[step].pragmas.extend(pragmas);
                chart.actions.push(Action {
                    name: name.clone(),
                    body: body.unwrap_or_default(),
                    sfc: None,
                    pragmas: Vec::new(),
                    span: self.tag_span(inline),
                });
                name
            } else {
                self.error(a_span, "an action without a `<reference>` or an `<inline>` body");
                continue;
            };
            chart.steps[step].associations.push(Association {
                action,
                qualifier,
                qualifier_span,
                duration,
                indicators,
                span: a_span,
            });
        }
    }
}
