//! Runs every scenario under `tests/scenarios` (simulation traces) and `tests/diagnostics` (what `baton check`
//! prints) through the one driver, `baton_tests::scenario::check`.

use std::path::{Path, PathBuf};

fn entries(folder: &str, keep: impl Fn(&Path) -> bool) -> Vec<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join(folder);
    let mut paths: Vec<PathBuf> = std::fs::read_dir(&root)
        .unwrap_or_else(|e| panic!("cannot list {}: {e}", root.display()))
        .map(|e| e.expect("directory entry").path())
        .filter(|p| keep(p))
        .collect();
    paths.sort();
    assert!(!paths.is_empty(), "no scenarios in {}", root.display());
    paths
}

fn run_all(paths: Vec<PathBuf>) {
    let failures: Vec<String> = paths.iter().filter_map(|p| baton_tests::scenario::check(p).err()).collect();
    assert!(
        failures.is_empty(),
        "{} of {} scenarios failed:\n\n{}",
        failures.len(),
        paths.len(),
        failures.join("\n\n")
    );
}

#[test]
fn simulation_scenarios() {
    run_all(entries("scenarios", |p| p.is_dir()));
}

#[test]
fn diagnostics_scenarios() {
    run_all(entries("diagnostics", |p| p.extension().is_some_and(|e| e == "st" || e == "xml")));
}
