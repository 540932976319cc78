//! `baton test`'s core: users' own scenarios for their charts (`scenario`), their conditions (`cond`), run on
//! the simulated cell and judged (`run`), what they exercised of the chart (`coverage`), and written out as
//! JUnit XML for CI (`junit`).

pub mod cond;
pub mod coverage;
pub mod junit;
pub mod run;
pub mod scenario;
