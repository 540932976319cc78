//! A cell across a mesh of three real routers (`zenohd` 1.10.2, which `.ci/run` installs in the machine's cache of tools):
//! the coordinator on the first, each robot on another. One robot's router is killed mid-run and started again: the
//! robot reconnects, its token resumes, and the run makes every part with nothing lost and nothing run twice. After
//! such a restart zenoh 1.10.2 may stop routing the robot's puts to the coordinator's router while it still carries
//! queries (`tests/scripts/zenoh_router_restart.py` shows it without Baton): the robot's reports then reach the
//! coordinator in the answers to its questions about quiet tokens (`CoordOutput::Ask`).

use std::path::Path;
use std::time::Duration;

use baton_proto::exec::trace::TraceEvent;
use baton_tests::loopback::{check_trace_invariants, free_port, start_zenohd, zenohd, Cluster, TIMEOUT};
use tokio::process::Child;

baton_tests::harness_main!(tokio a_run_across_three_routers_survives_one_of_them_restarting);

const PARTS: usize = 5;

/// Router `i` of the mesh: listens on its port and connects to the others; started, and ready once it accepts
/// connections.
async fn router(dir: &Path, ports: &[u16], i: usize) -> Child {
    // Each router connects to those before it: every pair linked once, from one side (routers that both dial each
    // other leave zenoh 1.10 with duplicate links to settle after a restart, and it then lost routes now and then).
    let others: Vec<String> = ports[..i].iter().map(|p| format!("\"tcp/127.0.0.1:{p}\"")).collect();
    let config = dir.join(format!("router{i}.json5"));
    std::fs::write(
        &config,
        format!(
            "{{ mode: \"router\", listen: {{ endpoints: [\"tcp/127.0.0.1:{}\"] }}, connect: {{ endpoints: [{}] }}, \
             scouting: {{ multicast: {{ enabled: false }} }} }}",
            ports[i],
            others.join(", ")
        ),
    )
    .expect("write the router's configuration");
    start_zenohd(&config, ports[i], &dir.join(format!("router{i}.log"))).await
}

fn marks(dir: &Path) -> Vec<String> {
    std::fs::read_to_string(dir.join("marks")).unwrap_or_default().lines().map(str::to_string).collect()
}

async fn a_run_across_three_routers_survives_one_of_them_restarting() {
    // Ignored (failing under CI) without zenohd, before anything starts.
    zenohd();
    let mut cluster = Cluster::new();
    let dir = cluster.dir.path().to_path_buf();
    let ports = [free_port(), free_port(), free_port()];
    let mut routers = Vec::new();
    for i in 0..3 {
        routers.push(Some(router(&dir, &ports, i).await));
    }
    let m = dir.join("marks");
    let m = m.display();
    let chart = dir.join("mesh.st");
    std::fs::write(
        &chart,
        format!(
            "PROGRAM mesh\nVAR n : INT; a, b : BOOL; END_VAR\nINITIAL_STEP Idle: END_STEP\n\
             TRANSITION FROM Idle TO (A, B) := n < {PARTS}; END_TRANSITION\n\
             TRANSITION FROM Idle TO Done := n >= {PARTS}; END_TRANSITION\n\
             STEP A: {{agent := 'r1'}} MoveA(N, a); END_STEP\nTRANSITION FROM A TO AW := a; END_TRANSITION\n\
             STEP AW: END_STEP\nSTEP B: {{agent := 'r2'}} MoveB(N, b); END_STEP\n\
             TRANSITION FROM B TO BW := b; END_TRANSITION\nSTEP BW: END_STEP\n\
             TRANSITION FROM (AW, BW) TO Count := TRUE; END_TRANSITION\nSTEP Count: Inc(P1); END_STEP\n\
             TRANSITION FROM Count TO Idle := TRUE; END_TRANSITION\nSTEP Done: END_STEP\n\
             ACTION MoveA: {{skill := 'shell', cmd := 'echo start A >> {m}; sleep 0.3; echo end A >> {m}'}} END_ACTION\n\
             ACTION MoveB: {{skill := 'shell', cmd := 'echo start B >> {m}; sleep 0.2; echo end B >> {m}'}} END_ACTION\n\
             ACTION Inc: IF Inc.Q THEN n := n + 1; END_IF; END_ACTION\nEND_PROGRAM\n"
        ),
    )
    .expect("write the chart");
    cluster.endpoint = format!("tcp/127.0.0.1:{}", ports[0]);
    let mut coordinator = cluster.coordinator_connecting(&chart, &["--watch", "n"]);
    coordinator.wait_ready().await;
    let fallback = format!("tcp/127.0.0.1:{}", ports[2]);
    let mut r1_args = vec!["--allow-shell", "--lease-ms", "1000", "--verbose"];
    if std::env::var_os("MESH_FALLBACK").is_some() {
        r1_args.extend(["--connect", fallback.as_str()]);
    }
    cluster.agent_at(&format!("tcp/127.0.0.1:{}", ports[1]), "r1", &[], &r1_args);
    cluster.agent_at(&format!("tcp/127.0.0.1:{}", ports[2]), "r2", &[], &["--allow-shell"]);
    // r1's router dies in the second part, and comes back.
    let second = tokio::time::timeout(TIMEOUT, async {
        while marks(&dir).iter().filter(|l| *l == "start A").count() < 2 {
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    })
    .await;
    assert!(second.is_ok(), "the second part never started: {:?}", marks(&dir));
    let mut dying = routers[1].take().expect("router 1");
    dying.start_kill().expect("kill router 1");
    dying.wait().await.expect("router 1 gone");
    routers[1] = Some(router(&dir, &ports, 1).await);
    let trace_path = coordinator.trace.clone();
    let ended = tokio::time::timeout(Duration::from_secs(20), async {
        while coordinator.child.try_wait().ok().flatten().is_none() {
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    })
    .await;
    if ended.is_err() {
        let t = baton_tests::loopback::read_trace(&trace_path);
        let tail: Vec<String> = t[t.len().saturating_sub(12)..]
            .iter()
            .map(|r| format!("{} {} {} {:?}", r.t_ms, r.event, r.name, r.agent))
            .collect();
        panic!(
            "the run did not end; its trace ends {tail:#?}; marks {:?}; the coordinator logged:\n{}\nr1 logged:\n{}\nr2 logged:\n{}",
            marks(&dir),
            coordinator.unread_log().await,
            cluster.agent_log("r1"),
            cluster.agent_log("r2"),
        )
    }
    let (status, log, trace, summary) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    check_trace_invariants(&trace, &chart);
    assert_eq!(summary["vars"]["n"], PARTS.to_string(), "{summary}");
    let marks = marks(&dir);
    for l in ["start A", "end A", "start B", "end B"] {
        assert_eq!(marks.iter().filter(|x| *x == l).count(), PARTS, "`{l}` in {marks:?}");
    }
    // The robot behind the restarted router came back: within its grace (`limits::loss_grace_ms`, never lost), or
    // lost and then up again.
    if let Some(lost) = trace.iter().position(|r| r.event == TraceEvent::AgentLost && r.name == "r1") {
        assert!(trace[lost..].iter().any(|r| r.event == TraceEvent::AgentUp && r.name == "r1"), "{trace:#?}");
    }
}
