//! A partition made by a real network: one agent in a network namespace of its own, joined by a veth pair,
//! and the cable cut while it holds a token. Needs root (CI runs as root); elsewhere the test says why it skips.

use baton_proto::keys;
use baton_tests::cluster::{self, check_trace_invariants, dispatches, free_port, repo, step_id, Cluster};
use baton_tests::netns::Netns;

/// Under the default policy (pause), the coordinator sees the cut-off agent lost when its lease runs out and
/// holds its token; when the cable is back, the same process reconnects, says it still holds the token, and
/// its result comes in. Nothing runs twice and nothing moves to another agent.
#[tokio::test(flavor = "multi_thread")]
async fn a_partitioned_agent_is_paused_and_resumes_when_the_link_is_back() {
    let netns = match Netns::new("p") {
        Ok(n) => n,
        Err(why) => {
            eprintln!("SKIPPED a_partitioned_agent_is_paused_and_resumes_when_the_link_is_back: cannot make a network namespace and a veth pair here (needs root and iproute2): {why}");
            return;
        }
    };
    let cell = repo("examples/cell.st");
    let mut cluster = Cluster::new();
    // The coordinator listens on loopback (robot2 and the test) and on the host's end of the veth (robot1).
    let far = format!("tcp/{}:{}", netns.host_addr, free_port());
    let mut coordinator = cluster.coordinator(&cell, &["--set", "parts=1", "--listen", &far]);
    coordinator.wait_for_log("running chart").await;
    let watch = cluster.watch().await;
    let cmds = watch.declare_subscriber(keys::agent_cmd_any("*")).await.expect("command subscriber");
    // robot1 alone assembles, so the token of Assemble goes to the agent behind the cable.
    cluster.agent_in(&netns, &far, "robot1", &["assembler"], &["--lease-ms", "1000"]);
    cluster.agent("robot2", &[], &[]);
    let Some((holder, _)) = cluster::next_dispatch_within(&cmds, step_id(&cell, "Assemble"), 1).await else {
        panic!(
            "Assemble was not dispatched in time; the coordinator logged:\n{}\nrobot1:\n{}\nrobot2:\n{}",
            coordinator.unread_log().await,
            cluster.agent_log("robot1"),
            cluster.agent_log("robot2")
        );
    };
    assert_eq!(holder, "robot1");
    netns.cut();
    coordinator.wait_for_log("agent `robot1` lost holding the token of step `Assemble`").await;
    netns.heal();
    let (status, log, trace, summary) = coordinator.finish().await;
    assert!(status.success(), "{log}\nrobot1:\n{}", cluster.agent_log("robot1"));
    check_trace_invariants(&trace, &cell);
    assert_eq!(summary["vars"]["done"], "1");
    assert_eq!(dispatches(&trace, "Assemble"), [("robot1".to_string(), Some(1))], "sent once, never moved");
    let lost = trace.iter().position(|r| r.event == "agent_lost" && r.name == "robot1").expect("lost");
    let resume = trace.iter().position(|r| r.event == "resume" && r.name == "Assemble").expect("resumed");
    let back = trace.iter().position(|r| r.event == "return" && r.name == "Assemble").expect("returned");
    assert!(lost < resume && resume < back, "lost, resumed, then the result");
    assert_eq!(trace[resume].message.as_deref(), Some("still held by the agent"));
    let motions = trace.iter().filter(|r| r.event == "action_on" && r.name == "AssemblePart").count();
    assert_eq!(motions, 1, "the assembly motion ran once");
}
