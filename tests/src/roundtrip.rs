//! What "the same chart" means for a chart written out and read back: the compiled program, element by
//! element in order (variables, steps with their associations, pragmas and the clearing order of the
//! transitions leaving them, transitions with their sources, targets, conditions and block calls, actions with
//! their bodies), and the trace `baton sim` prints for it under a script that moves every input.

use std::fmt::Write;
use std::sync::Arc;

use baton_proto::exec::program::{Program, StepId, TransitionId};
use baton_proto::exec::sim::{parse_inputs, simulate};
use baton_proto::exec::trace::Output;
use baton_proto::pipeline::check_source;
use baton_proto::types::Type;

/// The program as text, without source positions.
pub fn canonical(p: &Program) -> String {
    let mut out = String::new();
    let texts =
        |pragmas: &[baton_proto::front::model::Pragma]| pragmas.iter().map(|p| p.text.clone()).collect::<Vec<_>>();
    for v in &p.vars {
        let _ = writeln!(
            out,
            "var {} {} {} const={} {:?} hidden={}",
            v.name, v.ty, v.init, v.constant, v.section, v.hidden
        );
    }
    for (i, s) in p.steps.iter().enumerate() {
        let id = StepId(i as u32);
        // A step's outgoing transitions in clearing order: what ranks mean (their global numbers may differ).
        let _ = writeln!(
            out,
            "step {} initial={} {:?} leaves by {:?}",
            s.name,
            s.initial,
            texts(&s.pragmas),
            p.outgoing(id)
        );
        // In action order: a step's associations act together, whatever order a file lists them in (PLCopen
        // keeps CODESYS's entry and exit actions in vendor data, apart from its action blocks).
        let mut lines: Vec<String> =
            p.associations(id).iter().zip(p.indicators(id)).map(|(a, inds)| format!("  {a:?} {inds:?}")).collect();
        lines.sort();
        for line in lines {
            let _ = writeln!(out, "{line}");
        }
    }
    for (i, t) in p.transitions.iter().enumerate() {
        let id = TransitionId(i as u32);
        let _ = writeln!(
            out,
            "transition {} {:?} -> {:?} {:?} {:?} {:?}",
            t.name,
            p.sources(id),
            p.targets(id),
            t.condition,
            p.calls(id),
            texts(&t.pragmas)
        );
    }
    for a in &p.actions {
        let _ = writeln!(out, "action {} {:?} {:?} {:?} {:?}", a.name, a.once, a.bool_var, a.body, texts(&a.pragmas));
    }
    out
}

/// The trace of a program under a script that sets every BOOL input TRUE then FALSE and every integer input
/// 0 to 3, one variable every 30 ms, for four rounds, then 500 ms more.
pub fn trace(p: &Program) -> Vec<String> {
    trace_with(p, 500, |name| name.to_string())
}

/// `trace`, running `tail_ms` past the last input, with each event's name as `name` gives it (two forms of one
/// chart may spell names differently).
pub fn trace_with(p: &Program, tail_ms: u64, name: impl Fn(&str) -> String) -> Vec<String> {
    let mut script = String::new();
    let mut t = 0;
    for round in 0..4 {
        for v in p.vars.iter().filter(|v| !v.constant && !v.hidden) {
            let value = match v.ty {
                Type::Bool => serde_json::json!(round % 2 == 0),
                Type::Int(_) => serde_json::json!(round),
                _ => continue,
            };
            t += 30;
            script.push_str(&format!("{}\n", serde_json::json!({"t_ms": t, "set": {v.name.clone(): value}})));
        }
    }
    let inputs = parse_inputs(&script, p).expect("script");
    let mut out = Vec::new();
    simulate(Arc::new(p.clone()), &inputs, 10, t + tail_ms, |o| {
        out.push(match o {
            Output::Trace(r) => format!("{} {} {}", r.t_ms, r.event, name(&r.name)),
            Output::Fault { t_ms, message } => format!("{t_ms} fault {message}"),
        })
    })
    .expect("simulation runs");
    out
}

/// Exports every chart of a valid source to PLCopen XML (with a fixed creation time).
pub fn export(source: &str) -> String {
    let report = check_source(source);
    assert_eq!(report.error_count(), 0, "the source is valid: {:?}", report.diagnostics.first());
    let charts: Vec<_> = report.charts.iter().filter_map(|c| Some((&c.chart, c.program.as_ref()?))).collect();
    baton_proto::back::plcopen::export(&charts, &report.library, &report.types, "roundtrip", "2026-12-01T00:00:00")
}

/// Checks that a valid source, exported and read back, gives the same programs and traces; returns the XML.
pub fn assert_round_trip(what: &str, source: &str) -> String {
    let xml = export(source);
    let before = check_source(source);
    let after = check_source(&xml);
    let errors: Vec<String> = after.diagnostics.iter().filter(|d| d.is_error()).map(|d| d.message.clone()).collect();
    assert!(errors.is_empty(), "{what}: the export does not read back: {errors:?}\n{xml}");
    assert_eq!(before.charts.len(), after.charts.len(), "{what}: charts");
    for (a, b) in before.charts.iter().zip(&after.charts) {
        let (Some(pa), Some(pb)) = (&a.program, &b.program) else { panic!("{what}: a chart without a program") };
        let (ca, cb) = (canonical(pa), canonical(pb));
        if ca != cb {
            let diff: Vec<String> = ca
                .lines()
                .zip(cb.lines())
                .filter(|(x, y)| x != y)
                .take(5)
                .map(|(x, y)| format!("  source: {x}\n  export: {y}"))
                .collect();
            panic!("{what}: chart `{}` differs after the round trip:\n{}", pa.name, diff.join("\n"));
        }
        assert_eq!(trace(pa), trace(pb), "{what}: chart `{}` traces differ", pa.name);
    }
    xml
}
