//! What a chart computes on one engine with a cycle every `cycle_ms`, as `baton sim` runs it: the reference a
//! distributed run of the same chart is held to.

use std::sync::Arc;

use baton_proto::exec::engine::Engine;

/// The values of `names` once the chart (the first POU of `source`) reached a terminal situation; panics if it
/// does not within a minute of chart time.
pub fn final_values(source: &str, cycle_ms: u64, names: &[&str]) -> Vec<i64> {
    let report = baton_proto::front::check::check_source(source);
    let program = Arc::new(report.charts[0].program.clone().expect("a valid chart"));
    let mut engine = Engine::new(Arc::clone(&program));
    let mut now = 0;
    while !engine.is_terminal() {
        engine.handle_cycle(now).expect("cycle");
        while engine.poll_event().is_some() {}
        now += cycle_ms;
        assert!(now < 60_000, "the chart does not end");
    }
    names.iter().map(|n| engine.value(program.var_by_name(n).expect("variable")).as_i64()).collect()
}
