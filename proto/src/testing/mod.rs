//! `baton test`'s core: users' own scenarios for their charts (`scenario`), their conditions (`cond`), run on
//! the simulated cell and judged (`run`), and written out as JUnit XML for CI (`junit`).

pub mod cond;
pub mod junit;
pub mod run;
pub mod scenario;
