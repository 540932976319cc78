//! The coordinator as its systemd unit runs it (`deploy/systemd/baton-run@.service`): the unit's own command line,
//! its paths and environment put to the test's. `systemctl stop`, `systemctl restart` and a reboot send SIGTERM:
//! the coordinator leaves the run as it stands, the agents keep their tokens, and the unit started again resumes it
//! from its journal — the run's outcome is that of a run without the restart.

use baton_proto::cluster::wire;
use baton_proto::exec::trace::{TraceEvent, TraceRecord};
use baton_tests::loopback::{self, check_trace_invariants, dispatches, repo, Cluster};
use baton_tests::unit;

/// Two robots move at once for seconds, then one moves again and counts: a run of about 4.5 s.
const CHART: &str = "PROGRAM line\nVAR a, b, c : BOOL; n : INT; END_VAR\nINITIAL_STEP Idle: END_STEP\n\
    TRANSITION FROM Idle TO (A, B) := TRUE; END_TRANSITION\n\
    STEP A: {agent := 'robot1'} MoveA(N, a); END_STEP\nTRANSITION FROM A TO AEnd := a; END_TRANSITION\n\
    STEP AEnd: END_STEP\n\
    STEP B: {agent := 'robot2'} MoveB(N, b); END_STEP\nTRANSITION FROM B TO BEnd := b; END_TRANSITION\n\
    STEP BEnd: END_STEP\n\
    TRANSITION FROM (AEnd, BEnd) TO C := TRUE; END_TRANSITION\n\
    STEP C: {agent := 'robot1'} MoveC(N, c); Count(P1); END_STEP\nTRANSITION FROM C TO Done := c; END_TRANSITION\n\
    STEP Done: END_STEP\n\
    ACTION MoveA: {skill := 'motion', ms := 2500} END_ACTION\n\
    ACTION MoveB: {skill := 'motion', ms := 2000} END_ACTION\n\
    ACTION MoveC: {skill := 'motion', ms := 2000} END_ACTION\n\
    ACTION Count: n := n + 1; END_ACTION\nEND_PROGRAM\n";

/// Per step, how often it was active; and the variables' final values — what a run's outcome is.
fn outcome(summary: &serde_json::Value) -> (serde_json::Value, serde_json::Value) {
    let activations = summary["steps"]
        .as_object()
        .expect("steps")
        .iter()
        .map(|(k, v)| (k.clone(), v["activations"].clone()))
        .collect::<serde_json::Map<_, _>>();
    (serde_json::Value::Object(activations), summary["vars"].clone())
}

fn count(trace: &[TraceRecord], event: TraceEvent, name: &str) -> usize {
    trace.iter().filter(|r| r.event == event && r.name == name).count()
}

/// The unit's command, SIGTERMed while both robots move (`systemctl restart`), then started again: it resumes the
/// run from its journal, each robot's motion running once, and ends as the same command ends without the restart.
#[tokio::test(flavor = "multi_thread")]
async fn a_service_restart_resumes_the_run_and_changes_nothing_of_its_outcome() {
    let unit = std::fs::read_to_string(repo("deploy/systemd/baton-run@.service")).expect("the unit");
    let mut cluster = Cluster::with_router().await;
    let dir = cluster.dir.path().to_path_buf();
    std::fs::create_dir_all(dir.join("etc")).expect("etc");
    let chart = dir.join("etc/cell.st");
    std::fs::write(&chart, CHART).expect("the chart");
    std::fs::write(dir.join("etc/calm.st"), CHART).expect("the chart");
    cluster.agent("robot1", &[], &[]);
    cluster.agent("robot2", &[], &[]);
    let files = |name: &str| (dir.join(format!("{name}.jsonl")), dir.join(format!("{name}.json")));
    let command = |instance: &str| {
        let (trace, summary) = files(instance);
        let args = format!("--on-agent-loss reassign --trace {} --summary {}", trace.display(), summary.display());
        unit::command(&unit, &dir, instance, &[("BATON_ROUTER", &cluster.endpoint), ("BATON_RUN_ARGS", &args)])
    };
    // The run without a restart: an instance of its own.
    let (calm_trace, calm_summary) = files("calm");
    let (status, log, calm, calm_summary) = unit::start(&command("calm"), &calm_trace, &calm_summary).finish().await;
    assert!(status.success(), "{log}");
    // The same, restarted while A and B move.
    let watch = cluster.watch().await;
    let reports = watch.declare_subscriber("baton/run/*/report/*").await.expect("report subscriber");
    let (trace, summary) = files("cell");
    let command = command("cell");
    let first = unit::start(&command, &trace, &summary);
    // Both robots moving: each has reported what its segment did so far (its step active, its skill started).
    let mut moving = vec!["robot1".to_string(), "robot2".to_string()];
    let both = tokio::time::timeout(loopback::TIMEOUT, async {
        while !moving.is_empty() {
            let sample = reports.recv_async().await.expect("the report subscriber");
            if let Ok(r) = wire::decode::<wire::Report>(&sample.payload().to_bytes()) {
                if !r.events.is_empty() && !r.done {
                    moving.retain(|a| *a != r.agent);
                }
            }
        }
    })
    .await;
    assert!(both.is_ok(), "A and B did not both start");
    let pid = first.child.id().expect("running").to_string();
    assert!(std::process::Command::new("kill").args(["-TERM", &pid]).status().expect("kill").success());
    let (status, log, _, _) = first.finish().await;
    // It left the run as it stands, with an exit status that the unit counts a clean stop.
    let code = status.code().expect("an exit status, not a signal");
    assert_eq!(code, 5, "{log}");
    assert!(unit::setting(&unit, "SuccessExitStatus").split_whitespace().any(|s| s == code.to_string()));
    assert!(log.contains("is kept in its journal"), "{log}");
    let (status, log, restarted, restarted_summary) = unit::start(&command, &trace, &summary).finish().await;
    assert!(status.success(), "{log}");
    assert!(log.contains("resuming run"), "{log}");
    check_trace_invariants(&restarted, &chart);
    assert_eq!(outcome(&restarted_summary), outcome(&calm_summary), "{log}");
    // Count's body ran at C's activation and once more in its final scan (IEC 61131-3): C was entered once.
    assert_eq!(restarted_summary["vars"]["n"], "2");
    // Nothing was ended or stopped, the robots kept their tokens through the restart, and each motion ran once.
    assert!(!restarted.iter().any(|r| r.event == TraceEvent::State && r.name.starts_with("stop")), "{restarted:#?}");
    assert_eq!(restarted.iter().filter(|r| r.event == TraceEvent::Recover).count(), 1);
    for step in ["A", "B"] {
        let resumed = restarted.iter().find(|r| r.event == TraceEvent::Resume && r.name == step);
        let about: Vec<&TraceRecord> = restarted.iter().filter(|r| r.name == step).collect();
        assert_eq!(resumed.and_then(|r| r.message.as_deref()), Some("still held by the agent"), "{step}: {about:#?}");
    }
    for (step, action) in [("A", "MoveA"), ("B", "MoveB"), ("C", "MoveC")] {
        assert_eq!(dispatches(&restarted, step).len(), 1, "{step} dispatched once");
        assert_eq!(count(&restarted, TraceEvent::ActionOn, action), count(&calm, TraceEvent::ActionOn, action));
    }
}
