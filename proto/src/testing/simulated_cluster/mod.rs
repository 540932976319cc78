//! Deterministic simulation of a distributed run: the real coordinator and agent state machines from
//! `crate::cluster::runtime`, a simulated network and simulated skills, one thread, one seed, virtual time.
//!
//! Every message goes through the real wire encoding. The network can lose, duplicate, reorder and delay
//! messages; a cut link goes silent, and the coordinator hears of it only when the agent's lease runs out (the
//! agent fences itself first, as a real one does). The coordinator journals every input
//! (`crate::cluster::journal`), and can be crashed — before its latest records are durable, or after they are but
//! before what they led to was sent — and started again from its journal. What the agents do is watched too:
//! no segment starts twice in one epoch on any agent, and no engine ever gives a step a second token
//! (`violations`).
//!
//! What the skills do is the simulation's own (`SkillModel`): by default the `motion` skill's parameters (`ms`,
//! `fault_rate`); `baton test` gives each action the behaviour its scenario declares. Faults of the network can
//! be global (`Faults`) or on one agent's link for a while (`link_faults_at`).
//!
//! Deterministic simulation of a distributed run (real state machines, simulated network that
//! loses, duplicates, reorders and delays, agents killed, restarted, or cut silently — lost when their lease runs out,
//! fencing themselves first —, the coordinator crashed before or after its journal and restarted from it, one seed;
//! what agents start is watched, and `settled` finds tokens stuck between the coordinator and an agent). Product code,
//! not test code: the one simulator serves the project's tests and users' scenarios (`baton test`). What skills do is a
//! `SkillModel` (default: `motion`, the `motion` skill's parameters, which scenarios fall back

use std::collections::BTreeMap;
use std::sync::Arc;

use uuid::Uuid;

use crate::cluster::journal::Journaled;
use crate::cluster::layout::Layout;
use crate::cluster::runtime::agent::AgentRun;
use crate::cluster::runtime::coordinator::{CoordOutput, LossPolicy};
use crate::cluster::wire::{self, AgentInfo, ChartHash, CtlRequest, RunId, VarUpdate};
use crate::exec::program::{ActionId, Program};
use crate::exec::trace::{TraceEvent, TraceRecord};
use crate::pipeline::check_source;
use crate::types::Value;

mod election;
mod network;
mod skills;
pub use skills::{motion, motion_ms, motion_result, Rng, SimSkill, SkillModel, SkillStart, NETWORK_MIX};

/// The simulated run's cycle period, unless told otherwise (`SimCluster::with_program`).
pub const CYCLE_MS: u64 = 10;

/// What the simulated network does to messages.
#[derive(Clone, Copy, Debug, Default)]
pub struct Faults {
    /// Probability that a message is delivered twice.
    pub duplicate: f64,
    /// Deliver messages in random order rather than sent order.
    pub reorder: bool,
    /// Largest extra delay of a message, in ms.
    pub delay_ms_max: u64,
    /// Probability that a message is lost on a working link.
    pub loss: f64,
}

/// The lease every simulated agent announces.
pub const LEASE_MS: u64 = 1000;

enum Packet {
    /// To agent `.0`'s process `.1`: only that process hears it.
    ToAgent(usize, Uuid, Vec<u8>),
    /// From agent `.0`.
    Report(usize, Vec<u8>),
    /// From agent `.0`, or from the coordinator (`None`).
    Vars(Option<usize>, Vec<u8>),
}

/// An agent of the simulated run.
#[derive(Clone, Debug)]
pub struct SimAgentSpec {
    pub name: String,
    pub roles: Vec<String>,
    /// When its process starts (0: with the run).
    pub start_ms: u64,
    /// The skills it announces (`AgentInfo::skills`); `None`: it says nothing, and is sent anything.
    pub skills: Option<Vec<String>>,
}

/// Faults on one agent's link (both ways) for a while.
#[derive(Clone, Copy, Debug)]
struct LinkFault {
    agent: usize,
    from_ms: u64,
    until_ms: u64,
    faults: Faults,
}

/// Something that happens to an agent during a simulated run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Fate {
    /// SIGKILL: its state is gone and the coordinator sees it leave at once.
    Kill,
    /// The process starts again with the same name and no state.
    Restart,
    /// A cut cable or SIGSTOP: it keeps its state but nothing reaches it or leaves it; its lease runs out.
    Cut,
    /// The cable is back (or SIGCONT): its messages flow again.
    Heal,
}

/// How a running simulated skill ends: when, with what, and the outputs it writes first.
type Ending = (u64, Result<(), String>, Vec<(usize, Value)>);

/// The simulated cell's first run: its journal begins with it.
const FIRST_RUN: RunId = RunId(Uuid::from_u128(1));

/// How many records the simulated coordinator journals between snapshots: few, so that crashes resume from them.
const SNAPSHOT_EVERY: usize = 16;

/// How long a run that was aborted waits for the agents it could not tell (`baton run --abort-wait`'s default).
const ABORT_WAIT_MS: u64 = 30_000;

struct SimAgent {
    name: String,
    roles: Vec<String>,
    /// The skills it announces.
    offers: Option<Vec<String>>,
    alive: bool,
    reachable: bool,
    restarts: u128,
    run: AgentRun,
    /// Running skills: action → (finish time, result, the outputs it writes first); a hanging one has none.
    skills: BTreeMap<ActionId, Option<Ending>>,
    /// Since when its link is cut, whether it has fenced itself, and whether the coordinator was told (its lease
    /// ran out).
    cut_at: Option<u64>,
    fenced: bool,
    lost: bool,
    /// Skills its agent started while their branch was held, as last counted.
    held_starts: u64,
    /// The coordinator process of now knows it: a coordinator that started while the agent was cut off asks it
    /// (again and again, as `baton run` does) once its link is back.
    announced: bool,
}

/// The run's election.
struct Election {
    /// How long a coordinator's lease lasts: a paused or dead one is replaced this long after it stopped.
    lease_ms: u64,
    /// The active coordinator's term (the revision at which it won).
    term: u64,
    /// Pauses of the active coordinator to come: (from when, how long), in order.
    pauses: Vec<(u64, u64)>,
    /// Deposed coordinators that have not noticed yet: when each wakes, and what it sends then (at its term).
    zombies: Vec<(u64, Vec<Packet>)>,
    /// Per agent process (the agent's index, its restarts): the highest term of a message it took.
    taken: BTreeMap<(usize, u128), u64>,
    /// Messages of a deposed coordinator that agents refused.
    refused: u64,
    /// Takeovers so far, and the messages deposed coordinators sent as they woke.
    takeovers: u64,
    late_messages: u64,
    /// Cuts of the active coordinator from the store to come: (from when, how long), in order; the one under way.
    cuts: Vec<(u64, u64)>,
    cut: Option<Cut>,
    /// Cuts that healed before the coordinator's deadline (its writes went through), and cuts it outlasted (it
    /// stopped acting, its writes never durable).
    cuts_healed: u64,
    cuts_outlasted: u64,
}

/// A cut of the active coordinator from the store under way: when it heals, when the coordinator's own deadline
/// comes, and what waits for the store meanwhile.
struct Cut {
    heals: u64,
    deadline: u64,
    records: Vec<Vec<u8>>,
    outputs: Vec<CoordOutput>,
}

/// What the election did in a run, for a test to see that its faults happened.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ElectionStats {
    pub term: u64,
    pub takeovers: u64,
    /// Deposed coordinators' messages sent after a takeover (as they woke).
    pub late_messages: u64,
    /// Those refused by the agents that had heard a higher term.
    pub refused: u64,
    /// Cuts from the store that healed in time, and cuts the coordinator outlasted (it stopped acting).
    pub cuts_healed: u64,
    pub cuts_outlasted: u64,
}

pub struct SimCluster {
    pub coordinator: Journaled,
    /// The coordinator's durable records: everything it took before its outputs left.
    pub journal: Vec<Vec<u8>>,
    /// Snapshots of the coordinator (`Journaled::snapshot`), each with the number of records before it: taken every
    /// `snapshot_every` records (`usize::MAX`: never), as `baton run --journal` does, and resumed from after a crash.
    pub snapshots: Vec<(usize, Vec<u8>)>,
    pub snapshot_every: usize,
    /// Restarts that resumed from a snapshot (and were checked against the whole journal's replay).
    pub resumed_from_snapshot: u32,
    /// While the coordinator is down: when it starts again.
    down_until: Option<u64>,
    crashes: Vec<(u64, u64)>,
    /// Crashes right after records became durable, before what they led to was sent.
    crashes_after_journal: Vec<(u64, u64)>,
    /// Every (token, epoch) that started on an agent.
    started: std::collections::BTreeSet<(crate::cluster::wire::TokenId, u32)>,
    /// What went wrong on the agents' side, with the time.
    pub violations: Vec<String>,
    /// The coordinator died after its journal but before it sent (or wrote) what that led to.
    outputs_lost: bool,
    /// Standby coordinators and their election (`stand_by`); `None`: one coordinator, at term 0.
    election: Option<Election>,
    calm_from_ms: Option<u64>,
    fates: Vec<(u64, String, Fate)>,
    program: Arc<Program>,
    layout: Arc<Layout>,
    hash: ChartHash,
    /// Inputs to set, as (time, name, value), applied when their time comes.
    inputs: Vec<(u64, String, serde_json::Value)>,
    /// Operators' commands, and when (`command_at`).
    commands: Vec<(u64, CtlRequest)>,
    /// What the coordinator answered each command, in order.
    pub answers: Vec<(u64, Result<String, String>)>,
    /// When an operator's stop or abort ended the run.
    operator_end_ms: Option<u64>,
    /// Variable updates a rogue peer publishes, and when.
    forged: Vec<(u64, VarUpdate)>,
    agents: Vec<SimAgent>,
    net: Vec<(u64, Packet)>,
    rng: Rng,
    faults: Faults,
    links: Vec<LinkFault>,
    skill_model: Option<SkillModel>,
    cycle_ms: u64,
    /// What could not be done as asked (an input that cannot be set), with the time.
    pub errors: Vec<String>,
    pub now_ms: u64,
    /// The grid time of the coordinator's last cycle.
    last_cycle_ms: Option<u64>,
    pub trace: Vec<TraceRecord>,
    pub seed: u64,
    pub messages: u64,
    /// Variables whose `value` records the coordinator traces (`watch`), as `baton run --watch` has them.
    pub(super) watched: Vec<crate::exec::program::VarId>,
    /// Every message sent, as it went on the wire, when `capture` is on: `(what, bytes)` with `what` the fuzz
    /// target's selector (`testing::fuzz::wire_message`: 0 to an agent, 1 a report, 2 a variable update).
    pub captured: Option<Vec<(u8, Vec<u8>)>>,
}

/// The first chart of `source`, compiled and laid out; panics with the diagnostics if it has errors. (For the
/// project's own tests: `baton test` checks a user's chart and says what is wrong with it.)
pub fn compile(source: &str) -> (Arc<Program>, Arc<Layout>) {
    let mut report = check_source(source);
    assert_eq!(report.error_count(), 0, "chart has errors: {:#?}", report.diagnostics);
    let checked = report.charts.remove(0);
    (Arc::new(checked.program.expect("program")), Arc::new(checked.layout.expect("layout")))
}

/// A fresh agent process (its `restarts`-th incarnation) in the simulated run.
/// The chart a simulated cell runs, as its agents' processes take it.
struct ChartOf<'a> {
    hash: &'a ChartHash,
    program: &'a Arc<Program>,
    layout: &'a Arc<Layout>,
    cycle_ms: u64,
}

/// The part of run `run` that process number `restarts` of agent `name` runs.
fn agent_run(run: RunId, name: &str, roles: &[String], chart: &ChartOf<'_>, restarts: u128) -> AgentRun {
    let (program, layout) = (Arc::clone(chart.program), Arc::clone(chart.layout));
    let mut a = AgentRun::new(name, roles, run, chart.hash.clone(), program, layout, chart.cycle_ms);
    a.set_incarnation(Uuid::from_u128(restarts));
    a
}

impl SimCluster {
    /// Agents as (name, roles).
    pub fn new(source: &str, agents: &[(&str, &[&str])], faults: Faults, seed: u64) -> SimCluster {
        let (program, layout) = compile(source);
        let hash = ChartHash::of(source, &program.name);
        let agents: Vec<SimAgentSpec> = agents
            .iter()
            .map(|(name, roles)| SimAgentSpec {
                name: name.to_string(),
                roles: roles.iter().map(|r| r.to_string()).collect(),
                start_ms: 0,
                skills: None,
            })
            .collect();
        SimCluster::with_program(program, layout, hash, &agents, faults, seed, CYCLE_MS)
    }

    /// A simulated run of a compiled chart, with agents that may start later than the run, and its cycle period.
    pub fn with_program(
        program: Arc<Program>,
        layout: Arc<Layout>,
        hash: ChartHash,
        agents: &[SimAgentSpec],
        faults: Faults,
        seed: u64,
        cycle_ms: u64,
    ) -> SimCluster {
        let run = FIRST_RUN;
        let mut coordinator = Journaled::start(Arc::clone(&program), Arc::clone(&layout), run, hash.clone(), cycle_ms);
        let mut fates = Vec::new();
        let sim_agents = agents
            .iter()
            .map(|spec| {
                let now = spec.start_ms == 0;
                if now {
                    coordinator.agent_up(
                        0,
                        AgentInfo {
                            name: spec.name.clone(),
                            roles: spec.roles.clone(),
                            lease_ms: LEASE_MS,
                            incarnation: Uuid::from_u128(0),
                            held: Vec::new(),
                            pending: Vec::new(),
                            skills: spec.skills.clone(),
                        },
                    );
                } else {
                    // Its process starts later: a new incarnation then.
                    fates.push((spec.start_ms, spec.name.clone(), Fate::Restart));
                }
                SimAgent {
                    name: spec.name.clone(),
                    roles: spec.roles.clone(),
                    offers: spec.skills.clone(),
                    alive: now,
                    reachable: now,
                    restarts: 0,
                    run: agent_run(
                        run,
                        &spec.name,
                        &spec.roles,
                        &ChartOf { hash: &hash, program: &program, layout: &layout, cycle_ms },
                        0,
                    ),
                    skills: BTreeMap::new(),
                    cut_at: None,
                    fenced: false,
                    lost: false,
                    held_starts: 0,
                    announced: now,
                }
            })
            .collect();
        let mut sim = SimCluster {
            coordinator,
            journal: Vec::new(),
            snapshots: Vec::new(),
            snapshot_every: SNAPSHOT_EVERY,
            resumed_from_snapshot: 0,
            down_until: None,
            crashes: Vec::new(),
            crashes_after_journal: Vec::new(),
            started: std::collections::BTreeSet::new(),
            violations: Vec::new(),
            outputs_lost: false,
            election: None,
            calm_from_ms: None,
            fates,
            program: Arc::clone(&program),
            layout: Arc::clone(&layout),
            hash: hash.clone(),
            inputs: Vec::new(),
            commands: Vec::new(),
            answers: Vec::new(),
            operator_end_ms: None,
            forged: Vec::new(),
            agents: sim_agents,
            net: Vec::new(),
            rng: Rng::new(seed, NETWORK_MIX),
            faults,
            links: Vec::new(),
            skill_model: None,
            cycle_ms,
            errors: Vec::new(),
            now_ms: 0,
            last_cycle_ms: None,
            trace: Vec::new(),
            seed,
            messages: 0,
            watched: Vec::new(),
            captured: None,
        };
        sim.flush_coordinator();
        sim
    }

    fn random(&mut self) -> u64 {
        self.rng.next_u64()
    }

    fn chance(&mut self, p: f64) -> bool {
        p > 0.0 && (self.random() % 1_000_000) as f64 / 1_000_000.0 < p
    }

    /// From `t_ms` on, the network is perfect: no loss, duplicate, reordering or delay.
    pub fn calm_from(&mut self, t_ms: u64) {
        self.calm_from_ms = Some(t_ms);
    }

    /// Gives what the skills do to `model` instead of the `motion` parameters.
    pub fn set_skill_model(&mut self, model: SkillModel) {
        self.skill_model = Some(model);
    }

    /// From `from_ms` to `until_ms`, the messages between the coordinator and `agent` (both ways) suffer `faults`
    /// rather than the run's own.
    pub fn link_faults_at(&mut self, from_ms: u64, until_ms: u64, agent: &str, faults: Faults) {
        if let Some(i) = self.agents.iter().position(|a| a.name == agent) {
            self.links.push(LinkFault { agent: i, from_ms, until_ms, faults });
        }
    }

    pub fn set_loss_policy(&mut self, policy: LossPolicy) {
        self.coordinator.set_loss_policy(self.now_ms, policy);
        self.flush_coordinator();
    }

    /// The coordinator process dies at `t_ms` (SIGKILL: what it took but had not yet made durable is lost) and
    /// starts again from its journal `down_ms` later.
    /// Traces the values of every variable of the chart that an operator may see (`baton run --watch` on each),
    /// in the live run and in every resume and replay of it.
    pub fn watch_all(&mut self) {
        let vars = self.program.vars.iter().enumerate().filter(|(_, v)| !v.constant && !v.hidden);
        self.watched = vars.map(|(i, _)| crate::exec::program::VarId(i as u32)).collect();
        self.coordinator.watch(self.watched.clone());
    }

    pub fn crash_coordinator_at(&mut self, t_ms: u64, down_ms: u64) {
        self.crashes.push((t_ms, down_ms));
        self.crashes.sort_unstable();
    }

    /// The coordinator process dies at the first moment from `t_ms` on when it has something to send: its records
    /// are durable, what they led to never leaves. It starts again `down_ms` later.
    pub fn crash_coordinator_after_journal_at(&mut self, t_ms: u64, down_ms: u64) {
        self.crashes_after_journal.push((t_ms, down_ms));
        self.crashes_after_journal.sort_unstable();
    }

    fn crash_coordinator(&mut self, down_ms: u64) {
        if self.down_until.is_some() {
            // Already down: nothing more to lose.
            return;
        }
        // Records not yet durable die with the process, and so do the outputs they led to — those a cut from the
        // store held too.
        self.coordinator.take_records();
        while self.coordinator.poll_output().is_some() {}
        if let Some(e) = self.election.as_mut() {
            e.cut = None;
        }
        self.down_until = Some(self.now_ms + down_ms);
    }

    /// A new coordinator process: resumes from the latest snapshot and the records after it, checks that this
    /// rebuilt the same run as replaying the whole journal (what `baton replay` does) and as the live run wrote,
    /// and reconciles with the agents that answer.
    fn restart_coordinator(&mut self) {
        self.down_until = None;
        // With standbys, the process that goes on is one that won a new election.
        self.new_term();
        // The journal begins with the first run (a `reset` goes on to others in it).
        let run = FIRST_RUN;
        let (program, layout) = (Arc::clone(&self.program), Arc::clone(&self.layout));
        let mut whole = Journaled::start(program, layout, run, self.hash.clone(), self.cycle_ms);
        whole.watch(self.watched.clone());
        self.last_cycle_ms = None;
        let replayed = whole.replay(self.journal.iter().map(Vec::as_slice)).expect("the journal replays");
        assert!(replayed.ended.is_none(), "seed {}: a run that ended was restarted", self.seed);
        let again: Vec<TraceRecord> = std::iter::from_fn(|| whole.poll_output())
            .filter_map(|out| match out {
                CoordOutput::Trace(rec) => Some(rec),
                _ => None,
            })
            .collect();
        // The replay rebuilds what the run wrote, and — when the process died after its journal but before it
        // sent anything — what it was about to write; the resumed run writes the trace again in full.
        let outputs_lost = std::mem::take(&mut self.outputs_lost);
        self.check_rebuilt("the replay of the whole journal", &again, &self.trace, outputs_lost);
        // What `baton run --journal` resumes from: the latest snapshot, then the records after it. Its trace goes
        // on from the snapshot's count of trace records, and must be the rest of the same trace.
        let fresh = match self.snapshots.last() {
            None => whole,
            Some((at, bytes)) => {
                let (mut fresh, meta) =
                    Journaled::restore(Arc::clone(&self.program), Arc::clone(&self.layout), bytes).expect("restores");
                assert_eq!(meta.records, *at as u64, "seed {}: the snapshot's record count", self.seed);
                fresh.watch(self.watched.clone());
                fresh.replay(self.journal[*at..].iter().map(Vec::as_slice)).expect("the records after it replay");
                let mut resumed = again[..meta.trace_records as usize].to_vec();
                resumed.extend(std::iter::from_fn(|| fresh.poll_output()).filter_map(|out| match out {
                    CoordOutput::Trace(rec) => Some(rec),
                    _ => None,
                }));
                self.check_rebuilt("the resume from a snapshot", &resumed, &again, false);
                self.resumed_from_snapshot += 1;
                fresh
            }
        };
        self.trace = again;
        self.coordinator = fresh;
        self.coordinator.recover(self.now_ms);
        self.flush_coordinator();
        // The agents that are there announce themselves; as with a real router, nothing tells the new process
        // about those that are gone: it gives up on them when their lease runs out.
        for i in 0..self.agents.len() {
            self.agents[i].announced = false;
        }
        if self.coordinator.core().failure().is_some() {
            // The run failed before the crash: `baton run` records its end and exits, hearing no one.
            return;
        }
        for i in 0..self.agents.len() {
            if self.down_until.is_some() {
                // It died again on the way.
                return;
            }
            if self.agents[i].alive && self.agents[i].reachable {
                let info = self.info(i);
                self.agents[i].announced = true;
                self.coordinator.agent_up(self.now_ms, info);
            }
            self.flush_coordinator();
        }
    }

    /// Panics, showing where, unless `rebuilt` is `live` (or, when outputs were lost, goes on from it).
    fn check_rebuilt(&self, how: &str, rebuilt: &[TraceRecord], live: &[TraceRecord], outputs_lost: bool) {
        let same = if outputs_lost { rebuilt.starts_with(live) } else { rebuilt == live };
        if !same {
            let at = rebuilt.iter().zip(live).position(|(a, b)| a != b).unwrap_or(rebuilt.len().min(live.len()));
            let lo = at.saturating_sub(3);
            panic!(
                "seed {}: {how} did not rebuild the run's trace; from record {at}:\nrebuilt: {:#?}\nlive: {:#?}",
                self.seed,
                &rebuilt[lo..(at + 3).min(rebuilt.len())],
                &live[lo..(at + 3).min(live.len())]
            );
        }
    }

    fn info(&self, i: usize) -> AgentInfo {
        let a = &self.agents[i];
        AgentInfo {
            name: a.name.clone(),
            roles: a.roles.clone(),
            lease_ms: LEASE_MS,
            incarnation: Uuid::from_u128(a.restarts),
            held: a.run.held(),
            pending: Vec::new(),
            skills: a.offers.clone(),
        }
    }

    /// Makes something happen to an agent at `t_ms`.
    pub fn fate_at(&mut self, t_ms: u64, agent: &str, fate: Fate) {
        self.fates.push((t_ms, agent.to_string(), fate));
        self.fates.sort_by_key(|f| f.0);
    }

    fn apply_fate(&mut self, agent: &str, fate: Fate) {
        let Some(i) = self.agents.iter().position(|a| a.name == agent) else { return };
        let now = self.now_ms;
        let coordinator_up = self.down_until.is_none();
        match fate {
            Fate::Kill => {
                // The socket closes: the router drops the agent at once.
                let a = &mut self.agents[i];
                a.reachable = false;
                a.alive = false;
                a.skills.clear();
                a.cut_at = None;
                a.lost = true;
                if coordinator_up {
                    self.coordinator.agent_down(now, agent);
                }
            }
            Fate::Cut if !self.agents[i].alive || self.agents[i].cut_at.is_some() => {}
            Fate::Cut => {
                // Silence: nothing tells the coordinator until the agent's lease runs out (`run`).
                let a = &mut self.agents[i];
                a.reachable = false;
                a.cut_at = Some(now);
            }
            Fate::Restart => {
                // A restart is a new incarnation; a healed cut is the same process.
                self.agents[i].restarts += 1;
                let run = self.coordinator.core().run();
                let chart =
                    ChartOf { hash: &self.hash, program: &self.program, layout: &self.layout, cycle_ms: self.cycle_ms };
                let a = &mut self.agents[i];
                a.held_starts = 0;
                a.run = agent_run(run, agent, &a.roles, &chart, a.restarts);
                a.alive = true;
                a.reachable = true;
                a.cut_at = None;
                a.fenced = false;
                a.lost = false;
                a.skills.clear();
                if coordinator_up {
                    self.agents[i].announced = true;
                    self.coordinator.agent_up(now, self.info(i));
                }
            }
            Fate::Heal => {
                let a = &mut self.agents[i];
                if !a.alive || a.cut_at.is_none() {
                    return;
                }
                a.reachable = true;
                a.cut_at = None;
                if std::mem::take(&mut a.fenced) {
                    a.run.handle_contact(now, None);
                    self.flush_agent(i);
                }
                // Back within its lease, the agent was never dropped: its messages simply flow again. After it,
                // its liveliness token comes back, and the coordinator asks who it is.
                let lost = std::mem::take(&mut self.agents[i].lost);
                if (lost || !self.agents[i].announced) && coordinator_up {
                    self.agents[i].announced = true;
                    self.coordinator.agent_up(now, self.info(i));
                }
            }
        }
        self.flush_coordinator();
    }

    /// Sets an input at `t_ms`, as `baton set` would.
    pub fn set_at(&mut self, t_ms: u64, name: &str, value: serde_json::Value) {
        self.inputs.push((t_ms, name.to_string(), value));
        self.inputs.sort_by_key(|i| i.0);
    }

    /// The run stays at its end for `clear` and `reset` (`baton run --stay`).
    pub fn set_stay(&mut self) {
        self.coordinator.stay(self.now_ms);
        self.flush_coordinator();
    }

    /// Whether an operator's command is still to be sent.
    pub fn commands_pending(&self) -> bool {
        !self.commands.is_empty()
    }

    /// After a `reset`: the chart starts again as a new run (numbered on from the first), as the host does; every
    /// agent process forgets the old run's part and takes the new run's.
    fn new_run(&mut self) {
        let run = RunId(Uuid::from_u128(self.coordinator.core().run().0.as_u128() + 1));
        self.coordinator.new_run(self.now_ms, run);
        let chart = ChartOf { hash: &self.hash, program: &self.program, layout: &self.layout, cycle_ms: self.cycle_ms };
        for a in &mut self.agents {
            a.run = agent_run(run, &a.name, &a.roles, &chart, a.restarts);
            a.skills.clear();
            a.held_starts = 0;
        }
        self.operator_end_ms = None;
        self.flush_coordinator();
    }

    /// What agent `name`'s process holds now: its tokens and its running skills.
    pub fn agent_holds(&self, name: &str) -> (usize, usize) {
        let a = self.agents.iter().rev().find(|a| a.name == name).expect("an agent of the cluster");
        (a.run.tokens_held(), a.skills.len())
    }

    /// An operator sends `request` at `t_ms`, as `baton ctl` would; the answer goes to `answers`.
    pub fn command_at(&mut self, t_ms: u64, request: CtlRequest) {
        self.commands.push((t_ms, request));
        self.commands.sort_by_key(|c| c.0);
    }

    /// A rogue peer publishes `update` on the run's variable keys at `t_ms`: the coordinator and every agent it
    /// reaches hear it, as they would hear a process that is not theirs.
    pub fn forge_vars_at(&mut self, t_ms: u64, update: VarUpdate) {
        self.forged.push((t_ms, update));
        self.forged.sort_by_key(|f| f.0);
    }

    /// Runs until the chart reaches a terminal situation or `limit_ms` of virtual time passed; returns whether
    /// it finished.
    pub fn run(&mut self, limit_ms: u64) -> bool {
        while self.now_ms <= limit_ms {
            if let Some(finished) = self.tick() {
                return finished;
            }
            self.skip_idle(limit_ms + 1);
        }
        false
    }

    /// One millisecond of the run: what is due now happens, and the clock moves on. `Some` when the run is over
    /// now: `true` when the chart reached a terminal situation, `false` when the run failed (as `baton run`
    /// ends with exit status 2); the clock then stays.
    pub fn tick(&mut self) -> Option<bool> {
        {
            if self.down_until.is_some_and(|t| t <= self.now_ms) {
                self.restart_coordinator();
            }
            self.wake_zombies();
            self.store_due();
            while self.crashes.first().is_some_and(|c| c.0 <= self.now_ms) {
                let (_, down_ms) = self.crashes.remove(0);
                self.crash_coordinator(down_ms);
            }
            // As the hosts do: what is due by now runs first, then what arrived now (an agent's process dying or
            // coming back, a lease running out, a message).
            let up = self.down_until.is_none();
            if up {
                self.due_cycles();
            }
            while self.fates.first().is_some_and(|f| f.0 <= self.now_ms) {
                let (_, agent, fate) = self.fates.remove(0);
                self.apply_fate(&agent, fate);
            }
            self.leases();
            self.watch_engines();
            for i in 0..self.agents.len() {
                let now = self.now_ms;
                if self.agents[i].alive && self.agents[i].run.poll_timeout().is_some_and(|t| t <= now) {
                    self.agents[i].run.handle_timeout(now);
                    self.flush_agent(i);
                }
            }
            while up && self.inputs.first().is_some_and(|i| i.0 <= self.now_ms) {
                let (_, name, value) = self.inputs.remove(0);
                if let Err(e) = self.coordinator.set(self.now_ms, &name, &value) {
                    self.errors.push(format!("at {} ms, {name} cannot be set to {value}: {e}", self.now_ms));
                }
                self.flush_coordinator();
            }
            while up && self.commands.first().is_some_and(|c| c.0 <= self.now_ms) {
                let (_, request) = self.commands.remove(0);
                let answer = self.coordinator.command(self.now_ms, request);
                self.answers.push((self.now_ms, answer));
                self.flush_coordinator();
                if self.coordinator.core().wants_new_run() {
                    self.new_run();
                }
            }
            while self.forged.first().is_some_and(|f| f.0 <= self.now_ms) {
                let (_, update) = self.forged.remove(0);
                let now = self.now_ms;
                if up {
                    // Without access control on the router, a rogue publishes on the key of the writer it claims.
                    self.coordinator.vars(now, &update.from, &wire::encode(&update)).expect("a forged update encodes");
                }
                for a in self.agents.iter_mut().filter(|a| a.alive && a.reachable) {
                    a.run.handle_vars(now, 0, &update);
                }
                for i in 0..self.agents.len() {
                    self.flush_agent(i);
                }
                self.flush_coordinator();
            }
            self.deliver();
            for i in 0..self.agents.len() {
                if !self.agents[i].alive {
                    continue;
                }
                let now = self.now_ms;
                let due: Vec<ActionId> = self.agents[i]
                    .skills
                    .iter()
                    .filter(|(_, s)| s.as_ref().is_some_and(|(at, _, _)| *at <= now))
                    .map(|(a, _)| *a)
                    .collect();
                for a in due {
                    let Some(Some((_, result, writes))) = self.agents[i].skills.remove(&a) else { continue };
                    for (output, value) in writes {
                        self.agents[i].run.handle_skill_output(now, a, output, value);
                    }
                    self.agents[i].run.handle_skill_result(now, a, result);
                }
                self.flush_agent(i);
            }
            // Up now: it may have died since the start of this millisecond, with the end in its journal only. Cut
            // from the store, its end waits for the store, as `baton run` waits for its journal before it leaves.
            let up = self.down_until.is_none() && !self.cut_under_way();
            let core = self.coordinator.core();
            let by_operator = core.is_ended_by_operator();
            if up && core.stays() && core.failure().is_none() {
                // `baton run --stay`: the run waits at its end for `clear` and `reset`; the simulation ends there
                // once no command is left to send (and what was said on the way has arrived, or had its time).
                use crate::cluster::runtime::packml::State;
                if matches!(core.run_state(), State::Complete | State::Stopped | State::Aborted) {
                    let since = *self.operator_end_ms.get_or_insert(self.now_ms);
                    if self.commands.is_empty() && (self.net.is_empty() || self.now_ms >= since + 2_000) {
                        return Some(true);
                    }
                } else {
                    self.operator_end_ms = None;
                }
            } else if up && !by_operator && core.is_terminal() && self.net.is_empty() {
                return Some(true);
            } else if up && by_operator {
                // Stopped or aborted: `baton run` ends here (exit status 3 or 4); what it said on the way out reaches
                // the agents (unless lost), which the simulation lets happen for a while — and agents it could not
                // tell of an abort are waited for as `baton run --abort-wait` does by default.
                let since = *self.operator_end_ms.get_or_insert(self.now_ms);
                let untold = self.coordinator.core().untold_agents().next().is_some();
                let wait_ms = if untold { ABORT_WAIT_MS } else { 2_000 };
                if (self.net.is_empty() && !untold) || self.now_ms >= since + wait_ms {
                    return Some(true);
                }
            }
            if up && self.coordinator.core().failure().is_some() {
                // `baton run` ends here, with exit status 2.
                return Some(false);
            }
            self.now_ms += 1;
        }
        None
    }

    /// The earliest time from now on when anything is due: a message to deliver, a cycle or a timeout of the
    /// coordinator or an agent, a skill's end, a fault, an input, a lease running out. `None`: nothing ever.
    /// Between now and then the run is idle, so `skip_idle` may jump there.
    pub fn next_due_ms(&self) -> Option<u64> {
        let mut due: Vec<u64> = Vec::new();
        due.extend(self.down_until);
        due.extend(self.crashes.first().map(|c| c.0));
        due.extend(self.crashes_after_journal.first().map(|c| c.0));
        due.extend(self.election_due_ms());
        due.extend(self.fates.first().map(|f| f.0));
        due.extend(self.inputs.first().map(|i| i.0));
        due.extend(self.commands.first().map(|c| c.0));
        due.extend(self.forged.first().map(|f| f.0));
        due.extend(self.net.iter().map(|(t, _)| *t));
        if self.down_until.is_none() {
            due.extend(self.coordinator.core().next_cycle_ms(self.last_cycle_ms));
        }
        for a in self.agents.iter().filter(|a| a.alive) {
            due.extend(a.run.poll_timeout());
            due.extend(a.skills.values().flatten().map(|(t, _, _)| *t));
            if let Some(cut) = a.cut_at {
                if !a.fenced {
                    due.push(cut + crate::limits::fence_after_ms(LEASE_MS));
                }
                if !a.lost {
                    due.push(cut + LEASE_MS);
                }
            }
        }
        due.into_iter().min()
    }

    /// Jumps over idle time: to the next moment anything is due, at most `limit_ms`. Nothing happens in the
    /// time skipped, exactly as nothing would happen ticking through it.
    pub fn skip_idle(&mut self, limit_ms: u64) {
        let next = self.next_due_ms().unwrap_or(limit_ms).min(limit_ms);
        if next > self.now_ms {
            self.now_ms = next;
        }
    }

    /// Cut agents: each fences itself once it has not heard its router for `fence_after_ms`, and the coordinator
    /// hears it is gone when its lease runs out.
    fn leases(&mut self) {
        let now = self.now_ms;
        for i in 0..self.agents.len() {
            let Some(cut) = self.agents[i].cut_at else { continue };
            if !self.agents[i].fenced && now >= cut + crate::limits::fence_after_ms(LEASE_MS) {
                self.agents[i].fenced = true;
                self.agents[i].run.handle_contact(now, Some(now - cut));
                self.flush_agent(i);
            }
            if !self.agents[i].lost && now >= cut + LEASE_MS {
                self.agents[i].lost = true;
                if self.down_until.is_none() {
                    let name = self.agents[i].name.clone();
                    self.coordinator.agent_down(now, &name);
                    self.flush_coordinator();
                }
            }
        }
    }

    /// No engine, the coordinator's or an agent's, ever gives a step a second token.
    fn watch_engines(&mut self) {
        if !self.violations.is_empty() {
            return;
        }
        let now = self.now_ms;
        if self.coordinator.core().collisions() > 0 {
            self.violations.push(format!("at {now} ms the coordinator's engine gave a step a second token"));
        }
        for a in &self.agents {
            if a.run.collisions() > 0 {
                self.violations.push(format!("at {now} ms the engine of `{}` gave a step a second token", a.name));
            }
        }
    }

    /// The coordinator's cycles that are due, at their grid times, as `baton run` runs them.
    fn due_cycles(&mut self) {
        while let Some(at) = self.coordinator.core().next_cycle_ms(self.last_cycle_ms) {
            if at > self.now_ms {
                return;
            }
            self.last_cycle_ms = Some(at);
            self.coordinator.cycle(at);
            self.flush_coordinator();
        }
    }

    /// A run left alone for long enough (every input set, every link healed) has settled: every token the
    /// coordinator counts as out is held by its agent in the same epoch with every report acknowledged, or is
    /// explicitly held (paused, with an alarm) or waiting for an agent; and no agent holds a token the
    /// coordinator does not count as its own. Anything else is a token stuck between them.
    pub fn settled(&self) -> Result<(), String> {
        let status = self.coordinator.core().status();
        let alarms = self.trace.iter().any(|r| r.event == TraceEvent::Alarm);
        for t in &status.tokens {
            let Some(name) = &t.agent else { continue };
            if t.paused {
                if !alarms {
                    return Err(format!("token {} of `{}` is held with no alarm", t.token, t.entry));
                }
                continue;
            }
            let a = self.agents.iter().find(|a| &a.name == name).ok_or(format!("token at unknown agent `{name}`"))?;
            let held = a.run.held().iter().any(|h| h.token == t.token && h.epoch == t.epoch);
            // A dispatch lost on the way is sent again after 0.5, 1.5, 3.5 and 7.5 s: one younger may be on its way.
            let young = self.now_ms.saturating_sub(t.since_ms) < 8_000;
            if !(young || a.alive && a.reachable && held) {
                return Err(format!(
                    "token {} of `{}` epoch {} is out at `{name}`, which does not hold it (alive {}, reachable {})",
                    t.token, t.entry, t.epoch, a.alive, a.reachable
                ));
            }
        }
        for a in self.agents.iter().filter(|a| a.alive) {
            for h in a.run.held() {
                // A token that came back is held until its acknowledgement arrives (which the check below bounds).
                let known = status.tokens.iter().any(|t| t.token == h.token && t.epoch == h.epoch)
                    || self.coordinator.core().finished_epoch(h.token) == Some(h.epoch);
                if !known {
                    return Err(format!(
                        "`{}` holds token {} epoch {}, which the coordinator does not",
                        a.name, h.token, h.epoch
                    ));
                }
            }
            // A report is sent again until acknowledged, at most 5 s apart: one still waiting after 11 s is stuck.
            let oldest = a.run.oldest_unacked_ms().filter(|&t| a.reachable && self.now_ms.saturating_sub(t) > 11_000);
            if let Some(t) = oldest {
                return Err(format!("`{}` has a report sent at {t} ms and never acknowledged", a.name));
            }
        }
        Ok(())
    }

    /// A variable's value on the coordinator, by name.
    pub fn value(&self, name: &str) -> Option<crate::types::Value> {
        let var = self.coordinator.core().program().var_by_name(name)?;
        Some(self.coordinator.core().value(var))
    }

    /// A variable's value on the coordinator as its type shows it (see `reference::final_shown`).
    pub fn shown(&self, name: &str) -> Option<String> {
        let program = self.coordinator.core().program();
        let var = program.var_by_name(name)?;
        Some(program.vars[var.index()].ty.show(&self.coordinator.core().value(var)))
    }

    /// The trace's records of one kind, as (t_ms, name, agent).
    pub fn events(&self, event: TraceEvent) -> Vec<(u64, String, Option<String>)> {
        self.trace.iter().filter(|r| r.event == event).map(|r| (r.t_ms, r.name.clone(), r.agent.clone())).collect()
    }
}
