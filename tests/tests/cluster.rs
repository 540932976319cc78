//! Loopback cluster tests: real `baton run` and `baton-agent` processes over Zenoh on 127.0.0.1.

use std::time::Duration;

use baton_proto::cluster::keys;
use baton_proto::cluster::netconfig::NetConfig;
use baton_proto::cluster::wire::{self, ChartHash, RunId, ToAgent, TokenId};
use baton_proto::exec::trace::TraceEvent;
use baton_tests::loopback::{check_trace_invariants, cmd_key_of, events, repo, status_of, Cluster, TIMEOUT};
use zenoh::sample::Locality;

fn chart(name: &str) -> std::path::PathBuf {
    repo(&format!("tests/charts/{name}"))
}

fn var(summary: &serde_json::Value, name: &str) -> String {
    summary["vars"][name].as_str().unwrap_or("<missing>").to_string()
}

async fn client(endpoint: &str) -> zenoh::Session {
    let net = NetConfig::client(&[endpoint.to_string()], false);
    let config = zenoh::Config::from_json5(&net.json5()).expect("config");
    zenoh::open(config).await.expect("test session")
}

#[tokio::test(flavor = "multi_thread")]
async fn three_parallel_branches_converge_only_after_the_slowest() {
    let mut cluster = Cluster::new();
    for name in ["r1", "r2", "r3"] {
        cluster.agent(name, &[], &[]);
    }
    let coordinator = cluster.coordinator(&chart("three_branches.st"), &[]);
    let (status, log, trace, _) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    check_trace_invariants(&trace, &chart("three_branches.st"));
    let dispatched: Vec<(String, String)> =
        events(&trace, TraceEvent::Dispatch).into_iter().map(|(_, n, a)| (n, a.unwrap_or_default())).collect();
    assert_eq!(dispatched.len(), 3);
    for (step, agent) in [("A", "r1"), ("B", "r2"), ("C", "r3")] {
        assert!(dispatched.contains(&(step.to_string(), agent.to_string())), "{step} on {agent}: {dispatched:?}");
    }
    // The convergence clears after every return, the last of which is B's (300 ms of motion on r2).
    let fire =
        trace.iter().position(|r| r.event == TraceEvent::Fire && r.name == "(WaitA,WaitB,WaitC)->Done").expect("fired");
    let returns: Vec<usize> =
        trace.iter().enumerate().filter(|(_, r)| r.event == TraceEvent::Return).map(|(i, _)| i).collect();
    assert_eq!(returns.len(), 3);
    assert!(returns.iter().all(|&i| i < fire), "the convergence cleared before every branch returned");
    let last = &trace[*returns.last().expect("returns")];
    assert_eq!((last.name.as_str(), last.agent.as_deref()), ("B", Some("r2")));
    // Step events of steps that ran on agents say where.
    let b_fire = trace.iter().find(|r| r.event == TraceEvent::Fire && r.name == "B->WaitB").expect("B cleared");
    assert_eq!(b_fire.agent.as_deref(), Some("r2"));
    assert!(trace
        .iter()
        .any(|r| r.event == TraceEvent::ActionOn && r.name == "MoveB" && r.agent.as_deref() == Some("r2")));
    // Each agent's own trace (`baton-agent --trace`) says it came up, then started and finished the skill the
    // coordinator's trace says finished there — before it handed the token back, so it is written by now — on the
    // machine's clock.
    let run_began = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).expect("clock").as_millis();
    for agent in ["r1", "r2", "r3"] {
        let done: Vec<&str> = trace
            .iter()
            .filter(|r| r.event == TraceEvent::SkillDone && r.agent.as_deref() == Some(agent))
            .map(|r| r.name.as_str())
            .collect();
        assert_eq!(done.len(), 1, "{agent}: {done:?}");
        let own = cluster.agent_trace(agent);
        let said: Vec<(TraceEvent, &str)> = own.iter().map(|r| (r.event, r.name.as_str())).collect();
        let expected =
            [(TraceEvent::AgentUp, agent), (TraceEvent::SkillStart, done[0]), (TraceEvent::SkillDone, done[0])];
        assert_eq!(said, expected, "{agent}: {own:#?}");
        assert!(own.iter().all(|r| r.agent.as_deref() == Some(agent)), "{own:#?}");
        let times: Vec<u64> = own.iter().map(|r| r.t_ms).collect();
        assert!(times.windows(2).all(|w| w[0] <= w[1]), "{agent}: {times:?}");
        assert!(times.iter().all(|&t| u128::from(t) + 60_000 > run_began && u128::from(t) <= run_began), "{times:?}");
    }
}

#[tokio::test(flavor = "multi_thread")]
async fn a_selection_inside_a_segment_follows_an_input_set_at_run_time() {
    let mut cluster = Cluster::new();
    cluster.agent("r1", &[], &[]);
    let mut coordinator = cluster.coordinator(&chart("selection_segment.st"), &[]);
    coordinator.wait_ready().await;
    let ep = cluster.endpoint.clone();

    let status = cluster.baton(&["status", "--connect", &ep]).await;
    let text = String::from_utf8_lossy(&status.stdout);
    assert!(status.status.success(), "{}", String::from_utf8_lossy(&status.stderr));
    assert!(text.contains("chart `selection_segment`") && text.contains("Ready (the coordinator)"), "{text}");

    let refused = cluster.baton(&["set", "--connect", &ep, "a_count=5"]).await;
    assert_eq!(refused.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&refused.stderr).contains("the chart writes it on agent `r1`"));
    let unknown = cluster.baton(&["set", "--connect", &ep, "nosuch=1"]).await;
    assert_eq!(unknown.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&unknown.stderr).contains("has no variable `nosuch`"));
    let wrong_type = cluster.baton(&["set", "--connect", &ep, "mode=true"]).await;
    assert_eq!(wrong_type.status.code(), Some(1));

    for assignment in ["mode=2", "go=true"] {
        let set = cluster.baton(&["set", "--connect", &ep, assignment]).await;
        assert!(set.status.success(), "{assignment}: {}", String::from_utf8_lossy(&set.stderr));
    }
    let (status, log, trace, summary) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    check_trace_invariants(&trace, &chart("selection_segment.st"));
    let activated: Vec<String> = events(&trace, TraceEvent::Activate).into_iter().map(|e| e.1).collect();
    assert!(activated.contains(&"B".to_string()) && !activated.contains(&"A".to_string()), "{activated:?}");
    let b = trace.iter().find(|r| r.event == TraceEvent::Activate && r.name == "B").expect("B");
    assert_eq!(b.agent.as_deref(), Some("r1"), "B ran on r1");
    assert_eq!(events(&trace, TraceEvent::Dispatch).len(), 1, "one token for the whole segment");
    assert_eq!((var(&summary, "b_count"), var(&summary, "a_count")), ("1".into(), "0".into()));
}

#[tokio::test(flavor = "multi_thread")]
async fn a_role_served_by_two_agents_shares_the_work() {
    let mut cluster = Cluster::new();
    cluster.agent("robot1", &["assembler"], &[]);
    cluster.agent("robot2", &["assembler"], &[]);
    let coordinator = cluster.coordinator(&repo("examples/cell.st"), &["--set", "parts=4"]);
    let (status, log, trace, summary) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    check_trace_invariants(&trace, &repo("examples/cell.st"));
    assert_eq!(var(&summary, "done"), "4");
    let assemblers: std::collections::BTreeSet<String> =
        events(&trace, TraceEvent::Dispatch).into_iter().filter(|d| d.1 == "Assemble").filter_map(|d| d.2).collect();
    assert_eq!(assemblers.into_iter().collect::<Vec<_>>(), ["robot1", "robot2"]);
}

#[tokio::test(flavor = "multi_thread")]
async fn skill_indicators_drive_transitions() {
    let mut cluster = Cluster::new();
    cluster.agent("r1", &[], &["--allow-shell"]);
    let coordinator = cluster.coordinator(&chart("shell_skill.st"), &[]);
    let (status, log, trace, summary) = coordinator.finish().await;
    assert!(status.success(), "{log}\n{}", cluster.agent_log("r1"));
    let activated: Vec<String> = events(&trace, TraceEvent::Activate).into_iter().map(|e| e.1).collect();
    assert!(activated.contains(&"Handled".to_string()), "{activated:?}");
    assert!(!activated.contains(&"Wrong".to_string()));
    let done = trace.iter().find(|r| r.event == TraceEvent::SkillDone).expect("RunTrue succeeded");
    assert_eq!(done.name, "RunTrue");
    let fault = trace.iter().find(|r| r.event == TraceEvent::SkillFault).expect("RunFalse failed");
    assert_eq!(fault.name, "RunFalse");
    assert!(fault.message.as_deref().unwrap_or_default().contains("exit status: 3"), "{fault:?}");
    assert_eq!((var(&summary, "ok_done"), var(&summary, "bad_fault")), ("TRUE".into(), "TRUE".into()));
}

#[tokio::test(flavor = "multi_thread")]
async fn tokens_wait_for_agents_that_start_later() {
    let mut cluster = Cluster::new();
    let mut coordinator = cluster.coordinator(&chart("three_branches.st"), &[]);
    coordinator.wait_for_trace("a token waiting for an agent", |r| r.event == TraceEvent::Wait).await;
    for name in ["r1", "r2", "r3"] {
        cluster.agent(name, &[], &[]);
    }
    let (status, log, trace, _) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    check_trace_invariants(&trace, &chart("three_branches.st"));
    assert_eq!(events(&trace, TraceEvent::Wait).len(), 3);
    assert_eq!(events(&trace, TraceEvent::Return).len(), 3);
}

/// Republishes every message on Baton's keys, duplicated and in swapped pairs, so that each process sees
/// every message twice and some of them out of order.
async fn echo_chaos(
    session: zenoh::Session,
    sub: zenoh::pubsub::Subscriber<zenoh::handlers::FifoChannelHandler<zenoh::sample::Sample>>,
) {
    let mut held: Option<zenoh::sample::Sample> = None;
    while let Ok(sample) = sub.recv_async().await {
        let key = sample.key_expr().as_str().to_string();
        if !(key.contains("/report/") || key.ends_with("/cmd") || key.contains("/vars/")) {
            continue;
        }
        match held.take() {
            None => held = Some(sample),
            Some(first) => {
                for s in [&sample, &first] {
                    let put = session
                        .put(s.key_expr().clone(), s.payload().clone())
                        .allowed_destination(Locality::Remote)
                        .congestion_control(zenoh::qos::CongestionControl::Block);
                    let _ = put.await;
                }
            }
        }
    }
}

#[tokio::test(flavor = "multi_thread")]
async fn duplicated_and_reordered_messages_change_nothing() {
    let mut cluster = Cluster::new();
    let mut coordinator = cluster.coordinator(&repo("examples/cell.st"), &["--set", "parts=3"]);
    coordinator.wait_ready().await;
    let session = client(&cluster.endpoint).await;
    // Declared before any agent exists, so that it sees every message of the run.
    let sub = session.declare_subscriber(keys::everything()).await.expect("chaos subscriber");
    let chaos = tokio::spawn(echo_chaos(session.clone(), sub));
    cluster.agent("robot1", &["assembler"], &[]);
    cluster.agent("robot2", &["assembler"], &[]);
    let (status, log, trace, summary) = coordinator.finish().await;
    chaos.abort();
    assert!(status.success(), "{log}");
    check_trace_invariants(&trace, &repo("examples/cell.st"));
    assert_eq!(var(&summary, "done"), "3");
    assert_eq!(events(&trace, TraceEvent::Dispatch).len(), 9);
    let dropped = summary["messages_dropped"].as_u64().unwrap_or(0);
    assert!(dropped > 0, "the duplicates reached the coordinator and were dropped: {summary}");
}

#[tokio::test(flavor = "multi_thread")]
async fn garbage_on_batons_keys_changes_nothing() {
    let mut cluster = Cluster::new();
    let mut coordinator = cluster.coordinator(&chart("selection_segment.st"), &[]);
    coordinator.wait_ready().await;
    cluster.agent("r1", &[], &[]);
    // The agent must be listening before the garbage goes out.
    coordinator.wait_for_trace("r1 live", |r| r.event == TraceEvent::AgentUp && r.name == "r1").await;
    let session = client(&cluster.endpoint).await;
    let run = status_of(&session, keys::status_any_run()).await.run;
    let rogue_report = wire::Report {
        run,
        agent: "r1".into(),
        incarnation: uuid::Uuid::nil(),
        token: TokenId(uuid::Uuid::from_u128(1)),
        epoch: 1,
        seq: 0,
        events: vec![],
        vars: vec![],
        vars_seq: 1,
        done: true,
    };
    let rogue_vars = wire::VarUpdate {
        run,
        from: "intruder".into(),
        incarnation: uuid::Uuid::nil(),
        seq: 1,
        vars: vec![wire::VarValue { var: 0, value: wire::WireValue::Int(2) }],
    };
    let garbage: Vec<Vec<u8>> = vec![
        b"\x00\xff\x13garbage".to_vec(),
        b"{}".to_vec(),
        br#"{"v":1,"m":{"dispatch":{}}}"#.to_vec(),
        br#"{"v":99,"m":{"ack":{}}}"#.to_vec(),
        wire::encode(&rogue_report),
        wire::encode(&rogue_vars),
        vec![b'x'; 2 * 1024 * 1024],
    ];
    let put = |key: String, payload: Vec<u8>| {
        let s = session.clone();
        async move { s.put(key, payload).congestion_control(zenoh::qos::CongestionControl::Block).await.expect("put") }
    };
    // Commands reach one process of a name: r1's, found as a coordinator finds it.
    let r1_cmd = cmd_key_of(&session, "r1").await;
    for g in &garbage {
        put(keys::report(run, "r1"), g.clone()).await;
        put(keys::vars(run, "intruder"), g.clone()).await;
        put(r1_cmd.clone(), g.clone()).await;
    }
    // A dispatch for a run nobody coordinates: the agent cannot fetch its chart and drops it.
    let bogus = ToAgent::Dispatch {
        run: RunId(uuid::Uuid::from_u128(77)),
        chart: ChartHash("0000000000000000".into()),
        token: TokenId(uuid::Uuid::from_u128(2)),
        epoch: 1,
        segment: 0,
        entry: 0,
        vars: vec![],
        vars_seq: 0,
        acks: vec![],
        fence: false,
        peers: wire::Peers::default(),
        held: false,
        mode: Default::default(),
    };
    put(r1_cmd, wire::encode(&bogus)).await;
    // An agent that announces itself but never says who it is.
    let _ghost = session.liveliness().declare_token(keys::alive("ghost")).await.expect("token");
    // A set request that is not one.
    let bad_set =
        session.get(keys::set(run, "tester")).payload(b"nonsense".to_vec()).timeout(TIMEOUT).await.expect("set query");
    let answer = bad_set.recv_async().await.expect("an answer");
    let text = String::from_utf8_lossy(&answer.result().expect("ok").payload().to_bytes()).into_owned();
    assert!(text.contains("\"ok\":false") && text.contains("malformed request"), "{text}");

    // The run still goes as it should: mode 1 takes branch A.
    let go = cluster.baton(&["set", "--connect", &cluster.endpoint, "go=true"]).await;
    assert!(go.status.success(), "{}", String::from_utf8_lossy(&go.stderr));
    let (status, log, trace, summary) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    check_trace_invariants(&trace, &chart("selection_segment.st"));
    assert_eq!(var(&summary, "a_count"), "1");
    assert!(summary["messages_dropped"].as_u64().unwrap_or(0) >= 2 * garbage.len() as u64, "{summary}");
    assert!(log.contains("dropped a message"), "the coordinator says what it dropped:\n{log}");
    let agent_log = cluster.agent_log("r1");
    assert!(agent_log.contains("dropped a message"), "{agent_log}");
    assert!(agent_log.contains("cannot take part in run"), "{agent_log}");
    tokio::time::timeout(Duration::from_secs(5), session.close()).await.ok();
}

/// Two runs of one chart behind one router: `baton set` without `--run` sets neither and lists both; with the id
/// `baton status` prints (or its start) it sets that run only.
#[tokio::test(flavor = "multi_thread")]
async fn a_set_reaches_only_the_run_it_names() {
    let cluster = Cluster::with_router().await;
    let chart = cluster.dir.path().join("wait.st");
    std::fs::write(
        &chart,
        "PROGRAM wait\nVAR go : BOOL; END_VAR\nINITIAL_STEP Ready: END_STEP\nTRANSITION FROM Ready TO Done := go; \
         END_TRANSITION\nSTEP Done: END_STEP\nEND_PROGRAM\n",
    )
    .expect("write the chart");
    let ep = cluster.endpoint.clone();
    // The runs `baton status --json` lists, by their ids as `baton status` prints them, once there are `n`. (A run's
    // queryables reach the router a moment after its first trace record.)
    let runs = |n: usize| {
        let (cluster, ep) = (&cluster, &ep);
        async move {
            let listed = tokio::time::timeout(baton_tests::loopback::TIMEOUT, async {
                loop {
                    let status = cluster.baton(&["status", "--connect", ep, "--json"]).await;
                    let ids: Vec<String> = String::from_utf8_lossy(&status.stdout)
                        .lines()
                        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
                        .filter_map(|r| uuid::Uuid::parse_str(r["run"].as_str()?).ok())
                        .map(|id| id.simple().to_string())
                        .collect();
                    if ids.len() >= n {
                        return ids;
                    }
                }
            })
            .await;
            listed.unwrap_or_else(|_| panic!("baton status never listed {n} run(s)"))
        }
    };
    let mut first = cluster.coordinator_joining_as("1", &chart, &[]);
    first.wait_ready().await;
    let one = runs(1).await.remove(0);
    let mut second = cluster.coordinator_joining_as("2", &chart, &[]);
    second.wait_ready().await;
    let two = runs(2).await.into_iter().find(|r| *r != one).expect("the second run");
    // `baton status` lists both, by the ids it prints.
    let listed = tokio::time::timeout(baton_tests::loopback::TIMEOUT, async {
        loop {
            let status = cluster.baton(&["status", "--connect", &ep]).await;
            let listed = String::from_utf8_lossy(&status.stdout).to_string();
            if listed.contains(&one) && listed.contains(&two) {
                return listed;
            }
        }
    })
    .await;
    assert!(listed.is_ok(), "baton status never listed both runs");

    let ambiguous = cluster.baton(&["set", "--connect", &ep, "go=true"]).await;
    let err = String::from_utf8_lossy(&ambiguous.stderr).to_string();
    assert_eq!(ambiguous.status.code(), Some(2), "{err}");
    assert!(err.contains("--run") && err.contains(&one) && err.contains(&two), "{err}");
    let unknown = cluster.baton(&["set", "--connect", &ep, "--run", "ffff0000", "go=true"]).await;
    assert_eq!(unknown.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&unknown.stderr).contains("no run `ffff0000`"));

    // The second run, by the start of its id: it ends, and the first still waits.
    let set = cluster.baton(&["set", "--connect", &ep, "--run", &two[..12], "go=true"]).await;
    assert!(set.status.success(), "{}", String::from_utf8_lossy(&set.stderr));
    let (status, log, trace, _) = second.finish().await;
    assert!(status.success(), "{log}");
    assert!(events(&trace, TraceEvent::Activate).iter().any(|e| e.1 == "Done"));
    let status = cluster.baton(&["status", "--connect", &ep, "--json"]).await;
    let text = String::from_utf8_lossy(&status.stdout).to_string();
    let report: serde_json::Value = serde_json::from_str(text.trim()).expect("one run's status");
    assert_eq!(report["run"], serde_json::Value::String(uuid::Uuid::parse_str(&one).expect("id").to_string()));
    assert_eq!(report["active_steps"][0]["name"], "Ready", "the first run was not set: {text}");
    // One run is left: it needs no --run.
    let set = cluster.baton(&["set", "--connect", &ep, "go=true"]).await;
    assert!(set.status.success(), "{}", String::from_utf8_lossy(&set.stderr));
    let (status, log, _, _) = first.finish().await;
    assert!(status.success(), "{log}");
}

/// A client that reaches no router says so in an operator's words, soon (it tries for
/// `CLIENT_CONNECT_TIMEOUT_MS`, 2.5 s), never with a dependency's source path: nothing listening is told apart
/// from something that listens but does not open a Zenoh session over plain TCP (a TLS router, most likely).
#[tokio::test(flavor = "multi_thread")]
async fn a_client_that_reaches_no_router_says_why_in_plain_words() {
    let cluster = Cluster::new();
    let port = baton_tests::loopback::free_port();
    let out = cluster.baton(&["status", "--connect", &format!("tcp/127.0.0.1:{port}")]).await;
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(stderr.contains(&format!("nothing listens at 127.0.0.1:{port}")), "{stderr}");
    assert!(!stderr.contains(".cargo") && !stderr.contains("Timeout!"), "a dependency's words: {stderr}");

    // Something listens (the kernel completes the connection) but speaks no Zenoh: as a TLS router is, to a client
    // that came over plain TCP.
    let listener = std::net::TcpListener::bind("127.0.0.1:0").expect("a listener");
    let addr = listener.local_addr().expect("its address");
    let out = cluster.baton(&["ctl", "--connect", &format!("tcp/{addr}"), "hold"]).await;
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    assert!(stderr.contains(&format!("something listens at {addr}")), "{stderr}");
    assert!(stderr.contains(&format!("tls/{addr}")) && stderr.contains("--zenoh-config"), "{stderr}");
    drop(listener);
}

/// A normal end is not reported as a fault: when a run whose coordinator hosted the router ends, its agents lose
/// the router, but hold nothing — they say so plainly, with no lease-fence warning, and nothing of an abort.
#[tokio::test(flavor = "multi_thread")]
async fn agents_of_a_run_that_ended_normally_report_no_fault() {
    let mut cluster = Cluster::new();
    let chart = repo("tests/charts/one_step.st");
    let mut coordinator = cluster.coordinator(&chart, &[]);
    coordinator.wait_ready().await;
    // A short lease, so that the agent notices the router gone within a second or two.
    cluster.agent("r1", &[], &["--lease-ms", "1000"]);
    let (status, log, trace, _) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    check_trace_invariants(&trace, &chart);
    // The router went with the coordinator: r1 loses it, with nothing of the run left to stop.
    let said = cluster.wait_for_agent_trace("r1", "no contact", |r| r.event == TraceEvent::ContactLost).await;
    let faults = [TraceEvent::SkillCancel, TraceEvent::SkillFault, TraceEvent::InputRefused];
    assert!(!said.iter().any(|r| faults.contains(&r.event)), "{said:#?}");
}

/// Fencing by term, in the agent's own process: once a command of a higher coordinator term reached it (as from a
/// standby that won the run's election), the agent refuses what the coordinator of the lower term sends — its
/// values (a `baton set` through it changes nothing on the agent) and its commands (its abort) — and traces each
/// refusal; the token stays where the deposed coordinator could not move it.
#[tokio::test(flavor = "multi_thread")]
async fn an_agent_that_heard_a_higher_term_refuses_the_deposed_coordinators_values_and_commands() {
    let mut cluster = Cluster::new();
    let chart = fenced_chart(&cluster, "", "");
    let mut coordinator = cluster.coordinator(&chart, &[]);
    coordinator.wait_ready().await;
    cluster.agent("r1", &[], &[]);
    coordinator.wait_for_trace("Work dispatched", |r| r.event == TraceEvent::Dispatch && r.name == "Work").await;
    let session = client(&cluster.endpoint).await;
    let run = status_of(&session, keys::status_any_run()).await.run;
    // The coordinator runs at term 0 (it stands in no election); a command of term 9 reaches r1.
    let sync = wire::encode_termed(&ToAgent::Sync { run }, 9);
    session.put(cmd_key_of(&session, "r1").await, sync).await.expect("put");
    cluster.wait_for_agent_trace("r1", "term 9", |r| r.event == TraceEvent::Term && message_has(r, "term 9")).await;

    // Through the deposed coordinator, `go` is set: the coordinator takes it, r1 refuses its update.
    let go = cluster.baton(&["set", "--connect", &cluster.endpoint, "go=true"]).await;
    assert!(go.status.success(), "{}", String::from_utf8_lossy(&go.stderr));
    let refused = |what: &'static str| {
        move |r: &baton_proto::exec::trace::TraceRecord| r.event == TraceEvent::StaleTerm && r.name == what
    };
    let trace = cluster.wait_for_agent_trace("r1", "the refused update", refused("variable update")).await;
    let said = trace.iter().find(|r| refused("variable update")(r)).and_then(|r| r.message.clone());
    assert!(said.as_deref().is_some_and(|m| m.contains("term 0") && m.contains("term 9")), "{said:?}");
    // The update was refused, so Work's transition cannot clear on r1: the token is still there.
    let status = status_of(&session, keys::status(run)).await;
    assert!(status.active_steps.iter().any(|s| s.name == "Work"), "{status:?}");
    assert!(!cluster.agent_trace("r1").iter().any(|r| r.event == TraceEvent::Fire), "r1 fired nothing");

    // Its abort is refused too.
    let abort = cluster.baton(&["ctl", "--connect", &cluster.endpoint, "abort"]).await;
    assert!(abort.status.success(), "{}", String::from_utf8_lossy(&abort.stderr));
    cluster.wait_for_agent_trace("r1", "the refused abort", refused("abort")).await;
    let log = cluster.agent_log("r1");
    assert!(log.contains("refused: this run has seen term 9"), "{log}");
    coordinator.kill().await;
    tokio::time::timeout(Duration::from_secs(5), session.close()).await.ok();
}

/// The chart of the fencing tests: Work on r1 (its actions `work`, declared in `actions`), Done once `go` is set.
fn fenced_chart(cluster: &Cluster, work: &str, actions: &str) -> std::path::PathBuf {
    let chart = cluster.dir.path().join("fenced.st");
    let text = format!(
        "PROGRAM fenced\nVAR go : BOOL; END_VAR\nINITIAL_STEP Start: END_STEP\n\
         TRANSITION FROM Start TO Work := TRUE; END_TRANSITION\nSTEP Work: {{agent := 'r1'}} {work} END_STEP\n\
         TRANSITION FROM Work TO Done := go; END_TRANSITION\nSTEP Done: END_STEP\n{actions}END_PROGRAM\n"
    );
    std::fs::write(&chart, text).expect("write the chart");
    chart
}

/// An agent restarted (SIGKILL, then started again under its name, as systemd does) still refuses the deposed
/// coordinator: the highest term it had heard is in its state folder. The run's coordinator at term 0 stands for a
/// deposed one (a command of term 9 reached r1 mid-motion); after r1's restart, the coordinator sends r1 its token's
/// step again (r1 holds nothing), and r1 refuses it, where a restarted agent that forgot term 9 would move again.
#[tokio::test(flavor = "multi_thread")]
async fn a_restarted_agent_remembers_the_highest_term_and_still_refuses_the_deposed_coordinator() {
    let mut cluster = Cluster::new();
    let chart = fenced_chart(&cluster, "Move(N);", "ACTION Move: {skill := 'motion', ms := 600000} END_ACTION\n");
    let mut coordinator = cluster.coordinator(&chart, &[]);
    coordinator.wait_ready().await;
    cluster.agent("r1", &[], &[]);
    cluster.wait_for_agent_trace("r1", "Work's motion", |r| r.event == TraceEvent::SkillStart).await;
    let session = client(&cluster.endpoint).await;
    let run = status_of(&session, keys::status_any_run()).await.run;
    let sync = wire::encode_termed(&ToAgent::Sync { run }, 9);
    session.put(cmd_key_of(&session, "r1").await, sync).await.expect("put");
    cluster.wait_for_agent_trace("r1", "term 9", |r| r.event == TraceEvent::Term && message_has(r, "term 9")).await;

    cluster.kill_agent("r1").await;
    cluster.agent("r1", &[], &["--verbose"]);
    // The restarted r1 holds nothing: the coordinator (term 0) gives it Work again, and r1 refuses it.
    let refused = |r: &baton_proto::exec::trace::TraceRecord| {
        r.event == TraceEvent::StaleTerm && message_has(r, "term 0") && message_has(r, "seen term 9")
    };
    let either = |r: &baton_proto::exec::trace::TraceRecord| refused(r) || r.event == TraceEvent::SkillStart;
    let trace = cluster.wait_for_agent_trace("r1", "Work's dispatch refused or taken", either).await;
    assert!(trace.iter().any(refused), "the deposed coordinator's dispatch refused: {trace:?}");
    assert!(!trace.iter().any(|r| r.event == TraceEvent::SkillStart), "r1 moved nothing for term 0: {trace:?}");
    let log = cluster.agent_log("r1");
    assert!(log.contains("coordinator term 9 remembered from before this agent's restart"), "{log}");
    coordinator.kill().await;
    tokio::time::timeout(Duration::from_secs(5), session.close()).await.ok();
}

fn message_has(r: &baton_proto::exec::trace::TraceRecord, text: &str) -> bool {
    r.message.as_deref().is_some_and(|m| m.contains(text))
}
