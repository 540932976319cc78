//! Standby coordinators on a real etcd (Debian's etcd-server 3.4.23, three members on loopback started by the
//! test): two coordinators of one run, each in a folder of its own, keep its journal in etcd and stand in its
//! election (`baton run --journal etcd://…`, as `deploy/systemd/baton-standby@.service` runs it); one coordinates
//! and the other stands by; the active one killed with SIGKILL mid-branch, the standby wins and goes on from the
//! journal in etcd, and the run completes as one run — every part once, the trace's invariants holding, `baton
//! replay` rebuilding its trace from etcd — while an agent refuses what the deposed coordinator sends. Without
//! etcd's quorum a coordinator stops acting and says so; with the quorum back, it wins again and completes the run.
//! A coordinator cut off from etcd (a journal folder the pair shares, `--election`) stops acting before its standby
//! takes over. And a deposed coordinator's write to the journal in etcd is refused.

use baton_proto::cluster::keys;
use baton_proto::cluster::wire::{self, ToAgent};
use baton_proto::exec::trace::{TraceEvent, TraceRecord};
use baton_proto::testing::simulated_cluster::{Faults, SimCluster};
use baton_tests::etcd::Etcd;
use baton_tests::loopback::{
    check_trace_invariants, cmd_key_of, dispatches, next_dispatch, read_trace, repo, status_of, step_id, Cluster,
    Coordinator, Samples, TIMEOUT,
};
use baton_tests::{http, unit};

baton_tests::harness_main!(
    tokio a_standby_takes_over_from_a_killed_coordinator_and_the_deposed_ones_commands_are_refused,
    tokio without_etcds_quorum_the_coordinator_stops_acting_and_the_run_goes_on_when_it_is_back,
    tokio a_coordinator_cut_off_from_etcd_stops_acting_before_its_standby_takes_over_and_then_stands_by,
    tokio a_coordinator_paused_past_its_lease_adds_nothing_to_the_journal_in_etcd_once_it_wakes,
    tokio a_coordinator_whose_leadership_key_is_gone_is_refused_its_next_write_and_stops_acting,
    tokio over_etcds_tls_the_journal_and_the_election_hold_and_without_a_client_certificate_etcd_answers_nothing,
    tokio with_etcds_auth_on_a_coordinator_signs_in_as_its_user_and_reaches_only_its_own_keys,
);

const PARTS: &str = "2";

fn election(etcd: &Etcd) -> String {
    format!("etcd://{}/baton-test", etcd.endpoints())
}

/// A coordinator's arguments with the journal in etcd (and the election at the same place), snapshotted every 3
/// records — the run's records come with its events, a few before the first picks — and every segment kept: a takeover resumes from a snapshot in etcd, and `baton
/// replay` rebuilds the run from its start.
fn in_etcd(etcd: &Etcd) -> Vec<String> {
    let journal = election(etcd);
    let parts = format!("parts={PARTS}");
    ["--set", &parts, "--journal", &journal, "--lease", "2", "--snapshot-every", "3", "--journal-keep", "all"]
        .map(String::from)
        .to_vec()
}

fn args(cluster: &Cluster, etcd: &Etcd) -> Vec<String> {
    args_with(cluster, &election(etcd))
}

/// A coordinator's arguments with the journal in the cluster's folder and the election on etcd.
fn args_with(cluster: &Cluster, election: &str) -> Vec<String> {
    let journal = cluster.dir.path().join("journal");
    let journal = journal.to_str().expect("utf-8 path").to_string();
    ["--set", &format!("parts={PARTS}"), "--journal", &journal, "--election", election, "--lease", "2"]
        .map(String::from)
        .to_vec()
}

/// The term a coordinator said it won at, in its finished log ("coordinating at term N").
fn term_in(log: &str) -> u64 {
    let at = log.find("coordinating at term ").unwrap_or_else(|| panic!("no term in the log:\n{log}"));
    let digits: String = log[at + 21..].chars().take_while(char::is_ascii_digit).collect();
    digits.parse().expect("a term")
}

/// Asks `baton status --election … --json` until a run answers with coordinators that satisfy `done`; returns them.
async fn coordinators_once(
    cluster: &Cluster,
    etcd: &Etcd,
    done: impl Fn(&serde_json::Value) -> bool,
) -> serde_json::Value {
    let election = election(etcd);
    let mut last = serde_json::Value::Null;
    let found = tokio::time::timeout(TIMEOUT, async {
        loop {
            if let Some(status) = cluster.status_json(&["--election", &election]).await {
                last = status["coordinators"].clone();
                if done(&last) {
                    return last.clone();
                }
            }
        }
    })
    .await;
    found.unwrap_or_else(|_| panic!("the coordinators never became what the test awaits; last seen: {last}"))
}

/// Whether a candidate of the election is `coordinator`'s process (`… (pid N)`).
fn name_of(candidate: &serde_json::Value, coordinator: &Coordinator) -> bool {
    let pid = coordinator.child.id().expect("a live process");
    candidate["name"].as_str().is_some_and(|n| n.ends_with(&format!("(pid {pid})")))
}

/// Asks `baton status` until no run answers, calling `meanwhile` after each answer.
async fn until_no_run_answers(cluster: &Cluster, mut meanwhile: impl FnMut()) {
    let gone = tokio::time::timeout(TIMEOUT, async {
        while cluster.status_json(&[]).await.is_some() {
            meanwhile();
        }
    })
    .await;
    assert!(gone.is_ok(), "the run still answers after {TIMEOUT:?}");
}

/// Waits for the console's page to be told of coordinators whose terms (the active one's first) satisfy `done`;
/// returns them.
async fn console_terms(page: &mut http::Events, done: impl Fn(&[u64]) -> bool) -> Vec<u64> {
    let mut last = serde_json::Value::Null;
    while let Some((event, data)) = page.next().await {
        if event != "state" {
            continue;
        }
        last = serde_json::from_str(&data).expect("a state");
        let terms: Vec<u64> = last["coordinators"]
            .as_array()
            .map(|c| c.iter().filter_map(|c| c["term"].as_u64()).collect())
            .unwrap_or_default();
        if done(&terms) {
            return terms;
        }
    }
    panic!("the console never showed the coordinators awaited; its last state's: {}", last["coordinators"]);
}

/// Starts the three robots, and returns once the first part's picks are under way (Pick3 dispatched).
async fn robots_picking(cluster: &mut Cluster, cmds: &Samples, chart: &std::path::Path) {
    for robot in ["robot1", "robot2", "robot3"] {
        cluster.agent(robot, &[], &[]);
    }
    next_dispatch(cmds, step_id(chart, "Pick3"), 1).await;
}

/// The run made its parts as one run makes them: the trace's invariants hold, every part is counted, and every
/// pick and assembly was sent once per part — however many coordinators the run had.
fn made_every_part_once(trace: &[TraceRecord], summary: &serde_json::Value, log: &str, chart: &std::path::Path) {
    check_trace_invariants(trace, chart);
    assert_eq!(summary["vars"]["done"], PARTS, "{log}");
    // The same final values as the cell `baton test` simulates (`baton sim` runs no skills), the takeover
    // notwithstanding.
    let source = std::fs::read_to_string(chart).expect("the chart");
    let source = source.replace("parts : INT := 2", &format!("parts : INT := {PARTS}"));
    let robots: [(&str, &[&str]); 3] = [("robot1", &[]), ("robot2", &[]), ("robot3", &[])];
    let mut sim = SimCluster::new(&source, &robots, Faults::default(), 1);
    assert!(sim.run(120_000), "the simulated cell ends");
    for name in ["done", "picked1", "picked2", "picked3", "assembled"] {
        let expected = sim.shown(name).expect("a variable of the chart");
        assert_eq!(summary["vars"][name], expected.as_str(), "{name} as the simulated cell ends it\n{log}");
    }
    for step in ["Pick1", "Pick2", "Pick3", "Assemble"] {
        assert_eq!(dispatches(trace, step).len(), 2, "{step}: {:?}\n{log}", dispatches(trace, step));
    }
}

fn terms_heard(trace: &[TraceRecord]) -> Vec<String> {
    trace.iter().filter(|r| r.event == TraceEvent::Term).filter_map(|r| r.message.clone()).collect()
}

async fn a_standby_takes_over_from_a_killed_coordinator_and_the_deposed_ones_commands_are_refused() {
    let mut etcd = Etcd::start(3).await;
    let chart = repo("tests/charts/standby_cell.st");
    let mut cluster = Cluster::with_router().await;
    let watch = cluster.watch().await;
    let cmds = watch.declare_subscriber(keys::agent_cmd_any("*")).await.expect("command subscriber");
    // The pair as deploy/systemd/baton-standby@.service runs it, each in a folder of its own as on two machines:
    // nothing of the run is shared but etcd.
    let unit = std::fs::read_to_string(repo("deploy/systemd/baton-standby@.service")).expect("the unit");
    let election = election(&etcd);
    let coordinator = |name: &str| {
        let dir = cluster.dir.path().join(name);
        std::fs::create_dir_all(dir.join("etc")).expect("the test's /etc/baton");
        std::fs::copy(&chart, dir.join("etc/standby_cell.st")).expect("the chart in the test's /etc/baton");
        let (trace, summary) = (dir.join("trace.jsonl"), dir.join("summary.json"));
        let run_args =
            format!("--lease 2 --set parts={PARTS} --trace {} --summary {}", trace.display(), summary.display());
        let env =
            [("BATON_ROUTER", cluster.endpoint.as_str()), ("BATON_JOURNAL", &election), ("BATON_RUN_ARGS", &run_args)];
        unit::start(&unit::command(&unit, &dir, "standby_cell", &env), &trace, &summary)
    };
    let mut active = coordinator("a");
    active.wait_ready().await;
    let mut standby = coordinator("b");
    // Until the standby stands: `baton status --election` names the active coordinator and its standby.
    let seen = coordinators_once(&cluster, &etcd, |c| c["standbys"].as_array().is_some_and(|s| s.len() == 1)).await;
    let old_term = seen["active"]["term"].as_u64().expect("the active coordinator's term");
    assert!(name_of(&seen["active"], &active), "{seen}");
    assert!(name_of(&seen["standbys"][0], &standby), "{seen}");
    // The operator console names them too, and follows the takeover.
    let (_console, addr) = http::console(&cluster.endpoint, &["--election", &election]).await;
    let mut page = http::Events::open(&addr).await;
    let terms = console_terms(&mut page, |terms| terms.len() == 2).await;
    assert_eq!(terms[0], old_term, "the active coordinator first: {terms:?}");
    // One member of three lost: the cluster keeps its quorum, and nothing changes.
    etcd.kill(2).await;
    // Mid-branch: the three picks of the first part are under way (motions of 2 to 3 s).
    robots_picking(&mut cluster, &cmds, &chart).await;
    active.kill().await;
    standby.wait_ready().await;
    // The killed coordinator's candidacy ended with its lease: the standby is the active one, at a higher term, and
    // nobody stands by.
    let seen = coordinators_once(&cluster, &etcd, |c| c["active"]["term"] != old_term).await;
    let new_term = seen["active"]["term"].as_u64().expect("the active coordinator's term");
    assert!(new_term > old_term, "the standby won at term {new_term}, after term {old_term}");
    assert!(name_of(&seen["active"], &standby), "{seen}");
    assert_eq!(seen["standbys"], serde_json::json!([]), "{seen}");
    console_terms(&mut page, |terms| terms == [new_term]).await;
    // The deposed coordinator's abort, as it would send it had it been paused rather than killed: each robot that
    // heard the new term refuses it.
    let said = format!("term {new_term}");
    let heard =
        |r: &TraceRecord| r.event == TraceEvent::Term && r.message.as_deref().is_some_and(|m| m.contains(&said));
    cluster.wait_for_agent_trace("robot1", "the new term", heard).await;
    let run = status_of(&watch, keys::status_any_run()).await.run;
    let abort = wire::encode_termed(&ToAgent::Abort { run }, old_term);
    watch.put(cmd_key_of(&watch, "robot1").await, abort).await.expect("put");
    let refused = |r: &TraceRecord| r.event == TraceEvent::StaleTerm && r.name == "abort";
    cluster.wait_for_agent_trace("robot1", "the deposed coordinator's abort refused", refused).await;

    let (status, log, trace, summary) = standby.finish().await;
    assert!(status.success(), "{log}");
    assert!(log.contains("resuming run"), "{log}");
    // Every pick and assembly sent once per part, the picks the killed coordinator sent included.
    made_every_part_once(&trace, &summary, &log, &chart);
    assert_eq!(summary["state"], "complete", "{log}");
    // The journal in etcd holds the whole run: replayed, it gives the trace the standby wrote (which begins with
    // the killed coordinator's part, replayed from etcd when it took over).
    let (said, replayed) = replayed_from_etcd(&cluster, &etcd).await;
    assert!(said.contains("it completed"), "{said}");
    assert_eq!(replayed, trace, "the replay from etcd rebuilds the trace the run wrote");
    // Each robot heard the coordinators' terms in order, the new one last: from the killed one's (if a message of
    // it reached the robot before the kill) to the standby's. And no motion ran twice: one pick per part.
    for robot in ["robot1", "robot2", "robot3"] {
        let heard = terms_heard(&cluster.agent_trace(robot));
        let expected: [&[String]; 2] = [
            &[format!("coordinator term {new_term} (was 0)")],
            &[format!("coordinator term {old_term} (was 0)"), format!("coordinator term {new_term} (was {old_term})")],
        ];
        let said: Vec<String> = heard.iter().map(|m| m.split(':').next().unwrap_or("").to_string()).collect();
        assert!(expected.contains(&said.as_slice()), "{robot} heard {heard:?}");
        let picks = cluster.agent_trace(robot).iter().filter(|r| r.event == TraceEvent::SkillStart).count();
        let expected = if robot == "robot1" { 4 } else { 2 };
        assert_eq!(picks, expected, "{robot}'s skills started, a pick (and for robot1 an assembly) per part");
    }
}

async fn without_etcds_quorum_the_coordinator_stops_acting_and_the_run_goes_on_when_it_is_back() {
    let mut etcd = Etcd::start(3).await;
    let chart = repo("tests/charts/standby_cell.st");
    let mut cluster = Cluster::with_router().await;
    let args = in_etcd(&etcd);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let watch = cluster.watch().await;
    let cmds = watch.declare_subscriber(keys::agent_cmd_any("*")).await.expect("command subscriber");
    let mut active = cluster.coordinator_joining(&chart, &args);
    active.wait_ready().await;
    // What a write to a socket whose peer is gone raises (etcd members are about to die under its connections): a
    // coordinator that dies of it leaves the run (it once did, killed by SIGPIPE, 1 run in 10).
    signal(&active, "PIPE");
    robots_picking(&mut cluster, &cmds, &chart).await;
    etcd.kill(1).await;
    etcd.kill(2).await;
    // Without a renewal it stops acting: its run no longer answers (the process lives on, waiting for etcd).
    until_no_run_answers(&cluster, || {}).await;
    if active.child.try_wait().expect("the process's state").is_some() {
        let (status, log, _, _) = active.finish().await;
        panic!("it left ({status}) rather than stand again in the same process:\n{log}");
    }
    // A quorum again: the same process wins again, at a higher term, and completes the run from its journal.
    etcd.restart(1).await;
    let (status, log, trace, summary) = active.finish().await;
    assert!(status.success(), "{log}");
    assert!(log.contains("stopped coordinating: no renewal of its lease was granted by etcd in time"), "{log}");
    assert!(log.contains("standing in the election again"), "{log}");
    assert!(log.contains("is kept in its journal"), "{log}");
    // It resumed from its latest snapshot in etcd (its trace file holds the run up to it).
    assert!(log.contains("from its journal (its snapshot at record"), "{log}");
    let terms: Vec<u64> = log.match_indices("coordinating at term ").map(|(at, _)| term_in(&log[at..])).collect();
    assert!(terms.len() == 2 && terms[1] > terms[0], "won twice, the second time at a higher term: {terms:?}");
    made_every_part_once(&trace, &summary, &log, &chart);
}

async fn a_coordinator_cut_off_from_etcd_stops_acting_before_its_standby_takes_over_and_then_stands_by() {
    let etcd = Etcd::start(3).await;
    let chart = repo("tests/charts/standby_cell.st");
    let mut cluster = Cluster::with_router().await;
    // The first coordinator reaches every etcd member through a cable of its own; the standby reaches them directly.
    let mut cables = Vec::new();
    for addr in etcd.client_addrs() {
        cables.push(baton_host::cable::Cable::lay(addr, 7).await.expect("lay a cable to etcd"));
    }
    let through: Vec<String> = cables.iter().map(|c| c.endpoint().replace("tcp/", "")).collect();
    let cut_off = args_with(&cluster, &format!("etcd://{}/baton-test", through.join(",")));
    let cut_off: Vec<&str> = cut_off.iter().map(String::as_str).collect();
    let direct = args(&cluster, &etcd);
    let direct: Vec<&str> = direct.iter().map(String::as_str).collect();
    let watch = cluster.watch().await;
    let cmds = watch.declare_subscriber(keys::agent_cmd_any("*")).await.expect("command subscriber");
    let mut active = cluster.coordinator_joining(&chart, &cut_off);
    active.wait_ready().await;
    let mut standby = cluster.coordinator_joining_as("-standby", &chart, &direct);
    let seen = coordinators_once(&cluster, &etcd, |c| c["standbys"].as_array().is_some_and(|s| s.len() == 1)).await;
    let old_term = seen["active"]["term"].as_u64().expect("the active coordinator's term");
    robots_picking(&mut cluster, &cmds, &chart).await;
    cables.iter().for_each(|c| c.cut());
    // It stops on its own deadline, a third of the lease before etcd can end the lease for the standby: once its run
    // no longer answers, the standby has not begun its own (its trace is still empty).
    until_no_run_answers(&cluster, || {
        assert_eq!(standby.trace_mark(), 0, "the standby acted while the cut-off coordinator still answered");
    })
    .await;
    assert_eq!(standby.trace_mark(), 0, "the standby acted before the cut-off coordinator stopped");
    standby.wait_ready().await;
    let seen = coordinators_once(&cluster, &etcd, |c| c["active"]["term"] != old_term).await;
    let new_term = seen["active"]["term"].as_u64().expect("the active coordinator's term");
    assert!(new_term > old_term, "the standby won at term {new_term}, after term {old_term}");
    // Reconnected, the first coordinator (the same process) stands by behind the standby.
    cables.iter().for_each(|c| c.heal());
    let seen = coordinators_once(&cluster, &etcd, |c| c["standbys"].as_array().is_some_and(|s| s.len() == 1)).await;
    assert!(name_of(&seen["active"], &standby) && name_of(&seen["standbys"][0], &active), "{seen}");
    let (status, log, trace, summary) = standby.finish().await;
    assert!(status.success(), "{log}");
    made_every_part_once(&trace, &summary, &log, &chart);
    // The run over, the active coordinator gave the election up: the one standing by wins at once, finds nothing
    // to take over, and leaves (status 0: its unit does not start it again).
    let (status, log, trace, _) = active.finish().await;
    assert!(status.success(), "{log}");
    assert!(log.contains("stopped coordinating: no renewal of its lease was granted by etcd in time"), "{log}");
    assert!(
        deposed_because(&trace, "no renewal of its lease was granted by etcd in time"),
        "its trace says why: {trace:?}"
    );
    assert!(log.contains(&format!("(term {new_term}); taking over")), "it stood by behind the standby: {log}");
    assert!(log.contains("is over (it completed): there is nothing to take over"), "{log}");
}

/// Whether a coordinator's trace says it stopped acting, for a reason that says `why`.
fn deposed_because(trace: &[TraceRecord], why: &str) -> bool {
    trace.iter().any(|r| r.event == TraceEvent::Deposed && r.message.as_deref().is_some_and(|m| m.contains(why)))
}

/// `baton replay --journal etcd://…` of the run's journal, which must succeed: what it says, and the trace it rebuilds.
async fn replayed_from_etcd(cluster: &Cluster, etcd: &Etcd) -> (String, Vec<TraceRecord>) {
    let replayed = cluster.dir.path().join("replayed.jsonl");
    let journal = election(etcd);
    let out = cluster.baton(&["replay", "--journal", &journal, "--trace", replayed.to_str().expect("utf-8")]).await;
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    (String::from_utf8_lossy(&out.stdout).into_owned(), read_trace(&replayed))
}

/// Sends `signal` (`STOP`, `CONT`) to a coordinator's process.
fn signal(coordinator: &Coordinator, signal: &str) {
    let pid = coordinator.child.id().expect("the coordinator runs").to_string();
    let status = std::process::Command::new("kill").args([&format!("-{signal}"), &pid]).status().expect("kill runs");
    assert!(status.success(), "kill -{signal} {pid}");
}

/// The pause that fools every lease (a GC pause, a VM frozen): the active coordinator stopped with SIGSTOP mid-branch
/// for longer than its lease, the standby takes over from the journal in etcd, then the paused one wakes — with its
/// timers due and a commit perhaps under way — and whatever it tries to write is refused: the journal in etcd, replayed,
/// is the trace the standby wrote, and each part was made once.
async fn a_coordinator_paused_past_its_lease_adds_nothing_to_the_journal_in_etcd_once_it_wakes() {
    let etcd = Etcd::start(3).await;
    let chart = repo("tests/charts/standby_cell.st");
    let mut cluster = Cluster::with_router().await;
    let args = in_etcd(&etcd);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let watch = cluster.watch().await;
    let cmds = watch.declare_subscriber(keys::agent_cmd_any("*")).await.expect("command subscriber");
    let mut active = cluster.coordinator_joining(&chart, &args);
    active.wait_ready().await;
    let mut standby = cluster.coordinator_joining_as("-standby", &chart, &args);
    let seen = coordinators_once(&cluster, &etcd, |c| c["standbys"].as_array().is_some_and(|s| s.len() == 1)).await;
    let old_term = seen["active"]["term"].as_u64().expect("the active coordinator's term");
    robots_picking(&mut cluster, &cmds, &chart).await;
    signal(&active, "STOP");
    let seen = coordinators_once(&cluster, &etcd, |c| c["active"]["term"] != old_term).await;
    assert!(name_of(&seen["active"], &standby), "the standby won: {seen}");
    standby.wait_ready().await;
    signal(&active, "CONT");
    let (status, log, trace, summary) = standby.finish().await;
    assert!(status.success(), "{log}");
    made_every_part_once(&trace, &summary, &log, &chart);
    let (_, replayed) = replayed_from_etcd(&cluster, &etcd).await;
    assert_eq!(replayed, trace, "the journal in etcd holds the standby's run, nothing of the paused one's");
    // Woken, the paused coordinator stopped acting (its deadline had passed, or etcd refused its write), stood
    // by, and found the run over once the standby gave the election up.
    let (status, log, _, _) = active.finish().await;
    assert!(status.success(), "{log}");
    assert!(log.contains("stopped coordinating"), "{log}");
    assert!(log.contains("is over (it completed): there is nothing to take over"), "{log}");
}

/// The fence of the journal itself: the active coordinator's leadership key deleted in etcd (as an operator with
/// etcdctl, or a bug, could) while its lease goes on being renewed — its own deadline never comes, and the standby
/// wins at once. Its next write to the journal is refused by etcd (the transaction compares the key's creation
/// revision with its term), and it stops acting; the standby's run completes with every part made once, and the
/// journal in etcd is the standby's run.
async fn a_coordinator_whose_leadership_key_is_gone_is_refused_its_next_write_and_stops_acting() {
    let etcd = Etcd::start(3).await;
    let chart = repo("tests/charts/standby_cell.st");
    let mut cluster = Cluster::with_router().await;
    let args = in_etcd(&etcd);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let watch = cluster.watch().await;
    let cmds = watch.declare_subscriber(keys::agent_cmd_any("*")).await.expect("command subscriber");
    let mut active = cluster.coordinator_joining(&chart, &args);
    active.wait_ready().await;
    let mut standby = cluster.coordinator_joining_as("-standby", &chart, &args);
    let seen = coordinators_once(&cluster, &etcd, |c| c["standbys"].as_array().is_some_and(|s| s.len() == 1)).await;
    let old_term = seen["active"]["term"].as_u64().expect("the active coordinator's term");
    robots_picking(&mut cluster, &cmds, &chart).await;
    let candidates = etcd.keys_under("baton-test/coordinator/").await;
    let (key, _) = candidates.iter().find(|(_, created)| *created == old_term).expect("the active one's key");
    etcd.delete(key).await;
    standby.wait_ready().await;
    let (status, log, trace, summary) = standby.finish().await;
    assert!(status.success(), "{log}");
    made_every_part_once(&trace, &summary, &log, &chart);
    let (_, replayed) = replayed_from_etcd(&cluster, &etcd).await;
    assert_eq!(replayed, trace, "the journal in etcd holds the standby's run");
    let (status, log, trace, _) = active.finish().await;
    assert!(status.success(), "{log}");
    // Refused whatever it wrote next: a commit, or a snapshot's chunk or head.
    let refused = format!("this coordinator's term {old_term} is over (its leadership key is gone or another's)");
    assert!(log.contains("stopped coordinating: etcd refused") && log.contains(&refused), "{log}");
    assert!(deposed_because(&trace, &refused), "its trace says why: {trace:?}");
    assert!(log.contains("is over (it completed): there is nothing to take over"), "{log}");
}

/// etcd as a plant runs it: its client port over TLS, and a client certificate its CA signed required of every
/// client (`--client-cert-auth`), the certificates made by `baton deploy certs` as the deploying chapter makes a
/// cell's. A coordinator given them (`--journal etcds://…?cacert=…&cert=…&key=…`) keeps its journal and stands in
/// its election there, and its run completes as the open one does; `baton status` reads the election and `baton
/// replay` the journal back over TLS. Without a client certificate, etcd answers nothing.
async fn over_etcds_tls_the_journal_and_the_election_hold_and_without_a_client_certificate_etcd_answers_nothing() {
    let chart = repo("tests/charts/standby_cell.st");
    let mut cluster = Cluster::with_router().await;
    let certs = cluster.dir.path().join("certs");
    let certs_arg = certs.to_str().expect("utf-8 path");
    let made =
        cluster.baton(&["deploy", "certs", "--ca", certs_arg, "etcd", "coordinator", "--san", "127.0.0.1"]).await;
    assert!(made.status.success(), "{}", String::from_utf8_lossy(&made.stderr));
    let etcd = Etcd::start_tls(&certs).await;
    let file = |name: &str| certs.join(name).display().to_string();
    let at = format!("{}/baton-test", etcd.tls_endpoints());
    let parts = format!("parts={PARTS}");
    // Without a client certificate etcd refuses the connection: reading the election fails, and says where.
    let no_cert = format!("etcds://{at}?cacert={}", file("ca.pem"));
    let out = cluster.baton(&["status", "--connect", &cluster.endpoint, "--election", &no_cert, "--json"]).await;
    let said = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "the election read without a client certificate");
    assert!(said.contains(&format!("etcd at https://{}", etcd.tls_endpoints())), "{said}");
    let journal = format!(
        "etcds://{at}?cacert={}&cert={}&key={}",
        file("ca.pem"),
        file("coordinator.pem"),
        file("coordinator.key")
    );
    let args = ["--set", &parts, "--journal", &journal, "--lease", "2", "--journal-keep", "all"];
    let watch = cluster.watch().await;
    let cmds = watch.declare_subscriber(keys::agent_cmd_any("*")).await.expect("command subscriber");
    let mut active = cluster.coordinator_joining(&chart, &args);
    active.wait_ready().await;
    robots_picking(&mut cluster, &cmds, &chart).await;
    let read = cluster.status_json(&["--election", &journal]).await.expect("the run answers");
    let term = read["coordinators"]["active"]["term"].as_u64();
    assert!(name_of(&read["coordinators"]["active"], &active), "read over TLS, the active one is it: {read}");
    let (status, log, trace, summary) = active.finish().await;
    assert!(status.success(), "{log}");
    assert_eq!(term, Some(term_in(&log)), "the term it won in etcd over TLS, as `baton status` read it:\n{log}");
    made_every_part_once(&trace, &summary, &log, &chart);
    assert!(!etcd.keys_under("baton-test/").await.is_empty(), "the journal is in etcd");
    let replayed = cluster.dir.path().join("replayed.jsonl");
    let out = cluster.baton(&["replay", "--journal", &journal, "--trace", replayed.to_str().expect("utf-8")]).await;
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(read_trace(&replayed), trace, "the journal read back over TLS is the run");
}

/// etcd with its auth on, as a plant's administrator sets it up with etcdctl: each cell's coordinator an etcd user
/// whose role reads and writes its own prefix alone, its password in a file (`?user=NAME&password-file=FILE`).
/// Signed in, the journal and the election hold and the run completes as the open one does, though etcd's sign-ins
/// last a second unused (`--auth-token-ttl 1`, where etcd's default is 300) and the run waits longer for its start.
/// No user, a wrong password and another cell's user are refused, each with etcd's reason.
async fn with_etcds_auth_on_a_coordinator_signs_in_as_its_user_and_reaches_only_its_own_keys() {
    let chart = repo("tests/charts/standby_cell.st");
    let mut cluster = Cluster::with_router().await;
    let etcd = Etcd::start_short_tokens(1).await;
    etcd.enable_auth(&[("cell1", "cell1-password", "baton-test/"), ("cell2", "cell2-password", "cell2/")]).await;
    let password = |file: &str, password: &str| {
        let path = cluster.dir.path().join(file);
        std::fs::write(&path, format!("{password}\n")).expect("write a password file");
        path.display().to_string()
    };
    let (right, wrong, other) = (
        password("cell1.password", "cell1-password"),
        password("wrong.password", "cell1-passwort"),
        password("cell2.password", "cell2-password"),
    );
    let at = format!("etcd://{}/baton-test", etcd.endpoints());
    for (election, says) in [
        (at.clone(), "user name is empty"),
        (format!("{at}?user=cell1&password-file={wrong}"), "authentication failed"),
        (format!("{at}?user=cell2&password-file={other}"), "permission denied"),
    ] {
        let out = cluster.baton(&["status", "--connect", &cluster.endpoint, "--election", &election, "--json"]).await;
        let said = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{election}: the election read");
        assert!(said.contains(says) && said.contains(&etcd.endpoints()), "{election}: {said}");
    }
    let journal = format!("{at}?user=cell1&password-file={right}");
    let parts = format!("parts={PARTS}");
    let args = ["--set", &parts, "--journal", &journal, "--lease", "2", "--journal-keep", "all", "--wait-start"];
    let watch = cluster.watch().await;
    let cmds = watch.declare_subscriber(keys::agent_cmd_any("*")).await.expect("command subscriber");
    let mut active = cluster.coordinator_joining(&chart, &args);
    active.wait_ready().await;
    let read = cluster.status_json(&["--election", &journal]).await.expect("the run answers");
    let term = read["coordinators"]["active"]["term"].as_u64();
    assert!(name_of(&read["coordinators"]["active"], &active), "read signed in, the active one is it: {read}");
    assert_eq!(read["state"], "idle", "{read}");
    // What is tested is time itself: waiting for an operator's start, the coordinator writes nothing to etcd, and
    // its sign-in expires (etcd checks once a second). The start is journaled with the expired token, which etcd
    // refuses: the coordinator signs in again and goes on.
    tokio::time::sleep(std::time::Duration::from_secs(3)).await;
    let out = cluster.baton(&["ctl", "--connect", &cluster.endpoint, "start"]).await;
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    robots_picking(&mut cluster, &cmds, &chart).await;
    let (status, log, trace, summary) = active.finish().await;
    assert!(status.success(), "{log}");
    assert_eq!(term, Some(term_in(&log)), "the term it won in etcd, as `baton status` read it:\n{log}");
    made_every_part_once(&trace, &summary, &log, &chart);
    let replayed = cluster.dir.path().join("replayed.jsonl");
    let out = cluster.baton(&["replay", "--journal", &journal, "--trace", replayed.to_str().expect("utf-8")]).await;
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(read_trace(&replayed), trace, "the journal read back from etcd, signed in, is the run");
    let out = cluster.baton(&["replay", "--journal", &at, "--trace", replayed.to_str().expect("utf-8")]).await;
    assert!(!out.status.success(), "the journal read without signing in");
}
