//! A cell behind the access control `baton deploy acl` writes, on mutual TLS with the certificates of `baton deploy
//! certs`, enforced by Zenoh's own router — the one `baton run --listen` embeds, and a real `zenohd` 1.10.2 (which
//! `.ci/run` installs in the machine's cache of tools) that the coordinator joins as a client: the cell runs; a rogue process
//! holding another agent's certificate cannot announce robot1, cannot hear robot1's commands, cannot put a report,
//! a variable or a device report into the run, and cannot set or operate it — nothing it sends reaches the
//! coordinator, and the run's events are those of a run without it; an operator can. Without access control, the
//! same messages reach the coordinator (which drops them by its own checks).

use std::path::Path;
use std::time::Duration;

use baton_proto::cluster::keys;
use baton_proto::cluster::wire::{self, CtlRequest, DeviceReport, Report, RunId, SetRequest, TokenId, VarUpdate};
use baton_proto::exec::trace::{TraceEvent, TraceRecord};
use baton_tests::loopback::{bin, deploy_certs, free_port, start_zenohd, tls_config, zenohd, Cluster, TIMEOUT};

baton_tests::harness_main!(
    tokio behind_its_acl_a_rogue_with_another_agents_certificate_changes_nothing,
    tokio without_access_control_the_rogue_hears_robot1_and_aborts_the_run,
    tokio the_same_rules_keep_the_rogue_out_on_a_real_zenohd,
    sync the_identities_may_be_listed_after_one_plural_flag,
    tokio the_user_password_example_lets_only_operators_set_and_operate,
);

/// Which router enforces the rules.
#[derive(Clone, Copy, PartialEq)]
enum Router {
    /// The coordinator's own (`baton run --listen`).
    Embedded,
    /// A `zenohd` process the coordinator joins with its own certificate.
    Zenohd,
}

const CHART: &str = "PROGRAM line\nVAR go, a, b : BOOL; END_VAR\nINITIAL_STEP Idle: END_STEP\n\
    TRANSITION FROM Idle TO A := go; END_TRANSITION\n\
    STEP A: {agent := 'robot1'} MoveA(N, a); END_STEP\nTRANSITION FROM A TO B := a; END_TRANSITION\n\
    STEP B: {agent := 'robot2'} MoveB(N, b); END_STEP\nTRANSITION FROM B TO Done := b; END_TRANSITION\n\
    STEP Done: END_STEP\n\
    ACTION MoveA: {skill := 'motion', ms := 600} END_ACTION\n\
    ACTION MoveB: {skill := 'motion', ms := 100} END_ACTION\nEND_PROGRAM\n";

fn baton(args: &[&str]) -> std::process::Output {
    let out = std::process::Command::new(bin("baton")).args(args).output().expect("baton runs");
    assert!(out.status.success(), "baton {args:?}: {}", String::from_utf8_lossy(&out.stderr));
    out
}

/// The run's events that say what it did, without their times and token ids. A robot whose session the router
/// dropped and took back (`agent_lost`, the alarm of its token, `resume`) is left out: a loaded machine does that
/// now and then with or without a rogue (2026-12-04: 1 run in 25 with two busy loops beside the test, in calm and
/// attacked runs alike), and the rogue's own doing — a second robot1, a forged report, a set or an abort — shows
/// in what remains, and in `is_loss`'s complement of alarms.
fn story(trace: &[TraceRecord]) -> Vec<(TraceEvent, String, Option<String>)> {
    trace
        .iter()
        .filter(|r| !matches!(r.event, TraceEvent::Value | TraceEvent::Set | TraceEvent::AgentUp))
        .filter(|r| !is_loss(r))
        .map(|r| (r.event, r.name.clone(), r.agent.clone()))
        .collect()
}

/// A record of a robot lost and back: its `agent_lost`, the alarm of the token it held, the token's `resume`.
fn is_loss(r: &TraceRecord) -> bool {
    match r.event {
        TraceEvent::AgentLost | TraceEvent::Resume => true,
        TraceEvent::Alarm => r.message.as_deref().is_some_and(|m| m.contains(" lost holding the token")),
        _ => false,
    }
}

/// What a rogue saw and got: samples of robot1's commands, and answers to its set and ctl queries; and the
/// coordinator's log of the run, to say what it dropped when a check fails.
#[derive(Default, Debug)]
struct Rogue {
    commands_heard: usize,
    answers: usize,
    log: String,
}

type RogueSession = (Option<(zenoh::Session, zenoh::Result<zenoh::liveliness::LivelinessToken>)>, Option<Heard>);
type Heard = zenoh::pubsub::Subscriber<zenoh::handlers::FifoChannelHandler<zenoh::sample::Sample>>;

/// A process with robot2's certificate joins: it announces robot1 and listens to what is sent to robot1.
async fn rogue_joins(endpoint: &str, dir: &Path, pki: &Path) -> RogueSession {
    let config = tls_config(dir, pki, "robot2", false);
    let mut config = zenoh::Config::from_file(&config).expect("config");
    let net = baton_proto::cluster::netconfig::NetConfig::client(&[endpoint.to_string()], false);
    for (key, value) in net.overrides() {
        config.insert_json5(key, &value).expect("override");
    }
    let s = zenoh::open(config).await.expect("robot2's certificate connects");
    let token = s.liveliness().declare_token(keys::alive("robot1")).await;
    let heard = s.declare_subscriber("baton/agent/robot1/**").await.expect("declared");
    (Some((s, token)), Some(heard))
}

/// While robot1 works, the rogue's session `s` tries every forgery on robot1's keys and the coordinator's:
/// a report, updates, a device report and garbage put, a set and an abort asked. Returns how many of its queries
/// were answered.
async fn forge(s: &zenoh::Session, cluster: &Cluster, anna: &str) -> usize {
    let mut answers = 0;
    // While robot1 works: every forgery, on robot1's keys and the coordinator's.
    let status = cluster.baton(&["status", "--connect", &cluster.endpoint, "--zenoh-config", anna, "--json"]).await;
    let status: serde_json::Value =
        serde_json::from_str(String::from_utf8_lossy(&status.stdout).lines().next().unwrap_or("null")).expect("json");
    let run: RunId = serde_json::from_value(status["run"].clone()).expect("the run's id");
    let report = Report {
        run,
        agent: "robot1".into(),
        incarnation: uuid::Uuid::from_u128(1),
        token: TokenId(uuid::Uuid::from_u128(2)),
        epoch: 1,
        seq: 1,
        events: Vec::new(),
        vars: Vec::new(),
        vars_seq: 0,
        done: true,
    };
    let update = |from: &str| VarUpdate {
        run,
        from: from.into(),
        incarnation: uuid::Uuid::from_u128(1),
        seq: 99,
        vars: Vec::new(),
    };
    let device =
        DeviceReport { run, agent: "robot1".into(), incarnation: uuid::Uuid::from_u128(1), seq: 9, down: Vec::new() };
    for (key, payload) in [
        (keys::report(run, "robot1"), wire::encode(&report)),
        (keys::vars(run, "robot1"), wire::encode(&update("robot1"))),
        (keys::vars(run, "coordinator"), wire::encode(&update("coordinator"))),
        (keys::devices(run, "robot1"), wire::encode(&device)),
        (keys::report(run, "robot1"), b"garbage".to_vec()),
    ] {
        s.put(key, payload).await.expect("a put is accepted locally");
    }
    let set = SetRequest { name: "go".into(), value: serde_json::json!(false), by: "robot1".into(), user: None };
    let abort =
        CtlRequest { command: "abort".into(), reason: "rogue".into(), by: "robot1".into(), ..Default::default() };
    for (key, payload) in
        [(keys::set(run, "robot1"), wire::encode(&set)), (keys::ctl(run, "robot1"), wire::encode(&abort))]
    {
        let replies = s.get(key).payload(payload).timeout(Duration::from_secs(2)).await.expect("a query goes out");
        while let Ok(r) = replies.recv_async().await {
            if r.result().is_ok() {
                answers += 1;
            }
        }
    }
    answers
}

/// Runs the cell: with `acl`, the router enforces the generated rules (else it is plain TLS, everyone let in);
/// with `rogue`, a process with robot2's certificate tries every forgery while robot1 works. Returns the trace,
/// the summary and what the rogue got.
async fn cell(
    router_kind: Router,
    acl: bool,
    rogue: bool,
) -> (Option<i32>, Vec<TraceRecord>, serde_json::Value, Rogue) {
    let zenohd = (router_kind == Router::Zenohd).then(zenohd);
    let mut cluster = Cluster::new();
    let port = free_port();
    cluster.endpoint = format!("tls/127.0.0.1:{port}");
    let dir = cluster.dir.path().to_path_buf();
    let pki = dir.join("pki");
    let pki_arg = pki.to_str().expect("utf-8");
    deploy_certs(&pki, &["router", "coordinator", "robot1", "robot2", "anna", "--san", "127.0.0.1"]);
    let chart = dir.join("line.st");
    std::fs::write(&chart, CHART).expect("write the chart");
    let router = dir.join("router.json5");
    let mut args = vec!["deploy", "acl", chart.to_str().expect("utf-8"), "--coordinator", "coordinator"];
    args.extend(["--agent", "robot1", "--agent", "robot2", "--operator", "anna", "--pki", pki_arg]);
    let router_name = if zenohd.is_some() { "router" } else { "coordinator" };
    args.extend(["--router", router_name, "--listen", &cluster.endpoint, "-o", router.to_str().expect("utf-8")]);
    baton(&args);
    if !acl {
        // The same router, its access control switched off.
        let text = std::fs::read_to_string(&router).expect("read");
        std::fs::write(&router, text.replacen("\"enabled\": true", "\"enabled\": false", 1)).expect("write");
    }
    // The router: zenohd, ready once it accepts connections; or the coordinator's own.
    let mut _zenohd = None;
    let mut coordinator = match &zenohd {
        Some(_) => {
            _zenohd = Some(start_zenohd(&router, port, &dir.join("zenohd.log")).await);
            let own = tls_config(&dir, &pki, "coordinator", false);
            cluster.coordinator_connecting(&chart, &["--zenoh-config", own.to_str().expect("utf-8")])
        }
        None => cluster.coordinator(&chart, &["--zenoh-config", router.to_str().expect("utf-8")]),
    };
    coordinator.wait_ready().await;
    let mut got = Rogue::default();
    // With access control, the rogue comes first, announcing robot1 before robot1 boots; without, after the
    // robots (else the coordinator would see robot1 twice and never run).
    let (mut rogue_session, mut heard) = (None, None);
    if rogue && acl {
        (rogue_session, heard) = rogue_joins(&cluster.endpoint, &dir, &pki).await;
    }
    for name in ["robot1", "robot2"] {
        let config = tls_config(&dir, &pki, name, false);
        cluster.agent(name, &[], &["--zenoh-config", config.to_str().expect("utf-8")]);
    }
    let anna = tls_config(&dir, &pki, "anna", false);
    let anna = anna.to_str().expect("utf-8");
    // Both robots live before the part starts, as an operator sees them.
    let live = tokio::time::timeout(TIMEOUT, async {
        loop {
            let out =
                cluster.baton(&["status", "--connect", &cluster.endpoint, "--zenoh-config", anna, "--json"]).await;
            let text = String::from_utf8_lossy(&out.stdout).to_string();
            let s: serde_json::Value = serde_json::from_str(text.lines().next().unwrap_or("null")).unwrap_or_default();
            if s["agents"].as_array().is_some_and(|a| a.len() == 2) {
                return;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    })
    .await;
    assert!(live.is_ok(), "the robots never came up");
    if rogue && !acl {
        (rogue_session, heard) = rogue_joins(&cluster.endpoint, &dir, &pki).await;
    }
    let set = cluster.baton(&["set", "--connect", &cluster.endpoint, "--zenoh-config", anna, "go=true"]).await;
    assert!(set.status.success(), "the operator sets: {}", String::from_utf8_lossy(&set.stderr));
    if let Some((s, _)) = &rogue_session {
        got.answers = forge(s, &cluster, anna).await;
    }
    let (status, log, trace, summary) = coordinator.finish().await;
    assert!(status.code().is_some(), "{log}");
    if std::env::var_os("ACL_DEBUG").is_some() {
        eprintln!("=== coordinator log (acl {acl}, rogue {rogue}):\n{log}");
    }
    got.log = log;
    if let Some(h) = heard {
        while let Ok(Some(_)) = h.try_recv() {
            got.commands_heard += 1;
        }
    }
    if let Some((s, _)) = rogue_session {
        tokio::time::timeout(TIMEOUT, s.close()).await.ok();
    }
    (status.code(), trace, summary, got)
}

async fn behind_its_acl_a_rogue_with_another_agents_certificate_changes_nothing() {
    kept_out(Router::Embedded).await;
}

/// The same rules, written for a `zenohd` router that the coordinator joins as a client with its own certificate
/// (the coordinator's rules then apply to it too).
async fn the_same_rules_keep_the_rogue_out_on_a_real_zenohd() {
    kept_out(Router::Zenohd).await;
}

async fn kept_out(router: Router) {
    let (calm_status, calm, calm_summary, calm_got) = cell(router, true, false).await;
    let (status, attacked, summary, rogue) = cell(router, true, true).await;
    assert_eq!((calm_status, status), (Some(0), Some(0)), "{attacked:#?}");
    assert_eq!(story(&attacked), story(&calm), "the rogue changed the run");
    assert!(attacked.iter().any(|r| r.event == TraceEvent::Activate && r.name == "Done"));
    // Nothing the rogue sent reached the coordinator: the router dropped it all. The coordinator says every message it
    // drops for what it is (another's key, another run, unreadable) in a warning; the count in the summary also holds
    // the duplicates of robot1's own reports, which robot1 resends when an acknowledgement takes over 200 ms (it
    // did on a loaded machine: `messages_dropped` 1, no warning), and so says nothing of the rogue.
    assert_eq!(drop_warnings(&rogue.log), Vec::<String>::new(), "{summary}\n{}", rogue.log);
    assert_eq!(drop_warnings(&calm_got.log), Vec::<String>::new(), "{calm_summary}\n{}", calm_got.log);
    assert_eq!(rogue.commands_heard, 0, "the rogue heard robot1's commands");
    assert_eq!(rogue.answers, 0, "the rogue's set or ctl was answered");
    let alarm = |r: &&TraceRecord| r.event == TraceEvent::Alarm && !is_loss(r);
    assert!(!attacked.iter().any(|r| alarm(&r)), "robot1 was announced twice: {attacked:#?}");
    // A's motion ran its 600 ms: no forged report ended it.
    let at = |e: TraceEvent, n: &str| attacked.iter().find(|r| r.event == e && r.name == n).map(|r| r.t_ms);
    let (a, b) = (at(TraceEvent::Activate, "A").expect("A"), at(TraceEvent::Activate, "B").expect("B"));
    assert!(b - a >= 600 - 20, "A lasted {} ms", b - a);
}

/// The coordinator's warnings of messages it dropped for what they were (another's key, another run, unreadable).
fn drop_warnings(log: &str) -> Vec<String> {
    log.lines().filter(|l| l.contains("dropped")).map(str::to_string).collect()
}

/// The control: the same router with its access control off. The rogue's messages reach the coordinator, whose own
/// checks drop the forged report, update and device report (on robot1's keys, from a process that is not robot1's)
/// and the garbage; but the rogue hears robot1's commands, and its `abort` — the coordinator cannot tell who asks —
/// ends the run: what only the router's access control prevents.
async fn without_access_control_the_rogue_hears_robot1_and_aborts_the_run() {
    let (status, trace, summary, rogue) = cell(Router::Embedded, false, true).await;
    assert_eq!(status, Some(4), "{trace:#?}");
    assert!(summary["messages_dropped"].as_u64().unwrap_or(0) >= 3, "{summary}");
    // What `kept_out` looks for: here the rogue's misaddressed messages reach the coordinator, and each is said.
    assert!(drop_warnings(&rogue.log).len() >= 3, "{}", rogue.log);
    assert!(rogue.commands_heard > 0, "robot1's dispatch reached the rogue too");
    assert!(rogue.answers > 0, "the rogue's set or abort was answered");
    let abort = trace.iter().find(|r| r.event == TraceEvent::Command && r.name == "abort").expect("aborted");
    assert_eq!(abort.by.as_deref(), Some("robot1"), "who the rogue said it was");
}

/// `--agents robot1 robot2 --operators op1 op2`, as the issue that asked for `baton deploy acl` writes it, gives
/// the rules that one flag per name gives.
fn the_identities_may_be_listed_after_one_plural_flag() {
    let dir = tempfile::tempdir().expect("temp dir");
    let chart = dir.path().join("line.st");
    std::fs::write(&chart, CHART).expect("write the chart");
    let chart = chart.to_str().expect("utf-8");
    let write = |file: &str, identities: &[&str]| {
        let out = dir.path().join(file);
        let mut args = vec!["deploy", "acl", chart, "--coordinator", "coordinator"];
        args.extend(identities);
        args.extend(["-o", out.to_str().expect("utf-8")]);
        baton(&args);
        std::fs::read_to_string(out).expect("the rules")
    };
    let plural = write("plural.json5", &["--agents", "robot1", "robot2=welder", "--operators", "op1", "op2"]);
    let singular = write(
        "singular.json5",
        &["--agent", "robot1", "--agent", "robot2=welder", "--operator", "op1", "--operator", "op2"],
    );
    assert_eq!(plural, singular);
    for name in ["robot1", "robot2", "op1", "op2"] {
        assert!(plural.contains(&format!("\"{name}\"")), "{name} has no rule:\n{plural}");
    }
}

/// `deploy/acl`, the worked example with user names and passwords, on a real `zenohd` 1.10.2 as its README runs it
/// (from the repository's folder): the `cell` user runs the coordinator and an agent; the `operator` user's `set`
/// and `ctl` are taken, the `cell` user's are refused — the router passes them on to nobody.
async fn the_user_password_example_lets_only_operators_set_and_operate() {
    let mut cluster = Cluster::new();
    let port = free_port();
    cluster.endpoint = format!("tcp/127.0.0.1:{port}");
    let repo = baton_tests::loopback::repo("");
    let example = std::fs::read_to_string(repo.join("deploy/acl/zenohd.json5")).expect("the example");
    let config = cluster.dir.path().join("zenohd.json5");
    std::fs::write(&config, example.replace("tcp/0.0.0.0:7447", &cluster.endpoint)).expect("write");
    let _router = start_zenohd(&config, port, &cluster.dir.path().join("zenohd.log")).await;
    let cell = repo.join("deploy/acl/cell.json5");
    let operator = repo.join("deploy/acl/operator.json5");
    let (cell, operator) = (cell.to_str().expect("utf-8"), operator.to_str().expect("utf-8"));
    let chart = cluster.dir.path().join("wait.st");
    std::fs::write(
        &chart,
        "PROGRAM wait\nVAR go : BOOL; END_VAR\nINITIAL_STEP A: END_STEP\nTRANSITION FROM A TO B := go; END_TRANSITION\n\
         STEP B: {agent := 'r1'} END_STEP\nTRANSITION FROM B TO C := TRUE; END_TRANSITION\nSTEP C: END_STEP\nEND_PROGRAM\n",
    )
    .expect("write the chart");
    let mut coordinator = cluster.coordinator_connecting(&chart, &["--zenoh-config", cell]);
    coordinator.wait_ready().await;
    cluster.agent("r1", &[], &["--zenoh-config", cell]);
    cluster.wait_for_agent_trace("r1", "its start", |r| r.event == TraceEvent::AgentUp).await;
    let ep = cluster.endpoint.clone();
    let refused = cluster.baton(&["set", "--connect", &ep, "--zenoh-config", cell, "go=true"]).await;
    assert!(!refused.status.success(), "the cell user set an input");
    let refused = cluster.baton(&["ctl", "--connect", &ep, "--zenoh-config", cell, "abort"]).await;
    assert!(!refused.status.success(), "the cell user aborted the run");
    let hold = ["ctl", "--connect", &ep, "--zenoh-config", operator, "hold", "--reason", "material late", "--wait"];
    let hold = cluster.baton(&hold).await;
    assert!(hold.status.success(), "{}", String::from_utf8_lossy(&hold.stderr));
    let unhold = cluster.baton(&["ctl", "--connect", &ep, "--zenoh-config", operator, "unhold"]).await;
    assert!(unhold.status.success(), "{}", String::from_utf8_lossy(&unhold.stderr));
    let set = cluster.baton(&["set", "--connect", &ep, "--zenoh-config", operator, "go=true"]).await;
    assert!(set.status.success(), "{}", String::from_utf8_lossy(&set.stderr));
    let (status, log, trace, _) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    let by: Vec<(TraceEvent, String, Option<&str>)> = trace
        .iter()
        .filter(|r| matches!(r.event, TraceEvent::Command | TraceEvent::Set))
        .map(|r| (r.event, r.name.clone(), r.by.as_deref()))
        .collect();
    let operator = Some("operator");
    assert_eq!(
        by,
        [
            (TraceEvent::Command, "hold".to_string(), operator),
            (TraceEvent::Command, "unhold".to_string(), operator),
            (TraceEvent::Set, "go".to_string(), operator)
        ]
    );
}
