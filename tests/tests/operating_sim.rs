//! Operating a cell, in deterministic simulation: an operator's hold, unhold, stop and abort carried out by the real
//! coordinator and agents over a simulated network, with the run's PackML state following what the agents confirm.

use baton_proto::cluster::runtime::packml::State;
use baton_proto::cluster::wire::CtlRequest;
use baton_proto::exec::trace::{TraceEvent, TraceRecord};
use baton_proto::testing::simulated_cluster::{Fate, Faults, SimCluster};

/// Two robots, two motions each in sequence: r1's take 1 s each, r2's 0.6 s; the branches meet at the end.
const CELL: &str = "PROGRAM cell
VAR a1, a2, b1, b2 : BOOL; END_VAR
INITIAL_STEP Idle: END_STEP
TRANSITION FROM Idle TO (A1, B1) := TRUE; END_TRANSITION
STEP A1: {agent := 'r1'} MoveA1(N, a1); END_STEP
TRANSITION FROM A1 TO A2 := a1; END_TRANSITION
STEP A2: {agent := 'r1'} MoveA2(N, a2); END_STEP
TRANSITION FROM A2 TO AEnd := a2; END_TRANSITION
STEP AEnd: END_STEP
STEP B1: {agent := 'r2'} MoveB1(N, b1); END_STEP
TRANSITION FROM B1 TO B2 := b1; END_TRANSITION
STEP B2: {agent := 'r2'} MoveB2(N, b2); END_STEP
TRANSITION FROM B2 TO BEnd := b2; END_TRANSITION
STEP BEnd: END_STEP
TRANSITION FROM (AEnd, BEnd) TO Done := TRUE; END_TRANSITION
STEP Done: END_STEP
ACTION MoveA1: {skill := 'motion', ms := 1000} END_ACTION
ACTION MoveA2: {skill := 'motion', ms := 1000} END_ACTION
ACTION MoveB1: {skill := 'motion', ms := 600} END_ACTION
ACTION MoveB2: {skill := 'motion', ms := 600} END_ACTION
END_PROGRAM
";

const AGENTS: &[(&str, &[&str])] = &[("r1", &[]), ("r2", &[])];

fn ctl(command: &str) -> CtlRequest {
    CtlRequest {
        command: command.into(),
        reason: format!("test {command}"),
        by: "operator@cell".into(),
        ..Default::default()
    }
}

fn first(trace: &[TraceRecord], event: TraceEvent, name: &str) -> Option<u64> {
    trace.iter().find(|r| r.event == event && r.name == name).map(|r| r.t_ms)
}

fn all(trace: &[TraceRecord], event: TraceEvent, name: &str) -> Vec<u64> {
    trace.iter().filter(|r| r.event == event && r.name == name).map(|r| r.t_ms).collect()
}

fn states(trace: &[TraceRecord]) -> Vec<(u64, String)> {
    trace.iter().filter(|r| r.event == TraceEvent::State).map(|r| (r.t_ms, r.name.clone())).collect()
}

fn check(sim: &SimCluster) {
    let program = sim.coordinator.core().program();
    let complete = !sim.coordinator.core().is_ended_by_operator();
    if let Err(why) = baton_tests::invariants::check(&sim.trace, program, complete) {
        panic!("seed {}: {why}", sim.seed);
    }
    assert!(sim.violations.is_empty(), "seed {}: {:?}", sim.seed, sim.violations);
}

/// `hold` while both robots move: the run is `held` only when both motions finished and both agents confirmed;
/// nothing starts while held and the step times stand still; `unhold` goes on and nothing runs twice.
#[test]
fn a_hold_waits_for_the_running_motions_and_nothing_starts_until_unhold() {
    for seed in 0..8 {
        let faults = if seed % 2 == 0 {
            Faults::default()
        } else {
            Faults { duplicate: 0.3, reorder: true, delay_ms_max: 8, loss: 0.05 }
        };
        let mut sim = SimCluster::new(CELL, AGENTS, faults, seed);
        sim.command_at(300, ctl("hold"));
        sim.command_at(4_000, ctl("unhold"));
        assert!(sim.run(20_000), "seed {seed}: did not finish: {:#?}", sim.trace);
        check(&sim);
        let t = &sim.trace;
        assert!(sim.answers[0].1.is_ok() && sim.answers[1].1.is_ok(), "{:?}", sim.answers);
        let st = states(t);
        let names: Vec<&str> = st.iter().map(|s| s.1.as_str()).collect();
        assert_eq!(names, ["holding", "held", "unholding", "execute"], "seed {seed}");
        let held_at = st[1].0;
        // A motion running when the hold came finished before the run was held (a dispatch lost on the way and
        // sent again after the hold arrives held, and its motion starts only at unhold).
        for motion in ["MoveA1", "MoveB1"] {
            let on = first(t, TraceEvent::ActionOn, motion).expect("started");
            let done = first(t, TraceEvent::SkillDone, motion).expect("finished");
            if on < 300 {
                assert!(held_at >= done, "seed {seed}: held at {held_at} before {motion} ended at {done}");
            } else {
                assert!(on >= 4_000, "seed {seed}: {motion} started at {on} while held");
            }
        }
        for next in ["MoveA2", "MoveB2"] {
            let on = all(t, TraceEvent::ActionOn, next);
            assert_eq!(on.len(), 1, "seed {seed}: {next} started {on:?}");
            assert!(on[0] >= 4_000, "seed {seed}: {next} started at {} while held", on[0]);
        }
        for motion in ["MoveA1", "MoveB1", "MoveA2", "MoveB2"] {
            assert_eq!(all(t, TraceEvent::ActionOn, motion).len(), 1, "seed {seed}: {motion} ran twice");
        }
        let command = t.iter().find(|r| r.event == TraceEvent::Command).expect("the command is traced");
        assert_eq!((command.name.as_str(), command.by.as_deref()), ("hold", Some("operator@cell")));
        assert_eq!(command.message.as_deref(), Some("test hold"));
    }
}

/// A step's time stands still while the run is held: a wait of 500 ms on the coordinator, held for 2 s from
/// 200 ms, ends at 2.5 s, not at 0.5 s.
#[test]
fn step_times_stand_still_while_held() {
    let chart = "PROGRAM p\nINITIAL_STEP A: END_STEP\nTRANSITION FROM A TO W := TRUE; END_TRANSITION\n\
                 STEP W: END_STEP\nTRANSITION FROM W TO B := W.T >= T#500ms; END_TRANSITION\nSTEP B: END_STEP\nEND_PROGRAM\n";
    let mut sim = SimCluster::new(chart, &[], Faults::default(), 1);
    sim.command_at(200, ctl("hold"));
    sim.command_at(2_200, ctl("unhold"));
    assert!(sim.run(10_000));
    let w = first(&sim.trace, TraceEvent::Activate, "W").expect("W");
    let b = first(&sim.trace, TraceEvent::Activate, "B").expect("B");
    assert_eq!(b - w, 2_500, "W held 2 s of its 500 ms: {:?}", states(&sim.trace));
}

/// `hold --agent r1` holds r1's branch; r2's branch goes on to its end and the run stays in Execute.
#[test]
fn holding_one_robot_lets_the_other_finish_its_branch() {
    let mut sim = SimCluster::new(CELL, AGENTS, Faults::default(), 3);
    sim.command_at(300, CtlRequest { agent: Some("r1".into()), ..ctl("hold") });
    sim.command_at(5_000, CtlRequest { agent: Some("r1".into()), ..ctl("unhold") });
    assert!(sim.run(20_000), "did not finish: {:#?}", sim.trace);
    check(&sim);
    let t = &sim.trace;
    let b_end = first(t, TraceEvent::Activate, "BEnd").expect("r2's branch ended");
    assert!(b_end < 5_000, "r2's branch ended at {b_end}, not while r1 was held");
    let a2 = first(t, TraceEvent::ActionOn, "MoveA2").expect("A2 ran");
    assert!(a2 >= 5_000, "A2 started at {a2} while r1 was held");
    let names: Vec<String> = states(t).into_iter().map(|s| s.1).collect();
    assert!(names.is_empty(), "a partial hold leaves the run in Execute: {names:?}");
}

/// A misspelt agent in `hold --agent` is refused with the name meant — never "holding" while the robot it meant
/// carries on — as a misspelt step is; an agent that comes only as a role-holder is known by its name.
#[test]
fn holding_an_agent_the_run_does_not_know_is_refused_with_the_name_meant() {
    let mut sim = SimCluster::new(CELL, AGENTS, Faults::default(), 3);
    sim.command_at(300, CtlRequest { agent: Some("rl".into()), ..ctl("hold") });
    sim.command_at(310, CtlRequest { step: Some("B22".into()), ..ctl("hold") });
    sim.command_at(320, CtlRequest { agent: Some("nobody".into()), ..ctl("hold") });
    assert!(sim.run(20_000), "did not finish: {:#?}", sim.trace);
    check(&sim);
    let typo = sim.answers[0].1.clone().expect_err("an unknown agent is refused");
    assert!(typo.contains("no agent `rl`") && typo.contains("did you mean `r1`?"), "{typo}");
    let step = sim.answers[1].1.clone().expect_err("an unknown step is refused");
    assert!(step.contains("no step `B22`") && step.contains("did you mean `B2`?"), "{step}");
    let far = sim.answers[2].1.clone().expect_err("refused");
    assert!(!far.contains("did you mean") && far.contains("r1, r2"), "{far}");
    assert!(sim.coordinator.core().partial_holds().is_empty(), "nothing was held");
    assert!(
        sim.trace.iter().all(|r| r.event != TraceEvent::Command || r.name != "hold"),
        "a refused hold is not traced as taken"
    );

    // An agent that serves a role, and has no step placed on it by name, is known once it was heard.
    let chart = CELL.replace("STEP B1: {agent := 'r2'}", "STEP B1: {role := 'welder'}");
    let mut sim = SimCluster::new(&chart, &[("r1", &[]), ("r2", &["welder"])], Faults::default(), 3);
    sim.command_at(300, CtlRequest { agent: Some("r2".into()), ..ctl("hold") });
    sim.command_at(5_000, CtlRequest { agent: Some("r2".into()), ..ctl("unhold") });
    assert!(sim.run(20_000), "did not finish: {:#?}", sim.trace);
    assert!(sim.answers[0].1.is_ok(), "{:?}", sim.answers[0]);
}

/// `stop` lets the running motions finish, starts nothing, and ends the run `stopped`.
#[test]
fn stop_lets_running_motions_finish_and_ends_the_run_stopped() {
    let mut sim = SimCluster::new(CELL, AGENTS, Faults::default(), 4);
    sim.command_at(300, ctl("stop"));
    assert!(sim.run(20_000));
    check(&sim);
    assert_eq!(sim.coordinator.core().run_state(), State::Stopped);
    let t = &sim.trace;
    let names: Vec<String> = states(t).into_iter().map(|s| s.1).collect();
    assert_eq!(names, ["stopping", "stopped"]);
    let stopped = states(t)[1].0;
    assert!(stopped >= first(t, TraceEvent::SkillDone, "MoveA1").expect("A1 finished"));
    assert!(first(t, TraceEvent::ActionOn, "MoveA2").is_none() && first(t, TraceEvent::ActionOn, "MoveB2").is_none());
    assert!(first(t, TraceEvent::Activate, "Done").is_none());
}

/// `abort` mid-motion ends the run at once: both running motions are cancelled on their agents (no result comes
/// back), the actions get their final scan, and the run is `aborted`.
#[test]
fn abort_cancels_the_running_motions_and_ends_the_run_aborted() {
    let mut sim = SimCluster::new(CELL, AGENTS, Faults::default(), 5);
    sim.command_at(300, ctl("abort"));
    assert!(sim.run(20_000));
    assert_eq!(sim.coordinator.core().run_state(), State::Aborted);
    let t = &sim.trace;
    let names: Vec<String> = states(t).into_iter().map(|s| s.1).collect();
    assert_eq!(names, ["aborting", "aborted"]);
    assert!(first(t, TraceEvent::SkillDone, "MoveA1").is_none(), "the motion was cancelled, not finished");
    assert_eq!(first(t, TraceEvent::Deactivate, "A1"), Some(300), "A1 was left at the abort");
    assert_eq!(sim.coordinator.core().tokens_in_flight(), 0);
}

/// `abort` with a robot cut off: the run does not wait for it; its token is abandoned with an alarm. The robot,
/// which cannot know, goes on with its segment; the run waits for it, and once it is back it is told (`told`) and
/// holds nothing of the run.
#[test]
fn abort_with_a_robot_cut_off_abandons_its_token_with_an_alarm() {
    let mut sim = SimCluster::new(CELL, AGENTS, Faults::default(), 6);
    sim.fate_at(200, "r1", Fate::Cut);
    sim.command_at(4_000, ctl("abort"));
    assert!(!sim.run(5_000), "the run waits to tell r1");
    assert_eq!(sim.coordinator.core().run_state(), State::Aborted);
    sim.fate_at(6_000, "r1", Fate::Heal);
    assert!(sim.run(40_000));
    let told = sim.trace.iter().find(|r| r.event == TraceEvent::Told).expect("r1 told");
    assert!(told.name == "r1" && told.t_ms >= 6_000, "{told:?}");
    assert_eq!(sim.agent_holds("r1"), (0, 0), "told, r1 forgot the run and cancelled its skills");
    let abandoned = sim.trace.iter().find(|r| r.event == TraceEvent::Alarm && r.at_least_after(4_000));
    let abandoned = abandoned.expect("an alarm for the abandoned token");
    assert_eq!(abandoned.name, "r1");
    assert!(abandoned.message.as_deref().is_some_and(|m| m.contains("abandoned")), "{abandoned:?}");
}

/// Words an operator reads say where things are now: a token's line names the step it is at (with the step it was
/// dispatched at), and so does the alarm of an agent lost holding it.
#[test]
fn a_token_and_the_alarm_of_its_lost_agent_name_the_step_it_is_at_now() {
    let mut sim = SimCluster::new(CELL, AGENTS, Faults::default(), 8);
    // r1's token was dispatched at A1 and is at A2 from about 1 s.
    assert!(!sim.run(1_500));
    let status = sim.coordinator.core().status();
    let r1 = status.tokens.iter().find(|t| t.agent.as_deref() == Some("r1")).expect("r1's token");
    assert_eq!((r1.entry.as_str(), r1.at.clone()), ("A1", vec!["A2".to_string()]), "{r1:?}");
    sim.fate_at(1_600, "r1", Fate::Cut);
    sim.run(30_000);
    let lost = sim
        .trace
        .iter()
        .find(|r| r.event == TraceEvent::Alarm && r.name == "r1")
        .and_then(|r| r.message.clone())
        .expect("an alarm for the lost agent");
    assert!(lost.contains("holding the token of step `A2` (entered at `A1`)"), "{lost}");
}

/// A command's answer says what it did: `mode step` confirms the mode (not the run's PackML state), and a refusal
/// is worded once.
#[test]
fn a_mode_change_is_answered_with_the_mode_and_a_refusal_is_said_once() {
    let mut sim = SimCluster::new(CELL, AGENTS, Faults::default(), 9);
    sim.command_at(100, ctl_on("mode", "manual"));
    sim.command_at(200, ctl_on("activate", "B2"));
    sim.command_at(300, ctl_on("mode", "auto"));
    sim.run(20_000);
    assert_eq!(sim.answers[0].1.as_deref(), Ok("the run is in manual mode"));
    let refused = sim.answers[1].1.clone().expect_err("activating B2 beside B1 is unsafe");
    assert!(!refused.starts_with("refused"), "{refused}");
    assert_eq!(sim.answers[2].1.as_deref(), Ok("the run is in auto mode"));
}

/// After `reset`, the new run's time starts at the reset: `baton status` must not say a new idle run has been
/// running since the process started.
#[test]
fn a_run_made_by_reset_counts_its_time_from_the_reset() {
    let mut sim = SimCluster::new(CELL, AGENTS, Faults::default(), 10);
    sim.set_stay();
    sim.command_at(300, ctl("stop"));
    sim.command_at(4_000, ctl("reset"));
    sim.run(5_000);
    let status = sim.coordinator.core().status();
    assert!(sim.trace.iter().any(|r| r.event == TraceEvent::NewRun), "the reset made a new run");
    assert!(status.started_ms >= 4_000, "the new run began at {} ms", status.started_ms);
    assert!(status.t_ms - status.started_ms <= 1_000, "{} ms since the reset", status.t_ms - status.started_ms);
}

/// A command the run's state does not allow is refused, saying the state and what is legal, and traced.
#[test]
fn an_illegal_command_is_refused_with_what_is_legal() {
    let mut sim = SimCluster::new(CELL, AGENTS, Faults::default(), 7);
    sim.command_at(300, ctl("unhold"));
    sim.command_at(400, ctl("launch"));
    assert!(sim.run(20_000));
    let why = sim.answers[0].1.clone().expect_err("refused");
    assert!(why.contains("execute") && why.contains("hold") && why.contains("abort"), "{why}");
    assert!(sim.answers[1].1.as_ref().is_err_and(|w| w.contains("unknown command")));
    let refused: Vec<&TraceRecord> = sim.trace.iter().filter(|r| r.event == TraceEvent::CommandRefused).collect();
    assert_eq!(refused.len(), 2);
    assert_eq!(refused[0].message.as_deref(), Some(why.as_str()));
    assert!(states(&sim.trace).is_empty(), "nothing changed the run's state");
}

/// A coordinator that dies while the run is held comes back held, from its journal (the simulation checks that the
/// replay rebuilds the live trace, commands included), and the run goes on after `unhold`.
#[test]
fn a_coordinator_restarted_while_held_comes_back_held() {
    for seed in 0..4 {
        let mut sim = SimCluster::new(CELL, AGENTS, Faults::default(), seed);
        sim.command_at(300, ctl("hold"));
        sim.crash_coordinator_at(2_500, 700);
        sim.command_at(5_000, ctl("unhold"));
        assert!(sim.run(20_000), "seed {seed}: did not finish: {:#?}", sim.trace);
        check(&sim);
        let names: Vec<String> = states(&sim.trace).into_iter().map(|s| s.1).collect();
        assert_eq!(names, ["holding", "held", "unholding", "execute"], "seed {seed}");
        let a2 = first(&sim.trace, TraceEvent::ActionOn, "MoveA2").expect("A2 ran");
        assert!(a2 >= 5_000, "seed {seed}: A2 started at {a2} while held");
    }
}

trait After {
    fn at_least_after(&self, t_ms: u64) -> bool;
}

impl After for TraceRecord {
    fn at_least_after(&self, t_ms: u64) -> bool {
        self.t_ms >= t_ms
    }
}

/// `{max_ms}`: r1's step passes its maximum time while its motion runs. A latched alarm is raised with an id; the
/// step's transition waits for the acknowledgement though the motion finished, while r2's branch goes on; once
/// acknowledged, the step goes on, and the alarm is back to normal when the step is left.
#[test]
fn a_step_past_its_maximum_time_waits_for_an_acknowledgement_and_only_its_path_waits() {
    let chart = CELL.replace("STEP A1: {agent := 'r1'}", "STEP A1: {agent := 'r1', max_ms := T#500ms}");
    for seed in 0..4 {
        let mut sim = SimCluster::new(&chart, AGENTS, Faults::default(), seed);
        sim.command_at(3_000, CtlRequest { target: Some("1".into()), ..ctl("ack") });
        sim.command_at(3_100, CtlRequest { target: Some("1".into()), ..ctl("ack") });
        assert!(sim.run(20_000), "seed {seed}: {:#?}", sim.trace);
        check(&sim);
        let t = &sim.trace;
        let alarm = t.iter().find(|r| r.event == TraceEvent::Alarm).expect("a supervision alarm");
        assert_eq!((alarm.name.as_str(), alarm.id, alarm.agent.as_deref()), ("A1", Some(1), Some("r1")));
        assert!((500..=520).contains(&alarm.t_ms), "seed {seed}: raised at {}", alarm.t_ms);
        assert!(alarm.message.as_deref().is_some_and(|m| m.contains("500 ms")), "{alarm:?}");
        // What the step waited for when it faulted stays with the alarm: its motion, still running.
        let said = alarm.message.as_deref().unwrap_or_default();
        assert!(said.contains("A1->A2: `a1` is FALSE") && said.contains("skill of `MoveA1` running for"), "{said}");
        let done = first(t, TraceEvent::SkillDone, "MoveA1").expect("A1's motion finished");
        assert!(done < 3_000);
        let left = first(t, TraceEvent::Fire, "A1->A2").expect("A1 cleared");
        assert!(left >= 3_000, "seed {seed}: A1 cleared at {left}, before the acknowledgement");
        assert!(first(t, TraceEvent::Activate, "BEnd").is_some_and(|b| b < 3_000), "r2's branch went on");
        let ack = t.iter().find(|r| r.event == TraceEvent::Ack).expect("the acknowledgement is traced");
        assert_eq!((ack.id, ack.by.as_deref()), (Some(1), Some("operator@cell")));
        let clear = t.iter().find(|r| r.event == TraceEvent::AlarmClear).expect("back to normal");
        assert_eq!(clear.id, Some(1));
        assert!(clear.t_ms >= left, "normal only once the step is left");
        let again = sim.answers[1].1.clone().expect_err("a second acknowledgement is refused");
        assert!(again.contains("no standing alarm 1") || again.contains("acknowledged already"), "{again}");
    }
}

/// A chart that reads `S.overrun` branches to its own recovery at once; the alarm stays latched until acknowledged.
#[test]
fn a_chart_branches_to_its_own_recovery_on_a_fault_and_the_alarm_stays_until_acknowledged() {
    let mut sim = SimCluster::new(RECOVERING, &[("r1", &[])], Faults::default(), 1);
    sim.command_at(5_000, CtlRequest { target: Some("all".into()), reason: "drive checked".into(), ..ctl("ack") });
    assert!(!sim.run(2_000), "the chart waits in Recover");
    let t = &sim.trace;
    let alarm = first(t, TraceEvent::Alarm, "Move").expect("alarm");
    let recover = first(t, TraceEvent::Activate, "Recover").expect("recovery taken");
    assert!(recover >= alarm && recover < alarm + 50, "recovery at {recover}, alarm at {alarm}");
    assert!(first(t, TraceEvent::Activate, "Finished").is_none());
    let standing = sim.coordinator.core().status().alarms;
    assert_eq!(standing.len(), 1, "latched: the alarm stands though its step was left");
    assert_eq!(serde_json::to_value(standing[0].state).unwrap(), "active_unacknowledged");
    sim.run(6_000);
    assert!(sim.coordinator.core().status().alarms.is_empty(), "acknowledged, it is back to normal");
    let ack = sim.trace.iter().find(|r| r.event == TraceEvent::Ack).expect("ack traced");
    assert_eq!(ack.message.as_deref(), Some("drive checked"));
    // The acknowledgement ended the alarm (its cause was gone): the record still names what raised it.
    assert_eq!(ack.name, "Move", "{ack:?}");
    assert!(sim.trace.iter().any(|r| r.event == TraceEvent::AlarmClear && r.id == ack.id));
}

/// A chart that branches to its own recovery when `Move` passes its maximum time: the latched alarm stands after
/// its step was left.
const RECOVERING: &str = "PROGRAM p\nVAR done, retry : BOOL; END_VAR\nINITIAL_STEP A: END_STEP\n\
                 TRANSITION FROM A TO Move := TRUE; END_TRANSITION\n\
                 STEP Move: {agent := 'r1', max_ms := T#300ms} Drive(N, done); END_STEP\n\
                 TRANSITION FROM Move TO Finished := done; END_TRANSITION\n\
                 TRANSITION FROM Move TO Recover := Move.overrun; END_TRANSITION\n\
                 STEP Finished: END_STEP\nSTEP Recover: END_STEP\n\
                 TRANSITION FROM Recover TO Finished2 := retry; END_TRANSITION\nSTEP Finished2: END_STEP\n\
                 ACTION Drive: {skill := 'motion', ms := 1000} END_ACTION\nEND_PROGRAM\n";

/// ISA-18.2's shelving: a shelved alarm leaves the active list (status) and stays in the trace; when its time runs
/// out it comes back by itself, traced with who shelved it and why; `unshelve` ends a shelf early.
#[test]
fn a_shelved_alarm_leaves_the_active_list_and_comes_back_when_its_time_runs_out_or_is_unshelved() {
    let mut sim = SimCluster::new(RECOVERING, &[("r1", &[])], Faults::default(), 1);
    let shelve = || CtlRequest {
        target: Some("1".into()),
        for_ms: Some(2_000),
        reason: "sensor being replaced".into(),
        by: "anna".into(),
        ..ctl("shelve")
    };
    sim.command_at(1_000, shelve());
    assert!(!sim.run(1_500), "the chart waits in Recover");
    let status = sim.coordinator.core().status();
    assert!(status.alarms.is_empty(), "shelved, it is not in the active list: {:?}", status.alarms);
    assert_eq!(status.shelved.len(), 1);
    assert_eq!(status.shelved[0].shelved_until_ms, Some(3_000));
    assert_eq!(status.shelved[0].shelf.as_ref().map(|s| s.by.as_str()), Some("anna"));
    let shelved = sim.trace.iter().find(|r| r.event == TraceEvent::Shelve).expect("the shelving is traced");
    assert_eq!((shelved.name.as_str(), shelved.id, shelved.by.as_deref()), ("Move", Some(1), Some("anna")));
    assert!(shelved.message.as_deref().is_some_and(|m| m.contains("sensor being replaced")), "{shelved:?}");

    // Its time runs out at 3 s: back in the list, by itself, traced at that moment with who shelved it and why.
    sim.run(3_500);
    let status = sim.coordinator.core().status();
    assert_eq!(status.alarms.iter().map(|a| a.id).collect::<Vec<_>>(), vec![1]);
    assert!(status.shelved.is_empty());
    let back = sim.trace.iter().find(|r| r.event == TraceEvent::Unshelve).expect("the return is traced");
    assert_eq!((back.name.as_str(), back.id, back.by.as_deref()), ("Move", Some(1), Some("anna")));
    assert!((3_000..3_100).contains(&back.t_ms), "back at {} ms, its shelf ended at 3000", back.t_ms);
    let said = back.message.as_deref().unwrap_or_default();
    assert!(said.contains("sensor being replaced") && said.contains("ran out"), "{said}");

    // Shelved again, then unshelved early by another operator.
    sim.command_at(4_000, shelve());
    sim.command_at(4_500, CtlRequest { target: Some("1".into()), by: "ben".into(), ..ctl("unshelve") });
    sim.run(5_000);
    assert_eq!(sim.coordinator.core().status().alarms.len(), 1, "unshelved: back in the list");
    let early: Vec<_> = sim.trace.iter().filter(|r| r.event == TraceEvent::Unshelve).collect();
    assert_eq!(early.len(), 2);
    assert_eq!((early[1].t_ms, early[1].by.as_deref()), (4_500, Some("ben")));
    assert!(early[1].message.as_deref().is_some_and(|m| m.contains("shelved by anna")), "{:?}", early[1]);
    // Nothing was shelved any more at 6.5 s: no second return.
    sim.run(7_000);
    assert_eq!(sim.trace.iter().filter(|r| r.event == TraceEvent::Unshelve).count(), 2);
    let refused = sim.answers.last().map(|a| a.1.clone());
    assert!(refused.is_some_and(|r| r.is_ok()), "the unshelve was taken");
}

/// With the alarm list full (`ALARMS_STANDING_MAX` standing, none acknowledged), a step that passes its maximum
/// time gets no listed alarm, so nobody could acknowledge it: the overrun is said loudly, and the step does not wait
/// for an acknowledgement that can never come — on the coordinator as on an agent.
#[test]
fn a_step_past_its_maximum_time_with_the_alarm_list_full_does_not_wait_for_ever() {
    use baton_proto::limits::ALARMS_STANDING_MAX;
    // `Loop` passes its maximum time on each turn and recovers by itself, leaving its latched alarm standing, until
    // the list is full; then `Last` (on the coordinator) and `Remote` (on r1) overrun, each with a plain exit. `n`
    // counts two a visit of `Again`: a P action's body runs at activation and once more in its final scan (IEC).
    let visits = 2 * ALARMS_STANDING_MAX;
    let chart = format!(
        "PROGRAM full\nVAR n : DINT := 0; moved : BOOL; END_VAR\nINITIAL_STEP Start: END_STEP\n\
         TRANSITION FROM Start TO Loop := TRUE; END_TRANSITION\n\
         STEP Loop: {{max_ms := T#10ms}} END_STEP\n\
         TRANSITION FROM Loop TO Again := Loop.overrun; END_TRANSITION\n\
         STEP Again: Count(P); END_STEP\n\
         TRANSITION FROM Again TO Loop := n <= {visits}; END_TRANSITION\n\
         TRANSITION FROM Again TO Last := n > {visits}; END_TRANSITION\n\
         STEP Last: {{max_ms := T#10ms}} END_STEP\n\
         TRANSITION FROM Last TO Remote := Last.T >= T#50ms; END_TRANSITION\n\
         STEP Remote: {{agent := 'r1', max_ms := T#10ms}} Move(N, moved); END_STEP\n\
         TRANSITION FROM Remote TO Done := moved; END_TRANSITION\n\
         STEP Done: END_STEP\n\
         ACTION Count: n := n + 1; END_ACTION\n\
         ACTION Move: {{skill := 'motion', ms := 100}} END_ACTION\nEND_PROGRAM\n"
    );
    let mut sim = SimCluster::new(&chart, &[("r1", &[])], Faults::default(), 3);
    assert!(sim.run(600_000), "the run waits for an acknowledgement nobody can give: {:#?}", sim.trace.last());
    let status = sim.coordinator.core().status();
    assert_eq!(status.alarms.len(), ALARMS_STANDING_MAX, "the list stays full, never grows");
    for step in ["Last", "Remote"] {
        let alarm = sim
            .trace
            .iter()
            .find(|r| r.event == TraceEvent::Alarm && r.name == step)
            .unwrap_or_else(|| panic!("`{step}`'s overrun is traced"));
        assert_eq!(alarm.id, None, "not listed: {alarm:?}");
        let said = alarm.message.as_deref().unwrap_or_default();
        assert!(said.contains("not listed") && said.contains("does not wait"), "{said}");
    }
}

fn ctl_on(command: &str, target: &str) -> CtlRequest {
    CtlRequest { target: Some(target.into()), ..ctl(command) }
}

/// Step mode: a transition whose condition is TRUE waits for `confirm`, on an agent as on the coordinator; a
/// confirmation without a name is refused when several wait; back in auto mode the chart goes on by itself.
#[test]
fn in_step_mode_a_true_transition_waits_for_its_confirmation() {
    let mut sim = SimCluster::new(CELL, AGENTS, Faults::default(), 8);
    sim.command_at(50, ctl_on("mode", "step"));
    sim.command_at(1_500, ctl("confirm"));
    sim.command_at(2_000, ctl_on("confirm", "A1->A2"));
    sim.command_at(2_500, ctl_on("mode", "auto"));
    assert!(sim.run(20_000), "{:#?}", sim.trace);
    check(&sim);
    let t = &sim.trace;
    let modes: Vec<&str> = t.iter().filter(|r| r.event == TraceEvent::Mode).map(|r| r.name.as_str()).collect();
    assert_eq!(modes, ["step", "auto"]);
    let why = sim.answers[1].1.clone().expect_err("which one?");
    assert!(why.contains("A1->A2") && why.contains("B1->B2"), "both wait: {why}");
    assert!(sim.answers[2].1.is_ok(), "{:?}", sim.answers);
    let a = first(t, TraceEvent::Fire, "A1->A2").expect("A1->A2");
    assert!((2_000..2_050).contains(&a), "A1->A2 cleared at {a}, not on its confirmation");
    let b = first(t, TraceEvent::Fire, "B1->B2").expect("B1->B2");
    assert!((2_500..2_550).contains(&b), "B1->B2 cleared at {b}, not when the mode went back to auto");
}

/// Manual mode: nothing clears by itself; `force` clears a transition whatever its condition; a manual change of
/// the active steps that the chart could never reach by itself is refused, saying why.
#[test]
fn in_manual_mode_transitions_clear_only_when_forced_and_unsafe_switches_are_refused() {
    let mut sim = SimCluster::new(CELL, AGENTS, Faults::default(), 9);
    sim.command_at(50, ctl_on("mode", "manual"));
    sim.command_at(2_000, ctl_on("force", "A1->A2"));
    sim.command_at(2_100, ctl_on("activate", "AEnd"));
    sim.command_at(2_200, ctl_on("deactivate", "B1"));
    sim.command_at(2_300, ctl_on("force", "A2->AEnd"));
    sim.command_at(5_000, ctl_on("mode", "auto"));
    assert!(sim.run(20_000), "{:#?}", sim.trace);
    check(&sim);
    let t = &sim.trace;
    let a = first(t, TraceEvent::Fire, "A1->A2").expect("forced");
    assert!(
        (2_000..2_050).contains(&a),
        "A1->A2 cleared at {a}: its motion ended at 1 s, and only the force clears it"
    );
    for (i, what) in [(2, "activate AEnd"), (3, "deactivate B1")] {
        let why = sim.answers[i].1.clone().expect_err(what);
        assert!(why.contains("could never reach"), "{what}: {why}");
    }
    let a2 = first(t, TraceEvent::Fire, "A2->AEnd").expect("forced before its motion ended");
    assert!((2_300..2_350).contains(&a2), "forced at 2.3 s, cleared at {a2}");
    assert!(first(t, TraceEvent::Fire, "B1->B2").is_some_and(|b| b >= 5_000), "B1->B2 waited for auto mode");
    let refused = t.iter().filter(|r| r.event == TraceEvent::CommandRefused).count();
    assert_eq!(refused, 2);
}

/// Manual mode: `move FROM TO` takes a token from one step to another in one change, checked as one — r1's token
/// from its first motion straight to the end of its branch (its second motion never runs); a move that would put
/// two tokens in one branch is refused, saying why; back in auto mode the chart ends.
#[test]
fn in_manual_mode_a_token_moves_in_one_checked_change() {
    let mut sim = SimCluster::new(CELL, AGENTS, Faults::default(), 10);
    let mv = |from: &str, to: &str| CtlRequest { to: Some(to.into()), ..ctl_on("move", from) };
    sim.command_at(50, ctl_on("mode", "manual"));
    sim.command_at(2_000, mv("A1", "AEnd"));
    sim.command_at(2_100, mv("B1", "A2"));
    sim.command_at(2_200, mv("B1", "BEnd"));
    sim.command_at(2_300, ctl_on("mode", "auto"));
    assert!(sim.run(20_000), "{:#?}", sim.trace);
    check(&sim);
    let answers: Vec<Result<String, String>> = sim.answers.iter().map(|a| a.1.clone()).collect();
    assert_eq!(answers[1], Ok("the token of `A1` moved to `AEnd`".to_string()));
    let why = answers[2].clone().expect_err("two tokens in branch A");
    assert!(why.contains("could never reach") && why.contains("{A2, AEnd}"), "{why}");
    assert_eq!(answers[3], Ok("the token of `B1` moved to `BEnd`".to_string()));
    let t = &sim.trace;
    assert!(first(t, TraceEvent::ActionOn, "MoveA2").is_none(), "A2 was skipped: {t:#?}");
    assert!(first(t, TraceEvent::ActionOn, "MoveB2").is_none(), "B2 was skipped");
    let done = first(t, TraceEvent::Activate, "Done").expect("the chart ended");
    assert!(done >= 2_300, "Done at {done}, before auto mode");
}

/// A cell that stays at its end, operated at random moments on a faulty network — held, stopped or aborted, then
/// cleared, reset and started again, over and over, with a robot restarted and the coordinator crashed (its journal
/// replayed across the resets): the whole trace keeps the invariants, nothing starts while held, and the last run,
/// unless stopped or aborted, makes its three parts from the initial values.
#[test]
fn random_commands_on_a_cell_that_stays_keep_every_promise_across_resets() {
    use baton_proto::testing::simulated_cluster::Rng;
    let cell = std::fs::read_to_string(std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/cell.st"))
        .expect("examples/cell.st");
    let agents: &[(&str, &[&str])] = &[("robot1", &["assembler"]), ("robot2", &["assembler"])];
    let seeds: u64 = std::env::var("BATON_SIM_SEEDS").ok().and_then(|s| s.parse().ok()).unwrap_or(16);
    let mut new_runs = 0;
    for seed in 0..seeds {
        let mut rng = Rng::new(seed, 0x2545_F491_4F6C_DD1D);
        let faults = Faults { duplicate: 0.1, reorder: true, delay_ms_max: 5, loss: 0.03 };
        let mut sim = SimCluster::new(&cell, agents, faults, seed);
        sim.set_stay();
        let mut plan = Vec::new();
        let mut t = 0;
        for round in 0..4 {
            t += 300 + rng.next_u64() % 2_500;
            let command = ["hold", "stop", "abort", "suspend"][(rng.next_u64() % 4) as usize];
            plan.push(format!("{t} {command}"));
            sim.command_at(t, ctl(command));
            t += 200 + rng.next_u64() % 1_500;
            for command in ["unhold", "unsuspend", "clear", "reset", "start"] {
                plan.push(format!("{t} {command}"));
                sim.command_at(t, ctl(command));
                t += 50 + rng.next_u64() % 300;
            }
            if round == 1 && seed % 2 == 0 {
                plan.push(format!("{t} coordinator crash"));
                sim.crash_coordinator_at(t, 300);
            }
            if round == 2 && seed % 3 == 0 {
                plan.push(format!("{t} restart robot2"));
                sim.fate_at(t, "robot2", Fate::Restart);
            }
        }
        // Then the cell is let go on, again and again (a hold takes a motion's time to be held, and an unhold
        // before that is refused).
        for k in 0..6 {
            let at = t + 400 + k * 900;
            for command in ["unhold", "unsuspend", "clear", "reset", "start"] {
                sim.command_at(at, ctl(command));
            }
        }
        let plan = plan.join("\n");
        let ended = sim.run(200_000);
        assert!(
            ended,
            "seed {seed}: the cell did not end ({})\n{plan}\n{:#?}",
            sim.coordinator.core().run_state().name(),
            &sim.trace[sim.trace.len().saturating_sub(20)..]
        );
        let core = sim.coordinator.core();
        let by_operator = core.is_ended_by_operator();
        let last_run = sim.trace.iter().rposition(|r| r.event == TraceEvent::NewRun).map_or(0, |i| i + 1);
        new_runs += sim.trace.iter().filter(|r| r.event == TraceEvent::NewRun).count();
        // The whole trace, every run in it; every token of the last run back unless it was ended by an operator.
        if let Err(why) = baton_tests::invariants::check(&sim.trace, core.program(), false) {
            panic!("seed {seed}: {why}\n{plan}");
        }
        if let Err(why) = baton_tests::invariants::check(&sim.trace[last_run..], core.program(), !by_operator) {
            panic!("seed {seed}, the last run: {why}\n{plan}");
        }
        assert!(sim.violations.is_empty(), "seed {seed}: {:?}\n{plan}", sim.violations);
        if !by_operator {
            assert_eq!(core.run_state(), State::Complete, "seed {seed}\n{plan}");
            assert_eq!(sim.value("done"), Some(baton_proto::types::Value::Int(3)), "seed {seed}\n{plan}");
        }
    }
    assert!(new_runs >= seeds as usize, "{new_runs} resets in {seeds} seeds: the plan should reset most runs");
}

/// A command, and what an operator does next: confirmations follow step mode, a force follows manual mode.
type Cmd = (&'static str, Option<&'static str>, Option<&'static str>);
const MENU: [&[Cmd]; 9] = [
    &[("hold", None, None)],
    &[("unhold", None, None)],
    &[("suspend", None, None), ("unsuspend", None, None)],
    &[("hold", None, Some("robot1"))],
    &[("unhold", None, Some("robot1"))],
    &[
        ("mode", Some("step"), None),
        ("confirm", Some("Pick1->Picked1"), None),
        ("confirm", Some("Pick2->Picked2"), None),
        ("confirm", None, None),
    ],
    &[("mode", Some("manual"), None), ("force", Some("Pick1->Picked1"), None), ("force", Some("Pick2->Picked2"), None)],
    &[("force", Some("(Picked1,Picked2)->Assemble"), None)],
    &[("mode", Some("auto"), None)],
];

/// The commands (from `MENU`), the robot's restart and the coordinator's crash a seed's run gets, scheduled on
/// `sim`; the plan, as text for a failure's message.
fn random_plan(sim: &mut SimCluster, rng: &mut baton_proto::testing::simulated_cluster::Rng, seed: u64) -> String {
    let mut plan = Vec::new();
    let mut t = 0;
    for _ in 0..8 {
        t += 150 + rng.next_u64() % 700;
        for &(command, target, agent) in MENU[(rng.next_u64() % MENU.len() as u64) as usize] {
            let request =
                CtlRequest { target: target.map(str::to_string), agent: agent.map(str::to_string), ..ctl(command) };
            plan.push(format!("{t} {command} {target:?} {agent:?}"));
            sim.command_at(t, request);
            t += 100 + rng.next_u64() % 500;
        }
    }
    // Then the cell is let go on, again and again (a hold takes a motion's time to be held).
    for k in 0..6 {
        let at = t + 400 + k * 900;
        for (command, target, agent) in [
            ("unhold", None, None),
            ("unsuspend", None, None),
            ("unhold", None, Some("robot1")),
            ("mode", Some("auto"), None),
        ] {
            sim.command_at(
                at,
                CtlRequest { target: target.map(str::to_string), agent: agent.map(str::to_string), ..ctl(command) },
            );
        }
    }
    let end = match seed % 5 {
        0 => Some("stop"),
        1 => Some("abort"),
        _ => None,
    };
    if let Some(e) = end {
        let at = 300 + rng.next_u64() % 3_000;
        plan.push(format!("{at} {e}"));
        sim.command_at(at, ctl(e));
    }
    if seed.is_multiple_of(3) {
        let at = 200 + rng.next_u64() % 4_000;
        plan.push(format!("{at} restart robot2"));
        sim.fate_at(at, "robot2", Fate::Restart);
    }
    if seed % 4 == 1 {
        let at = 300 + rng.next_u64() % 4_000;
        plan.push(format!("{at} coordinator crash"));
        sim.crash_coordinator_at(at, 400);
    }
    plan.join("\n")
}

/// Operators' commands at random moments — hold, unhold, suspend, partial holds, modes, confirmations, a stop or
/// an abort — on a network that loses, duplicates and reorders, with a robot restarted and the coordinator crashed:
/// no skill starts while its branch is held, no segment runs twice in an epoch, every token is accounted for, the
/// journal replays to the same trace (commands and alarms included; the simulation checks it at each restart), and
/// a run that was not stopped or aborted makes its three parts. `BATON_SIM_SEEDS=N` runs more seeds.
#[test]
fn random_commands_on_a_faulty_cell_keep_every_promise() {
    use baton_proto::testing::simulated_cluster::Rng;
    let cell = std::fs::read_to_string(std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/cell.st"))
        .expect("examples/cell.st");
    let agents: &[(&str, &[&str])] = &[("robot1", &["assembler"]), ("robot2", &["assembler"])];
    let seeds: u64 = std::env::var("BATON_SIM_SEEDS").ok().and_then(|s| s.parse().ok()).unwrap_or(24);
    // What the seeds exercised, together: each kind of command must have had its effect in some run.
    let mut seen = std::collections::BTreeSet::new();
    for seed in 0..seeds {
        let mut rng = Rng::new(seed, 0x5851_F42D_4C95_7F2D);
        let faults = Faults { duplicate: 0.1, reorder: true, delay_ms_max: 5, loss: 0.03 };
        let mut sim = SimCluster::new(&cell, agents, faults, seed);
        let plan = random_plan(&mut sim, &mut rng, seed);
        let finished = sim.run(120_000);
        assert!(
            finished,
            "seed {seed}: the cell did not end\n{plan}\n{:#?}",
            &sim.trace[sim.trace.len().saturating_sub(30)..]
        );
        let program = sim.coordinator.core().program();
        let by_operator = sim.coordinator.core().is_ended_by_operator();
        if let Err(why) = baton_tests::invariants::check(&sim.trace, program, !by_operator) {
            panic!("seed {seed}: {why}\n{plan}");
        }
        assert!(sim.violations.is_empty(), "seed {seed}: {:?}\n{plan}", sim.violations);
        if by_operator {
            assert_eq!(sim.coordinator.core().tokens_in_flight(), 0, "seed {seed}: an ended run holds no token");
        } else {
            if let Err(why) = sim.settled() {
                panic!("seed {seed}: {why}\n{plan}");
            }
            assert_eq!(sim.value("done"), Some(baton_proto::types::Value::Int(3)), "seed {seed}\n{plan}");
        }
        assert_eq!(sim.answers.len(), plan_commands(&sim), "seed {seed}: every command was answered");
        for r in &sim.trace {
            match r.event {
                TraceEvent::State => seen.insert(format!("state {}", r.name)),
                TraceEvent::Command => seen.insert(format!("command {}", r.name)),
                TraceEvent::Recover => seen.insert("recover".to_string()),
                _ => false,
            };
        }
    }
    for wanted in [
        "state held",
        "state suspended",
        "state stopped",
        "state aborted",
        "command confirm",
        "command force",
        "recover",
    ] {
        assert!(seen.contains(wanted), "no seed exercised `{wanted}`: {seen:?}");
    }
}

/// How many commands a run answered: all it was sent before it ended.
fn plan_commands(sim: &SimCluster) -> usize {
    sim.trace.iter().filter(|r| matches!(r.event, TraceEvent::Command | TraceEvent::CommandRefused)).count()
}

/// `baton run --wait-start`: the run waits in Idle — no cycle, no dispatch, a hold refused — until `start`.
#[test]
fn a_run_that_waits_for_start_runs_nothing_until_started() {
    let mut sim = SimCluster::new(CELL, AGENTS, Faults::default(), 10);
    sim.coordinator.wait_start(0);
    sim.command_at(500, ctl("hold"));
    sim.command_at(2_000, ctl("start"));
    assert!(sim.run(20_000), "{:#?}", sim.trace);
    check(&sim);
    let t = &sim.trace;
    let names: Vec<String> = states(t).into_iter().map(|s| s.1).collect();
    assert_eq!(names, ["idle", "starting", "execute"]);
    let why = sim.answers[0].1.clone().expect_err("hold is not legal in idle");
    assert!(why.contains("idle") && why.contains("start"), "{why}");
    let first_fire = t.iter().find(|r| r.event == TraceEvent::Fire).map(|r| r.t_ms).expect("it ran");
    assert!(first_fire >= 2_000, "a transition cleared at {first_fire}, before the start");
    assert!(first(t, TraceEvent::Dispatch, "A1").is_some_and(|d| d >= 2_000));
}

/// `hold --step B1` holds only the branch that holds B1 (r2's), wherever its token is: r1's branch goes on to its end.
#[test]
fn holding_one_step_holds_its_branch_only() {
    let mut sim = SimCluster::new(CELL, AGENTS, Faults::default(), 11);
    sim.command_at(100, CtlRequest { step: Some("B1".into()), ..ctl("hold") });
    sim.command_at(4_000, CtlRequest { step: Some("B1".into()), ..ctl("unhold") });
    assert!(sim.run(20_000), "{:#?}", sim.trace);
    check(&sim);
    let t = &sim.trace;
    assert!(first(t, TraceEvent::Activate, "AEnd").is_some_and(|a| a < 4_000), "r1's branch went on");
    let b2 = first(t, TraceEvent::ActionOn, "MoveB2").expect("B2 ran");
    assert!(b2 >= 4_000, "B2 started at {b2}, while B1's branch was held");
    assert!(states(t).is_empty(), "a step's hold leaves the run in Execute");
}
