//! The distributed runtime's state machines in deterministic simulation: real coordinator and agents, a
//! simulated network that duplicates, reorders and delays, virtual time.

use baton_proto::cluster::runtime::coordinator::LossPolicy;
use baton_proto::exec::trace::TraceEvent;
use baton_proto::testing::simulated_cluster::{Faults, SimCluster};

fn chart(name: &str) -> String {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("charts").join(name);
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

const THREE: &[(&str, &[&str])] = &[("r1", &[]), ("r2", &[]), ("r3", &[])];

#[test]
fn three_branches_converge_after_the_slowest() {
    let mut sim = SimCluster::new(&chart("three_branches.st"), THREE, Faults::default(), 1);
    assert!(sim.run(5_000), "did not finish; trace: {:#?}", sim.trace);
    let dispatched: Vec<_> = sim.events(TraceEvent::Dispatch).into_iter().map(|(_, n, a)| (n, a.unwrap())).collect();
    assert_eq!(dispatched.len(), 3, "{dispatched:?}");
    let returns = sim.events(TraceEvent::Return);
    let last_return = returns.iter().map(|r| r.0).max().unwrap();
    let done = sim.events(TraceEvent::Activate).into_iter().find(|e| e.1 == "Done").expect("Done activated");
    assert!(done.0 >= last_return, "Done at {} before the last return at {last_return}", done.0);
    assert_eq!(returns.iter().max_by_key(|r| r.0).unwrap().2.as_deref(), Some("r2"), "r2 is the slowest");
    assert!(done.0 >= 300, "B's motion takes 300 ms; Done at {}", done.0);
}

/// A step's minimum time (`{min_ms := …}`) holds on the agent that runs the step, as in `baton sim`: its exit
/// is TRUE at once, and still the token comes back no sooner.
#[test]
fn a_placed_steps_minimum_time_holds_on_its_agent() {
    let chart = "PROGRAM p\nINITIAL_STEP A: END_STEP\nTRANSITION FROM A TO W := TRUE; END_TRANSITION\n\
                 STEP W: {agent := 'r1', min_ms := T#300ms} END_STEP\nTRANSITION FROM W TO B := TRUE; END_TRANSITION\n\
                 STEP B: END_STEP\nEND_PROGRAM\n";
    let mut sim = SimCluster::new(chart, &[("r1", &[])], Faults::default(), 1);
    assert!(sim.run(5_000), "did not finish; trace: {:#?}", sim.trace);
    let at = |event: TraceEvent, name: &str| sim.events(event).into_iter().find(|e| e.1 == name).map(|e| e.0);
    let (dispatched, back) = (at(TraceEvent::Dispatch, "W").expect("W dispatched"), at(TraceEvent::Activate, "B"));
    let back = back.expect("B reached");
    assert!(back >= dispatched + 300, "W held its token {} ms, under its 300 ms minimum", back - dispatched);
    assert!(back < dispatched + 400, "and not much longer: {} ms", back - dispatched);
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
    let dispatches = sim.events(TraceEvent::Dispatch);
    let returns = sim.events(TraceEvent::Return);
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
        match (r.event, r.name.as_str()) {
            (TraceEvent::Return, "Pick1" | "Pick2") => picks_back += 1,
            (TraceEvent::Fire, "(Picked1,Picked2)->Assemble") => {
                assert_eq!(picks_back, 2, "seed {seed}: convergence at {} ms with {picks_back} pick(s) back", r.t_ms);
                picks_back = 0;
            }
            _ => {}
        }
    }
    // Every assembly waited for its motion: an indicator left TRUE by an earlier part never clears the step.
    let mut moving = false;
    for r in &sim.trace {
        match (r.event, r.name.as_str()) {
            (TraceEvent::ActionOn, "AssemblePart") => moving = true,
            (TraceEvent::SkillDone, "AssemblePart") => moving = false,
            (TraceEvent::Fire, "Assemble->Inspect") => {
                assert!(!moving, "seed {seed}: Assemble left at {} ms before its motion was done", r.t_ms)
            }
            _ => {}
        }
    }
    // Activations and deactivations of each step alternate: no step ever got a second token.
    let mut active = std::collections::HashSet::new();
    for r in &sim.trace {
        match r.event {
            TraceEvent::Activate => assert!(active.insert(r.name.clone()), "seed {seed}: `{}` activated twice", r.name),
            TraceEvent::Deactivate => {
                assert!(active.remove(&r.name), "seed {seed}: `{}` deactivated while inactive", r.name)
            }
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
fn lost_duplicated_reordered_and_delayed_messages_change_nothing() {
    for seed in 0..40 {
        let faults = Faults { duplicate: 0.3, reorder: true, delay_ms_max: 8, loss: 0.05 };
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
        sim.events(TraceEvent::Dispatch).into_iter().filter(|d| d.1 == "Assemble").filter_map(|d| d.2).collect();
    assert_eq!(assemblers.into_iter().collect::<Vec<_>>(), ["robot1", "robot2"]);
}

/// The seeds of the random runs: `BATON_SIM_SEED=N` replays one, `BATON_SIM_SEEDS=N` runs seeds 0 to N − 1
/// (64 by default; the soak in CONTRIBUTING.md runs thousands).
fn seeds() -> Vec<u64> {
    let var = |name: &str| std::env::var(name).ok().and_then(|v| v.parse::<u64>().ok());
    match var("BATON_SIM_SEED") {
        Some(seed) => vec![seed],
        None => (0..var("BATON_SIM_SEEDS").unwrap_or(64)).collect(),
    }
}

/// A random cell from one seed: a structured chart whose steps are placed at random on the coordinator, agents
/// a1 and a2 and role r (both), with skills and counters on placed steps; inputs `c0`…`c3` toggled every 7 ms;
/// a network that loses, duplicates, reorders and delays; agents killed, restarted, cut and healed; the
/// coordinator crashed before or after its journal, under a random loss policy. After 1 s the chaos stops
/// (every cut is healed, the network is perfect) and the run has 12 s to settle.
struct RandomCell {
    source: String,
    sim: SimCluster,
    with_actions: bool,
}

const CHAOS_MS: u64 = 1_000;
const SETTLE_MS: u64 = 12_000;

impl RandomCell {
    fn new(seed: u64) -> Option<RandomCell> {
        use baton_proto::testing::simulated_cluster::Fate;
        use baton_tests::gen::{random_shapes, ChartBuilder, Rng};
        let mut rng = Rng::new(seed);
        let shapes = random_shapes(&mut rng, 3);
        let plain = ChartBuilder::chart(&shapes, 4, rng.chance(0.5));
        let (placements, actions): (Vec<u64>, Vec<u64>) = (0..256).map(|_| (rng.below(4), rng.below(4))).unzip();
        let ms: Vec<u64> = (0..256).map(|_| rng.below(60)).collect();
        let decorated = decorate(&plain, &placements, Some((&actions, &ms)));
        let ok = |src: &str| baton_proto::pipeline::check_source(src).error_count() == 0;
        let (source, with_actions) = if ok(&decorated) {
            (decorated, true)
        } else {
            let placed = decorate(&plain, &placements, None);
            if !ok(&placed) {
                return None;
            }
            (placed, false)
        };
        let faults = Faults {
            duplicate: rng.fraction(0.3),
            reorder: rng.chance(0.7),
            delay_ms_max: rng.below(7),
            loss: rng.fraction(0.08),
        };
        let mut sim = SimCluster::new(&source, &[("a1", &["r"]), ("a2", &["r"])], faults, seed);
        sim.set_loss_policy(match rng.below(6) {
            0 => LossPolicy::Fail,
            1 | 2 => LossPolicy::Reassign,
            _ => LossPolicy::Pause,
        });
        for k in 0..1 + rng.below(120) {
            sim.set_at(1 + 7 * k, &format!("c{}", k % 4), serde_json::Value::Bool(rng.chance(0.5)));
        }
        for _ in 0..rng.below(4) {
            let fate = [Fate::Kill, Fate::Restart, Fate::Cut, Fate::Heal][rng.below(4) as usize];
            sim.fate_at(rng.below(CHAOS_MS), ["a1", "a2"][rng.below(2) as usize], fate);
        }
        for agent in ["a1", "a2"] {
            sim.fate_at(CHAOS_MS, agent, Fate::Heal);
        }
        sim.calm_from(CHAOS_MS);
        for _ in 0..rng.below(3) {
            let (at, down) = (rng.below(CHAOS_MS - 400), 1 + rng.below(400));
            if rng.chance(0.5) {
                sim.crash_coordinator_at(at, down);
            } else {
                sim.crash_coordinator_after_journal_at(at, down);
            }
        }
        Some(RandomCell { source, sim, with_actions })
    }

    /// Runs it; what went wrong, if anything.
    fn run(&mut self) -> Result<(), String> {
        let finished = self.sim.run(CHAOS_MS + SETTLE_MS);
        let sim = &self.sim;
        if let Some(why) = sim.violations.first() {
            return Err(why.clone());
        }
        let program = sim.coordinator.core().program();
        baton_tests::invariants::check(&sim.trace, program, finished)?;
        // Tokens that left at least once (a token that never found an agent has not).
        let out = baton_tests::invariants::tokens_out(&sim.trace);
        let dispatched: std::collections::HashSet<&str> =
            sim.trace.iter().filter(|r| r.event == TraceEvent::Dispatch).filter_map(|r| r.token.as_deref()).collect();
        let status = sim.coordinator.core().status();
        let left = status.tokens.iter().filter(|t| dispatched.contains(t.token.to_string().as_str())).count();
        if out != left {
            return Err(format!("{out} token(s) out in the trace, {left} at the coordinator"));
        }
        if sim.coordinator.core().failure().is_none() {
            sim.settled()?;
        }
        Ok(())
    }
}

/// Places step `S{i}` of a generated chart on the coordinator, agent a1, agent a2 or role r, and, with
/// `actions`, gives placed steps a motion (its indicator gates the step's exits) or a counter of cycles.
fn decorate(src: &str, placements: &[u64], actions: Option<(&[u64], &[u64])>) -> String {
    let (mut vars, mut decls) = (String::new(), String::new());
    let mut moves = std::collections::HashSet::new();
    // The last step of a simultaneous branch waits at the convergence and holds no action.
    let waiting: std::collections::HashSet<usize> = src
        .lines()
        .filter_map(|l| l.strip_prefix("TRANSITION FROM (")?.split(')').next())
        .flat_map(|list| list.split(", ").filter_map(|s| s.trim_start_matches('S').parse().ok()).collect::<Vec<_>>())
        .collect();
    let mut out = String::with_capacity(src.len() * 2);
    for line in src.lines() {
        if let Some(head) = line.strip_suffix(": END_STEP") {
            let i: usize = head.rsplit('S').next().and_then(|n| n.parse().ok()).unwrap_or(0);
            let pragma = match placements.get(i).copied().unwrap_or(0) {
                1 => "{agent := 'a1'} ",
                2 => "{agent := 'a2'} ",
                3 => "{role := 'r'} ",
                _ => "",
            };
            let mut assocs = String::new();
            if let (Some((kinds, ms)), false) = (actions, pragma.is_empty() || waiting.contains(&i)) {
                let kind = kinds.get(i).copied().unwrap_or(0);
                if kind & 1 == 1 {
                    let ms = ms.get(i).copied().unwrap_or(0);
                    assocs.push_str(&format!("Move{i}(N, d{i}); "));
                    vars.push_str(&format!("  d{i} : BOOL;\n"));
                    decls.push_str(&format!("ACTION Move{i}: {{skill := 'motion', ms := {ms}}} END_ACTION\n"));
                    moves.insert(i);
                }
                if kind & 2 == 2 {
                    assocs.push_str(&format!("Inc{i}(N); "));
                    vars.push_str(&format!("  n{i} : DINT;\n"));
                    decls.push_str(&format!("ACTION Inc{i}: n{i} := n{i} + 1; END_ACTION\n"));
                }
            }
            out.push_str(&format!("{head}: {pragma}{assocs}END_STEP\n"));
            continue;
        }
        // A step with a motion is left only once the motion is done.
        let gated = line.strip_prefix("TRANSITION FROM S").and_then(|rest| {
            let i: usize = rest.split(' ').next()?.parse().ok()?;
            moves.contains(&i).then(|| line.replacen("; END_TRANSITION", &format!(" AND d{i}; END_TRANSITION"), 1))
        });
        out.push_str(gated.as_deref().unwrap_or(line));
        out.push('\n');
    }
    out.replacen("END_VAR\n", &format!("{vars}END_VAR\n"), 1).replacen("END_PROGRAM", &format!("{decls}END_PROGRAM"), 1)
}

/// Random cells, one per seed: no step ever holds two tokens (on any engine), no segment starts twice in one
/// epoch on any agent, no convergence clears early, every token is accounted for, and once the chaos stops every
/// token comes back or is explicitly held — nothing is stuck between the coordinator and an agent. A failure
/// says the seed and the command that replays exactly it.
#[test]
fn random_cells_keep_their_promises() {
    let seeds = seeds();
    let (mut accepted, mut with_actions) = (0usize, 0usize);
    for &seed in &seeds {
        let Some(mut cell) = RandomCell::new(seed) else { continue };
        accepted += 1;
        with_actions += usize::from(cell.with_actions);
        if let Err(why) = cell.run() {
            panic!(
                "seed {seed}: {why}\n{}\nreplay exactly this run: BATON_SIM_SEED={seed} cargo test -p baton-tests --test distributed_sim random_cells_keep_their_promises",
                cell.source
            );
        }
    }
    eprintln!("random cells: {} seeds, {accepted} accepted, {with_actions} with skills and counters", seeds.len());
    // The promises are checked only on charts the validator accepts: too few of those would prove nothing.
    if seeds.len() > 1 {
        assert!(accepted * 10 >= seeds.len() * 9, "only {accepted} of {} random charts were accepted", seeds.len());
        assert!(with_actions * 2 >= accepted, "only {with_actions} of {accepted} charts kept their actions");
    }
}

/// Standby coordinators, on the random cells: each cell's coordinator stands in an election (a lease of 200–500
/// ms), is paused once or twice past its lease — at a moment when it has durable records whose messages it has not
/// sent, the GC pause that fools every lease — and its crashes become takeovers too. The paused coordinator wakes
/// and sends what it held at its old term. It is also cut from the store (etcd) up to twice, for up to its lease:
/// a cut that heals before its deadline lets its writes through; one it outlasts stops it, what waited never
/// durable nor sent, and a standby takes over from the store. Over the seeds (64, or `BATON_SIM_SEEDS`: the book runs 1,000): every
/// promise of `random_cells_keep_their_promises` holds, with the journal the standby resumed from — nothing
/// acknowledged is lost — and no agent process ever takes a message of a lower term after one of a higher
/// (`violations`); the deposed coordinators' late messages were sent and agents refused some of them.
#[test]
fn standby_coordinators_never_both_command_an_agent() {
    use baton_tests::gen::Rng;
    let seeds = seeds();
    let mut total = baton_proto::testing::simulated_cluster::ElectionStats::default();
    let mut accepted = 0usize;
    for &seed in &seeds {
        let Some(mut cell) = RandomCell::new(seed) else { continue };
        accepted += 1;
        // Drawn apart from the cell's own faults, so that the cell is the one the plain test runs.
        let mut rng = Rng::new(seed ^ 0x5ba7_0e1e_c7ed);
        let lease = 200 + rng.below(300);
        cell.sim.stand_by(lease);
        for _ in 0..1 + rng.below(2) {
            cell.sim.pause_coordinator_at(rng.below(CHAOS_MS - 400), lease + 1 + rng.below(400));
        }
        // Cut from the store (etcd) for up to the lease: some heal before the coordinator's deadline, some not.
        for _ in 0..rng.below(3) {
            cell.sim.cut_coordinator_from_store_at(rng.below(CHAOS_MS - 400), 1 + rng.below(lease));
        }
        if let Err(why) = cell.run() {
            panic!(
                "seed {seed}: {why}\n{}\nreplay exactly this run: BATON_SIM_SEED={seed} cargo test -p baton-tests --test distributed_sim standby_coordinators_never_both_command_an_agent",
                cell.source
            );
        }
        let e = cell.sim.election().expect("an election");
        total.takeovers += e.takeovers;
        total.late_messages += e.late_messages;
        total.refused += e.refused;
        total.cuts_healed += e.cuts_healed;
        total.cuts_outlasted += e.cuts_outlasted;
    }
    eprintln!("standby coordinators: {} seeds, {accepted} accepted, {total:?}", seeds.len());
    if seeds.len() > 1 {
        assert!(total.takeovers >= accepted as u64 / 2, "too few takeovers to prove anything: {total:?}");
        assert!(
            total.late_messages > 0 && total.refused > 0,
            "no deposed coordinator was heard and refused: {total:?}"
        );
        assert!(total.cuts_healed > 0 && total.cuts_outlasted > 0, "cuts from the store of both kinds: {total:?}");
    }
}

/// One part of the cell, with robot1 lost at 600 ms, while it assembles (Assemble leaves for it at about
/// 500 ms and takes 300 ms).
fn cell_losing_robot1(
    fates: &[(u64, baton_proto::testing::simulated_cluster::Fate)],
    policy: LossPolicy,
) -> SimCluster {
    let mut sim = SimCluster::new(&cell(), CELL_AGENTS, Faults::default(), 11);
    sim.set_loss_policy(policy);
    sim.set_at(0, "parts", serde_json::json!(1));
    for &(t, fate) in fates {
        sim.fate_at(t, "robot1", fate);
    }
    sim
}

fn assembled_by(sim: &SimCluster) -> Vec<(String, Option<u32>)> {
    baton_tests::loopback::dispatches(&sim.trace, "Assemble")
}

#[test]
fn reassign_restarts_a_lost_agents_segment_elsewhere_in_a_new_epoch() {
    use baton_proto::testing::simulated_cluster::Fate;
    let mut sim = cell_losing_robot1(&[(600, Fate::Kill)], LossPolicy::Reassign);
    assert!(sim.run(10_000), "did not finish");
    assert_eq!(sim.value("done"), Some(baton_proto::types::Value::Int(1)));
    assert_eq!(assembled_by(&sim), [("robot1".to_string(), Some(1)), ("robot2".to_string(), Some(2))]);
    assert_eq!(sim.events(TraceEvent::AgentLost).len(), 1);
    assert!(sim
        .trace
        .iter()
        .any(|r| r.event == TraceEvent::Alarm && r.message.as_deref().unwrap_or("").contains("reassigned")));
    assert!(sim.coordinator.core().failure().is_none());
}

#[test]
fn pause_resumes_a_cut_off_agent_where_it_was() {
    use baton_proto::testing::simulated_cluster::Fate;
    let mut sim = cell_losing_robot1(&[(600, Fate::Cut), (2_000, Fate::Heal)], LossPolicy::Pause);
    assert!(sim.run(10_000), "did not finish");
    assert_eq!(sim.value("done"), Some(baton_proto::types::Value::Int(1)));
    // The same process kept its token: it says so when it comes back, keeps it in the same epoch, its held-back
    // reports follow, and the motion is not run twice.
    assert_eq!(assembled_by(&sim), [("robot1".to_string(), Some(1))]);
    let resume = sim.trace.iter().find(|r| r.event == TraceEvent::Resume && r.name == "Assemble").expect("resumed");
    assert_eq!((resume.agent.as_deref(), resume.epoch), (Some("robot1"), Some(1)));
    assert!(resume.t_ms >= 2_000, "resumed at {} ms, before robot1 came back", resume.t_ms);
    let motions = sim.trace.iter().filter(|r| r.event == TraceEvent::ActionOn && r.name == "AssemblePart").count();
    assert!(motions <= 1, "the assembly motion ran {motions} times");
}

#[test]
fn pause_restarts_the_segment_on_an_agent_that_came_back_restarted() {
    use baton_proto::testing::simulated_cluster::Fate;
    let mut sim = cell_losing_robot1(&[(600, Fate::Kill), (2_000, Fate::Restart)], LossPolicy::Pause);
    assert!(sim.run(10_000), "did not finish");
    assert_eq!(sim.value("done"), Some(baton_proto::types::Value::Int(1)));
    assert_eq!(assembled_by(&sim), [("robot1".to_string(), Some(1)), ("robot1".to_string(), Some(2))]);
    let again =
        sim.trace.iter().filter(|r| r.event == TraceEvent::Dispatch && r.name == "Assemble").nth(1).expect("again");
    assert!(again.t_ms >= 2_000, "sent again at {} ms, before robot1 came back", again.t_ms);
    assert!(sim
        .trace
        .iter()
        .any(|r| r.event == TraceEvent::Alarm && r.message.as_deref().unwrap_or("").contains("restarted")));
}

#[test]
fn fail_ends_the_run_and_says_why() {
    use baton_proto::testing::simulated_cluster::Fate;
    let mut sim = cell_losing_robot1(&[(600, Fate::Kill)], LossPolicy::Fail);
    assert!(!sim.run(3_000));
    let why = sim.coordinator.core().failure().expect("failed");
    assert!(why.contains("robot1") && why.contains("Assemble"), "{why}");
}

#[test]
fn a_cut_off_agents_late_result_is_rejected_after_a_reassign() {
    use baton_proto::testing::simulated_cluster::Fate;
    // Cut at 600 ms: robot1 fences itself at 850 ms, the coordinator hears it is lost at 1 600 ms (its lease)
    // and moves the token at 2 100 ms; the cable is back at 2 500 ms.
    let mut sim = cell_losing_robot1(&[(600, Fate::Cut), (2_500, Fate::Heal)], LossPolicy::Reassign);
    assert!(sim.run(10_000), "did not finish");
    assert_eq!(sim.value("done"), Some(baton_proto::types::Value::Int(1)));
    assert_eq!(assembled_by(&sim), [("robot1".to_string(), Some(1)), ("robot2".to_string(), Some(2))]);
    // Back, robot1 says it holds epoch 1: it is told to drop it at once (any late report of it is rejected).
    let stale: Vec<_> = sim.trace.iter().filter(|r| r.event == TraceEvent::RejectStale).collect();
    assert!(stale.iter().all(|r| r.agent.as_deref() == Some("robot1") && r.epoch == Some(1)));
    assert_eq!(sim.settled(), Ok(()), "robot1 holds nothing any more");
    // Only epoch 2's return counts.
    let returns: Vec<_> = sim.trace.iter().filter(|r| r.event == TraceEvent::Return && r.name == "Assemble").collect();
    assert_eq!(returns.len(), 1);
    assert_eq!(returns[0].epoch, Some(2));
}

/// The cell (three parts) with the coordinator killed at `at` ms and started again from its journal `down` ms
/// later, over a network that duplicates and reorders.
fn cell_with_coordinator_crash(seed: u64, at: u64, down: u64) -> SimCluster {
    let faults = Faults { duplicate: 0.2, reorder: true, delay_ms_max: 5, loss: 0.0 };
    let mut sim = SimCluster::new(&cell(), CELL_AGENTS, faults, seed);
    sim.crash_coordinator_at(at, down);
    // Snapshots often, so that most crashes resume from one; every variable watched, so that a resume traces their
    // values as the live run did.
    sim.snapshot_every = 8;
    sim.watch_all();
    sim
}

#[test]
fn the_cell_survives_a_coordinator_crash_at_any_moment() {
    // From before the first dispatch to the end of the run, in steps that land in every phase: each crash at a
    // different fraction of the time the same seed takes without one. A restart resumes from the latest snapshot
    // (here one every 8 records) when there is one, and its trace is checked against the live
    // run's and the whole journal's replay.
    let mut from_snapshot = 0;
    for k in 0..27u64 {
        let mut calm = SimCluster::new(
            &cell(),
            CELL_AGENTS,
            Faults { duplicate: 0.2, reorder: true, delay_ms_max: 5, loss: 0.0 },
            k,
        );
        assert!(calm.run(120_000), "seed {k}: did not finish without a crash");
        let at = calm.now_ms * k / 27;
        let mut sim = cell_with_coordinator_crash(k, at, 50 + 37 * k % 700);
        assert!(sim.run(120_000), "crash at {at} ms: did not finish");
        check_cell_run(&sim);
        assert_eq!(sim.events(TraceEvent::Recover).len(), 1, "crash at {at} ms");
        from_snapshot += sim.resumed_from_snapshot;
    }
    assert!(from_snapshot >= 20, "only {from_snapshot} of 27 restarts resumed from a snapshot");
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
    let resume = sim.trace.iter().find(|r| r.event == TraceEvent::Resume && r.name == "Assemble").expect("reconciled");
    assert_eq!(resume.message.as_deref(), Some("still held by the agent"));
    assert!(resume.t_ms >= 1_600);
    let back = sim.trace.iter().find(|r| r.event == TraceEvent::Return && r.name == "Assemble").expect("returned");
    assert!(back.t_ms >= 1_600 && back.t_ms < 1_700, "the held result came back at once: {} ms", back.t_ms);
    let motions = sim.trace.iter().filter(|r| r.event == TraceEvent::ActionOn && r.name == "AssemblePart").count();
    assert_eq!(motions, 1, "the assembly motion ran once");
}

#[test]
fn an_agent_restarted_while_the_coordinator_was_down_runs_its_segment_again_in_a_new_epoch() {
    use baton_proto::testing::simulated_cluster::Fate;
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
    assert!(sim
        .trace
        .iter()
        .any(|r| r.event == TraceEvent::Alarm && r.message.as_deref().unwrap_or("").contains("restarted")));
}

#[test]
fn an_agent_that_does_not_come_back_after_a_coordinator_restart_is_lost_after_its_lease() {
    use baton_proto::testing::simulated_cluster::Fate;
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
    let lost = sim.trace.iter().find(|r| r.event == TraceEvent::AgentLost && r.name == "robot1").expect("lost");
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
    let expected =
        baton_tests::reference::final_values(COUNTING, baton_proto::testing::simulated_cluster::CYCLE_MS, &["n"]);
    assert_eq!(sim.value("n").map(|v| v.as_i64()), Some(expected[0]), "n as one engine counts it");
    assert_eq!(sim.events(TraceEvent::Return).len(), 1);
}

/// r1 counts in one step for 1 s, then, after a pause on the coordinator that takes a snapshot, counts again in a
/// later step for 300 ms; the coordinator waits for ten more counts than the snapshot. r1 is restarted while it
/// holds no token.
const RECOUNTING: &str = "PROGRAM recounting
VAR v : DINT := 0; snap : DINT := 0; END_VAR
INITIAL_STEP Start: END_STEP
TRANSITION FROM Start TO First := TRUE; END_TRANSITION
STEP First: {agent := 'r1'} IncV(N); END_STEP
TRANSITION FROM First TO Between := First.T >= T#1s; END_TRANSITION
STEP Between: Remember(P); END_STEP
TRANSITION FROM Between TO Second := Between.T >= T#1s; END_TRANSITION
STEP Second: {agent := 'r1'} IncV(N); END_STEP
TRANSITION FROM Second TO Check := Second.T >= T#300ms; END_TRANSITION
STEP Check: END_STEP
TRANSITION FROM Check TO Done := v >= snap + 10; END_TRANSITION
STEP Done: END_STEP
ACTION IncV: v := v + 1; END_ACTION
ACTION Remember: snap := v; END_ACTION
END_PROGRAM
";

#[test]
fn a_restarted_agent_computes_on_the_values_the_chart_has() {
    // The new process must start from the run's value of `v`, which only it writes, not from the chart's initial
    // value: then it counts on from about 100 and the chart ends with what one engine computes. (Before, it
    // counted from 0 to about 30, `v` fell below the snapshot, and Check never cleared.)
    let names = ["v", "snap"];
    let expected =
        baton_tests::reference::final_values(RECOUNTING, baton_proto::testing::simulated_cluster::CYCLE_MS, &names);
    assert!(expected[1] >= 90 && expected[0] >= expected[1] + 25, "the reference counted: {expected:?}");
    for seed in 0..8 {
        // No loss: a report lost and not yet resent when r1 dies would restart First in a new epoch, which counts
        // again by design (the progress of a segment that restarts is lost).
        let faults = Faults { duplicate: 0.3, reorder: true, delay_ms_max: 8, loss: 0.0 };
        let mut sim = SimCluster::new(RECOUNTING, &[("r1", &[])], faults, seed);
        // SIGKILLed while it holds no token, and started again under its name.
        sim.fate_at(1_500, "r1", baton_proto::testing::simulated_cluster::Fate::Kill);
        sim.fate_at(1_600, "r1", baton_proto::testing::simulated_cluster::Fate::Restart);
        let done = sim.run(30_000);
        let got: Vec<i64> = names.iter().map(|n| sim.value(n).map_or(-1, |v| v.as_i64())).collect();
        assert!(done, "seed {seed}: the chart never ended ({names:?} = {got:?})");
        assert_eq!(got, expected, "seed {seed}: {names:?}");
        let restarted = sim.trace.iter().any(|r| r.event == TraceEvent::AgentUp && r.t_ms >= 1_600);
        assert!(restarted, "seed {seed}: r1 came back as a new process");
        let epochs: Vec<Option<u32>> =
            sim.trace.iter().filter(|r| r.event == TraceEvent::Dispatch).map(|r| r.epoch).collect();
        assert_eq!(epochs, [Some(1), Some(1)], "seed {seed}: no segment restarted, so none lost its progress");
    }
}

#[test]
fn standard_function_blocks_compute_what_baton_sim_computes_on_any_schedule() {
    let source = chart("timers.st");
    let names = ["blinks.CV", "ticks", "blink.ET", "pulsed", "pulse.ET"];
    let expected = baton_tests::reference::final_values(&source, 10, &names);
    assert!(expected[0] >= 12 && expected[1] > 40 && expected[3] > 5, "the blocks ran: {expected:?}");
    for seed in 0..8 {
        let faults = Faults { duplicate: 0.3, reorder: true, delay_ms_max: 8, loss: 0.05 };
        let mut sim = SimCluster::new(&source, &[("r1", &[])], faults, seed);
        assert!(sim.run(30_000), "seed {seed}: did not finish");
        let got: Vec<i64> = names.iter().map(|n| sim.value(n).map_or(-1, |v| v.as_i64())).collect();
        assert_eq!(got, expected, "seed {seed}: {names:?}");
    }
}

#[test]
fn user_blocks_functions_arrays_and_structures_compute_what_baton_sim_computes_across_machines() {
    let source = chart("library.st");
    let names = [
        "pump.pumped",
        "samples[1]",
        "samples[8]",
        "slot",
        "total",
        "tank.level",
        "tank.phase",
        "verified",
        "label",
        "report",
        "receipt",
    ];
    let expected = baton_tests::reference::final_shown(&source, 10, &names);
    assert!(expected[2] != "0" && expected[4] != "0" && expected[7] == "TRUE", "the chart computed: {expected:?}");
    // The receipt is a STRING[20]: what is past its twentieth character is cut when it is stored.
    let receipt: String = format!("ok:{}", expected[9].trim_matches('\'')).chars().take(20).collect();
    assert_eq!(expected[10], format!("'{receipt}'"), "the strings were built");
    // Seed 2 found that a dispatch's values were numbered as the last update published before them, so an agent
    // that had that update kept its older values (the coordinator now publishes first).
    let agents: &[(&str, &[&str])] = &[("r1", &[]), ("r2", &[])];
    for seed in 0..8 {
        let faults = Faults { duplicate: 0.3, reorder: true, delay_ms_max: 8, loss: 0.05 };
        let mut sim = SimCluster::new(&source, agents, faults, seed);
        assert!(sim.run(30_000), "seed {seed}: did not finish");
        let got: Vec<String> = names.iter().map(|n| sim.shown(n).unwrap_or_default()).collect();
        assert_eq!(got, expected, "seed {seed}: {names:?}");
    }
}

/// The same with a TON inside the user block. Seed 3 found that an agent which had planned a cycle (after a
/// variable update) before its first token never set its engine's grid: the token's step time and the timer's
/// start were floored to the millisecond it arrived while cycles ran on the planned grid, so the timer primed
/// one cycle late (pump.pumped 10 instead of 12).
#[test]
fn a_timer_inside_a_user_block_on_an_agent_computes_what_baton_sim_computes() {
    let source = chart("library_timer.st");
    let names = ["pump.pumped", "samples[8]", "total", "verified"];
    let expected = baton_tests::reference::final_values(&source, 10, &names);
    let agents: &[(&str, &[&str])] = &[("r1", &[]), ("r2", &[])];
    for seed in 0..16 {
        let faults = Faults { duplicate: 0.3, reorder: true, delay_ms_max: 8, loss: 0.05 };
        let mut sim = SimCluster::new(&source, agents, faults, seed);
        assert!(sim.run(30_000), "seed {seed}: did not finish");
        let got: Vec<i64> = names.iter().map(|n| sim.value(n).map_or(-1, |v| v.as_i64())).collect();
        assert_eq!(got, expected, "seed {seed}: {names:?}");
    }
}

/// An action written in SFC, run on an agent: its chart's state is variables written where the action runs, so
/// a distributed run carries it and ends with what `baton sim` computes.
#[test]
fn a_nested_chart_on_an_agent_computes_what_baton_sim_computes() {
    let source = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/conformance/traces/nested_action_chart/chart.st"
    ))
    .expect("scenario")
    .replace("STEP Work: Batch(N); END_STEP", "STEP Work: {agent := 'r1'} Batch(N); END_STEP");
    assert!(source.contains("{agent := 'r1'}"), "the scenario still has the step placed here");
    let names = ["fills", "mixes", "valve", "beep", "Batch.Hold.X", "Batch.Leave.Q"];
    let expected = baton_tests::reference::final_shown(&source, 10, &names);
    // The nested chart reached Hold and counted its fourth mix there; Work's end reset it (Hold off) and gave Leave,
    // still on, its final run: the distributed run must carry that reset too.
    assert_eq!((expected[1].as_str(), expected[4].as_str()), ("4", "FALSE"), "the nested chart ran: {expected:?}");
    for seed in 0..8 {
        let faults = Faults { duplicate: 0.3, reorder: true, delay_ms_max: 8, loss: 0.05 };
        let mut sim = SimCluster::new(&source, &[("r1", &[])], faults, seed);
        assert!(sim.run(30_000), "seed {seed}: did not finish");
        let got: Vec<String> = names.iter().map(|n| sim.shown(n).unwrap_or_default()).collect();
        assert_eq!(got, expected, "seed {seed}: {names:?}");
        let batch: Vec<_> =
            sim.events(TraceEvent::ActionOn).into_iter().filter(|(_, name, _)| name == "Batch").collect();
        assert!(!batch.is_empty() && batch.iter().all(|(_, _, agent)| agent.as_deref() == Some("r1")), "{batch:?}");
    }
}

/// r1 waits for an input the coordinator owns.
const WAITING_FOR_GO: &str = "PROGRAM waiting
VAR go : BOOL; END_VAR
INITIAL_STEP Start: END_STEP
TRANSITION FROM Start TO Wait := TRUE; END_TRANSITION
STEP Wait: {agent := 'r1'} END_STEP
TRANSITION FROM Wait TO Done := go; END_TRANSITION
STEP Done: END_STEP
END_PROGRAM
";

#[test]
fn agents_take_a_value_only_from_its_writer_and_the_coordinators_own_process() {
    use baton_proto::cluster::wire::{VarUpdate, VarValue};
    use baton_proto::types::Value;
    let go = |from: &str, incarnation: u128, seq: u64| {
        let sim = SimCluster::new(WAITING_FOR_GO, &[("r1", &[])], Faults::default(), 0);
        let program = sim.coordinator.core().program();
        let var = program.var_by_name("go").expect("go");
        VarUpdate {
            run: sim.coordinator.core().run(),
            from: from.to_string(),
            incarnation: uuid::Uuid::from_u128(incarnation),
            seq,
            vars: vec![VarValue::new(var, Value::Bool(true))],
        }
    };
    for seed in 0..8 {
        let faults = Faults { duplicate: 0.3, reorder: true, delay_ms_max: 8, loss: 0.05 };
        let mut sim = SimCluster::new(WAITING_FOR_GO, &[("r1", &[])], faults, seed);
        // A made-up writer, and a process claiming to be the coordinator with numbers far ahead of the real one:
        // neither clears the transition, and the second does not silence the real coordinator on r1.
        sim.forge_vars_at(300, go("evil", 5, 1));
        sim.forge_vars_at(400, go("coordinator", 6, 1_000_000));
        // The agent itself is no writer of `go` either.
        sim.forge_vars_at(450, go("r1", 0, 1_000_000));
        sim.set_at(1_000, "go", serde_json::json!(true));
        assert!(sim.run(10_000), "seed {seed}: the real coordinator's `go` never reached r1");
        let fired =
            sim.trace.iter().find(|r| r.event == TraceEvent::Fire && r.name == "Wait->Done").expect("Wait left");
        assert!(fired.t_ms >= 1_000, "seed {seed}: Wait left at {} ms, on a forged value", fired.t_ms);
    }
}

/// A random chart whose every condition reads only step times, so that one engine and a distributed run take the
/// same path: structured shapes without loops, steps placed at random on the coordinator, agent a1, agent a2 or
/// role r, each placed step counting its cycles (N) and its visits (P) into the counters of its placement
/// (`k_a1`, `v_a1`, … — one pair per agent, so that a value an agent wrote in one step is counted on in a later
/// one — and `k_r{i}`, `v_r{i}` per step for the role, whose two agents may run steps side by side).
fn counting_cell(rng: &mut baton_tests::gen::Rng) -> (String, Vec<String>) {
    use baton_tests::gen::{random_shapes, ChartBuilder, Shape};
    fn no_loops(shapes: Vec<Shape>) -> Vec<Shape> {
        shapes
            .into_iter()
            .flat_map(|s| match s {
                Shape::Loop(body) => no_loops(body),
                Shape::Selection(b) => vec![Shape::Selection(b.into_iter().map(no_loops).collect())],
                Shape::Parallel(b) => vec![Shape::Parallel(b.into_iter().map(no_loops).collect())],
                Shape::Step => vec![Shape::Step],
            })
            .collect()
    }
    let shapes = no_loops(random_shapes(rng, 3));
    let plain = ChartBuilder::chart(&shapes, 1, false);
    let waiting: std::collections::HashSet<usize> = plain
        .lines()
        .filter_map(|l| l.strip_prefix("TRANSITION FROM (")?.split(')').next())
        .flat_map(|list| list.split(", ").filter_map(|s| s.trim_start_matches('S').parse().ok()).collect::<Vec<_>>())
        .collect();
    // The last step is terminal: it stays on the coordinator and does nothing, so that the chart ends where one
    // engine ends it.
    let sources: std::collections::HashSet<usize> = plain
        .lines()
        .filter_map(|l| l.strip_prefix("TRANSITION FROM ")?.split(" TO ").next())
        .flat_map(|list| {
            list.trim_matches(|c| c == '(' || c == ')')
                .split(", ")
                .filter_map(|s| s.trim_start_matches('S').parse().ok())
                .collect::<Vec<usize>>()
        })
        .collect();
    let (mut vars, mut actions, mut names) = (String::new(), String::new(), Vec::new());
    let declare = |vars: &mut String, names: &mut Vec<String>, name: String| {
        if !names.contains(&name) {
            vars.push_str(&format!("  {name} : DINT;\n"));
            names.push(name);
        }
    };
    let mut out = String::new();
    for line in plain.lines() {
        if let Some(head) = line.strip_suffix(": END_STEP") {
            let i: usize = head.rsplit('S').next().and_then(|n| n.parse().ok()).unwrap_or(0);
            let terminal = !sources.contains(&i);
            let placement = if i == 0 || terminal { 0 } else { rng.below(4) };
            let (pragma, counter) = match placement {
                1 => ("{agent := 'a1'} ", "a1".to_string()),
                2 => ("{agent := 'a2'} ", "a2".to_string()),
                3 => ("{role := 'r'} ", format!("r{i}")),
                _ => ("", "coord".to_string()),
            };
            let mut assocs = String::new();
            if !waiting.contains(&i) && !terminal {
                declare(&mut vars, &mut names, format!("k_{counter}"));
                declare(&mut vars, &mut names, format!("v_{counter}"));
                assocs = format!("Count{i}(N); Visit{i}(P); ");
                actions.push_str(&format!("ACTION Count{i}: k_{counter} := k_{counter} + 1; END_ACTION\n"));
                actions.push_str(&format!("ACTION Visit{i}: v_{counter} := v_{counter} + 1; END_ACTION\n"));
            }
            out.push_str(&format!("{head}: {pragma}{assocs}END_STEP\n"));
            continue;
        }
        if let Some(rest) = line.strip_prefix("TRANSITION FROM ") {
            let (from, _) = rest.split_once(" := ").expect("a condition");
            let condition = match from.strip_prefix('S').and_then(|r| r.split(' ').next()) {
                Some(source) => format!("S{source}.T >= T#{}ms", 10 * (1 + rng.below(8))),
                None => "TRUE".to_string(),
            };
            out.push_str(&format!("TRANSITION FROM {from} := {condition}; END_TRANSITION\n"));
            continue;
        }
        out.push_str(line);
        out.push('\n');
    }
    let source = out.replacen("END_VAR\n", &format!("{vars}END_VAR\n"), 1).replacen(
        "END_PROGRAM",
        &format!("{actions}END_PROGRAM"),
        1,
    );
    (source, names)
}

/// Random cells whose agents are killed and started again, cut and healed, and whose coordinator crashes, on a
/// network that loses, duplicates, reorders and delays: once the chart ends, every counter holds what one engine
/// computes (`baton sim`) — but those of an agent whose segment restarted in a new epoch, which counts that
/// segment's progress again by design, and the coordinator's if it was down (no cycle runs in a dead process). A new process that computed on the chart's initial values, or a value
/// lost between processes, shows here.
#[test]
fn random_restarts_end_with_the_values_baton_sim_computes() {
    use baton_proto::testing::simulated_cluster::{Fate, CYCLE_MS};
    use baton_tests::gen::Rng;
    let (mut compared, mut restarted_agents) = (0usize, 0usize);
    for &seed in &seeds() {
        let mut rng = Rng::new(seed ^ 0x7e57);
        let (source, names) = counting_cell(&mut rng);
        if baton_proto::pipeline::check_source(&source).error_count() != 0 {
            continue;
        }
        let refs: Vec<&str> = names.iter().map(String::as_str).collect();
        let expected = baton_tests::reference::final_values(&source, CYCLE_MS, &refs);
        let faults = Faults {
            duplicate: rng.fraction(0.3),
            reorder: rng.chance(0.7),
            delay_ms_max: rng.below(7),
            loss: rng.fraction(0.05),
        };
        let mut plan = format!("{faults:?}");
        let mut sim = SimCluster::new(&source, &[("a1", &["r"]), ("a2", &["r"])], faults, seed);
        if rng.chance(0.3) {
            sim.set_loss_policy(LossPolicy::Reassign);
            plan.push_str(", reassign");
        }
        for _ in 0..1 + rng.below(3) {
            let (agent, at) = (["a1", "a2"][rng.below(2) as usize], rng.below(1_500));
            let mut fate = |t: u64, f: Fate| {
                sim.fate_at(t, agent, f);
                plan.push_str(&format!(", {f:?} {agent} at {t} ms"));
            };
            match rng.below(3) {
                0 => {
                    fate(at, Fate::Kill);
                    fate(at + 1 + rng.below(300), Fate::Restart);
                }
                1 => fate(at, Fate::Restart),
                _ => {
                    fate(at, Fate::Cut);
                    fate(at + rng.below(2_000), Fate::Heal);
                }
            }
        }
        let crashed = rng.chance(0.3);
        if crashed {
            let (at, down) = (rng.below(1_500), 1 + rng.below(300));
            sim.crash_coordinator_at(at, down);
            plan.push_str(&format!(", coordinator down at {at} ms for {down} ms"));
        }
        let finished = sim.run(60_000);
        let replay = format!(
            "{plan}\nreplay: BATON_SIM_SEED={seed} cargo test -p baton-tests --test distributed_sim random_restarts_end_with_the_values_baton_sim_computes\n{source}"
        );
        let tail: Vec<String> = sim.trace.iter().rev().take(12).rev().map(|r| format!("{r:?}")).collect();
        assert!(
            finished,
            "seed {seed}: the chart did not end ({:?}, {:?}); last records:\n{}\n{replay}",
            sim.coordinator.core().failure(),
            sim.errors,
            tail.join("\n")
        );
        if let Some(why) = sim.violations.first() {
            panic!("seed {seed}: {why}\n{replay}");
        }
        // The agents one of whose segments ran again in a new epoch, and whether a role step did.
        let again: std::collections::BTreeSet<String> = sim
            .trace
            .iter()
            .filter(|r| r.event == TraceEvent::Dispatch && r.epoch.is_some_and(|e| e > 1))
            .filter_map(|r| r.agent.clone())
            .collect();
        let role_again = sim.trace.iter().any(|r| {
            r.event == TraceEvent::Dispatch
                && r.epoch.is_some_and(|e| e > 1)
                && source.contains(&format!("{}: {{role", r.name))
        });
        restarted_agents += usize::from(plan.contains("Restart"));
        for (name, want) in names.iter().zip(&expected) {
            // The coordinator's own steps run no cycle while it is down: its counters lose that time by design.
            let exempt = match name.split_once('_').map(|(_, p)| p) {
                Some("coord") => crashed,
                Some(p) if p.starts_with('r') => role_again,
                Some(agent) => again.contains(agent),
                None => false,
            };
            if exempt {
                continue;
            }
            let got = sim.value(name).map_or(-1, |v| v.as_i64());
            assert_eq!(got, *want, "seed {seed}: `{name}`\n{replay}");
        }
        compared += 1;
    }
    eprintln!("random restarts: {compared} charts compared, {restarted_agents} with a restarted agent");
    if seeds().len() > 1 {
        assert!(compared * 10 >= seeds().len() * 8, "only {compared} random charts were valid");
    }
}
