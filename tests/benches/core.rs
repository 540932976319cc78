//! Benchmarks of the SFC core: parse + check of a 100,000-step chart and import + check of a 10,000-step PLCopen
//! file; the import of an LD body whose rungs go through continuations and of a macro step's long body, each at
//! two sizes four times apart (linear work takes four times as long; the quadratic reader took 19 s and 21 s at
//! the larger); and the cost of one engine cycle on a 1,000-step and a 100,000-step chart with the same 100
//! active steps, without and with 1,000 TON instances. Run with `cargo bench -p baton-tests --bench core`.

use std::hint::black_box;
use std::sync::Arc;
use std::time::Duration;

use baton_proto::exec::engine::Engine;
use baton_proto::pipeline::check_source;
use baton_tests::gen::{
    large_plcopen_chart, large_structured_chart, plcopen_continuations, plcopen_macro, rings, timer_rings,
};
use criterion::{criterion_group, criterion_main, Criterion};

fn parse_and_check(c: &mut Criterion) {
    let src = large_structured_chart(100_000);
    let report = check_source(&src);
    let program = report.charts[0].program.as_ref().expect("the generated chart is valid");
    eprintln!("chart: {} steps, {} transitions, {} bytes", program.steps.len(), program.transitions.len(), src.len());
    let mut group = c.benchmark_group("check");
    group.sample_size(10).measurement_time(Duration::from_secs(10));
    group.bench_function("parse_check_100k_steps", |b| b.iter(|| check_source(black_box(&src))));
    let xml = large_plcopen_chart(10_000);
    let report = check_source(&xml);
    assert_eq!(report.error_count(), 0, "the generated PLCopen file is valid: {:?}", report.diagnostics.first());
    let program = report.charts[0].program.as_ref().expect("the generated PLCopen chart is valid");
    eprintln!("PLCopen: {} steps, {} transitions, {} bytes", program.steps.len(), program.transitions.len(), xml.len());
    group.bench_function("import_check_plcopen_10k_steps", |b| b.iter(|| check_source(black_box(&xml))));
    for n in [5_000, 20_000] {
        let xml = plcopen_continuations(n);
        assert_eq!(check_source(&xml).error_count(), 0, "the generated LD body is valid");
        group
            .bench_function(format!("import_ld_continuations_{n}_rungs"), |b| b.iter(|| check_source(black_box(&xml))));
        let xml = plcopen_macro(n, false);
        assert_eq!(check_source(&xml).error_count(), 0, "the generated macro step is valid");
        group.bench_function(format!("import_macro_body_{n}_steps"), |b| b.iter(|| check_source(black_box(&xml))));
    }
    group.finish();
}

fn engine_cycle(c: &mut Criterion) {
    let mut group = c.benchmark_group("cycle");
    let charts = [
        ("1k_steps_100_active", rings(100, 10)),
        ("100k_steps_100_active", rings(100, 1000)),
        ("1k_steps_100_active_1k_ton", timer_rings(100, 10, 10)),
        ("100k_steps_100_active_1k_ton", timer_rings(100, 1000, 10)),
    ];
    for (label, src) in charts {
        let report = check_source(&src);
        let program = Arc::new(report.charts[0].program.clone().expect("the ring chart is valid"));
        let mut engine = Engine::new(program);
        let mut now = 0u64;
        group.bench_function(label, |b| {
            b.iter(|| {
                now += 10;
                engine.handle_cycle(now).expect("time moves forward");
                let mut events = 0;
                while engine.poll_event().is_some() {
                    events += 1;
                }
                black_box(events)
            })
        });
        assert_eq!(engine.active_steps().len(), 100, "every ring keeps one token");
    }
    group.finish();
}

criterion_group!(benches, parse_and_check, engine_cycle);
criterion_main!(benches);
