//! `baton-agent --simulate SCENARIO`: the agent's skills do what a `baton test` scenario says — the same
//! durations, outcome sequences, hangs and written values as in the simulated cell (`testing::run::skill_model`),
//! in real time — so that the real binaries and the real network run a user's scenario too.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use baton_proto::testing::scenario::Scenario;
use baton_proto::testing::simulated_cluster::{Rng, SimSkill, SkillModel, SkillStart, NETWORK_MIX};

use crate::skill::{Skill, SkillCall, SkillFuture, Skills};

/// Every skill of the scenario's chart, simulated.
pub struct Simulated {
    scenario: Arc<Scenario>,
    model: Mutex<(SkillModel, Rng)>,
}

impl Simulated {
    pub fn new(scenario: Scenario, seed: u64) -> Simulated {
        let model = baton_proto::testing::run::skill_model(&scenario);
        Simulated { scenario: Arc::new(scenario), model: Mutex::new((model, Rng::new(seed, NETWORK_MIX))) }
    }

    /// The built-in skills, each name the chart's actions bind replaced by this simulation.
    pub fn skills(self) -> Skills {
        let names: std::collections::BTreeSet<String> =
            self.scenario.layout.skills.iter().flatten().map(|b| b.skill.clone()).collect();
        let shared = Arc::new(self);
        names.into_iter().fold(Skills::builtin(), |skills, name| skills.with(&name, Shared(Arc::clone(&shared))))
    }

    fn decide(&self, call: &SkillCall) -> SimSkill {
        let program = &self.scenario.program;
        let Some(index) = program.actions.iter().position(|a| a.name == call.action) else {
            let path = self.scenario.path.display();
            return SimSkill::Finish {
                after_ms: 0,
                result: Err(format!("action `{}` is not in the chart of {path}", call.action)),
                writes: Vec::new(),
            };
        };
        let Some(binding) = self.scenario.layout.skills[index].as_ref() else {
            return SimSkill::Finish { after_ms: 0, result: Ok(()), writes: Vec::new() };
        };
        let mut guard = self.model.lock().expect("the simulation's lock");
        let (model, rng) = &mut *guard;
        let random = rng.next_u64();
        model(SkillStart { agent: &call.agent, action: &call.action, binding, random })
    }
}

struct Shared(Arc<Simulated>);

impl Skill for Shared {
    fn start(&self, call: SkillCall) -> SkillFuture {
        let decided = self.0.decide(&call);
        Box::pin(async move {
            match decided {
                // Dropped when the action's Q falls: a hang ends only so.
                SimSkill::Hang => std::future::pending().await,
                SimSkill::Finish { after_ms, result, writes } => {
                    tokio::time::sleep(Duration::from_millis(after_ms)).await;
                    for (output, value) in writes {
                        call.ctx.write(output, value);
                    }
                    result
                }
            }
        })
    }
}
