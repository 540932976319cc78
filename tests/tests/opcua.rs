//! The `opcua_method` skill and variables bound to OPC UA nodes, against an OPC UA server Baton did not write:
//! FreeOpcUa's asyncua (PyPI), running
//! `tests/scripts/opcua_server.py` on a loopback port. The chart names its endpoint; the test writes the
//! server's port into a copy of the chart.

use std::path::PathBuf;

use baton_proto::exec::trace::{TraceEvent, TraceRecord};
use baton_tests::loopback::{events, free_port, repo, Cluster, Coordinator};
use baton_tests::peer::{opcua_server as server, opcua_server_on, with_opcua_port};

/// `tests/charts/NAME` with the server's port in its endpoints.
fn chart_for(cluster: &Cluster, name: &str, port: u16) -> PathBuf {
    with_opcua_port(&repo(&format!("tests/charts/{name}")), cluster.dir.path(), port)
}

/// Starts agent `cell1`, its certificates in the cluster's folder, and a coordinator on `chart`.
fn start(cluster: &mut Cluster, chart: &std::path::Path) -> Coordinator {
    let pki = cluster.dir.path().join("pki");
    cluster.agent("cell1", &[], &["--opcua-pki", pki.to_str().expect("utf-8 path"), "--verbose"]);
    cluster.coordinator_joining(chart, &[])
}

/// Runs `chart` with agent `cell1` until the chart ends.
async fn run(cluster: &mut Cluster, chart: &std::path::Path) -> (Vec<TraceRecord>, serde_json::Value) {
    let coordinator = start(cluster, chart);
    let (status, log, trace, summary) = coordinator.finish().await;
    assert!(status.success(), "{log}\n{}", cluster.agent_log("cell1"));
    (trace, summary)
}

fn var(summary: &serde_json::Value, name: &str) -> String {
    summary["vars"][name].as_str().unwrap_or("<missing>").to_string()
}

fn reached(trace: &[TraceRecord], step: &str) -> bool {
    events(trace, TraceEvent::Activate).iter().any(|e| e.1 == step)
}

fn faults(trace: &[TraceRecord]) -> Vec<String> {
    trace.iter().filter(|r| r.event == TraceEvent::SkillFault).map(|r| r.message.clone().unwrap_or_default()).collect()
}

async fn methods_are_called_with_their_declared_types_and_a_job_is_followed_to_its_end() {
    let (server, port) = server().await;
    let mut cluster = Cluster::with_router().await;
    let chart = chart_for(&cluster, "opcua_method.st", port);
    let (trace, summary) = run(&mut cluster, &chart).await;
    assert!(reached(&trace, "Done"), "{:?}\n{}", faults(&trace), cluster.agent_log("cell1"));
    // Add(a: Int32, b: Int16) took 40 and 2 and answered 42; Pick answered job 1, and its job added 3 parts.
    assert_eq!(var(&summary, "sum"), "42");
    assert_eq!(var(&summary, "job"), "1");
    assert_eq!(var(&summary, "count"), "3");
    assert_eq!(events(&trace, TraceEvent::SkillDone).len(), 2);
    let said = server.finish().await;
    let calls: Vec<&String> = said.iter().filter(|l| l.starts_with("CALL") || l.starts_with("JOB")).collect();
    assert_eq!(calls, ["CALL Add 40 2", "CALL Pick 3 0.5", "JOB DONE"], "{said:?}");
}

async fn a_bad_status_an_argument_that_does_not_fit_and_a_fault_node_are_faults() {
    let (server, port) = server().await;
    let mut cluster = Cluster::with_router().await;
    let chart = chart_for(&cluster, "opcua_faults.st", port);
    let (trace, _) = run(&mut cluster, &chart).await;
    assert!(reached(&trace, "Done"), "{:?}", faults(&trace));
    let faults = faults(&trace);
    assert_eq!(faults.len(), 3, "{faults:?}");
    assert!(faults[0].contains("BadInvalidState"), "{}", faults[0]);
    assert!(faults[1].contains("argument `b`") && faults[1].contains("70000 does not fit a Int16"), "{}", faults[1]);
    assert!(faults[2].contains("ns=2;s=Cell.Fault became TRUE"), "{}", faults[2]);
    let said = server.finish().await;
    assert!(!said.iter().any(|l| l.starts_with("CALL Add")), "an argument that does not fit calls nothing: {said:?}");
    assert!(said.iter().any(|l| l == "JOB FAULT"), "{said:?}");
}

async fn a_job_whose_step_is_left_is_cancelled_on_the_server_and_never_reported_done() {
    let (mut server, port) = server().await;
    let mut cluster = Cluster::with_router().await;
    let chart = chart_for(&cluster, "opcua_cancel.st", port);
    let (trace, summary) = run(&mut cluster, &chart).await;
    assert!(reached(&trace, "Left"));
    server.wait_for("CANCELLED").await;
    let stopped = |r: &TraceRecord| r.event == TraceEvent::SkillStopped && r.name == "PickSlowly";
    let agent_trace = cluster.wait_for_agent_trace("cell1", "PickSlowly stopped", stopped).await;
    assert!(!agent_trace.iter().any(|r| r.event == TraceEvent::SkillDone), "{agent_trace:#?}");
    assert!(events(&trace, TraceEvent::SkillDone).is_empty() && faults(&trace).is_empty(), "{trace:?}");
    assert_eq!((var(&summary, "picked"), var(&summary, "pick_fault")), ("FALSE".into(), "FALSE".into()));
    let said = server.finish().await;
    assert!(!said.iter().any(|l| l == "JOB DONE"), "{said:?}");
}

async fn a_server_killed_during_a_call_is_a_fault_at_once() {
    let (mut server, port) = server().await;
    let mut cluster = Cluster::with_router().await;
    let chart = chart_for(&cluster, "opcua_hang.st", port);
    let coordinator = start(&mut cluster, &chart);
    server.wait_for("CALL Hang").await;
    server.kill().await;
    let (status, log, trace, _) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    assert!(reached(&trace, "Lost"), "{:?}", faults(&trace));
    let fault = &faults(&trace)[0];
    assert!(!fault.contains("timeout_ms"), "the fault came from the lost connection, not the timeout: {fault}");
    assert!(fault.contains("calling ns=2;s=Cell.Hang") || fault.contains("lost the connection"), "{fault}");
}

async fn no_server_is_a_fault_after_the_timeout() {
    let mut cluster = Cluster::with_router().await;
    let port = free_port();
    let chart = chart_for(&cluster, "opcua_hang.st", port);
    let text = std::fs::read_to_string(&chart).expect("chart").replace("timeout_ms := 50000", "timeout_ms := 800");
    std::fs::write(&chart, text).expect("write the chart");
    let (trace, _) = run(&mut cluster, &chart).await;
    assert!(reached(&trace, "Lost"));
    let fault = &faults(&trace)[0];
    assert!(fault.contains(&format!("cannot reach opc.tcp://127.0.0.1:{port}/")), "{fault}");
}

async fn bound_nodes_drive_a_transition_take_the_outputs_and_a_server_away_is_reported_and_caught_up() {
    let mut cluster = Cluster::with_router().await;
    let port = free_port();
    let chart = chart_for(&cluster, "opcua_io.st", port);
    let mut coordinator = start(&mut cluster, &chart);
    // No server yet: the agent says so, through the coordinator, and keeps trying.
    coordinator.wait_for_trace("door down", |r| r.event == TraceEvent::DeviceDown && r.name == "door").await;
    let mut server = opcua_server_on(port).await;
    // Once the session is up, the outputs' values are written, and the inputs are watched.
    server.wait_for("WRITE Lamp False").await;
    server.wait_for("WRITE Setpoint 0").await;
    coordinator.wait_for_trace("door back", |r| r.event == TraceEvent::DeviceUp && r.name == "door").await;
    server.send("SET Count 2").await;
    server.send("SET Door true").await;
    // The transition cleared on the machine's values; the action's outputs reach the machine, converted to
    // the nodes' types (the DINT setpoint to an Int16 node).
    server.wait_for("WRITE Lamp True").await;
    server.wait_for("WRITE Setpoint 20").await;
    // The machine goes away: reported, and the inputs keep their values.
    let mark = coordinator.trace_mark();
    server.kill().await;
    coordinator
        .wait_for_trace_after(mark, "door down", |r| r.event == TraceEvent::DeviceDown && r.name == "door")
        .await;
    // It comes back (restarted, its nodes at their initial values): the chart's outputs are written again.
    let mut again = opcua_server_on(port).await;
    again.wait_for("WRITE Lamp True").await;
    again.wait_for("WRITE Setpoint 20").await;
    coordinator.wait_for_trace("door back", |r| r.event == TraceEvent::DeviceUp && r.name == "door").await;
    // Its count reads 0 now, and the action, still running, follows it.
    again.wait_for("WRITE Setpoint 0").await;
    let ep = cluster.endpoint.clone();
    let set = cluster.baton(&["set", "--connect", &ep, "stop=true"]).await;
    assert!(set.status.success(), "{}", String::from_utf8_lossy(&set.stderr));
    let (status, log, trace, summary) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    assert!(reached(&trace, "Done"));
    let door = |event: TraceEvent| trace.iter().filter(|r| r.event == event && r.name == "door").count();
    assert_eq!((door(TraceEvent::DeviceDown), door(TraceEvent::DeviceUp)), (2, 2), "{trace:?}");
    let down = trace.iter().find(|r| r.event == TraceEvent::DeviceDown && r.name == "door").expect("a device_down");
    assert_eq!(down.agent.as_deref(), Some("cell1"));
    assert!(down.message.as_deref().is_some_and(|m| m.contains("OPC UA node ns=2;s=Cell.Door")), "{down:?}");
    // The restarted machine's door and count are the inputs' values now.
    assert_eq!((var(&summary, "door"), var(&summary, "count")), ("FALSE".into(), "0".into()));
    assert_eq!((var(&summary, "lamp"), var(&summary, "setpoint")), ("TRUE".into(), "0".into()));
    drop(again.finish().await);
}

async fn a_step_entered_again_starts_its_job_only_once_the_old_job_is_cancelled() {
    let (mut server, port) = server().await;
    let mut cluster = Cluster::with_router().await;
    let chart = chart_for(&cluster, "opcua_reenter.st", port);
    let (trace, _) = run(&mut cluster, &chart).await;
    assert!(reached(&trace, "Done"), "{:?}\n{}", faults(&trace), cluster.agent_log("cell1"));
    server.wait_for("CANCELLED JOB 2").await;
    let said = server.finish().await;
    let jobs: Vec<&String> = said.iter().filter(|l| l.starts_with("CALL") || l.starts_with("CANCELLED")).collect();
    // The slow cancel of the first job answered before the second job was asked for: each cancel stopped its own.
    assert_eq!(jobs, ["CALL Pick 2 0.001", "CANCELLED JOB 1", "CALL Pick 2 0.001", "CANCELLED JOB 2"], "{said:?}");
}

baton_tests::harness_main!(
    tokio methods_are_called_with_their_declared_types_and_a_job_is_followed_to_its_end,
    tokio a_bad_status_an_argument_that_does_not_fit_and_a_fault_node_are_faults,
    tokio a_job_whose_step_is_left_is_cancelled_on_the_server_and_never_reported_done,
    tokio a_server_killed_during_a_call_is_a_fault_at_once,
    tokio no_server_is_a_fault_after_the_timeout,
    tokio bound_nodes_drive_a_transition_take_the_outputs_and_a_server_away_is_reported_and_caught_up,
    tokio a_step_entered_again_starts_its_job_only_once_the_old_job_is_cancelled,
);
