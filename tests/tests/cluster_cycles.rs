//! The scan cycle on real processes: a distributed run computes what `baton sim` computes, whatever the traffic
//! between the coordinator and its agents, and an idle run with a journal writes (almost) nothing.

use baton_tests::loopback::{check_trace_invariants, repo, Cluster, TIMEOUT};
use baton_tests::reference::final_values;

fn chart(name: &str) -> std::path::PathBuf {
    repo(&format!("tests/charts/{name}"))
}

#[tokio::test(flavor = "multi_thread")]
async fn a_counter_on_an_agent_counts_what_baton_sim_counts() {
    let path = chart("counter.st");
    let expected = final_values(&std::fs::read_to_string(&path).expect("chart"), 10, &["n", "m"]);
    assert!(expected[0] > 100 && expected[1] > 10, "the counters counted: {expected:?}");
    let mut cluster = Cluster::new();
    cluster.agent("r1", &[], &[]);
    let coordinator = cluster.coordinator(&path, &["--cycle-ms", "10"]);
    let (status, log, trace, summary) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    check_trace_invariants(&trace, &path);
    // Every change of n is a report and every report an acknowledgement: none of them may make a cycle.
    let got: Vec<i64> =
        ["n", "m"].iter().map(|v| summary["vars"][v].as_str().and_then(|s| s.parse().ok()).unwrap_or(-1)).collect();
    assert_eq!(got, expected, "n counted on agent r1, m on the coordinator; log:\n{log}");
}

#[tokio::test(flavor = "multi_thread")]
async fn an_idle_run_with_a_journal_commits_only_what_changed() {
    let path = chart("idle.st");
    let cluster = Cluster::new();
    let journal = cluster.dir.path().join("journal");
    let journal_arg = journal.to_str().expect("utf-8 path").to_string();
    let mut coordinator = cluster.coordinator(&path, &["--journal", &journal_arg, "--cycle-ms", "10"]);
    coordinator.wait_ready().await;
    let ep = cluster.endpoint.clone();
    // A second of waiting for the input, measured on the run's own clock: 100 cycles at 10 ms.
    let waited = tokio::time::timeout(TIMEOUT, async {
        loop {
            let out = cluster.baton(&["status", "--connect", &ep, "--json"]).await;
            let text = String::from_utf8_lossy(&out.stdout);
            let status: serde_json::Value =
                text.lines().next().and_then(|l| serde_json::from_str(l).ok()).unwrap_or_default();
            let t_ms = status["t_ms"].as_u64().unwrap_or(0);
            if t_ms >= 1_000 {
                return t_ms;
            }
        }
    })
    .await
    .expect("the run's clock passed 1 s");
    let set = cluster.baton(&["set", "--connect", &ep, "go=true"]).await;
    assert!(set.status.success(), "{}", String::from_utf8_lossy(&set.stderr));
    let (status, log, trace, summary) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    check_trace_invariants(&trace, &path);
    // Idle for over a second, then a step timed for a second: about 200 cycles, of which only those that changed
    // something (the first, the one after the input, the one that left Hold) are records of their own.
    let commits = summary["journal"]["commits"].as_u64().expect("journal stats");
    let records = summary["journal"]["records"].as_u64().expect("journal stats");
    eprintln!("idle for {waited} ms, then 1 s in Hold: {records} records in {commits} commits");
    assert!(records <= 12, "{records} journal records for an idle run ({commits} commits); log:\n{log}");
    assert!(commits <= records);
}
