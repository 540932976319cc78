//! What a chart computes on one engine with a cycle every `cycle_ms`, as `baton sim` runs it: the reference a
//! distributed run of the same chart is held to.

use std::sync::Arc;

use baton_proto::exec::engine::Engine;
use baton_proto::types::{Type, Value};

/// The values of `names` once the chart (the first POU of `source`) reached a terminal situation; panics if it
/// does not within a minute of chart time.
pub fn final_values(source: &str, cycle_ms: u64, names: &[&str]) -> Vec<i64> {
    final_shown_as(source, cycle_ms, names, |_, v| v.as_i64())
}

/// The same values as their types show them (`'text'` for a STRING, an enumeration's value by name), for any type.
pub fn final_shown(source: &str, cycle_ms: u64, names: &[&str]) -> Vec<String> {
    final_shown_as(source, cycle_ms, names, |ty, v| ty.show(v))
}

fn final_shown_as<T>(source: &str, cycle_ms: u64, names: &[&str], show: impl Fn(&Type, &Value) -> T) -> Vec<T> {
    let report = baton_proto::pipeline::check_source(source);
    let program = Arc::new(report.charts[0].program.clone().expect("a valid chart"));
    let mut engine = Engine::new(Arc::clone(&program));
    let mut now = 0;
    while !engine.is_terminal() {
        engine.handle_cycle(now).expect("cycle");
        while engine.poll_event().is_some() {}
        now += cycle_ms;
        assert!(now < 60_000, "the chart does not end");
    }
    names
        .iter()
        .map(|n| {
            let var = program.var_by_name(n).expect("variable");
            show(&program.vars[var.index()].ty, &engine.value(var))
        })
        .collect()
}
