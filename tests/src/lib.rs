//! Test support for Baton: the scenario driver and chart generators shared by tests and benchmarks.

pub mod cluster;
pub mod gen;
pub mod invariants;
pub mod netns;
pub mod reference;
pub mod scenario;
pub mod simnet;

use std::path::PathBuf;

/// The team's shared folder (`../shared` beside the checkout), where the public SFC corpus lives.
pub fn shared_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared")
}
