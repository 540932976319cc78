//! What a process may claim behind the access control `baton deploy acl` writes (mutual TLS, the router the
//! coordinator embeds): roles are the deployment's — an agent announcing another is refused and says why, and a
//! process that claims a role in its answer without the router's leave is not given the role's steps; who sent a
//! command is the name the router checked, whatever the request says; and an agent that has lost its router when it
//! joins a run starts fenced.

use std::path::{Path, PathBuf};
use std::time::Duration;

use baton_proto::cluster::keys;
use baton_proto::cluster::wire::{self, AgentInfo, CtlRequest, RunId};
use baton_proto::exec::trace::{TraceEvent, TraceRecord};
use baton_tests::loopback::{deploy_certs, free_port, read_trace, tls_config, Cluster, Coordinator, TIMEOUT};

/// A welder's step, then robot1's (a motion that may move under `reassign`).
const CHART: &str = "PROGRAM weld\nVAR go, welded, moved : BOOL; END_VAR\nINITIAL_STEP Idle: END_STEP\n\
    TRANSITION FROM Idle TO Move := go; END_TRANSITION\n\
    STEP Move: {agent := 'robot1'} MoveIt(N, moved); END_STEP\nTRANSITION FROM Move TO Weld := moved; END_TRANSITION\n\
    STEP Weld: {role := 'welder'} WeldIt(N, welded); END_STEP\nTRANSITION FROM Weld TO Done := welded; END_TRANSITION\n\
    STEP Done: END_STEP\n\
    ACTION MoveIt: {skill := 'motion', ms := 300} END_ACTION\n\
    ACTION WeldIt: {skill := 'motion', ms := 300} END_ACTION\nEND_PROGRAM\n";

/// A cell on TLS behind the generated rules (`edit` changes the file first), robot1 and w1 (the welder) deployed,
/// anna the operator: the cluster, its folder, its certificates, and the coordinator (the router) running.
async fn secured(edit: impl Fn(String) -> String) -> (Cluster, PathBuf, PathBuf, Coordinator) {
    let mut cluster = Cluster::new();
    cluster.endpoint = format!("tls/127.0.0.1:{}", free_port());
    let dir = cluster.dir.path().to_path_buf();
    let pki = dir.join("pki");
    deploy_certs(&pki, &["coordinator", "robot1", "w1", "anna", "--san", "127.0.0.1"]);
    let chart = dir.join("weld.st");
    std::fs::write(&chart, CHART).expect("write the chart");
    let router = dir.join("router.json5");
    let out = cluster
        .baton(&[
            "deploy",
            "acl",
            chart.to_str().expect("utf-8"),
            "--coordinator",
            "coordinator",
            "--agent",
            "robot1",
            "--agent",
            "w1=welder",
            "--operator",
            "anna",
            "--pki",
            pki.to_str().expect("utf-8"),
            "--router",
            "coordinator",
            "--listen",
            &cluster.endpoint,
            "-o",
            router.to_str().expect("utf-8"),
        ])
        .await;
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = std::fs::read_to_string(&router).expect("the rules");
    std::fs::write(&router, edit(text)).expect("write the rules");
    let args = ["--zenoh-config", router.to_str().expect("utf-8"), "--on-agent-loss", "reassign"];
    let mut coordinator = cluster.coordinator(&chart, &args);
    coordinator.wait_ready().await;
    (cluster, dir, pki, coordinator)
}

/// A session of the test's own with `name`'s certificate.
async fn session(cluster: &Cluster, dir: &Path, pki: &Path, name: &str) -> zenoh::Session {
    let mut config = zenoh::Config::from_file(tls_config(dir, pki, name, false)).expect("config");
    let net = baton_proto::cluster::netconfig::NetConfig::client(std::slice::from_ref(&cluster.endpoint), false);
    for (key, value) in net.overrides() {
        config.insert_json5(key, &value).expect("override");
    }
    zenoh::open(config).await.expect("the certificate connects")
}

/// The only run behind the router, as anna's `baton status --json` lists it.
async fn run_id(cluster: &Cluster, dir: &Path, pki: &Path) -> RunId {
    let anna = tls_config(dir, pki, "anna", false);
    let out = cluster
        .baton(&["status", "--connect", &cluster.endpoint, "--zenoh-config", anna.to_str().unwrap(), "--json"])
        .await;
    let status: serde_json::Value =
        serde_json::from_str(String::from_utf8_lossy(&out.stdout).lines().next().unwrap_or("null")).expect("json");
    serde_json::from_value(status["run"].clone()).expect("the run's id")
}

/// The trace once it holds a record `found` accepts (read again each time its folder changes).
async fn trace_once(path: &Path, found: impl Fn(&TraceRecord) -> bool) -> Vec<TraceRecord> {
    let dir = path.parent().expect("the trace's folder");
    let what = format!("a record the test waits for in {}", path.display());
    baton_tests::loopback::when_changed(dir, &what, || {
        let trace = baton_tests::loopback::read_trace_so_far(path);
        trace.iter().any(&found).then_some(trace)
    })
    .await
}

/// robot1, deployed without a role, started with `--role welder`: refused before it runs, saying why. A process on
/// robot1's certificate that claims the role in its own answer (its role token is what the router refuses) is taken
/// as robot1 without it: the welder's step waits for the welder, and goes to w1 once it comes.
#[tokio::test(flavor = "multi_thread")]
async fn an_identity_serves_only_the_roles_its_deployment_gives_it() {
    let (mut cluster, dir, pki, coordinator) = secured(|t| t).await;
    let robot1 = tls_config(&dir, &pki, "robot1", false);
    let out = tokio::process::Command::new(baton_tests::loopback::bin("baton-agent"))
        .args(["--connect", &cluster.endpoint, "--name", "robot1", "--role", "welder", "--zenoh-config"])
        .arg(&robot1)
        .output();
    let out = tokio::time::timeout(TIMEOUT, out).await.expect("in time").expect("runs");
    let said = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{said}");
    assert!(said.contains("the router does not let `robot1` serve role `welder`"), "{said}");
    // A process of robot1's own making: its token, and an answer that claims the welder's role.
    let s = session(&cluster, &dir, &pki, "robot1").await;
    let info = s.declare_queryable(keys::agent_info("robot1")).await.expect("robot1 may answer for itself");
    let _role = s.liveliness().declare_token(keys::alive_role("robot1", "welder")).await;
    let _alive = s.liveliness().declare_token(keys::alive("robot1")).await.expect("robot1 may announce itself");
    let claim = AgentInfo {
        name: "robot1".into(),
        roles: vec!["welder".into()],
        lease_ms: 2000,
        incarnation: uuid::Uuid::from_u128(77),
        held: Vec::new(),
        pending: Vec::new(),
        skills: None,
    };
    let answered = tokio::time::timeout(TIMEOUT, async {
        let q = info.recv_async().await.expect("asked who it is");
        q.reply(q.key_expr().clone(), wire::encode(&claim)).await.expect("answered");
    })
    .await;
    assert!(answered.is_ok(), "the coordinator never asked robot1 who it is");
    let anna = tls_config(&dir, &pki, "anna", false);
    let anna = anna.to_str().expect("utf-8");
    let up = tokio::time::timeout(TIMEOUT, async {
        loop {
            let out =
                cluster.baton(&["status", "--connect", &cluster.endpoint, "--zenoh-config", anna, "--json"]).await;
            let s: serde_json::Value =
                serde_json::from_str(String::from_utf8_lossy(&out.stdout).lines().next().unwrap_or("null"))
                    .unwrap_or_default();
            if let Some(a) = s["agents"].as_array().and_then(|a| a.iter().find(|a| a["name"] == "robot1")) {
                return a["roles"].clone();
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    })
    .await
    .expect("robot1 is listed");
    assert_eq!(up, serde_json::json!([]), "robot1 is taken without the role it claimed");
    drop(info);
    tokio::time::timeout(TIMEOUT, s.close()).await.ok();
    // The real robot1 and the welder: the welder's step goes to w1.
    for (name, roles) in [("robot1", vec![]), ("w1", vec!["welder"])] {
        let config = tls_config(&dir, &pki, name, false);
        cluster.agent(name, &roles, &["--zenoh-config", config.to_str().expect("utf-8")]);
        cluster.wait_for_agent_trace(name, "its start", |r| r.event == TraceEvent::AgentUp).await;
    }
    let set = cluster.baton(&["set", "--connect", &cluster.endpoint, "--zenoh-config", anna, "go=true"]).await;
    assert!(set.status.success(), "{}", String::from_utf8_lossy(&set.stderr));
    let (status, log, trace, _) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    assert!(log.contains("claims role(s) welder that the router did not let it announce"), "{log}");
    let welds: Vec<Option<&str>> = trace
        .iter()
        .filter(|r| r.event == TraceEvent::Dispatch && r.name == "Weld")
        .map(|r| r.agent.as_deref())
        .collect();
    assert_eq!(welds, [Some("w1")], "{trace:#?}");
}

/// anna's client writes `by: "plant-manager"` in its command: the run records anna, the name on the key the router
/// let her certificate ask on; a key naming anyone else is refused her (nobody answers). And `baton set` is
/// recorded with her name too.
#[tokio::test(flavor = "multi_thread")]
async fn who_sent_a_command_is_the_name_the_router_checked() {
    let (cluster, dir, pki, coordinator) = secured(|t| t).await;
    let run = run_id(&cluster, &dir, &pki).await;
    let s = session(&cluster, &dir, &pki, "anna").await;
    let hold =
        CtlRequest { command: "hold".into(), reason: "check".into(), by: "plant-manager".into(), ..Default::default() };
    let answers = |key: String| {
        let s = &s;
        let hold = &hold;
        async move {
            let replies = s.get(key).payload(wire::encode(hold)).timeout(Duration::from_secs(3)).await.expect("asked");
            let mut n = 0;
            while let Ok(r) = replies.recv_async().await {
                n += usize::from(r.result().is_ok());
            }
            n
        }
    };
    assert_eq!(answers(keys::ctl(run, "plant-manager")).await, 0, "a key naming another is refused her");
    assert_eq!(answers(keys::ctl(run, "anna")).await, 1, "her own is answered");
    let anna = tls_config(&dir, &pki, "anna", false);
    let set = cluster
        .baton(&["set", "--connect", &cluster.endpoint, "--zenoh-config", anna.to_str().expect("utf-8"), "go=false"])
        .await;
    assert!(set.status.success(), "{}", String::from_utf8_lossy(&set.stderr));
    tokio::time::timeout(TIMEOUT, s.close()).await.ok();
    coordinator.kill().await;
    let trace = read_trace(&dir.join("trace.jsonl"));
    let by: Vec<(TraceEvent, Option<&str>)> = trace
        .iter()
        .filter(|r| matches!(r.event, TraceEvent::Command | TraceEvent::CommandRefused | TraceEvent::Set))
        .map(|r| (r.event, r.by.as_deref()))
        .collect();
    assert_eq!(by, [(TraceEvent::Command, Some("anna")), (TraceEvent::Set, Some("anna"))], "{trace:#?}");
}

/// With the rules an older `baton deploy acl` wrote — no liveliness query for an agent — robot1's watch on its
/// router hears nothing and fences it. The run it joins after that starts fenced: its motion, which may move to
/// another agent under `reassign`, is not started.
#[tokio::test(flavor = "multi_thread")]
async fn a_run_joined_while_fenced_starts_its_skills_fenced() {
    let old_rules = |text: String| {
        let json = text.lines().filter(|l| !l.starts_with("//")).collect::<Vec<_>>().join("\n");
        let mut config: serde_json::Value = serde_json::from_str(&json).expect("json");
        let acl = &mut config["access_control"];
        let query = |r: &serde_json::Value| {
            r["id"].as_str().is_some_and(|id| id.starts_with("agent-robot1"))
                && r["messages"] == serde_json::json!(["liveliness_query"])
        };
        let gone: Vec<serde_json::Value> =
            acl["rules"].as_array().expect("rules").iter().filter(|r| query(r)).map(|r| r["id"].clone()).collect();
        assert_eq!(gone.len(), 1, "robot1's liveliness query, allowed now");
        acl["rules"].as_array_mut().expect("rules").retain(|r| !query(r));
        for p in acl["policies"].as_array_mut().expect("policies") {
            p["rules"].as_array_mut().expect("rules").retain(|id| !gone.contains(id));
        }
        config.to_string()
    };
    let (mut cluster, dir, pki, coordinator) = secured(old_rules).await;
    let robot1 = tls_config(&dir, &pki, "robot1", false);
    cluster.agent("robot1", &[], &["--zenoh-config", robot1.to_str().expect("utf-8"), "--lease-ms", "2000"]);
    cluster.wait_for_agent_trace("robot1", "no contact", |r| r.event == TraceEvent::ContactLost).await;
    let anna = tls_config(&dir, &pki, "anna", false);
    let set = cluster
        .baton(&["set", "--connect", &cluster.endpoint, "--zenoh-config", anna.to_str().expect("utf-8"), "go=true"])
        .await;
    assert!(set.status.success(), "{}", String::from_utf8_lossy(&set.stderr));
    let skill =
        |r: &TraceRecord| matches!(r.event, TraceEvent::SkillFault | TraceEvent::SkillDone) && r.name == "MoveIt";
    let trace = trace_once(&coordinator.trace, skill).await;
    let outcome = trace.iter().find(|r| skill(r)).expect("found");
    assert_eq!(outcome.event, TraceEvent::SkillFault, "{outcome:?}");
    assert!(
        outcome.message.as_deref().is_some_and(|m| m.starts_with("not started") && m.contains("lease fence")),
        "{outcome:?}"
    );
    coordinator.kill().await;
}
