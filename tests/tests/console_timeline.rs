//! The Rerun timeline in the operator console's page, in a real browser with WebGL drawn in software: Rerun's own
//! web viewer (the 0.36.3 wasm the console serves from its origin) opens the run's recording live from the
//! coordinator (`--rerun serve`), a click on a history entry moves its time cursor to that entry's time, a click on
//! a step in the viewer (its node in the chart graph, or its row of the steps view) selects it on the chart, a finished run's recording opens from the console's
//! folder (`--recordings`), and nothing is fetched from beyond the cell. The book's picture of the timeline is made
//! here (`BATON_SCREENSHOTS=1` writes it).

use baton_tests::http::{browse_for, require_browser};
use baton_tests::loopback::{free_port, Cluster, TIMEOUT};

/// A part moved by r1 for a second, then waiting for `go`, which nobody sets: the run stays, for the page to
/// follow.
const CHART: &str = "PROGRAM part\nVAR go : BOOL; moved : BOOL; END_VAR\nINITIAL_STEP Start: END_STEP\n\
    TRANSITION FROM Start TO Move := TRUE; END_TRANSITION\nSTEP Move: {agent := 'r1'} Motion(N, moved); END_STEP\n\
    TRANSITION FROM Move TO Waiting := moved; END_TRANSITION\nSTEP Waiting: END_STEP\n\
    TRANSITION FROM Waiting TO Done := go; END_TRANSITION\nSTEP Done: END_STEP\n\
    ACTION Motion: {skill := 'motion', ms := 1000} END_ACTION\nEND_PROGRAM\n";

/// CHART's steps, in its order.
const STEPS: [&str; 4] = ["Start", "Move", "Waiting", "Done"];

/// A chart the coordinator runs alone, to its end in a few cycles: a finished run's recording.
const FINISHED: &str = "PROGRAM counted\nVAR n : INT; END_VAR\nINITIAL_STEP Count: Add(N); END_STEP\n\
    TRANSITION FROM Count TO Done := n >= 3; END_TRANSITION\nSTEP Done: END_STEP\n\
    ACTION Add: n := n + 1; END_ACTION\nEND_PROGRAM\n";

fn unix_ms() -> f64 {
    std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).expect("after 1970").as_millis() as f64
}

async fn the_timeline_follows_the_run_live_moves_to_a_history_entry_and_selects_steps_on_the_chart() {
    require_browser();
    let mut cluster = Cluster::with_router().await;
    // A finished run's recording, for the console's folder.
    let recordings = cluster.dir.path().join("recordings");
    std::fs::create_dir(&recordings).expect("a folder");
    let finished = cluster.dir.path().join("counted.st");
    std::fs::write(&finished, FINISHED).expect("write the chart");
    let saved = recordings.join("counted.rrd");
    let sink = format!("save:{}", saved.display());
    let (status, log, _, summary) = cluster.coordinator_joining(&finished, &["--rerun", &sink]).finish().await;
    assert!(status.success(), "{log}");
    // The recording is named by the run's id (Rerun's recording id, the id's 32 hex digits).
    let finished_run = summary["run"].as_str().expect("the run's id").replace('-', "");
    // The live run, its recording served for the page.
    let chart = cluster.dir.path().join("part.st");
    std::fs::write(&chart, CHART).expect("write the chart");
    let serve = format!("serve:127.0.0.1:{}", free_port());
    let started = unix_ms();
    let mut coordinator = cluster.coordinator_joining(&chart, &["--rerun", &serve]);
    coordinator.wait_ready().await;
    cluster.agent("r1", &[], &[]);
    coordinator.wait_for_trace("the part waiting", |r| r.name == "Waiting").await;
    let status = cluster.baton(&["status", "--connect", &cluster.endpoint, "--json"]).await;
    let status: serde_json::Value = serde_json::from_slice(&status.stdout).expect("status JSON");
    let run = status["run"].as_str().expect("the run's id").to_string();
    let recording_id = run.replace('-', "");
    assert_eq!(status["rerun"], format!("rerun+http://{}/proxy", &serve["serve:".len()..]), "{status}");
    let folder = recordings.to_str().expect("utf-8");
    let (_console, addr) = baton_tests::http::console(&cluster.endpoint, &["--recordings", folder]).await;

    let shot = cluster.dir.path().join("timeline.png");
    let shot_path = shot.to_str().expect("utf-8");
    let said = browse_for(&addr, &["timeline", &STEPS.join(","), "counted.rrd", shot_path], TIMEOUT * 8).await;
    let said =
        |key: &str| said.iter().find_map(|l| l.get(key).cloned()).unwrap_or_else(|| panic!("no {key}: {said:?}"));
    // Rerun's viewer has this run's recording open, live, on the wall-clock timeline, from the run's start on.
    let viewer = said("viewer");
    assert!(viewer["recording"].as_str().is_some_and(|r| r.contains(&recording_id)), "{viewer}");
    let range = &viewer["range"];
    assert!(range["min"].as_f64().is_some_and(|t| t >= started - 1000.0 && t <= unix_ms()), "{viewer}");
    // A click on the oldest history entry puts the cursor at its time, which the recording holds.
    let sought = said("sought");
    let entry = sought["entry"].as_f64().expect("the entry's time");
    assert_eq!(sought["viewer"]["timeline"], "wall", "{sought}");
    // (Rerun keeps the time in nanoseconds as a float: a part of a millisecond is rounding.)
    assert!(sought["viewer"]["time"].as_f64().is_some_and(|t| (t - entry).abs() < 0.5), "{sought}");
    let range = &sought["viewer"]["range"];
    assert!(range["min"].as_f64() <= Some(entry) && Some(entry) <= range["max"].as_f64(), "{sought}");
    assert_eq!(sought["row"], true, "the entry is marked: {sought}");
    // Real clicks on the viewer, and the events Rerun's viewer itself sent for them.
    let clicked = said("clicked");
    let clicked = clicked.as_array().expect("clicks");
    let item = |click: &serde_json::Value| click["event"]["items"][0].clone();
    // Down the chart view: the graph's nodes, one after the other as the chart draws them from top to bottom
    // (the recording logs the steps in the chart's order, then the transitions: t0 Start→Move is node 4).
    let mut nodes: Vec<u64> = clicked
        .iter()
        .filter(|c| item(c)["entity_path"] == "/sfc/graph")
        .filter_map(|c| item(c)["instance_id"].as_u64())
        .collect();
    nodes.dedup();
    assert_eq!(nodes, [0, 4, 1, 5, 2, 6, 3], "Start, t0, Move, t1, Waiting, t2, Done: {clicked:?}");
    // Every click that selected a step — its node in the graph or its own timeline — selected it alone on the
    // chart.
    let mut timelines = std::collections::BTreeSet::new();
    for click in clicked {
        let item = item(click);
        let path = item["entity_path"].as_str().unwrap_or_default();
        let step = match (path.strip_prefix("/sfc/steps/"), item["instance_id"].as_u64()) {
            (Some(step), _) => {
                timelines.insert(step.to_string());
                Some(step)
            }
            (None, Some(node)) if path == "/sfc/graph" => STEPS.get(node as usize).copied(),
            _ => None,
        };
        if let Some(step) = step {
            assert_eq!(click["selected"], serde_json::json!([step]), "{click}");
        }
    }
    // Across the steps view: the timelines of the steps the run went through.
    assert!(["Start", "Move", "Waiting"].iter().all(|s| timelines.contains(*s)), "{timelines:?}");
    // The finished run's recording, opened from the console's folder.
    let recording = said("recording");
    assert!(recording["recording"].as_str().is_some_and(|r| r.contains(&finished_run)), "{recording}");
    // The page and the viewer fetched from the console and the coordinator's recording server only.
    let origins = said("origins");
    let origins: Vec<&str> = origins.as_array().expect("origins").iter().filter_map(|o| o.as_str()).collect();
    assert!(!origins.is_empty() && origins.iter().all(|o| o.starts_with("http://127.0.0.1:")), "{origins:?}");
    let png = std::fs::read(&shot).expect("the screenshot");
    assert!(png.starts_with(b"\x89PNG"), "not a PNG");
    if std::env::var_os("BATON_SCREENSHOTS").is_some() {
        std::fs::write(baton_tests::loopback::repo("docs/book/src/console-timeline.png"), &png).expect("the picture");
    }
    coordinator.kill().await;
}

baton_tests::harness_main!(tokio the_timeline_follows_the_run_live_moves_to_a_history_entry_and_selects_steps_on_the_chart,);
