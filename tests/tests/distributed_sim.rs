//! The distributed runtime's state machines in deterministic simulation: real coordinator and agents, a
//! simulated network that duplicates, reorders and delays, virtual time.

use baton_proto::runtime::coordinator::LossPolicy;
use baton_tests::gen::{shape_strategy, ChartBuilder};
use baton_tests::simnet::{Faults, SimCluster};
use proptest::prelude::*;

fn chart(name: &str) -> String {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("charts").join(name);
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

const THREE: &[(&str, &[&str])] = &[("r1", &[]), ("r2", &[]), ("r3", &[])];

#[test]
fn three_branches_converge_after_the_slowest() {
    let mut sim = SimCluster::new(&chart("three_branches.st"), THREE, Faults::default(), 1);
    assert!(sim.run(5_000), "did not finish; trace: {:#?}", sim.trace);
    let dispatched: Vec<_> = sim.events("dispatch").into_iter().map(|(_, n, a)| (n, a.unwrap())).collect();
    assert_eq!(dispatched.len(), 3, "{dispatched:?}");
    let returns = sim.events("return");
    let last_return = returns.iter().map(|r| r.0).max().unwrap();
    let done = sim.events("activate").into_iter().find(|e| e.1 == "Done").expect("Done activated");
    assert!(done.0 >= last_return, "Done at {} before the last return at {last_return}", done.0);
    assert_eq!(returns.iter().max_by_key(|r| r.0).unwrap().2.as_deref(), Some("r2"), "r2 is the slowest");
    assert!(done.0 >= 300, "B's motion takes 300 ms; Done at {}", done.0);
}

fn cell() -> String {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples/cell.st");
    std::fs::read_to_string(path).expect("examples/cell.st")
}

const CELL_AGENTS: &[(&str, &[&str])] = &[("robot1", &["assembler"]), ("robot2", &["assembler"])];

/// Invariants every run of the cell must keep, whatever the network did.
fn check_cell_run(sim: &SimCluster) {
    let seed = sim.seed;
    assert_eq!(sim.value("done"), Some(baton_proto::types::Value::Int(3)), "seed {seed}: three parts done");
    let dispatches = sim.events("dispatch");
    let returns = sim.events("return");
    assert_eq!(dispatches.len(), returns.len(), "seed {seed}: every token came back");
    // 3 parts × (2 picks + 1 assembly segment).
    assert_eq!(dispatches.len(), 9, "seed {seed}: {dispatches:?}");
    let program = sim.coordinator.core().program();
    if let Err(why) = baton_tests::invariants::check(&sim.trace, program, true) {
        panic!("seed {seed}: {why}");
    }
    // Every convergence clears only after both pick tokens of that part returned.
    let mut picks_back = 0;
    for r in &sim.trace {
        match (r.event.as_str(), r.name.as_str()) {
            ("return", "Pick1" | "Pick2") => picks_back += 1,
            ("fire", "(Picked1,Picked2)->Assemble") => {
                assert_eq!(picks_back, 2, "seed {seed}: convergence at {} ms with {picks_back} pick(s) back", r.t_ms);
                picks_back = 0;
            }
            _ => {}
        }
    }
    // Activations and deactivations of each step alternate: no step ever got a second token.
    let mut active = std::collections::HashSet::new();
    for r in &sim.trace {
        match r.event.as_str() {
            "activate" => assert!(active.insert(r.name.clone()), "seed {seed}: `{}` activated twice", r.name),
            "deactivate" => assert!(active.remove(&r.name), "seed {seed}: `{}` deactivated while inactive", r.name),
            _ => {}
        }
    }
    assert_eq!(active.into_iter().collect::<Vec<_>>(), ["Finished"], "seed {seed}");
}

#[test]
fn the_cell_runs_to_the_end() {
    let mut sim = SimCluster::new(&cell(), CELL_AGENTS, Faults::default(), 7);
    assert!(sim.run(60_000), "did not finish");
    check_cell_run(&sim);
}

#[test]
fn duplicated_reordered_and_delayed_messages_change_nothing() {
    for seed in 0..40 {
        let faults = Faults { duplicate: 0.3, reorder: true, delay_ms_max: 8 };
        let mut sim = SimCluster::new(&cell(), CELL_AGENTS, faults, seed);
        assert!(sim.run(120_000), "seed {seed}: did not finish");
        check_cell_run(&sim);
    }
}

#[test]
fn a_role_served_by_two_agents_shares_the_work() {
    let mut sim = SimCluster::new(&cell(), CELL_AGENTS, Faults::default(), 3);
    assert!(sim.run(60_000));
    let assemblers: std::collections::BTreeSet<String> =
        sim.events("dispatch").into_iter().filter(|d| d.1 == "Assemble").filter_map(|d| d.2).collect();
    assert_eq!(assemblers.into_iter().collect::<Vec<_>>(), ["robot1", "robot2"]);
}

/// Places step `S{i}` of a generated chart on the coordinator, agent a1, agent a2 or role r.
fn place(src: &str, placements: &[u8]) -> String {
    let mut out = String::with_capacity(src.len() * 2);
    for line in src.lines() {
        let placed = line.strip_suffix(": END_STEP").and_then(|head| {
            let i: usize = head.rsplit('S').next()?.parse().ok()?;
            let pragma = match placements.get(i).copied().unwrap_or(0) % 4 {
                1 => "{agent := 'a1'}",
                2 => "{agent := 'a2'}",
                3 => "{role := 'r'}",
                _ => return None,
            };
            Some(format!("{head}: {pragma} END_STEP"))
        });
        out.push_str(placed.as_deref().unwrap_or(line));
        out.push('\n');
    }
    out
}

proptest! {
    // 64 cases in the test suite; PROPTEST_CASES=N soaks.
    #![proptest_config(ProptestConfig {
        cases: std::env::var("PROPTEST_CASES").ok().and_then(|v| v.parse().ok()).unwrap_or(64),
        ..ProptestConfig::default()
    })]

    /// Random structured charts, their steps placed at random on the coordinator and two agents, driven by
    /// random inputs over a network that duplicates, reorders and delays: no step ever holds two tokens, no
    /// token is dispatched twice, and every token dispatched is either back or still out at the end.
    #[test]
    fn random_placements_keep_every_token_accounted_for(
        shapes in prop::collection::vec(shape_strategy(3), 1..5),
        cyclic in any::<bool>(),
        placements in prop::collection::vec(any::<u8>(), 64),
        toggles in prop::collection::vec(any::<bool>(), 1..120),
        seed in any::<u64>(),
        duplicate in 0.0f64..0.4,
    ) {
        let faults = Faults { duplicate, reorder: true, delay_ms_max: 6 };
        let Some((mut sim, src)) = random_sim(&shapes, cyclic, &placements, &toggles, seed, faults) else {
            return Err(TestCaseError::reject("the chart has errors"));
        };
        sim.run(1_200);
        check_random_run(&sim, &src)?;
    }

    /// The same, with the coordinator killed at a random moment and started again from its journal a random
    /// while later: the replay rebuilds the same trace (checked by the simulation), and the run goes on with
    /// the same invariants — no segment runs twice in an epoch, no convergence clears early, no token is lost.
    #[test]
    fn a_coordinator_restarted_from_its_journal_loses_nothing(
        shapes in prop::collection::vec(shape_strategy(3), 1..5),
        cyclic in any::<bool>(),
        placements in prop::collection::vec(any::<u8>(), 64),
        toggles in prop::collection::vec(any::<bool>(), 1..120),
        seed in any::<u64>(),
        crashes in prop::collection::vec((1u64..900, 1u64..400), 1..3),
    ) {
        let faults = Faults { duplicate: 0.1, reorder: true, delay_ms_max: 6 };
        let Some((mut sim, src)) = random_sim(&shapes, cyclic, &placements, &toggles, seed, faults) else {
            return Err(TestCaseError::reject("the chart has errors"));
        };
        for (at, down) in crashes {
            sim.crash_coordinator_at(at, down);
        }
        sim.run(2_000);
        check_random_run(&sim, &src)?;
    }
}

/// A generated chart placed at random on the coordinator, agents a1 and a2 and role r (both agents), with its
/// inputs `c0`…`c3` toggled every 7 ms; `None` if the chart has errors.
fn random_sim(
    shapes: &[baton_tests::gen::Shape],
    cyclic: bool,
    placements: &[u8],
    toggles: &[bool],
    seed: u64,
    faults: Faults,
) -> Option<(SimCluster, String)> {
    let src = place(&ChartBuilder::chart(shapes, 4, cyclic), placements);
    if baton_proto::check::check_source(&src).error_count() != 0 {
        return None;
    }
    let mut sim = SimCluster::new(&src, &[("a1", &["r"]), ("a2", &["r"])], faults, seed);
    for (k, on) in toggles.iter().enumerate() {
        sim.set_at(1 + 7 * k as u64, &format!("c{}", k % 4), serde_json::Value::Bool(*on));
    }
    Some((sim, src))
}

fn check_random_run(sim: &SimCluster, src: &str) -> Result<(), TestCaseError> {
    let seed = sim.seed;
    let program = sim.coordinator.core().program();
    if let Err(why) = baton_tests::invariants::check(&sim.trace, program, false) {
        return Err(TestCaseError::fail(format!("seed {seed}: {why}\n{src}")));
    }
    let out = baton_tests::invariants::tokens_out(&sim.trace);
    prop_assert_eq!(
        out,
        sim.coordinator.core().tokens_in_flight(),
        "seed {}: a token is unaccounted for\n{}",
        seed,
        src
    );
    Ok(())
}

/// One part of the cell, with robot1 lost at 600 ms, while it assembles (Assemble leaves for it at about
/// 500 ms and takes 300 ms).
fn cell_losing_robot1(fates: &[(u64, baton_tests::simnet::Fate)], policy: LossPolicy) -> SimCluster {
    let mut sim = SimCluster::new(&cell(), CELL_AGENTS, Faults::default(), 11);
    sim.set_loss_policy(policy);
    sim.set_at(0, "parts", serde_json::json!(1));
    for &(t, fate) in fates {
        sim.fate_at(t, "robot1", fate);
    }
    sim
}

fn assembled_by(sim: &SimCluster) -> Vec<(String, Option<u32>)> {
    baton_tests::cluster::dispatches(&sim.trace, "Assemble")
}

#[test]
fn reassign_restarts_a_lost_agents_segment_elsewhere_in_a_new_epoch() {
    use baton_tests::simnet::Fate;
    let mut sim = cell_losing_robot1(&[(600, Fate::Kill)], LossPolicy::Reassign);
    assert!(sim.run(10_000), "did not finish");
    assert_eq!(sim.value("done"), Some(baton_proto::types::Value::Int(1)));
    assert_eq!(assembled_by(&sim), [("robot1".to_string(), Some(1)), ("robot2".to_string(), Some(2))]);
    assert_eq!(sim.events("agent_lost").len(), 1);
    assert!(sim.trace.iter().any(|r| r.event == "alarm" && r.message.as_deref().unwrap_or("").contains("reassigned")));
    assert!(sim.coordinator.core().failure().is_none());
}

#[test]
fn pause_resumes_a_cut_off_agent_where_it_was() {
    use baton_tests::simnet::Fate;
    let mut sim = cell_losing_robot1(&[(600, Fate::Cut), (2_000, Fate::Heal)], LossPolicy::Pause);
    assert!(sim.run(10_000), "did not finish");
    assert_eq!(sim.value("done"), Some(baton_proto::types::Value::Int(1)));
    // The same process kept its token: it says so when it comes back, keeps it in the same epoch, its held-back
    // reports follow, and the motion is not run twice.
    assert_eq!(assembled_by(&sim), [("robot1".to_string(), Some(1))]);
    let resume = sim.trace.iter().find(|r| r.event == "resume" && r.name == "Assemble").expect("resumed");
    assert_eq!((resume.agent.as_deref(), resume.epoch), (Some("robot1"), Some(1)));
    assert!(resume.t_ms >= 2_000, "resumed at {} ms, before robot1 came back", resume.t_ms);
    let motions = sim.trace.iter().filter(|r| r.event == "action_on" && r.name == "AssemblePart").count();
    assert!(motions <= 1, "the assembly motion ran {motions} times");
}

#[test]
fn pause_restarts_the_segment_on_an_agent_that_came_back_restarted() {
    use baton_tests::simnet::Fate;
    let mut sim = cell_losing_robot1(&[(600, Fate::Kill), (2_000, Fate::Restart)], LossPolicy::Pause);
    assert!(sim.run(10_000), "did not finish");
    assert_eq!(sim.value("done"), Some(baton_proto::types::Value::Int(1)));
    assert_eq!(assembled_by(&sim), [("robot1".to_string(), Some(1)), ("robot1".to_string(), Some(2))]);
    let again = sim.trace.iter().filter(|r| r.event == "dispatch" && r.name == "Assemble").nth(1).expect("again");
    assert!(again.t_ms >= 2_000, "sent again at {} ms, before robot1 came back", again.t_ms);
    assert!(sim.trace.iter().any(|r| r.event == "alarm" && r.message.as_deref().unwrap_or("").contains("restarted")));
}

#[test]
fn fail_ends_the_run_and_says_why() {
    use baton_tests::simnet::Fate;
    let mut sim = cell_losing_robot1(&[(600, Fate::Kill)], LossPolicy::Fail);
    assert!(!sim.run(3_000));
    let why = sim.coordinator.core().failure().expect("failed");
    assert!(why.contains("robot1") && why.contains("Assemble"), "{why}");
}

#[test]
fn a_cut_off_agents_late_result_is_rejected_after_a_reassign() {
    use baton_tests::simnet::Fate;
    let mut sim = cell_losing_robot1(&[(600, Fate::Cut), (1_500, Fate::Heal)], LossPolicy::Reassign);
    assert!(sim.run(10_000), "did not finish");
    assert_eq!(sim.value("done"), Some(baton_proto::types::Value::Int(1)));
    assert_eq!(assembled_by(&sim), [("robot1".to_string(), Some(1)), ("robot2".to_string(), Some(2))]);
    let stale: Vec<_> = sim.trace.iter().filter(|r| r.event == "reject_stale").collect();
    assert!(!stale.is_empty(), "robot1's epoch-1 reports came back and were rejected");
    assert!(stale.iter().all(|r| r.agent.as_deref() == Some("robot1") && r.epoch == Some(1)));
    // Only epoch 2's return counts.
    let returns: Vec<_> = sim.trace.iter().filter(|r| r.event == "return" && r.name == "Assemble").collect();
    assert_eq!(returns.len(), 1);
    assert_eq!(returns[0].epoch, Some(2));
}

/// The cell (three parts) with the coordinator killed at `at` ms and started again from its journal `down` ms
/// later, over a network that duplicates and reorders.
fn cell_with_coordinator_crash(seed: u64, at: u64, down: u64) -> SimCluster {
    let faults = Faults { duplicate: 0.2, reorder: true, delay_ms_max: 5 };
    let mut sim = SimCluster::new(&cell(), CELL_AGENTS, faults, seed);
    sim.crash_coordinator_at(at, down);
    sim
}

#[test]
fn the_cell_survives_a_coordinator_crash_at_any_moment() {
    // From before the first dispatch to the end of the run, in steps that land in every phase: each crash at a
    // different fraction of the time the same seed takes without one.
    for k in 0..27u64 {
        let mut calm =
            SimCluster::new(&cell(), CELL_AGENTS, Faults { duplicate: 0.2, reorder: true, delay_ms_max: 5 }, k);
        assert!(calm.run(120_000), "seed {k}: did not finish without a crash");
        let at = calm.now_ms * k / 27;
        let mut sim = cell_with_coordinator_crash(k, at, 50 + 37 * k % 700);
        assert!(sim.run(120_000), "crash at {at} ms: did not finish");
        check_cell_run(&sim);
        assert_eq!(sim.events("recover").len(), 1, "crash at {at} ms");
    }
}

#[test]
fn a_segment_that_finishes_while_the_coordinator_is_down_is_not_run_again() {
    // Assemble leaves at about 500 ms and takes 300 ms: the coordinator is down from 600 to 1 600 ms, so the
    // agent finishes while nobody listens and keeps its result until the new coordinator acknowledges it.
    let mut sim = SimCluster::new(&cell(), CELL_AGENTS, Faults::default(), 5);
    sim.set_at(0, "parts", serde_json::json!(1));
    sim.crash_coordinator_at(600, 1_000);
    assert!(sim.run(10_000), "did not finish");
    assert_eq!(sim.value("done"), Some(baton_proto::types::Value::Int(1)));
    let assemble = assembled_by(&sim);
    assert_eq!(assemble.len(), 1, "Assemble was dispatched once: {assemble:?}");
    let resume = sim.trace.iter().find(|r| r.event == "resume" && r.name == "Assemble").expect("reconciled");
    assert_eq!(resume.message.as_deref(), Some("still held by the agent"));
    assert!(resume.t_ms >= 1_600);
    let back = sim.trace.iter().find(|r| r.event == "return" && r.name == "Assemble").expect("returned");
    assert!(back.t_ms >= 1_600 && back.t_ms < 1_700, "the held result came back at once: {} ms", back.t_ms);
    let motions = sim.trace.iter().filter(|r| r.event == "action_on" && r.name == "AssemblePart").count();
    assert_eq!(motions, 1, "the assembly motion ran once");
}

#[test]
fn an_agent_restarted_while_the_coordinator_was_down_runs_its_segment_again_in_a_new_epoch() {
    use baton_tests::simnet::Fate;
    let mut sim = SimCluster::new(&cell(), CELL_AGENTS, Faults::default(), 5);
    sim.set_at(0, "parts", serde_json::json!(1));
    sim.crash_coordinator_at(600, 1_000);
    let holder = "robot1";
    sim.fate_at(650, holder, Fate::Kill);
    sim.fate_at(700, holder, Fate::Restart);
    assert!(sim.run(10_000), "did not finish");
    assert_eq!(sim.value("done"), Some(baton_proto::types::Value::Int(1)));
    let assemble = assembled_by(&sim);
    assert_eq!(assemble.len(), 2, "{assemble:?}");
    assert_eq!(assemble[1].1, Some(assemble[0].1.unwrap() + 1), "a new epoch: {assemble:?}");
    assert!(sim.trace.iter().any(|r| r.event == "alarm" && r.message.as_deref().unwrap_or("").contains("restarted")));
}

#[test]
fn an_agent_that_does_not_come_back_after_a_coordinator_restart_is_lost_after_its_lease() {
    use baton_tests::simnet::Fate;
    // robot1 holds Assemble and dies while the coordinator is down; the new coordinator waits for it for its
    // lease (1 s in the simulation), then reassigns its segment to robot2 in a new epoch.
    let mut sim = SimCluster::new(&cell(), CELL_AGENTS, Faults::default(), 5);
    sim.set_loss_policy(LossPolicy::Reassign);
    sim.set_at(0, "parts", serde_json::json!(1));
    sim.crash_coordinator_at(600, 500);
    sim.fate_at(650, "robot1", Fate::Kill);
    assert!(sim.run(10_000), "did not finish");
    assert_eq!(sim.value("done"), Some(baton_proto::types::Value::Int(1)));
    assert_eq!(assembled_by(&sim), [("robot1".to_string(), Some(1)), ("robot2".to_string(), Some(2))]);
    let lost = sim.trace.iter().find(|r| r.event == "agent_lost" && r.name == "robot1").expect("lost");
    assert!((2_100..2_300).contains(&lost.t_ms), "lost one lease after the restart at 1 100 ms: {} ms", lost.t_ms);
}

/// A step on r1 whose action changes a variable every cycle, for 20 s.
const COUNTING: &str = "PROGRAM counting
VAR n : DINT := 0; END_VAR
INITIAL_STEP Start: END_STEP
TRANSITION FROM Start TO Count := TRUE; END_TRANSITION
STEP Count: {agent := 'r1'} Inc(N); END_STEP
TRANSITION FROM Count TO Done := Count.T >= T#20s; END_TRANSITION
STEP Done: END_STEP
ACTION Inc: n := n + 1; END_ACTION
END_PROGRAM
";

#[test]
fn a_long_outage_of_the_coordinator_loses_no_report() {
    // 15 s without a coordinator at a report per cycle is past the agent's cap of unacknowledged reports: what
    // came after it must still reach the coordinator resumed from its journal, and the token come back.
    let mut sim = SimCluster::new(COUNTING, &[("r1", &[])], Faults::default(), 3);
    sim.crash_coordinator_at(2_000, 15_000);
    assert!(sim.run(60_000), "seed 3: the token never came back");
    let expected = baton_tests::reference::final_values(COUNTING, baton_tests::simnet::CYCLE_MS, &["n"]);
    assert_eq!(sim.value("n").map(|v| v.as_i64()), Some(expected[0]), "n as one engine counts it");
    assert_eq!(sim.events("return").len(), 1);
}

/// r1 counts in one step, then (restarted meanwhile, so from its initial value) in a later one; the coordinator
/// waits for the count to change.
const RECOUNTING: &str = "PROGRAM recounting
VAR n : DINT := 0; before : DINT := 0; END_VAR
INITIAL_STEP Start: END_STEP
TRANSITION FROM Start TO First := TRUE; END_TRANSITION
STEP First: {agent := 'r1'} IncN(N); END_STEP
TRANSITION FROM First TO Between := First.T >= T#1s; END_TRANSITION
STEP Between: Remember(P); END_STEP
TRANSITION FROM Between TO Second := Between.T >= T#1s; END_TRANSITION
STEP Second: {agent := 'r1'} IncN(N); END_STEP
TRANSITION FROM Second TO Check := Second.T >= T#300ms; END_TRANSITION
STEP Check: END_STEP
TRANSITION FROM Check TO Done := n <> before; END_TRANSITION
STEP Done: END_STEP
ACTION IncN: n := n + 1; END_ACTION
ACTION Remember: before := n; END_ACTION
END_PROGRAM
";

#[test]
fn a_restarted_agents_values_are_heard() {
    // The new process numbers its variable updates from 1 again: the coordinator must not take them for old
    // ones of the process it replaced, or the count it waits for never changes.
    let mut sim = SimCluster::new(RECOUNTING, &[("r1", &[])], Faults::default(), 4);
    sim.fate_at(1_500, "r1", baton_tests::simnet::Fate::Restart);
    let done = sim.run(30_000);
    let (n, before) = (sim.value("n").map(|v| v.as_i64()), sim.value("before").map(|v| v.as_i64()));
    assert!(done, "seed 4: the coordinator never heard r1's new process (n = {n:?}, before = {before:?})");
    // About 100 cycles in First; the new process counted from 0 for about 30.
    let (n, before) = (n.unwrap_or(-1), before.unwrap_or(-1));
    assert!(before > 50 && n > 0 && n < before, "n = {n}, before = {before}");
}
