//! Runs recorded for Rerun — live (`baton run --rerun save:…`) and rebuilt from a journal afterwards
//! (`baton replay --journal DIR --rerun save:…`) — read back with the Rerun SDK of the same version
//! (`rerun-sdk==0.36.3`, Python) and checked against the run's trace.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use baton_proto::cluster::keys;
use baton_proto::exec::trace::{TraceEvent, TraceRecord};
use baton_tests::loopback::{self, read_trace, repo, step_id, Cluster};
use baton_tests::rrd::{log_lines, read_recording, require_reader};

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

/// Checks a recording of a run of `examples/cell.st` (`parts` parts, agents robot1 and robot2) against the run's
/// trace: every documented entity path is there, each step's active/inactive sequence is the trace's at the
/// trace's times (plus the run's start), the graph's colours change over time, and the counters end where the
/// run ended.
fn check_recording(rrd: &Path, trace: &[TraceRecord], parts: u64) {
    let recording = read_recording(rrd);
    let paths: BTreeSet<String> = recording["entity_paths"]
        .as_array()
        .expect("entity paths")
        .iter()
        .map(|p| p.as_str().unwrap_or_default().to_string())
        .collect();
    let cell = repo("examples/cell.st");
    let source = std::fs::read_to_string(&cell).expect("chart");
    let report = baton_proto::pipeline::check_source(&source);
    let program = report.charts[0].program.as_ref().expect("valid chart");
    let mut expected: Vec<String> = vec!["/sfc/graph".into(), "/log".into(), "/vars/done".into(), "/vars/parts".into()];
    expected.extend(program.steps.iter().map(|s| format!("/sfc/steps/{}", s.name)));
    expected.extend(["/agents/robot1".to_string(), "/agents/robot2".to_string()]);
    let tokens: BTreeSet<&str> =
        trace.iter().filter(|r| r.event == TraceEvent::Dispatch).filter_map(|r| r.token.as_deref()).collect();
    assert!(!tokens.is_empty());
    expected.extend(tokens.iter().map(|t| format!("/tokens/{t}")));
    for path in &expected {
        assert!(paths.contains(path), "{path} is missing from the recording; it has {paths:?}");
    }

    // Each step's activity in the recording is the trace's, on the wall clock (run start + t_ms).
    let mut offsets = BTreeSet::new();
    for step in &program.steps {
        let from_trace =
            activity(trace.iter().filter(|r: &&TraceRecord| r.name == step.name).filter_map(|r| match r.event {
                TraceEvent::Activate => Some((r.t_ms as i64, true)),
                TraceEvent::Deactivate => Some((r.t_ms as i64, false)),
                _ => None,
            }));
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

    // Each token's log tells its life: dispatched, progress on its agent, returned.
    for token in &tokens {
        let entries: Vec<String> = recording["tokens"][*token]
            .as_array()
            .unwrap_or_else(|| panic!("no log for token {token}"))
            .iter()
            .map(|e| e[1].as_str().unwrap_or_default().to_string())
            .collect();
        let short = &token[..8];
        assert!(entries.iter().all(|e| e.starts_with(&format!("[{short}] "))), "{entries:?}");
        assert!(entries.iter().any(|e| e.contains("dispatched to robot")), "token {token}: {entries:?}");
        assert!(entries.iter().any(|e| e.contains("returned from robot")), "token {token}: {entries:?}");
        let assembles = trace
            .iter()
            .any(|r| r.event == TraceEvent::Dispatch && r.name == "Assemble" && r.token.as_deref() == Some(token));
        if assembles {
            assert!(
                entries.iter().any(|e| e.contains("skill AssemblePart done on robot")),
                "token {token}: {entries:?}"
            );
            assert!(entries.iter().any(|e| e.contains("at step Inspect on robot")), "token {token}: {entries:?}");
        }
    }

    // The chart's colours follow the steps: more than the initial colouring.
    let colour_updates = recording["graph_colour_updates"].as_u64().unwrap_or(0);
    assert!(colour_updates > 2, "sfc/graph has {colour_updates} colour update(s)");
    // The counters as series: `done` counts up to `parts`, one change per part.
    let done: Vec<f64> = recording["vars"]["done"]
        .as_array()
        .expect("vars/done")
        .iter()
        .map(|p| p[1].as_f64().expect("a number"))
        .collect();
    assert_eq!(done, (0..=parts).map(|k| k as f64).collect::<Vec<_>>(), "vars/done");
}

/// Runs `examples/cell.st` for two parts on robot1 and robot2 with `extra` arguments; returns its trace.
async fn run_two_parts(cluster: &mut Cluster, extra: &[&str]) -> Vec<TraceRecord> {
    let mut args = vec!["--set", "parts=2"];
    args.extend_from_slice(extra);
    let mut coordinator = cluster.coordinator(&repo("examples/cell.st"), &args);
    coordinator.wait_ready().await;
    cluster.agent("robot1", &["assembler"], &[]);
    cluster.agent("robot2", &["assembler"], &[]);
    let (status, log, trace, _) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    trace
}

async fn a_live_recording_holds_every_entity_and_the_steps_states_of_the_trace() {
    require_reader();
    let mut cluster = Cluster::new();
    let rrd = cluster.dir.path().join("run.rrd");
    let sink = format!("save:{}", rrd.display());
    let trace = run_two_parts(&mut cluster, &["--rerun", &sink]).await;
    check_recording(&rrd, &trace, 2);
}

/// A run recorded with `--rerun off` can still be reviewed: `baton replay` rebuilds its trace, identical to the
/// live one, and its recording, which passes the same checks as a live recording.
async fn a_run_without_a_recording_is_recorded_afterwards_from_its_journal() {
    require_reader();
    let mut cluster = Cluster::new();
    let journal = cluster.dir.path().join("journal");
    let journal_arg = journal.display().to_string();
    let trace = run_two_parts(&mut cluster, &["--rerun", "off", "--journal", &journal_arg]).await;

    let rrd = cluster.dir.path().join("replayed.rrd");
    let replayed_trace = cluster.dir.path().join("replayed.jsonl");
    let sink = format!("save:{}", rrd.display());
    let out = cluster
        .baton(&[
            "replay",
            "--journal",
            &journal_arg,
            "--rerun",
            &sink,
            "--trace",
            &replayed_trace.display().to_string(),
        ])
        .await;
    assert!(out.status.success(), "baton replay failed: {}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(read_trace(&replayed_trace), trace, "the replayed trace differs from the live one");
    check_recording(&rrd, &trace, 2);
}

/// What went wrong is on the timeline: the robot holding Assemble is killed under `--on-agent-loss reassign`;
/// the recording shows the agent lost, the alarm, the token dispatched again in a new epoch to the other robot,
/// and the step running there.
async fn a_lost_agent_and_the_reassignment_are_on_the_timeline() {
    require_reader();
    let cell = repo("examples/cell.st");
    let mut cluster = Cluster::new();
    let rrd = cluster.dir.path().join("loss.rrd");
    let sink = format!("save:{}", rrd.display());
    let mut coordinator =
        cluster.coordinator(&cell, &["--set", "parts=1", "--on-agent-loss", "reassign", "--rerun", &sink]);
    coordinator.wait_ready().await;
    let session = cluster.watch().await;
    let cmds = session.declare_subscriber(keys::agent_cmd_any("*")).await.expect("subscriber");
    cluster.agent("robot1", &["assembler"], &[]);
    cluster.agent("robot2", &["assembler"], &[]);
    let (holder, token) = loopback::next_dispatch(&cmds, step_id(&cell, "Assemble"), 1).await;
    let other = if holder == "robot1" { "robot2" } else { "robot1" };
    cluster.kill_agent(&holder).await;
    let (status, log, trace, _) = coordinator.finish().await;
    assert!(status.success(), "{log}");

    let recording = read_recording(&rrd);
    let lines = log_lines(&recording);
    assert!(lines.contains(&("WARN".to_string(), format!("agent {holder} lost"))), "{lines:?}");
    assert!(lines.iter().any(|(level, text)| level == "ERROR" && text.starts_with("alarm #")), "{lines:?}");

    let states = |agent: &str| -> Vec<String> {
        recording["agents"][agent]
            .as_array()
            .unwrap_or_else(|| panic!("no states for {agent}"))
            .iter()
            .map(|s| s[1].as_str().unwrap_or_default().to_string())
            .collect()
    };
    let short = token.to_string()[..8].to_string();
    assert_eq!(states(&holder).last().map(String::as_str), Some("lost"), "{:?}", states(&holder));
    assert!(states(other).contains(&format!("busy: Assemble ({short})")), "{:?}", states(other));

    let entries: Vec<(String, String)> = recording["tokens"][token.to_string()]
        .as_array()
        .expect("the token's log")
        .iter()
        .map(|e| (e[0].as_str().unwrap_or_default().to_string(), e[1].as_str().unwrap_or_default().to_string()))
        .collect();
    let again = format!("[{short}] dispatched again, the segment restarting, to {other}: step Assemble, epoch 2");
    assert!(entries.contains(&("WARN".to_string(), again)), "{entries:?}");
    assert!(entries.iter().any(|(_, t)| t.contains(&format!("returned from {other}: step Assemble, epoch 2"))));

    let assemble: Vec<String> = recording["steps"]["Assemble"]
        .as_array()
        .expect("Assemble")
        .iter()
        .map(|s| s[1].as_str().unwrap_or_default().to_string())
        .collect();
    assert!(assemble.contains(&format!("on {holder}")) && assemble.contains(&format!("on {other}")), "{assemble:?}");
    assert!(trace.iter().any(|r| r.event == TraceEvent::AgentLost && r.name == holder));
}

/// An operator's work is on the timeline: a supervision alarm (its step marked faulted), a hold and an unhold with
/// who sent them and why, the run's states, and the alarm acknowledged with its comment and back to normal.
async fn commands_states_and_alarms_are_in_the_log() {
    require_reader();
    let mut cluster = Cluster::new();
    let chart = cluster.dir.path().join("slow.st");
    std::fs::write(
        &chart,
        "PROGRAM slow\nVAR moved : BOOL; END_VAR\nINITIAL_STEP Idle: END_STEP\n\
         TRANSITION FROM Idle TO Move := TRUE; END_TRANSITION\n\
         STEP Move: {agent := 'r1', max_ms := T#300ms} Drive(N, moved); END_STEP\n\
         TRANSITION FROM Move TO Done := moved; END_TRANSITION\nSTEP Done: END_STEP\n\
         ACTION Drive: {skill := 'motion', ms := 1000} END_ACTION\nEND_PROGRAM\n",
    )
    .expect("write the chart");
    let rrd = cluster.dir.path().join("operate.rrd");
    let sink = format!("save:{}", rrd.display());
    let mut coordinator = cluster.coordinator(&chart, &["--rerun", &sink]);
    coordinator.wait_ready().await;
    cluster.agent("r1", &[], &[]);
    coordinator.wait_for_trace("Move's supervision alarm", |r| r.event == TraceEvent::Alarm && r.name == "Move").await;
    let ctl = |args: &[&str]| {
        let mut all = vec!["ctl".to_string(), "--connect".to_string(), cluster.endpoint.clone()];
        all.extend(args.iter().map(|a| a.to_string()));
        all
    };
    for args in [
        ctl(&["hold", "--reason", "inspect the drive"]),
        ctl(&["unhold"]),
        ctl(&["ack", "1", "--comment", "drive checked"]),
    ] {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        // A hold is confirmed once the motion ends; the unhold is legal only then.
        let ok = tokio::time::timeout(baton_tests::loopback::TIMEOUT, async {
            loop {
                let out = cluster.baton(&args).await;
                if out.status.success() {
                    return;
                }
                tokio::time::sleep(std::time::Duration::from_millis(50)).await;
            }
        })
        .await;
        assert!(ok.is_ok(), "{args:?} never taken");
    }
    let (status, log, _, _) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    let recording = read_recording(&rrd);
    let lines = log_lines(&recording);
    let has = |level: &str, start: &str| lines.iter().any(|(l, t)| l == level && t.starts_with(start));
    assert!(has("ERROR", "alarm #1 (Move): step `Move` has been active longer than its maximum time of 300 ms"));
    assert!(lines.iter().any(|(_, t)| t.starts_with("command hold by ") && t.ends_with(": inspect the drive")));
    assert!(has("INFO", "run state: holding") && has("INFO", "run state: held"), "{lines:?}");
    assert!(lines.iter().any(|(_, t)| t.starts_with("command unhold by ")), "{lines:?}");
    assert!(lines.iter().any(|(_, t)| t.starts_with("alarm #1 acknowledged by ") && t.ends_with(": drive checked")));
    assert!(has("INFO", "alarm #1 (Move) back to normal"), "{lines:?}");
    let states: Vec<String> = recording["steps"]["Move"]
        .as_array()
        .expect("Move")
        .iter()
        .map(|s| s[1].as_str().unwrap_or_default().to_string())
        .collect();
    assert!(states.contains(&"faulted".to_string()), "{states:?}");
    // The chart view follows SFC notation: each transition a node of its own, labelled with its condition, between
    // its steps.
    let pairs = |key: &str| -> Vec<(String, String)> {
        recording[key]
            .as_array()
            .unwrap_or_else(|| panic!("no {key} in the recording"))
            .iter()
            .map(|n| (n[0].as_str().unwrap_or_default().to_string(), n[1].as_str().unwrap_or_default().to_string()))
            .collect()
    };
    let nodes = pairs("graph_nodes");
    let t = nodes.iter().find(|(_, label)| label == "moved").map(|(id, _)| id.clone());
    let t = t.unwrap_or_else(|| panic!("no node labelled with Move's condition: {nodes:?}"));
    let edges = pairs("graph_edges");
    assert!(edges.contains(&("Move".to_string(), t.clone())) && edges.contains(&(t, "Done".to_string())), "{edges:?}");
}

baton_tests::harness_main!(
    tokio commands_states_and_alarms_are_in_the_log,
    tokio a_live_recording_holds_every_entity_and_the_steps_states_of_the_trace,
    tokio a_run_without_a_recording_is_recorded_afterwards_from_its_journal,
    tokio a_lost_agent_and_the_reassignment_are_on_the_timeline,
);
