//! `AgentRun` at its seams, one input at a time, without a network or a coordinator: what a dispatch starts,
//! what a skill's result hands back, what is sent again until acknowledged, and what the agent refuses. The
//! deterministic simulation (`testing::simulated_cluster`) runs the same state machine among many; these name
//! the rule that broke.

use crate::cluster::runtime::COORDINATOR;
use crate::cluster::wire::{AckEntry, AgentEventKind};
use crate::testing::simulated_cluster::compile;

use super::*;

const CHART: &str = "
PROGRAM Cell
VAR go, moved : BOOL; n : INT; END_VAR
INITIAL_STEP Idle: END_STEP
TRANSITION FROM Idle TO Work := go; END_TRANSITION
STEP Work: {agent := 'a1'} Move(N, moved); Count(N); END_STEP
TRANSITION Done FROM Work TO Back := moved; END_TRANSITION
STEP Back: END_STEP
ACTION Move: {skill := 'motion', ms := 100} END_ACTION
ACTION Count: IF n < 6 THEN n := n + 1; END_IF; END_ACTION
END_PROGRAM
";

const CYCLE_MS: u64 = 10;
const COORDINATOR_PROCESS: Uuid = Uuid::from_u128(7);

struct Fixture {
    program: Arc<Program>,
    layout: Arc<Layout>,
}

impl Fixture {
    fn new() -> Fixture {
        let (program, layout) = compile(CHART);
        Fixture { program, layout }
    }

    fn agent(&self, name: &str) -> AgentRun {
        let hash = ChartHash::of(CHART, "Cell");
        let mut a = AgentRun::new(
            name,
            &[],
            RunId(Uuid::from_u128(1)),
            hash,
            Arc::clone(&self.program),
            Arc::clone(&self.layout),
            CYCLE_MS,
        );
        a.set_incarnation(Uuid::from_u128(100));
        a
    }

    fn step(&self, name: &str) -> StepId {
        StepId(self.program.steps.iter().position(|s| s.name == name).expect("a step") as u32)
    }

    fn action(&self, name: &str) -> ActionId {
        ActionId(self.program.actions.iter().position(|a| a.name == name).expect("an action") as u32)
    }

    fn var(&self, name: &str) -> VarId {
        self.program.var_by_name(name).expect("a variable")
    }

    /// The dispatch of the segment that starts at `Work`, as the coordinator sends it.
    fn dispatch(&self, token: u128, epoch: u32, fence: bool) -> Dispatch {
        let work = self.step("Work");
        let segment = self.layout.segments.iter().position(|s| s.steps.contains(&work)).expect("Work's segment");
        Dispatch {
            token: TokenId(Uuid::from_u128(token)),
            epoch,
            segment: segment as u32,
            entry: work.0,
            vars: vec![VarValue::new(self.var("n"), Value::Int(5))],
            vars_seq: 1,
            fence,
            peers: Peers { seq: 1, coordinator: COORDINATOR_PROCESS, agents: Vec::new() },
            held: false,
            mode: Default::default(),
        }
    }
}

/// Every output the agent has, in order.
fn drain(a: &mut AgentRun) -> Vec<AgentOutput> {
    std::iter::from_fn(|| a.poll_output()).collect()
}

/// Runs the agent's timers up to `until_ms`, as a host does, and returns what it asked for on the way.
fn run_until(a: &mut AgentRun, until_ms: u64) -> Vec<AgentOutput> {
    let mut out = drain(a);
    while let Some(t) = a.poll_timeout().filter(|&t| t <= until_ms) {
        a.handle_timeout(t);
        out.extend(drain(a));
    }
    out
}

fn reports(out: &[AgentOutput]) -> Vec<&Report> {
    out.iter().filter_map(|o| if let AgentOutput::Report(r) = o { Some(r) } else { None }).collect()
}

fn started(out: &[AgentOutput]) -> Vec<ActionId> {
    out.iter()
        .filter_map(|o| if let AgentOutput::StartSkill { action, .. } = o { Some(*action) } else { None })
        .collect()
}

#[test]
fn a_dispatch_starts_its_skill_and_the_skills_success_hands_the_token_back() {
    let f = Fixture::new();
    let mut a = f.agent("a1");
    a.handle_dispatch(0, f.dispatch(1, 1, false));
    let out = run_until(&mut a, 30);
    assert_eq!(started(&out), vec![f.action("Move")], "{out:?}");
    assert_eq!(a.tokens_held(), 1);
    // The dispatch's values are the chart's: Count counts on from 5 (to 6), not from its initial 0.
    assert_eq!(a.engine.value(f.var("n")), Value::Int(6));
    a.handle_skill_result(35, f.action("Move"), Ok(()));
    let out = run_until(&mut a, 60);
    let last = reports(&out).into_iter().last().expect("a report");
    assert!(last.done, "the token left the agent: {last:?}");
    let done = f.program.transitions.iter().position(|t| t.name == "Done").expect("Done") as u32;
    let kinds: Vec<&AgentEventKind> = last.events.iter().map(|e| &e.kind).collect();
    assert!(kinds.contains(&&AgentEventKind::Fire { transition: done }), "{kinds:?}");
    let skill_done = reports(&out)
        .iter()
        .flat_map(|r| &r.events)
        .any(|e| e.kind == AgentEventKind::SkillDone { action: f.action("Move").0 });
    assert!(skill_done, "{out:?}");
}

#[test]
fn a_dispatch_seen_before_changes_nothing() {
    let f = Fixture::new();
    let mut a = f.agent("a1");
    a.handle_dispatch(0, f.dispatch(1, 2, false));
    assert_eq!(started(&run_until(&mut a, 20)), vec![f.action("Move")]);
    // The same epoch again, and an older one: duplicates, counted and dropped.
    a.handle_dispatch(25, f.dispatch(1, 2, false));
    a.handle_dispatch(26, f.dispatch(1, 1, false));
    assert!(started(&run_until(&mut a, 40)).is_empty());
    assert_eq!((a.dropped(), a.tokens_held()), (2, 1));
}

#[test]
fn a_report_goes_again_until_it_is_acknowledged_and_not_after() {
    let f = Fixture::new();
    let mut a = f.agent("a1");
    let d = f.dispatch(1, 1, false);
    let token = d.token;
    a.handle_dispatch(0, d);
    let first = run_until(&mut a, 20);
    let sent: Vec<u32> = reports(&first).iter().map(|r| r.seq).collect();
    assert!(!sent.is_empty(), "the skill's start is reported: {first:?}");
    // Unacknowledged, the same reports go again later, with the same numbers.
    let again = run_until(&mut a, 5_000);
    let resent: Vec<u32> = reports(&again).iter().map(|r| r.seq).collect();
    assert!(resent.iter().all(|s| sent.contains(s)) && !resent.is_empty(), "{sent:?} then {resent:?}");
    assert!(a.oldest_unacked_ms().is_some());
    // Acknowledged, they stop.
    a.handle_ack(token, 1, *sent.iter().max().expect("a report"), false);
    assert_eq!(a.oldest_unacked_ms(), None);
    assert!(reports(&run_until(&mut a, 60_000)).is_empty());
}

/// `d` as the coordinator sends it, with `acks`, for the run `run` of the chart with `hash`.
fn dispatch_message(d: Dispatch, run: RunId, chart: ChartHash, acks: Vec<AckEntry>) -> ToAgent {
    let Dispatch { token, epoch, segment, entry, vars, vars_seq, fence, peers, held, mode } = d;
    ToAgent::Dispatch { run, chart, token, epoch, segment, entry, vars, vars_seq, acks, fence, peers, held, mode }
}

#[test]
fn a_message_is_taken_whole_acknowledgements_first_and_only_for_this_run_and_chart() {
    let f = Fixture::new();
    let mut a = f.agent("a1");
    let (run, hash) = (a.run(), a.hash().clone());
    // Token 1 runs and comes back: its last report, `done`, waits for its acknowledgement.
    a.handle_message(0, 0, dispatch_message(f.dispatch(1, 1, false), run, hash.clone(), Vec::new())).expect("taken");
    run_until(&mut a, 30);
    a.handle_skill_result(35, f.action("Move"), Ok(()));
    let out = run_until(&mut a, 60);
    let last = *reports(&out).last().expect("a report");
    assert!(last.done && a.oldest_unacked_ms().is_some(), "{out:?}");
    // Another run's message, and a dispatch of another version of the chart, change nothing here.
    let other_run = RunId(Uuid::from_u128(99));
    let stray = dispatch_message(f.dispatch(2, 1, false), other_run, hash.clone(), Vec::new());
    assert_eq!(a.handle_message(70, 0, stray), Err(NotTaken::OtherRun));
    let other_chart = dispatch_message(f.dispatch(2, 1, false), run, ChartHash("another".into()), Vec::new());
    assert_eq!(a.handle_message(70, 0, other_chart), Err(NotTaken::OtherChart));
    assert!(started(&run_until(&mut a, 90)).is_empty() && a.tokens_held() == 0);
    // Token 2's dispatch carries the acknowledgement of token 1's `done`: both are taken, the acknowledgement
    // first, so nothing of token 1 is sent again while token 2 runs.
    let ack = AckEntry { token: last.token, epoch: last.epoch, seq: last.seq, done: true };
    a.handle_message(100, 0, dispatch_message(f.dispatch(2, 1, false), run, hash, vec![ack])).expect("taken");
    assert!(a.pending_reports(usize::MAX).iter().all(|r| r.token != last.token));
    let out = run_until(&mut a, 5_000);
    assert_eq!(started(&out), vec![f.action("Move")], "{out:?}");
    assert!(reports(&out).iter().all(|r| r.token != last.token), "{out:?}");
}

#[test]
fn a_token_of_a_segment_placed_elsewhere_is_refused() {
    let f = Fixture::new();
    let mut a = f.agent("a2");
    a.handle_dispatch(0, f.dispatch(1, 1, false));
    let out = run_until(&mut a, 20);
    assert!(started(&out).is_empty() && a.tokens_held() == 0, "{out:?}");
    let said = out.iter().any(|o| matches!(o, AgentOutput::Log { message, .. } if message.contains("does not serve")));
    assert!(said, "{out:?}");
}

#[test]
fn a_dropped_token_stops_running_here() {
    let f = Fixture::new();
    let mut a = f.agent("a1");
    let d = f.dispatch(1, 1, false);
    let token = d.token;
    a.handle_dispatch(0, d);
    run_until(&mut a, 20);
    a.handle_drop(25, token, 1);
    let out = run_until(&mut a, 40);
    assert_eq!(a.tokens_held(), 0);
    assert!(
        out.iter().any(|o| matches!(o, AgentOutput::StopSkill { action } if *action == f.action("Move"))),
        "{out:?}"
    );
    // Its epoch is remembered: a late copy of the dispatch does not start it again.
    a.handle_dispatch(45, f.dispatch(1, 1, false));
    assert!(started(&run_until(&mut a, 60)).is_empty());
}

#[test]
fn the_lease_fence_stops_the_skills_of_a_token_that_may_move_and_only_those() {
    let f = Fixture::new();
    for fence in [true, false] {
        let mut a = f.agent("a1");
        a.handle_dispatch(0, f.dispatch(1, 1, fence));
        run_until(&mut a, 20);
        a.handle_contact(25, Some(crate::limits::fence_after_ms(1_000)));
        let out = run_until(&mut a, 40);
        let stopped = out.iter().any(|o| matches!(o, AgentOutput::StopSkill { .. }));
        assert_eq!(stopped, fence, "fence {fence}: {out:?}");
        // Each cancel is in the agent's trace, with its action and token, and only a cancel.
        let expected = if fence { vec![("Move".to_string(), Some(token_text(1)))] } else { Vec::new() };
        assert_eq!(cancels(&out), expected, "fence {fence}: {out:?}");
    }
}

#[test]
fn a_value_claiming_the_coordinators_name_from_another_process_is_refused() {
    let f = Fixture::new();
    let mut a = f.agent("a1");
    a.handle_dispatch(0, f.dispatch(1, 1, false));
    run_until(&mut a, 5);
    let go = f.var("go");
    let forged = VarUpdate {
        run: RunId(Uuid::from_u128(1)),
        from: COORDINATOR.to_string(),
        incarnation: Uuid::from_u128(666),
        seq: 99,
        vars: vec![VarValue::new(go, Value::Bool(true))],
    };
    a.handle_vars(6, 0, &forged);
    assert_eq!(a.engine.value(go), Value::Bool(false), "a forged update changed nothing");
    let genuine = VarUpdate { incarnation: COORDINATOR_PROCESS, seq: 2, ..forged };
    a.handle_vars(7, 0, &genuine);
    assert_eq!(a.engine.value(go), Value::Bool(true), "the coordinator's own process is heard");
}

fn events(out: &[AgentOutput]) -> Vec<AgentEventKind> {
    reports(out).iter().flat_map(|r| r.events.iter().map(|e| e.kind.clone())).collect()
}

fn stopped(out: &[AgentOutput]) -> Vec<ActionId> {
    out.iter().filter_map(|o| if let AgentOutput::StopSkill { action } = o { Some(*action) } else { None }).collect()
}

/// A hold lets the running skill finish: the agent confirms `Held` only after its result, and the transition its
/// result makes TRUE does not clear until the token is released.
#[test]
fn a_held_token_is_confirmed_only_when_its_skill_finished_and_clears_nothing_until_released() {
    let f = Fixture::new();
    let mut a = f.agent("a1");
    let token = TokenId(Uuid::from_u128(1));
    a.handle_dispatch(0, f.dispatch(1, 1, false));
    run_until(&mut a, 15);
    a.handle_hold(20, token, 1, true);
    let out = run_until(&mut a, 30);
    assert!(!events(&out).contains(&AgentEventKind::Held), "confirmed while its skill runs: {out:?}");
    a.handle_skill_result(35, f.action("Move"), Ok(()));
    let out = run_until(&mut a, 200);
    let ev = events(&out);
    assert!(ev.contains(&AgentEventKind::Held), "{ev:?}");
    assert!(!ev.iter().any(|e| matches!(e, AgentEventKind::Fire { .. })), "a held token cleared a transition: {ev:?}");
    // A repeat of the hold changes nothing and says nothing new.
    a.handle_hold(210, token, 1, true);
    assert!(events(&run_until(&mut a, 220)).is_empty());
    a.handle_hold(230, token, 1, false);
    let ev = events(&run_until(&mut a, 260));
    assert_eq!(ev.first(), Some(&AgentEventKind::Released), "{ev:?}");
    assert!(ev.iter().any(|e| matches!(e, AgentEventKind::Fire { .. })), "released, Done clears: {ev:?}");
}

/// A token that arrives held starts nothing (its entry step waits) and is confirmed at once; released, it runs.
#[test]
fn a_token_dispatched_held_starts_nothing_until_released() {
    let f = Fixture::new();
    let mut a = f.agent("a1");
    a.handle_dispatch(0, Dispatch { held: true, ..f.dispatch(1, 1, false) });
    let out = run_until(&mut a, 100);
    assert!(started(&out).is_empty(), "{out:?}");
    assert_eq!(events(&out), [AgentEventKind::Held]);
    assert!(!reports(&out).iter().any(|r| r.done), "a token waiting to be released is not done");
    a.handle_hold(110, TokenId(Uuid::from_u128(1)), 1, false);
    assert_eq!(started(&run_until(&mut a, 130)), [f.action("Move")]);
}

/// An abort cancels the running skill, forgets the token and refuses what comes for the run later.
#[test]
fn an_abort_cancels_the_running_skill_and_forgets_the_run() {
    let f = Fixture::new();
    let mut a = f.agent("a1");
    a.handle_dispatch(0, f.dispatch(1, 1, false));
    run_until(&mut a, 15);
    a.handle_abort(20);
    let out = drain(&mut a);
    assert_eq!(stopped(&out), [f.action("Move")], "{out:?}");
    assert_eq!(cancels(&out), [("Move".to_string(), Some(token_text(1)))], "{out:?}");
    assert_eq!(a.tokens_held(), 0);
    assert!(a.poll_timeout().is_none_or(|t| t > 20), "nothing due at once");
    a.handle_dispatch(30, f.dispatch(2, 1, false));
    assert!(started(&drain(&mut a)).is_empty() && a.tokens_held() == 0, "a dispatch after the abort runs nothing");
}

/// The skills the agent's trace says were cancelled: (action, token).
fn cancels(out: &[AgentOutput]) -> Vec<(String, Option<String>)> {
    out.iter()
        .filter_map(|o| match o {
            AgentOutput::Trace(r) if r.event == crate::exec::trace::TraceEvent::SkillCancel => {
                Some((r.name.clone(), r.token.clone()))
            }
            _ => None,
        })
        .collect()
}

/// Token `n` of `Fixture::dispatch`, as a trace writes it.
fn token_text(n: u128) -> String {
    TokenId(Uuid::from_u128(n)).to_string()
}

fn logs(out: &[AgentOutput]) -> Vec<(Level, String)> {
    out.iter()
        .filter_map(|o| match o {
            AgentOutput::Log { level, message } => Some((*level, message.clone())),
            _ => None,
        })
        .collect()
}

/// The end of a run's segments (`ToAgent::Abort`, which a stop sends too, once the motions finished) is a warning
/// only where it cancels something: an agent that held nothing says it plainly.
#[test]
fn the_end_of_a_run_is_a_warning_only_where_it_cancels_a_skill() {
    let f = Fixture::new();
    let mut idle = f.agent("a1");
    idle.handle_abort(20);
    let said = logs(&drain(&mut idle));
    assert!(said.iter().all(|(level, _)| *level == Level::Info), "{said:?}");
    assert!(said.iter().all(|(_, m)| !m.contains("aborted") && !m.contains("cancelled")), "{said:?}");

    let mut busy = f.agent("a1");
    busy.handle_dispatch(0, f.dispatch(1, 1, false));
    run_until(&mut busy, 15);
    busy.handle_abort(20);
    let said = logs(&drain(&mut busy));
    assert!(said.iter().any(|(l, m)| *l == Level::Warn && m.contains("1 skill(s) cancelled")), "{said:?}");
}

/// Fencing by term: once a run has seen a coordinator's term, nothing of a lower one is taken — no command, not
/// even a drop or an abort, and no value of the coordinator's — while the same or a higher term is; each refusal
/// is traced with what it refused.
#[test]
fn a_deposed_coordinators_commands_and_values_are_refused_once_a_newer_term_is_seen() {
    let f = Fixture::new();
    let mut a = f.agent("a1");
    let (run, hash) = (a.run(), a.hash().clone());
    let token = TokenId(Uuid::from_u128(1));
    a.handle_message(0, 5, dispatch_message(f.dispatch(1, 1, false), run, hash.clone(), Vec::new())).expect("taken");
    assert_eq!(started(&run_until(&mut a, 20)), vec![f.action("Move")]);
    assert_eq!(a.term(), (5, 0));

    // The old coordinator (term 4) drops the token and aborts the run: neither is taken.
    assert_eq!(a.handle_message(25, 4, ToAgent::Drop { run, token, epoch: 1 }), Err(NotTaken::StaleTerm));
    assert_eq!(a.handle_message(26, 4, ToAgent::Abort { run }), Err(NotTaken::StaleTerm));
    let out = run_until(&mut a, 40);
    assert_eq!(a.tokens_held(), 1, "the token runs on: {out:?}");
    assert!(stopped(&out).is_empty(), "no skill was stopped: {out:?}");
    let refused: Vec<String> = out
        .iter()
        .filter_map(|o| match o {
            AgentOutput::Trace(r) if r.event == crate::exec::trace::TraceEvent::StaleTerm => Some(r.name.clone()),
            _ => None,
        })
        .collect();
    assert_eq!(refused, vec!["drop".to_string(), "abort".to_string()], "{out:?}");
    let warned = out
        .iter()
        .filter(|o| matches!(o, AgentOutput::Log { level: Level::Warn, message } if message.contains("term 4")))
        .count();
    assert_eq!(warned, 1, "said once per stale term: {out:?}");

    // Its value is refused too; the same value from term 5 is taken.
    let go = f.var("go");
    let update = VarUpdate {
        run,
        from: COORDINATOR.to_string(),
        incarnation: COORDINATOR_PROCESS,
        seq: 2,
        vars: vec![VarValue::new(go, Value::Bool(true))],
    };
    a.handle_vars(41, 4, &update);
    assert_eq!(a.engine.value(go), Value::Bool(false), "a deposed coordinator's value changed nothing");
    a.handle_vars(42, 5, &update);
    assert_eq!(a.engine.value(go), Value::Bool(true), "the current coordinator's value is taken");
    assert_eq!(a.term(), (5, 3));

    // A newer coordinator (term 7) takes over; term 5 is now the stale one, and 7 is heard.
    a.handle_message(50, 7, ToAgent::Sync { run }).expect("a higher term is taken");
    assert_eq!(a.handle_message(51, 5, ToAgent::Drop { run, token, epoch: 1 }), Err(NotTaken::StaleTerm));
    assert_eq!(a.tokens_held(), 1);
    a.handle_message(52, 7, ToAgent::Drop { run, token, epoch: 1 }).expect("the current term is heard");
    run_until(&mut a, 70);
    assert_eq!(a.tokens_held(), 0);
    assert_eq!(a.term(), (7, 4));
}

/// A run joined again by a restarted agent process starts from the term the process before it had heard
/// (`remember_term`): a dispatch of a lower term is refused before anything moves, one of that term is taken, and a
/// lower remembered term (none, 0) changes nothing.
#[test]
fn a_remembered_term_refuses_a_deposed_coordinators_dispatch_from_the_first_message() {
    let f = Fixture::new();
    let mut a = f.agent("a1");
    let (run, hash) = (a.run(), a.hash().clone());
    a.remember_term(0, 9);
    a.remember_term(0, 0);
    assert_eq!(a.term(), (9, 0));
    let stale = dispatch_message(f.dispatch(1, 1, false), run, hash.clone(), Vec::new());
    assert_eq!(a.handle_message(1, 0, stale), Err(NotTaken::StaleTerm));
    assert!(started(&run_until(&mut a, 20)).is_empty(), "nothing moved for term 0");
    assert_eq!(a.tokens_held(), 0);
    a.handle_message(21, 9, dispatch_message(f.dispatch(1, 1, false), run, hash, Vec::new())).expect("taken");
    assert_eq!(started(&run_until(&mut a, 40)), vec![f.action("Move")]);
    assert_eq!(a.term(), (9, 1));
}

/// A coordinator that stands in no election sends term 0, before and after it restarts from its journal: every
/// message of it is taken, as before terms existed.
#[test]
fn without_an_election_every_message_is_of_term_0_and_taken() {
    let f = Fixture::new();
    let mut a = f.agent("a1");
    let (run, hash) = (a.run(), a.hash().clone());
    a.handle_message(0, 0, dispatch_message(f.dispatch(1, 1, false), run, hash, Vec::new())).expect("taken");
    a.handle_message(5, 0, ToAgent::Sync { run }).expect("taken");
    a.handle_message(6, 0, ToAgent::Drop { run, token: TokenId(Uuid::from_u128(1)), epoch: 1 }).expect("taken");
    run_until(&mut a, 20);
    assert_eq!((a.tokens_held(), a.term()), (0, (0, 0)));
}
