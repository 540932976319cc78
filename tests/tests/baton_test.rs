//! `baton test`, as users run it: the example cell's scenario passes with its faults striking; a fault of each
//! kind strikes in the project's own scenarios (`tests/baton_test/pass`); each kind of expectation fails with
//! the message it must (`fail/`); malformed files are said at FILE:LINE:COL with exit status 3; `--seeds` finds
//! a planted schedule-dependent bug and the command it prints replays exactly it; the JUnit report says it all.

use std::path::Path;
use std::process::{Command, Output};

use baton_proto::exec::trace::{TraceEvent, TraceRecord};
use baton_proto::testing::run::run;
use baton_proto::testing::scenario::{self, LoadError};
use baton_tests::loopback::{bin, read_trace, repo};

fn scenario(path: &str) -> scenario::Scenario {
    match scenario::load(&repo(path), &|p| std::fs::read_to_string(p)) {
        Ok(s) => s,
        Err(e) => panic!("{path}: {e:?}"),
    }
}

/// `baton test ARGS` from `dir`, failures kept under a temporary folder.
fn baton_test(dir: &Path, args: &[&str], out: &Path) -> (Output, String, String) {
    let o = Command::new(bin("baton"))
        .arg("test")
        .args(args)
        .arg("--out")
        .arg(out)
        .current_dir(dir)
        .output()
        .expect("run baton test");
    let (stdout, stderr) =
        (String::from_utf8_lossy(&o.stdout).to_string(), String::from_utf8_lossy(&o.stderr).to_string());
    (o, stdout, stderr)
}

fn count(trace: &[TraceRecord], event: TraceEvent, name: &str) -> usize {
    trace.iter().filter(|r| r.event == event && r.name == name).count()
}

fn the_example_cell_passes_with_a_robot_killed_and_an_inspection_failing_twice() {
    let sc = scenario("examples/cell.test.toml");
    let o = run(&sc, sc.seed);
    assert!(o.passed(), "{:?}\n{:?}", o.cases, o.errors);
    // What the scenario says happened did: assembler1 died holding Assemble, assembler2 took it in a new epoch,
    // and the inspection faulted twice before it passed.
    assert_eq!(count(&o.trace, TraceEvent::AgentLost, "assembler1"), 1, "{:#?}", o.trace);
    let again = o.trace.iter().find(|r| r.event == TraceEvent::Dispatch && r.name == "Assemble" && r.epoch == Some(2));
    assert_eq!(again.and_then(|r| r.agent.as_deref()), Some("assembler2"));
    assert_eq!(count(&o.trace, TraceEvent::SkillFault, "InspectPart"), 2);
    assert!(o.faults.iter().any(|(_, f)| f == "kill assembler1"), "{:?}", o.faults);
    let out = tempfile::tempdir().expect("tmp");
    let (status, stdout, _) = baton_test(&repo("examples"), &["cell.test.toml"], out.path());
    assert!(status.status.success(), "{stdout}");
    assert!(stdout.starts_with("running 1 run(s) of 1 scenario(s)"), "{stdout}");
    assert!(stdout.contains("\nPASS cell (cell.test.toml): 8 expectation(s), seed 1"), "{stdout}");
    assert!(stdout.contains("faster)"), "{stdout}");
    // The time given is the runs' own, summed over the threads they ran on: not called wall time.
    assert!(stdout.contains(" ms of run time (") && !stdout.contains("ms wall"), "{stdout}");
}

/// The operating examples — the demo cell held mid-part and unheld, the cell aborted, and a motion whose step passes
/// its maximum time and waits for an acknowledgement — pass on every seed, and what they say happened did.
fn the_operating_examples_hold_abort_and_acknowledge_on_every_seed() {
    let first = |t: &[TraceRecord], e: TraceEvent, name: &str| t.iter().position(|r| r.event == e && r.name == name);
    let hold = scenario("examples/cell_hold.test.toml");
    for seed in 0..16 {
        let o = run(&hold, seed);
        assert!(o.passed(), "seed {seed}: {:?}\n{:?}", o.cases, o.errors);
        let t = &o.trace;
        let held = first(t, TraceEvent::State, "held").expect("held");
        let unhold = t.iter().position(|r| r.event == TraceEvent::Command && r.name == "unhold").expect("unhold");
        assert!(first(t, TraceEvent::SkillDone, "AssemblePart").is_some_and(|d| d < held), "seed {seed}");
        assert!(first(t, TraceEvent::ActionOn, "InspectPart").is_some_and(|i| i > unhold), "seed {seed}");
        assert_eq!(count(t, TraceEvent::ActionOn, "AssemblePart"), 3, "seed {seed}: three parts, one assembly each");
    }
    let abort = scenario("examples/cell_abort.test.toml");
    for seed in 0..16 {
        let o = run(&abort, seed);
        assert!(o.passed(), "seed {seed}: {:?}\n{:?}", o.cases, o.errors);
        assert_eq!(count(&o.trace, TraceEvent::SkillDone, "AssemblePart"), 0, "seed {seed}: cancelled, not finished");
    }
    let modes = scenario("tests/baton_test/pass/modes.test.toml");
    for seed in 0..16 {
        let o = run(&modes, seed);
        assert!(o.passed(), "seed {seed}: {:?}\n{:?}", o.cases, o.errors);
        let confirms: Vec<&str> = o
            .trace
            .iter()
            .filter(|r| r.event == TraceEvent::Command && r.name == "confirm")
            .map(|r| r.by.as_deref().unwrap_or_default())
            .collect();
        assert_eq!(confirms, ["baton test", "baton test"], "seed {seed}");
    }
    // A run that stays: reset after it completes (each robot moves twice, in two runs), and cleared after an abort
    // (the aborted run's motions are cancelled, the next run's finish).
    for (name, done_per_robot) in [("reset", 2), ("clear", 1)] {
        let sc = scenario(&format!("tests/baton_test/pass/{name}.test.toml"));
        for seed in 0..16 {
            let o = run(&sc, seed);
            assert!(
                o.passed(),
                "{name} seed {seed}: {:?}
{:?}",
                o.cases,
                o.errors
            );
            let t = &o.trace;
            assert_eq!(count(t, TraceEvent::NewRun, "line"), 1, "{name} seed {seed}");
            assert_eq!(count(t, TraceEvent::SkillDone, "DoA"), done_per_robot, "{name} seed {seed}: {t:#?}");
            assert_eq!(count(t, TraceEvent::SkillDone, "DoB"), done_per_robot, "{name} seed {seed}");
            let new_run = first(t, TraceEvent::NewRun, "line").expect("the new run");
            assert!(t[..new_run].iter().all(|r| r.t_ms <= t[new_run].t_ms), "{name} seed {seed}: time goes on");
            assert!(t[new_run..].windows(2).all(|w| w[0].t_ms <= w[1].t_ms), "{name} seed {seed}: {t:#?}");
        }
    }
    let motion = scenario("examples/motion.test.toml");
    for seed in 0..16 {
        let o = run(&motion, seed);
        assert!(o.passed(), "seed {seed}: {:?}\n{:?}", o.cases, o.errors);
        let t = &o.trace;
        let alarm = t.iter().find(|r| r.event == TraceEvent::Alarm).expect("the supervision alarm");
        assert_eq!((alarm.name.as_str(), alarm.id), ("Moving", Some(1)));
        let ack = t.iter().find(|r| r.event == TraceEvent::Ack).expect("acknowledged");
        assert_eq!((ack.id, ack.by.as_deref()), (Some(1), Some("baton test")));
        assert_eq!(ack.message.as_deref(), Some("drive checked, it was only slow"));
        assert!(t.iter().any(|r| r.event == TraceEvent::AlarmClear && r.id == Some(1) && r.name == "Moving"));
    }
}

/// The README's example: the convergence waits for the slower robot, whatever each seed draws for it.
fn the_readme_example_waits_for_both_robots_on_every_seed() {
    let sc = scenario("examples/two_robots.test.toml");
    for seed in 0..32 {
        let o = run(&sc, seed);
        assert!(o.passed(), "seed {seed}: {:?}\n{:?}", o.cases, o.errors);
        let at =
            |event: TraceEvent, name: &str| o.trace.iter().find(|r| r.event == event && r.name == name).map(|r| r.t_ms);
        let done = at(TraceEvent::Activate, "Done").expect("Done reached");
        assert!(at(TraceEvent::Activate, "RightDone").is_some_and(|t| t <= done), "seed {seed}: {:#?}", o.trace);
        assert!(at(TraceEvent::Activate, "LeftDone").is_some_and(|t| t <= done), "seed {seed}: {:#?}", o.trace);
    }
}

fn a_fault_of_each_kind_strikes_and_the_run_survives_it() {
    let outcome = |name: &str| {
        let sc = scenario(&format!("tests/baton_test/pass/{name}.test.toml"));
        let o = run(&sc, sc.seed);
        assert!(o.passed(), "{name}: {:?}\n{:?}", o.cases, o.errors);
        o
    };
    // Killed, then a new process: the token goes to it in a new epoch.
    let o = outcome("restart");
    assert_eq!(count(&o.trace, TraceEvent::AgentLost, "r1"), 1);
    assert!(
        o.trace.iter().any(|r| r.event == TraceEvent::Dispatch && r.name == "A" && r.epoch == Some(2)),
        "{:#?}",
        o.trace
    );
    // Cut off within its lease: never lost, and its work is heard only once the link is back.
    let o = outcome("partition");
    assert_eq!(count(&o.trace, TraceEvent::AgentLost, "r2"), 0);
    let back = o.trace.iter().find(|r| r.event == TraceEvent::Return && r.name == "B").expect("B's token back");
    assert!(back.t_ms >= 400, "B's token came back at {} ms, while r2 was cut off", back.t_ms);
    // A lossy link: more messages than a clean run sends, and the same end.
    let o = outcome("link");
    assert!(o.faults.iter().any(|(_, f)| f.starts_with("drop 0.3, duplicate 0.3, delay up to 20ms on r1's link")));
    // The coordinator crashed and came back from its journal.
    let o = outcome("crash");
    assert!(o.trace.iter().any(|r| r.event == TraceEvent::Recover), "{:#?}", o.trace);
    // An input set when a step is active, and an agent that starts late.
    let o = outcome("when");
    let set = o.trace.iter().find(|r| r.event == TraceEvent::Set).expect("set");
    assert!((200..=215).contains(&set.t_ms), "set at {}", set.t_ms);
    let b = o.trace.iter().find(|r| r.event == TraceEvent::Dispatch && r.name == "B").expect("B dispatched");
    assert!(b.t_ms >= 1000 && b.agent.as_deref() == Some("r2"), "{b:?}");
}

fn each_kind_of_expectation_fails_with_its_message() {
    let cases = [
        ("reached", "expected step Broken is reached; it was never active"),
        ("reached_on", "expected step A is reached on r2; it was reached at 0s on r1"),
        ("order", "expected the steps in order Done → A; passed Done, then never A"),
        ("value", "at the end: first = 1 (expected 2)"),
        ("value_at", "at 100ms: first = 0 (expected 1)"),
        ("always", "`NOT B.X` was FALSE at 0s"),
        ("never", "`A.X AND B.X` was TRUE at 0s"),
        ("ends_by", "the chart ended at 301ms, after 100ms"),
        ("alarms", "never raised: `lost`"),
        ("state", "expected the run to end failed; it finished at 301ms"),
        ("states", "never reached `unholding` in that order; the states the run passed: holding, held"),
    ];
    let dir = repo("tests/baton_test");
    let out = tempfile::tempdir().expect("tmp");
    for (name, message) in cases {
        let file = format!("fail/{name}.test.toml");
        let (o, stdout, stderr) = baton_test(&dir, &[&file], out.path());
        assert_eq!(o.status.code(), Some(1), "{name}: {stdout}{stderr}");
        assert!(stdout.contains(&format!("FAIL {name} ({file})")), "{stdout}");
        assert!(stdout.contains(&format!("  {file}:14: ")), "the expectation's line: {stdout}");
        assert!(stdout.contains(message), "{name}: expected `{message}` in:\n{stdout}");
        // The failing run is kept: its trace, its recording, and how to run it again.
        let trace = out.path().join(format!("{name}-seed1.trace.jsonl"));
        assert!(stdout.contains(&format!("trace: {}", trace.display())), "{stdout}");
        let records = std::fs::read_to_string(&trace).expect("trace kept");
        assert!(records.lines().all(|l| serde_json::from_str::<TraceRecord>(l).is_ok()));
        assert!(out.path().join(format!("{name}-seed1.rrd")).is_file());
        assert!(stdout.contains(&format!("replay: baton test {file} --seed 1")), "{stdout}");
        assert!(stdout.contains("active steps"), "{stdout}");
    }
}

fn malformed_files_are_said_at_file_line_col_with_exit_status_3() {
    let dir = repo("tests/baton_test");
    let out = tempfile::tempdir().expect("tmp");
    let (o, stdout, stderr) = baton_test(&dir, &["malformed"], out.path());
    assert_eq!(o.status.code(), Some(3), "{stdout}{stderr}");
    let expected = [
        "malformed/commands.test.toml:11:11: error: `pause` is no command (they are: start, clear, reset, hold",
        "malformed/commands.test.toml:14:1: error: `ack` names its alarm: `target = 1`",
        "malformed/commands.test.toml:18:1: error: no agent named `r3` in the scenario (it has: r1, r2)",
        "malformed/commands.test.toml:24:19: error: `paused` is no run state",
        "malformed/commands.test.toml:27:11: error: `reset` needs a run that stays at its end: `stay = true` in [run]",
        "malformed/commands.test.toml:32:8: error: `state waiting`: `waiting` is not a run state (stopped, resetting,",
        "malformed/keys.test.toml:3:1: error: unknown field `untill`",
        "malformed/names.test.toml:10:1: error: no agent named `r3` in the scenario (it has: r1, r2)",
        "malformed/names.test.toml:14:1: error: the chart has no step `Finish`",
        "malformed/names.test.toml:18:11: error: `soon` is not a duration",
        "malformed/syntax.test.toml:4:9: error: unclosed array table, expected `]]`",
        "malformed/vacuous.test.toml:16:9: error: `Done.X AND first != 1` is not an expression",
        "malformed/vacuous.test.toml:18:1: error: `value` names no variable, so it could never fail",
        "malformed/vacuous.test.toml:21:1: error: action `MarkA` starts no skill, so `once_per_epoch` could never fail",
        "malformed/vacuous.test.toml:25:10: error: `1 = 1` reads no step and no variable and always holds",
        "malformed/vacuous.test.toml:28:9: error: `FALSE AND TRUE` reads no step and no variable and never holds",
    ];
    for e in expected {
        assert!(stderr.lines().any(|l| l.starts_with(e)), "expected `{e}` in:\n{stderr}");
    }
    assert!(stdout.contains("5 scenario(s): 0 passed, 0 failed, 5 malformed"), "{stdout}");
    // Malformed outranks failed: a folder of both exits 3.
    let (o, stdout, _) = baton_test(&dir, &["fail/value.test.toml", "malformed/keys.test.toml"], out.path());
    assert_eq!(o.status.code(), Some(3), "{stdout}");
}

fn a_scenario_whose_chart_is_missing_or_wrong_cannot_run() {
    let dir = tempfile::tempdir().expect("tmp");
    let write = |name: &str, text: &str| std::fs::write(dir.path().join(name), text).expect("write");
    write("gone.test.toml", "chart = \"nowhere.st\"\n\n[[expect]]\nstate = \"finished\"\n");
    write(
        "broken.st",
        "PROGRAM p\nINITIAL_STEP S: END_STEP\nTRANSITION FROM S TO T := nothing; END_TRANSITION\nEND_PROGRAM\n",
    );
    write("broken.test.toml", "chart = \"broken.st\"\n\n[[expect]]\nstate = \"finished\"\n");
    let out = dir.path().join("out");
    let (o, stdout, stderr) = baton_test(dir.path(), &["gone.test.toml"], &out);
    assert_eq!(o.status.code(), Some(2), "{stdout}{stderr}");
    assert!(stderr.contains("gone.test.toml:1:9: cannot read the chart"), "{stderr}");
    let (o, stdout, stderr) = baton_test(dir.path(), &["broken.test.toml"], &out);
    assert_eq!(o.status.code(), Some(2), "{stdout}{stderr}");
    assert!(stderr.contains("has errors (see `baton check`)"), "{stderr}");
    assert!(matches!(
        scenario::load(&dir.path().join("gone.test.toml"), &|p| std::fs::read_to_string(p)),
        Err(LoadError::CannotRun(_))
    ));
}

/// A skill name that no agent has (`motoin`) fails the scenario, in the simulated cell and with real processes
/// alike, with the nearest built-in name; said what it does (`[actions.X]`) or named in an agent's `skills`, a
/// custom skill runs; an agent whose `skills` lack it is sent nothing of the step and an alarm names it.
fn a_skill_nobody_has_fails_the_scenario_before_anything_runs() {
    let dir = tempfile::tempdir().expect("tmp");
    let write = |name: &str, text: &str| std::fs::write(dir.path().join(name), text).expect("write");
    let chart = |skill: &str| {
        format!(
            "PROGRAM p\nVAR picked : BOOL; END_VAR\nACTION Pick: {{skill := '{skill}', ms := 100}} END_ACTION\n\
             INITIAL_STEP Home: END_STEP\nTRANSITION FROM Home TO Grab := TRUE; END_TRANSITION\n\
             STEP Grab: {{agent := 'r1'}} Pick(N, picked); END_STEP\nTRANSITION FROM Grab TO Done := picked; END_TRANSITION\n\
             STEP Done: END_STEP\nEND_PROGRAM\n"
        )
    };
    write("typo.st", &chart("motoin"));
    write("grip.st", &chart("grip"));
    let expect_done = "[[agents]]\nname = \"r1\"\n\n[[expect]]\nreached = \"Done\"\n";
    write("typo.test.toml", &format!("chart = \"typo.st\"\n\n{expect_done}"));
    write("simulated.test.toml", &format!("chart = \"grip.st\"\n\n{expect_done}\n[actions.Pick]\nduration = \"1s\"\n"));
    write(
        "listed.test.toml",
        "chart = \"grip.st\"\n\n[[agents]]\nname = \"r1\"\nskills = [\"grip\"]\n\n[[expect]]\nreached = \"Done\"\n",
    );
    // r2 has the skill, r1 (where the step is placed) does not: nothing is sent to r1, and the chart waits.
    write(
        "lacking.test.toml",
        "chart = \"grip.st\"\n\n[[agents]]\nname = \"r1\"\nskills = [\"motion\"]\n\n[[agents]]\nname = \"r2\"\n\
         skills = [\"grip\"]\n\n[[expect]]\nnever = \"Done.X\"\n\n[[expect]]\nstate = \"running\"\n",
    );
    let out = dir.path().join("out");
    for mode in [&[][..], &["--cluster"][..]] {
        let args: Vec<&str> = mode.iter().copied().chain(["typo.test.toml"]).collect();
        let (o, stdout, stderr) = baton_test(dir.path(), &args, &out);
        assert_eq!(o.status.code(), Some(3), "{mode:?}: {stdout}{stderr}");
        assert!(
            stderr.contains("typo.test.toml:1:9: error: action `Pick` of the chart uses skill `motoin`")
                && stderr.contains("did you mean `motion`?"),
            "{mode:?}: {stderr}"
        );
    }
    let (o, stdout, stderr) = baton_test(dir.path(), &["simulated.test.toml", "listed.test.toml"], &out);
    assert_eq!(o.status.code(), Some(0), "{stdout}{stderr}");
    let lacking = scenario(dir.path().join("lacking.test.toml").to_str().expect("utf-8"));
    let outcome = run(&lacking, lacking.seed);
    let failures: Vec<_> = outcome.cases.iter().filter_map(|c| c.failure.as_ref()).collect();
    assert!(outcome.passed(), "{:?} {failures:?}", outcome.errors);
    let alarms: Vec<&TraceRecord> = outcome.trace.iter().filter(|r| r.event == TraceEvent::Alarm).collect();
    assert!(
        alarms.iter().any(|r| r.name == "r1"
            && r.message.as_deref().is_some_and(|m| m.contains("has no skill `grip`") && m.contains("step `Grab`"))),
        "{alarms:?}"
    );
    assert_eq!(count(&outcome.trace, TraceEvent::Dispatch, "Grab"), 0, "a step went to an agent without its skill");
}

fn seeds_find_a_planted_race_and_the_printed_command_replays_exactly_it() {
    let dir = repo("tests/baton_test");
    let out = tempfile::tempdir().expect("tmp");
    // Its own seed hides the bug.
    let (o, stdout, _) = baton_test(&dir, &["seeds/race.test.toml"], out.path());
    assert!(o.status.success(), "{stdout}");
    let (o, stdout, _) = baton_test(&dir, &["seeds/race.test.toml", "--seeds", "40"], out.path());
    assert_eq!(o.status.code(), Some(1), "{stdout}");
    let failed: usize = stdout
        .split(" of 40 run(s) failed")
        .next()
        .and_then(|s| s.rsplit(' ').next())
        .and_then(|n| n.parse().ok())
        .expect("a count of failed runs");
    assert!(failed > 0 && failed < 40, "some schedules hit the race, not all: {stdout}");
    let replay = stdout.lines().find_map(|l| l.trim().strip_prefix("replay: baton test ")).expect("a replay command");
    let args: Vec<&str> = replay.split_whitespace().collect();
    let seed = args.last().expect("seed").to_string();
    let (o, again, _) = baton_test(&dir, &args, out.path());
    assert_eq!(o.status.code(), Some(1), "the replay fails too: {again}");
    assert!(again.contains(&format!("1 of 1 run(s) failed (seed {seed})")), "{again}");
    assert!(again.contains("first = 2 (expected 1)"), "{again}");
    // The same seed, the same run: its trace is the same record for record.
    let sc = scenario("tests/baton_test/seeds/race.test.toml");
    let seed: u64 = seed.parse().expect("a number");
    assert_eq!(run(&sc, seed).trace, run(&sc, seed).trace);
}

fn the_junit_report_has_a_suite_per_file_and_a_case_per_expectation() {
    let dir = repo("tests/baton_test");
    let out = tempfile::tempdir().expect("tmp");
    let report = out.path().join("report.xml");
    let report_arg = report.to_str().expect("utf-8");
    let (o, stdout, _) = baton_test(
        &dir,
        &["pass/crash.test.toml", "fail", "malformed/syntax.test.toml", "--junit", report_arg],
        out.path(),
    );
    assert_eq!(o.status.code(), Some(3), "{stdout}");
    let xml = std::fs::read_to_string(&report).expect("report written");
    let doc = roxmltree::Document::parse(&xml).expect("well-formed XML");
    let root = doc.root_element();
    assert_eq!(root.tag_name().name(), "testsuites");
    let suites: Vec<_> = root.children().filter(|n| n.has_tag_name("testsuite")).collect();
    assert_eq!(suites.len(), 13, "one per file");
    assert_eq!(root.attribute("failures"), Some("11"));
    assert_eq!(root.attribute("errors"), Some("1"));
    let crash = suites.iter().find(|s| s.attribute("name") == Some("crash")).expect("crash suite");
    assert_eq!(crash.attribute("file"), Some("pass/crash.test.toml"));
    let cases: Vec<_> = crash.children().filter(|n| n.has_tag_name("testcase")).collect();
    assert_eq!(cases.len(), 3);
    let text = std::fs::read_to_string(dir.join("pass/crash.test.toml")).expect("read");
    let first = text.lines().position(|l| l == "[[expect]]").expect("an expectation") + 1;
    assert_eq!(cases[0].attribute("line"), Some(first.to_string().as_str()));
    assert!(cases.iter().all(|c| !c.children().any(|n| n.has_tag_name("failure"))));
    let value = suites.iter().find(|s| s.attribute("name") == Some("value")).expect("value suite");
    let failure = value.descendants().find(|n| n.has_tag_name("failure")).expect("a failure");
    assert!(failure.attribute("message").is_some_and(|m| m.contains("first = 1 (expected 2)")));
    let system_out = value.descendants().find(|n| n.has_tag_name("system-out")).and_then(|n| n.text()).unwrap_or("");
    assert!(system_out.contains("timeline:") && system_out.contains("activate Done"), "{system_out}");
    // And as CI's tools read it: junitparser, a JUnit reader we did not write.
    baton_tests::peer::require_python("junitparser", "junitparser");
    let script = "import sys, junitparser\n\
        x = junitparser.JUnitXml.fromfile(sys.argv[1])\n\
        cases = [c for s in x for c in s]\n\
        bad = [c for c in cases if c.result]\n\
        print(len(list(x)), len(cases), len(bad))\n";
    let o = Command::new("python3").args(["-c", script, report_arg]).output().expect("python3");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(String::from_utf8_lossy(&o.stdout).trim(), "13 15 12");
    // And against the JUnit schema CI's reporters follow (Surefire's junit-10.xsd, from pytest's sources).
    let xsd = repo("target/junit/junit-10.xsd");
    if !xsd.is_file() {
        baton_tests::missing(&format!("{} is absent: run .ci/run once", xsd.display()));
    }
    baton_tests::peer::require_python("xmlschema", "xmlschema");
    let o = Command::new("python3")
        .arg(repo("tests/scripts/validate_junit.py"))
        .arg(&xsd)
        .arg(&report)
        .output()
        .expect("python3");
    let said = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{said}{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(said.trim(), "valid 15");
}

/// The published schema (`docs/baton-test.schema.json`), as an editor would apply it: it accepts every scenario
/// of the project and refuses a key that does not exist.
fn the_published_schema_accepts_the_scenarios_and_refuses_unknown_keys() {
    baton_tests::peer::require_python("jsonschema", "jsonschema");
    let o = Command::new("python3")
        .arg(repo("tests/scripts/check_scenario_schema.py"))
        .arg(repo(""))
        .output()
        .expect("python3");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let said = String::from_utf8_lossy(&o.stdout);
    assert!(said.trim().ends_with(" True"), "{said}");
    let checked: usize = said.split_whitespace().next().and_then(|n| n.parse().ok()).unwrap_or(0);
    assert!(checked >= 17, "{said}");
}

fn coverage_says_what_each_scenario_exercised_and_what_faults_struck() {
    let dir = repo("tests/baton_test");
    let out = tempfile::tempdir().expect("tmp");
    let (o, stdout, _) =
        baton_test(&dir, &["pass/crash.test.toml", "pass/skill_fault.test.toml", "--coverage", "-q"], out.path());
    assert!(o.status.success(), "{stdout}");
    let line = |start: &str| stdout.lines().find(|l| l.trim_start().starts_with(start)).unwrap_or_default().to_string();
    assert_eq!(
        line("crash:"),
        "  crash: steps 6/7, transitions 4/5, branches 1/2; never active: Broken; never fired: A->Broken"
    );
    assert_eq!(
        line("skill_fault:"),
        "  skill_fault: steps 5/7, transitions 3/5, branches 1/2; never active: AWait, Done; never fired: A->AWait, (AWait,BWait)->Done"
    );
    // Together they exercise the whole chart.
    assert_eq!(line("all 2 scenario(s):"), "  all 2 scenario(s): steps 7/7, transitions 5/5, branches 2/2");
    assert_eq!(
        line("fault `crash"),
        "  fault `crash the coordinator, back after 500ms` (crash) struck: A on r1, B on r2"
    );
}

fn a_time_limit_or_an_interrupt_stops_the_runs_and_the_junit_report_is_still_written() {
    let dir = repo("tests/baton_test");
    let out = tempfile::tempdir().expect("tmp");
    let report = out.path().join("limit.xml");
    let report_arg = report.to_str().expect("utf-8");
    let many = ["seeds", "pass", "--seeds", "100000000", "--junit", report_arg];
    let (o, stdout, _) = baton_test(&dir, &[&many[..], &["--timeout", "500ms", "-q"]].concat(), out.path());
    assert_eq!(o.status.code(), Some(2), "{stdout}");
    assert!(stdout.contains("stopped by the time limit of 500ms: runs not made are not counted"), "{stdout}");
    let xml = std::fs::read_to_string(&report).expect("report written");
    let doc = roxmltree::Document::parse(&xml).expect("well-formed XML");
    assert_eq!(doc.root_element().attribute("name"), Some("baton test (interrupted: the time limit of 500ms)"));
    // Every scenario had its first seeds before the limit: each has a suite of its own.
    assert_eq!(doc.root_element().children().filter(|n| n.has_tag_name("testsuite")).count(), 10);
    // An interrupt, once the runs are under way.
    let report = out.path().join("interrupt.xml");
    let mut child = Command::new(bin("baton"))
        .arg("test")
        .args(["seeds", "--seeds", "100000000", "--out"])
        .arg(out.path())
        .arg("--junit")
        .arg(&report)
        .current_dir(&dir)
        .stdout(std::process::Stdio::piped())
        .spawn()
        .expect("start baton test");
    let mut stdout = std::io::BufReader::new(child.stdout.take().expect("stdout"));
    let mut first = String::new();
    std::io::BufRead::read_line(&mut stdout, &mut first).expect("read");
    assert!(first.starts_with("running 100000000 run(s) of 1 scenario(s)"), "{first}");
    let killed = Command::new("kill").args(["-INT", &child.id().to_string()]).status().expect("kill");
    assert!(killed.success());
    let mut rest = String::new();
    std::io::Read::read_to_string(&mut stdout, &mut rest).expect("read");
    let status = child.wait().expect("wait");
    assert_eq!(status.code(), Some(130), "{rest}");
    assert!(rest.contains("stopped by an interrupt"), "{rest}");
    let xml = std::fs::read_to_string(&report).expect("report written");
    assert!(xml.contains("<testsuites name=\"baton test (interrupted: an interrupt)\""), "{xml}");
}

/// `baton-agent --simulate SCENARIO`: real agent processes on the real network run the skills as the scenario
/// says — the first step towards `baton test --cluster`.
async fn agents_started_with_simulate_run_the_scenarios_skills_over_the_real_network() {
    let mut cluster = baton_tests::loopback::Cluster::with_router().await;
    let scenario_path = repo("examples/cell.test.toml");
    let scenario_arg = scenario_path.to_str().expect("utf-8");
    cluster.agent("robot1", &[], &["--simulate", scenario_arg]);
    cluster.agent("robot2", &[], &["--simulate", scenario_arg]);
    cluster.agent("assembler1", &["assembler"], &["--simulate", scenario_arg]);
    let coordinator = cluster.coordinator_joining(&repo("examples/cell.st"), &[]);
    let (status, log, trace, summary) = coordinator.finish().await;
    assert!(status.success(), "{log}");
    // The scenario's inspection faults twice, then passes; its assembly takes a second.
    assert_eq!(count(&trace, TraceEvent::SkillFault, "InspectPart"), 2, "{trace:#?}");
    let at = |event: TraceEvent, name: &str| {
        trace.iter().filter(|r| r.event == event && r.name == name).map(|r| r.t_ms).collect::<Vec<u64>>()
    };
    let (on, done) = (at(TraceEvent::ActionOn, "AssemblePart"), at(TraceEvent::SkillDone, "AssemblePart"));
    assert_eq!((on.len(), done.len()), (3, 3), "{trace:#?}");
    // (Agent events are placed on the coordinator's clock from their offsets: a cycle either way, at most.)
    assert!(on.iter().zip(&done).all(|(a, b)| b - a >= 1000 - 2 * 10 && b - a < 1500), "{on:?} {done:?}");
    let var = |name: &str| summary["vars"][name].as_str().unwrap_or_default().to_string();
    assert_eq!((var("done"), var("reworks")), ("3".to_string(), "2".to_string()));
}

/// `baton test --cluster`: the example cell and a fault of each kind real processes can suffer, with an
/// embedded router, `baton run` and `baton-agent --simulate` processes, in real time. What each scenario says
/// happened is seen in the trace that the real coordinator wrote.
fn cluster_runs_the_example_and_each_fault_with_real_processes() {
    let out = tempfile::tempdir().expect("tmp");
    let (o, stdout, stderr) = baton_test(&repo("examples"), &["cell.test.toml", "--cluster", "--keep"], out.path());
    assert!(o.status.success(), "{stdout}{stderr}");
    assert!(stdout.contains("each on real processes on loopback, in real time"), "{stdout}");
    assert!(stdout.contains("\nPASS cell (cell.test.toml): 8 expectation(s), seed 1"), "{stdout}");
    assert!(stdout.contains("(real time)"), "{stdout}");
    let trace = read_trace(&out.path().join("cell-seed1.trace.jsonl"));
    // Four real agents joined; assembler1 was SIGKILLed holding Assemble and assembler2 took it in epoch 2.
    let ups: std::collections::BTreeSet<&str> =
        trace.iter().filter(|r| r.event == TraceEvent::AgentUp).map(|r| r.name.as_str()).collect();
    assert_eq!(ups.into_iter().collect::<Vec<_>>(), ["assembler1", "assembler2", "robot1", "robot2"]);
    assert_eq!(count(&trace, TraceEvent::AgentLost, "assembler1"), 1, "{trace:#?}");
    let again = trace.iter().find(|r| r.event == TraceEvent::Dispatch && r.name == "Assemble" && r.epoch == Some(2));
    assert_eq!(again.and_then(|r| r.agent.as_deref()), Some("assembler2"), "{trace:#?}");
    assert_eq!(count(&trace, TraceEvent::SkillFault, "InspectPart"), 2, "{trace:#?}");
    // A passing run leaves no processes' folder behind.
    assert!(!out.path().join("cell-seed1.cluster").exists());

    let dir = repo("tests/baton_test");
    let files = ["pass/restart.test.toml", "pass/partition.test.toml", "pass/crash.test.toml", "pass/when.test.toml"];
    let mut args = files.to_vec();
    args.extend(["--cluster", "--keep", "--jobs", "2"]);
    let (o, stdout, stderr) = baton_test(&dir, &args, out.path());
    assert!(o.status.success(), "{stdout}{stderr}");
    assert!(stdout.contains("4 scenario(s): 4 passed, 0 failed"), "{stdout}");
    let trace = |name: &str| read_trace(&out.path().join(format!("{name}-seed1.trace.jsonl")));
    // Killed, then a new process: the token goes to it in a new epoch.
    let t = trace("restart");
    assert_eq!(count(&t, TraceEvent::AgentLost, "r1"), 1, "{t:#?}");
    assert_eq!(count(&t, TraceEvent::AgentUp, "r1"), 2, "{t:#?}");
    assert!(t.iter().any(|r| r.event == TraceEvent::Dispatch && r.name == "A" && r.epoch == Some(2)), "{t:#?}");
    // Its cable pulled out from 100 to 400 ms, within its lease: never lost, and its work heard only once back.
    let t = trace("partition");
    assert_eq!(count(&t, TraceEvent::AgentLost, "r2"), 0, "{t:#?}");
    let back = t.iter().find(|r| r.event == TraceEvent::Return && r.name == "B").expect("B's token back");
    assert!(back.t_ms >= 400, "B's token came back at {} ms, while r2 was cut off", back.t_ms);
    // The coordinator was SIGKILLed and started again on its journal; the trace goes on past its recovery.
    let t = trace("crash");
    let recover = t.iter().position(|r| r.event == TraceEvent::Recover).expect("recovered");
    assert!(t[recover..].iter().any(|r| r.event == TraceEvent::Activate && r.name == "Done"), "{t:#?}");
    assert_eq!(count(&t, TraceEvent::Activate, "Idle"), 1, "the replayed past is not taken in twice: {t:#?}");
    // `baton run --watch`, which the runner asks for every variable: values as the chart changed them, once
    // each (the replayed past is skipped). Both tokens come back after the recovery, in either order.
    let firsts: Vec<&str> = t
        .iter()
        .filter(|r| r.event == TraceEvent::Value && r.name == "first")
        .filter_map(|r| r.value.as_deref())
        .collect();
    assert!(firsts == ["0", "1"] || firsts == ["0", "2"], "{firsts:?}");
    // An input set 200 ms after a step became active, and an agent that starts a second late.
    let t = trace("when");
    let set = t.iter().find(|r| r.event == TraceEvent::Set).expect("set");
    assert!(set.t_ms >= 200, "set at {}", set.t_ms);
    let b = t.iter().find(|r| r.event == TraceEvent::Dispatch && r.name == "B").expect("B dispatched");
    assert!(b.t_ms >= 1000 && b.agent.as_deref() == Some("r2"), "{b:?}");

    // The operating examples on real processes: commands go as `baton ctl` sends them, and `baton run`'s exit
    // status says how the run ended.
    let files =
        ["cell_hold.test.toml", "cell_abort.test.toml", "motion.test.toml", "--cluster", "--keep", "--jobs", "2"];
    let (o, stdout, stderr) = baton_test(&repo("examples"), &files, out.path());
    assert!(o.status.success(), "{stdout}{stderr}");
    assert!(stdout.contains("PASS cell_abort (cell_abort.test.toml): 4 expectation(s), seed 1, chart"), "{stdout}");
    assert!(stdout.contains("(aborted)"), "{stdout}");
    // Runs that stay at their end, reset and cleared by `baton ctl`, ended by an interrupt at their end.
    let files = ["pass/reset.test.toml", "pass/clear.test.toml", "--cluster", "--keep", "--jobs", "2"];
    let (o, stdout, stderr) = baton_test(&dir, &files, out.path());
    assert!(o.status.success(), "{stdout}{stderr}");
    for name in ["reset", "clear"] {
        let t = trace(name);
        assert_eq!(count(&t, TraceEvent::NewRun, "line"), 1, "{name}: {t:#?}");
        let last = t.iter().rev().find(|r| r.event == TraceEvent::State).expect("states");
        assert_eq!(last.name, "complete", "{name}");
    }
    let t = trace("cell_hold");
    let hold = t.iter().find(|r| r.event == TraceEvent::Command && r.name == "hold").expect("the hold, traced");
    assert_eq!((hold.by.as_deref(), hold.message.as_deref()), (Some("baton test"), Some("material late")));

    // A failing expectation on real processes: the same message, the processes' logs kept, and the replay
    // command runs on real processes again.
    let (o, stdout, _) = baton_test(&dir, &["fail/value.test.toml", "--cluster"], out.path());
    assert_eq!(o.status.code(), Some(1), "{stdout}");
    assert!(stdout.contains("at the end: first = 1 (expected 2)"), "{stdout}");
    assert!(stdout.contains("replay: baton test fail/value.test.toml --seed 1 --cluster"), "{stdout}");
    let logs = out.path().join("value-seed1.cluster");
    assert!(logs.join("coordinator.1.log").is_file() && logs.join("agent-r1.1.log").is_file(), "{stdout}");
    // What TCP cannot do is said, and nothing runs.
    let (o, stdout, stderr) = baton_test(&dir, &["pass/link.test.toml", "--cluster"], out.path());
    assert_eq!(o.status.code(), Some(2), "{stdout}{stderr}");
    assert!(stderr.contains("needs the simulated network"), "{stderr}");
}

/// Two scenario files of one name (in two folders), run side by side with `--cluster` into one `--out`: each
/// run has a folder of its own, so neither finds the other's journal in use nor has its logs deleted by the
/// other's pass.
fn scenarios_of_one_name_run_side_by_side_on_real_processes() {
    let dir = tempfile::tempdir().expect("tmp");
    let crash = std::fs::read_to_string(repo("tests/baton_test/pass/crash.test.toml")).expect("crash scenario");
    let line = repo("tests/baton_test/line.st");
    for side in ["left", "right"] {
        std::fs::create_dir_all(dir.path().join(side)).expect("folder");
        let text = crash.replace("chart = \"../line.st\"", &format!("chart = {:?}", line.display().to_string()));
        std::fs::write(dir.path().join(side).join("twin.test.toml"), text).expect("write");
    }
    let out = dir.path().join("out");
    let run = |side: &str| {
        Command::new(bin("baton"))
            .args(["test", &format!("{side}/twin.test.toml"), "--cluster", "--out"])
            .arg(&out)
            .current_dir(dir.path())
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .expect("baton test starts")
    };
    let (left, right) = (run("left"), run("right"));
    for child in [left, right] {
        let o = child.wait_with_output().expect("baton test ends");
        let stdout = String::from_utf8_lossy(&o.stdout);
        assert!(o.status.success(), "{stdout}{}", String::from_utf8_lossy(&o.stderr));
        assert!(stdout.contains("PASS twin"), "{stdout}");
    }
}

/// The processes of the runs in `/proc` whose parent is `pid`.
fn children_of(pid: u32) -> Vec<u32> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir("/proc").into_iter().flatten().flatten() {
        let Ok(child) = entry.file_name().to_string_lossy().parse::<u32>() else { continue };
        let Ok(stat) = std::fs::read_to_string(entry.path().join("stat")) else { continue };
        // pid (comm) state ppid …: the command may hold spaces and parentheses, the last `)` ends it.
        let fields: Vec<&str> = stat.rsplit_once(')').map_or(Vec::new(), |(_, rest)| rest.split_whitespace().collect());
        if fields.get(1).and_then(|p| p.parse::<u32>().ok()) == Some(pid) && fields.first() != Some(&"Z") {
            out.push(child);
        }
    }
    out
}

/// `baton test --cluster` killed outright (SIGKILL, where it cannot tear anything down): its coordinator and
/// agents die with it instead of living on, reparented to PID 1.
fn the_processes_of_a_cluster_run_die_with_their_runner() {
    let dir = tempfile::tempdir().expect("tmp");
    // A run that lasts: r1's motion takes a minute.
    let line =
        std::fs::read_to_string(repo("tests/baton_test/line.st")).expect("chart").replace("ms := 200", "ms := 60000");
    std::fs::write(dir.path().join("slow.st"), line).expect("write");
    std::fs::write(
        dir.path().join("slow.test.toml"),
        "chart = \"slow.st\"\n\n[[agents]]\nname = \"r1\"\n\n[[agents]]\nname = \"r2\"\n\n[[inputs]]\nat = \"0s\"\n\
         set = { start = true }\n\n[[expect]]\nstate = \"finished\"\n",
    )
    .expect("write");
    let mut runner = Command::new(bin("baton"))
        .args(["test", "slow.test.toml", "--cluster", "--out"])
        .arg(dir.path().join("out"))
        .current_dir(dir.path())
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .expect("baton test starts");
    // Wait for its coordinator and both agents.
    let deadline = std::time::Instant::now() + baton_tests::loopback::TIMEOUT;
    let children = loop {
        let c = children_of(runner.id());
        if c.len() >= 3 {
            break c;
        }
        assert!(std::time::Instant::now() < deadline, "the runner never started its processes: {c:?}");
        std::thread::sleep(std::time::Duration::from_millis(20));
    };
    runner.kill().expect("SIGKILL the runner");
    runner.wait().expect("reaped");
    let alive = |pid: &u32| {
        std::fs::read_to_string(format!("/proc/{pid}/stat"))
            .is_ok_and(|s| s.rsplit_once(')').is_some_and(|(_, rest)| !rest.trim_start().starts_with('Z')))
    };
    let deadline = std::time::Instant::now() + baton_tests::loopback::TIMEOUT;
    while children.iter().any(alive) {
        assert!(
            std::time::Instant::now() < deadline,
            "{:?} outlived their runner",
            children.iter().filter(|p| alive(p)).collect::<Vec<_>>()
        );
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
}

baton_tests::harness_main!(
    sync the_example_cell_passes_with_a_robot_killed_and_an_inspection_failing_twice,
    sync the_readme_example_waits_for_both_robots_on_every_seed,
    sync the_operating_examples_hold_abort_and_acknowledge_on_every_seed,
    sync a_fault_of_each_kind_strikes_and_the_run_survives_it,
    sync each_kind_of_expectation_fails_with_its_message,
    sync malformed_files_are_said_at_file_line_col_with_exit_status_3,
    sync a_scenario_whose_chart_is_missing_or_wrong_cannot_run,
    sync a_skill_nobody_has_fails_the_scenario_before_anything_runs,
    sync seeds_find_a_planted_race_and_the_printed_command_replays_exactly_it,
    sync the_junit_report_has_a_suite_per_file_and_a_case_per_expectation,
    sync the_published_schema_accepts_the_scenarios_and_refuses_unknown_keys,
    sync coverage_says_what_each_scenario_exercised_and_what_faults_struck,
    sync a_time_limit_or_an_interrupt_stops_the_runs_and_the_junit_report_is_still_written,
    tokio agents_started_with_simulate_run_the_scenarios_skills_over_the_real_network,
    sync cluster_runs_the_example_and_each_fault_with_real_processes,
    sync scenarios_of_one_name_run_side_by_side_on_real_processes,
    sync the_processes_of_a_cluster_run_die_with_their_runner,
);
