//! Lost agents with real processes: SIGKILL of the agent holding a token, under each `--on-agent-loss` policy.

use baton_proto::cluster::keys;
use baton_proto::exec::trace::TraceEvent;
use baton_tests::loopback::{
    self, check_trace_invariants, check_trace_invariants_with_tokens_out, dispatches, repo, step_id, Cluster, Samples,
};

/// Starts the one-part cell with two assemblers and waits, on the agents' command keys, for the dispatch of
/// Assemble; returns the cluster, the coordinator and the agent that holds the token.
async fn assembling(policy: &str) -> (Cluster, baton_tests::loopback::Coordinator, String, zenoh::Session) {
    let (cluster, coordinator, holder, session, _) = assembling_with(policy, 1, &[]).await;
    (cluster, coordinator, holder, session)
}

/// `assembling` with more parts and extra agent arguments; also returns the command subscriber, still
/// listening.
async fn assembling_with(
    policy: &str,
    parts: u32,
    agent_args: &[&str],
) -> (Cluster, baton_tests::loopback::Coordinator, String, zenoh::Session, Commands) {
    let mut cluster = Cluster::new();
    let parts = format!("parts={parts}");
    let mut coordinator = cluster.coordinator(&repo("examples/cell.st"), &["--set", &parts, "--on-agent-loss", policy]);
    coordinator.wait_ready().await;
    let session = cluster.watch().await;
    let cmds = session.declare_subscriber(keys::agent_cmd_any("*")).await.expect("subscriber");
    cluster.agent("robot1", &["assembler"], agent_args);
    cluster.agent("robot2", &["assembler"], agent_args);
    let holder = next_dispatch(&cmds, "Assemble", 1).await;
    (cluster, coordinator, holder, session, cmds)
}

type Commands = Samples;

/// Waits for the dispatch of the cell's `step` in `epoch`; returns the agent it went to.
async fn next_dispatch(cmds: &Commands, step: &str, epoch: u32) -> String {
    loopback::next_dispatch(cmds, step_id(&repo("examples/cell.st"), step), epoch).await.0
}

fn other(agent: &str) -> &'static str {
    if agent == "robot1" {
        "robot2"
    } else {
        "robot1"
    }
}

#[tokio::test(flavor = "multi_thread")]
async fn reassign_moves_a_killed_agents_segment_to_another_agent() {
    let (mut cluster, coordinator, holder, _session) = assembling("reassign").await;
    cluster.kill_agent(&holder).await;
    let (status, log, trace, summary) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    check_trace_invariants(&trace, &repo("examples/cell.st"));
    assert_eq!(summary["vars"]["done"], "1");
    assert_eq!(dispatches(&trace, "Assemble"), [(holder.clone(), Some(1)), (other(&holder).to_string(), Some(2))]);
    assert!(trace.iter().any(|r| r.event == TraceEvent::AgentLost && r.name == holder));
    assert!(trace.iter().any(|r| r.event == TraceEvent::Alarm));
}

#[tokio::test(flavor = "multi_thread")]
async fn pause_holds_the_segment_until_the_killed_agent_is_back() {
    let (mut cluster, coordinator, holder, _session) = assembling("pause").await;
    cluster.kill_agent(&holder).await;
    cluster.agent(&holder, &["assembler"], &[]);
    let (status, log, trace, summary) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    check_trace_invariants(&trace, &repo("examples/cell.st"));
    assert_eq!(summary["vars"]["done"], "1");
    // Nothing moved to the other robot; the restarted process runs the segment again in a new epoch.
    assert_eq!(dispatches(&trace, "Assemble"), [(holder.clone(), Some(1)), (holder.clone(), Some(2))]);
    let lost = trace.iter().position(|r| r.event == TraceEvent::AgentLost).expect("lost");
    let back = trace.iter().rposition(|r| r.event == TraceEvent::AgentUp && r.name == holder).expect("back");
    assert!(lost < back, "the holder came back after it was lost");
    assert!(log.contains("came back restarted"), "{log}");
}

#[tokio::test(flavor = "multi_thread")]
async fn fail_ends_the_run_with_an_error_that_says_why() {
    let (mut cluster, coordinator, holder, _session) = assembling("fail").await;
    cluster.kill_agent(&holder).await;
    let (status, log, trace, _) = coordinator.finish().await;
    assert_eq!(status.code(), Some(2), "{log}");
    assert!(
        log.contains(&format!("the run failed: agent `{holder}` was lost holding the token of step `Assemble`")),
        "{log}"
    );
    assert!(trace.iter().any(|r| r.event == TraceEvent::AgentLost));
    // Every token is back but the one the failure names.
    check_trace_invariants_with_tokens_out(&trace, &repo("examples/cell.st"), 1);
}

#[tokio::test(flavor = "multi_thread")]
async fn a_stopped_agents_late_result_is_rejected_after_a_reassign() {
    // A lease of 1 s: SIGSTOP makes the agent silent, and the router declares it lost when the lease runs out.
    let (cluster, coordinator, holder, _session, cmds) = assembling_with("reassign", 2, &["--lease-ms", "1000"]).await;
    cluster.signal_agent(&holder, "STOP");
    // Wait for the reassignment (epoch 2) on the command keys, then wake the old holder up.
    next_dispatch(&cmds, "Assemble", 2).await;
    cluster.signal_agent(&holder, "CONT");
    let (status, log, trace, summary) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    check_trace_invariants(&trace, &repo("examples/cell.st"));
    assert_eq!(summary["vars"]["done"], "2");
    // Woken up, the old holder still has epoch 1: it is told to drop it — when its late result comes in
    // (`reject_stale`), or as soon as it announces itself holding it, whichever reaches the coordinator first.
    let stale: Vec<_> = trace.iter().filter(|r| r.event == TraceEvent::RejectStale).collect();
    assert!(stale.iter().all(|r| r.agent.as_deref() == Some(holder.as_str()) && r.epoch == Some(1)));
    let mut told_to_drop = false;
    while let Ok(Some(sample)) = cmds.try_recv() {
        let to_holder = sample.key_expr().as_str().split('/').nth(2) == Some(holder.as_str());
        if let Ok(baton_proto::cluster::wire::ToAgent::Drop { epoch: 1, .. }) =
            baton_proto::cluster::wire::decode(&sample.payload().to_bytes())
        {
            told_to_drop |= to_holder;
        }
    }
    assert!(told_to_drop, "the stopped agent was told to drop its epoch-1 token:\n{log}");
    let first_assembly =
        trace.iter().find(|r| r.event == TraceEvent::Return && r.name == "Assemble").expect("returned");
    assert_eq!((first_assembly.agent.as_deref(), first_assembly.epoch), (Some(other(&holder)), Some(2)));
}
