//! POUs and types: programs and function blocks with their interfaces, data types, global variable lists, and named
//! actions and their bodies.

use std::collections::HashMap;

use roxmltree::Node;

use crate::front::diag::Span;
use crate::front::model::{
    Action, ArraySpec, Chart, FbDef, Ident, PouKind, Pragma, Sfc, SfcFlags, Stmt, TypeDef, TypeKind, VarDecl,
    VarSection,
};
use crate::front::parser::{Fragment, FragmentKind};
use crate::front::plcopen::order::{apply_order, baton_order, walk_order};
use crate::front::plcopen::xml::{child, children, flag, is, type_name};

use super::{Reader, CODESYS_SFC_SETTINGS};

impl Reader<'_> {
    pub(super) fn pou(&mut self, pou: Node) -> Option<Chart> {
        let Some(sfc) = child(pou, "body").and_then(|b| child(b, "SFC")) else {
            if pou.attribute("pouType") == Some("program") {
                if let Some(program) = self.caller_program(pou) {
                    self.programs.push(program);
                }
            } else {
                self.function_block(pou);
            }
            return None;
        };
        let kind = match pou.attribute("pouType") {
            Some("program") => PouKind::Program,
            Some("functionBlock") => PouKind::FunctionBlock,
            other => {
                let message = format!(
                    "an SFC body in a POU of type `{}`: only programs and function blocks hold charts",
                    other.unwrap_or("(none)")
                );
                self.error(self.tag_span(pou), message);
                return None;
            }
        };
        let name = self.ident_attr(pou, "name")?;
        let range = pou.range();
        let mut chart = Chart {
            vars: self.interface(pou),
            pragmas: self.documentation_pragmas(pou),
            ..Chart::empty(name, kind, Span::new(range.start, range.end))
        };
        let named_transitions: HashMap<String, Node> = child(pou, "transitions")
            .into_iter()
            .flat_map(|t| children(t, "transition"))
            .filter_map(|t| Some((t.attribute("name")?.to_ascii_uppercase(), t)))
            .collect();
        self.implicit.clear();
        self.condition_calls.clear();
        self.names = chart.vars.iter().map(|v| v.name.key()).collect();
        for action in child(pou, "actions").into_iter().flat_map(|a| children(a, "action")) {
            self.named_action(action, &named_transitions, &mut chart);
        }
        let transition_ids = self.sfc(sfc, &named_transitions, &mut chart);
        self.compute_blocks(&mut chart);
        chart.vars.append(&mut self.implicit);
        // A file Baton wrote keeps Baton's element order; any other is ordered as Beremiz would run it.
        match baton_order(pou) {
            Some(order) => apply_order(&mut chart, &transition_ids, &order),
            None => walk_order(&mut chart),
        }
        Some(chart)
    }

    /// An `<array>` type (dimensions, element type) with its `arrayValue` initial elements, as runs.
    pub(super) fn array_spec(&mut self, array: Node, init: Option<Node>) -> Option<ArraySpec> {
        let mut dims = Vec::new();
        for d in children(array, "dimension") {
            let bound = |attr: &str| d.attribute(attr).and_then(|v| v.trim().parse::<i64>().ok());
            dims.push((bound("lower")?, bound("upper")?));
        }
        let elem = child(array, "baseType").and_then(|b| b.first_element_child())?;
        let name = type_name(elem)?;
        let mut values = Vec::new();
        for v in init.and_then(|i| child(i, "arrayValue")).into_iter().flat_map(|a| children(a, "value")) {
            // A count past u64 is as many as any array refuses.
            let count = v.attribute("repetitionValue").map_or(1, |r| {
                let r = r.trim();
                r.parse::<u64>().unwrap_or(if r.bytes().all(|b| b.is_ascii_digit()) { u64::MAX } else { 1 })
            });
            if let Some(e) = child(v, "simpleValue").and_then(|s| self.expr_attr(s, "value")) {
                values.push(crate::front::model::InitRun { count, value: e });
            }
        }
        let range = array.range();
        Some(ArraySpec {
            dims,
            elem: Ident { name, span: self.tag_span(elem) },
            init: values,
            span: Span::new(range.start, range.end),
        })
    }

    /// The project's `types/dataTypes`: enumerations, subranges and aliases; other kinds named as unsupported.
    pub(super) fn data_types(&mut self, root: Node) -> Vec<TypeDef> {
        let mut out = Vec::new();
        for dt in root.descendants().filter(|n| is(n, "dataType")) {
            let Some(name) = dt.attribute("name").map(str::trim).filter(|n| !n.is_empty()) else { continue };
            let name = Ident { name: name.to_string(), span: self.attr_span(dt, "name") };
            let Some(base) = child(dt, "baseType").and_then(|b| b.first_element_child()) else { continue };
            let base_name = |n: Node| -> Option<Ident> {
                Some(Ident { name: type_name(n.first_element_child()?)?, span: Span::default() })
            };
            let kind = match base.tag_name().name() {
                "enum" => {
                    let values: Vec<Ident> = child(base, "values")
                        .into_iter()
                        .flat_map(|v| children(v, "value"))
                        .filter_map(|v| {
                            Some(Ident {
                                name: v.attribute("name")?.trim().to_string(),
                                span: self.attr_span(v, "name"),
                            })
                        })
                        .collect();
                    let init = child(dt, "initialValue")
                        .and_then(|i| child(i, "simpleValue"))
                        .and_then(|s| s.attribute("value"))
                        .map(|v| Ident { name: v.rsplit('#').next().unwrap_or(v).trim().to_string(), span: name.span });
                    TypeKind::Enum { values, init }
                }
                "subrangeSigned" | "subrangeUnsigned" => {
                    let range = child(base, "range");
                    let bound =
                        |attr: &str| range.and_then(|r| r.attribute(attr)).and_then(|v| v.trim().parse::<i64>().ok());
                    match (bound("lower"), bound("upper"), child(base, "baseType").and_then(base_name)) {
                        (Some(low), Some(high), Some(base)) => TypeKind::Subrange { base, low, high },
                        _ => TypeKind::Unsupported("malformed subranges".to_string()),
                    }
                }
                "derived" => match base.attribute("name") {
                    Some(n) => TypeKind::Alias(Ident { name: n.to_string(), span: name.span }),
                    None => continue,
                },
                "array" => match self.array_spec(base, child(dt, "initialValue")) {
                    Some(spec) => TypeKind::Array(spec),
                    None => TypeKind::Unsupported("malformed arrays".to_string()),
                },
                "struct" => TypeKind::Struct(self.var_list(base, VarSection::Local, false)),
                "wstring" => TypeKind::Unsupported("wide strings (WSTRING)".to_string()),
                "string" => match type_name(base) {
                    Some(n) => TypeKind::Alias(Ident { name: n, span: name.span }),
                    None => TypeKind::Unsupported("strings of a length past the limit".to_string()),
                },
                other => TypeKind::Alias(Ident { name: other.to_ascii_uppercase(), span: name.span }),
            };
            out.push(TypeDef { name, kind });
        }
        out
    }

    /// A function block POU with an ST body (or none), kept for the charts that instantiate it; its errors are
    /// kept with it until one does.
    pub(super) fn function_block(&mut self, pou: Node) {
        let returns = match pou.attribute("pouType") {
            Some("functionBlock") => None,
            Some("function") => {
                let ty =
                    child(pou, "interface").and_then(|i| child(i, "returnType")).and_then(|t| t.first_element_child());
                let Some(name) = ty.map(|t| type_name(t).unwrap_or_else(|| "(unreadable type)".to_string())) else {
                    return;
                };
                Some(Ident { span: ty.map_or(Span::default(), |t| self.tag_span(t)), name })
            }
            _ => return,
        };
        let Some(name) = pou.attribute("name").map(str::trim).filter(|n| !n.is_empty()) else { return };
        let name = Ident { name: name.to_string(), span: self.attr_span(pou, "name") };
        let outer = std::mem::take(&mut self.diags);
        let vars = self.interface(pou);
        let body = match child(pou, "body").and_then(|b| b.first_element_child()) {
            None => Some(Vec::new()),
            Some(st) if is(&st, "ST") => match self.fragment(st, FragmentKind::Statements).0 {
                Some(Fragment::Statements(body)) => Some(body),
                _ => None,
            },
            Some(other) => {
                let message = format!(
                    "function block `{}` has a `<{}>` body: Baton runs function blocks written in ST",
                    name.name,
                    other.tag_name().name()
                );
                self.error(self.tag_span(other), message);
                None
            }
        };
        // Its actions (CODESYS, TwinCAT), which an instance runs when called as `instance.Action();` or as a step's
        // action: in ST, LD or FBD, or in SFC (a nested chart, read as a chart's is; the actions drawn inline in it
        // become the block's).
        let mut scratch = Chart::empty(name.clone(), PouKind::FunctionBlock, name.span);
        let named_transitions: HashMap<String, Node> = child(pou, "transitions")
            .into_iter()
            .flat_map(|t| children(t, "transition"))
            .filter_map(|t| Some((t.attribute("name")?.to_ascii_uppercase(), t)))
            .collect();
        let (implicit, condition_calls) =
            (std::mem::take(&mut self.implicit), std::mem::take(&mut self.condition_calls));
        let names = std::mem::replace(&mut self.names, vars.iter().map(|v| v.name.key()).collect());
        for a in child(pou, "actions").into_iter().flat_map(|x| children(x, "action")) {
            self.named_action(a, &named_transitions, &mut scratch);
        }
        if !self.condition_calls.is_empty() {
            let at = self.tag_span(pou);
            let message = format!(
                "a block wired into a condition of a chart of function block `{}`: Baton runs such blocks in a \
                 program's chart only; write the condition in ST",
                name.name
            );
            self.error(at, message);
        }
        let mut vars = vars;
        vars.append(&mut self.implicit);
        self.implicit = implicit;
        self.condition_calls = condition_calls;
        self.names = names;
        let actions: Vec<crate::front::model::FbAction> = scratch
            .actions
            .into_iter()
            .map(|a| crate::front::model::FbAction { name: a.name, body: a.body, sfc: a.sfc })
            .collect();
        let problems = std::mem::replace(&mut self.diags, outer);
        let range = pou.range();
        let span = Span::new(range.start, range.end);
        let body = body.unwrap_or_default();
        self.library.push(FbDef { name, returns, vars, body, actions, problems, span });
    }

    /// The project's global variable lists, outside any POU: a configuration's or a resource's `globalVars`
    /// (IEC, Beremiz), and the GVLs CODESYS and TwinCAT keep in project-level vendor data
    /// (`…/plcopenxml/globalvars`), which are named.
    pub(super) fn global_lists(&mut self, root: Node) -> Vec<(Option<Ident>, Vec<VarDecl>)> {
        let mut lists = Vec::new();
        for g in root.descendants().filter(|n| is(n, "globalVars")) {
            if g.parent_element().is_some_and(|p| is(&p, "interface")) {
                continue;
            }
            let name = if g.has_attribute("name") { self.ident_attr(g, "name") } else { None };
            let vars = self.var_list(g, VarSection::Global, flag(g, "constant"));
            lists.push((name, vars));
        }
        lists
    }

    pub(super) fn interface(&mut self, pou: Node) -> Vec<VarDecl> {
        let mut vars = Vec::new();
        let Some(interface) = child(pou, "interface") else { return vars };
        for block in interface.children().filter(Node::is_element) {
            let section = match block.tag_name().name() {
                "localVars" => VarSection::Local,
                "inputVars" => VarSection::Input,
                "outputVars" => VarSection::Output,
                "inOutVars" => VarSection::InOut,
                "externalVars" => VarSection::External,
                "globalVars" => VarSection::Global,
                "tempVars" => VarSection::Temp,
                _ => continue,
            };
            let constant = flag(block, "constant");
            vars.extend(self.var_list(block, section, constant));
        }
        vars
    }

    /// The `<variable>`s of a list (an interface's section, a structure's fields).
    pub(super) fn var_list(&mut self, block: Node, section: VarSection, constant: bool) -> Vec<VarDecl> {
        let mut vars = Vec::new();
        for v in children(block, "variable") {
            let Some(name) = self.ident_attr(v, "name") else { continue };
            let type_node = child(v, "type").and_then(|t| t.first_element_child());
            let array = type_node
                .filter(|t| t.tag_name().name() == "array")
                .and_then(|t| self.array_spec(t, child(v, "initialValue")));
            let type_name = match type_node {
                Some(t) => match type_name(t) {
                    Some(n) => n,
                    None => {
                        let message = match t.attribute("length") {
                            Some(n) => format!(
                                "a STRING holds 1 to {} characters, not `{n}`",
                                crate::limits::STRING_LENGTH_MAX
                            ),
                            None => format!("the type of variable `{}` names no type", name.name),
                        };
                        self.error(self.tag_span(t), message);
                        continue;
                    }
                },
                None => {
                    self.error(name.span, format!("variable `{}` has no type", name.name));
                    continue;
                }
            };
            let type_span = type_node.map_or(name.span, |t| self.tag_span(t));
            let init =
                child(v, "initialValue").and_then(|i| child(i, "simpleValue")).and_then(|s| self.expr_attr(s, "value"));
            // A function block instance's initial inputs: `<structValue><value member="PT">…`.
            let mut members = Vec::new();
            let struct_value = child(v, "initialValue").and_then(|i| child(i, "structValue"));
            for value in struct_value.into_iter().flat_map(|s| children(s, "value")) {
                let member = self.ident_attr(value, "member");
                let simple = child(value, "simpleValue").and_then(|s| self.expr_attr(s, "value"));
                if let (Some(member), Some(simple)) = (member, simple) {
                    members.push((member, simple));
                }
            }
            vars.push(VarDecl {
                name,
                section,
                constant,
                type_name: Ident { name: type_name, span: type_span },
                init,
                members,
                array,
                pragmas: Vec::new(),
                address: v.attribute("address").map(str::trim).filter(|a| !a.is_empty()).map(str::to_string),
            });
        }
        vars
    }

    /// A named action of the POU: its body in ST, LD or FBD.
    pub(super) fn named_action(&mut self, action: Node, named_transitions: &HashMap<String, Node>, chart: &mut Chart) {
        let Some(name) = self.ident_attr(action, "name") else {
            chart.broken.unnamed_action = true;
            return;
        };
        let span = self.tag_span(action);
        let body = child(action, "body").and_then(|b| b.first_element_child());
        if let Some(sfc) = body.filter(|b| is(b, "SFC")) {
            // An action written in SFC: its net as a chart of its own, in the order Beremiz would run it; the
            // actions drawn inline in it become the POU's, which every association names.
            let mut inner = Chart::empty(name.clone(), chart.kind, span);
            let ids = self.sfc(sfc, named_transitions, &mut inner);
            match baton_order(action) {
                Some(order) => apply_order(&mut inner, &ids, &order),
                None => walk_order(&mut inner),
            }
            chart.actions.append(&mut inner.actions);
            chart.broken.actions.append(&mut inner.broken.actions);
            let nested = Sfc { steps: inner.steps, transitions: inner.transitions, flags: sfc_flags(action) };
            let pragmas = self.documentation_pragmas(action);
            chart.actions.push(Action { name, body: Vec::new(), sfc: Some(Box::new(nested)), pragmas, span });
            return;
        }
        let (statements, pragmas) = match body {
            Some(b) => self.body_statements(b),
            None => {
                self.error(span, format!("action `{}` has no body", name.name));
                (None, Vec::new())
            }
        };
        if statements.is_none() {
            chart.broken.actions.push(name.key());
        }
        chart.actions.push(Action { name, body: statements.unwrap_or_default(), sfc: None, pragmas, span });
    }

    /// The statements of an action body (`<ST>`, `<LD>` or `<FBD>`), or `None` after an error.
    pub(super) fn body_statements(&mut self, body: Node) -> (Option<Vec<Stmt>>, Vec<Pragma>) {
        match body.tag_name().name() {
            "ST" => match self.fragment(body, FragmentKind::Statements) {
                (Some(Fragment::Statements(s)), pragmas) => (Some(s), pragmas),
                (_, pragmas) => (None, pragmas),
            },
            "LD" | "FBD" => (self.network_statements(body), Vec::new()),
            other => {
                let message = match other {
                    "IL" => "Instruction List bodies are not supported: write the action in ST, LD or FBD".to_string(),
                    _ => format!("`<{other}>` bodies are not supported"),
                };
                self.error(self.tag_span(body), message);
                (None, Vec::new())
            }
        }
    }
}

/// The SFC flags a CODESYS export says an action's chart uses (`addData/…/sfcsettings`: `Flags/Init@Use`,
/// `Flags/Reset@Use`); `None` where it says nothing.
fn sfc_flags(action: Node) -> Option<SfcFlags> {
    let flags = child(action, "addData")
        .into_iter()
        .flat_map(|a| children(a, "data"))
        .filter(|d| d.attribute("name") == Some(CODESYS_SFC_SETTINGS))
        .flat_map(|d| children(d, "SFCSettings"))
        .find_map(|s| child(s, "Flags"))?;
    let used = |name: &str| child(flags, name).and_then(|f| f.attribute("Use")).is_some_and(|u| u.trim() == "true");
    Some(SfcFlags { init: used("Init"), reset: used("Reset") })
}
