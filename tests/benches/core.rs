//! Benchmarks of the SFC core: parse + check of a 100,000-step chart and import + check of a 10,000-step PLCopen
//! file; the import of an LD body whose rungs go through continuations and of a macro step's long body, each at
//! two sizes four times apart (linear work takes four times as long; the quadratic reader took 19 s and 21 s at
//! the larger); and the cost of one engine cycle on a 1,000-step and a 100,000-step chart with the same 100
//! active steps, without and with 1,000 TON instances; and a journal's snapshot of a coordinator with 1,024 tokens
//! out on 256 agents, taken and restored; and Baton's own work in a token's round trip — the coordinator's and the
//! agent's state machines and the wire's encoding, with no network between them. Run with
//! `cargo bench -p baton-tests --bench core`.

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

/// A coordinator with 1,024 tokens out on 256 agents (a simulated cell, every token parked on a transition that
/// waits for an input): what a snapshot of it costs the coordinator's main loop, and what restoring it costs a resume.
fn snapshot(c: &mut Criterion) {
    use baton_proto::cluster::runtime::coordinator::Coordinator;
    use baton_proto::testing::simulated_cluster::{Faults, SimCluster};
    let (tokens, agents) = (1024, 256);
    let mut src = String::from("PROGRAM snap\nVAR go : BOOL; END_VAR\nINITIAL_STEP Start: END_STEP\n");
    let list = |p: &str| (1..=tokens).map(|k| format!("{p}{k}")).collect::<Vec<_>>().join(", ");
    src.push_str(&format!("TRANSITION FROM Start TO ({}) := TRUE; END_TRANSITION\n", list("S")));
    for k in 1..=tokens {
        let a = (k - 1) % agents + 1;
        src.push_str(&format!(
            "STEP S{k}: {{agent := 'a{a}'}} END_STEP\nTRANSITION FROM S{k} TO W{k} := go; END_TRANSITION\nSTEP W{k}: END_STEP\n"
        ));
    }
    src.push_str(&format!(
        "TRANSITION FROM ({}) TO Done := TRUE; END_TRANSITION\nSTEP Done: END_STEP\nEND_PROGRAM\n",
        list("W")
    ));
    let names: Vec<String> = (1..=agents).map(|a| format!("a{a}")).collect();
    let specs: Vec<(&str, &[&str])> = names.iter().map(|n| (n.as_str(), &[][..])).collect();
    let mut sim = SimCluster::new(&src, &specs, Faults::default(), 1);
    sim.snapshot_every = usize::MAX;
    sim.run(2_000);
    let core = sim.coordinator.core();
    assert_eq!(core.tokens_in_flight(), tokens, "every token out");
    let bytes = core.snapshot();
    eprintln!("snapshot of {tokens} tokens on {agents} agents: {} kB", bytes.len() / 1000);
    let (program, layout) = (Arc::clone(core.program()), Arc::clone(core.layout()));
    let mut group = c.benchmark_group("snapshot");
    group.bench_function("take_1024_tokens_256_agents", |b| b.iter(|| black_box(core.snapshot().len())));
    group.bench_function("restore_1024_tokens_256_agents", |b| {
        b.iter(|| {
            let restored = Coordinator::restore(Arc::clone(&program), Arc::clone(&layout), black_box(&bytes));
            black_box(restored.expect("restores").tokens_in_flight())
        })
    });
    group.finish();
}

/// What a token's round trip costs Baton itself, the network left out: `baton bench`'s phase (2) chart in the
/// simulated cell (one agent, no faults), where each dispatch and report is encoded, decoded and handled by the same
/// state machines as in `baton run` and `baton-agent`, and the coordinator's inputs are framed as journal records.
/// Per round trip: the dispatch's encoding, the agent's decoding and handling of it and encoding of its report, the
/// coordinator's decoding and handling of the report, its engine's reaction and the next dispatch's encoding.
fn round_trip(c: &mut Criterion) {
    use baton_proto::testing::bench_charts::token_round_trip;
    use baton_proto::testing::simulated_cluster::{Faults, SimCluster};
    let mut group = c.benchmark_group("round_trip");
    group.bench_function("token_in_process", |b| {
        b.iter_custom(|iters| {
            let mut sim = SimCluster::new(&token_round_trip(iters), &[("bench1", &[])], Faults::default(), 1);
            sim.snapshot_every = usize::MAX;
            let t0 = std::time::Instant::now();
            assert!(sim.run(u64::MAX / 2), "the chart finishes");
            let took = t0.elapsed();
            assert_eq!(sim.value("i").map(|v| v.to_string()), Some(iters.to_string()), "every round trip made");
            took
        })
    });
    group.finish();
}

criterion_group!(benches, parse_and_check, engine_cycle, snapshot, round_trip);
criterion_main!(benches);
