//! `Coordinator` at its seams, one input at a time, without a network: membership (agents that come and go,
//! devices), tokens (a dispatch waits for its placement), reports (applied once, in order; an older epoch is
//! told to drop), and control (what `baton set` may set). Agents are played by `AgentRun`s where a real
//! answer is needed.

use crate::cluster::wire::{AgentInfo, Report};
use crate::limits::AGENTS_MAX;

use super::*;

const RUN: RunId = RunId(uuid::Uuid::from_u128(7));

fn coordinator_of(program: &Arc<Program>, layout: &Arc<Layout>) -> Coordinator {
    let (program, layout) = (Arc::clone(program), Arc::clone(layout));
    Coordinator::new(program, layout, RUN, ChartHash("h".into()), crate::cluster::journal::token_ids(RUN))
}

fn coordinator() -> Coordinator {
    let (program, layout) = crate::testing::simulated_cluster::compile(
        "PROGRAM p\nINITIAL_STEP A: END_STEP\nTRANSITION FROM A TO B := TRUE; END_TRANSITION\n\
         STEP B: {role := 'worker'} END_STEP\nEND_PROGRAM\n",
    );
    coordinator_of(&program, &layout)
}

fn info(name: &str, n: u128) -> AgentInfo {
    AgentInfo {
        name: name.into(),
        roles: Vec::new(),
        lease_ms: 1000,
        incarnation: uuid::Uuid::from_u128(n),
        held: Vec::new(),
        pending: Vec::new(),
        skills: None,
    }
}

#[test]
fn agents_that_are_gone_and_hold_nothing_are_forgotten() {
    let mut c = coordinator();
    // Far more names than the coordinator tracks come and go, as on a cell whose agents restart under new
    // names for months.
    for i in 0..(2 * AGENTS_MAX) {
        let name = format!("a{i}");
        let t = i as u64 * 1_000;
        c.handle_agent_up(t, info(&name, i as u128));
        lose(&mut c, t, &name);
    }
    assert!(c.agents.is_empty(), "{} agents remembered", c.agents.len());
    c.handle_agent_up(100_000_000, info("newcomer", 1));
    assert_eq!(c.status().agents.len(), 1, "a new agent is still taken");
}

#[test]
fn a_device_that_cannot_be_reached_is_traced_once_each_way_and_a_rogue_report_changes_nothing() {
    use crate::cluster::runtime::agent::{AgentOutput, AgentRun};
    let source = "PROGRAM p\nVAR\n  door : BOOL; {input := 'opcua', agent := 'cell1', endpoint := \
                  'opc.tcp://10.0.0.5:4840', node := 'ns=2;s=Door'}\n  lamp : BOOL; {output := 'zenoh', \
                  agent := 'cell2', key := 'cell2/lamp'}\nEND_VAR\nINITIAL_STEP A: END_STEP\n\
                  TRANSITION FROM A TO B := door; END_TRANSITION\nSTEP B: END_STEP\nEND_PROGRAM\n";
    let (program, layout) = crate::testing::simulated_cluster::compile(source);
    let mut c = coordinator_of(&program, &layout);
    let mut agent = AgentRun::new("cell1", &[], RUN, ChartHash("h".into()), program, layout, 10);
    agent.set_incarnation(uuid::Uuid::from_u128(1));
    c.handle_agent_up(0, info("cell1", 1));
    c.handle_agent_up(0, info("cell2", 2));
    let reports = |a: &mut AgentRun| {
        let mut out = Vec::new();
        while let Some(o) = a.poll_output() {
            if let AgentOutput::Devices(d) = o {
                out.push(d);
            }
        }
        out
    };
    let traced = |c: &mut Coordinator| {
        let mut out = Vec::new();
        while let Some(o) = c.poll_output() {
            if let CoordOutput::Trace(t) = o {
                if matches!(t.event, TraceEvent::DeviceUp | TraceEvent::DeviceDown) {
                    out.push((t.event, t.name, t.message.unwrap_or_default()));
                }
            }
        }
        out
    };
    traced(&mut c);
    agent.handle_device(0, Err("cannot reach opc.tcp://10.0.0.5:4840: BadTimeout".into()));
    // Tried again and failing for another reason: no second report.
    agent.handle_device(0, Err("cannot reach opc.tcp://10.0.0.5:4840: BadConnectionRejected".into()));
    let down = reports(&mut agent);
    assert_eq!(down.len(), 1);
    c.handle_devices(10, down[0].clone());
    let t = traced(&mut c);
    assert_eq!(t.len(), 1, "{t:?}");
    assert_eq!((t[0].0, t[0].1.as_str()), (TraceEvent::DeviceDown, "door"));
    assert!(t[0].2.contains("OPC UA node ns=2;s=Door") && t[0].2.contains("BadTimeout"), "{}", t[0].2);
    assert_eq!(c.status().agents[0].devices_down[0].var, "door");
    // The same report again (a Join answered), a late one, another process's, and one about a binding of
    // another agent: nothing is traced.
    c.handle_devices(11, down[0].clone());
    let join = crate::cluster::runtime::agent::Join { vars: Vec::new(), vars_seq: 0, peers: Peers::default() };
    agent.handle_join(0, join);
    let again = reports(&mut agent);
    c.handle_devices(12, again[0].clone());
    let mut stale = again[0].clone();
    stale.seq = 1;
    stale.down.clear();
    c.handle_devices(13, stale);
    let mut other = again[0].clone();
    other.seq = 99;
    other.incarnation = uuid::Uuid::from_u128(5);
    other.down.clear();
    c.handle_devices(14, other);
    let mut rogue = again[0].clone();
    rogue.seq = 100;
    rogue.down[0].binding = 1;
    c.handle_devices(15, rogue);
    assert!(traced(&mut c).is_empty());
    assert_eq!(c.status().agents[0].devices_down.len(), 1);
    agent.handle_device(0, Ok(()));
    for r in reports(&mut agent) {
        c.handle_devices(20, r);
    }
    assert_eq!(
        traced(&mut c),
        vec![(TraceEvent::DeviceUp, "door".into(), "OPC UA node ns=2;s=Door on opc.tcp://10.0.0.5:4840".into())]
    );
    assert!(c.status().agents[0].devices_down.is_empty());
}

/// The chart of the seam tests: a segment of one step on the role `worker`, whose exit waits for `done`.
const WORKER_CHART: &str =
    "PROGRAM p\nVAR go : BOOL; done : BOOL; n : INT; END_VAR\nINITIAL_STEP A: Count(N); END_STEP\n\
    TRANSITION FROM A TO B := go; END_TRANSITION\nSTEP B: {role := 'worker'} END_STEP\n\
    TRANSITION FROM B TO C := TRUE; END_TRANSITION\nSTEP C: END_STEP\n\
    ACTION Count: n := n + 1; END_ACTION\nEND_PROGRAM\n";

/// Agent `name` (of `info`'s lease) is lost at `t_ms`: its token goes, and its grace passes without it.
fn lose(c: &mut Coordinator, t_ms: u64, name: &str) {
    c.handle_agent_down(t_ms, name);
    c.handle_cycle(t_ms + crate::limits::loss_grace_ms(1000));
}

fn worker(name: &str, n: u128) -> AgentInfo {
    AgentInfo { roles: vec!["worker".into()], ..info(name, n) }
}

/// Every output, in order.
fn drain(c: &mut Coordinator) -> Vec<CoordOutput> {
    std::iter::from_fn(|| c.poll_output()).collect()
}

fn dispatches(out: &[CoordOutput]) -> Vec<(String, TokenId, u32)> {
    out.iter()
        .filter_map(|o| match o {
            CoordOutput::Send { agent, msg: ToAgent::Dispatch { token, epoch, .. }, .. } => {
                Some((agent.clone(), *token, *epoch))
            }
            _ => None,
        })
        .collect()
}

fn traced(out: &[CoordOutput], event: TraceEvent) -> usize {
    out.iter().filter(|o| matches!(o, CoordOutput::Trace(t) if t.event == event)).count()
}

#[test]
fn a_token_waits_for_an_agent_of_its_role_and_goes_to_the_first_that_comes() {
    let (program, layout) = crate::testing::simulated_cluster::compile(WORKER_CHART);
    let mut c = coordinator_of(&program, &layout);
    c.handle_set(0, "go", &serde_json::json!(true)).expect("go is an input");
    c.handle_cycle(10);
    let out = drain(&mut c);
    assert!(dispatches(&out).is_empty(), "{out:?}");
    assert_eq!(traced(&out, TraceEvent::Wait), 1, "the token says it waits: {out:?}");
    c.handle_agent_up(20, info("stranger", 1));
    assert!(dispatches(&drain(&mut c)).is_empty(), "an agent without the role takes nothing");
    c.handle_agent_up(30, worker("w1", 2));
    let sent = dispatches(&drain(&mut c));
    assert_eq!(sent.len(), 1, "{sent:?}");
    assert_eq!((sent[0].0.as_str(), sent[0].2), ("w1", 1));
    assert_eq!(c.tokens_in_flight(), 1);
}

/// A step whose action binds skill `grip`, on the role `worker`.
const GRIP_CHART: &str = "PROGRAM p\nVAR go : BOOL; gripped : BOOL; END_VAR\nINITIAL_STEP A: END_STEP\n\
    TRANSITION FROM A TO B := go; END_TRANSITION\nSTEP B: {role := 'worker'} Grip(N, gripped); END_STEP\n\
    TRANSITION FROM B TO C := gripped; END_TRANSITION\nSTEP C: END_STEP\n\
    ACTION Grip: {skill := 'grip', force := 20} END_ACTION\nEND_PROGRAM\n";

fn offering(name: &str, n: u128, skills: &[&str]) -> AgentInfo {
    AgentInfo { skills: Some(skills.iter().map(|s| s.to_string()).collect()), ..worker(name, n) }
}

fn skill_alarms(c: &Coordinator) -> Vec<(String, String, bool)> {
    c.alarms()
        .standing()
        .filter(|a| a.message.contains("has no skill"))
        .map(|a| (a.source.clone(), a.message.clone(), a.cause))
        .collect()
}

#[test]
fn an_agent_that_lacks_a_skill_of_the_step_is_sent_nothing_and_an_alarm_names_it_before_anything_moves() {
    let (program, layout) = crate::testing::simulated_cluster::compile(GRIP_CHART);
    let mut c = coordinator_of(&program, &layout);
    // The agent announces itself before the chart reaches the step: the alarm comes at once.
    c.handle_agent_up(0, offering("w1", 1, &["motion"]));
    let alarms = skill_alarms(&c);
    assert_eq!(alarms.len(), 1, "{alarms:?}");
    let (source, message, cause) = &alarms[0];
    assert_eq!(source, "w1");
    assert!(*cause);
    for part in ["agent `w1`", "no skill `grip`", "action `Grip`", "step `B`", "its skills: motion"] {
        assert!(message.contains(part), "{part} missing from: {message}");
    }
    c.handle_set(0, "go", &serde_json::json!(true)).expect("go is an input");
    c.handle_cycle(10);
    let out = drain(&mut c);
    assert!(dispatches(&out).is_empty(), "a step that runs `grip` went to an agent without it: {out:?}");
    assert_eq!(traced(&out, TraceEvent::Wait), 1, "the token says it waits: {out:?}");
    let logged: Vec<&String> = out
        .iter()
        .filter_map(|o| match o {
            CoordOutput::Log { message, .. } => Some(message),
            _ => None,
        })
        .collect();
    assert!(
        logged.iter().any(|m| m.contains("waits") && m.contains("no live agent with role `worker` has the skills")),
        "{logged:?}"
    );
    // Another agent of the role that has the skill takes the token; the one without never does.
    c.handle_agent_up(20, offering("w2", 2, &["grip", "motion"]));
    let sent = dispatches(&drain(&mut c));
    assert_eq!(sent.iter().map(|s| s.0.as_str()).collect::<Vec<_>>(), ["w2"], "{sent:?}");
    // w1 comes back restarted with the skill: its alarm's cause is gone.
    c.handle_agent_up(30, offering("w1", 3, &["grip"]));
    assert!(skill_alarms(&c).iter().all(|(_, _, cause)| !cause), "{:?}", skill_alarms(&c));
}

#[test]
fn an_agent_that_says_nothing_of_its_skills_is_sent_what_its_placement_allows() {
    let (program, layout) = crate::testing::simulated_cluster::compile(GRIP_CHART);
    let mut c = coordinator_of(&program, &layout);
    c.handle_agent_up(0, worker("w1", 1));
    c.handle_set(0, "go", &serde_json::json!(true)).expect("go is an input");
    c.handle_cycle(10);
    assert_eq!(dispatches(&drain(&mut c)).len(), 1);
    assert!(skill_alarms(&c).is_empty());
}

/// The coordinator and one worker agent, with the token of `B` on the agent; returns the agent's reports.
/// A coordinator of `chart` with `w1` (process 2) up as its worker, `go` set and the first cycle run at 10 ms,
/// and the agent `w1` itself.
fn worker_up(chart: &str) -> (Coordinator, crate::cluster::runtime::agent::AgentRun) {
    let (program, layout) = crate::testing::simulated_cluster::compile(chart);
    let mut c = coordinator_of(&program, &layout);
    let mut agent = crate::cluster::runtime::agent::AgentRun::new(
        "w1",
        &["worker".into()],
        RUN,
        ChartHash("h".into()),
        program,
        layout,
        10,
    );
    agent.set_incarnation(uuid::Uuid::from_u128(2));
    c.handle_agent_up(0, worker("w1", 2));
    c.handle_set(1, "go", &serde_json::json!(true)).expect("go is an input");
    c.handle_cycle(10);
    (c, agent)
}

fn one_token_out() -> (Coordinator, Vec<Report>) {
    use crate::cluster::runtime::agent::{AgentOutput, Dispatch};
    let (mut c, mut agent) = worker_up(WORKER_CHART);
    let msg = drain(&mut c)
        .into_iter()
        .find_map(|o| match o {
            CoordOutput::Send { msg: m @ ToAgent::Dispatch { .. }, .. } => Some(m),
            _ => None,
        })
        .expect("a dispatch");
    let ToAgent::Dispatch { token, epoch, segment, entry, vars, vars_seq, fence, peers, held, mode, .. } = msg else {
        unreachable!()
    };
    agent.handle_dispatch(10, Dispatch { token, epoch, segment, entry, vars, vars_seq, fence, peers, held, mode });
    let mut reports = Vec::new();
    let mut now = 10;
    while reports.iter().all(|r: &Report| !r.done) && now < 1_000 {
        now += 10;
        agent.handle_timeout(now);
        while let Some(o) = agent.poll_output() {
            if let AgentOutput::Report(r) = o {
                reports.push(r);
            }
        }
    }
    assert!(reports.iter().any(|r| r.done), "the token came back: {reports:?}");
    (c, reports)
}

#[test]
fn a_report_applies_once_and_its_duplicate_changes_nothing() {
    let (mut c, reports) = one_token_out();
    let last = reports.last().expect("a report").clone();
    for r in &reports {
        c.handle_report(100, r.clone());
    }
    let out = drain(&mut c);
    assert_eq!(traced(&out, TraceEvent::Return), 1, "{out:?}");
    assert_eq!((c.stats().returned, c.tokens_in_flight()), (1, 0));
    let dropped = c.stats().dropped;
    c.handle_report(110, last);
    let out = drain(&mut c);
    assert_eq!(traced(&out, TraceEvent::Return), 0, "a duplicate returns nothing: {out:?}");
    assert_eq!(c.stats().returned, 1);
    assert!(c.stats().dropped > dropped, "the duplicate is counted as dropped");
}

#[test]
fn a_report_of_an_older_epoch_is_answered_with_a_drop() {
    let (mut c, reports) = one_token_out();
    let mut stale = reports[0].clone();
    stale.epoch = 0;
    c.handle_report(100, stale.clone());
    let out = drain(&mut c);
    let dropped = out.iter().any(
        |o| matches!(o, CoordOutput::Send { msg: ToAgent::Drop { token, epoch: 0, .. }, .. } if *token == stale.token),
    );
    assert!(dropped, "{out:?}");
    assert_eq!(traced(&out, TraceEvent::RejectStale), 1, "{out:?}");
    assert_eq!(c.tokens_in_flight(), 1, "the current epoch is untouched");
}

#[test]
fn baton_set_sets_inputs_and_refuses_what_the_chart_writes() {
    let (program, layout) = crate::testing::simulated_cluster::compile(WORKER_CHART);
    let mut c = coordinator_of(&program, &layout);
    let n = program.var_by_name("n").expect("n");
    let err = c.handle_set(0, "n", &serde_json::json!(3)).expect_err("n is written by Count");
    assert!(err.contains("cannot be set") && err.contains("writes it"), "{err}");
    assert!(c.handle_set(0, "go", &serde_json::json!(7)).is_err(), "7 is not a BOOL");
    assert!(c.handle_set(0, "nothing", &serde_json::json!(true)).is_err());
    assert_eq!(c.value(n), Value::Int(0), "a refused set changed nothing");
    assert_eq!(c.handle_set(0, "go", &serde_json::json!(true)), Ok("go := TRUE".to_string()));
}

#[test]
fn a_run_that_reaches_its_end_goes_completing_then_complete() {
    use crate::cluster::runtime::packml::{Command, State};
    let (mut c, reports) = one_token_out();
    assert_eq!((c.run_state(), c.status().state), (State::Execute, State::Execute));
    assert_eq!(c.status().available, vec![Command::Stop, Command::Hold, Command::Suspend, Command::Abort]);
    for r in &reports {
        c.handle_report(100, r.clone());
    }
    c.handle_cycle(110);
    assert!(c.is_terminal(), "C has no way out");
    drain(&mut c);
    c.handle_end(120, None);
    let states: Vec<String> = drain(&mut c)
        .into_iter()
        .filter_map(|o| match o {
            CoordOutput::Trace(t) if t.event == TraceEvent::State => Some(t.name),
            _ => None,
        })
        .collect();
    assert_eq!(states, ["completing", "complete"]);
    let status = c.status();
    assert_eq!(status.state, State::Complete);
    // PackML's table allows `reset` here, but this run ends at Complete: it is not offered, and refused.
    assert_eq!(status.available, vec![Command::Stop, Command::Abort]);
    let err = c.handle_command(125, &ctl("reset")).expect_err("the run does not stay");
    assert!(err.contains("baton run --stay"), "{err}");
    assert_eq!(c.run_state(), State::Complete);
    // Ending again changes nothing.
    c.handle_end(130, None);
    assert_eq!(traced(&drain(&mut c), TraceEvent::State), 0);
}

fn ctl(command: &str) -> crate::cluster::wire::CtlRequest {
    crate::cluster::wire::CtlRequest { command: command.into(), by: "op".into(), ..Default::default() }
}

fn states(out: &[CoordOutput]) -> Vec<String> {
    out.iter()
        .filter_map(|o| match o {
            CoordOutput::Trace(t) if matches!(t.event, TraceEvent::State | TraceEvent::NewRun) => {
                Some(if t.event == TraceEvent::NewRun { "new_run".to_string() } else { t.name.clone() })
            }
            _ => None,
        })
        .collect()
}

/// `baton run --stay`: the run completes by itself, offers `reset`, and the reset run is the same chart from its
/// initial steps under a new run id, waiting for `start`; its token goes to the agent the old run knew.
#[test]
fn a_run_that_stays_completes_by_itself_and_reset_starts_the_chart_again_as_a_new_run() {
    use crate::cluster::runtime::packml::{Command, State};
    let (mut c, reports) = one_token_out();
    c.handle_stay();
    for r in &reports {
        c.handle_report(100, r.clone());
    }
    c.handle_cycle(110);
    assert_eq!(states(&drain(&mut c)), ["completing", "complete"], "no End record needed");
    assert_eq!(c.status().available, vec![Command::Reset, Command::Stop, Command::Abort]);
    assert_eq!(c.status().active_steps.iter().map(|s| s.name.as_str()).collect::<Vec<_>>(), ["C"]);
    let go = c.program().var_by_name("go").expect("go");
    assert_eq!(c.value(go), Value::Bool(true));
    c.handle_cycle(120);
    assert!(drain(&mut c).is_empty(), "a complete run does not cycle its chart");
    assert!(!c.wants_new_run());
    c.handle_command(130, &ctl("reset")).expect("reset is legal at Complete");
    assert!(c.wants_new_run());
    assert_eq!(states(&drain(&mut c)), ["resetting"]);
    let second = RunId(uuid::Uuid::from_u128(8));
    let mut next = c.new_run(140, second, crate::cluster::journal::token_ids(second));
    assert_eq!(states(&drain(&mut next)), ["new_run", "idle"]);
    assert_eq!((next.run(), next.run_state(), next.stays()), (second, State::Idle, true));
    assert_eq!(next.status().active_steps.iter().map(|s| s.name.as_str()).collect::<Vec<_>>(), ["A"]);
    assert_eq!(next.value(go), Value::Bool(false), "the initial values again");
    next.handle_cycle(150);
    assert_eq!(next.status().active_steps.iter().map(|s| s.name.as_str()).collect::<Vec<_>>(), ["A"]);
    next.handle_command(160, &ctl("start")).expect("start from Idle");
    next.handle_set(161, "go", &serde_json::json!(true)).expect("go is an input");
    next.handle_cycle(170);
    let out = drain(&mut next);
    let sent: Vec<(String, RunId)> = out
        .iter()
        .filter_map(|o| match o {
            CoordOutput::Send { agent, msg: ToAgent::Dispatch { run, .. }, .. } => Some((agent.clone(), *run)),
            _ => None,
        })
        .collect();
    assert_eq!(sent, [("w1".to_string(), second)], "{out:?}");
}

/// Aborted, then `clear` (to Stopped) and `reset` (to Resetting), as PackML's table says.
#[test]
fn clear_takes_an_aborted_run_that_stays_to_stopped_and_reset_on() {
    use crate::cluster::runtime::packml::State;
    let (mut c, _) = one_token_out();
    c.handle_stay();
    drain(&mut c);
    assert!(c.handle_command(100, &ctl("reset")).is_err(), "reset is not legal in Execute");
    c.handle_command(110, &ctl("abort")).expect("abort");
    c.handle_command(120, &ctl("clear")).expect("clear from Aborted");
    assert_eq!(states(&drain(&mut c)), ["aborting", "aborted", "clearing", "stopped"]);
    assert!(c.handle_command(125, &ctl("clear")).is_err(), "clear only from Aborted");
    c.handle_command(130, &ctl("reset")).expect("reset from Stopped");
    assert_eq!(c.run_state(), State::Resetting);
}

/// An agent lost when the run is aborted is not waited for: its token is abandoned with an alarm. When it is heard
/// from again it is told of the abort (and the alarm's cause is gone); until then it is listed as untold.
#[test]
fn an_agent_cut_off_at_the_abort_is_told_when_it_comes_back() {
    use crate::cluster::runtime::alarms::AlarmState;
    let (mut c, _) = one_token_out();
    lose(&mut c, 50, "w1");
    drain(&mut c);
    c.handle_command(300, &ctl("abort")).expect("abort");
    let out = drain(&mut c);
    let aborts = |out: &[CoordOutput]| {
        out.iter().filter(|o| matches!(o, CoordOutput::Send { msg: ToAgent::Abort { run }, .. } if *run == RUN)).count()
    };
    assert_eq!(aborts(&out), 0, "w1 cannot hear it now: {out:?}");
    assert_eq!(c.untold_agents().collect::<Vec<_>>(), ["w1"]);
    let abandoned = c.status().alarms.into_iter().find(|a| a.message.contains("abandoned")).expect("the alarm");
    assert_eq!(abandoned.state, AlarmState::ActiveUnacknowledged);
    c.handle_agent_up(400, worker("w1", 2));
    let out = drain(&mut c);
    assert_eq!(aborts(&out), 1, "{out:?}");
    assert_eq!(traced(&out, TraceEvent::Told), 1, "{out:?}");
    assert_eq!(c.untold_agents().count(), 0);
    let alarm = c.status().alarms.into_iter().find(|a| a.id == abandoned.id).expect("latched until acknowledged");
    assert_eq!(alarm.state, AlarmState::ReturnedUnacknowledged);
}

#[test]
fn a_run_that_ends_failed_or_not_terminal_does_not_complete() {
    let (mut c, _) = one_token_out();
    c.handle_end(100, None);
    assert_eq!(traced(&drain(&mut c), TraceEvent::State), 0, "a token is still out: the chart is not done");
    let (mut c, reports) = one_token_out();
    for r in &reports {
        c.handle_report(100, r.clone());
    }
    c.handle_cycle(110);
    drain(&mut c);
    c.handle_end(120, Some("agent `w1` was lost"));
    assert_eq!(traced(&drain(&mut c), TraceEvent::State), 0);
    assert_eq!(c.run_state(), crate::cluster::runtime::packml::State::Execute);
}

#[test]
fn an_agent_lost_holding_a_token_raises_an_alarm_of_its_own_that_the_status_lists() {
    use crate::cluster::runtime::alarms::AlarmState;
    let (mut c, _) = one_token_out();
    drain(&mut c);
    lose(&mut c, 50, "w1");
    let alarms: Vec<TraceRecord> = drain(&mut c)
        .into_iter()
        .filter_map(|o| match o {
            CoordOutput::Trace(t) if t.event == TraceEvent::Alarm => Some(t),
            _ => None,
        })
        .collect();
    assert_eq!(alarms.len(), 1, "{alarms:?}");
    assert_eq!((alarms[0].name.as_str(), alarms[0].id), ("w1", Some(1)), "its source and its id");
    assert!(alarms[0].message.as_deref().is_some_and(|m| m.contains("lost holding the token of step `B`")));
    let status = c.status();
    assert_eq!(status.alarms.len(), 1);
    assert_eq!((status.alarms[0].id, status.alarms[0].state), (1, AlarmState::ActiveUnacknowledged));
    // The next occurrence is an alarm of its own.
    c.handle_agent_up(300, worker("w1", 3));
    lose(&mut c, 400, "w1");
    let ids: Vec<u64> = c.status().alarms.iter().map(|a| a.id).collect();
    assert!(ids.len() >= 2 && ids.windows(2).all(|w| w[0] < w[1]), "{ids:?}");
}

/// A token that reported and then went quiet makes the coordinator ask its agent for the reports it has not had
/// acknowledged — after `ASK_FIRST_MS`, then at doubling delays — and a token that came back is never asked for.
#[test]
fn the_agent_of_a_token_gone_quiet_is_asked_for_its_pending_reports() {
    use crate::cluster::runtime::agent::{AgentOutput, AgentRun, Dispatch};
    // Two steps on the worker: it reports the first transition, then waits for `done`.
    let (mut c, mut agent) = worker_up(
        "PROGRAM p\nVAR go : BOOL; done : BOOL; END_VAR\nINITIAL_STEP A: END_STEP\n\
         TRANSITION FROM A TO B := go; END_TRANSITION\nSTEP B: {role := 'worker'} END_STEP\n\
         TRANSITION FROM B TO B2 := TRUE; END_TRANSITION\nSTEP B2: {role := 'worker'} END_STEP\n\
         TRANSITION FROM B2 TO C := done; END_TRANSITION\nSTEP C: END_STEP\nEND_PROGRAM\n",
    );
    // What the coordinator sends reaches the agent, what the agent reports reaches the coordinator at `now`.
    let exchange = |c: &mut Coordinator, agent: &mut AgentRun, now: u64| -> Vec<(String, uuid::Uuid)> {
        let mut asks = Vec::new();
        for o in drain(c) {
            match o {
                CoordOutput::Send {
                    msg:
                        ToAgent::Dispatch { token, epoch, segment, entry, vars, vars_seq, fence, peers, held, mode, .. },
                    ..
                } => {
                    let d = Dispatch { token, epoch, segment, entry, vars, vars_seq, fence, peers, held, mode };
                    agent.handle_dispatch(now, d);
                }
                CoordOutput::Send { msg: ToAgent::Ack { acks, .. }, .. } => {
                    for a in acks {
                        agent.handle_ack(a.token, a.epoch, a.seq, a.done);
                    }
                }
                CoordOutput::Vars(u) => agent.handle_vars(now, 0, &u),
                CoordOutput::Ask { agent, incarnation } => asks.push((agent, incarnation)),
                _ => {}
            }
        }
        agent.handle_timeout(now);
        while let Some(o) = agent.poll_output() {
            if let AgentOutput::Report(r) = o {
                c.handle_report(now, r);
            }
        }
        asks
    };
    let mut asked_at = Vec::new();
    for t in (10..=8_000).step_by(10) {
        if c.poll_timeout().is_some_and(|due| due <= t) {
            c.handle_cycle(t);
        }
        for ask in exchange(&mut c, &mut agent, t) {
            assert_eq!(ask, ("w1".to_string(), uuid::Uuid::from_u128(2)), "the process that holds it");
            asked_at.push(t);
        }
    }
    let first = asked_at.first().copied().expect("asked");
    assert!((1_000..1_100).contains(&first), "a second after its report: {asked_at:?}");
    assert_eq!(asked_at, [first, first + 2_000, first + 6_000], "then after 2 s, then after 4 s");
    assert_eq!(c.stats().asked, 3);
    assert_eq!(agent.pending_reports(8), Vec::new(), "its report was acknowledged: nothing to list");
    // It comes back: nothing is asked any more.
    c.handle_set(8_000, "done", &serde_json::json!(true)).expect("done is an input");
    for t in (8_010..=30_000).step_by(10) {
        c.handle_cycle(t);
        assert!(exchange(&mut c, &mut agent, t).is_empty(), "asked at {t} about a token that came back");
    }
    assert_eq!(c.tokens_in_flight(), 0);
}

/// A session Zenoh drops and takes back within the agent's grace (`limits::loss_grace_ms`, an eighth of its lease)
/// is no loss: nothing is traced, no alarm, the token stays where it is. Past the grace, the agent is lost; a new
/// process of its name within the grace means the old one was lost.
#[test]
fn an_agent_back_within_its_grace_was_never_lost() {
    let grace = crate::limits::loss_grace_ms(1000);
    assert_eq!(grace, 125);
    let (mut c, _) = one_token_out();
    drain(&mut c);
    c.handle_agent_down(50, "w1");
    assert_eq!(c.poll_timeout(), Some(50 + grace), "the grace's end is a deadline");
    c.handle_cycle(50 + grace - 10);
    c.handle_agent_up(50 + grace - 5, worker("w1", 2));
    c.handle_cycle(50 + 2 * grace);
    let out = drain(&mut c);
    for e in [TraceEvent::AgentLost, TraceEvent::Alarm, TraceEvent::AgentUp, TraceEvent::Resume] {
        assert_eq!(traced(&out, e), 0, "{e:?}: {out:?}");
    }
    assert_eq!(c.status().tokens[0].agent.as_deref(), Some("w1"));
    assert!(!c.status().tokens[0].paused);
    // Gone past its grace: lost, with its alarm.
    c.handle_agent_down(1_000, "w1");
    c.handle_cycle(1_000 + grace - 1);
    assert_eq!(traced(&drain(&mut c), TraceEvent::AgentLost), 0, "still within its grace");
    c.handle_cycle(1_000 + grace);
    let out = drain(&mut c);
    assert_eq!((traced(&out, TraceEvent::AgentLost), traced(&out, TraceEvent::Alarm)), (1, 1), "{out:?}");
    assert!(c.status().tokens[0].paused);
    // Another process under its name within the grace: the one that went was lost.
    let (mut c, _) = one_token_out();
    drain(&mut c);
    c.handle_agent_down(50, "w1");
    c.handle_agent_up(60, worker("w1", 9));
    let out = drain(&mut c);
    assert_eq!((traced(&out, TraceEvent::AgentLost), traced(&out, TraceEvent::AgentUp)), (1, 1), "{out:?}");
}
