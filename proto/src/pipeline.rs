//! `check_source`: parse, compile and analyse every chart of a source text, reporting every problem at once.
//!
//! `pipeline::check_source` picks the front end by content (XML or text), ties parse, compile and analysis
//! together (no net analysis after a syntax error: the net is not the one drawn; placement checked beside the
//! compiler's errors, so that one run reports them all), sorts and dedups the diagnostics.

use crate::cluster::layout::{layout, Layout};
use crate::exec::analysis::{analyse, Finding};
use crate::exec::compile::compile;
use crate::exec::program::Program;
use crate::front::diag::{Diagnostic, Span};
use crate::front::model::Chart;
use crate::front::parser::parse;
use crate::front::plcopen;
use crate::limits::{CHART_ELEMENTS_MAX, DIAGNOSTICS_MAX, SOURCE_BYTES_MAX};

pub struct CheckedChart {
    pub chart: Chart,
    /// Present when the chart has no errors.
    pub program: Option<Program>,
    /// Where each part runs in a distributed run; present with `program`.
    pub layout: Option<Layout>,
}

pub struct Report {
    pub charts: Vec<CheckedChart>,
    /// The file's function blocks with ST bodies, which its charts may instantiate.
    pub library: Vec<crate::front::model::FbDef>,
    /// The file's declared types.
    pub types: Vec<crate::front::model::TypeDef>,
    /// In source order.
    pub diagnostics: Vec<Diagnostic>,
}

impl Report {
    pub fn error_count(&self) -> usize {
        self.diagnostics.iter().filter(|d| d.is_error()).count()
    }
}

pub fn check_source(src: &str) -> Report {
    if src.len() > SOURCE_BYTES_MAX {
        let message = format!("the chart's text is larger than {} MiB (as UTF-8)", SOURCE_BYTES_MAX >> 20);
        return Report {
            charts: Vec::new(),
            library: Vec::new(),
            types: Vec::new(),
            diagnostics: vec![Diagnostic::error(Span::default(), message)],
        };
    }
    let xml = plcopen::looks_like_xml(src);
    let parsed = if xml { plcopen::parse(src) } else { parse(src) };
    let mut diagnostics = parsed.diagnostics;
    if parsed.charts.is_empty() && !diagnostics.iter().any(Diagnostic::is_error) {
        let message = if xml {
            "no sequential function chart found: no program or function block of this PLCopen file has an SFC body"
        } else {
            "no sequential function chart found: expected `INITIAL_STEP` in a PROGRAM, a FUNCTION_BLOCK or at the top level"
        };
        diagnostics.push(Diagnostic::error(Span::new(0, 0), message));
    }
    let mut charts = Vec::with_capacity(parsed.charts.len());
    for chart in parsed.charts {
        let inside = |d: &Diagnostic| chart.span.start <= d.span.start && d.span.end <= chart.span.end;
        let parse_errors = diagnostics.iter().any(|d| d.is_error() && inside(d));
        let largest = chart.steps.len().max(chart.transitions.len()).max(chart.actions.len());
        if largest > CHART_ELEMENTS_MAX {
            let message =
                format!("chart `{}` has more than {CHART_ELEMENTS_MAX} steps, transitions or actions", chart.name.name);
            diagnostics.push(Diagnostic::error(chart.name.span, message));
            charts.push(CheckedChart { program: None, layout: None, chart });
            continue;
        }
        let mut own = Vec::new();
        let compiled = compile(&chart, &parsed.library, &parsed.types, &mut own);
        // After a syntax error the net is not the one the author drew: what the analysis would say of it is noise.
        if compiled.net_ok && !parse_errors && !compiled.program.initial_steps.is_empty() {
            for finding in analyse(&compiled.program) {
                own.push(describe(&chart, &compiled.program, finding));
            }
        }
        let mut ok = !parse_errors && !own.iter().any(Diagnostic::is_error);
        let mut placed = None;
        // Placement is checked beside the other errors, not after they are fixed, so that one run of `baton check`
        // reports every problem the chart has — as long as its steps and transitions resolved (`net_ok`).
        if !parse_errors && compiled.net_ok {
            let laid_out = layout(&chart, &compiled.program, &mut own);
            ok = ok && !own.iter().any(Diagnostic::is_error);
            placed = ok.then_some(laid_out);
        }
        diagnostics.extend(own);
        charts.push(CheckedChart { program: ok.then_some(compiled.program), layout: placed, chart });
    }
    diagnostics.sort_by_key(|d| d.span.start);
    // One expression can be read twice (a named transition body that two transitions use): one report each.
    let mut seen = std::collections::BTreeSet::new();
    diagnostics.retain(|d| seen.insert((d.span, d.message.clone())));
    if diagnostics.len() > DIAGNOSTICS_MAX {
        let more = diagnostics.len() - DIAGNOSTICS_MAX;
        let last = diagnostics[DIAGNOSTICS_MAX - 1].span;
        diagnostics.truncate(DIAGNOSTICS_MAX);
        diagnostics.push(Diagnostic::error(last, format!("{more} more problems not shown")));
    }
    Report { charts, library: parsed.library, types: parsed.types, diagnostics }
}

/// Whether the chart's own pragmas (those before its first element) accept a net whose safety is not proven.
fn unverified_net_allowed(chart: &Chart) -> bool {
    chart.pragmas.iter().any(|p| match crate::front::pragma::read(&p.text) {
        crate::front::pragma::Pragma::Pairs(pairs) => pairs.iter().any(|(k, v)| {
            k == "unverified_net" && *v == crate::front::pragma::Param::Value(crate::types::Value::Bool(true))
        }),
        _ => false,
    })
}

/// The net analysis runs only on charts whose steps and transitions all resolved, so ids follow the chart's
/// declaration order.
fn describe(chart: &Chart, program: &Program, finding: Finding) -> Diagnostic {
    match finding {
        Finding::Unsafe { transition, step } => {
            let t = &chart.transitions[transition.index()];
            let message = format!(
                "unsafe chart: step `{}` can receive a second token, because transition `{}` can clear while `{}` is still active",
                program.steps[step.index()].name,
                t.display_name(),
                program.steps[step.index()].name
            );
            Diagnostic::error(t.arc_span, message)
        }
        Finding::DeadConvergence { transition } => {
            let t = &chart.transitions[transition.index()];
            let names: Vec<String> = t.from.iter().map(|s| format!("`{}`", s.name)).collect();
            let message = format!(
                "simultaneous convergence `{}` can never clear: steps {} are never active at the same time",
                t.display_name(),
                names.join(", ")
            );
            Diagnostic::error(t.arc_span, message)
        }
        Finding::UnreachableStep { step } => {
            let s = &chart.steps[step.index()];
            Diagnostic::error(s.name.span, format!("step `{}` is unreachable: no evolution from the initial steps activates it", s.name.name))
        }
        Finding::Incomplete { situations } if unverified_net_allowed(chart) => Diagnostic::warning(
            chart.name.span,
            format!(
                "chart `{}` has more than {situations} reachable situations: its safety is not proven (`unverified_net := TRUE`), so a second token on a step is a run-time fault, and reachability was not checked",
                chart.name.name
            ),
        ),
        Finding::Incomplete { situations } => Diagnostic::error(
            chart.name.span,
            format!(
                "chart `{}` has more than {situations} reachable situations: Baton cannot prove that no step ever receives a second token. Give it the structured shape (each simultaneous divergence closed by its own convergence), or accept the risk with the chart pragma `{{unverified_net := TRUE}}`, which makes a second token a run-time fault",
                chart.name.name
            ),
        ),
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn edge_contacts_pulse_for_one_evaluation_after_their_edge() {
        // An LD action: `pulse` is a rising-edge contact on `x`, `low` a falling-edge one; a counter counts
        // the pulses. They are R_TRIG and F_TRIG instances, as Beremiz compiles them, so the falling one also
        // pulses at its first call, x being FALSE.
        let src = r#"<project xmlns="http://www.plcopen.org/xml/tc6_0201"><types><pous>
<pou name="p" pouType="program"><interface><localVars>
<variable name="x"><type><BOOL/></type></variable>
<variable name="pulse"><type><BOOL/></type></variable>
<variable name="low"><type><BOOL/></type></variable>
<variable name="n"><type><INT/></type></variable>
<variable name="m"><type><INT/></type></variable>
</localVars></interface>
<actions>
<action name="Watch"><body><LD>
<leftPowerRail localId="1"><connectionPointOut formalParameter=""/></leftPowerRail>
<contact localId="2" edge="rising"><connectionPointIn><connection refLocalId="1"/></connectionPointIn><connectionPointOut/><variable>x</variable></contact>
<coil localId="3"><connectionPointIn><connection refLocalId="2"/></connectionPointIn><connectionPointOut/><variable>pulse</variable></coil>
<contact localId="4" edge="falling"><connectionPointIn><connection refLocalId="1"/></connectionPointIn><connectionPointOut/><variable>x</variable></contact>
<coil localId="5"><connectionPointIn><connection refLocalId="4"/></connectionPointIn><connectionPointOut/><variable>low</variable></coil>
</LD></body></action>
<action name="Count"><body><ST><![CDATA[IF pulse THEN n := n + 1; END_IF; IF low THEN m := m + 1; END_IF;]]></ST></body></action>
</actions>
<body><SFC>
<step localId="10" name="S" initialStep="true"/>
<actionBlock localId="11"><connectionPointIn><connection refLocalId="10"/></connectionPointIn>
<action localId="0" qualifier="N"><reference name="Watch"/></action>
<action localId="0" qualifier="N"><reference name="Count"/></action></actionBlock>
</SFC></body></pou></pous></types></project>"#;
        let report = super::check_source(src);
        assert_eq!(report.error_count(), 0, "{:?}", report.diagnostics);
        let program = std::sync::Arc::new(report.charts[0].program.clone().expect("a program"));
        let x = program.var_by_name("x").expect("x");
        let mut engine = crate::exec::engine::Engine::new(std::sync::Arc::clone(&program));
        // x: FALSE, TRUE ×3, FALSE ×2, TRUE, FALSE: two rising edges, two falling ones and the start-up one.
        for (i, v) in [false, true, true, true, false, false, true, false].into_iter().enumerate() {
            engine.handle(crate::exec::engine::Input::Set(x, crate::types::Value::Bool(v))).expect("set");
            engine.handle_cycle(10 * i as u64).expect("cycle");
        }
        let value = |name: &str| engine.value(program.var_by_name(name).expect("var")).as_i64();
        assert_eq!((value("n"), value("m")), (2, 3));
    }
}
