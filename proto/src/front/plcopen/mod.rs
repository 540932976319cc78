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
//!
//! The PLCopen TC6 XML reader (roxmltree, positions kept). It rebuilds the net from the consumer-side
//! arcs (walking back through selection divergences and simultaneous convergences to a transition's sources, forward
//! through convergences, divergences and jumps to its targets), turns wired LD/FBD logic into expressions and LD/FBD
//! bodies into assignments (with a budget on connections walked), and parses ST bodies with `parser::parse_fragment`,
//! markup blanked in place and each decoded entity noted in the offset map, so that diagnostics point into the XML. A
//! block with an `instanceName` becomes a call of that instance (`fb_call`), queued once after the calls its inputs
//! need: in an LD/FBD action it runs in execution order, and wired into a condition it goes, with the edge contacts'
//! statements, into the POU's action `COMPUTE_FUNCTION_BLOCKS`, held stored (S) by the first initial step
//! (`compute_blocks`), which is how Beremiz's generator compiles such a chart for matiec and so how OpenPLC runs it:
//! every cycle, after the transitions are judged; other blocks become operators or function calls that the compiler
//! types. A step's and a POU's `<documentation>` may hold pragmas; an `indicator` may list two names (`done, fault`); a
//! POU with Baton's order data is ordered by it. It orders elements depth first from the initial steps, as Beremiz's
//! generator does, because action order is execution order. An action whose body is `<SFC>` is read by the same walk
//! into the action's `Sfc` (its inline actions become the POU's); a `macroStep`'s body is read the same way and joined
//! to the chart, the macro standing for its entry step where arcs lead to it and its exit step where they leave it
//! (`macros`, `macro_ends`, both linear: continuations are found through a map of connectors, and a body's exit through
//! one pass over its arcs). CODESYS's per-step vendor data gives a step its active (N), entry and exit actions
//! (`codesys_step_actions`, by GUID); a function block's `<actions>` in ST become `FbDef::actions`; the project's
//! global variable lists (a configuration's or resource's `globalVars`, CODESYS's and TwinCAT's GVLs in project-level
//! vendor data) are given to every chart (`share_globals`: an external variable without a value takes the global's, a
//! global the POU does not declare becomes its VAR_GLOBAL) and the named ones kept as `Chart::global_lists`, so that
//! `GVL.x` resolves.
#![allow(
    clippy::disallowed_types,
    reason = "id and name tables, looked up only: the chart follows the XML's order (or Baton's element order)"
)]

mod net;
mod order;
mod pou;
mod task;
mod wires;
mod xml;

use std::collections::{HashMap, HashSet};

use roxmltree::{Document, Node, ParsingOptions};

use crate::front::diag::{Diagnostic, Span};
use crate::front::model::{Chart, Expr, FbDef, GlobalList, Ident, Pragma, Stmt, Transition, VarDecl, VarSection};
use crate::front::parser::{parse_fragment, Fragment, FragmentKind, Parsed};
use crate::limits::XML_NODES_MAX;

use xml::{blank_markup, child, is, offset_of, strip_position, BodyText};

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

pub(crate) const CODESYS_ACTIVE_ACTION: &str = "700a583f-b4d4-43e4-8c14-629c7cd3bec8";

/// CODESYS's per-POU (and per-action) SFC settings: which SFC flags its chart declares and uses.
pub(crate) const CODESYS_SFC_SETTINGS: &str = "http://www.3s-software.com/plcopenxml/sfcsettings";

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
        programs: Vec::new(),
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
    let names: Vec<String> = charts.iter().map(|c| c.name.key()).collect();
    for chart in &mut charts {
        reader.adopt_caller(chart, &names);
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
    /// Programs in ST, one of which may run a chart (`task`).
    programs: Vec<CallerProgram>,
}

/// A program with an ST body and no chart, kept in case it runs one of the file's charts.
pub(super) struct CallerProgram {
    pub name: Ident,
    pub vars: Vec<VarDecl>,
    pub body: Vec<Stmt>,
    pub problems: Vec<Diagnostic>,
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
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::front::model::BinOp;
    use crate::front::model::ExprKind;

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
