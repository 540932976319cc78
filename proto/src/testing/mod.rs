//! The top layer of the core: charts run whole, on virtual time, and judged. `simulated_cluster` runs the real
//! coordinator and agent state machines over a simulated network with simulated skills; `baton test`'s users'
//! scenarios for their charts (`scenario`) with their conditions (`cond`) run on it and are judged (`run`), with
//! what they exercised of the chart (`coverage`), written out as JUnit XML for CI (`junit`).
//!
//! `testing/` (at the root): `baton test`'s core. `scenario.rs` reads a `*.test.toml` (serde and `toml`'s spans, so
//! every mistake is at its line and column) and checks it whole against its chart: steps, actions, agents, variables,
//! durations, conditions; `cond.rs`, conditions (`step X active on A`, or an ST expression read by the chart's own
//! parser, evaluated over the steps active anywhere and the coordinator's variables); `run.rs`, one scenario run with
//! one seed on `testing::simulated_cluster` — faults and inputs at times or when conditions first hold, invariants
//! judged at every moment something happened, expectations judged on the trace and the end state. The judging is
//! `Observer`, which knows nothing of `testing::simulated_cluster`: it takes trace records and a way to read variables,
//! says which `when` triggers fired at a moment, and gives the verdicts at the end — the simulated run and `baton test
//! --cluster` (which feeds it the trace of real processes) judge alike. Also `follow_steps`, where each step is active
//! (the runner's and coverage's one tracker), `skill_model` (shared with `baton-agent --simulate`) and `runs_twice`,
//! the once-per-epoch judge; `coverage.rs`, steps, transitions, branches and the steps each fault struck; `junit.rs`,
//! the JUnit XML report; `bench_charts.rs`, the charts `baton bench` and the criterion benches both run.

pub mod bench_charts;
pub mod cond;
pub mod coverage;
pub mod fuzz;
pub mod junit;
pub mod run;
pub mod scenario;
pub mod simulated_cluster;
