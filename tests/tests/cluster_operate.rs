//! Operating a cell with real processes on loopback: `baton ctl hold`, `unhold`, `hold --agent`, `abort`, and an
//! interrupt that stops the run — each checked against what the robots (shell skills that leave marks in files)
//! actually did.

use std::path::{Path, PathBuf};
use std::time::Duration;

use baton_proto::exec::trace::{TraceEvent, TraceRecord};
use baton_tests::invariants::tokens_out;
use baton_tests::loopback::{
    self, check_trace_invariants, check_trace_invariants_with_tokens_out, Cluster, Coordinator, TIMEOUT,
};

/// Two robots, each with two shell motions in sequence that write `start NAME` and `end NAME` to `marks`; the
/// branches meet at `Done`. r1's first motion takes `first_s` seconds.
fn cell(dir: &Path, first_s: f64) -> PathBuf {
    let m = dir.join("marks");
    let m = m.display();
    cell_with(dir, &format!("sleep {first_s}; echo end MoveA1 >> {m}"))
}

/// The cell that `chart` writes in the cluster's folder, running: a coordinator (with `args`, once it has begun
/// its run) and the robots r1 (with `r1_extra`) and r2, both allowed shell motions.
async fn running_cell(
    chart: impl FnOnce(&Path) -> PathBuf,
    args: &[&str],
    r1_extra: &[&str],
) -> (Cluster, PathBuf, Coordinator) {
    let mut cluster = Cluster::new();
    let chart = chart(cluster.dir.path());
    let mut coordinator = cluster.coordinator(&chart, args);
    coordinator.wait_ready().await;
    let r1: Vec<&str> = ["--allow-shell"].into_iter().chain(r1_extra.iter().copied()).collect();
    cluster.agent("r1", &[], &r1);
    cluster.agent("r2", &[], &["--allow-shell"]);
    (cluster, chart, coordinator)
}

/// The cell, r1's first motion doing `first` after its start mark.
fn cell_with(dir: &Path, first: &str) -> PathBuf {
    let marks = dir.join("marks");
    let m = marks.display();
    let motion = |name: &str, secs: f64| {
        let body = if name == "MoveA1" { first.to_string() } else { format!("sleep {secs}; echo end {name} >> {m}") };
        format!("ACTION {name}: {{skill := 'shell', cmd := 'echo start {name} >> {m}; {body}'}} END_ACTION\n")
    };
    let text = format!(
        "PROGRAM cell\nVAR a1, a2, b1, b2 : BOOL; END_VAR\n\
         INITIAL_STEP Idle: END_STEP\nTRANSITION FROM Idle TO (A1, B1) := TRUE; END_TRANSITION\n\
         STEP A1: {{agent := 'r1'}} MoveA1(N, a1); END_STEP\nTRANSITION FROM A1 TO A2 := a1; END_TRANSITION\n\
         STEP A2: {{agent := 'r1'}} MoveA2(N, a2); END_STEP\nTRANSITION FROM A2 TO AEnd := a2; END_TRANSITION\n\
         STEP AEnd: END_STEP\n\
         STEP B1: {{agent := 'r2'}} MoveB1(N, b1); END_STEP\nTRANSITION FROM B1 TO B2 := b1; END_TRANSITION\n\
         STEP B2: {{agent := 'r2'}} MoveB2(N, b2); END_STEP\nTRANSITION FROM B2 TO BEnd := b2; END_TRANSITION\n\
         STEP BEnd: END_STEP\nTRANSITION FROM (AEnd, BEnd) TO Done := TRUE; END_TRANSITION\nSTEP Done: END_STEP\n\
         {}{}{}{}END_PROGRAM\n",
        motion("MoveA1", 0.0),
        motion("MoveA2", 0.1),
        motion("MoveB1", 0.2),
        motion("MoveB2", 0.1),
    );
    let path = dir.join("cell.st");
    std::fs::write(&path, text).expect("write the chart");
    path
}

fn marks(dir: &Path) -> Vec<String> {
    std::fs::read_to_string(dir.join("marks")).unwrap_or_default().lines().map(str::to_string).collect()
}

/// Waits until `marks` holds `line` (read again each time the folder changes).
async fn wait_for_mark(dir: &Path, line: &str) {
    let what = format!("the mark `{line}`");
    loopback::when_changed(dir, &what, || marks(dir).iter().any(|l| l == line).then_some(())).await;
}

/// `baton ctl ARGS…` on the cluster: its exit status and what it printed.
async fn ctl(cluster: &Cluster, args: &[&str]) -> (bool, String) {
    let mut all = vec!["ctl", "--connect", cluster.endpoint.as_str()];
    all.extend_from_slice(args);
    let out = cluster.baton(&all).await;
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    (out.status.success(), text)
}

/// The run's status as `baton status --json` gives it.
async fn status(cluster: &Cluster) -> serde_json::Value {
    let out = cluster.baton(&["status", "--connect", &cluster.endpoint, "--json"]).await;
    let text = String::from_utf8_lossy(&out.stdout);
    serde_json::from_str(text.lines().next().unwrap_or("null")).unwrap_or(serde_json::Value::Null)
}

/// Asks `baton status --why` every 50 ms until `holds` says yes of its answer (under the timeout); `what` names
/// what was waited for, if it never came.
async fn wait_for_status(
    cluster: &Cluster,
    what: &str,
    holds: impl Fn(&serde_json::Value) -> bool,
) -> serde_json::Value {
    let found = tokio::time::timeout(TIMEOUT, async {
        loop {
            let s = status_why(cluster).await;
            if holds(&s) {
                return s;
            }
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
    })
    .await;
    found.unwrap_or_else(|_| panic!("{what} never came"))
}

/// Asks `baton status` until the run's state is `state`.
async fn wait_for_state(cluster: &Cluster, state: &str) -> serde_json::Value {
    wait_for_status(cluster, &format!("the state `{state}`"), |s| s["state"] == state).await
}

fn first(trace: &[TraceRecord], event: TraceEvent, name: &str) -> Option<usize> {
    trace.iter().position(|r| r.event == event && r.name == name)
}

fn count(trace: &[TraceRecord], event: TraceEvent, name: &str) -> usize {
    trace.iter().filter(|r| r.event == event && r.name == name).count()
}

/// `hold` while r1's first motion runs: no motion starts from then on, the run is `held` only once the running
/// motions ended and the agents confirmed, the held step's time stands still; `unhold` goes on, nothing runs
/// twice, and the run completes.
#[tokio::test(flavor = "multi_thread")]
async fn hold_waits_for_the_running_motion_and_unhold_goes_on() {
    let (cluster, chart, coordinator) = running_cell(|dir| cell(dir, 1.5), &[], &[]).await;
    let dir = cluster.dir.path().to_path_buf();
    wait_for_mark(&dir, "start MoveA1").await;
    let (ok, said) = ctl(&cluster, &["hold", "--reason", "material late"]).await;
    assert!(ok, "{said}");
    let held = wait_for_state(&cluster, "held").await;
    let m = marks(&dir);
    assert!(m.contains(&"end MoveA1".to_string()), "held before r1's motion ended: {m:?}");
    assert!(!m.contains(&"start MoveA2".to_string()), "a motion started while holding: {m:?}");
    assert!(held["tokens"].as_array().is_some_and(|t| t.iter().all(|t| t["held_confirmed"] == true)), "{held}");
    assert_eq!(held["available"], serde_json::json!(["stop", "unhold", "abort"]), "{held}");
    // Held, A1's time stands still (r1 says so twice, apart in time).
    let t1 = step_time(&status_why(&cluster).await, "A1");
    let t2 = step_time(&status_why(&cluster).await, "A1");
    assert!(t1.is_some() && t1 == t2, "A1.T went on while held: {t1:?} then {t2:?}");
    let (ok, said) = ctl(&cluster, &["hold"]).await;
    assert!(!ok && said.contains("held") && said.contains("unhold"), "a second hold is refused: {said}");
    let (ok, said) = ctl(&cluster, &["unhold", "--reason", "material here"]).await;
    assert!(ok, "{said}");
    let (status, log, trace, summary) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    assert_eq!(summary["state"], "complete", "{summary}");
    check_trace_invariants(&trace, &chart);
    let hold = trace.iter().position(|r| r.event == TraceEvent::Command && r.name == "hold").expect("hold traced");
    assert_eq!(trace[hold].message.as_deref(), Some("material late"));
    assert!(trace[hold].by.as_deref().is_some_and(|b| b.contains('@')), "{:?}", trace[hold]);
    let unhold = trace.iter().position(|r| r.event == TraceEvent::Command && r.name == "unhold").expect("unhold");
    let refused = trace.iter().position(|r| r.event == TraceEvent::CommandRefused && r.name == "hold");
    assert!(refused.is_some_and(|r| hold < r && r < unhold), "the refused hold is traced between them");
    for motion in ["MoveA1", "MoveA2", "MoveB1", "MoveB2"] {
        assert_eq!(count(&trace, TraceEvent::ActionOn, motion), 1, "{motion} ran once");
    }
    assert!(first(&trace, TraceEvent::ActionOn, "MoveA2").is_some_and(|a2| a2 > unhold), "A2 started after unhold");
    let m = marks(&dir);
    assert_eq!(m.iter().filter(|l| l.starts_with("start")).count(), 4, "{m:?}");
}

/// `hold --agent r1` holds r1's branch while r2's branch completes; the run stays in Execute.
#[tokio::test(flavor = "multi_thread")]
async fn holding_one_robot_lets_the_other_go_on() {
    let (cluster, chart, coordinator) = running_cell(|dir| cell(dir, 1.0), &[], &[]).await;
    let dir = cluster.dir.path().to_path_buf();
    wait_for_mark(&dir, "start MoveA1").await;
    let (ok, said) = ctl(&cluster, &["hold", "--agent", "r1", "--reason", "r1 gripper check"]).await;
    assert!(ok, "{said}");
    wait_for_mark(&dir, "end MoveB2").await;
    let s = status(&cluster).await;
    assert_eq!(s["state"], "execute", "{s}");
    assert_eq!(s["held"], serde_json::json!(["agent r1"]), "{s}");
    wait_for_mark(&dir, "end MoveA1").await;
    assert!(!marks(&dir).contains(&"start MoveA2".to_string()), "r1 started a motion while held");
    let (ok, said) = ctl(&cluster, &["unhold", "--agent", "r1"]).await;
    assert!(ok, "{said}");
    let (status, log, trace, _) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    check_trace_invariants(&trace, &chart);
    let unhold = trace.iter().position(|r| r.event == TraceEvent::Command && r.name == "unhold").expect("unhold");
    assert!(first(&trace, TraceEvent::ActionOn, "MoveA2").is_some_and(|a2| a2 > unhold));
    assert!(first(&trace, TraceEvent::Activate, "BEnd").is_some_and(|b| b < unhold), "r2's branch went on");
}

/// `abort` mid-motion: the run ends at once, `aborted` (exit 4), and the running shell motion is killed on its
/// agent (its process, which would sleep 100 s, is gone).
#[tokio::test(flavor = "multi_thread")]
async fn abort_cancels_the_running_motion_and_ends_the_run_aborted() {
    // `$$` is how an IEC 61131-3 string writes one `$`: the shell gets `echo $$`, its own pid.
    let motion =
        |dir: &Path| cell_with(dir, &format!("echo $$$$ > {}; exec sleep 100", dir.join("motion.pid").display()));
    let (cluster, chart, coordinator) = running_cell(motion, &[], &["--verbose"]).await;
    let pid_file = cluster.dir.path().join("motion.pid");
    let dir = cluster.dir.path().to_path_buf();
    wait_for_mark(&dir, "start MoveA1").await;
    let (ok, said) = ctl(&cluster, &["abort", "--reason", "collision risk"]).await;
    assert!(ok, "{said}");
    let (status, log, trace, summary) = coordinator.finish().await;
    assert_eq!(status.code(), Some(4), "{log}");
    assert_eq!(summary["state"], "aborted");
    let states: Vec<&str> = trace.iter().filter(|r| r.event == TraceEvent::State).map(|r| r.name.as_str()).collect();
    assert_eq!(states, ["aborting", "aborted"]);
    // Aborted with r1's motion running: its token is cancelled there, not handed back.
    check_trace_invariants_with_tokens_out(&trace, &chart, tokens_out(&trace));
    cluster
        .wait_for_agent_trace("r1", "MoveA1 cancelled", |r| r.event == TraceEvent::SkillCancel && r.name == "MoveA1")
        .await;
    let pid = std::fs::read_to_string(&pid_file).expect("the motion wrote its pid");
    assert!(pid.trim().parse::<u32>().is_ok(), "`{pid}` is not a pid");
    let proc = PathBuf::from(format!("/proc/{}", pid.trim()));
    let gone = tokio::time::timeout(TIMEOUT, async {
        while proc.exists() && !std::fs::read_to_string(proc.join("stat")).unwrap_or_default().contains(") Z ") {
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    })
    .await;
    assert!(gone.is_ok(), "the motion's process {} still runs", pid.trim());
}

/// An interrupt (SIGINT, as Ctrl-C) stops the run: the running motion finishes, nothing new starts, and `baton run`
/// exits 3 with its summary.
#[tokio::test(flavor = "multi_thread")]
async fn an_interrupt_stops_the_run_after_the_running_motion() {
    let (cluster, chart, coordinator) = running_cell(|dir| cell(dir, 1.0), &[], &[]).await;
    let dir = cluster.dir.path().to_path_buf();
    wait_for_mark(&dir, "start MoveA1").await;
    let pid = coordinator.child.id().expect("running").to_string();
    assert!(std::process::Command::new("kill").args(["-INT", &pid]).status().expect("kill").success());
    let (status, log, trace, summary) = coordinator.finish().await;
    assert_eq!(status.code(), Some(3), "{log}");
    assert_eq!(summary["state"], "stopped");
    // A stop lets the running motion finish and starts nothing new: the robots' segments end the run where they
    // stand, their tokens not handed back.
    check_trace_invariants_with_tokens_out(&trace, &chart, tokens_out(&trace));
    let m = marks(&dir);
    assert!(m.contains(&"end MoveA1".to_string()), "stopped before the running motion ended: {m:?}");
    assert!(!m.contains(&"start MoveA2".to_string()), "a motion started while stopping: {m:?}");
    let stop = trace.iter().find(|r| r.event == TraceEvent::Command).expect("the stop is traced");
    assert_eq!((stop.name.as_str(), stop.message.as_deref()), ("stop", Some("interrupted")));
}

/// A step's `S.T` as `baton status --why` gives it.
fn step_time(status: &serde_json::Value, step: &str) -> Option<u64> {
    status["why"].as_array()?.iter().find(|w| w["step"] == step)?["active_ms"].as_u64()
}

/// `baton status --json --why`, the run's entry.
async fn status_why(cluster: &Cluster) -> serde_json::Value {
    let out = cluster.baton(&["status", "--connect", &cluster.endpoint, "--json", "--why"]).await;
    let text = String::from_utf8_lossy(&out.stdout).to_string();
    serde_json::from_str::<serde_json::Value>(text.lines().next().unwrap_or("null")).unwrap_or_default()
}

/// `baton status --why`: the agents say why their steps wait — the FALSE parts of a condition with their values,
/// a skill still running — and the coordinator why a convergence waits: the branch still missing.
#[tokio::test(flavor = "multi_thread")]
async fn status_why_gathers_what_each_transition_waits_for_from_the_agents() {
    let mut cluster = Cluster::new();
    let chart = cluster.dir.path().join("why.st");
    std::fs::write(
        &chart,
        "PROGRAM why\nVAR part_ok : BOOL; pressure : INT; moved : BOOL; END_VAR\n\
         INITIAL_STEP Idle: END_STEP\nTRANSITION FROM Idle TO (Check, Move) := TRUE; END_TRANSITION\n\
         STEP Check: {agent := 'r1'} END_STEP\nTRANSITION FROM Check TO Checked := part_ok AND pressure > 5; END_TRANSITION\n\
         STEP Checked: END_STEP\nSTEP Move: {agent := 'r2'} Drive(N, moved); END_STEP\n\
         TRANSITION FROM Move TO Moved := moved; END_TRANSITION\nSTEP Moved: END_STEP\n\
         TRANSITION FROM (Checked, Moved) TO Done := TRUE; END_TRANSITION\nSTEP Done: END_STEP\n\
         ACTION Drive: {skill := 'motion', ms := 60000} END_ACTION\nEND_PROGRAM\n",
    )
    .expect("write the chart");
    let mut coordinator = cluster.coordinator(&chart, &[]);
    coordinator.wait_ready().await;
    cluster.agent("r1", &[], &[]);
    cluster.agent("r2", &[], &[]);
    let step = |s: &serde_json::Value, name: &str| {
        s["why"].as_array().and_then(|w| w.iter().find(|x| x["step"] == name).cloned()).unwrap_or_default()
    };
    // Both branches out: r1 judges Check's condition, r2 runs its motion.
    let s = wait_for_status(&cluster, "the agents' answers", |s| {
        step(s, "Check")["agent"] == "r1" && step(s, "Move")["agent"] == "r2"
    })
    .await;
    let check = step(&s, "Check");
    assert_eq!(
        check["transitions"][0]["false_parts"],
        serde_json::json!(["`part_ok` is FALSE", "`pressure > 5` is FALSE (pressure = 0)"]),
        "{s}"
    );
    let mv = step(&s, "Move");
    assert_eq!(mv["skills"][0]["action"], "Drive", "{s}");
    assert_eq!(mv["transitions"][0]["false_parts"], serde_json::json!(["`moved` is FALSE"]), "{s}");
    // Half of it true: only the other half is said.
    let set = cluster.baton(&["set", "--connect", &cluster.endpoint, "part_ok=true"]).await;
    assert!(set.status.success());
    let set = cluster.baton(&["set", "--connect", &cluster.endpoint, "pressure=7"]).await;
    assert!(set.status.success());
    // Check cleared: the coordinator's convergence now waits for r2's branch.
    let s = wait_for_status(&cluster, "step Checked", |s| !step(s, "Checked").is_null()).await;
    let checked = step(&s, "Checked");
    assert_eq!(checked["agent"], serde_json::Value::Null, "{s}");
    assert_eq!(checked["transitions"][0]["missing"], serde_json::json!(["Moved"]), "{s}");
    let (ok, said) = ctl(&cluster, &["abort"]).await;
    assert!(ok, "{said}");
    let (status, log, trace, _) = coordinator.finish().await;
    assert_eq!(status.code(), Some(4), "{log}");
    // Aborted with r2's motion running: that token is cancelled on r2; r1's came back when Check cleared.
    check_trace_invariants_with_tokens_out(&trace, &chart, 1);
}

/// `{hold := 'cancel'}`: a hold cancels the running motion on its agent (its process is killed), so the run is held
/// at once rather than after the motion; `unhold` starts the motion again, and the run completes.
#[tokio::test(flavor = "multi_thread")]
async fn a_hold_cancels_a_motion_that_says_so_and_unhold_runs_it_again() {
    let mut cluster = Cluster::new();
    let dir = cluster.dir.path().to_path_buf();
    let m = dir.join("marks");
    let chart = dir.join("cancel.st");
    // The first run of the motion sleeps 100 s (it must be cancelled); the second, after the unhold, is quick.
    let cmd = format!(
        "echo start MoveA >> {m}; if [ -f {m}.again ]; then sleep 0.2; else touch {m}.again; exec sleep 100; fi; echo end MoveA >> {m}",
        m = m.display()
    );
    std::fs::write(
        &chart,
        format!(
            "PROGRAM cancel\nVAR moved : BOOL; END_VAR\nINITIAL_STEP Idle: END_STEP\n\
             TRANSITION FROM Idle TO A := TRUE; END_TRANSITION\nSTEP A: {{agent := 'r1'}} MoveA(N, moved); END_STEP\n\
             TRANSITION FROM A TO Done := moved; END_TRANSITION\nSTEP Done: END_STEP\n\
             ACTION MoveA: {{skill := 'shell', cmd := '{cmd}', hold := 'cancel'}} END_ACTION\nEND_PROGRAM\n"
        ),
    )
    .expect("write the chart");
    let mut coordinator = cluster.coordinator(&chart, &[]);
    coordinator.wait_ready().await;
    cluster.agent("r1", &[], &["--allow-shell", "--verbose"]);
    wait_for_mark(&dir, "start MoveA").await;
    let (ok, said) = ctl(&cluster, &["hold"]).await;
    assert!(ok, "{said}");
    // Held well before the 100 s motion could have ended: it was cancelled.
    wait_for_state(&cluster, "held").await;
    cluster
        .wait_for_agent_trace("r1", "MoveA cancelled", |r| r.event == TraceEvent::SkillCancel && r.name == "MoveA")
        .await;
    assert_eq!(marks(&dir), ["start MoveA"], "nothing ran while held");
    let (ok, said) = ctl(&cluster, &["unhold"]).await;
    assert!(ok, "{said}");
    let (status, log, trace, _) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    assert_eq!(marks(&dir), ["start MoveA", "start MoveA", "end MoveA"], "the motion ran again from its start");
    check_trace_invariants(&trace, &chart);
}

/// A coordinator killed while the run is held, in step mode, with a supervision alarm standing, comes back from its
/// journal held, in step mode, with the alarm; the motion does not run again, and the run goes on when released.
#[tokio::test(flavor = "multi_thread")]
async fn a_restarted_coordinator_comes_back_held_in_its_mode_with_its_alarms() {
    let mut cluster = Cluster::with_router().await;
    let dir = cluster.dir.path().to_path_buf();
    let m = dir.join("marks");
    let chart = dir.join("slow.st");
    std::fs::write(
        &chart,
        format!(
            "PROGRAM slow\nVAR moved : BOOL; END_VAR\nINITIAL_STEP Idle: END_STEP\n\
             TRANSITION FROM Idle TO A := TRUE; END_TRANSITION\n\
             STEP A: {{agent := 'r1', max_ms := T#300ms}} MoveA(N, moved); END_STEP\n\
             TRANSITION FROM A TO Done := moved; END_TRANSITION\nSTEP Done: END_STEP\n\
             ACTION MoveA: {{skill := 'shell', cmd := 'echo start MoveA >> {m}; sleep 1; echo end MoveA >> {m}'}} END_ACTION\n\
             END_PROGRAM\n",
            m = m.display()
        ),
    )
    .expect("write the chart");
    let journal = dir.join("journal");
    let args = ["--journal", journal.to_str().expect("utf-8 path")];
    let mut coordinator = cluster.coordinator_joining(&chart, &args);
    coordinator.wait_ready().await;
    cluster.agent("r1", &[], &["--allow-shell"]);
    coordinator.wait_for_trace("A's supervision alarm", |r| r.event == TraceEvent::Alarm && r.name == "A").await;
    for command in [&["mode", "step"][..], &["hold", "--reason", "check the drive"][..]] {
        let (ok, said) = ctl(&cluster, command).await;
        assert!(ok, "{said}");
    }
    wait_for_state(&cluster, "held").await;
    coordinator.kill().await;
    let mut coordinator = cluster.coordinator_joining(&chart, &args);
    coordinator.wait_ready().await;
    let s = wait_for_state(&cluster, "held").await;
    assert_eq!(s["mode"], "step", "{s}");
    assert_eq!(s["alarms"][0]["id"], 1, "{s}");
    assert_eq!(s["alarms"][0]["source"], "A", "{s}");
    for command in [&["mode", "auto"][..], &["unhold"][..], &["ack", "1", "--comment", "ok"][..]] {
        let (ok, said) = ctl(&cluster, command).await;
        assert!(ok, "{command:?}: {said}");
    }
    let (status, log, trace, _) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    assert_eq!(marks(&dir), ["start MoveA", "end MoveA"], "the motion ran once");
    // The resumed coordinator's trace is the whole run's, the part before the kill replayed from the journal.
    check_trace_invariants(&trace, &chart);
    let states: Vec<&str> = trace.iter().filter(|r| r.event == TraceEvent::State).map(|r| r.name.as_str()).collect();
    assert_eq!(states, ["holding", "held", "unholding", "execute", "completing", "complete"], "the whole run's states");
}

/// A run begun with `--wait-start` and killed before anyone started it comes back from its journal still waiting:
/// its `idle` state was journaled and traced as it began, not with whatever came next.
#[tokio::test(flavor = "multi_thread")]
async fn a_waiting_run_killed_before_its_start_comes_back_waiting() {
    let cluster = Cluster::new();
    let chart = cell(cluster.dir.path(), 0.1);
    let journal = cluster.dir.path().join("journal");
    let journal = journal.to_str().expect("utf-8 path");
    let mut coordinator = cluster.coordinator(&chart, &["--journal", journal, "--wait-start"]);
    let trace = coordinator.wait_ready().await;
    assert!(trace.iter().any(|r| r.event == TraceEvent::State && r.name == "idle"), "{trace:#?}");
    coordinator.kill().await;
    let mut coordinator = cluster.coordinator(&chart, &["--journal", journal]);
    coordinator.wait_ready().await;
    let s = wait_for_state(&cluster, "idle").await;
    assert_eq!(s["available"], serde_json::json!(["start", "stop", "abort"]), "{s}");
    coordinator.kill().await;
}

/// `baton run --wait-start` waits in Idle, saying `start` is legal, and runs the chart once started.
#[tokio::test(flavor = "multi_thread")]
async fn a_run_started_by_an_operator() {
    let (cluster, chart, coordinator) = running_cell(|dir| cell(dir, 0.1), &["--wait-start"], &[]).await;
    let s = wait_for_state(&cluster, "idle").await;
    assert_eq!(s["available"], serde_json::json!(["start", "stop", "abort"]), "{s}");
    assert!(marks(cluster.dir.path()).is_empty(), "nothing ran before the start");
    let (ok, said) = ctl(&cluster, &["start", "--reason", "shift begins"]).await;
    assert!(ok, "{said}");
    let (status, log, trace, _) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    let states: Vec<&str> = trace.iter().filter(|r| r.event == TraceEvent::State).map(|r| r.name.as_str()).collect();
    assert_eq!(states, ["idle", "starting", "execute", "completing", "complete"]);
    check_trace_invariants(&trace, &chart);
}

/// Asks `baton status` until transition `t` waits for a confirmation.
async fn wait_for_waiting(cluster: &Cluster, t: &str) -> serde_json::Value {
    let what = format!("a confirmation wait of `{t}`");
    wait_for_status(cluster, &what, |s| s["waiting"].as_array().is_some_and(|w| w.iter().any(|x| x == t))).await
}

/// Step mode with real processes: r1's TRUE transition waits on r1 for `confirm`; manual mode: a switch the chart
/// could never reach is refused, and `force` clears a transition whatever its condition.
#[tokio::test(flavor = "multi_thread")]
async fn step_mode_waits_for_confirm_and_manual_mode_forces_and_refuses_unsafe_switches() {
    let (cluster, chart, coordinator) = running_cell(|dir| cell(dir, 0.2), &["--wait-start"], &[]).await;
    wait_for_state(&cluster, "idle").await;
    for args in [&["mode", "step"][..], &["start"][..]] {
        let (ok, said) = ctl(&cluster, args).await;
        assert!(ok, "{args:?}: {said}");
    }
    let dir = cluster.dir.path().to_path_buf();
    // The first clearing, the coordinator's divergence, waits too: nothing has started.
    let waiting = wait_for_waiting(&cluster, "Idle->(A1,B1)").await;
    assert_eq!(waiting["mode"], "step", "{waiting}");
    assert!(marks(&dir).is_empty(), "a motion started before the confirmation");
    let (ok, said) = ctl(&cluster, &["confirm"]).await;
    assert!(ok, "the only one waiting is confirmed without its name: {said}");
    wait_for_mark(&dir, "end MoveA1").await;
    // r1 says its transition waits; nothing of A2 starts until it is confirmed.
    wait_for_waiting(&cluster, "A1->A2").await;
    assert!(!marks(&dir).contains(&"start MoveA2".to_string()));
    let (ok, said) = ctl(&cluster, &["confirm", "A1->A2"]).await;
    assert!(ok, "{said}");
    wait_for_mark(&dir, "end MoveA2").await;
    // Manual: B's branch is at B1 or B2; activating AEnd's sibling Done alone could never happen.
    let (ok, said) = ctl(&cluster, &["mode", "manual"]).await;
    assert!(ok, "{said}");
    let (ok, said) = ctl(&cluster, &["activate", "Done"]).await;
    assert!(!ok && said.contains("could never reach"), "{said}");
    wait_for_mark(&dir, "end MoveB1").await;
    let (ok, said) = ctl(&cluster, &["force", "B1->B2"]).await;
    assert!(ok, "{said}");
    wait_for_mark(&dir, "end MoveB2").await;
    // r2's token waits at B2 (nothing clears by itself): the operator moves it to the end of its branch, taking it
    // back from r2 in one checked change; moving it into A's branch is refused.
    let (ok, said) = ctl(&cluster, &["move", "B2", "A1"]).await;
    assert!(!ok && said.contains("could never reach"), "{said}");
    let (ok, said) = ctl(&cluster, &["move", "B2", "BEnd", "--reason", "B2 done by hand"]).await;
    assert!(ok && said.contains("the token of `B2` moved to `BEnd`"), "{said}");
    let (ok, said) = ctl(&cluster, &["mode", "auto"]).await;
    assert!(ok, "{said}");
    let (status, log, trace, _) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    check_trace_invariants(&trace, &chart);
    let modes: Vec<&str> = trace.iter().filter(|r| r.event == TraceEvent::Mode).map(|r| r.name.as_str()).collect();
    assert_eq!(modes, ["step", "manual", "auto"]);
    let withdrawn = trace.iter().find(|r| r.event == TraceEvent::Withdraw).expect("r2's token taken back");
    assert_eq!((withdrawn.name.as_str(), withdrawn.agent.as_deref()), ("B2", Some("r2")));
    assert!(first(&trace, TraceEvent::Activate, "BEnd")
        .is_some_and(|b| b > first(&trace, TraceEvent::Withdraw, "B2").unwrap_or(usize::MAX)));
}

/// `{max_ms}` with real processes: the chart branches to its own recovery on `S.overrun` (cancelling the slow motion
/// by leaving its step), the alarm is raised with what the step waited for, and acknowledged.
#[tokio::test(flavor = "multi_thread")]
async fn a_step_past_its_maximum_time_branches_to_the_charts_recovery_and_the_alarm_is_acknowledged() {
    let mut cluster = Cluster::new();
    let dir = cluster.dir.path().to_path_buf();
    let chart = dir.join("recover.st");
    std::fs::write(
        &chart,
        "PROGRAM recover\nVAR moved, reset : BOOL; END_VAR\nINITIAL_STEP Idle: END_STEP\n\
         TRANSITION FROM Idle TO Move := TRUE; END_TRANSITION\n\
         STEP Move: {agent := 'r1', max_ms := T#300ms} Drive(N, moved); END_STEP\n\
         TRANSITION FROM Move TO Done := moved; END_TRANSITION\n\
         TRANSITION FROM Move TO Recover := Move.overrun; END_TRANSITION\n\
         STEP Done: END_STEP\nSTEP Recover: END_STEP\nTRANSITION FROM Recover TO Idle := reset; END_TRANSITION\n\
         ACTION Drive: {skill := 'motion', ms := 5000} END_ACTION\nEND_PROGRAM\n",
    )
    .expect("write the chart");
    let mut coordinator = cluster.coordinator(&chart, &[]);
    coordinator.wait_ready().await;
    cluster.agent("r1", &[], &[]);
    coordinator.wait_for_trace("Move's supervision alarm", |r| r.event == TraceEvent::Alarm && r.name == "Move").await;
    let s = wait_for_status(&cluster, "the chart's recovery", |s| {
        s["active_steps"].as_array().is_some_and(|a| a.iter().any(|x| x["name"] == "Recover"))
    })
    .await;
    let alarm = &s["alarms"][0];
    assert_eq!((alarm["id"].as_u64(), alarm["source"].as_str()), (Some(1), Some("Move")), "{s}");
    let message = alarm["message"].as_str().unwrap_or_default();
    assert!(message.contains("it waited for: Move->Done: `moved` is FALSE"), "{message}");
    assert!(message.contains("skill of `Drive` running for"), "{message}");
    // Shelved for a minute: out of the active list, listed apart with who and why; unshelved: back.
    let (ok, said) = ctl(&cluster, &["shelve", "1", "--for", "1m", "--reason", "drive being replaced"]).await;
    assert!(ok, "{said}");
    let out = cluster.baton(&["status", "--connect", &cluster.endpoint]).await;
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(!text.contains("alarms:") && text.contains("shelved: 1"), "{text}");
    assert!(text.contains("drive being replaced") && text.contains("Move"), "{text}");
    let (ok, said) = ctl(&cluster, &["unshelve", "1"]).await;
    assert!(ok, "{said}");
    let s = status(&cluster).await;
    assert_eq!((s["alarms"].as_array().map(Vec::len), s["shelved"].as_array().map(Vec::len)), (Some(1), Some(0)));
    // A refusal says what is legal once.
    let (ok, said) = ctl(&cluster, &["unhold"]).await;
    assert!(!ok && said.matches("legal now").count() == 1, "{said}");
    let (ok, said) = ctl(&cluster, &["ack", "1", "--comment", "drive replaced"]).await;
    assert!(ok, "{said}");
    let (ok, said) = ctl(&cluster, &["ack", "1"]).await;
    assert!(!ok && said.contains("no standing alarm 1"), "acknowledged and gone: {said}");
    let (ok, said) = ctl(&cluster, &["abort"]).await;
    assert!(ok, "{said}");
    let (status, log, trace, _) = coordinator.finish().await;
    assert_eq!(status.code(), Some(4), "{log}");
    let ack = trace.iter().find(|r| r.event == TraceEvent::Ack).expect("the acknowledgement");
    assert_eq!((ack.id, ack.message.as_deref(), ack.name.as_str()), (Some(1), Some("drive replaced"), "Move"));
    let unshelved = trace.iter().find(|r| r.event == TraceEvent::Unshelve).expect("the unshelve is traced");
    assert!(unshelved.message.as_deref().is_some_and(|m| m.contains("drive being replaced")), "{unshelved:?}");
    assert!(trace.iter().any(|r| r.event == TraceEvent::AlarmClear && r.id == Some(1)));
    assert!(trace.iter().all(|r| r.event != TraceEvent::SkillDone), "the slow motion was cancelled, not finished");
    // Move's token came back when its step left for the recovery, which is the coordinator's: none is out.
    check_trace_invariants(&trace, &chart);
}

/// An agent that lacks a skill a step of its placement runs (r1 without `--allow-shell`, for a `shell` action) is
/// sent nothing of that step — the command never runs — and an alarm names the agent, the skill, the action and the
/// step from the moment it announces itself; started again with the skill, it is sent the step, the alarm's cause
/// is gone, and the run completes.
#[tokio::test(flavor = "multi_thread")]
async fn an_agent_without_the_skill_of_a_step_is_sent_nothing_and_an_alarm_names_it() {
    let mut cluster = Cluster::new();
    let dir = cluster.dir.path().to_path_buf();
    let chart = dir.join("grip.st");
    let m = dir.join("marks");
    std::fs::write(
        &chart,
        format!(
            "PROGRAM grip\nVAR gripped : BOOL; END_VAR\nINITIAL_STEP Idle: END_STEP\n\
             TRANSITION FROM Idle TO Grip := TRUE; END_TRANSITION\n\
             STEP Grip: {{agent := 'r1'}} Close(N, gripped); END_STEP\n\
             TRANSITION FROM Grip TO Done := gripped; END_TRANSITION\nSTEP Done: END_STEP\n\
             ACTION Close: {{skill := 'shell', cmd := 'echo closed >> {}'}} END_ACTION\nEND_PROGRAM\n",
            m.display()
        ),
    )
    .expect("write the chart");
    let mut coordinator = cluster.coordinator(&chart, &[]);
    coordinator.wait_ready().await;
    cluster.agent("r1", &[], &[]);
    coordinator
        .wait_for_trace("an alarm for r1's missing skill", |r| r.event == TraceEvent::Alarm && r.name == "r1")
        .await;
    let s = wait_for_status(&cluster, "the skill's alarm", |s| {
        s["alarms"].as_array().is_some_and(|a| a.iter().any(|x| x["source"] == "r1"))
    })
    .await;
    let alarm = s["alarms"].as_array().and_then(|a| a.iter().find(|x| x["source"] == "r1")).expect("r1's alarm");
    let message = alarm["message"].as_str().unwrap_or_default();
    for part in ["agent `r1` has no skill `shell`", "action `Close` of step `Grip`", "its skills: motion"] {
        assert!(message.contains(part), "{part} missing from: {message}");
    }
    assert!(s["tokens"].as_array().is_some_and(|t| t.iter().all(|t| t["agent"].is_null())), "{s}");
    assert!(marks(&dir).is_empty(), "{:?}", marks(&dir));
    // The status says what each agent announced.
    let r1 = s["agents"].as_array().and_then(|a| a.iter().find(|x| x["name"] == "r1")).expect("r1 is listed");
    let skills: Vec<&str> =
        r1["skills"].as_array().map(|a| a.iter().filter_map(|x| x.as_str()).collect()).unwrap_or_default();
    assert!(skills.contains(&"motion") && !skills.contains(&"shell"), "{s}");
    // Started again with the skill: the alarm's cause is gone, the step is sent, and the chart reaches its end.
    cluster.kill_agent("r1").await;
    cluster.agent("r1", &[], &["--allow-shell"]);
    coordinator.wait_for_trace("Grip sent to r1", |r| r.event == TraceEvent::Dispatch && r.name == "Grip").await;
    let (status, log, trace, _) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    assert_eq!(marks(&dir), ["closed"], "the command ran once, on the process that has the skill");
    let sent: Vec<_> = trace.iter().filter(|r| r.event == TraceEvent::Dispatch && r.name == "Grip").collect();
    assert_eq!(sent.len(), 1, "{sent:?}");
    let alarm_at = first(&trace, TraceEvent::Alarm, "r1").expect("the alarm is traced");
    assert!(alarm_at < first(&trace, TraceEvent::Dispatch, "Grip").expect("dispatched"), "raised before any dispatch");
    assert!(first(&trace, TraceEvent::AgentUp, "r1").is_some_and(|up| up < alarm_at), "said once r1 is live");
    check_trace_invariants(&trace, &chart);
}

/// `baton run --stay --journal`: the run stays at Complete; `reset` starts the chart again as a new run (new id,
/// Idle until `start`); an abort, then `clear`, leaves it Stopped; a coordinator killed there comes back from its
/// journal in that run, Stopped; `reset` and `start` run the cell a third time; an interrupt at Complete ends the
/// process with status 0. Every motion ran once per run that reached it, never twice.
#[tokio::test(flavor = "multi_thread")]
async fn a_run_that_stays_is_reset_cleared_and_resumed_as_new_runs_of_its_journal() {
    let mut cluster = Cluster::with_router().await;
    let dir = cluster.dir.path().to_path_buf();
    let chart = cell(&dir, 0.1);
    let journal = dir.join("journal");
    let args = ["--stay", "--journal", journal.to_str().expect("utf-8 path")];
    let mut coordinator = cluster.coordinator_joining(&chart, &args);
    coordinator.wait_ready().await;
    cluster.agent("r1", &[], &["--allow-shell"]);
    cluster.agent("r2", &[], &["--allow-shell"]);
    let s = wait_for_state(&cluster, "complete").await;
    assert_eq!(s["available"], serde_json::json!(["reset", "stop", "abort"]), "{s}");
    let first = s["run"].clone();
    let ends = |n: usize| {
        let m = marks(&dir);
        ["MoveA1", "MoveA2", "MoveB1", "MoveB2"]
            .iter()
            .all(|a| m.iter().filter(|l| **l == format!("end {a}")).count() == n)
    };
    assert!(ends(1), "{:?}", marks(&dir));
    let (ok, said) = ctl(&cluster, &["reset", "--reason", "next batch"]).await;
    assert!(ok, "{said}");
    let s = wait_for_state(&cluster, "idle").await;
    assert_ne!(s["run"], first, "a new run");
    assert!(ends(1), "nothing runs before start: {:?}", marks(&dir));
    let (ok, said) = ctl(&cluster, &["start"]).await;
    assert!(ok, "{said}");
    wait_for_state(&cluster, "complete").await;
    assert!(ends(2), "{:?}", marks(&dir));
    // The third run is aborted once r1's first motion started, then cleared.
    for command in [&["reset"][..], &["start"][..]] {
        let (ok, said) = ctl(&cluster, command).await;
        assert!(ok, "{command:?}: {said}");
    }
    let m = dir.join("marks");
    let third_start = |n: usize| marks(&dir).iter().filter(|l| *l == "start MoveA1").count() == n;
    let found = tokio::time::timeout(TIMEOUT, async {
        while !third_start(3) {
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    })
    .await;
    assert!(found.is_ok(), "{:?}", std::fs::read_to_string(&m));
    let (ok, said) = ctl(&cluster, &["abort", "--reason", "jam"]).await;
    assert!(ok, "{said}");
    wait_for_state(&cluster, "aborted").await;
    let at_abort = marks(&dir);
    let (ok, said) = ctl(&cluster, &["clear"]).await;
    assert!(ok, "{said}");
    let s = wait_for_state(&cluster, "stopped").await;
    let third = s["run"].clone();
    coordinator.kill().await;
    let mut coordinator = cluster.coordinator_joining(&chart, &args);
    coordinator.wait_ready().await;
    let s = wait_for_state(&cluster, "stopped").await;
    assert_eq!(s["run"], third, "the journal's latest run, where it stood");
    assert_eq!(marks(&dir), at_abort, "nothing ran after the abort, nor on the resumed coordinator");
    for command in [&["reset"][..], &["start"][..]] {
        let (ok, said) = ctl(&cluster, command).await;
        assert!(ok, "{command:?}: {said}");
    }
    let s = wait_for_state(&cluster, "complete").await;
    let fourth = s["run"].clone();
    // The fourth run moved each robot once more, from the initial steps.
    let count = |m: &[String], l: &str| m.iter().filter(|x| *x == l).count();
    let now = marks(&dir);
    for a in ["MoveA1", "MoveA2", "MoveB1", "MoveB2"] {
        for l in [format!("start {a}"), format!("end {a}")] {
            assert_eq!(count(&now, &l), count(&at_abort, &l) + 1, "{l}: {now:?}");
        }
    }
    let pid = coordinator.child.id().expect("running").to_string();
    assert!(std::process::Command::new("kill").args(["-INT", &pid]).status().expect("kill").success());
    let (status, log, trace, summary) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    let fourth = fourth.as_str().expect("a run id").replace('-', "");
    assert_eq!((summary["state"].as_str(), summary["run"].as_str()), (Some("complete"), Some(fourth.as_str())));
    let news = trace.iter().filter(|r| r.event == TraceEvent::NewRun).count();
    assert_eq!(news, 3, "three resets: {trace:#?}");
    // Four runs in one trace; the third's token on r1 was cancelled by its abort, not handed back.
    check_trace_invariants_with_tokens_out(&trace, &chart, tokens_out(&trace));
}

/// `abort` with a robot cut off (its cable pulled out, past its lease): the run ends `aborted` at once, its token
/// abandoned with an alarm; the robot, cut off, does not know and its motion goes on. `baton run` waits for it;
/// when the cable is plugged back in, the robot is told, its motion is cancelled (the process is gone) and nothing
/// after it starts; then `baton run` exits 4.
#[tokio::test(flavor = "multi_thread")]
async fn abort_with_a_robot_cut_off_tells_it_once_it_is_back() {
    let mut cluster = Cluster::with_router().await;
    let dir = cluster.dir.path().to_path_buf();
    let pid_file = dir.join("motion.pid");
    let chart = cell_with(&dir, &format!("echo $$$$ > {}; exec sleep 100", pid_file.display()));
    let mut coordinator = cluster.coordinator_joining(&chart, &["--abort-wait", "60s"]);
    coordinator.wait_ready().await;
    let cable = baton_host::cable::Cable::lay(cluster.router_addr(), 1).await.expect("lay r1's cable");
    cluster.agent_at(&cable.endpoint(), "r1", &[], &["--allow-shell", "--lease-ms", "1000", "--verbose"]);
    cluster.agent("r2", &[], &["--allow-shell"]);
    wait_for_mark(&dir, "start MoveA1").await;
    cable.cut();
    coordinator.wait_for_trace("r1 lost", |r| r.event == TraceEvent::AgentLost && r.name == "r1").await;
    let (ok, said) = ctl(&cluster, &["abort", "--reason", "r1 unreachable"]).await;
    assert!(ok, "{said}");
    let s = wait_for_state(&cluster, "aborted").await;
    let abandoned = s["alarms"].as_array().and_then(|a| {
        a.iter().find(|x| x["message"].as_str().is_some_and(|m| m.contains("abandoned: `r1` could not be told")))
    });
    assert!(abandoned.is_some(), "{s}");
    let pid = std::fs::read_to_string(&pid_file).expect("the motion wrote its pid");
    let proc = PathBuf::from(format!("/proc/{}", pid.trim()));
    assert!(proc.exists(), "cut off, r1 does not know: its motion still runs");
    cable.heal();
    let (status, log, trace, summary) = coordinator.finish().await;
    assert_eq!(status.code(), Some(4), "{log}");
    assert_eq!(summary["state"], "aborted");
    let aborted = trace.iter().position(|r| r.event == TraceEvent::State && r.name == "aborted").expect("aborted");
    let told = trace.iter().position(|r| r.event == TraceEvent::Told && r.name == "r1");
    let told = told.unwrap_or_else(|| panic!("r1 was never told: {trace:#?}"));
    assert!(told > aborted);
    // r1's token was abandoned while it was cut off: it never comes back.
    check_trace_invariants_with_tokens_out(&trace, &chart, tokens_out(&trace));
    cluster
        .wait_for_agent_trace("r1", "MoveA1 cancelled", |r| r.event == TraceEvent::SkillCancel && r.name == "MoveA1")
        .await;
    let gone = tokio::time::timeout(TIMEOUT, async {
        while proc.exists() && !std::fs::read_to_string(proc.join("stat")).unwrap_or_default().contains(") Z ") {
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    })
    .await;
    assert!(gone.is_ok(), "the motion's process {} still runs", pid.trim());
    assert!(!marks(&dir).iter().any(|l| l.contains("MoveA2")), "{:?}", marks(&dir));
}

/// `baton ctl … --wait` rides out a moment in which no run answers: the run's session to the router dropped and made
/// again (zenoh-link-tls does so under load), as the deploying chapter's `hold --wait` once met. A stand-in run on
/// the test's router takes the hold, answers `holding`, stops answering for a second, then answers `held`.
#[tokio::test(flavor = "multi_thread")]
async fn ctl_wait_asks_again_while_its_run_is_briefly_unreachable() {
    use baton_proto::cluster::keys;
    use baton_proto::cluster::runtime::packml::State;
    use baton_proto::cluster::wire::{self, ChartHash, CtlReply, RunId, StatusReport};

    let cluster = Cluster::with_router().await;
    let run = RunId(uuid::Uuid::from_u128(0x5eed));
    let status = move |state| StatusReport {
        run,
        chart: "stand_in".into(),
        hash: ChartHash("1".into()),
        t_ms: 0,
        started_ms: 0,
        unix_ms: 0,
        active_steps: Vec::new(),
        tokens: Vec::new(),
        agents: Vec::new(),
        state,
        available: Vec::new(),
        alarms: Vec::new(),
        shelved: Vec::new(),
        held: Vec::new(),
        mode: Default::default(),
        waiting: Vec::new(),
        why: Vec::new(),
        messages_dropped: 0,
        values: Vec::new(),
        rerun: None,
    };
    let session = cluster.watch().await;
    let ctl = session.declare_queryable(format!("baton/run/{}/ctl/*", run.key())).await.expect("ctl queryable");
    let ctl_task = tokio::spawn(async move {
        while let Ok(q) = ctl.recv_async().await {
            let reply = CtlReply {
                chart: "stand_in".into(),
                ok: true,
                message: "the run is holding".into(),
                state: State::Holding,
                available: Vec::new(),
            };
            let _ = q.reply(q.key_expr().clone(), wire::encode(&reply)).await;
        }
    });
    // The first question about its status finds it holding; then it is unreachable for a second; then held.
    let statuses = session.declare_queryable(keys::status(run)).await.expect("status queryable");
    let ask = tokio::spawn({
        let (ep, dir) = (cluster.endpoint.clone(), cluster.dir.path().to_path_buf());
        async move {
            tokio::process::Command::new(baton_tests::loopback::bin("baton"))
                .args(["ctl", "--connect", &ep, "hold", "--wait"])
                .current_dir(dir)
                .kill_on_drop(true)
                .output()
                .await
                .expect("baton ctl ran")
        }
    });
    let q = tokio::time::timeout(TIMEOUT, statuses.recv_async()).await.expect("asked for its status").expect("query");
    q.reply(keys::status(run), wire::encode(&status(State::Holding))).await.expect("reply");
    drop(q);
    drop(statuses);
    // Unreachable: what the client asks now finds no run. (The outage's length is the scenario, not a wait for an event.)
    tokio::time::sleep(Duration::from_secs(1)).await;
    let statuses = session.declare_queryable(keys::status(run)).await.expect("status queryable again");
    let answering = tokio::spawn(async move {
        while let Ok(q) = statuses.recv_async().await {
            let _ = q.reply(keys::status(run), wire::encode(&status(State::Held))).await;
        }
    });
    let out = tokio::time::timeout(TIMEOUT, ask).await.expect("ctl --wait ended").expect("joined");
    let (stdout, stderr) = (String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(out.status.success(), "{stdout}\n{stderr}");
    assert!(stdout.contains("the run is held"), "{stdout}\n{stderr}");
    ctl_task.abort();
    answering.abort();
}
