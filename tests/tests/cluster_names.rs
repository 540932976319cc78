//! A name is held by one live process: a second agent under a taken name is refused at start, a coordinator
//! that hears two processes answer to one name dispatches to neither and raises an alarm, and commands reach
//! one process only.

use baton_proto::dist::keys;
use baton_proto::dist::wire::{self, AgentInfo};
use baton_proto::exec::trace::TraceEvent;
use baton_tests::loopback::{bin, check_trace_invariants, events, read_trace, repo, Cluster, TIMEOUT};
use tokio::process::Command;

fn chart() -> std::path::PathBuf {
    repo("tests/charts/one_step.st")
}

#[tokio::test(flavor = "multi_thread")]
async fn a_second_agent_under_a_taken_name_is_refused_at_start() {
    let mut cluster = Cluster::new();
    let mut coordinator = cluster.coordinator(&chart(), &[]);
    coordinator.wait_for_log("running chart").await;
    cluster.agent("r1", &[], &[]);
    coordinator.wait_for_log("agent `r1` is live").await;
    let second = Command::new(bin("baton-agent"))
        .args(["--connect", &cluster.endpoint, "--name", "r1"])
        .kill_on_drop(true)
        .output();
    let second = tokio::time::timeout(TIMEOUT, second).await.expect("the second agent ended").expect("it ran");
    let stderr = String::from_utf8_lossy(&second.stderr);
    assert!(!second.status.success(), "a second `r1` ran: {stderr}");
    assert!(stderr.contains("an agent named `r1` is already live"), "{stderr}");
    let (status, log, trace, _) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    check_trace_invariants(&trace, &chart());
    assert_eq!(events(&trace, TraceEvent::Dispatch).len(), 1);
}

#[tokio::test(flavor = "multi_thread")]
async fn two_processes_answering_to_one_name_get_nothing_until_one_is_left() {
    let mut cluster = Cluster::new();
    let mut coordinator = cluster.coordinator(&chart(), &[]);
    coordinator.wait_for_log("running chart").await;
    // A process that answers as r1 besides the real one (started at the same moment, both passed the check).
    let session = cluster.watch().await;
    let impostor = session.declare_queryable(keys::agent_info("r1")).await.expect("queryable");
    let info = AgentInfo {
        name: "r1".into(),
        roles: Vec::new(),
        lease_ms: 10_000,
        incarnation: uuid::Uuid::from_u128(0xdead),
        held: Vec::new(),
    };
    let answering = tokio::spawn(async move {
        while let Ok(q) = impostor.recv_async().await {
            let _ = q.reply(q.key_expr().clone(), wire::encode(&info)).await;
        }
    });
    cluster.agent("r1", &[], &[]);
    coordinator.wait_for_log("2 processes answer as agent `r1`").await;
    let so_far = read_trace(&coordinator.trace);
    assert!(
        events(&so_far, TraceEvent::Dispatch).is_empty(),
        "dispatched to a name two processes answer to: {so_far:?}"
    );
    assert!(so_far.iter().any(|r| r.event == TraceEvent::Alarm), "{so_far:?}");
    // The impostor goes: the real r1 answers alone, and gets the token.
    answering.abort();
    let _ = answering.await;
    coordinator.wait_for_log("agent `r1` answers alone again").await;
    let (status, log, trace, _) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    check_trace_invariants(&trace, &chart());
    assert_eq!(events(&trace, TraceEvent::Dispatch).len(), 1);
}
