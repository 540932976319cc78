//! The invariants every distributed run's trace keeps, whatever happened to the network, the agents or the
//! coordinator: shared by the simulations and the cluster tests.

use std::collections::{BTreeMap, HashMap, HashSet};

use baton_proto::exec::program::{Program, TransitionId};
use baton_proto::exec::trace::{TraceEvent, TraceRecord};

/// Checks a trace of a run of `program`:
/// - no step holds two tokens (activations and deactivations of each step alternate);
/// - no token (so no segment) is dispatched twice in one epoch;
/// - no convergence (a transition with several source steps) clears before every source step is active;
/// - a token comes back at most once, in the last epoch it was dispatched in;
/// - with `all_back`, every token that left came back.
pub fn check(trace: &[TraceRecord], program: &Program, all_back: bool) -> Result<(), String> {
    let by_name: HashMap<&str, TransitionId> =
        program.transitions.iter().enumerate().rev().map(|(i, t)| (t.name.as_str(), TransitionId(i as u32))).collect();
    let mut active: HashSet<&str> = HashSet::new();
    let mut dispatched: HashSet<(&str, u32)> = HashSet::new();
    let mut last_epoch: BTreeMap<&str, u32> = BTreeMap::new();
    let mut returned: HashSet<&str> = HashSet::new();
    for r in trace {
        let at = r.t_ms;
        match r.event {
            // `reset`: the chart starts again from its initial steps; the old run's steps are gone with it.
            TraceEvent::NewRun => active.clear(),
            TraceEvent::Activate if !active.insert(&r.name) => {
                return Err(format!("`{}` got a second token at {at} ms", r.name));
            }
            TraceEvent::Deactivate if !active.remove(r.name.as_str()) => {
                return Err(format!("`{}` was deactivated while inactive at {at} ms", r.name));
            }
            TraceEvent::Fire => {
                let Some(&t) = by_name.get(r.name.as_str()) else { continue };
                let sources = program.sources(t);
                if sources.len() > 1 {
                    let missing: Vec<&str> = sources
                        .iter()
                        .map(|s| program.steps[s.index()].name.as_str())
                        .filter(|s| !active.contains(s))
                        .collect();
                    if !missing.is_empty() {
                        return Err(format!(
                            "convergence `{}` cleared at {at} ms before {} arrived",
                            r.name,
                            missing.join(", ")
                        ));
                    }
                }
            }
            TraceEvent::Dispatch => {
                let token = r.token.as_deref().ok_or(format!("dispatch without a token at {at} ms"))?;
                let epoch = r.epoch.unwrap_or(0);
                if !dispatched.insert((token, epoch)) {
                    return Err(format!("token {token} (step `{}`) dispatched twice in epoch {epoch}", r.name));
                }
                last_epoch.insert(token, epoch);
            }
            // An operator's withdrawal accounts for a token as its return does.
            TraceEvent::Return | TraceEvent::Withdraw => {
                let token = r.token.as_deref().ok_or(format!("return without a token at {at} ms"))?;
                let epoch = r.epoch.unwrap_or(0);
                if last_epoch.get(token) != Some(&epoch) {
                    return Err(format!(
                        "token {token} came back in epoch {epoch}, not the last it was dispatched in ({:?})",
                        last_epoch.get(token)
                    ));
                }
                if !returned.insert(token) {
                    return Err(format!("token {token} came back twice"));
                }
            }
            _ => {}
        }
    }
    if all_back {
        let out: Vec<&&str> = last_epoch.keys().filter(|t| !returned.contains(**t)).collect();
        if !out.is_empty() {
            return Err(format!("{} token(s) left and never came back: {out:?}", out.len()));
        }
    }
    Ok(())
}

/// The tokens out at the end of a trace: dispatched and not back.
pub fn tokens_out(trace: &[TraceRecord]) -> usize {
    let left: HashSet<&str> =
        trace.iter().filter(|r| r.event == TraceEvent::Dispatch).filter_map(|r| r.token.as_deref()).collect();
    let back: HashSet<&str> = trace
        .iter()
        .filter(|r| matches!(r.event, TraceEvent::Return | TraceEvent::Withdraw))
        .filter_map(|r| r.token.as_deref())
        .collect();
    left.difference(&back).count()
}
