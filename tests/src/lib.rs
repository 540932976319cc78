//! Test support for Baton: the scenario driver and chart generators shared by tests and benchmarks.

pub mod conformance;
pub mod gen;
pub mod invariants;
pub mod loopback;
pub mod netns;
pub mod peer;
pub mod reference;
pub mod roundtrip;
pub mod rrd;

use std::path::PathBuf;

/// A test's prerequisite is missing (the shared corpus, root for namespaces, rerun-sdk): under CI (`CI` set)
/// the test fails, since CI installs everything; elsewhere it says SKIPPED and why.
pub fn missing(why: &str) {
    assert!(std::env::var_os("CI").is_none(), "cannot run under CI: {why}");
    eprintln!("SKIPPED: {why}");
}

/// The team's shared folder (`../shared` beside the checkout), where the public SFC corpus lives.
pub fn shared_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared")
}
