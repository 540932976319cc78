//! Who may do what at `baton console`, as a deployment sets it up: beyond loopback it refuses to start without TLS
//! and users; with them (the certificates of `baton deploy certs`, the users of `baton deploy users`) it serves
//! HTTPS only, lets nobody in without a login, lets each role do its part — a viewer looks, an operator operates,
//! maintenance also switches to manual mode — refuses the rest with 403, and traces logins and refusals; the
//! coordinator records each command as the user's via the console. In a browser, a viewer finds no command button.

use std::path::Path;

use baton_proto::exec::trace::TraceEvent;
use baton_tests::http::{browse, require_browser, Client};
use baton_tests::loopback::{bin, read_trace, Cluster, TIMEOUT};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::process::Command;

/// A gate opens when `open` is set; the run stays, for the users to operate.
const CHART: &str = "PROGRAM gate\nVAR open : BOOL; END_VAR\nINITIAL_STEP Closed: END_STEP\n\
    TRANSITION FROM Closed TO Opened := open; END_TRANSITION\nSTEP Opened: END_STEP\n\
    TRANSITION FROM Opened TO Closed := NOT open; END_TRANSITION\nEND_PROGRAM\n";

/// `baton deploy users FILE anna=operator bob=viewer carl=maintenance`: each user's password, as printed.
async fn deploy_users(cluster: &Cluster, file: &Path) -> std::collections::BTreeMap<String, String> {
    let out = cluster
        .baton(&["deploy", "users", file.to_str().expect("utf-8"), "anna=operator", "bob=viewer", "carl=maintenance"])
        .await;
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| {
            let (who, password) = l.split_once("): ")?;
            Some((who.split(" (").next()?.to_string(), password.to_string()))
        })
        .collect()
}

/// `baton console` with `args` for the cell of `cluster`, on a free loopback port: its process and its address.
async fn console(cluster: &Cluster, args: &[&str]) -> (tokio::process::Child, String) {
    baton_tests::http::console(&cluster.endpoint, args).await
}

async fn login(client: &mut Client, user: &str, password: &str) -> (u16, String) {
    let body = serde_json::json!({"user": user, "password": password}).to_string();
    client.send("POST", "/api/login", Some(&body)).await
}

async fn beyond_loopback_the_console_needs_tls_and_users() {
    let out = Command::new(bin("baton"))
        .args(["console", "--connect", "tcp/127.0.0.1:1", "--listen", "0.0.0.0:0"])
        .output()
        .await
        .expect("baton runs");
    let said = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{said}");
    assert!(said.contains("--tls-cert") && said.contains("--users"), "{said}");
}

async fn over_tls_each_user_may_do_what_their_role_allows() {
    let cluster = Cluster::with_router().await;
    let dir = cluster.dir.path().to_path_buf();
    let chart = dir.join("gate.st");
    std::fs::write(&chart, CHART).expect("write the chart");
    let mut coordinator = cluster.coordinator_joining(&chart, &[]);
    coordinator.wait_ready().await;
    let pki = dir.join("pki");
    let ca_dir = pki.to_str().expect("utf-8");
    let certs = cluster.baton(&["deploy", "certs", "--ca", ca_dir, "console", "--san", "127.0.0.1"]).await;
    assert!(certs.status.success(), "{}", String::from_utf8_lossy(&certs.stderr));
    let users = dir.join("users.json");
    let passwords = deploy_users(&cluster, &users).await;
    let trace = dir.join("console.jsonl");
    let file = |f: &str| pki.join(f).to_str().expect("utf-8").to_string();
    let (_console, addr) = console(
        &cluster,
        &[
            "--tls-cert",
            &file("console.pem"),
            "--tls-key",
            &file("console.key"),
            "--users",
            users.to_str().expect("utf-8"),
            "--trace",
            trace.to_str().expect("utf-8"),
        ],
    )
    .await;
    // HTTPS only: a plain request gets no HTTP answer.
    let mut plain = tokio::net::TcpStream::connect(&addr).await.expect("connect");
    plain.write_all(b"GET /api/state HTTP/1.1\r\nHost: x\r\n\r\n").await.expect("send");
    let mut answer = Vec::new();
    let _ = tokio::time::timeout(TIMEOUT, plain.read_to_end(&mut answer)).await.expect("closed in time");
    assert!(!answer.starts_with(b"HTTP/"), "{}", String::from_utf8_lossy(&answer));
    // Over TLS, with the cell's CA: the page, but nothing of the cell without a login.
    let ca = pki.join("ca.pem");
    let mut nobody = Client::tls(&addr, &ca);
    assert_eq!(nobody.send("GET", "/", None).await.0, 200);
    assert_eq!(nobody.send("GET", "/api/state", None).await.0, 401);
    assert_eq!(nobody.send("GET", "/api/events", None).await.0, 401);
    assert_eq!(login(&mut nobody, "anna", &passwords["bob"]).await.0, 401, "anna with bob's password");
    assert_eq!(nobody.send("GET", "/api/state", None).await.0, 401);
    // bob looks, and may not operate.
    let mut bob = Client::tls(&addr, &ca);
    let (code, me) = login(&mut bob, "bob", &passwords["bob"]).await;
    assert_eq!(code, 200, "{me}");
    let (code, state) = bob.send("GET", "/api/state", None).await;
    assert_eq!(code, 200, "{state}");
    let state: serde_json::Value = serde_json::from_str(&state).expect("JSON");
    let run = state["runs"][0]["run"].as_str().expect("the run").to_string();
    let ctl = format!("/api/runs/{run}/ctl");
    let (code, refused) = bob.send("POST", &ctl, Some(r#"{"command": "hold"}"#)).await;
    assert_eq!((code, refused.contains("bob is viewer")), (403, true), "{refused}");
    let set = format!("/api/runs/{run}/set");
    assert_eq!(bob.send("POST", &set, Some(r#"{"name": "open", "value": true}"#)).await.0, 403);
    // anna operates, and may not switch to manual mode.
    let mut anna = Client::tls(&addr, &ca);
    assert_eq!(login(&mut anna, "anna", &passwords["anna"]).await.0, 200);
    let (code, taken) = anna.send("POST", &ctl, Some(r#"{"command": "hold", "reason": "door check"}"#)).await;
    assert!(code == 200 && taken.contains("\"ok\":true"), "{taken}");
    let (code, refused) = anna.send("POST", &ctl, Some(r#"{"command": "mode", "target": "manual"}"#)).await;
    assert_eq!((code, refused.contains("needs maintenance")), (403, true), "{refused}");
    let (_, taken) = anna.send("POST", &ctl, Some(r#"{"command": "unhold"}"#)).await;
    assert!(taken.contains("\"ok\":true"), "{taken}");
    // carl does.
    let mut carl = Client::tls(&addr, &ca);
    assert_eq!(login(&mut carl, "carl", &passwords["carl"]).await.0, 200);
    let (_, taken) = carl.send("POST", &ctl, Some(r#"{"command": "mode", "target": "manual", "reason": "jog"}"#)).await;
    assert!(taken.contains("\"ok\":true"), "{taken}");
    // Logged out, carl's cookie opens nothing.
    assert_eq!(carl.send("POST", "/api/logout", None).await.0, 204);
    assert_eq!(carl.send("GET", "/api/state", None).await.0, 401);
    // Five wrong passwords, and the right one waits.
    for _ in 0..5 {
        assert_eq!(login(&mut nobody, "bob", "guess").await.0, 401);
    }
    let (code, why) = login(&mut nobody, "bob", &passwords["bob"]).await;
    assert_eq!(code, 429, "{why}");
    // The coordinator records each command as the user's, via the console's identity.
    let me = baton_tests::loopback::who_sends();
    let trace_of_run = coordinator.wait_for_trace("carl's mode", |r| r.event == TraceEvent::Mode).await;
    let commands: Vec<(&str, Option<&str>)> = trace_of_run
        .iter()
        .filter(|r| matches!(r.event, TraceEvent::Command | TraceEvent::CommandRefused))
        .map(|r| (r.name.as_str(), r.by.as_deref()))
        .collect();
    let via = |user: &str| format!("{user} via {me}");
    assert_eq!(
        commands,
        [
            ("hold", Some(via("anna").as_str())),
            ("unhold", Some(via("anna").as_str())),
            ("mode", Some(via("carl").as_str()))
        ]
    );
    // The console's own trace: logins, the refused one, each command refused for a role, with who.
    let console_trace = read_trace(&trace);
    let seen: Vec<(TraceEvent, &str, Option<&str>)> =
        console_trace.iter().map(|r| (r.event, r.name.as_str(), r.by.as_deref())).collect();
    let (bob_via, anna_via) = (via("bob"), via("anna"));
    for expected in [
        (TraceEvent::LoginRefused, "anna", None),
        (TraceEvent::Login, "bob", None),
        (TraceEvent::CommandRefused, "hold", Some(bob_via.as_str())),
        (TraceEvent::CommandRefused, "set", Some(bob_via.as_str())),
        (TraceEvent::CommandRefused, "mode", Some(anna_via.as_str())),
        (TraceEvent::Login, "carl", None),
    ] {
        assert!(seen.contains(&expected), "{expected:?} not in {seen:?}");
    }
    assert_eq!(seen.iter().filter(|(e, n, _)| *e == TraceEvent::LoginRefused && *n == "bob").count(), 6, "{seen:?}");
}

/// In a browser: bob, a viewer, logs in through the page's form and finds no command button; anna, an operator,
/// finds the run's commands, and the manual mode button disabled, saying it is maintenance's.
async fn in_a_browser_a_viewer_finds_no_command_button() {
    require_browser();
    let cluster = Cluster::with_router().await;
    let chart = cluster.dir.path().join("gate.st");
    std::fs::write(&chart, CHART).expect("write the chart");
    let mut coordinator = cluster.coordinator_joining(&chart, &[]);
    coordinator.wait_ready().await;
    let users = cluster.dir.path().join("users.json");
    let passwords = deploy_users(&cluster, &users).await;
    // On loopback without TLS, users may still be asked to log in.
    let (_console, addr) = console(&cluster, &["--users", users.to_str().expect("utf-8")]).await;
    let seen_as = |user: &'static str| {
        let (addr, password) = (addr.clone(), passwords[user].clone());
        async move { browse(&addr, &["login", user, &password]).await.remove(0) }
    };
    let bob = seen_as("bob").await;
    assert_eq!(bob["visible"], serde_json::json!([]), "{bob}");
    assert_eq!(bob["who"], "bob (viewer)");
    let anna = seen_as("anna").await;
    let visible: Vec<&str> = anna["visible"].as_array().expect("buttons").iter().filter_map(|b| b.as_str()).collect();
    assert!(visible.contains(&"hold") && visible.contains(&"stop"), "{anna}");
    assert_eq!(anna["manual"]["disabled"], true, "{anna}");
    assert!(anna["manual"]["title"].as_str().is_some_and(|t| t.contains("maintenance")), "{anna}");
}

baton_tests::harness_main!(
    tokio beyond_loopback_the_console_needs_tls_and_users,
    tokio over_tls_each_user_may_do_what_their_role_allows,
    tokio in_a_browser_a_viewer_finds_no_command_button,
);
