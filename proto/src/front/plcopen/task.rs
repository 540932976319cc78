//! The program a task runs around a chart: CODESYS projects often keep their sequence in a function block written in
//! SFC (`PPU`) and run it from a program in ST (`MAIN`) that calls it, calls its instances' bodies and copies
//! signals between them, which other blocks then read as `MAIN.x`. Baton runs the chart as its own, and the
//! program's body — but for the call of the chart — as an action every step of the chart holds stored (S), so that
//! it runs every cycle from the first, after the chart's transitions. The program's variables become the chart's
//! globals, read as `MAIN.x` (a global list of the program's name), and the program's instance name stands for the
//! chart itself (`PPU.Crane` is the chart's `Crane`).

use roxmltree::Node;

use crate::front::diag::Diagnostic;
use crate::front::model::{Action, Association, Chart, GlobalList, Ident, Stmt, VarDecl, VarSection};
use crate::front::parser::{Fragment, FragmentKind};
use crate::front::plcopen::xml::{child, is};

use super::{CallerProgram, Reader};

impl Reader<'_> {
    /// Keeps a program whose body is ST (`None` where it has another).
    pub(super) fn caller_program(&mut self, pou: Node) -> Option<CallerProgram> {
        let name = pou.attribute("name").map(str::trim).filter(|n| !n.is_empty())?;
        let name = Ident { name: name.to_string(), span: self.attr_span(pou, "name") };
        let st = child(pou, "body").and_then(|b| b.first_element_child()).filter(|b| is(b, "ST"))?;
        let outer = std::mem::take(&mut self.diags);
        let vars = self.interface(pou);
        let body = match self.fragment(st, FragmentKind::Statements).0 {
            Some(Fragment::Statements(body)) => body,
            _ => Vec::new(),
        };
        let problems = std::mem::replace(&mut self.diags, outer);
        Some(CallerProgram { name, vars, body, problems })
    }

    /// Gives `chart` the program that runs it, of those kept (`adopt_caller`).
    pub(super) fn adopt_caller(&mut self, chart: &mut Chart, charts: &[String]) {
        adopt_caller(chart, charts, &self.programs, &mut self.diags);
    }
}

/// Gives `chart` the program that runs it, as the module says: the first whose variables hold one instance of it
/// and of no other chart of the file (a program running several charts is not one chart's task, and is left out).
fn adopt_caller(chart: &mut Chart, charts: &[String], programs: &[CallerProgram], diags: &mut Vec<Diagnostic>) {
    let is_instance = |v: &VarDecl| v.type_name.key() == chart.name.key() && v.array.is_none();
    let only_this = |p: &&CallerProgram| {
        p.vars.iter().filter(|v| is_instance(v)).count() == 1
            && !p.vars.iter().any(|v| v.type_name.key() != chart.name.key() && charts.contains(&v.type_name.key()))
    };
    let Some(program) = programs.iter().find(only_this) else { return };
    let Some(instance) = program.vars.iter().find(|v| is_instance(v)).map(|v| v.name.clone()) else { return };
    diags.extend(program.problems.iter().cloned());
    let mut body = Vec::with_capacity(program.body.len());
    for stmt in &program.body {
        match stmt {
            Stmt::Call { callee, args, span } if callee.key() == instance.key() => {
                if !args.is_empty() {
                    let message = format!(
                        "program `{}` calls `{}` with arguments: Baton runs chart `{}` as the task's own, so give its \
                         inputs values in the program's body (`{}.x := …;`) instead",
                        program.name.name, callee.name, chart.name.name, instance.name
                    );
                    diags.push(Diagnostic::error(*span, message));
                }
            }
            other => body.push(other.clone()),
        }
    }
    // The chart itself, by the program's instance name; then the program's variables, as the chart's globals.
    let own: Vec<Ident> = chart.vars.iter().map(|v| v.name.clone()).collect();
    chart.global_lists.push(GlobalList { name: instance.clone(), vars: own });
    let mut names = Vec::new();
    for v in program.vars.iter().filter(|v| !is_instance(v)) {
        if chart.vars.iter().any(|c| c.name.key() == v.name.key()) {
            let message = format!(
                "`{}` of program `{}` has the name of a variable of chart `{}`, which runs inside it: rename one",
                v.name.name, program.name.name, chart.name.name
            );
            diags.push(Diagnostic::error(v.name.span, message));
            continue;
        }
        names.push(v.name.clone());
        chart.vars.push(VarDecl { section: VarSection::Global, ..v.clone() });
    }
    chart.global_lists.push(GlobalList { name: program.name.clone(), vars: names });
    if body.is_empty() {
        return;
    }
    // Held stored by every step, so that it runs from the first cycle on whichever step the chart is (an initial
    // step left in the first cycle sets nothing: its transitions are judged before actions).
    let name = program.name.clone();
    for step in &mut chart.steps {
        step.associations.push(Association::stored(name.clone(), step.span));
    }
    chart.actions.push(Action { name, body, sfc: None, pragmas: Vec::new(), span: program.name.span });
}
