//! A partition made by a real network: one agent in a network namespace of its own, joined by a veth pair,
//! and the cable cut while it holds a token. Needs root (CI runs as root); elsewhere the test says why it skips.

use std::time::{SystemTime, UNIX_EPOCH};

use baton_proto::cluster::keys;
use baton_proto::exec::trace::{TraceEvent, TraceRecord};
use baton_tests::loopback::{self, check_trace_invariants, dispatches, free_port, repo, step_id, Cluster};
use baton_tests::netns::Netns;

/// A network namespace; where none can be made (not root, no iproute2) the test is ignored with the reason —
/// except under CI (`CI` set), where a test that cannot run fails.
fn netns_or_skip(tag: &str, test: &str) -> Netns {
    match Netns::new(tag) {
        Ok(n) => n,
        Err(why) => baton_tests::missing(&format!(
            "{test}: cannot make a network namespace and a veth pair here (needs root and iproute2): {why}"
        )),
    }
}

/// A cluster whose coordinator listens on loopback and on the host's end of the veth, for `chart` run with
/// `extra`, robot1 started behind the cable with a 1 s lease and `roles`, and the test watching the commands.
async fn behind_a_cable(
    netns: &Netns,
    chart: &std::path::Path,
    extra: &[&str],
    roles: &[&str],
) -> (Cluster, loopback::Coordinator, zenoh::Session, loopback::Samples) {
    let mut cluster = Cluster::new();
    let far = format!("tcp/{}:{}", netns.host_addr, free_port());
    let mut args = extra.to_vec();
    args.extend(["--listen", &far]);
    let mut coordinator = cluster.coordinator(chart, &args);
    coordinator.wait_ready().await;
    let watch = cluster.watch().await;
    let cmds = watch.declare_subscriber(keys::agent_cmd_any("*")).await.expect("command subscriber");
    cluster.agent_in(netns, &far, "robot1", roles, &["--lease-ms", "1000"]);
    (cluster, coordinator, watch, cmds)
}

fn unix_ms() -> u128 {
    SystemTime::now().duration_since(UNIX_EPOCH).map_or(0, |d| d.as_millis())
}

/// Under `reassign`, the lease is a fence on both sides: the cut-off agent stops its skill before the coordinator
/// gives the token to another agent, so the two never move at once. When the cable is back, the cut-off agent's
/// stale result is rejected and it is told to drop the token.
async fn a_cut_off_agent_stops_before_its_token_moves_under_reassign() {
    let netns = netns_or_skip("f", "a_cut_off_agent_stops_before_its_token_moves_under_reassign");
    let chart = repo("tests/charts/long_motion.st");
    // robot1 alone first, behind the cable, so that the token goes to it.
    let (mut cluster, mut coordinator, _watch, cmds) =
        behind_a_cable(&netns, &chart, &["--on-agent-loss", "reassign"], &["worker"]).await;
    let work = step_id(&chart, "Work");
    let Some((holder, _)) = loopback::next_dispatch_within(&cmds, work, 1).await else {
        panic!("Work was not dispatched; the coordinator logged:\n{}", coordinator.unread_log().await);
    };
    assert_eq!(holder, "robot1");
    cluster.agent("robot2", &["worker"], &[]);
    coordinator.wait_for_trace("robot2 live", |r| r.event == TraceEvent::AgentUp && r.name == "robot2").await;
    netns.cut();
    let cut_ms = unix_ms();
    let Some((moved_to, _)) = loopback::next_dispatch_within(&cmds, work, 2).await else {
        panic!("Work was not reassigned; the coordinator logged:\n{}", coordinator.unread_log().await);
    };
    let reassigned_ms = unix_ms();
    assert_eq!(moved_to, "robot2");
    // robot1's trace says when it fenced itself, on its own clock (the same machine's, in Unix time): it cancelled
    // its motion, having lost the router.
    let fenced = |r: &TraceRecord| r.event == TraceEvent::SkillCancel && r.name == "Motion";
    let trace = cluster.wait_for_agent_trace("robot1", "its motion cancelled", fenced).await;
    let fence = trace.iter().find(|r| fenced(r)).expect("found");
    let lost = trace.iter().position(|r| r.event == TraceEvent::ContactLost);
    assert!(lost.is_some_and(|i| trace[i].t_ms <= fence.t_ms), "cancelled before it lost the router: {trace:#?}");
    let fenced_ms = u128::from(fence.t_ms);
    eprintln!("cut → robot1 stopped: {} ms; cut → token moved: {} ms", fenced_ms - cut_ms, reassigned_ms - cut_ms);
    assert!(
        cut_ms <= fenced_ms && fenced_ms < reassigned_ms,
        "cut at {cut_ms}, robot1 stopped at {fenced_ms}, the token moved at {reassigned_ms} (unix ms)"
    );
    netns.heal();
    let (status, log, trace, summary) = coordinator.finish().await;
    assert!(status.success(), "{log}\nrobot1:\n{}", cluster.agent_log("robot1"));
    check_trace_invariants(&trace, &chart);
    assert_eq!(summary["vars"]["moved"], "TRUE");
    assert_eq!(dispatches(&trace, "Work"), [("robot1".to_string(), Some(1)), ("robot2".to_string(), Some(2))]);
    let done: Vec<_> = trace.iter().filter(|r| r.event == TraceEvent::SkillDone).map(|r| r.agent.clone()).collect();
    assert_eq!(done, [Some("robot2".to_string())], "only robot2's motion finished");
}

/// Under the default policy (pause), the coordinator sees the cut-off agent lost when its lease runs out and
/// holds its token; when the cable is back, the same process reconnects, says it still holds the token, and
/// its result comes in. Nothing runs twice and nothing moves to another agent.
async fn a_partitioned_agent_is_paused_and_resumes_when_the_link_is_back() {
    let netns = netns_or_skip("p", "a_partitioned_agent_is_paused_and_resumes_when_the_link_is_back");
    let cell = repo("examples/cell.st");
    // robot1 alone assembles, so the token of Assemble goes to the agent behind the cable.
    let (mut cluster, mut coordinator, _watch, cmds) =
        behind_a_cable(&netns, &cell, &["--set", "parts=1"], &["assembler"]).await;
    cluster.agent("robot2", &[], &[]);
    let Some((holder, _)) = loopback::next_dispatch_within(&cmds, step_id(&cell, "Assemble"), 1).await else {
        panic!(
            "Assemble was not dispatched in time; the coordinator logged:\n{}\nrobot1:\n{}\nrobot2:\n{}",
            coordinator.unread_log().await,
            cluster.agent_log("robot1"),
            cluster.agent_log("robot2")
        );
    };
    assert_eq!(holder, "robot1");
    netns.cut();
    coordinator.wait_for_trace("robot1 lost", |r| r.event == TraceEvent::AgentLost && r.name == "robot1").await;
    netns.heal();
    let (status, log, trace, summary) = coordinator.finish().await;
    assert!(status.success(), "{log}\nrobot1:\n{}", cluster.agent_log("robot1"));
    check_trace_invariants(&trace, &cell);
    assert_eq!(summary["vars"]["done"], "1");
    assert_eq!(dispatches(&trace, "Assemble"), [("robot1".to_string(), Some(1))], "sent once, never moved");
    let lost = trace.iter().position(|r| r.event == TraceEvent::AgentLost && r.name == "robot1").expect("lost");
    let resume = trace.iter().position(|r| r.event == TraceEvent::Resume && r.name == "Assemble").expect("resumed");
    let back = trace.iter().position(|r| r.event == TraceEvent::Return && r.name == "Assemble").expect("returned");
    assert!(lost < resume && resume < back, "lost, resumed, then the result");
    assert_eq!(trace[resume].message.as_deref(), Some("still held by the agent"));
    let motions = trace.iter().filter(|r| r.event == TraceEvent::ActionOn && r.name == "AssemblePart").count();
    assert_eq!(motions, 1, "the assembly motion ran once");
}

baton_tests::harness_main!(
    tokio a_cut_off_agent_stops_before_its_token_moves_under_reassign,
    tokio a_partitioned_agent_is_paused_and_resumes_when_the_link_is_back,
);
