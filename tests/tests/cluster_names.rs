//! A name is held by one live process: a second agent under a taken name is refused at start, a coordinator
//! that hears two processes answer to one name dispatches to neither and raises an alarm, and commands reach
//! one process only. An agent waiting for its router at start still stops when told.

use baton_proto::cluster::keys;
use baton_proto::cluster::wire::{self, AgentInfo};
use baton_proto::exec::trace::TraceEvent;
use baton_tests::loopback::{bin, check_trace_invariants, events, free_port, read_trace, repo, Cluster, TIMEOUT};
use tokio::process::Command;

fn chart() -> std::path::PathBuf {
    repo("tests/charts/one_step.st")
}

#[tokio::test(flavor = "multi_thread")]
async fn a_second_agent_under_a_taken_name_is_refused_at_start() {
    let mut cluster = Cluster::new();
    // r1 holds its step until the test says `go`: the run (and the router the coordinator hosts) stays up until the
    // second agent has been refused, however fast the first one's step would otherwise end.
    let chart = cluster.dir.path().join("held.st");
    std::fs::write(
        &chart,
        "PROGRAM held\nVAR_INPUT go : BOOL; END_VAR\nINITIAL_STEP Start: END_STEP\n\
         TRANSITION FROM Start TO Move := TRUE; END_TRANSITION\nSTEP Move: {agent := 'r1'} END_STEP\n\
         TRANSITION FROM Move TO Done := go; END_TRANSITION\nSTEP Done: END_STEP\nEND_PROGRAM\n",
    )
    .expect("write the chart");
    let mut coordinator = cluster.coordinator(&chart, &[]);
    coordinator.wait_ready().await;
    cluster.agent("r1", &[], &[]);
    coordinator.wait_for_trace("r1 live", |r| r.event == TraceEvent::AgentUp && r.name == "r1").await;
    let second = Command::new(bin("baton-agent"))
        .args(["--connect", &cluster.endpoint, "--name", "r1"])
        .kill_on_drop(true)
        .output();
    let second = tokio::time::timeout(TIMEOUT, second).await.expect("the second agent ended").expect("it ran");
    let stderr = String::from_utf8_lossy(&second.stderr);
    assert!(!second.status.success(), "a second `r1` ran: {stderr}");
    assert!(stderr.contains("an agent named `r1` is already live"), "{stderr}");
    let go = cluster.baton(&["set", "--connect", &cluster.endpoint, "go=true"]).await;
    assert!(go.status.success(), "{}", String::from_utf8_lossy(&go.stderr));
    let (status, log, trace, _) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    check_trace_invariants(&trace, &chart);
    assert_eq!(events(&trace, TraceEvent::Dispatch).len(), 1);
}

#[tokio::test(flavor = "multi_thread")]
async fn two_processes_answering_to_one_name_get_nothing_until_one_is_left() {
    let mut cluster = Cluster::new();
    let mut coordinator = cluster.coordinator(&chart(), &[]);
    coordinator.wait_ready().await;
    // A process that answers as r1 besides the real one (started at the same moment, both passed the check).
    let session = cluster.watch().await;
    let impostor = session.declare_queryable(keys::agent_info("r1")).await.expect("queryable");
    let info = AgentInfo {
        name: "r1".into(),
        roles: Vec::new(),
        lease_ms: 10_000,
        incarnation: uuid::Uuid::from_u128(0xdead),
        held: Vec::new(),
        pending: Vec::new(),
        skills: None,
    };
    let answering = tokio::spawn(async move {
        while let Ok(q) = impostor.recv_async().await {
            let _ = q.reply(q.key_expr().clone(), wire::encode(&info)).await;
        }
    });
    cluster.agent("r1", &[], &[]);
    coordinator
        .wait_for_trace("an alarm for two processes named r1", |r| r.event == TraceEvent::Alarm && r.name == "r1")
        .await;
    let so_far = read_trace(&coordinator.trace);
    assert!(
        events(&so_far, TraceEvent::Dispatch).is_empty(),
        "dispatched to a name two processes answer to: {so_far:?}"
    );
    assert!(so_far.iter().any(|r| r.event == TraceEvent::Alarm), "{so_far:?}");
    // The impostor goes: the real r1 answers alone, and gets the token.
    answering.abort();
    let _ = answering.await;
    coordinator.wait_for_trace("the token sent to r1", |r| r.event == TraceEvent::Dispatch).await;
    let (status, log, trace, _) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    check_trace_invariants(&trace, &chart());
    assert_eq!(events(&trace, TraceEvent::Dispatch).len(), 1);
}

/// `baton-agent --instances N` (benchmarks and tests): N agents in one process, each its own session and name,
/// each taking the steps placed on it; an instance whose name is taken stops the whole process, saying which.
#[tokio::test(flavor = "multi_thread")]
async fn agents_hosted_in_one_process_each_take_their_own_steps() {
    let mut cluster = Cluster::new();
    let chart = cluster.dir.path().join("three.st");
    std::fs::write(
        &chart,
        "PROGRAM three\nINITIAL_STEP Start: END_STEP\nTRANSITION FROM Start TO (A, B, C) := TRUE; END_TRANSITION\n\
         STEP A: {agent := 'h1'} END_STEP\nTRANSITION FROM A TO AW := TRUE; END_TRANSITION\nSTEP AW: END_STEP\n\
         STEP B: {agent := 'h2'} END_STEP\nTRANSITION FROM B TO BW := TRUE; END_TRANSITION\nSTEP BW: END_STEP\n\
         STEP C: {agent := 'h3'} END_STEP\nTRANSITION FROM C TO CW := TRUE; END_TRANSITION\nSTEP CW: END_STEP\n\
         TRANSITION FROM (AW, BW, CW) TO Done := TRUE; END_TRANSITION\nSTEP Done: END_STEP\nEND_PROGRAM\n",
    )
    .expect("write the chart");
    let mut coordinator = cluster.coordinator(&chart, &[]);
    coordinator.wait_ready().await;
    cluster.agent("h", &[], &["--instances", "3"]);
    let (status, log, trace, _) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    check_trace_invariants(&trace, &chart);
    let mut dispatched: Vec<(String, Option<String>)> =
        events(&trace, TraceEvent::Dispatch).into_iter().map(|(_, step, agent)| (step, agent)).collect();
    dispatched.sort();
    let expected: Vec<(String, Option<String>)> =
        [("A", "h1"), ("B", "h2"), ("C", "h3")].iter().map(|(s, a)| (s.to_string(), Some(a.to_string()))).collect();
    assert_eq!(dispatched, expected);
}

#[tokio::test(flavor = "multi_thread")]
async fn a_hosted_agent_whose_name_is_taken_stops_its_process() {
    let mut cluster = Cluster::new();
    let mut coordinator = cluster.coordinator(&chart(), &[]);
    coordinator.wait_ready().await;
    // x2 is taken; the chart needs none of the x's, so that a hosted x1 that came up first is given nothing.
    cluster.agent("x2", &[], &[]);
    coordinator.wait_for_trace("x2 live", |r| r.event == TraceEvent::AgentUp && r.name == "x2").await;
    let hosted = Command::new(bin("baton-agent"))
        .args(["--connect", &cluster.endpoint, "--name", "x", "--instances", "3"])
        .kill_on_drop(true)
        .output();
    let hosted = tokio::time::timeout(TIMEOUT, hosted).await.expect("the hosting process ended").expect("it ran");
    let stderr = String::from_utf8_lossy(&hosted.stderr);
    assert!(!hosted.status.success(), "three agents ran beside a live `x2`: {stderr}");
    assert!(stderr.contains("agent `x2`: an agent named `x2` is already live"), "{stderr}");
    cluster.agent("r1", &[], &[]);
    let (status, log, trace, _) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    check_trace_invariants(&trace, &chart());
}

/// An agent started before its router waits for it, says so, and still stops on Ctrl-C (SIGINT) or the service
/// manager's SIGTERM while it waits: it said "Ctrl-C to stop", and a unit that ignores SIGTERM is killed only after
/// systemd's timeout.
#[tokio::test(flavor = "multi_thread")]
async fn an_agent_waiting_for_its_router_stops_when_told() {
    let mut cluster = Cluster::new();
    // Nothing listens there: the port was free a moment ago and nobody is started on it.
    let nowhere = format!("tcp/127.0.0.1:{}", free_port());
    for (name, signal) in [("waiting_int", "INT"), ("waiting_term", "TERM")] {
        cluster.agent_at(&nowhere, name, &[], &[]);
        cluster.wait_for_agent_trace(name, "no router yet", |r| r.event == TraceEvent::ContactLost).await;
        cluster.signal_agent(name, signal);
        let status = cluster.wait_agent(name).await;
        assert!(status.success(), "SIG{signal}: {status}; {}", cluster.agent_log(name));
        assert!(cluster.agent_log(name).contains("stopped before a router answered"), "{}", cluster.agent_log(name));
    }
}
