//! The public textual charts in `../shared/corpus/sfc` (see its SOURCES.md): each parses, or is rejected with
//! precise errors, exactly as recorded in `tests/corpus_expected`; the valid ones also run.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use baton_proto::exec::sim::simulate;
use baton_proto::front::check::check_source;

fn corpus_files() -> Option<Vec<PathBuf>> {
    let dir = baton_tests::shared_dir().join("corpus/sfc");
    let Ok(entries) = std::fs::read_dir(&dir) else {
        let message = format!(
            "the shared SFC corpus is absent ({}): these tests need ../shared beside the checkout",
            dir.display()
        );
        // CI always has ../shared; a missing corpus there is a broken setup, not a reason to pass.
        assert!(std::env::var_os("CI").is_none(), "{message}");
        eprintln!("SKIPPED: {message}");
        return None;
    };
    let mut files: Vec<PathBuf> = entries
        .map(|e| e.expect("directory entry").path())
        .filter(|p| p.extension().is_some_and(|e| e == "st" || e == "txt" || e == "test"))
        .collect();
    files.sort();
    assert!(!files.is_empty(), "no textual charts in {}", dir.display());
    Some(files)
}

fn expected_path(file: &Path) -> PathBuf {
    let name = file.file_name().expect("file name").to_string_lossy().into_owned();
    Path::new(env!("CARGO_MANIFEST_DIR")).join("corpus_expected").join(format!("{name}.expected"))
}

#[test]
fn corpus_charts_parse_or_are_rejected_precisely() {
    let Some(files) = corpus_files() else { return };
    let failures: Vec<String> = files
        .iter()
        .filter_map(|f| baton_tests::scenario::check_diagnostics_against(f, &expected_path(f)).err())
        .collect();
    assert!(failures.is_empty(), "{}", failures.join("\n\n"));
}

#[test]
fn valid_corpus_charts_run() {
    let Some(files) = corpus_files() else { return };
    let mut ran = 0;
    for file in files {
        let src = std::fs::read_to_string(&file).expect("readable corpus file");
        for chart in check_source(&src).charts {
            let Some(program) = chart.program else { continue };
            let mut events = 0;
            simulate(Arc::new(program), &[], 10, 2000, |_| events += 1).expect("simulation runs");
            assert!(events > 0, "{}: chart `{}` produced no events", file.display(), chart.chart.name.name);
            ran += 1;
        }
    }
    // matiec's sfc.txt and both ironplc charts are valid.
    assert!(ran >= 3, "only {ran} corpus charts ran");
}
