//! `baton console` as an operator uses it: on a cell on loopback (a router, a coordinator, a robot with a motion of
//! seconds), the page and its API — the chart drawn as `baton export --svg` draws it, the run's state and legal
//! commands as `baton status` has them, a command taken or refused as `baton ctl` takes or refuses it, traced with
//! the console's identity — and the page in a real browser (Debian's Chromium through its WebDriver), which shows
//! the active step and its robot, enables exactly the legal commands, and follows a `hold` to `held`.

use std::path::PathBuf;

use baton_proto::exec::trace::TraceEvent;
use baton_tests::http::{browse, http, require_browser, Events};
use baton_tests::loopback::{bin, Cluster, Coordinator, TIMEOUT};
use tokio::io::{AsyncBufReadExt, BufReader};
use tokio::process::Command;

/// A part waits for `go`; robot r1 moves it for 3 s; then it is done.
const CHART: &str = "PROGRAM part\nVAR go : BOOL; moved : BOOL; END_VAR\nINITIAL_STEP Ready: END_STEP\n\
    TRANSITION FROM Ready TO Move := go; END_TRANSITION\nSTEP Move: {agent := 'r1'} Motion(N, moved); END_STEP\n\
    TRANSITION FROM Move TO Done := moved; END_TRANSITION\nSTEP Done: END_STEP\n\
    ACTION Motion: {skill := 'motion', ms := 3000} END_ACTION\nEND_PROGRAM\n";

/// A cell running CHART with r1, and a console on a free loopback port: (cluster, chart file, coordinator, the
/// console's process, its address).
async fn cell_with_console(text: &str) -> (Cluster, PathBuf, Coordinator, tokio::process::Child, String) {
    cell_with_console_of("part.st", text).await
}

/// `cell_with_console` with the chart in a file named `file` (`.xml` for PLCopen).
async fn cell_with_console_of(
    file: &str,
    text: &str,
) -> (Cluster, PathBuf, Coordinator, tokio::process::Child, String) {
    let mut cluster = Cluster::with_router().await;
    let chart = cluster.dir.path().join(file);
    std::fs::write(&chart, text).expect("write the chart");
    let mut coordinator = cluster.coordinator_joining(&chart, &[]);
    coordinator.wait_ready().await;
    cluster.agent("r1", &[], &[]);
    let (console, addr) = start_console(&cluster).await;
    (cluster, chart, coordinator, console, addr)
}

/// `baton console` for the cell of `cluster`, on a free loopback port: its process and its address.
async fn start_console(cluster: &Cluster) -> (tokio::process::Child, String) {
    baton_tests::http::console(&cluster.endpoint, &[]).await
}

/// Run `run`'s history on the console at `addr`, once `enough` of it is there: (event, name, by, message) each.
async fn history_until(
    addr: &str,
    run: &str,
    enough: impl Fn(&[(String, String, String, String)]) -> bool,
) -> Vec<(String, String, String, String)> {
    let mut events = Events::open(addr).await;
    loop {
        let (_, history) = http(addr, "GET", &format!("/api/runs/{run}/history"), None).await;
        let history: Vec<serde_json::Value> = serde_json::from_str(&history).expect("a history is JSON");
        let field = |e: &serde_json::Value, f: &str| e[f].as_str().unwrap_or_default().to_string();
        let entries: Vec<_> = history
            .iter()
            .map(|e| (field(e, "event"), field(e, "name"), field(e, "by"), field(e, "message")))
            .collect();
        if enough(&entries) {
            return entries;
        }
        while events.next().await.unwrap_or_else(|| panic!("the history stopped short: {entries:?}")).0 != "history" {}
    }
}

/// Follows the console's server-sent events until a state `holds`: returns it.
async fn event_until(addr: &str, holds: impl Fn(&serde_json::Value) -> bool) -> serde_json::Value {
    let mut events = Events::open(addr).await;
    while let Some((name, data)) = events.next().await {
        if name != "state" {
            continue;
        }
        let state: serde_json::Value = serde_json::from_str(&data).expect("a state is JSON");
        if holds(&state) {
            return state;
        }
    }
    panic!("the console never showed the state waited for")
}

/// Holds the part of the run that `{field: name}` names (`step` or `agent`), as `baton ctl hold --step/--agent`
/// does, through the console at `ctl_path`: the run's held list names it; then releases it, and the list is empty.
async fn hold_and_release(addr: &str, ctl_path: &str, field: &str, name: &str) {
    let body = |command: &str| serde_json::json!({"command": command, field: name}).to_string();
    let (_, held) = http(addr, "POST", ctl_path, Some(&body("hold"))).await;
    assert!(held.contains("\"ok\":true"), "{held}");
    let state = event_until(addr, |s| s["runs"][0]["held"].as_array().is_some_and(|h| !h.is_empty())).await;
    assert!(state["runs"][0]["held"][0].as_str().is_some_and(|h| h.contains(name)), "{state}");
    let (_, released) = http(addr, "POST", ctl_path, Some(&body("unhold"))).await;
    assert!(released.contains("\"ok\":true"), "{released}");
    event_until(addr, |s| s["runs"][0]["held"].as_array().is_some_and(|h| h.is_empty())).await;
}

fn run_state(state: &serde_json::Value) -> &str {
    state["runs"][0]["state"].as_str().unwrap_or_default()
}

async fn the_page_and_its_api_show_the_run_as_status_does_and_send_commands_as_ctl_does() {
    let (cluster, chart, coordinator, _console, addr) = cell_with_console(CHART).await;
    // The page: one document with everything it needs, nothing fetched from elsewhere.
    let (status, page) = http(&addr, "GET", "/", None).await;
    assert_eq!(status, 200);
    assert!(page.contains("<svg") || page.contains("EventSource"), "{page}");
    let elsewhere: Vec<&str> = page.split(['"', '\'', '(', ' ']).filter(|w| w.starts_with("http")).collect();
    assert_eq!(elsewhere, ["http://www.w3.org/2000/svg"], "the page reaches out: {elsewhere:?}");
    // The run as `baton status --json` has it.
    let state = event_until(&addr, |s| s["runs"].as_array().is_some_and(|r| r.len() == 1)).await;
    let out = cluster.baton(&["status", "--connect", &cluster.endpoint, "--json"]).await;
    let status: serde_json::Value = serde_json::from_slice(&out.stdout).expect("status JSON");
    let run = state["runs"][0]["run"].as_str().expect("a run id").to_string();
    assert_eq!(run, status["run"]);
    assert_eq!(state["runs"][0]["available"], status["available"]);
    assert!(state["connected"].as_bool().expect("connected"), "{state}");
    // Its chart, drawn as `baton export --svg` draws it.
    let (code, svg) = http(&addr, "GET", &format!("/api/runs/{run}/chart.svg"), None).await;
    assert_eq!(code, 200, "{svg}");
    let export = cluster.baton(&["export", "--svg", chart.to_str().expect("utf-8")]).await;
    assert_eq!(svg, String::from_utf8_lossy(&export.stdout), "the console draws the chart as the export does");
    let (code, _) = http(&addr, "GET", "/api/runs/not-a-run/chart.svg", None).await;
    assert_eq!(code, 400);
    // The part goes: Move runs on r1.
    let go = cluster.baton(&["set", "--connect", &cluster.endpoint, "go=true"]).await;
    assert!(go.status.success(), "{}", String::from_utf8_lossy(&go.stderr));
    let moving = |s: &serde_json::Value| {
        s["runs"][0]["active_steps"]
            .as_array()
            .is_some_and(|a| a.iter().any(|x| x["name"] == "Move" && x["agent"] == "r1"))
    };
    event_until(&addr, moving).await;
    // Why Move waits, as `baton status --why --json` says it (the agent asked for its step).
    let (code, why) = http(&addr, "GET", &format!("/api/runs/{run}/why"), None).await;
    assert_eq!(code, 200, "{why}");
    let why: serde_json::Value = serde_json::from_str(&why).expect("why JSON");
    let status_why = cluster.baton(&["status", "--connect", &cluster.endpoint, "--why", "--json"]).await;
    let status_why: serde_json::Value = serde_json::from_slice(&status_why.stdout).expect("status JSON");
    let steps = |w: &serde_json::Value| -> Vec<(String, String)> {
        w.as_array()
            .expect("a list")
            .iter()
            .map(|s| (s["step"].as_str().unwrap_or_default().into(), s["agent"].as_str().unwrap_or_default().into()))
            .collect()
    };
    assert_eq!(steps(&why), steps(&status_why["why"]), "{why}");
    assert!(why[0]["summary"].as_str().is_some_and(|s| s.contains("moved")), "{why}");
    // The step alone held, then released, as `baton ctl hold --step Move` does.
    let ctl_path = format!("/api/runs/{run}/ctl");
    hold_and_release(&addr, &ctl_path, "step", "Move").await;
    // A command that is not legal now is refused, saying what is; a legal one is taken, with its reason.
    let ctl = |body: &'static str| http(&addr, "POST", &ctl_path, Some(body));
    let (code, refused) = ctl(r#"{"command": "unhold"}"#).await;
    assert_eq!(code, 200, "{refused}");
    let refused: serde_json::Value = serde_json::from_str(&refused).expect("a reply");
    assert_eq!(refused["ok"], false);
    assert!(refused["message"].as_str().is_some_and(|m| m.contains("hold")), "{refused}");
    let (_, taken) = ctl(r#"{"command": "hold", "reason": "material late", "by": "someone-else"}"#).await;
    let taken: serde_json::Value = serde_json::from_str(&taken).expect("a reply");
    assert_eq!(taken["ok"], true, "{taken}");
    // Held once the motion has finished, as the page follows it.
    let held = event_until(&addr, |s| run_state(s) == "held").await;
    assert!(held["runs"][0]["available"].as_array().is_some_and(|a| a.contains(&"unhold".into())), "{held}");
    let (_, taken) = ctl(r#"{"command": "unhold", "reason": "material here"}"#).await;
    assert!(taken.contains("\"ok\":true"), "{taken}");
    let (status, log, trace, _) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    // The commands are traced as the console's own identity sent them, not as the request said.
    let commands: Vec<(&str, Option<&str>, Option<&str>)> = trace
        .iter()
        .filter(|r| r.event == TraceEvent::Command)
        .map(|r| (r.name.as_str(), r.by.as_deref(), r.message.as_deref()))
        .collect();
    let me = baton_tests::loopback::who_sends();
    assert_eq!(
        commands,
        [
            ("hold", Some(me.as_str()), None),
            ("unhold", Some(me.as_str()), None),
            ("hold", Some(me.as_str()), Some("material late")),
            ("unhold", Some(me.as_str()), Some("material here"))
        ],
        "{trace:#?}"
    );
}

/// The run's history — each command with who sent it and why, the states it led to — as the console heard it
/// live, and as a console that joins the run later gets it from the coordinator.
async fn the_history_lists_commands_with_who_and_why_for_a_console_that_joins_late_too() {
    let (cluster, _chart, _coordinator, _console, addr) = cell_with_console(CHART).await;
    let state = event_until(&addr, |s| s["runs"].as_array().is_some_and(|r| r.len() == 1)).await;
    let run = state["runs"][0]["run"].as_str().expect("a run id").to_string();
    let ctl_path = format!("/api/runs/{run}/ctl");
    let (_, taken) = http(&addr, "POST", &ctl_path, Some(r#"{"command": "hold", "reason": "shift change"}"#)).await;
    assert!(taken.contains("\"ok\":true"), "{taken}");
    event_until(&addr, |s| run_state(s) == "held").await;
    let (_, taken) = http(&addr, "POST", &ctl_path, Some(r#"{"command": "unhold", "reason": "crew in"}"#)).await;
    assert!(taken.contains("\"ok\":true"), "{taken}");
    let me = baton_tests::loopback::who_sends();
    let commands = |h: &[(String, String, String, String)]| -> Vec<(String, String, String)> {
        h.iter().filter(|e| e.0 == "command").map(|e| (e.1.clone(), e.2.clone(), e.3.clone())).collect()
    };
    let expected = vec![
        ("hold".to_string(), me.clone(), "shift change".to_string()),
        ("unhold".to_string(), me.clone(), "crew in".to_string()),
    ];
    let live = history_until(&addr, &run, |h| commands(h).len() >= 2).await;
    assert_eq!(commands(&live), expected, "{live:?}");
    // The states the hold went through, in order, between the two commands.
    let states: Vec<&str> = live.iter().filter(|e| e.0 == "state").map(|e| e.1.as_str()).collect();
    assert!(states.windows(2).any(|w| w == ["holding", "held"]), "{live:?}");
    // A console that starts now was not there: it asks the coordinator, and lists the same.
    let (_late, late_addr) = start_console(&cluster).await;
    let late = history_until(&late_addr, &run, |h| commands(h).len() >= 2).await;
    assert_eq!(commands(&late), expected, "{late:?}");
}

/// `baton run --console ADDR` serves the same page for its own cell (here the router it embeds): the run is
/// there, its input set through it moves the part on, and a command sent through it is taken.
async fn a_run_serves_the_console_of_its_own_cell() {
    let cluster = Cluster::new();
    let chart = cluster.dir.path().join("part.st");
    std::fs::write(&chart, CHART).expect("write the chart");
    let addr = format!("127.0.0.1:{}", baton_tests::loopback::free_port());
    let mut coordinator = cluster.coordinator(&chart, &["--console", &addr]);
    coordinator.wait_ready().await;
    let state = event_until(&addr, |s| s["runs"].as_array().is_some_and(|r| r.len() == 1)).await;
    assert_eq!(state["runs"][0]["chart"], "part");
    let run = state["runs"][0]["run"].as_str().expect("a run id").to_string();
    // Its inputs, as the chart declares them (`moved` is the motion's indicator: an action writes it), set as
    // `baton set` sets them; a refusal says why.
    let (code, inputs) = http(&addr, "GET", &format!("/api/runs/{run}/inputs"), None).await;
    assert_eq!(code, 200, "{inputs}");
    assert_eq!(
        serde_json::from_str::<serde_json::Value>(&inputs).expect("JSON"),
        serde_json::json!([{"name": "go", "type": "BOOL"}])
    );
    let set_path = format!("/api/runs/{run}/set");
    let (_, refused) = http(&addr, "POST", &set_path, Some(r#"{"name": "moved", "value": true}"#)).await;
    assert!(refused.contains("\"ok\":false"), "{refused}");
    let (_, taken) = http(&addr, "POST", &set_path, Some(r#"{"name": "go", "value": true}"#)).await;
    assert!(taken.contains("\"ok\":true"), "{taken}");
    event_until(&addr, |s| {
        s["runs"][0]["active_steps"].as_array().is_some_and(|a| a.iter().any(|x| x["name"] == "Move"))
    })
    .await;
    let (_, reply) = http(&addr, "POST", &format!("/api/runs/{run}/ctl"), Some(r#"{"command": "stop"}"#)).await;
    assert!(reply.contains("\"ok\":true"), "{reply}");
    let (status, log, _, summary) = coordinator.finish().await;
    assert_eq!(status.code(), Some(3), "stopped: {log}");
    assert_eq!(summary["state"], "stopped");
}

/// A run that serves its console ends cleanly: the console, a client of the run's embedded router, closes its
/// session before the router goes. (Torn down under a connected console, zenoh 1.10.2's router panicked in about
/// one run in six: `resource.rs:486`, `Option::unwrap()` on `None`.)
async fn a_run_with_its_console_ends_without_a_panic() {
    let cluster = Cluster::new();
    let chart = cluster.dir.path().join("quick.st");
    std::fs::write(
        &chart,
        "PROGRAM quick\nINITIAL_STEP A: END_STEP\nTRANSITION FROM A TO B := TRUE; END_TRANSITION\n\
        STEP B: END_STEP\nEND_PROGRAM\n",
    )
    .expect("write the chart");
    for round in 0..12 {
        let addr = format!("127.0.0.1:{}", baton_tests::loopback::free_port());
        let (status, log, _, _) = cluster.coordinator(&chart, &["--console", &addr]).finish().await;
        assert!(status.success() && !log.contains("panicked"), "round {round}: {status}\n{log}");
    }
}

/// An agent's branches are held and released from the page; an agent that goes is kept on the page, greyed, with
/// since when; back, it is live again.
async fn a_lost_agent_stays_listed_as_lost_until_it_is_back() {
    let (mut cluster, _chart, _coordinator, _console, addr) = cell_with_console(CHART).await;
    let listed =
        |s: &serde_json::Value| s["runs"][0]["agents"].as_array().is_some_and(|a| a.iter().any(|x| x["name"] == "r1"));
    let state = event_until(&addr, listed).await;
    // Its branches held and released, as `baton ctl hold --agent r1` does (the page's buttons by each agent).
    let ctl_path = format!("/api/runs/{}/ctl", state["runs"][0]["run"].as_str().expect("a run id"));
    hold_and_release(&addr, &ctl_path, "agent", "r1").await;
    let before = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).expect("clock").as_millis();
    cluster.kill_agent("r1").await;
    let lost = event_until(&addr, |s| s["lost_agents"].as_array().is_some_and(|l| !l.is_empty())).await;
    let entry = &lost["lost_agents"][0];
    assert_eq!(
        (entry["name"].as_str(), entry["run"].as_str()),
        (Some("r1"), lost["runs"][0]["run"].as_str()),
        "{lost}"
    );
    let since = u128::from(entry["since_unix_ms"].as_u64().expect("since"));
    assert!(since >= before, "lost at {since}, before it was killed at {before}");
    assert!(!listed(&lost), "{lost}");
    cluster.agent("r1", &[], &[]);
    let back = event_until(&addr, listed).await;
    assert_eq!(back["lost_agents"], serde_json::json!([]), "{back}");
}

async fn in_a_browser_the_chart_lights_the_running_step_and_a_click_holds_the_run() {
    require_browser();
    // Move stays active until the test releases it, however slowly the browser starts.
    let waits = CHART
        .replace("go : BOOL;", "go : BOOL; release : BOOL;")
        .replace("Done := moved;", "Done := moved AND release;");
    let (cluster, _chart, coordinator, _console, addr) = cell_with_console(&waits).await;
    let go = cluster.baton(&["set", "--connect", &cluster.endpoint, "go=true"]).await;
    assert!(go.status.success(), "{}", String::from_utf8_lossy(&go.stderr));
    event_until(&addr, |s| {
        s["runs"][0]["active_steps"].as_array().is_some_and(|a| a.iter().any(|x| x["name"] == "Move"))
    })
    .await;
    let status = cluster.baton(&["status", "--connect", &cluster.endpoint, "--json"]).await;
    let status: serde_json::Value = serde_json::from_slice(&status.stdout).expect("status JSON");
    let shot = cluster.dir.path().join("console.png");
    let lines = browse(&addr, &["hold", "Move", "hold", "held", shot.to_str().expect("utf-8")]).await;
    let shown = &lines[0]["shown"];
    // What the page shows is what `baton status` says: the active step (Move, on r1), the legal commands enabled,
    // every other one disabled, and every step of the chart drawn.
    assert_eq!(shown["active"], serde_json::json!(["Move"]), "{shown}");
    assert_eq!(shown["agents"], serde_json::json!(["Move@r1"]), "the robot holding it: {shown}");
    let legal: Vec<String> =
        status["available"].as_array().expect("available").iter().map(|c| c.as_str().expect("a name").into()).collect();
    let mut legal_sorted = legal.clone();
    legal_sorted.sort();
    assert_eq!(shown["enabled"], serde_json::json!(legal_sorted), "{shown}");
    assert_eq!(shown["all_steps"], serde_json::json!(["Done", "Move", "Ready"]));
    assert_eq!(shown["stale"], false);
    // Clicked, the step says where it runs and why it waits: its motion, on r1, as `baton status --why` says.
    let why = cluster.baton(&["status", "--connect", &cluster.endpoint, "--why", "--json"]).await;
    let why: serde_json::Value = serde_json::from_slice(&why.stdout).expect("status JSON");
    let move_why = why["why"].as_array().and_then(|w| w.iter().find(|w| w["step"] == "Move")).expect("Move's why");
    assert_eq!(move_why["agent"], "r1");
    assert!(lines[1]["where"].as_str().is_some_and(|w| w.contains("r1")), "{}", lines[1]);
    let shown_why = lines[1]["why"].as_array().expect("why lines");
    assert_eq!(shown_why.len(), 1, "{}", lines[1]);
    assert!(shown_why[0].as_str().is_some_and(|l| l.contains("Move->Done") && l.contains("release")), "{}", lines[1]);
    let after = &lines[2]["after"];
    assert_eq!(after["state"], "held", "{after}");
    assert!(after["enabled"].as_array().is_some_and(|e| e.contains(&"unhold".into())), "{after}");
    let png = std::fs::read(&shot).expect("the screenshot");
    assert!(png.starts_with(b"\x89PNG"), "not a PNG");
    let release = cluster.baton(&["set", "--connect", &cluster.endpoint, "release=true"]).await;
    assert!(release.status.success(), "{}", String::from_utf8_lossy(&release.stderr));
    let unhold = cluster.baton(&["ctl", "--connect", &cluster.endpoint, "unhold"]).await;
    assert!(unhold.status.success(), "{}", String::from_utf8_lossy(&unhold.stderr));
    let (status, log, _, _) = coordinator.finish().await;
    assert!(status.success(), "{log}");
}

/// A step past its maximum time raises an alarm; in the browser the operator shelves it with a reason, unshelves it
/// and acknowledges it with a comment: the page lists it shelved, then active again, and the trace records each
/// with the console's identity (the shelve with its reason, the acknowledgement with its comment); the run goes on
/// to its end.
async fn in_a_browser_an_alarm_is_shelved_unshelved_and_acknowledged_with_a_comment() {
    require_browser();
    let mut cluster = Cluster::with_router().await;
    let chart = cluster.dir.path().join("part.st");
    // A motion of 8 s under a limit of 0.5 s: the alarm stands while the operator shelves, unshelves and acks it.
    let text =
        CHART.replace("{agent := 'r1'}", "{agent := 'r1', max_ms := T#500ms}").replace("ms := 3000", "ms := 8000");
    std::fs::write(&chart, text).expect("write");
    let mut coordinator = cluster.coordinator_joining(&chart, &[]);
    coordinator.wait_ready().await;
    cluster.agent("r1", &[], &[]);
    let addr = format!("127.0.0.1:{}", baton_tests::loopback::free_port());
    let _console = Command::new(bin("baton"))
        .args(["console", "--connect", &cluster.endpoint, "--listen", &addr])
        .stdout(std::process::Stdio::null())
        .kill_on_drop(true)
        .spawn()
        .expect("start baton console");
    let go = cluster.baton(&["set", "--connect", &cluster.endpoint, "go=true"]).await;
    assert!(go.status.success(), "{}", String::from_utf8_lossy(&go.stderr));
    let lines = browse(&addr, &["ack", "checked the axis", "drive being replaced"]).await;
    assert_eq!(lines[0]["shown_state"], "active, unacknowledged", "{lines:?}");
    let alarm: u64 = lines[0]["alarm"].as_str().and_then(|a| a.parse().ok()).expect("an alarm id");
    let (status, log, trace, _) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    let raised =
        trace.iter().find(|r| r.event == TraceEvent::Alarm && r.id == Some(alarm)).expect("the alarm is traced");
    assert_eq!(raised.name, "Move", "{raised:?}");
    let me = baton_tests::loopback::who_sends();
    // Shelved, then unshelved, then acknowledged, each traced with who did it (and the shelve with its reason).
    let at = |event: TraceEvent| {
        trace.iter().position(|r| r.event == event && r.id == Some(alarm)).unwrap_or_else(|| panic!("no {event:?}"))
    };
    let (shelved, unshelved, acked) = (at(TraceEvent::Shelve), at(TraceEvent::Unshelve), at(TraceEvent::Ack));
    assert!(shelved < unshelved && unshelved < acked, "{trace:?}");
    let shelve = &trace[shelved];
    assert_eq!(shelve.by.as_deref(), Some(me.as_str()), "{shelve:?}");
    assert!(shelve.message.as_deref().is_some_and(|m| m.contains("drive being replaced")), "{shelve:?}");
    assert_eq!(trace[unshelved].by.as_deref(), Some(me.as_str()), "{:?}", trace[unshelved]);
    let acked = &trace[acked];
    assert_eq!((acked.by.as_deref(), acked.message.as_deref()), (Some(me.as_str()), Some("checked the axis")));
}

/// Step mode in the browser: the operator clicks `step` and sets the input `go` in the page's form; the transition
/// then waits, marked on the chart and offered as a button; a click on it lets it clear, and the run goes on.
async fn in_a_browser_step_mode_waits_for_a_confirm_clicked() {
    require_browser();
    let (cluster, _chart, coordinator, _console, addr) = cell_with_console(CHART).await;
    let lines = browse(&addr, &["confirm", "Ready->Move", "Move"]).await;
    assert_eq!(lines[1]["waiting"], serde_json::json!(["Ready->Move"]), "{lines:?}");
    assert_eq!(lines[2]["after"]["active"], serde_json::json!(["Move"]), "{lines:?}");
    // The rest of the chart, confirmed by hand as well.
    let mode = cluster.baton(&["ctl", "--connect", &cluster.endpoint, "mode", "auto"]).await;
    assert!(mode.status.success(), "{}", String::from_utf8_lossy(&mode.stderr));
    let (status, log, trace, _) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    let modes: Vec<&str> = trace.iter().filter(|r| r.event == TraceEvent::Mode).map(|r| r.name.as_str()).collect();
    assert_eq!(modes, ["step", "auto"]);
    let confirmed = trace.iter().any(|r| r.event == TraceEvent::Command && r.name == "confirm");
    assert!(confirmed, "{trace:#?}");
    let set = trace.iter().find(|r| r.event == TraceEvent::Set && r.name == "go").expect("go set");
    let me = baton_tests::loopback::who_sends();
    assert_eq!((set.message.as_deref(), set.by.as_deref()), (Some("TRUE"), Some(me.as_str())), "{set:?}");
}

/// Manual mode in the browser: the operator switches to manual, is asked for a reason before forcing a
/// transition, forces it with one, finds the running step by a part of its name (the view zooms to it) and moves
/// its token on; the page's history lists each command with the reason, and the trace has them as the console's.
async fn in_a_browser_manual_mode_forces_and_moves_with_a_reason() {
    require_browser();
    // Done leads back to Ready: the run stays for the page to show Done active.
    let looping = CHART
        .replace("go : BOOL;", "go : BOOL; again : BOOL;")
        .replace("STEP Done: END_STEP", "STEP Done: END_STEP\nTRANSITION FROM Done TO Ready := again; END_TRANSITION");
    let (cluster, _chart, coordinator, _console, addr) = cell_with_console(&looping).await;
    let lines = browse(&addr, &["manual", "Ready->Move", "mov", "Done", "jog after a jam"]).await;
    assert!(lines[0]["refused"].as_str().is_some_and(|r| r.contains("reason")), "{lines:?}");
    assert_eq!((lines[1]["found"].as_str(), lines[1]["zoomed"].as_bool()), (Some("Move"), Some(true)), "{lines:?}");
    let history = lines[2]["history"].as_array().expect("rows");
    let listed = |what: &str| history.iter().any(|r| r[1].as_str() == Some(what) && r[3] == "jog after a jam");
    assert!(listed("command force") && listed("command move"), "{lines:?}");
    assert_eq!(lines[2]["after"]["active"], serde_json::json!(["Done"]), "{lines:?}");
    let stop = cluster.baton(&["ctl", "--connect", &cluster.endpoint, "stop"]).await;
    assert!(stop.status.success(), "{}", String::from_utf8_lossy(&stop.stderr));
    let (status, log, trace, _) = coordinator.finish().await;
    assert_eq!(status.code(), Some(3), "stopped: {log}");
    let me = baton_tests::loopback::who_sends();
    let manual: Vec<(&str, Option<&str>, Option<&str>)> = trace
        .iter()
        .filter(|r| r.event == TraceEvent::Command && matches!(r.name.as_str(), "force" | "move"))
        .map(|r| (r.name.as_str(), r.by.as_deref(), r.message.as_deref()))
        .collect();
    let why = Some("jog after a jam");
    assert_eq!(manual, [("force", Some(me.as_str()), why), ("move", Some(me.as_str()), why)], "{trace:#?}");
    assert!(trace.iter().any(|r| r.event == TraceEvent::Withdraw && r.name == "Move"), "{trace:#?}");
}

/// A mixer whose batch is an action written in SFC, which fills and mixes in turn until `stop` (nobody sets it).
const MIXER: &str = "PROGRAM mixer\nVAR fills : INT; valve : BOOL; stop : BOOL; END_VAR\n\
    INITIAL_STEP Work: Batch(N); END_STEP\nTRANSITION FROM Work TO Stopped := stop; END_TRANSITION\n\
    STEP Stopped: END_STEP\n\
    ACTION Batch:\n  INITIAL_STEP Fill: CountFill(N); valve(S); END_STEP\n\
    TRANSITION FROM Fill TO Mix := Fill.T >= T#400ms; END_TRANSITION\n  STEP Mix: valve(R); END_STEP\n\
    TRANSITION FROM Mix TO Fill := Mix.T >= T#400ms; END_TRANSITION\nEND_ACTION\n\
    ACTION CountFill: fills := fills + 1; END_ACTION\nEND_PROGRAM\n";

/// An action written in SFC opens from its block on the chart as a chart of its own, in the same notation, with
/// the step its token is at lit as the run goes: one step at a time, each in turn.
async fn in_a_browser_an_action_written_in_sfc_opens_as_a_chart_with_its_token_moving() {
    require_browser();
    let (_cluster, _chart, coordinator, _console, addr) = cell_with_console(MIXER).await;
    let said = browse(&addr, &["nested", "Batch"]).await;
    let seen = &said[0];
    assert_eq!(seen["title"], "Batch", "{seen}");
    assert_eq!(seen["steps"], serde_json::json!(["Fill", "Mix"]), "{seen}");
    // The token at one step at a time (or, between two states of the page, none yet): never both.
    let lit = seen["lit"].as_array().expect("lit");
    assert!(lit.iter().all(|l| l.as_array().is_some_and(|l| l.len() <= 1)), "{seen}");
    coordinator.kill().await;
}

/// A PLCopen chart with macro steps (TC6 `macroStep`): Start, then Dose — Heat, then Settle: Calm, then Hold, held
/// by r1 — then Done once `go` is set.
const DOSING: &str = r#"<?xml version="1.0" encoding="utf-8"?>
<project xmlns="http://www.plcopen.org/xml/tc6_0201" xmlns:xhtml="http://www.w3.org/1999/xhtml">
  <fileHeader companyName="Baton tests" productName="hand-written" productVersion="1" creationDateTime="2026-12-07T12:00:00"/>
  <contentHeader name="dosing" modificationDateTime="2026-12-07T12:00:00">
    <coordinateInfo><fbd><scaling x="0" y="0"/></fbd><ld><scaling x="0" y="0"/></ld><sfc><scaling x="0" y="0"/></sfc></coordinateInfo>
  </contentHeader>
  <types><dataTypes/><pous>
    <pou name="Dosing" pouType="program">
      <interface><localVars>
        <variable name="go"><type><BOOL/></type></variable>
        <variable name="held"><type><BOOL/></type></variable>
      </localVars></interface>
      <actions>
        <action name="Hold_part"><body><ST><xhtml:p><![CDATA[{skill := 'motion', ms := 60000}]]></xhtml:p></ST></body></action>
      </actions>
      <body><SFC>
        <step localId="1" name="Start" initialStep="true"><position x="100" y="20"/><connectionPointOut formalParameter="sfc"/></step>
        <transition localId="2"><position x="100" y="60"/>
          <connectionPointIn><connection refLocalId="1"/></connectionPointIn><connectionPointOut/>
          <condition><inline name=""><ST><xhtml:p><![CDATA[TRUE]]></xhtml:p></ST></inline></condition>
        </transition>
        <macroStep localId="3" name="Dose"><position x="100" y="100"/>
          <connectionPointIn><connection refLocalId="2"/></connectionPointIn><connectionPointOut/>
          <body><SFC>
            <step localId="1" name="Heat" initialStep="true"><position x="10" y="10"/><connectionPointOut formalParameter="sfc"/></step>
            <transition localId="2"><position x="10" y="40"/>
              <connectionPointIn><connection refLocalId="1"/></connectionPointIn><connectionPointOut/>
              <condition><inline name=""><ST><xhtml:p><![CDATA[Heat.T >= T#20ms]]></xhtml:p></ST></inline></condition>
            </transition>
            <macroStep localId="3" name="Settle"><position x="10" y="70"/>
              <connectionPointIn><connection refLocalId="2"/></connectionPointIn><connectionPointOut/>
              <body><SFC>
                <step localId="1" name="Calm" initialStep="true"><position x="10" y="10"/><connectionPointOut formalParameter="sfc"/></step>
                <transition localId="2"><position x="10" y="40"/>
                  <connectionPointIn><connection refLocalId="1"/></connectionPointIn><connectionPointOut/>
                  <condition><inline name=""><ST><xhtml:p><![CDATA[Calm.T >= T#20ms]]></xhtml:p></ST></inline></condition>
                </transition>
                <step localId="3" name="Hold"><position x="10" y="70"/>
                  <documentation><xhtml:p>{agent := 'r1'}</xhtml:p></documentation>
                  <connectionPointIn><connection refLocalId="2"/></connectionPointIn>
                  <connectionPointOut formalParameter="sfc"/><connectionPointOutAction formalParameter=""/>
                </step>
                <actionBlock localId="4"><position x="80" y="70"/>
                  <connectionPointIn><connection refLocalId="3"/></connectionPointIn>
                  <action localId="0" qualifier="N"><relPosition x="0" y="0"/><reference name="Hold_part"/></action>
                </actionBlock>
              </SFC></body>
            </macroStep>
          </SFC></body>
        </macroStep>
        <transition localId="4"><position x="100" y="140"/>
          <connectionPointIn><connection refLocalId="3"/></connectionPointIn><connectionPointOut/>
          <condition><inline name=""><ST><xhtml:p><![CDATA[go]]></xhtml:p></ST></inline></condition>
        </transition>
        <step localId="5" name="Done"><position x="100" y="180"/><connectionPointIn><connection refLocalId="4"/></connectionPointIn></step>
      </SFC></body>
    </pou>
  </pous></types>
  <instances><configurations/></instances>
</project>
"#;

/// A macro step is drawn as one step (IEC 60848's box with a line across its top and bottom), lit while a step of
/// its body is, with the agent holding that step's token; a click opens its body as a chart of its own, with the
/// running step lit there, and a macro step nested in it opens the same way.
async fn in_a_browser_a_macro_step_is_one_step_that_opens_on_its_body() {
    require_browser();
    let (cluster, _chart, mut coordinator, _console, addr) = cell_with_console_of("dosing.xml", DOSING).await;
    // The page is opened once the run is in Hold, r1's (before it, Heat and Calm are the coordinator's own).
    coordinator
        .wait_for_trace("r1 holding the part in Hold", |r| r.event == TraceEvent::Dispatch && r.name == "Hold")
        .await;
    let said = browse(&addr, &["macro", "Dose", "Settle"]).await;
    let (drawn, body, inner) = (&said[0]["chart"], &said[1]["body"], &said[2]["body"]);
    assert_eq!(drawn["steps"], serde_json::json!(["Done", "Dose", "Start"]), "{said:?}");
    assert_eq!(drawn["lit"], serde_json::json!(["Dose"]), "{said:?}");
    assert_eq!(drawn["agent"], "r1", "{said:?}");
    // Dose's body, Settle in it one step; then Settle's body, opened from there.
    assert_eq!(body["steps"], serde_json::json!(["Heat", "Settle"]), "{said:?}");
    assert_eq!(body["lit"], serde_json::json!(["Settle"]), "{said:?}");
    assert_eq!(body["title"], "Macro step Dose", "{said:?}");
    // Selected, the macro step is where the step of its body that is active is.
    assert!(body["where"].as_str().is_some_and(|w| w.starts_with("active, on r1")), "{said:?}");
    assert_eq!(inner["steps"], serde_json::json!(["Calm", "Hold"]), "{said:?}");
    assert_eq!(inner["lit"], serde_json::json!(["Hold"]), "{said:?}");
    assert_eq!(inner["title"], "Macro step Settle", "{said:?}");
    // The API: the body of a macro step, and no body for a name that is none.
    let status = cluster.status_json(&[]).await.expect("the run's status");
    let run = status["run"].as_str().expect("the run's id");
    let (code, svg) = http(&addr, "GET", &format!("/api/runs/{run}/macro/Dose"), None).await;
    assert_eq!(code, 200, "{svg}");
    assert!(svg.contains("data-step=\"Settle\"") && !svg.contains("data-step=\"Done\""), "{svg}");
    assert_eq!(http(&addr, "GET", &format!("/api/runs/{run}/macro/Heat"), None).await.0, 404);
    coordinator.kill().await;
}

/// The demo cell's chart (`examples/cell.st`) with motions of seconds — each pick, assembly, inspection and rework
/// ten times as long — and robot2's pick supervised at 4.5 s of its 5 s motion, so that it overruns.
fn demo_cell_of_seconds() -> String {
    let text = std::fs::read_to_string(baton_tests::loopback::repo("examples/cell.st")).expect("the demo chart");
    let slow = ["ms := 400", "ms := 500", "ms := 300", "ms := 100", "ms := 200"]
        .iter()
        .fold(text, |t, ms| t.replace(ms, &format!("{ms}0")))
        .replace("{agent := 'robot2'}", "{agent := 'robot2', max_ms := T#4500ms}");
    assert!(slow.contains("ms := 5000") && slow.contains("max_ms := T#4500ms"), "the demo chart changed: {slow}");
    slow
}

/// The next line the browser script printed, as JSON.
async fn said_next(lines: &mut tokio::io::Lines<BufReader<tokio::process::ChildStdout>>) -> serde_json::Value {
    let line = tokio::time::timeout(TIMEOUT * 2, lines.next_line()).await.expect("the browser said on in time");
    let line = line.expect("read").expect("the browser script stopped early (its error is above)");
    serde_json::from_str(&line).expect("JSON")
}

/// The demo cell, operated in the browser as an operator does: the page lights the two picks with their robots as
/// `baton status` has them and enables exactly the legal commands; a click on hold shows holding, then held once the
/// picks' motions have finished; unhold; robot2's pick overruns and the alarm is acknowledged with a comment; robot1
/// is killed and shows as lost. The screenshot is the book's (`BATON_SCREENSHOTS=1` writes it there).
async fn in_a_browser_the_demo_cell_is_held_its_alarm_acknowledged_and_a_lost_robot_shown() {
    require_browser();
    let mut cluster = Cluster::with_router().await;
    let chart = cluster.dir.path().join("cell.st");
    std::fs::write(&chart, demo_cell_of_seconds()).expect("write the chart");
    let serve = format!("serve:127.0.0.1:{}", baton_tests::loopback::free_port());
    let mut coordinator = cluster.coordinator_joining(&chart, &["--rerun", &serve]);
    coordinator.wait_ready().await;
    cluster.agent("robot1", &[], &[]);
    cluster.agent("robot2", &["assembler"], &[]);
    let (_console, addr) = start_console(&cluster).await;
    let shot = cluster.dir.path().join("console.png");
    let comment = "gripper checked, cycle time ok";
    let mut script = Command::new("python3")
        .arg(baton_tests::loopback::repo("tests/scripts/console_browser.py"))
        .args([&format!("http://{addr}/"), "demo", shot.to_str().expect("utf-8"), comment])
        .stdout(std::process::Stdio::piped())
        .kill_on_drop(true)
        .spawn()
        .expect("python3 runs");
    let mut lines = BufReader::new(script.stdout.take().expect("piped")).lines();
    // What the page shows while both robots pick is what `baton status` says (each pick takes seconds).
    let first = said_next(&mut lines).await;
    let shown = first["shown"].clone();
    let status = cluster.baton(&["status", "--connect", &cluster.endpoint, "--json"]).await;
    let status: serde_json::Value = serde_json::from_slice(&status.stdout).expect("status JSON");
    // The chart's variables as `baton status` has them (those that cannot change while both robots pick compared).
    let values = status["values"].as_array().expect("values");
    let page = first["values"].as_object().expect("the page's values");
    assert_eq!(page.keys().collect::<Vec<_>>().len(), values.len(), "{first} {status}");
    for v in values {
        let name = v["name"].as_str().expect("a name");
        assert!(page.contains_key(name), "{name}: {first}");
        if ["parts", "done"].contains(&name) {
            assert_eq!(page[name], v["value"], "{name}: {first} {status}");
        }
    }
    // A browser without WebGL (this one has no GPU at all) is told so where the Rerun timeline would be; the rest of
    // the page works on, as the rest of this test shows.
    assert_eq!(first["timeline"][0], "unavailable", "{first}");
    assert!(first["timeline"][1].as_str().is_some_and(|t| t.contains("WebGL")), "{first}");
    let steps = status["active_steps"].as_array().expect("active steps");
    let mut names: Vec<&str> = steps.iter().filter_map(|s| s["name"].as_str()).collect();
    names.sort();
    let mut agents: Vec<String> =
        steps.iter().filter_map(|s| Some(format!("{}@{}", s["name"].as_str()?, s["agent"].as_str()?))).collect();
    agents.sort();
    assert_eq!(names, ["Pick1", "Pick2"], "{status}");
    assert_eq!(shown["active"], serde_json::json!(names), "{shown}");
    assert_eq!(shown["agents"], serde_json::json!(agents), "{shown}");
    let mut legal: Vec<&str> =
        status["available"].as_array().expect("legal").iter().filter_map(|c| c.as_str()).collect();
    legal.sort();
    assert_eq!(shown["enabled"], serde_json::json!(legal), "{shown}");
    assert!(shown["disabled"].as_array().is_some_and(|d| d.contains(&"unhold".into())), "{shown}");
    // Held: holding first, held once the motions finished; then unhold is legal and hold is not.
    let held = said_next(&mut lines).await;
    let states: Vec<&str> = held["states"].as_array().expect("states").iter().filter_map(|s| s.as_str()).collect();
    assert_eq!(states.first().copied(), Some("holding"), "{held}");
    assert_eq!(states.last().copied(), Some("held"), "{held}");
    assert!(held["held"]["enabled"].as_array().is_some_and(|e| e.contains(&"unhold".into())), "{held}");
    assert!(held["held"]["disabled"].as_array().is_some_and(|d| d.contains(&"hold".into())), "{held}");
    let alarm = said_next(&mut lines).await;
    assert_eq!(alarm["alarm"][1], "Pick2", "the overrun's source: {alarm}");
    assert_eq!(alarm["alarm"][2], "active, unacknowledged", "{alarm}");
    // Pick2's time ran past its 4.5 s limit below its box, marked; Pick1, unsupervised, was never marked.
    let times = &alarm["times"];
    assert_eq!(times["Pick2"]["over"], true, "{alarm}");
    assert!(times["Pick2"]["max_ms"].as_u64().is_some_and(|ms| ms > 4500), "{alarm}");
    assert!(times["Pick2"]["text"].as_str().is_some_and(|t| t.ends_with("≤ 4.5 s")), "{alarm}");
    assert_eq!(times["Pick1"]["over"], false, "{alarm}");
    assert_eq!(said_next(&mut lines).await["kill"], "robot1");
    cluster.kill_agent("robot1").await;
    let lost = said_next(&mut lines).await;
    assert!(lost["lost"].as_str().is_some_and(|l| l.contains("robot1") && l.contains("lost")), "{lost}");
    let ended = tokio::time::timeout(TIMEOUT, script.wait()).await.expect("the browser closed").expect("wait");
    assert!(ended.success(), "the browser script failed (its error is above)");
    // The trace: the hold waited for the motions, and the
    // acknowledgement carries the comment and the console's identity.
    let me = baton_tests::loopback::who_sends();
    let trace = coordinator.wait_for_trace("the acknowledgement", |r| r.event == TraceEvent::Ack).await;
    let at = |e: TraceEvent, name: &str| trace.iter().find(|r| r.event == e && r.name == name).map(|r| r.t_ms);
    let (holding, held) =
        (at(TraceEvent::State, "holding").expect("holding"), at(TraceEvent::State, "held").expect("held"));
    // Both picks' motions ran to their end while holding, and only then was the run held.
    let done_while_holding = |action: &str| {
        trace.iter().any(|r| r.event == TraceEvent::SkillDone && r.name == action && (holding..=held).contains(&r.t_ms))
    };
    assert!(
        done_while_holding("PickPart1") && done_while_holding("PickPart2"),
        "holding {holding}, held {held}: {trace:#?}"
    );
    let ack = trace.iter().find(|r| r.event == TraceEvent::Ack).expect("acknowledged");
    assert_eq!(
        (ack.by.as_deref(), ack.message.as_deref(), ack.name.as_str()),
        (Some(me.as_str()), Some(comment), "Pick2")
    );
    let png = std::fs::read(&shot).expect("the screenshot");
    assert!(png.starts_with(b"\x89PNG"), "not a PNG");
    if std::env::var_os("BATON_SCREENSHOTS").is_some() {
        std::fs::write(baton_tests::loopback::repo("docs/book/src/console.png"), &png).expect("the book's picture");
    }
    coordinator.kill().await;
}

/// `baton bench --console-only` as the benchmarks chapter runs it (with 4 agents here): it starts the console and
/// Chromium itself and reports every figure it promises. What the figures are is measured, not judged, here: the
/// chapter has them, from a release build.
async fn baton_bench_times_the_console_in_chromium() {
    require_browser();
    let bench = Command::new(bin("baton"))
        .args(["bench", "--console-only", "--console-agents", "4", "--json"])
        .kill_on_drop(true)
        .output();
    let out = tokio::time::timeout(TIMEOUT * 12, bench).await.expect("the bench in time").expect("baton runs");
    let said = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{said}");
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).expect("JSON");
    let console = &report["console"];
    assert_eq!(console["steps"], 1000, "{report}");
    let point = &console["latency"][0];
    assert_eq!(point["agents"], 4, "{report}");
    // Half the measured steps at least: those lit before the page showed the chart are left out.
    assert!(point["samples"].as_u64().is_some_and(|n| (75..=150).contains(&n)), "{report}");
    let (median, p99) = (point["event_to_dom_median_ms"].as_f64(), point["event_to_dom_p99_ms"].as_f64());
    assert!(median.zip(p99).is_some_and(|(m, p)| 0.0 <= m && m <= p), "{report}");
    assert!(point["first_render_ms"].as_f64().is_some_and(|t| t > 0.0), "{report}");
    assert_eq!(console["runs"], 16, "{report}");
    assert!(console["memory_mib"].as_f64().is_some_and(|m| m > 1.0), "{report}");
    // Only phase 13 ran.
    assert!(report.get("token_round_trip").is_none() && report.get("scale").is_none(), "{report}");
}

baton_tests::harness_main!(
    tokio the_history_lists_commands_with_who_and_why_for_a_console_that_joins_late_too,
    tokio the_page_and_its_api_show_the_run_as_status_does_and_send_commands_as_ctl_does,
    tokio a_run_serves_the_console_of_its_own_cell,
    tokio a_run_with_its_console_ends_without_a_panic,
    tokio a_lost_agent_stays_listed_as_lost_until_it_is_back,
    tokio in_a_browser_the_chart_lights_the_running_step_and_a_click_holds_the_run,
    tokio in_a_browser_an_alarm_is_shelved_unshelved_and_acknowledged_with_a_comment,
    tokio in_a_browser_step_mode_waits_for_a_confirm_clicked,
    tokio in_a_browser_manual_mode_forces_and_moves_with_a_reason,
    tokio in_a_browser_the_demo_cell_is_held_its_alarm_acknowledged_and_a_lost_robot_shown,
    tokio in_a_browser_an_action_written_in_sfc_opens_as_a_chart_with_its_token_moving,
    tokio in_a_browser_a_macro_step_is_one_step_that_opens_on_its_body,
    tokio baton_bench_times_the_console_in_chromium,
);
