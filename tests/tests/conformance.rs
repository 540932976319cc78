//! One test per conformance case under `tests/conformance/`: `traces::NAME` runs a trace case (what `baton sim`
//! prints for `traces/NAME/`), `diagnostics::NAME` a diagnostics case (what `baton check` prints for
//! `diagnostics/NAME.st` or `.xml`). Each goes through the one driver, `baton_tests::conformance::check`, and is
//! named, so that a failing case says which and runs alone:
//! `cargo test -p baton-tests --test conformance -- traces::fb_timers`.

use std::path::{Path, PathBuf};

use libtest_mimic::{Arguments, Failed, Trial};

/// The cases of one folder, sorted, as (name, path).
fn cases(folder: &str, keep: impl Fn(&Path) -> bool) -> Vec<(String, PathBuf)> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("conformance").join(folder);
    let mut paths: Vec<PathBuf> = std::fs::read_dir(&root)
        .unwrap_or_else(|e| panic!("cannot list {}: {e}", root.display()))
        .map(|e| e.expect("directory entry").path())
        .filter(|p| keep(p))
        .collect();
    paths.sort();
    assert!(!paths.is_empty(), "no conformance cases in {}", root.display());
    let name = |p: &Path| format!("{folder}::{}", p.file_stem().expect("a name").to_string_lossy());
    paths.into_iter().map(|p| (name(&p), p)).collect()
}

fn main() {
    let args = Arguments::from_args();
    let traces = cases("traces", |p| p.is_dir());
    let diagnostics = cases("diagnostics", |p| p.extension().is_some_and(|e| e == "st" || e == "xml"));
    let trials = traces
        .into_iter()
        .chain(diagnostics)
        .map(|(name, path)| Trial::test(name, move || baton_tests::conformance::check(&path).map_err(Failed::from)))
        .collect();
    libtest_mimic::run(&args, trials).exit();
}
