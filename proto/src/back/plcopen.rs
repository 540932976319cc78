//! PLCopen TC6 v2.01 XML from checked charts, laid out so that an IDE (Beremiz, OpenPLC Editor) shows a
//! readable chart: steps in rows by their distance from the initial steps, branches side by side, back edges
//! as jumps.
//!
//! The net becomes the standard's elements: a step with several outgoing transitions gets a selection
//! divergence, a step with several forward incoming ones a selection convergence, a transition with several
//! sources a simultaneous convergence and one with several targets a simultaneous divergence; a transition to a
//! step on its own row or above is drawn as a jump. Named transitions and actions go to the POU's
//! `transitions` and `actions` with ST bodies; a step's pragmas (placement) to its documentation, the chart's to
//! the POU's. Baton's element order — which is execution order — goes to the POU's `addData` under
//! `ORDER_DATA`, which Baton's reader follows and other tools ignore, so that importing the export gives the
//! same program.
//!
//! PLCopen TC6 v2.01 XML from a chart and its program (`baton export --plcopen`): rows by breadth-first
//! distance, back edges as jumps, divergences and convergences where the net needs them, every transition's priority
//! (the clearing order), named transitions and actions with ST bodies, step pragmas in `documentation`, and Baton's
//! element order in the POU's `addData` (`ORDER_DATA`), which the reader follows instead of its Beremiz order. An
//! imported chart whose conditions were wired to blocks exports its `COMPUTE_FUNCTION_BLOCKS` action as any ST action,
//! so every valid chart exports. The test of "the same chart" is `tests/src/roundtrip.rs`.
#![allow(clippy::disallowed_types, reason = "tables looked up only: the XML follows the chart's order")]

use std::collections::HashMap;
use std::fmt::Write;

use crate::back::diagram::{Diagram, BRANCH, COLUMN, STEP_H, STEP_W};
use crate::back::st;
use crate::exec::program::{Program, TransitionId};
use crate::front::model::{
    Action, ArraySpec, Chart, Duration, FbDef, Ident, PouKind, Pragma, Qualifier, TypeDef, TypeKind, VarDecl,
    VarSection,
};
use crate::front::plcopen::ORDER_DATA;

/// The TC6 element of an elementary type, or `None` for a derived one.
fn elementary(upper: &str) -> Option<&'static str> {
    Some(match upper {
        "BOOL" => "BOOL",
        "BYTE" => "BYTE",
        "WORD" => "WORD",
        "DWORD" => "DWORD",
        "LWORD" => "LWORD",
        "SINT" => "SINT",
        "INT" => "INT",
        "DINT" => "DINT",
        "LINT" => "LINT",
        "USINT" => "USINT",
        "UINT" => "UINT",
        "UDINT" => "UDINT",
        "ULINT" => "ULINT",
        "REAL" => "REAL",
        "LREAL" => "LREAL",
        "TIME" => "TIME",
        "DATE" => "DATE",
        "DT" | "DATE_AND_TIME" => "DT",
        "TOD" | "TIME_OF_DAY" => "TOD",
        "STRING" => "string",
        "WSTRING" => "wstring",
        _ => return None,
    })
}

/// An array's initial elements as `<initialValue><arrayValue>` (nothing when it has none).
fn array_value(spec: &ArraySpec) -> String {
    if spec.init.is_empty() {
        return String::new();
    }
    let value = |r: &crate::front::model::InitRun| {
        let repeat = if r.count == 1 { String::new() } else { format!(" repetitionValue=\"{}\"", r.count) };
        format!("<value{repeat}><simpleValue value=\"{}\"/></value>", esc(&st::expr(&r.value)))
    };
    let values: String = spec.init.iter().map(value).collect();
    format!("<initialValue><arrayValue>{values}</arrayValue></initialValue>")
}

/// `<array>` with its dimensions and element type.
fn array_element(spec: &ArraySpec) -> String {
    let dims: String = spec.dims.iter().map(|(l, h)| format!("<dimension lower=\"{l}\" upper=\"{h}\"/>")).collect();
    format!("<array>{dims}<baseType>{}</baseType></array>", type_element(&spec.elem.name))
}

/// The TC6 element of a type: elementary, or derived by name.
fn type_element(name: &str) -> String {
    let upper = name.to_ascii_uppercase();
    if let Some(n) = upper.strip_prefix("STRING[").and_then(|r| r.strip_suffix(']')) {
        return format!("<string length=\"{}\"/>", esc(n));
    }
    match elementary(&upper) {
        Some(e) => format!("<{e}/>"),
        None => format!("<derived name=\"{}\"/>", esc(name)),
    }
}

/// Escapes text for an attribute value or element content. XML 1.0 has no place for control characters other
/// than tab and line ends: they are written as `\u{..}`, visibly, rather than making the file unreadable.
pub fn esc(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&apos;"),
            '\t' | '\n' | '\r' => out.push(c),
            c if (c as u32) < 0x20 => out.push_str(&format!("\\u{{{:x}}}", c as u32)),
            c => out.push(c),
        }
    }
    out
}

/// Text as a CDATA section inside `<xhtml:p>` (a `]]>` in the text is split across two sections).
fn xhtml(text: &str) -> String {
    format!("<xhtml:p><![CDATA[{}]]></xhtml:p>", text.replace("]]>", "]]]]><![CDATA[>"))
}

fn pragmas_text(pragmas: &[Pragma]) -> String {
    pragmas.iter().map(|p| format!("{{{}}}", p.text)).collect::<Vec<_>>().join("\n")
}

/// A PLCopen project holding each chart with its program (a chart that compiled without errors).
/// `created` is the file header's `creationDateTime` (`2026-12-01T12:00:00`): the caller's clock.
/// `library` holds the file's function blocks and functions with ST bodies: every one Baton read whole is
/// written too, before the charts.
pub fn export(
    charts: &[(&Chart, &Program)],
    library: &[FbDef],
    types: &[TypeDef],
    project: &str,
    created: &str,
) -> String {
    let mut out = String::new();
    out.push_str("<?xml version=\"1.0\" encoding=\"utf-8\"?>\n");
    out.push_str(
        "<project xmlns=\"http://www.plcopen.org/xml/tc6_0201\" xmlns:xhtml=\"http://www.w3.org/1999/xhtml\">\n",
    );
    let _ = writeln!(
        out,
        "  <fileHeader companyName=\"Baton\" productName=\"baton\" productVersion=\"{}\" creationDateTime=\"{}\"/>",
        env!("CARGO_PKG_VERSION"),
        esc(created)
    );
    let _ = writeln!(out, "  <contentHeader name=\"{}\" modificationDateTime=\"{}\">", esc(project), esc(created));
    out.push_str(
        "    <coordinateInfo>\n      <fbd><scaling x=\"0\" y=\"0\"/></fbd>\n      <ld><scaling x=\"0\" y=\"0\"/></ld>\n      <sfc><scaling x=\"0\" y=\"0\"/></sfc>\n    </coordinateInfo>\n  </contentHeader>\n",
    );
    out.push_str("  <types>\n    <dataTypes>\n");
    for t in types {
        data_type(&mut out, t);
    }
    out.push_str("    </dataTypes>\n    <pous>\n");
    for def in whole_blocks(library) {
        function_block(&mut out, def, library, types);
    }
    for (chart, program) in charts {
        pou(&mut out, chart, program, library, types);
    }
    out.push_str("    </pous>\n  </types>\n  <instances>\n    <configurations/>\n  </instances>\n");
    global_lists(&mut out, charts);
    out.push_str("</project>\n");
    out
}

/// The charts' named global variable lists, as CODESYS writes its GVLs: in project-level vendor data, so that
/// `GVL.x` reads back. (Their variables are in each chart's interface too, as VAR_GLOBAL.)
fn global_lists(out: &mut String, charts: &[(&Chart, &Program)]) {
    let mut written: Vec<String> = Vec::new();
    let mut text = String::new();
    for (chart, _) in charts {
        for list in &chart.global_lists {
            if written.contains(&list.name.key()) {
                continue;
            }
            written.push(list.name.key());
            let vars: Vec<&VarDecl> =
                list.vars.iter().filter_map(|v| chart.vars.iter().find(|d| d.name.key() == v.key())).collect();
            let constant = !vars.is_empty() && vars.iter().all(|v| v.constant);
            let _ = writeln!(
                text,
                "    <data name=\"{}\" handleUnknown=\"implementation\">\n      <globalVars name=\"{}\"{}>",
                crate::front::plcopen::CODESYS_GLOBAL_VARS,
                esc(&list.name.name),
                if constant { " constant=\"true\"" } else { "" }
            );
            for v in vars {
                variable(&mut text, v);
            }
            text.push_str("      </globalVars>\n    </data>\n");
        }
    }
    if !text.is_empty() {
        let _ = write!(out, "  <addData>\n{text}  </addData>\n");
    }
}

fn pou(out: &mut String, chart: &Chart, program: &Program, library: &[FbDef], types: &[TypeDef]) {
    let kind = match chart.kind {
        PouKind::FunctionBlock => "functionBlock",
        PouKind::Program | PouKind::Bare => "program",
    };
    let _ = writeln!(out, "      <pou name=\"{}\" pouType=\"{kind}\">", esc(&chart.name.name));
    interface(out, &chart.vars);
    let named: HashMap<String, &Action> = chart.actions.iter().map(|a| (a.name.key(), a)).collect();
    out.push_str("        <actions>\n");
    for a in &program.actions {
        let Some(action) = named.get(&a.name.to_ascii_uppercase()) else { continue };
        if let Some(sfc) = &action.sfc {
            let pou = Pou { vars: &chart.vars, actions: &chart.actions, kind: chart.kind };
            nested(out, &pou, &action.name, &action.pragmas, sfc, library, types);
            continue;
        }
        let mut text = pragmas_text(&action.pragmas);
        if !text.is_empty() {
            text.push('\n');
        }
        text.push_str(&st::statements(&action.body, 0));
        let _ = writeln!(
            out,
            "          <action name=\"{}\">\n            <body>\n              <ST>{}</ST>\n            </body>\n          </action>",
            esc(&action.name.name),
            xhtml(&text)
        );
    }
    out.push_str("        </actions>\n");
    // A chart without errors compiles to a program whose steps and transitions are the chart's, in order.
    out.push_str("        <transitions>\n");
    for (t, tr) in program.transitions.iter().zip(&chart.transitions) {
        if tr.name.is_none() {
            continue;
        }
        let mut text = pragmas_text(&tr.pragmas);
        if !text.is_empty() {
            text.push('\n');
        }
        let _ = write!(text, ":= {};", st::expr(&tr.condition));
        let _ = writeln!(
            out,
            "          <transition name=\"{}\">\n            <body>\n              <ST>{}</ST>\n            </body>\n          </transition>",
            esc(&t.name),
            xhtml(&text)
        );
    }
    out.push_str("        </transitions>\n");
    out.push_str("        <body>\n          <SFC>\n");
    let order = Sfc::new(chart, program).write(out);
    out.push_str("          </SFC>\n        </body>\n");
    order_data(out, "        ", &order.steps, &order.transitions, &order.actions);
    if !chart.pragmas.is_empty() {
        let _ = writeln!(out, "        <documentation>{}</documentation>", xhtml(&pragmas_text(&chart.pragmas)));
    }
    out.push_str("      </pou>\n");
}

/// Baton's element order (`ORDER_DATA`) as an `addData` block at `indent`.
fn order_data(out: &mut String, indent: &str, steps: &str, transitions: &str, actions: &str) {
    order_data_with(out, indent, steps, transitions, actions, "");
}

/// The same, with more `<data>` (a line, or nothing) in the one `addData` an element may have.
fn order_data_with(out: &mut String, indent: &str, steps: &str, transitions: &str, actions: &str, more: &str) {
    let _ = writeln!(
        out,
        "{indent}<addData>\n{indent}  <data name=\"{ORDER_DATA}\" handleUnknown=\"discard\">\n{indent}    <order steps=\"{}\" transitions=\"{transitions}\" actions=\"{}\"/>\n{indent}  </data>\n{more}{indent}</addData>",
        esc(steps),
        esc(actions)
    );
}

/// An action written in SFC: its chart drawn as the POU's is, with Baton's order in the action's `addData`. The
/// net comes from compiling the nested chart as a chart of its own with the POU's variables and actions (what
/// that reports is the real compile's business).
/// The POU an action written in SFC belongs to: a chart, or a function block.
struct Pou<'a> {
    vars: &'a [VarDecl],
    actions: &'a [Action],
    kind: PouKind,
}

fn nested(
    out: &mut String,
    pou: &Pou,
    name: &Ident,
    pragmas: &[Pragma],
    sfc: &crate::front::model::Sfc,
    library: &[FbDef],
    types: &[TypeDef],
) {
    let shadow = Chart {
        vars: pou.vars.to_vec(),
        steps: sfc.steps.clone(),
        transitions: sfc.transitions.clone(),
        actions: pou.actions.iter().map(|a| Action { body: Vec::new(), sfc: None, ..a.clone() }).collect(),
        ..Chart::empty(name.clone(), pou.kind, name.span)
    };
    let program = crate::exec::compile::compile(&shadow, library, types, &mut Vec::new()).program;
    let _ = writeln!(out, "          <action name=\"{}\">\n            <body>\n              <SFC>", esc(&name.name));
    let order = Sfc::new(&shadow, &program).write(out);
    out.push_str("              </SFC>\n            </body>\n");
    // Its actions are the POU's, ordered there; the SFC flags its chart uses, where the file it was read from said
    // (CODESYS's settings).
    let settings = sfc.flags.map_or(String::new(), |flags| {
        format!(
            "              <data name=\"{}\" handleUnknown=\"implementation\"><SFCSettings><Flags><Init Declare=\"true\" Use=\"{}\"/><Reset Declare=\"true\" Use=\"{}\"/></Flags></SFCSettings></data>\n",
            crate::front::plcopen::CODESYS_SFC_SETTINGS,
            flags.init,
            flags.reset
        )
    });
    order_data_with(out, "            ", &order.steps, &order.transitions, "", &settings);
    if !pragmas.is_empty() {
        let _ = writeln!(out, "            <documentation>{}</documentation>", xhtml(&pragmas_text(pragmas)));
    }
    out.push_str("          </action>\n");
}

/// A declared type; kinds Baton does not execute are left out (a chart using one does not export).
fn data_type(out: &mut String, t: &TypeDef) {
    let (base, init) = match &t.kind {
        TypeKind::Enum { values, init } => {
            let values: String =
                values.iter().map(|v| format!("<value name=\"{}\"/>", esc(&v.name))).collect::<Vec<_>>().join("");
            (format!("<enum><values>{values}</values></enum>"), init.as_ref().map(|i| i.name.clone()))
        }
        TypeKind::Subrange { base, low, high } => {
            let signed = !matches!(
                base.key().as_str(),
                "USINT" | "UINT" | "UDINT" | "ULINT" | "BYTE" | "WORD" | "DWORD" | "LWORD"
            );
            let tag = if signed { "subrangeSigned" } else { "subrangeUnsigned" };
            (
                format!(
                    "<{tag}><range lower=\"{low}\" upper=\"{high}\"/><baseType>{}</baseType></{tag}>",
                    type_element(&base.name)
                ),
                None,
            )
        }
        TypeKind::Alias(base) => (type_element(&base.name), None),
        TypeKind::Array(spec) => (array_element(spec), None),
        TypeKind::Struct(fields) => {
            let mut s = String::from("<struct>\n");
            for f in fields {
                variable(&mut s, f);
            }
            s.push_str("      </struct>");
            (s, None)
        }
        TypeKind::Unsupported(_) => return,
    };
    let _ = write!(out, "      <dataType name=\"{}\"><baseType>{base}</baseType>", esc(&t.name.name));
    if let TypeKind::Array(spec) = &t.kind {
        out.push_str(&array_value(spec));
    }
    if let Some(init) = init {
        let _ = write!(out, "<initialValue><simpleValue value=\"{}\"/></initialValue>", esc(&init));
    }
    out.push_str("</dataType>\n");
}

/// The library's function blocks and functions that Baton read whole (those with syntax errors are left out:
/// no chart that exports uses one), in library order.
fn whole_blocks(library: &[FbDef]) -> Vec<&FbDef> {
    library.iter().filter(|d| d.problems.is_empty()).collect()
}

fn function_block(out: &mut String, def: &FbDef, library: &[FbDef], types: &[TypeDef]) {
    let kind = if def.returns.is_some() { "function" } else { "functionBlock" };
    let _ = writeln!(out, "      <pou name=\"{}\" pouType=\"{kind}\">", esc(&def.name.name));
    interface_returning(out, &def.vars, def.returns.as_ref());
    if !def.actions.is_empty() {
        out.push_str("        <actions>\n");
        // The block's actions as a chart's, for the nested charts' associations (their bodies do not matter there).
        let actions: Vec<Action> = def
            .actions
            .iter()
            .map(|a| Action { name: a.name.clone(), body: Vec::new(), sfc: None, pragmas: Vec::new(), span: def.span })
            .collect();
        for a in &def.actions {
            if let Some(sfc) = &a.sfc {
                let pou = Pou { vars: &def.vars, actions: &actions, kind: PouKind::FunctionBlock };
                nested(out, &pou, &a.name, &[], sfc, library, types);
                continue;
            }
            let _ = writeln!(
                out,
                "          <action name=\"{}\">\n            <body>\n              <ST>{}</ST>\n            </body>\n          </action>",
                esc(&a.name.name),
                xhtml(&st::statements(&a.body, 0))
            );
        }
        out.push_str("        </actions>\n");
    }
    let _ = writeln!(
        out,
        "        <body>\n          <ST>{}</ST>\n        </body>\n      </pou>",
        xhtml(&st::statements(&def.body, 0))
    );
}

fn interface(out: &mut String, vars: &[VarDecl]) {
    interface_returning(out, vars, None);
}

fn interface_returning(out: &mut String, vars: &[VarDecl], returns: Option<&Ident>) {
    out.push_str("        <interface>\n");
    if let Some(ty) = returns {
        let _ = writeln!(out, "          <returnType>{}</returnType>", type_element(&ty.name));
    }
    // Consecutive declarations of one section and constancy share one list, in declaration order.
    let mut i = 0;
    while i < vars.len() {
        let (section, constant) = (vars[i].section, vars[i].constant);
        let tag = match section {
            VarSection::Local => "localVars",
            VarSection::Input => "inputVars",
            VarSection::Output => "outputVars",
            VarSection::InOut => "inOutVars",
            VarSection::External => "externalVars",
            VarSection::Global => "globalVars",
            VarSection::Temp => "tempVars",
        };
        let attr = if constant { " constant=\"true\"" } else { "" };
        let _ = writeln!(out, "          <{tag}{attr}>");
        while i < vars.len() && vars[i].section == section && vars[i].constant == constant {
            variable(out, &vars[i]);
            i += 1;
        }
        let _ = writeln!(out, "          </{tag}>");
    }
    out.push_str("        </interface>\n");
}

fn variable(out: &mut String, v: &VarDecl) {
    let ty = match &v.array {
        Some(spec) => array_element(spec),
        None => type_element(&v.type_name.name),
    };
    let address = v.address.as_ref().map_or(String::new(), |a| format!(" address=\"{}\"", esc(a)));
    let _ = write!(out, "            <variable name=\"{}\"{address}><type>{ty}</type>", esc(&v.name.name));
    if let Some(spec) = &v.array {
        out.push_str(&array_value(spec));
    } else if let Some(init) = &v.init {
        let _ = write!(out, "<initialValue><simpleValue value=\"{}\"/></initialValue>", esc(&st::expr(init)));
    } else if !v.members.is_empty() {
        out.push_str("<initialValue><structValue>");
        for (member, value) in &v.members {
            let _ = write!(
                out,
                "<value member=\"{}\"><simpleValue value=\"{}\"/></value>",
                esc(&member.name),
                esc(&st::expr(value))
            );
        }
        out.push_str("</structValue></initialValue>");
    }
    out.push_str("</variable>\n");
}

/// Baton's element order, as written to `ORDER_DATA`.
struct Order {
    steps: String,
    /// The `localId`s of the transitions, in program order.
    transitions: String,
    actions: String,
}

/// The SFC body being written: element ids, and where its parts are drawn.
struct Sfc<'a> {
    chart: &'a Chart,
    program: &'a Program,
    next_id: u64,
    diagram: Diagram,
}

impl<'a> Sfc<'a> {
    fn new(chart: &'a Chart, program: &'a Program) -> Sfc<'a> {
        Sfc { chart, program, next_id: 1, diagram: Diagram::lay_out(program) }
    }

    fn id(&mut self) -> u64 {
        let id = self.next_id;
        self.next_id += 1;
        id
    }

    fn xy(&self, s: usize) -> (i64, i64) {
        self.diagram.step_xy(crate::exec::program::StepId(s as u32))
    }

    fn write(mut self, out: &mut String) -> Order {
        let p = self.program;
        let n = p.steps.len();
        let step_id: Vec<u64> = (0..n).map(|_| self.id()).collect();
        let transition_id: Vec<u64> = (0..p.transitions.len()).map(|_| self.id()).collect();
        // Where a transition's input comes from for each of its sources: the step, or its selection divergence.
        let leaves = |s: usize| p.outgoing(crate::exec::program::StepId(s as u32)).len();
        let mut selection_div: HashMap<usize, u64> = HashMap::new();
        for s in 0..n {
            if leaves(s) > 1 {
                let id = self.id();
                selection_div.insert(s, id);
            }
        }
        let from_step: Vec<u64> = (0..n).map(|s| selection_div.get(&s).copied().unwrap_or(step_id[s])).collect();
        let mut elements = String::new();
        // Steps (each with its input left as a mark, filled in once the transitions are laid out), their actions
        // and their selection divergences.
        let steps_text: Vec<String> =
            (0..n).map(|s| self.step_element(s, step_id[s], selection_div.get(&s).map(|&d| (d, leaves(s))))).collect();
        // Transitions, with the simultaneous convergences before and divergences after them; where each step's
        // inputs come from.
        let mut step_inputs: Vec<Vec<u64>> = vec![Vec::new(); n];
        for (t, &tid) in transition_id.iter().enumerate() {
            self.transition_element(t, tid, &from_step, &mut step_inputs, &mut elements);
        }
        // Steps' inputs: one connection, or a selection convergence of several.
        for (s, inputs) in step_inputs.iter().enumerate() {
            let text = self.step_input(s, inputs, &mut elements);
            let mark = format!("              @@IN{s}@@\n");
            let filled = if text.is_empty() { String::new() } else { format!("              {text}\n") };
            out.push_str(&steps_text[s].replacen(&mark, &filled, 1));
        }
        out.push_str(&elements);
        Order {
            steps: p.steps.iter().map(|s| s.name.as_str()).collect::<Vec<_>>().join(" "),
            transitions: transition_id.iter().map(|id| id.to_string()).collect::<Vec<_>>().join(" "),
            actions: p.actions.iter().map(|a| a.name.as_str()).collect::<Vec<_>>().join(" "),
        }
    }

    /// Step `s` (its input a mark `@@INs@@`), its action block, and its selection divergence (`(id, branches)`).
    fn step_element(&mut self, s: usize, id: u64, selection_div: Option<(u64, usize)>) -> String {
        let info = &self.program.steps[s];
        let mut elements = String::new();
        let (x, y) = self.xy(s);
        let _ = writeln!(
            elements,
            "            <step localId=\"{}\" name=\"{}\" initialStep=\"{}\" height=\"{STEP_H}\" width=\"{STEP_W}\">",
            id,
            esc(&info.name),
            info.initial
        );
        let _ = writeln!(elements, "              <position x=\"{x}\" y=\"{y}\"/>");
        // The step's input: filled in below, once the transitions' ids are known.
        let _ = writeln!(elements, "              @@IN{s}@@");
        let _ = writeln!(
            elements,
            "              <connectionPointOut formalParameter=\"\"><relPosition x=\"{}\" y=\"{STEP_H}\"/></connectionPointOut>",
            STEP_W / 2
        );
        let associations = self.associations(s);
        if !associations.is_empty() {
            let _ = writeln!(
                elements,
                "              <connectionPointOutAction formalParameter=\"\"><relPosition x=\"{STEP_W}\" y=\"{}\"/></connectionPointOutAction>",
                STEP_H / 2
            );
        }
        elements.push_str(&self.entry_exit(s));
        if !info.pragmas.is_empty() {
            let _ = writeln!(
                elements,
                "              <documentation>{}</documentation>",
                xhtml(&pragmas_text(&info.pragmas))
            );
        }
        elements.push_str("            </step>\n");
        if !associations.is_empty() {
            let block = self.id();
            let _ = writeln!(
                elements,
                "            <actionBlock localId=\"{block}\" width=\"200\" height=\"{}\">\n              <position x=\"{}\" y=\"{y}\"/>\n              <connectionPointIn><relPosition x=\"0\" y=\"{}\"/><connection refLocalId=\"{}\"/></connectionPointIn>",
                20 * associations.len().max(1),
                x + STEP_W + 30,
                STEP_H / 2,
                id
            );
            elements.push_str(&associations);
            elements.push_str("            </actionBlock>\n");
        }
        if let Some((div, _)) = selection_div {
            // Each branch's point over its transition's column.
            let xs = self.diagram.branch_xs(self.program, crate::exec::program::StepId(s as u32));
            let _ = writeln!(
                elements,
                "            <selectionDivergence localId=\"{div}\" height=\"1\" width=\"{}\">\n              <position x=\"{x}\" y=\"{}\"/>\n              <connectionPointIn><relPosition x=\"{}\" y=\"0\"/><connection refLocalId=\"{}\"/></connectionPointIn>",
                xs.iter().max().map_or(0, |m| m - x),
                y + STEP_H + 20,
                STEP_W / 2,
                id
            );
            for bx in xs {
                let _ = writeln!(
                    elements,
                    "              <connectionPointOut formalParameter=\"\"><relPosition x=\"{}\" y=\"1\"/></connectionPointOut>",
                    bx - x
                );
            }
            elements.push_str("            </selectionDivergence>\n");
        }
        elements
    }

    /// Transition `t` (`tid`) into `elements`, with a simultaneous convergence before it and a divergence after
    /// it where it has several sources or targets; the ids its targets take their input from go to `step_inputs`
    /// (a target above it is reached by a jump).
    fn transition_element(
        &mut self,
        t: usize,
        tid: u64,
        from_step: &[u64],
        step_inputs: &mut [Vec<u64>],
        elements: &mut String,
    ) {
        let p = self.program;
        let tr = TransitionId(t as u32);
        let sources = p.sources(tr);
        let targets = p.targets(tr);
        let (x, y) = self.diagram.transition_xy(p, tr);
        let input = if sources.len() > 1 {
            let conv = self.id();
            let _ = writeln!(
                elements,
                "            <simultaneousConvergence localId=\"{conv}\" height=\"3\" width=\"{}\">\n              <position x=\"{x}\" y=\"{}\"/>",
                (sources.len() as i64 - 1) * COLUMN,
                y - 30
            );
            for s in sources {
                let _ = writeln!(
                    elements,
                    "              <connectionPointIn><connection refLocalId=\"{}\"/></connectionPointIn>",
                    from_step[s.index()]
                );
            }
            elements.push_str("              <connectionPointOut/>\n            </simultaneousConvergence>\n");
            conv
        } else {
            sources.first().map_or(0, |s| from_step[s.index()])
        };
        // The clearing order over the whole chart (which also orders a cycle's events), so that every
        // transition has one: within a divergence it orders the branches for any tool.
        let priority = format!(" priority=\"{}\"", p.rank(tr) + 1);
        let tr = &self.chart.transitions[t];
        let condition = match &tr.name {
            Some(name) => format!("<reference name=\"{}\"/>", esc(&name.name)),
            None => {
                let mut text = pragmas_text(&tr.pragmas);
                if !text.is_empty() {
                    text.push(' ');
                }
                text.push_str(&st::expr(&tr.condition));
                format!("<inline name=\"\"><ST>{}</ST></inline>", xhtml(&text))
            }
        };
        let _ = writeln!(
            elements,
            "            <transition localId=\"{tid}\" height=\"2\" width=\"20\"{priority}>\n              <position x=\"{}\" y=\"{y}\"/>\n              <connectionPointIn><relPosition x=\"10\" y=\"0\"/><connection refLocalId=\"{input}\"/></connectionPointIn>\n              <connectionPointOut><relPosition x=\"10\" y=\"2\"/></connectionPointOut>\n              <condition>{condition}</condition>\n            </transition>",
            x + STEP_W / 2 - 10
        );
        let out_from = if targets.len() > 1 {
            let div = self.id();
            let _ = writeln!(
                elements,
                "            <simultaneousDivergence localId=\"{div}\" height=\"3\" width=\"{}\">\n              <position x=\"{x}\" y=\"{}\"/>\n              <connectionPointIn><connection refLocalId=\"{tid}\"/></connectionPointIn>",
                (targets.len() as i64 - 1) * COLUMN,
                y + 30
            );
            for _ in targets {
                elements.push_str("              <connectionPointOut formalParameter=\"\"/>\n");
            }
            elements.push_str("            </simultaneousDivergence>\n");
            div
        } else {
            tid
        };
        for u in targets {
            if !self.diagram.is_jump(p, TransitionId(t as u32), *u) {
                step_inputs[u.index()].push(out_from);
            } else {
                let jump = self.id();
                let _ = writeln!(
                    elements,
                    "            <jumpStep localId=\"{jump}\" targetName=\"{}\" height=\"13\" width=\"12\">\n              <position x=\"{}\" y=\"{}\"/>\n              <connectionPointIn><relPosition x=\"6\" y=\"0\"/><connection refLocalId=\"{out_from}\"/></connectionPointIn>\n            </jumpStep>",
                    esc(&p.steps[u.index()].name),
                    x + STEP_W / 2 - 6,
                    y + 60
                );
            }
        }
    }

    /// The input of step `s` from `inputs`: one connection, or a selection convergence of several (written into
    /// `elements`); empty for none.
    fn step_input(&mut self, s: usize, inputs: &[u64], elements: &mut String) -> String {
        match inputs {
            [] => String::new(),
            [one] => format!(
                "<connectionPointIn><relPosition x=\"{}\" y=\"0\"/><connection refLocalId=\"{one}\"/></connectionPointIn>",
                STEP_W / 2
            ),
            many => {
                let conv = self.id();
                let (x, y) = self.xy(s);
                let _ = writeln!(
                    elements,
                    "            <selectionConvergence localId=\"{conv}\" height=\"1\" width=\"{}\">\n              <position x=\"{x}\" y=\"{}\"/>",
                    (many.len() as i64 - 1) * BRANCH,
                    y - 30
                );
                for i in many {
                    let _ = writeln!(
                        elements,
                        "              <connectionPointIn><connection refLocalId=\"{i}\"/></connectionPointIn>"
                    );
                }
                elements.push_str("              <connectionPointOut/>\n            </selectionConvergence>\n");
                format!(
                    "<connectionPointIn><relPosition x=\"{}\" y=\"0\"/><connection refLocalId=\"{conv}\"/></connectionPointIn>",
                    STEP_W / 2
                )
            }
        }
    }

    /// Step s's entry and exit actions, as CODESYS and TwinCAT write them: GUID-keyed attributes of the step's
    /// vendor data (the reader takes them back).
    fn entry_exit(&self, s: usize) -> String {
        let attributes: String = self.chart.steps[s]
            .associations
            .iter()
            .filter_map(|a| {
                let guid = match a.qualifier {
                    Qualifier::Entry => crate::front::plcopen::CODESYS_ENTRY_ACTION,
                    Qualifier::Exit => crate::front::plcopen::CODESYS_EXIT_ACTION,
                    Qualifier::Active => crate::front::plcopen::CODESYS_ACTIVE_ACTION,
                    _ => return None,
                };
                Some(format!("<attribute guid=\"{guid}\">{}</attribute>", esc(&a.action.name)))
            })
            .collect();
        if attributes.is_empty() {
            return String::new();
        }
        format!(
            "              <addData><data name=\"{}\" handleUnknown=\"implementation\"><attributes>{attributes}</attributes></data></addData>\n",
            crate::front::plcopen::CODESYS_SFC_ELEMENT
        )
    }

    /// The `<action>` elements of step s's associations (but its entry and exit actions: `entry_exit`).
    fn associations(&self, s: usize) -> String {
        let step = &self.chart.steps[s];
        let mut out = String::new();
        for a in step
            .associations
            .iter()
            .filter(|a| !matches!(a.qualifier, Qualifier::Entry | Qualifier::Exit | Qualifier::Active))
        {
            let duration = match &a.duration {
                Some(Duration::Literal { ms, .. }) => format!(" duration=\"T#{ms}ms\""),
                Some(Duration::Var(v)) => format!(" duration=\"{}\"", esc(&v.name)),
                None => String::new(),
            };
            let indicator = if a.indicators.is_empty() {
                String::new()
            } else {
                let names: Vec<&str> = a.indicators.iter().map(|i| i.name.as_str()).collect();
                format!(" indicator=\"{}\"", esc(&names.join(", ")))
            };
            let _ = writeln!(
                out,
                "              <action localId=\"0\" qualifier=\"{:?}\"{duration}{indicator}><relPosition x=\"0\" y=\"0\"/><reference name=\"{}\"/></action>",
                a.qualifier,
                esc(&a.action.name)
            );
        }
        out
    }
}
