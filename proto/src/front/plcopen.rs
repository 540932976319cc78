//! Reads PLCopen TC6 XML (v1.0, v2.0, v2.01, as Beremiz/OpenPLC Editor, CODESYS V3.5 and TwinCAT 3 write it)
//! into the same chart model as the textual parser, with spans into the XML so that every diagnostic points
//! at the element's line.
//!
//! The SFC body is a graph of elements with `localId`s; edges exist only on the consumer side
//! (`connectionPointIn/connection@refLocalId`). A transition's sources are found walking back through selection
//! divergences and simultaneous convergences to steps; its targets walking forward through selection
//! convergences and simultaneous divergences to steps and jumps. Conditions and actions are ST text (parsed by
//! the textual parser as fragments, at their place in the file) or LD/FBD networks, which become expressions
//! and assignments. What Baton does not run yet is refused with an error that names it.
#![allow(
    clippy::disallowed_types,
    reason = "id and name tables, looked up only: the chart follows the XML's order (or Baton's element order)"
)]

use std::collections::{HashMap, HashSet};

use roxmltree::{Document, Node, ParsingOptions, TextPos};

use crate::front::diag::{Diagnostic, Span};
use crate::front::model::*;
use crate::front::parser::{parse_fragment, Fragment, FragmentKind, Parsed};
use crate::limits::{NESTING_DEPTH_MAX, XML_CONNECTIONS_WALKED_MAX, XML_NODES_MAX};

/// The `addData/data@name` under which Baton keeps its element order.
pub const ORDER_DATA: &str = "https://baton.dev/plcopen/element-order";

/// The namespaces of the TC6 versions Baton reads.
const NAMESPACES: [&str; 3] = [
    "http://www.plcopen.org/xml/tc6.xsd",
    "http://www.plcopen.org/xml/tc6_0200",
    "http://www.plcopen.org/xml/tc6_0201",
];

/// The action Beremiz generates for the blocks wired into a POU's conditions (its name, kept for the same reason).
const COMPUTE_BLOCKS: &str = "COMPUTE_FUNCTION_BLOCKS";
/// CODESYS V3.5's per-element vendor data, and the attribute in it that names a step's active (N) action.
pub(crate) const CODESYS_SFC_ELEMENT: &str = "http://www.3s-software.com/plcopenxml/sfc/element";
const CODESYS_ACTIVE_ACTION: &str = "700a583f-b4d4-43e4-8c14-629c7cd3bec8";
/// The project-level vendor data in which CODESYS and TwinCAT keep a global variable list (GVL).
pub(crate) const CODESYS_GLOBAL_VARS: &str = "http://www.3s-software.com/plcopenxml/globalvars";
/// A step's entry action (run once on activation) and exit action (once on deactivation) in the same vendor data.
pub(crate) const CODESYS_ENTRY_ACTION: &str = "a6b08bd8-b696-47e3-9cbf-7408b61c9ff8";
pub(crate) const CODESYS_EXIT_ACTION: &str = "a2621e18-7de3-4ea6-ae6d-89e9e0b7befd";

/// Whether a source text is XML (and so PLCopen) rather than textual SFC: decided by content, not file name.
pub fn looks_like_xml(src: &str) -> bool {
    src.trim_start_matches('\u{feff}').trim_start().starts_with('<')
}

pub fn parse(src: &str) -> Parsed {
    let options = ParsingOptions { allow_dtd: false, nodes_limit: XML_NODES_MAX, ..ParsingOptions::default() };
    let doc = match Document::parse_with_options(src, options) {
        Ok(doc) => doc,
        Err(e) => {
            let at = offset_of(src, e.pos());
            let message = format!("malformed XML: {}", strip_position(&e.to_string()));
            return Parsed {
                types: Vec::new(),
                charts: Vec::new(),
                library: Vec::new(),
                diagnostics: vec![Diagnostic::error(Span::new(at, at + 1), message)],
            };
        }
    };
    let mut reader = Reader {
        src,
        diags: Vec::new(),
        visits: 0,
        calls: Vec::new(),
        called: HashSet::new(),
        condition_calls: Vec::new(),
        edges: HashMap::new(),
        names: HashSet::new(),
        references: HashMap::new(),
        macros: HashMap::new(),
        macro_names: HashMap::new(),
        macro_depth: 0,
        library: Vec::new(),
        implicit: Vec::new(),
    };
    let root = doc.root_element();
    if root.tag_name().name() != "project" {
        let message =
            format!("not a PLCopen TC6 file: the root element is `<{}>`, expected `<project>`", root.tag_name().name());
        reader.diags.push(Diagnostic::error(reader.tag_span(root), message));
        return Parsed { charts: Vec::new(), types: Vec::new(), library: Vec::new(), diagnostics: reader.diags };
    }
    match root.tag_name().namespace() {
        Some(ns) if NAMESPACES.contains(&ns) => {}
        ns => {
            let message = format!(
                "unknown PLCopen namespace {}: read as TC6 v2.01 (known: {})",
                ns.map_or("(none)".to_string(), |n| format!("`{n}`")),
                NAMESPACES.join(", ")
            );
            reader.diags.push(Diagnostic::warning(reader.tag_span(root), message));
        }
    }
    // POUs under types/pous, and those that TwinCAT and CODESYS keep in project-level addData.
    let mut charts: Vec<Chart> =
        root.descendants().filter(|n| is(n, "pou")).filter_map(|pou| reader.pou(pou)).collect();
    let globals = reader.global_lists(root);
    for chart in &mut charts {
        share_globals(&mut chart.vars, &globals, true);
        chart.global_lists = globals
            .iter()
            .filter_map(|(name, vars)| {
                let vars = vars.iter().map(|v| v.name.clone()).collect();
                Some(GlobalList { name: name.clone()?, vars })
            })
            .collect();
    }
    for def in &mut reader.library {
        share_globals(&mut def.vars, &globals, false);
    }
    let types = reader.data_types(root);
    Parsed { charts, types, library: reader.library, diagnostics: reader.diags }
}

/// A project's global variables in a POU: an external variable declared without an initial value takes the
/// global's (Beremiz declares `VAR_EXTERNAL ResetCounterValue : INT;` and gives it 17 in the configuration), and,
/// where `add`, a global the POU does not declare is added as VAR_GLOBAL (CODESYS and TwinCAT POUs use GVL
/// variables without declaring them).
fn share_globals(vars: &mut Vec<VarDecl>, globals: &[(Option<Ident>, Vec<VarDecl>)], add: bool) {
    for global in globals.iter().flat_map(|(_, list)| list) {
        match vars.iter_mut().find(|v| v.name.key() == global.name.key()) {
            Some(v) if v.section == VarSection::External && v.init.is_none() && v.members.is_empty() => {
                v.init.clone_from(&global.init);
                v.members.clone_from(&global.members);
                if v.array.is_none() {
                    v.array.clone_from(&global.array);
                }
            }
            Some(_) => {}
            None if add => vars.push(global.clone()),
            None => {}
        }
    }
}

/// roxmltree ends its messages with ` at LINE:COL`, which the diagnostic header already says.
fn strip_position(message: &str) -> &str {
    match message.rfind(" at ") {
        Some(i) if message[i + 4..].chars().all(|c| c.is_ascii_digit() || c == ':') => &message[..i],
        _ => message,
    }
}

/// The byte offset of a 1-based line and character column.
fn offset_of(src: &str, pos: TextPos) -> usize {
    let mut line_start = 0;
    for _ in 1..pos.row {
        match src[line_start..].find('\n') {
            Some(i) => line_start += i + 1,
            None => return src.len(),
        }
    }
    let line = &src[line_start..];
    line_start + line.char_indices().nth(pos.col.saturating_sub(1) as usize).map_or(line.len(), |(i, _)| i)
}

fn is(n: &Node, name: &str) -> bool {
    n.is_element() && n.tag_name().name() == name
}

fn child<'a, 'i>(n: Node<'a, 'i>, name: &str) -> Option<Node<'a, 'i>> {
    n.children().find(|c| is(c, name))
}

fn children<'a, 'i: 'a>(n: Node<'a, 'i>, name: &'a str) -> impl Iterator<Item = Node<'a, 'i>> + 'a {
    n.children().filter(move |c| is(c, name))
}

/// An element's `localId`, where it is a number (`Reader::elements` reports it where it is not).
fn local_id(n: Node) -> Option<u64> {
    n.attribute("localId")?.trim().parse().ok()
}

fn flag(n: Node, attr: &str) -> bool {
    matches!(n.attribute(attr), Some("true" | "1"))
}

/// A transition, kept with what orders it among its siblings.
struct ReadTransition {
    transition: Transition,
    local_id: Option<u64>,
    /// The selection divergence it leaves from (its document index), else its own document index; then its
    /// drawn x position: Beremiz gives branches no priority, their order is left to right.
    order: (usize, f64, usize),
}

/// One body's elements by `localId`.
struct Elements<'a, 'i> {
    by_id: HashMap<u64, Node<'a, 'i>>,
    /// The `connector` elements by name (uppercase), which continuations of the same name continue: found once,
    /// not by a scan of the body per continuation.
    connectors: HashMap<String, Node<'a, 'i>>,
    /// Which elements take each element's output, in document order.
    consumers: HashMap<u64, Vec<u64>>,
    /// Document index of each element.
    index: HashMap<u64, usize>,
}

struct Reader<'s> {
    src: &'s str,
    diags: Vec<Diagnostic>,
    /// Connections followed since the last transition or network began (`too_deep`).
    visits: usize,
    /// Calls of the block instances the logic being read needs, in the order they must run, and the blocks
    /// (by `localId`) already called.
    calls: Vec<Stmt>,
    called: HashSet<u64>,
    /// The calls the POU's wired conditions need, in the order its transitions were read (see `compute_blocks`).
    condition_calls: Vec<Stmt>,
    /// The edge contacts of the network or condition being read (by `localId`), and the R_TRIG/F_TRIG instance
    /// each became; the names the POU declares, which those instances' names avoid.
    edges: HashMap<u64, String>,
    names: HashSet<String>,
    /// How many SFC transitions of the body being read refer to each named transition.
    references: HashMap<String, usize>,
    /// The macro steps of the body being read, by `localId`: the entry and exit steps of their bodies, which
    /// they stand for; and the entry steps by the macro step's name, for jumps to it.
    macros: HashMap<u64, (Ident, Ident)>,
    macro_names: HashMap<String, Ident>,
    /// Macro steps around the body being read.
    macro_depth: usize,
    /// Function blocks with ST bodies.
    library: Vec<FbDef>,
    /// Variables the POU being read needs that its interface does not declare (edge contacts' instances).
    implicit: Vec<VarDecl>,
}

impl Reader<'_> {
    fn error(&mut self, span: Span, message: impl Into<String>) {
        self.diags.push(Diagnostic::error(span, message));
    }

    /// The span of an element's `<name`, where a diagnostic about the element points.
    fn tag_span(&self, n: Node) -> Span {
        let start = n.range().start;
        let rest = &self.src[start..n.range().end];
        let len = rest.find(|c: char| c.is_whitespace() || c == '>' || c == '/').unwrap_or(rest.len());
        Span::new(start, start + len.max(1))
    }

    fn attr_span(&self, n: Node, attr: &str) -> Span {
        n.attribute_node(attr)
            .map_or_else(|| self.tag_span(n), |a| Span::new(a.range_value().start, a.range_value().end))
    }

    fn dangling(&mut self, at: Span, id: u64) {
        self.error(at, format!("`refLocalId` {id} points to no element of this body"));
    }

    /// A step's name where it has one (the step itself reports it where it has none).
    fn step_ident(&self, n: Node) -> Option<Ident> {
        let name = n.attribute("name").map(str::trim).filter(|name| !name.is_empty())?;
        Some(Ident { name: name.to_string(), span: self.attr_span(n, "name") })
    }

    /// An attribute as a name, or an error naming the element and the attribute.
    fn ident_attr(&mut self, n: Node, attr: &str) -> Option<Ident> {
        match n.attribute(attr).map(str::trim) {
            Some(name) if !name.is_empty() => Some(Ident { name: name.to_string(), span: self.attr_span(n, attr) }),
            _ => {
                let message = format!("`<{}>` has no `{attr}`", n.tag_name().name());
                self.error(self.tag_span(n), message);
                None
            }
        }
    }

    /// The text inside an element, with markup (`<xhtml:p>`, CDATA delimiters, comments) blanked out and
    /// entities decoded in place, so that each character keeps its offset in the file; and that offset.
    fn inner_text(&self, n: Node) -> (BodyText, usize) {
        let range = n.range();
        let raw = &self.src[range.clone()];
        if raw.ends_with("/>") && !raw.contains("</") {
            return (BodyText { text: String::new(), shifts: Vec::new() }, range.end);
        }
        let after_attrs = n.attributes().map(|a| a.range().end).max().unwrap_or(range.start);
        let open_end = self.src[after_attrs..range.end].find('>').map_or(range.end, |i| after_attrs + i + 1);
        let close = raw.rfind("</").map_or(range.end, |i| range.start + i).max(open_end);
        (blank_markup(&self.src[open_end..close]), open_end)
    }

    fn fragment(&mut self, n: Node, kind: FragmentKind) -> (Option<Fragment>, Vec<Pragma>) {
        let (body, base) = self.inner_text(n);
        if body.text.trim().is_empty() {
            let what = match kind {
                FragmentKind::Statements => return (Some(Fragment::Statements(Vec::new())), Vec::new()),
                _ => "an expression",
            };
            self.error(self.tag_span(n), format!("`<{}>` is empty: expected {what}", n.tag_name().name()));
            return (None, Vec::new());
        }
        self.parse_body(&body, base, kind)
    }

    /// Parses a body's text as `kind`, with every span at its place in the file.
    fn parse_body(&mut self, body: &BodyText, base: usize, kind: FragmentKind) -> (Option<Fragment>, Vec<Pragma>) {
        let parsed = parse_fragment(&body.text, |at| base + body.raw(at), kind);
        self.diags.extend(parsed.diagnostics);
        (parsed.fragment, parsed.pragmas)
    }

    /// The pragmas (`{agent := 'r1'}`) in an element's `<documentation>`: where a PLCopen file keeps what a
    /// textual chart writes as pragmas (placement, for one). The rest of the text is prose.
    fn documentation_pragmas(&mut self, n: Node) -> Vec<Pragma> {
        let Some(doc) = child(n, "documentation") else { return Vec::new() };
        let (body, base) = self.inner_text(doc);
        let mut out = Vec::new();
        let mut from = 0;
        while let Some(open) = body.text[from..].find('{').map(|i| from + i) {
            // A pragma ends at its first `}`.
            let Some(close) = body.text[open..].find('}').map(|i| open + i) else { break };
            let text = body.text[open + 1..close].trim().to_string();
            out.push(Pragma { text, span: Span::new(base + body.raw(open), base + body.raw(close + 1)) });
            from = close + 1;
        }
        out
    }

    fn expr_text(&mut self, n: Node) -> Option<Expr> {
        match self.fragment(n, FragmentKind::Expr).0 {
            Some(Fragment::Expr(e)) => Some(e),
            _ => None,
        }
    }

    /// An attribute's value as an expression (a duration, an initial value).
    fn expr_attr(&mut self, n: Node, attr: &str) -> Option<Expr> {
        let a = n.attribute_node(attr)?;
        let range = a.range_value();
        let body = blank_markup(&self.src[range.clone()]);
        match self.parse_body(&body, range.start, FragmentKind::Expr).0 {
            Some(Fragment::Expr(e)) => Some(e),
            _ => None,
        }
    }

    fn pou(&mut self, pou: Node) -> Option<Chart> {
        let Some(sfc) = child(pou, "body").and_then(|b| child(b, "SFC")) else {
            self.function_block(pou);
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
    fn array_spec(&mut self, array: Node, init: Option<Node>) -> Option<ArraySpec> {
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
    fn data_types(&mut self, root: Node) -> Vec<TypeDef> {
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
    fn function_block(&mut self, pou: Node) {
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
        // Its actions (CODESYS, TwinCAT), in ST, which an instance runs when called as `instance.Action();`.
        let mut actions = Vec::new();
        for a in child(pou, "actions").into_iter().flat_map(|x| children(x, "action")) {
            let Some(action) = self.ident_attr(a, "name") else { continue };
            match child(a, "body").and_then(|b| b.first_element_child()) {
                Some(st) if is(&st, "ST") => {
                    if let Some(Fragment::Statements(body)) = self.fragment(st, FragmentKind::Statements).0 {
                        actions.push(crate::front::model::FbAction { name: action, body });
                    }
                }
                Some(other) => {
                    let message = format!(
                        "action `{}` of function block `{}` has a `<{}>` body: Baton runs function blocks' actions \
                         written in ST",
                        action.name,
                        name.name,
                        other.tag_name().name()
                    );
                    self.error(self.tag_span(other), message);
                }
                None => actions.push(crate::front::model::FbAction { name: action, body: Vec::new() }),
            }
        }
        let problems = std::mem::replace(&mut self.diags, outer);
        let range = pou.range();
        let span = Span::new(range.start, range.end);
        let body = body.unwrap_or_default();
        self.library.push(FbDef { name, returns, vars, body, actions, problems, span });
    }

    /// The project's global variable lists, outside any POU: a configuration's or a resource's `globalVars`
    /// (IEC, Beremiz), and the GVLs CODESYS and TwinCAT keep in project-level vendor data
    /// (`…/plcopenxml/globalvars`), which are named.
    fn global_lists(&mut self, root: Node) -> Vec<(Option<Ident>, Vec<VarDecl>)> {
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

    fn interface(&mut self, pou: Node) -> Vec<VarDecl> {
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
    fn var_list(&mut self, block: Node, section: VarSection, constant: bool) -> Vec<VarDecl> {
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
            });
        }
        vars
    }

    /// A named action of the POU: its body in ST, LD or FBD.
    fn named_action(&mut self, action: Node, named_transitions: &HashMap<String, Node>, chart: &mut Chart) {
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
            let nested = Sfc { steps: inner.steps, transitions: inner.transitions };
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
    fn body_statements(&mut self, body: Node) -> (Option<Vec<Stmt>>, Vec<Pragma>) {
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

    /// An LD or FBD network as assignments: each coil and output variable, in execution order, gets what is
    /// wired to it.
    fn network_statements(&mut self, body: Node) -> Option<Vec<Stmt>> {
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

    /// A body's elements by `localId`; `structural` names the kinds whose inputs are SFC arcs, for `consumers`.
    fn elements<'a, 'i>(&mut self, body: Node<'a, 'i>, structural: &[&str]) -> Elements<'a, 'i> {
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
    fn connections(&mut self, n: Node) -> Vec<(u64, Option<String>, Span)> {
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
    fn sfc(&mut self, sfc: Node, named_transitions: &HashMap<String, Node>, chart: &mut Chart) -> Vec<Option<u64>> {
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
                macro_names.insert(name.to_ascii_uppercase(), entry);
            }
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
    fn compute_blocks(&mut self, chart: &mut Chart) {
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
        step.associations.push(Association {
            action: name.clone(),
            qualifier: Qualifier::S,
            qualifier_span: step.span,
            duration: None,
            indicators: Vec::new(),
            span: step.span,
        });
        chart.actions.push(Action { name, body, sfc: None, pragmas: Vec::new(), span: step.span });
    }

    /// A macro step's entry step (its body's initial step, or else the one no transition of the body leads to)
    /// and its exit step (the one no transition of the body leaves); the entry step stops being initial.
    fn macro_ends(&mut self, inner: &mut Chart, span: Span) -> Option<(Ident, Ident)> {
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
    fn codesys_step_actions(&mut self, step_node: Node, step: &mut Step) {
        let attributes = child(step_node, "addData")
            .into_iter()
            .flat_map(|a| children(a, "data"))
            .filter(|d| d.attribute("name") == Some(CODESYS_SFC_ELEMENT))
            .flat_map(|d| children(d, "attributes"))
            .flat_map(|a| children(a, "attribute"));
        for a in attributes {
            let qualifier = match a.attribute("guid") {
                Some(CODESYS_ACTIVE_ACTION) => Qualifier::N,
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

    fn transition(
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

    fn too_deep(&mut self, depth: usize, span: Span) -> bool {
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
    fn sources(&mut self, elements: &Elements, id: u64, at: Span, out: &mut Vec<Ident>, depth: usize) -> bool {
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
    fn targets(&mut self, elements: &Elements, id: u64, at: Span, out: &mut Vec<Ident>, depth: usize) -> bool {
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

    /// A transition's condition: inline ST, a named transition's body, or LD/FBD logic wired to it.
    fn condition(
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

    fn unsupported_language(&mut self, body: Node) {
        let message = match body.tag_name().name() {
            "IL" => "Instruction List conditions are not supported: write the condition in ST".to_string(),
            other => format!("`<{other}>` bodies are not supported here"),
        };
        self.error(self.tag_span(body), message);
    }

    /// The body of a named transition, `pou/transitions/transition@name`.
    fn named_condition(&mut self, reference: Node, named: &HashMap<String, Node>) -> Option<Expr> {
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
    fn wired(&mut self, elements: &Elements, n: Node, depth: usize) -> Option<Expr> {
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
    fn bounded(&mut self, e: Expr, at: Span) -> Option<Expr> {
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
    fn output_of(
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
    fn fb_call(&mut self, elements: &Elements, n: Node, depth: usize) -> Option<Ident> {
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
    fn block(&mut self, elements: &Elements, n: Node, formal: Option<&str>, depth: usize) -> Option<Expr> {
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

    fn action_block(
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

/// Baton's element order from a POU's `addData` (see `ORDER_DATA`): step names, transition
/// `localId`s and action names.
struct BatonOrder {
    steps: Vec<String>,
    transitions: Vec<u64>,
    actions: Vec<String>,
}

fn baton_order(pou: Node) -> Option<BatonOrder> {
    let data = child(pou, "addData")?.children().find(|d| is(d, "data") && d.attribute("name") == Some(ORDER_DATA))?;
    let order = child(data, "order")?;
    let words = |attr: &str| -> Vec<String> {
        order.attribute(attr).unwrap_or_default().split_whitespace().map(str::to_ascii_uppercase).collect()
    };
    Some(BatonOrder {
        steps: words("steps"),
        transitions: words("transitions").iter().filter_map(|w| w.parse().ok()).collect(),
        actions: words("actions"),
    })
}

/// Orders the chart's elements as the order data says; what it does not name keeps its place after them.
fn apply_order(chart: &mut Chart, transition_ids: &[Option<u64>], order: &BatonOrder) {
    fn rank<T>(items: &mut Vec<T>, key: impl Fn(usize, &T) -> Option<usize>) {
        let mut keyed: Vec<(usize, usize, T)> =
            items.drain(..).enumerate().map(|(i, t)| (key(i, &t).unwrap_or(usize::MAX), i, t)).collect();
        keyed.sort_by_key(|(k, i, _)| (*k, *i));
        items.extend(keyed.into_iter().map(|(_, _, t)| t));
    }
    let position =
        |list: &[String]| -> HashMap<String, usize> { list.iter().enumerate().map(|(i, n)| (n.clone(), i)).collect() };
    let steps = position(&order.steps);
    rank(&mut chart.steps, |_, s| steps.get(&s.name.key()).copied());
    let transitions: HashMap<u64, usize> = order.transitions.iter().enumerate().map(|(i, id)| (*id, i)).collect();
    rank(&mut chart.transitions, |i, _| {
        transition_ids.get(i).copied().flatten().and_then(|id| transitions.get(&id).copied())
    });
    let actions = position(&order.actions);
    rank(&mut chart.actions, |_, a| actions.get(&a.name.key()).copied());
}

/// Orders steps, transitions and actions as Beremiz's generator writes the chart out for matiec (and so as
/// OpenPLC runs it): depth first from the initial steps, each step followed by its actions and its outgoing
/// transitions in priority order, each transition by the steps it leads to. Action order is execution order
/// within a cycle, so a chart imported from XML runs as it does in the tool that drew it. What the walk does not
/// reach keeps its document order, after the rest.
fn walk_order(chart: &mut Chart) {
    let step_of: HashMap<String, usize> = chart.steps.iter().enumerate().map(|(i, s)| (s.name.key(), i)).collect();
    let mut outgoing: Vec<Vec<usize>> = vec![Vec::new(); chart.steps.len()];
    for (t, tr) in chart.transitions.iter().enumerate() {
        for from in &tr.from {
            if let Some(&s) = step_of.get(&from.key()) {
                outgoing[s].push(t);
            }
        }
    }
    let (mut visited, mut placed) = (vec![false; chart.steps.len()], vec![false; chart.transitions.len()]);
    let (mut step_order, mut transition_order) = (Vec::new(), Vec::new());
    // (step, next outgoing transition, the transition whose targets are being visited and the next target)
    type Frame = (usize, usize, Option<(usize, usize)>);
    let mut frames: Vec<Frame> = Vec::new();
    let roots: Vec<usize> =
        (0..chart.steps.len()).filter(|&i| chart.steps[i].initial).chain(0..chart.steps.len()).collect();
    for root in roots {
        if visited[root] {
            continue;
        }
        visited[root] = true;
        step_order.push(root);
        frames.push((root, 0, None));
        while let Some(frame) = frames.last_mut() {
            if let Some((t, k)) = frame.2 {
                let targets = &chart.transitions[t].to;
                if k < targets.len() {
                    frame.2 = Some((t, k + 1));
                    if let Some(&s) = step_of.get(&targets[k].key()) {
                        if !visited[s] {
                            visited[s] = true;
                            step_order.push(s);
                            frames.push((s, 0, None));
                        }
                    }
                } else {
                    frame.2 = None;
                }
                continue;
            }
            let step = frame.0;
            if frame.1 < outgoing[step].len() {
                let t = outgoing[step][frame.1];
                frame.1 += 1;
                if !placed[t] {
                    placed[t] = true;
                    transition_order.push(t);
                    frame.2 = Some((t, 0));
                }
                continue;
            }
            frames.pop();
        }
    }
    transition_order.extend((0..chart.transitions.len()).filter(|&t| !placed[t]));
    let action_of: HashMap<String, usize> = chart.actions.iter().enumerate().map(|(i, a)| (a.name.key(), i)).collect();
    let mut action_placed = vec![false; chart.actions.len()];
    let mut action_order = Vec::new();
    for &s in &step_order {
        for association in &chart.steps[s].associations {
            if let Some(&a) = action_of.get(&association.action.key()) {
                if !std::mem::replace(&mut action_placed[a], true) {
                    action_order.push(a);
                }
            }
        }
    }
    action_order.extend((0..chart.actions.len()).filter(|&a| !action_placed[a]));
    fn reorder<T>(items: &mut Vec<T>, order: &[usize]) {
        let mut slots: Vec<Option<T>> = std::mem::take(items).into_iter().map(Some).collect();
        items.extend(order.iter().filter_map(|&i| slots[i].take()));
    }
    reorder(&mut chart.steps, &step_order);
    reorder(&mut chart.transitions, &transition_order);
    reorder(&mut chart.actions, &action_order);
}

fn not(e: Expr) -> Expr {
    let span = e.span;
    Expr { kind: ExprKind::Unary(UnOp::Not, Box::new(e)), span }
}

fn binary(op: BinOp, a: Expr, b: Expr) -> Expr {
    let span = a.span.to(b.span);
    Expr { kind: ExprKind::Binary(op, Box::new(a), Box::new(b)), span }
}

/// The text of an element with markup blanked out and entities decoded, and how to find each of its bytes in the
/// file: a tag, a comment and CDATA delimiters become spaces (newlines kept) so that offsets stay; an entity
/// becomes its character, which shortens the text (padding it would split `&gt;=`), and each one is noted.
struct BodyText {
    text: String,
    /// (offset in `text` after an entity, bytes the text is shorter than the file from there on).
    shifts: Vec<(usize, usize)>,
}

impl BodyText {
    /// The file offset (relative to where the text starts) of offset `at` of the text.
    fn raw(&self, at: usize) -> usize {
        let i = self.shifts.partition_point(|&(pos, _)| pos <= at);
        at + if i == 0 { 0 } else { self.shifts[i - 1].1 }
    }
}

fn blank_markup(raw: &str) -> BodyText {
    let mut out = String::with_capacity(raw.len());
    let mut shifts = Vec::new();
    let mut rest = raw;
    while let Some(c) = rest.chars().next() {
        if let Some(inner) = rest.strip_prefix("<![CDATA[") {
            out.push_str("         ");
            let end = inner.find("]]>").unwrap_or(inner.len());
            out.push_str(&inner[..end]);
            rest = &inner[end..];
            if let Some(r) = rest.strip_prefix("]]>") {
                out.push_str("   ");
                rest = r;
            }
        } else if rest.starts_with("<!--") {
            let end = rest.find("-->").map_or(rest.len(), |i| i + 3);
            blank_bytes(&mut out, &rest[..end]);
            rest = &rest[end..];
        } else if c == '<' {
            let end = rest.find('>').map_or(rest.len(), |i| i + 1);
            blank_bytes(&mut out, &rest[..end]);
            rest = &rest[end..];
        } else if c == '&' {
            let end = rest.find(';').filter(|&i| i <= 10);
            match end.and_then(|i| Some((i, entity(&rest[1..i])?))) {
                Some((i, ch)) => {
                    out.push(ch);
                    let extra = shifts.last().map_or(0, |&(_, e)| e) + (i + 1 - ch.len_utf8());
                    shifts.push((out.len(), extra));
                    rest = &rest[i + 1..];
                }
                None => {
                    out.push('&');
                    rest = &rest[1..];
                }
            }
        } else {
            out.push(c);
            rest = &rest[c.len_utf8()..];
        }
    }
    BodyText { text: out, shifts }
}

/// The name of the type a `<type>`'s element stands for: a derived type's name, `STRING[n]` for a string with a
/// length, the element's name in capitals for an elementary type; `None` for an unnamed derived type or a length
/// that is no number.
fn type_name(t: Node) -> Option<String> {
    match t.tag_name().name() {
        "derived" => Some(t.attribute("name")?.to_string()),
        "string" => match t.attribute("length") {
            Some(n) => {
                let n: usize = n.trim().parse().ok()?;
                (1..=crate::limits::STRING_LENGTH_MAX).contains(&n).then(|| format!("STRING[{n}]"))
            }
            None => Some("STRING".to_string()),
        },
        other => Some(other.to_ascii_uppercase()),
    }
}

/// Spaces for every byte of `s` but newlines, so that offsets and lines stay as they were.
fn blank_bytes(out: &mut String, s: &str) {
    out.extend(s.bytes().map(|b| if b == b'\n' { '\n' } else { ' ' }));
}

fn entity(name: &str) -> Option<char> {
    Some(match name {
        "lt" => '<',
        "gt" => '>',
        "amp" => '&',
        "quot" => '"',
        "apos" => '\'',
        _ => {
            let code = match name.strip_prefix("#x").or_else(|| name.strip_prefix("#X")) {
                Some(hex) => u32::from_str_radix(hex, 16).ok()?,
                None => name.strip_prefix('#')?.parse().ok()?,
            };
            char::from_u32(code)?
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn markup_is_blanked_in_place_and_entities_are_mapped_back() {
        let raw = "<xhtml:p><![CDATA[a < b]]></xhtml:p>";
        let body = blank_markup(raw);
        assert_eq!(body.text.len(), raw.len());
        assert_eq!(body.text.trim(), "a < b");
        assert_eq!(body.text.find('a'), raw.find('a'));
        let raw = "x &lt;= 3 AND y &gt;= 1 AND z &lt;&gt; 2";
        let body = blank_markup(raw);
        assert_eq!(body.text, "x <= 3 AND y >= 1 AND z <> 2");
        for word in ["y", "z", "2"] {
            let at = body.text.find(word).unwrap();
            assert_eq!(&raw[body.raw(at)..body.raw(at) + 1], word);
        }
    }

    /// A transition whose inline ST condition is `cond`, in an otherwise valid file.
    fn with_condition(cond: &str) -> String {
        format!(
            "<project xmlns=\"http://www.plcopen.org/xml/tc6_0201\"><types><pous><pou name=\"P\" pouType=\"program\">\
             <interface><localVars><variable name=\"a\"><type><INT/></type></variable>\
             <variable name=\"bb\"><type><INT/></type></variable></localVars></interface><body><SFC>\
             <step localId=\"1\" name=\"S\" initialStep=\"true\"/>\
             <transition localId=\"2\"><connectionPointIn><connection refLocalId=\"1\"/></connectionPointIn>\
             <condition><inline><ST>{cond}</ST></inline></condition></transition>\
             <jumpStep localId=\"3\" targetName=\"S\"><connectionPointIn><connection refLocalId=\"2\"/></connectionPointIn></jumpStep>\
             </SFC></body></pou></pous></types></project>"
        )
    }

    #[test]
    fn names_and_errors_after_entities_keep_their_place_in_the_file() {
        let src = with_condition("a &lt;&gt; bb");
        let parsed = parse(&src);
        assert!(parsed.diagnostics.is_empty(), "{:?}", parsed.diagnostics);
        let ExprKind::Binary(BinOp::Ne, _, rhs) = &parsed.charts[0].transitions[0].condition.kind else {
            panic!("{:?}", parsed.charts[0].transitions[0].condition)
        };
        let ExprKind::Name(id) = &rhs.kind else { panic!("{rhs:?}") };
        assert_eq!(id.name, "bb");
        assert_eq!(&src[id.span.start as usize..id.span.end as usize], "bb");
        let src = with_condition("a &lt;&gt; )");
        let parsed = parse(&src);
        let d = &parsed.diagnostics[0];
        assert_eq!(&src[d.span.start as usize..d.span.end as usize], ")", "{}", d.message);
    }

    #[test]
    fn malformed_xml_is_one_error_at_its_place() {
        let src = "<project>\n  <types>\n</project>\n";
        let parsed = parse(src);
        assert_eq!(parsed.diagnostics.len(), 1);
        let d = &parsed.diagnostics[0];
        assert!(d.message.starts_with("malformed XML"), "{}", d.message);
        assert_eq!(crate::front::diag::LineIndex::new(src).line_col(d.span.start).0, 3);
    }
}
