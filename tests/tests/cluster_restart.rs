//! A coordinator killed with SIGKILL and started again from its journal, with real processes on loopback.

use baton_proto::cluster::keys;
use baton_proto::cluster::wire::{self, Report};
use baton_proto::exec::trace::{TraceEvent, TraceRecord};
use baton_tests::loopback::{self, check_trace_invariants, dispatches, repo, step_id, Cluster, TIMEOUT};
use zenoh::qos::CongestionControl;

fn journal_args(cluster: &Cluster) -> Vec<String> {
    let journal = cluster.dir.path().join("journal");
    ["--set", "parts=1", "--journal", journal.to_str().expect("utf-8 path")].map(String::from).to_vec()
}

/// The coordinator dies while an agent assembles; the agent finishes while nobody coordinates (its done report
/// is seen on the wire, unanswered), and the coordinator started again from its journal takes that result
/// without sending the segment again.
#[tokio::test(flavor = "multi_thread")]
async fn a_coordinator_killed_mid_segment_resumes_from_its_journal() {
    let cell = repo("examples/cell.st");
    let mut cluster = Cluster::with_router().await;
    let args = journal_args(&cluster);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let watch = cluster.watch().await;
    let cmds = watch.declare_subscriber(keys::agent_cmd_any("*")).await.expect("command subscriber");
    let reports = watch.declare_subscriber("baton/run/*/report/*").await.expect("report subscriber");
    let mut coordinator = cluster.coordinator_joining(&cell, &args);
    coordinator.wait_ready().await;
    cluster.agent("robot1", &["assembler"], &[]);
    cluster.agent("robot2", &["assembler"], &[]);
    let (holder, token) = loopback::next_dispatch(&cmds, step_id(&cell, "Assemble"), 1).await;
    coordinator.kill().await;
    // The holder finishes with nobody to acknowledge it, and keeps its result: its done report goes out (and
    // out again, with backoff) unanswered.
    let done = tokio::time::timeout(TIMEOUT, async {
        while let Ok(sample) = reports.recv_async().await {
            if let Ok(r) = wire::decode::<Report>(&sample.payload().to_bytes()) {
                if r.token == token && r.done {
                    return r;
                }
            }
        }
        panic!("the report subscriber closed");
    })
    .await
    .expect("the holder finished Assemble while the coordinator was down");
    assert_eq!(done.agent, holder);
    let coordinator = cluster.coordinator_joining(&cell, &args);
    let (status, log, trace, summary) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    assert!(log.contains("resuming run"), "{log}");
    check_trace_invariants(&trace, &cell);
    assert_eq!(summary["vars"]["done"], "1", "{log}");
    assert_eq!(dispatches(&trace, "Assemble"), [(holder.clone(), Some(1))], "Assemble was sent once");
    let recover = trace.iter().position(|r| r.event == TraceEvent::Recover).expect("recover in the trace");
    let resume = trace.iter().position(|r| r.event == TraceEvent::Resume && r.name == "Assemble").expect("reconciled");
    assert_eq!(trace[resume].message.as_deref(), Some("still held by the agent"));
    let back = trace.iter().position(|r| r.event == TraceEvent::Return && r.name == "Assemble").expect("returned");
    assert!(recover < resume && resume < back, "recover, reconcile, then the held result");
    let motions = trace.iter().filter(|r| r.event == TraceEvent::ActionOn && r.name == "AssemblePart").count();
    assert_eq!(motions, 1, "the assembly motion ran once");
}

/// Snapshots every few records, every segment kept, every variable watched: the coordinator killed while an agent
/// assembles resumes from its last snapshot, not from the run's start; the trace file it leaves is the live run's up
/// to the kill, then the rest, the records after the snapshot written again as the live run wrote them — watched
/// values included; and `baton replay --watch`, which replays the whole journal from the run's start, rebuilds that
/// same trace record for record.
#[tokio::test(flavor = "multi_thread")]
async fn a_coordinator_resumes_from_its_last_snapshot_and_its_trace_goes_on_as_the_live_one() {
    let cell = repo("examples/cell.st");
    let mut cluster = Cluster::with_router().await;
    let journal = cluster.dir.path().join("journal");
    let journal_arg = journal.to_str().expect("utf-8 path");
    const WATCHED: [&str; 8] = ["parts", "done", "reworks", "picked1", "picked2", "assembled", "passed", "failed"];
    let watching: Vec<&str> = WATCHED.iter().flat_map(|v| ["--watch", v]).collect();
    let mut args = vec!["--set", "parts=1", "--journal", journal_arg, "--snapshot-every", "4", "--journal-keep", "all"];
    args.extend(&watching);
    let watch = cluster.watch().await;
    let cmds = watch.declare_subscriber(keys::agent_cmd_any("*")).await.expect("command subscriber");
    let mut coordinator = cluster.coordinator_joining(&cell, &args);
    coordinator.wait_ready().await;
    cluster.agent("robot1", &["assembler"], &[]);
    cluster.agent("robot2", &["assembler"], &[]);
    loopback::next_dispatch(&cmds, step_id(&cell, "Assemble"), 1).await;
    let trace_path = coordinator.trace.clone();
    coordinator.kill().await;
    // What the live run wrote (its last line, if the kill tore it, is not a record).
    let text = std::fs::read_to_string(&trace_path).expect("the live run's trace");
    let whole = &text[..text.rfind('\n').map_or(0, |i| i + 1)];
    let live: Vec<TraceRecord> = whole.lines().map(|l| serde_json::from_str(l).expect("a trace record")).collect();
    let segments = |dir: &std::path::Path| {
        let mut names: Vec<String> = std::fs::read_dir(dir)
            .expect("the journal folder")
            .map(|e| e.expect("an entry").file_name().into_string().expect("utf-8"))
            .filter(|n| n.starts_with("journal") && n.ends_with(".log"))
            .collect();
        names.sort();
        names
    };
    assert!(segments(&journal).len() >= 3, "snapshots before the kill: {:?}", segments(&journal));
    let coordinator = cluster.coordinator_joining(&cell, &args);
    let (status, log, trace, summary) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    assert!(log.contains("from its journal (its snapshot at record"), "{log}");
    check_trace_invariants(&trace, &cell);
    assert_eq!(summary["vars"]["done"], "1", "{log}");
    assert_eq!(dispatches(&trace, "Assemble").len(), 1, "Assemble was sent once");
    assert!(trace.len() > live.len() && trace[..live.len()] == live[..], "the live run's trace goes on unchanged");
    // The whole journal, replayed from the run's start, gives the trace the run wrote.
    let replayed = cluster.dir.path().join("replayed.jsonl");
    let mut replay = vec!["replay", "--journal", journal_arg, "--trace", replayed.to_str().unwrap()];
    replay.extend(&watching);
    let out = cluster.baton(&replay).await;
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(String::from_utf8_lossy(&out.stdout).contains("it completed"), "{}", String::from_utf8_lossy(&out.stdout));
    assert_eq!(loopback::read_trace(&replayed), trace, "the replay rebuilds the trace the run wrote");
    let values = trace.iter().filter(|r| r.event == TraceEvent::Value).count();
    assert!(values > WATCHED.len(), "the watched values are in it: {values}");
    // A segment missing from the middle is refused, not skipped.
    let names = segments(&journal);
    std::fs::remove_file(journal.join(&names[1])).expect("remove a segment");
    let out = cluster.baton(&["replay", "--journal", journal_arg]).await;
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("a segment is missing or damaged"), "{err}");
}

/// The usual setup, where the coordinator embeds the router: the agents lose the router with it, reconnect to
/// the new one, and the run goes on to the end.
#[tokio::test(flavor = "multi_thread")]
async fn agents_reconnect_to_a_coordinator_restarted_with_its_router() {
    let cell = repo("examples/cell.st");
    let mut cluster = Cluster::new();
    let args = journal_args(&cluster);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let mut coordinator = cluster.coordinator(&cell, &args);
    coordinator.wait_ready().await;
    let watch = cluster.watch().await;
    let cmds = watch.declare_subscriber(keys::agent_cmd_any("*")).await.expect("command subscriber");
    cluster.agent("robot1", &["assembler"], &[]);
    cluster.agent("robot2", &["assembler"], &[]);
    loopback::next_dispatch(&cmds, step_id(&cell, "Pick2"), 1).await;
    coordinator.kill().await;
    let coordinator = cluster.coordinator(&cell, &args);
    let (status, log, trace, summary) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    check_trace_invariants(&trace, &cell);
    assert_eq!(summary["vars"]["done"], "1", "{log}");
    assert_eq!(trace.iter().filter(|r| r.event == TraceEvent::Recover).count(), 1);
    for step in ["Pick1", "Pick2", "Assemble"] {
        assert_eq!(dispatches(&trace, step).len(), 1, "{step} dispatched once:\n{log}");
    }
}

/// A journal is resumed only by the chart version that wrote it, and a finished run is not run again.
#[tokio::test(flavor = "multi_thread")]
async fn a_journal_of_another_chart_version_or_a_finished_run_is_refused() {
    let cell = repo("examples/cell.st");
    let cluster = Cluster::new();
    let journal = cluster.dir.path().join("journal");
    let journal = journal.to_str().expect("utf-8 path");
    // A run that waits for agents that never come, killed outright (SIGKILL, a power cut): its journal stays
    // resumable.
    let mut coordinator = cluster.coordinator(&cell, &["--journal", journal]);
    coordinator.wait_for_trace("a token waiting for an agent", |r| r.event == TraceEvent::Wait).await;
    coordinator.kill().await;
    // The same chart with one value changed is another version.
    let source = std::fs::read_to_string(&cell).expect("cell chart");
    let changed = cluster.dir.path().join("cell_v2.st");
    std::fs::write(&changed, source.replacen("ms := 300", "ms := 301", 1)).expect("write");
    let endpoint = cluster.endpoint.clone();
    let out = cluster.baton(&["run", changed.to_str().unwrap(), "--listen", &endpoint, "--journal", journal]).await;
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("a run only resumes with the chart it started with"), "{err}");
    assert!(err.contains("cell_v2.st"), "{err}");
    // A chart that ends at once leaves a finished journal, which is not run again.
    let quick = cluster.dir.path().join("quick.st");
    std::fs::write(&quick, "PROGRAM Quick\nINITIAL_STEP S0: END_STEP\nEND_PROGRAM\n").expect("write");
    let quick_journal = cluster.dir.path().join("quick_journal");
    let quick_journal = quick_journal.to_str().unwrap();
    let run = ["run", quick.to_str().unwrap(), "--listen", &endpoint, "--journal", quick_journal];
    let first = cluster.baton(&run).await;
    assert!(first.status.success(), "{}", String::from_utf8_lossy(&first.stderr));
    let again = cluster.baton(&run).await;
    let err = String::from_utf8_lossy(&again.stderr);
    assert_eq!(again.status.code(), Some(2), "{err}");
    assert!(err.contains("is over (it completed)"), "{err}");
    // Ctrl-C (SIGINT, a person at the terminal) is an operator's stop: the run ends `stopped`, exit 3, its journal
    // closed as ended — and a resume says how it ended.
    let stopped_journal = cluster.dir.path().join("stopped_journal");
    let stopped_journal = stopped_journal.to_str().unwrap();
    let mut coordinator = cluster.coordinator(&cell, &["--journal", stopped_journal]);
    coordinator.wait_for_trace("a token waiting for an agent", |r| r.event == TraceEvent::Wait).await;
    let pid = coordinator.child.id().expect("running").to_string();
    assert!(std::process::Command::new("kill").args(["-INT", &pid]).status().expect("kill").success());
    let (status, log, trace, _) = coordinator.finish().await;
    assert_eq!(status.code(), Some(3), "{log}");
    let states: Vec<&str> = trace.iter().filter(|r| r.event == TraceEvent::State).map(|r| r.name.as_str()).collect();
    assert_eq!(states, ["stopping", "stopped"], "{log}");
    let again =
        cluster.baton(&["run", cell.to_str().unwrap(), "--listen", &endpoint, "--journal", stopped_journal]).await;
    let err = String::from_utf8_lossy(&again.stderr);
    assert_eq!(again.status.code(), Some(2), "{err}");
    assert!(err.contains("is over (it was stopped)"), "{err}");
    let replay = cluster.baton(&["replay", "--journal", stopped_journal]).await;
    let said = String::from_utf8_lossy(&replay.stdout);
    assert!(replay.status.success() && said.contains("it was stopped"), "{said}");
}

/// A peer floods the run with what the coordinator refuses — a megabyte at a time from an agent it does not know,
/// reports of a token nobody holds —: none of it is journaled (a resume would replay it all), and the run goes on.
#[tokio::test(flavor = "multi_thread")]
async fn what_the_coordinator_refuses_never_reaches_its_journal() {
    use baton_proto::cluster::wire::{RunId, TokenId, VarUpdate, VarValue};
    let chart = repo("tests/charts/selection_segment.st");
    let mut cluster = Cluster::new();
    let journal = cluster.dir.path().join("journal");
    let mut coordinator = cluster.coordinator(&chart, &["--journal", journal.to_str().expect("utf-8 path")]);
    coordinator.wait_ready().await;
    // The run's queryables reach the router a moment after its first trace record.
    let first = tokio::time::timeout(TIMEOUT, async {
        loop {
            if let Some(s) = cluster.status_json(&[]).await {
                return s;
            }
        }
    })
    .await
    .expect("baton status answers");
    let run = RunId(uuid::Uuid::parse_str(first["run"].as_str().expect("a run id")).expect("a run id"));
    let rogue = cluster.watch().await;
    const FLOOD: usize = 40;
    // Blocking puts: a put's default, `Drop`, lets Zenoh give up on a message its queue cannot take in time (a
    // fragmented one's fragments within 50 ms by zenoh 1.10.2's defaults); with it, on a loaded machine, the
    // coordinator counted 79 of the 80 messages.
    let put = |key: String, bytes: Vec<u8>| rogue.put(key, bytes).congestion_control(CongestionControl::Block);
    let big = VarValue { var: 0, value: wire::WireValue::Str("x".repeat(1_000_000)) };
    for seq in 0..FLOOD as u64 {
        let update = VarUpdate {
            run,
            from: "ghost".into(),
            incarnation: uuid::Uuid::from_u128(9),
            seq,
            vars: vec![big.clone()],
        };
        put(keys::vars(run, "ghost"), wire::encode(&update)).await.expect("put");
        let report = Report {
            run,
            agent: "ghost".into(),
            incarnation: uuid::Uuid::from_u128(9),
            token: TokenId(uuid::Uuid::from_u128(seq as u128)),
            epoch: 1,
            seq: 0,
            events: Vec::new(),
            vars: vec![big.clone()],
            vars_seq: 0,
            done: true,
        };
        put(keys::report(run, "ghost"), wire::encode(&report)).await.expect("put");
    }
    // Every message of the flood refused before the run goes on, as `baton status` counts them.
    let refused = tokio::time::timeout(TIMEOUT, async {
        loop {
            let dropped = cluster.status_json(&[]).await.and_then(|s| s["messages_dropped"].as_u64()).unwrap_or(0);
            if dropped >= 2 * FLOOD as u64 {
                return dropped;
            }
        }
    })
    .await;
    assert!(refused.is_ok(), "not all refused; the coordinator's log:\n{}", coordinator.unread_log().await);
    cluster.agent("r1", &[], &[]);
    let go = cluster.baton(&["set", "--connect", &cluster.endpoint, "go=true"]).await;
    assert!(go.status.success(), "{}", String::from_utf8_lossy(&go.stderr));
    let (status, log, trace, summary) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    check_trace_invariants(&trace, &chart);
    assert!(summary["messages_dropped"].as_u64().unwrap_or(0) >= 2 * FLOOD as u64, "{summary}");
    let size: u64 = std::fs::read_dir(&journal)
        .expect("the journal")
        .map(|e| e.expect("entry").metadata().expect("size").len())
        .sum();
    // The run itself takes a few kilobytes; the flood was 80 MB.
    assert!(size < 1024 * 1024, "the journal holds {size} bytes");
    tokio::time::timeout(TIMEOUT, rogue.close()).await.ok();
}

/// A run that waits for its start, on a journal: `x` is set eight times, each acknowledged.
const WAITING: &str = "PROGRAM waiting\nVAR x : INT; END_VAR\nINITIAL_STEP A: END_STEP\n\
    TRANSITION FROM A TO B := x >= 8; END_TRANSITION\nSTEP B: END_STEP\nEND_PROGRAM\n";

/// Eight acknowledged `baton set`s, the coordinator SIGKILLed, and the length in the head of the commit that holds
/// the second damaged — a byte the frames' checksums once did not cover: `baton replay` and a resume both refuse
/// the journal, saying where the damage is, and neither changes a byte of it. With the byte put back, the run
/// resumes with every value it was told it had.
#[tokio::test(flavor = "multi_thread")]
async fn a_damaged_commit_is_refused_where_it_is_and_never_cut_off() {
    let mut cluster = Cluster::new();
    let chart = cluster.dir.path().join("waiting.st");
    std::fs::write(&chart, WAITING).expect("write the chart");
    let journal = cluster.dir.path().join("journal");
    let journal_arg = journal.to_str().expect("utf-8 path");
    let mut coordinator = cluster.coordinator(&chart, &["--journal", journal_arg, "--wait-start"]);
    coordinator.wait_ready().await;
    for n in 1..=8 {
        let out = cluster.baton(&["set", "--connect", &cluster.endpoint, &format!("x={n}")]).await;
        assert!(out.status.success(), "set x={n}: {}", String::from_utf8_lossy(&out.stderr));
    }
    coordinator.kill().await;
    // The commit holding `x = 2`: its head (`BTNC`, the segment format in coordinator/src/journal/segment.rs)
    // is the last before the record, and its length is bytes 20..24 of it.
    let path = journal.join("journal.log");
    let good = std::fs::read(&path).expect("the journal");
    let find = |needle: &[u8], before: usize| good[..before].windows(needle.len()).rposition(|w| w == needle);
    let record = find(br#""value":2"#, good.len()).expect("the second set's record");
    let head = find(b"BTNC", record).expect("its commit's head");
    let mut damaged = good.clone();
    damaged[head + 22] ^= 0x40;
    std::fs::write(&path, &damaged).expect("damage the journal");
    let replay = cluster.baton(&["replay", "--journal", journal_arg]).await;
    let err = String::from_utf8_lossy(&replay.stderr).to_string();
    assert!(!replay.status.success(), "{err}");
    let located = format!("at byte {head} is damaged");
    assert!(err.contains(&located) && err.contains("were acknowledged and cannot be read"), "{err}");
    assert_eq!(std::fs::read(&path).expect("the journal"), damaged, "a replay never writes");
    let endpoint = cluster.endpoint.clone();
    let resume =
        cluster.baton(&["run", chart.to_str().unwrap(), "--listen", &endpoint, "--journal", journal_arg]).await;
    let err = String::from_utf8_lossy(&resume.stderr).to_string();
    assert_eq!(resume.status.code(), Some(2), "{err}");
    assert!(err.contains(&located), "{err}");
    assert_eq!(std::fs::read(&path).expect("the journal"), damaged, "a refused resume never writes");
    // Undamaged, it resumes with all eight values, and the chart goes on with x = 8.
    std::fs::write(&path, &good).expect("repair the journal");
    let mut coordinator = cluster.coordinator(&chart, &["--journal", journal_arg]);
    coordinator.wait_ready().await;
    cluster.agent("nobody-needed", &[], &[]);
    let start = cluster.baton(&["ctl", "--connect", &endpoint, "start"]).await;
    assert!(start.status.success(), "{}", String::from_utf8_lossy(&start.stderr));
    let (status, log, _, summary) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    assert_eq!(summary["vars"]["x"], "8", "{log}");
}

/// What a journaled run refuses while it waits — for its start, or at its end — is answered at once with the
/// reason, as a run without a journal answers it: an input it does not have, a command not legal now, a
/// malformed request. (It once waited for a journal batch that a refusal never writes: the client gave up after
/// its three seconds, exit 2, "the run did not answer".)
#[tokio::test(flavor = "multi_thread")]
async fn refusals_are_answered_at_once_with_or_without_a_journal() {
    for journaled in [false, true] {
        let cluster = Cluster::new();
        let chart = cluster.dir.path().join("waiting.st");
        std::fs::write(&chart, WAITING).expect("write the chart");
        let journal = cluster.dir.path().join("journal");
        let mut args = vec!["--wait-start", "--stay"];
        if journaled {
            args.extend(["--journal", journal.to_str().expect("utf-8 path")]);
        }
        let mut coordinator = cluster.coordinator(&chart, &args);
        coordinator.wait_ready().await;
        let ep = cluster.endpoint.clone();
        let refused = |out: std::process::Output, why: &str| {
            let err = String::from_utf8_lossy(&out.stderr).to_string();
            assert_eq!(out.status.code(), Some(1), "journal {journaled}: {err}");
            assert!(err.contains(why), "journal {journaled}: {err}");
        };
        for state in ["idle", "aborted"] {
            refused(cluster.baton(&["set", "--connect", &ep, "nosuch=1"]).await, "nosuch");
            refused(cluster.baton(&["set", "--connect", &ep, "x=yes"]).await, "x");
            refused(cluster.baton(&["ctl", "--connect", &ep, "unhold"]).await, "refused");
            // A request no client of Baton's would send.
            let session = cluster.watch().await;
            let status = baton_coordinator_status(&session).await;
            let run: wire::RunId = serde_json::from_value(status["run"].clone()).expect("run id");
            for key in [keys::set(run, "tester"), keys::ctl(run, "tester")] {
                let replies = session
                    .get(&key)
                    .payload(b"{not a request".to_vec())
                    .timeout(std::time::Duration::from_secs(30))
                    .await
                    .expect("asked");
                let reply = replies.recv_async().await.expect("an answer");
                let text = String::from_utf8_lossy(&reply.result().expect("a reply").payload().to_bytes()).to_string();
                assert!(text.contains("malformed request") && text.contains("\"ok\":false"), "{state}: {text}");
            }
            tokio::time::timeout(TIMEOUT, session.close()).await.ok();
            if state == "idle" {
                let out = cluster.baton(&["ctl", "--connect", &ep, "abort", "--reason", "test"]).await;
                assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
            }
        }
        coordinator.kill().await;
    }
}

/// What `baton status --json` says of the only run behind the session's router.
async fn baton_coordinator_status(session: &zenoh::Session) -> serde_json::Value {
    let replies = session.get(keys::status_any_run()).await.expect("asked");
    let reply = replies.recv_async().await.expect("a run answers");
    let status: wire::StatusReport =
        wire::decode(&reply.result().expect("a reply").payload().to_bytes()).expect("a status");
    serde_json::to_value(status).expect("json")
}
