//! A run recorded for Rerun (`baton run --rerun save:…`), read back with the Rerun SDK of the same version
//! (`rerun-sdk==0.36.3`, Python) and checked against the run's trace.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use baton_proto::sim::TraceRecord;
use baton_tests::cluster::{repo, Cluster};

/// Whether `python3` has rerun-sdk 0.36.3; in CI (`CI` set) its absence fails the test.
fn reader_available() -> bool {
    let probe = std::process::Command::new("python3")
        .args(["-c", "import rerun, sys; sys.exit(0 if rerun.__version__ == '0.36.3' else 1)"])
        .output();
    let ok = probe.is_ok_and(|o| o.status.success());
    if !ok {
        assert!(
            std::env::var_os("CI").is_none(),
            "CI needs python3 with rerun-sdk==0.36.3 (`pip install 'rerun-sdk[datafusion]==0.36.3'`, as .ci/run does)"
        );
        eprintln!(
            "SKIPPED: reading a recording back needs python3 with rerun-sdk 0.36.3: \
             pip install 'rerun-sdk[datafusion]==0.36.3'"
        );
    }
    ok
}

fn read_recording(rrd: &Path) -> serde_json::Value {
    let script = repo("tests/scripts/read_recording.py");
    let out = std::process::Command::new("python3").arg(&script).arg(rrd).output().expect("python3 runs");
    assert!(out.status.success(), "reading {} failed: {}", rrd.display(), String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).expect("the reader prints JSON")
}

/// A step's activity over time: (time, active), the last of each instant, without repeats.
fn activity(changes: impl IntoIterator<Item = (i64, bool)>) -> Vec<(i64, bool)> {
    let mut last_per_instant: BTreeMap<i64, bool> = BTreeMap::new();
    let mut order = Vec::new();
    for (t, active) in changes {
        if last_per_instant.insert(t, active).is_none() {
            order.push(t);
        }
    }
    let mut out: Vec<(i64, bool)> = Vec::new();
    for t in order {
        let active = last_per_instant[&t];
        if out.last().map(|l| l.1) != Some(active) {
            out.push((t, active));
        }
    }
    out
}

#[tokio::test(flavor = "multi_thread")]
async fn a_recording_holds_every_entity_and_the_steps_states_of_the_trace() {
    if !reader_available() {
        return;
    }
    let cell = repo("examples/cell.st");
    let mut cluster = Cluster::new();
    let rrd = cluster.dir.path().join("run.rrd");
    let sink = format!("save:{}", rrd.display());
    let mut coordinator = cluster.coordinator(&cell, &["--set", "parts=2", "--rerun", &sink]);
    coordinator.wait_for_log("running chart").await;
    cluster.agent("robot1", &["assembler"], &[]);
    cluster.agent("robot2", &["assembler"], &[]);
    let (status, log, trace, _) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    let recording = read_recording(&rrd);

    let paths: BTreeSet<String> = recording["entity_paths"]
        .as_array()
        .expect("entity paths")
        .iter()
        .map(|p| p.as_str().unwrap_or_default().to_string())
        .collect();
    let source = std::fs::read_to_string(&cell).expect("chart");
    let report = baton_proto::check::check_source(&source);
    let program = report.charts[0].program.as_ref().expect("valid chart");
    let mut expected: Vec<String> = vec!["/sfc/graph".into(), "/log".into(), "/vars/done".into(), "/vars/parts".into()];
    expected.extend(program.steps.iter().map(|s| format!("/sfc/steps/{}", s.name)));
    expected.extend(["/agents/robot1".to_string(), "/agents/robot2".to_string()]);
    let tokens: BTreeSet<&str> =
        trace.iter().filter(|r| r.event == "dispatch").filter_map(|r| r.token.as_deref()).collect();
    assert!(!tokens.is_empty());
    expected.extend(tokens.iter().map(|t| format!("/tokens/{t}")));
    for path in &expected {
        assert!(paths.contains(path), "{path} is missing from the recording; it has {paths:?}");
    }

    // Each step's activity in the recording is the trace's, on the wall clock (run start + t_ms).
    let mut offsets = BTreeSet::new();
    for step in &program.steps {
        let from_trace =
            activity(trace.iter().filter(|r: &&TraceRecord| r.name == step.name).filter_map(
                |r| match r.event.as_str() {
                    "activate" => Some((r.t_ms as i64, true)),
                    "deactivate" => Some((r.t_ms as i64, false)),
                    _ => None,
                },
            ));
        let logged = recording["steps"][&step.name].as_array().cloned().unwrap_or_default();
        let from_recording = activity(logged.iter().map(|c| {
            let wall = c[0].as_i64().expect("wall ms");
            (wall, c[1].as_str() != Some("inactive"))
        }));
        assert_eq!(
            from_trace.iter().map(|c| c.1).collect::<Vec<_>>(),
            from_recording.iter().map(|c| c.1).collect::<Vec<_>>(),
            "step {}: trace {from_trace:?}, recording {from_recording:?}",
            step.name
        );
        for (a, b) in from_trace.iter().zip(&from_recording) {
            offsets.insert(b.0 - a.0);
        }
    }
    let (lo, hi) = (offsets.first().copied().unwrap_or(0), offsets.last().copied().unwrap_or(0));
    assert!(hi - lo <= 1, "the recording's wall times are the trace's plus one start time: offsets {offsets:?}");
}
