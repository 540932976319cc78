//! Safety and reachability of a chart's net, with every transition condition taken as free (possibly TRUE).
//!
//! Two passes. The structural pass gives every step the *thread* that can hold its token: each initial step
//! starts a thread, a simultaneous divergence starts one child thread per branch, and a convergence that joins
//! exactly the children of one divergence hands the token back to their parent. When every step gets exactly
//! one thread and every convergence joins a complete set of sibling threads, each thread holds at most one
//! token at any time, so the chart is safe, and a step is reachable exactly when it got a thread. This is
//! linear in the size of the chart. Anything that does not fit this shape (a branch left through a selection,
//! a convergence of mutually exclusive steps, initial steps that meet) is settled by the exhaustive pass,
//! which explores the reachable situations (sets of active steps) up to `ANALYSIS_SITUATIONS_MAX`.
//!
//! Safety and reachability with conditions taken as free. A linear structural pass (threads of tokens
//! through simultaneous divergences and convergences) decides structured charts; anything else goes to an exhaustive
//! exploration of reachable situations, bounded by `ANALYSIS_SITUATIONS_MAX`.
#![allow(
    clippy::disallowed_types,
    reason = "the explored situations are looked up, never iterated: the exploration order is the queue's"
)]

use std::collections::{HashMap, HashSet, VecDeque};
use std::ops::ControlFlow;

use crate::exec::program::{Program, StepId, TransitionId};
use crate::limits::ANALYSIS_SITUATIONS_MAX;

#[derive(Clone, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Finding {
    /// `transition` can clear while `step`, one of its targets but not one of its sources, is active.
    Unsafe {
        transition: TransitionId,
        step: StepId,
    },
    /// A convergence whose source steps are each reachable but never all active at once.
    DeadConvergence {
        transition: TransitionId,
    },
    UnreachableStep {
        step: StepId,
    },
    /// The exhaustive pass stopped after this many situations; unreachability was not judged.
    Incomplete {
        situations: usize,
    },
}

pub fn analyse(program: &Program) -> Vec<Finding> {
    match structural(program) {
        Some(threads) => threads
            .iter()
            .enumerate()
            .filter(|(_, t)| t.is_none())
            .map(|(i, _)| Finding::UnreachableStep { step: StepId(i as u32) })
            .collect(),
        None => exhaustive(program),
    }
}

#[derive(Clone, Copy, PartialEq, Eq, Hash)]
struct Thread {
    parent: u32,
    divergence: u32,
    branch: u32,
}

const ROOT: u32 = u32::MAX;

/// The thread of every step (None: unreachable), or None when the net does not have the structured shape.
fn structural(program: &Program) -> Option<Vec<Option<u32>>> {
    let mut threads: Vec<Thread> = Vec::new();
    let mut interned: HashMap<Thread, u32> = HashMap::new();
    let mut intern = |t: Thread, threads: &mut Vec<Thread>| {
        *interned.entry(t).or_insert_with(|| {
            threads.push(t);
            threads.len() as u32 - 1
        })
    };
    let mut label: Vec<Option<u32>> = vec![None; program.steps.len()];
    let mut queue: VecDeque<StepId> = VecDeque::new();
    for (n, &s) in program.initial_steps.iter().enumerate() {
        let root = intern(Thread { parent: ROOT, divergence: ROOT, branch: n as u32 }, &mut threads);
        label[s.index()] = Some(root);
        queue.push_back(s);
    }
    // How many of each transition's sources have a thread; it is judged when all have.
    let mut labelled_sources: Vec<u32> = vec![0; program.transitions.len()];
    while let Some(s) = queue.pop_front() {
        for &t in program.outgoing(s) {
            let (sources, targets) = (program.sources(t), program.targets(t));
            labelled_sources[t.index()] += 1;
            if labelled_sources[t.index()] as usize != sources.len() {
                continue;
            }
            let thread =
                if let [only] = sources[..] { label[only.index()]? } else { join(program, sources, &label, &threads)? };
            for (branch, &target) in targets.iter().enumerate() {
                let wanted = if targets.len() == 1 {
                    thread
                } else {
                    intern(Thread { parent: thread, divergence: t.0, branch: branch as u32 }, &mut threads)
                };
                match label[target.index()] {
                    None => {
                        label[target.index()] = Some(wanted);
                        queue.push_back(target);
                    }
                    Some(have) if have == wanted => {}
                    Some(_) => return None,
                }
            }
        }
    }
    Some(label)
}

/// The parent thread of a convergence's sources, when they are exactly the branches of one divergence.
fn join(program: &Program, sources: &[StepId], label: &[Option<u32>], threads: &[Thread]) -> Option<u32> {
    let first = threads[label[sources[0].index()]? as usize];
    if first.parent == ROOT {
        return None;
    }
    let branches = program.targets(TransitionId(first.divergence)).len();
    if sources.len() != branches {
        return None;
    }
    let mut seen = vec![false; branches];
    for s in sources {
        let t = threads[label[s.index()]? as usize];
        if t.parent != first.parent
            || t.divergence != first.divergence
            || std::mem::replace(&mut seen[t.branch as usize], true)
        {
            return None;
        }
    }
    Some(first.parent)
}

/// Explores every reachable situation, firing one transition at a time. `analyse` uses it only where the
/// structural pass cannot decide; it is public so that tests can hold the two passes against each other.
pub fn exhaustive(program: &Program) -> Vec<Finding> {
    let mut findings = Vec::new();
    let mut reached = vec![false; program.steps.len()];
    let mut enabled = vec![false; program.transitions.len()];
    let mut unsafe_pairs: HashSet<(TransitionId, StepId)> = HashSet::new();
    let explored = explore(
        program,
        |situation| {
            for s in situation {
                reached[s.index()] = true;
            }
            ControlFlow::Continue(())
        },
        |t| enabled[t.index()] = true,
        |t, target| {
            unsafe_pairs.insert((t, target));
        },
    );
    findings.extend(unsafe_pairs.into_iter().map(|(transition, step)| Finding::Unsafe { transition, step }));
    match explored {
        Explored::All => {
            for (i, &was_enabled) in enabled.iter().enumerate() {
                let sources = program.sources(TransitionId(i as u32));
                if !was_enabled && sources.len() > 1 && sources.iter().all(|s| reached[s.index()]) {
                    findings.push(Finding::DeadConvergence { transition: TransitionId(i as u32) });
                }
            }
            findings.extend(
                reached
                    .iter()
                    .enumerate()
                    .filter(|(_, r)| !**r)
                    .map(|(i, _)| Finding::UnreachableStep { step: StepId(i as u32) }),
            );
        }
        Explored::Capped { situations } => findings.push(Finding::Incomplete { situations }),
        Explored::Stopped => unreachable!("exhaustive never stops the exploration"),
    }
    findings.sort();
    findings
}

/// Whether `situation` (the set of active steps) is one the chart can reach by itself from its initial steps, with
/// every condition taken as free: a manual change to it keeps the chart's promises (one token per step, whole
/// simultaneous branches, no stranded token). `None` when the exploration stopped at `ANALYSIS_SITUATIONS_MAX`
/// without finding it.
pub fn is_reachable(program: &Program, situation: &[StepId]) -> Option<bool> {
    let mut wanted: Vec<StepId> = situation.to_vec();
    wanted.sort();
    wanted.dedup();
    let found = |here: &[StepId]| if here == wanted { ControlFlow::Break(()) } else { ControlFlow::Continue(()) };
    match explore(program, found, |_| {}, |_, _| {}) {
        Explored::Stopped => Some(true),
        Explored::All => Some(false),
        Explored::Capped { .. } => None,
    }
}

/// How an exploration ended (`explore`).
enum Explored {
    /// Every reachable situation was seen.
    All,
    /// At `ANALYSIS_SITUATIONS_MAX` situations: those queued were seen, no more were queued.
    Capped { situations: usize },
    /// Its `situation` visitor ended it.
    Stopped,
}

/// Breadth first through the situations reachable from the initial steps, every condition taken as free, one
/// transition at a time: `situation` is shown each one as it is taken from the queue (and may end the walk),
/// `enabled` each transition that clears in it, and `second_token` each target a clearing would give a second
/// token (the net is not safe there). The one walk of the chart's situations that `exhaustive` and `is_reachable`
/// share.
fn explore(
    program: &Program,
    mut situation: impl FnMut(&[StepId]) -> ControlFlow<()>,
    mut enabled: impl FnMut(TransitionId),
    mut second_token: impl FnMut(TransitionId, StepId),
) -> Explored {
    let mut initial: Vec<StepId> = program.initial_steps.clone();
    initial.sort();
    let mut seen: HashSet<Vec<StepId>> = HashSet::new();
    let mut queue = VecDeque::new();
    seen.insert(initial.clone());
    queue.push_back(initial);
    let mut capped = false;
    let mut candidates = Vec::new();
    while let Some(here) = queue.pop_front() {
        if situation(&here).is_break() {
            return Explored::Stopped;
        }
        candidates.clear();
        for s in &here {
            candidates.extend_from_slice(program.outgoing(*s));
        }
        candidates.sort();
        candidates.dedup();
        for &t in &candidates {
            let Some(next) = clear(program, &here, t, |target| second_token(t, target)) else { continue };
            enabled(t);
            if seen.len() >= ANALYSIS_SITUATIONS_MAX {
                capped = true;
                continue;
            }
            if seen.insert(next.clone()) {
                queue.push_back(next);
            }
        }
    }
    if capped {
        Explored::Capped { situations: seen.len() }
    } else {
        Explored::All
    }
}

/// The situation (sorted active steps) after `t` clears in `situation`, or `None` if it is not enabled there. A
/// target that is active already is said to `second_token` (the net is not safe there) and stays one entry.
fn clear(
    program: &Program,
    situation: &[StepId],
    t: TransitionId,
    mut second_token: impl FnMut(StepId),
) -> Option<Vec<StepId>> {
    let sources = program.sources(t);
    if !sources.iter().all(|s| situation.binary_search(s).is_ok()) {
        return None;
    }
    let mut next: Vec<StepId> = situation.iter().copied().filter(|s| !sources.contains(s)).collect();
    for &target in program.targets(t) {
        match next.binary_search(&target) {
            Ok(_) => second_token(target),
            Err(at) => next.insert(at, target),
        }
    }
    Some(next)
}
