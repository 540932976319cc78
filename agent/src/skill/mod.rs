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

pub use builtin::{ShellCommand, SimulatedMotion};

use std::collections::{BTreeMap, HashMap};
use std::future::Future;
use std::pin::Pin;
use std::sync::Arc;
use std::time::Duration;

use baton_proto::front::literal::FieldPath;
use baton_proto::front::pragma::Param;
use baton_proto::types::Value;
use tokio::sync::{mpsc, watch};

/// One start of a skill.
#[derive(Clone, Debug)]
pub struct SkillCall {
    /// The agent's name.
    pub agent: String,
    /// The chart's action that started the skill.
    pub action: String,
    /// The binding pragma's keys other than `skill`, lowercased.
    pub params: BTreeMap<String, Param>,
    /// The binding's mappings, by index: which parameter maps it (`result`, `feedback`…) and the part of the
    /// answer it takes. Write a part with `ctx.write(index, value)`.
    pub outputs: Vec<(String, FieldPath)>,
    /// The agent's Zenoh session, through which skills reach devices that speak Zenoh (ROS 2 over rmw_zenoh).
    pub session: zenoh::Session,
    pub ctx: SkillContext,
}

/// A running skill's line to the agent: where it writes parts of its answer, and how it hears that its action
/// ended.
#[derive(Clone, Debug)]
pub struct SkillContext {
    writes: mpsc::UnboundedSender<(usize, Value)>,
    stop: watch::Receiver<bool>,
}

impl SkillContext {
    /// A context and the agent's ends of it: the writes it receives, and the switch that stops the skill.
    pub fn new() -> (SkillContext, mpsc::UnboundedReceiver<(usize, Value)>, watch::Sender<bool>) {
        let (writes, written) = mpsc::unbounded_channel();
        let (stop_tx, stop) = watch::channel(false);
        (SkillContext { writes, stop }, written, stop_tx)
    }

    /// Writes a part of the answer to the variable that mapping `output` names (converted to its type). Writes
    /// made before the future ends are applied before its result.
    pub fn write(&self, output: usize, value: Value) {
        let _ = self.writes.send((output, value));
    }

    /// Whether the action's Q fell.
    pub fn is_stopped(&self) -> bool {
        *self.stop.borrow()
    }

    /// Completes when the action's Q falls (never, if it does not).
    pub async fn stopped(&self) {
        let mut stop = self.stop.clone();
        if stop.wait_for(|s| *s).await.is_err() {
            std::future::pending::<()>().await;
        }
    }
}

/// The mappings of one parameter (`result`, `feedback`…): each output's index and path.
pub fn outputs_of<'a>(
    outputs: &'a [(String, FieldPath)],
    key: &'a str,
) -> impl Iterator<Item = (usize, &'a FieldPath)> + 'a {
    outputs.iter().enumerate().filter(move |(_, (k, _))| k == key).map(|(i, (_, p))| (i, p))
}

impl SkillCall {
    pub fn number(&self, key: &str) -> Option<f64> {
        self.params.get(key).and_then(Param::as_f64)
    }

    pub fn text(&self, key: &str) -> Option<&str> {
        self.params.get(key).and_then(Param::as_str)
    }
}

/// The skill's outcome: `Err` carries a message for the trace and the log.
pub type SkillFuture = Pin<Box<dyn Future<Output = Result<(), String>> + Send>>;

pub trait Skill: Send + Sync {
    /// Starts the skill. Unless `stops_itself`, dropping the future cancels it.
    fn start(&self, call: SkillCall) -> SkillFuture;

    /// Whether the skill, told that its action ended (`SkillContext::stopped`), ends by itself — after
    /// cancelling a goal on its server, say — rather than being dropped. Its future's result then says whether
    /// the stop went well; the agent logs it (the chart has moved on). The agent drops it anyway after
    /// `STOP_WAIT_MAX`.
    fn stops_itself(&self) -> bool {
        false
    }

    /// What the skill would refuse in these parameters, said when the agent joins a run rather than when the
    /// action starts (a type the agent does not know, a goal that does not fit it).
    fn check(&self, params: &BTreeMap<String, Param>) -> Result<(), String> {
        let _ = params;
        Ok(())
    }
}

/// How long the agent waits for a skill that stops itself before it drops it.
pub const STOP_WAIT_MAX: Duration = Duration::from_secs(30);

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
