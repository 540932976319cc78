//! What a skill is (`Skill`) and what it is given: one start's `SkillCall` and `SkillContext`.

use std::collections::BTreeMap;
use std::future::Future;
use std::pin::Pin;
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
