//! What scenarios exercised of a chart: the steps activated, the transitions fired, the alternatives taken at
//! each selection divergence (a step with several ways out), and which steps each fault struck — per scenario
//! and over all the scenarios of one chart.

use std::collections::{BTreeMap, BTreeSet};

use super::run::{follow_steps, Outcome};
use crate::exec::program::{Program, StepId};
use crate::exec::trace::TraceEvent;

#[derive(Clone, Debug, Default)]
pub struct Coverage {
    pub steps: BTreeSet<usize>,
    pub transitions: BTreeSet<usize>,
    /// Each fault as it struck, and the steps active then (with where they ran).
    pub fault_hits: BTreeSet<(String, String)>,
}

impl Coverage {
    /// What one run exercised.
    pub fn of(program: &Program, o: &Outcome) -> Coverage {
        let step = |name: &str| program.steps.iter().position(|s| s.name == name);
        let mut c = Coverage::default();
        for r in &o.trace {
            match r.event {
                TraceEvent::Activate => c.steps.extend(step(&r.name)),
                TraceEvent::Fire => c.transitions.extend(program.transitions.iter().position(|t| t.name == r.name)),
                _ => {}
            }
        }
        for (t, fault) in &o.faults {
            // The steps active just before the fault struck.
            let mut active: BTreeMap<usize, Option<String>> = BTreeMap::new();
            for r in o.trace.iter().take_while(|r| r.t_ms < *t) {
                if let Some(i) = step(&r.name) {
                    follow_steps(&mut active, i, r);
                }
            }
            for (i, agent) in active {
                let at = agent.map_or(String::new(), |a| format!(" on {a}"));
                c.fault_hits.insert((fault.clone(), format!("{}{at}", program.steps[i].name)));
            }
        }
        c
    }

    pub fn add(&mut self, other: &Coverage) {
        self.steps.extend(other.steps.iter().copied());
        self.transitions.extend(other.transitions.iter().copied());
        self.fault_hits.extend(other.fault_hits.iter().cloned());
    }

    /// `steps 9/11, transitions 8/11, branches 3/4`, then what was never exercised.
    pub fn summary(&self, program: &Program) -> String {
        let divergences = divergences(program);
        let branches: usize = divergences.iter().map(|(_, ts)| ts.len()).sum();
        let taken: usize =
            divergences.iter().map(|(_, ts)| ts.iter().filter(|t| self.transitions.contains(t)).count()).sum();
        let mut s = format!(
            "steps {}/{}, transitions {}/{}, branches {taken}/{branches}",
            self.steps.len(),
            program.steps.len(),
            self.transitions.len(),
            program.transitions.len()
        );
        let never_steps: Vec<&str> = (0..program.steps.len())
            .filter(|i| !self.steps.contains(i))
            .map(|i| program.steps[i].name.as_str())
            .collect();
        let never_fired: Vec<&str> = (0..program.transitions.len())
            .filter(|i| !self.transitions.contains(i))
            .map(|i| program.transitions[i].name.as_str())
            .collect();
        if !never_steps.is_empty() {
            s.push_str(&format!("; never active: {}", never_steps.join(", ")));
        }
        if !never_fired.is_empty() {
            s.push_str(&format!("; never fired: {}", never_fired.join(", ")));
        }
        s
    }
}

/// The selection divergences: each step with several ways out, and those ways (transition indices).
pub fn divergences(program: &Program) -> Vec<(usize, Vec<usize>)> {
    (0..program.steps.len())
        .map(|s| (s, program.outgoing(StepId(s as u32)).iter().map(|t| t.index()).collect::<Vec<usize>>()))
        .filter(|(_, ts)| ts.len() > 1)
        .collect()
}
