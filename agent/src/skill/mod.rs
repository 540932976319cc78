//! Skills: what an agent does when one of its actions becomes active.
//!
//! A chart binds an action to a skill with a pragma, `ACTION Pick: {skill := 'motion', ms := 800} END_ACTION`.
//! When the action's Q rises on the agent, the agent starts the skill with the pragma's other keys as
//! parameters; when Q falls before the skill finished, the skill is stopped: its future is dropped, or, for a
//! skill that `stops_itself` (a ROS 2 goal must be cancelled on the server), it is told through
//! `SkillContext::stopped` and ends on its own. The result reaches the chart through the association's
//! indicator variables: `Pick(N, done, fault)` sets `done` when the skill succeeds and `fault` when it fails
//! (both are reset when the skill starts); parts of the answer reach chart variables through the binding's
//! mappings (`result := 'sequence[4] => last'`), written with `SkillContext::write`.
//!
//! Users who embed the agent in their own robot program implement `Skill` and register it with
//! `Skills::with`; `baton-agent` ships `motion` (a simulated motion) and `shell` (a command, opt-in) in
//! `builtin`, and, given `crate::Connections`, `ros2_action` and `ros2_service` (see `crate::ros2`) and
//! `opcua_method` (see `crate::opcua`).

mod builtin;
mod call;

use std::collections::HashMap;
use std::sync::Arc;

pub use builtin::{ShellCommand, SimulatedMotion};
pub use call::{outputs_of, Skill, SkillCall, SkillContext, SkillFuture, STOP_WAIT_MAX};

/// The skills an agent offers, by name. The protocols some of them speak are `crate::Connections`, which the
/// chart's bound variables use too.
#[derive(Clone, Default)]
pub struct Skills {
    by_name: HashMap<String, Arc<dyn Skill>>,
}

impl Skills {
    /// `motion` only; `shell` is added by `with_shell`, because it runs whatever command a chart names.
    pub fn builtin() -> Skills {
        Skills::default().with("motion", SimulatedMotion)
    }

    pub fn with_shell(self) -> Skills {
        self.with("shell", ShellCommand)
    }

    pub fn with(mut self, name: &str, skill: impl Skill + 'static) -> Skills {
        self.by_name.insert(name.to_string(), Arc::new(skill));
        self
    }

    pub fn get(&self, name: &str) -> Option<Arc<dyn Skill>> {
        self.by_name.get(name).cloned()
    }

    pub fn names(&self) -> Vec<String> {
        let mut names: Vec<String> = self.by_name.keys().cloned().collect();
        names.sort();
        names
    }

    /// What `baton-agent --list-skills` prints and `baton check --skills` reads: each skill by name, with the
    /// parameters of a built-in one (`cluster::skills::Catalogue::builtin`); a custom skill's are left open.
    pub fn catalogue(&self) -> baton_proto::cluster::skills::Catalogue {
        baton_proto::cluster::skills::Catalogue::of_names(self.names())
    }
}
