//! The top layer of the core: charts run whole, on virtual time, and judged. `simulated_cluster` runs the real
//! coordinator and agent state machines over a simulated network with simulated skills; `baton test`'s users'
//! scenarios for their charts (`scenario`) with their conditions (`cond`) run on it and are judged (`run`), with
//! what they exercised of the chart (`coverage`), written out as JUnit XML for CI (`junit`).

pub mod cond;
pub mod coverage;
pub mod junit;
pub mod run;
pub mod scenario;
pub mod simulated_cluster;
