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
//! `Skills::with`; `baton-agent` ships `motion` (a simulated motion), `ros2_action` and `ros2_service` (see
//! `crate::ros2`), `opcua_method` (see `crate::opcua`), and `shell` (a command, opt-in).

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

/// The skills an agent offers, by name, and the protocols they speak — which serve the chart's bound variables
/// too (`crate::io`).
#[derive(Clone, Default)]
pub struct Skills {
    by_name: HashMap<String, Arc<dyn Skill>>,
    ros2: Option<Arc<crate::ros2::Ros2>>,
    opcua: Option<Arc<crate::opcua::OpcUa>>,
}

impl Skills {
    /// `motion` only; `shell` is added by `with_shell`, because it runs whatever command a chart names.
    pub fn builtin() -> Skills {
        Skills::default().with("motion", SimulatedMotion)
    }

    pub fn with_shell(self) -> Skills {
        self.with("shell", ShellCommand)
    }

    /// `ros2_action` and `ros2_service`, speaking rmw_zenoh over the agent's session; and variables bound to
    /// ROS 2 topics.
    pub fn with_ros2(mut self, ros2: Arc<crate::ros2::Ros2>) -> Skills {
        self.ros2 = Some(Arc::clone(&ros2));
        self.with("ros2_action", crate::ros2::skills::Ros2Action { ros2: Arc::clone(&ros2) })
            .with("ros2_service", crate::ros2::skills::Ros2Service { ros2 })
    }

    /// `opcua_method`, with async-opcua's client; and variables bound to OPC UA nodes.
    pub fn with_opcua(mut self, opcua: Arc<crate::opcua::OpcUa>) -> Skills {
        self.opcua = Some(Arc::clone(&opcua));
        self.with("opcua_method", crate::opcua::skills::OpcuaMethod { opcua })
    }

    pub fn ros2(&self) -> Option<&Arc<crate::ros2::Ros2>> {
        self.ros2.as_ref()
    }

    pub fn opcua(&self) -> Option<&Arc<crate::opcua::OpcUa>> {
        self.opcua.as_ref()
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
}

/// A uniform random number in [0, 1), from the operating system's generator (through `uuid`).
fn uniform() -> f64 {
    (uuid::Uuid::new_v4().as_u128() >> 75) as f64 / (1u64 << 53) as f64
}

/// `{skill := 'motion', ms := 800, fault_rate := 0.1}`: takes `ms` milliseconds (default 500), then fails with
/// probability `fault_rate` (default 0).
pub struct SimulatedMotion;

impl Skill for SimulatedMotion {
    fn start(&self, call: SkillCall) -> SkillFuture {
        let ms = call.number("ms").unwrap_or(500.0).clamp(0.0, 86_400_000.0) as u64;
        let fault_rate = call.number("fault_rate").unwrap_or(0.0);
        Box::pin(async move {
            tokio::time::sleep(Duration::from_millis(ms)).await;
            if uniform() < fault_rate {
                Err(format!("simulated fault after {ms} ms (fault_rate {fault_rate})"))
            } else {
                Ok(())
            }
        })
    }
}

/// `{skill := 'shell', cmd := 'gripper close'}`: runs `cmd` with `sh -c`; succeeds on exit status 0. The
/// command is killed if the action ends first.
pub struct ShellCommand;

impl Skill for ShellCommand {
    fn start(&self, call: SkillCall) -> SkillFuture {
        let cmd = call.text("cmd").map(str::to_string);
        let agent = call.agent.clone();
        let action = call.action.clone();
        Box::pin(async move {
            let cmd = cmd.ok_or_else(|| "the shell skill needs `cmd := '…'`".to_string())?;
            let status = tokio::process::Command::new("sh")
                .arg("-c")
                .arg(&cmd)
                .env("BATON_AGENT", agent)
                .env("BATON_ACTION", action)
                .kill_on_drop(true)
                .status()
                .await
                .map_err(|e| format!("cannot run `{cmd}`: {e}"))?;
            if status.success() {
                Ok(())
            } else {
                Err(format!("`{cmd}` ended with {status}"))
            }
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A session on nothing: no scouting, no listener, no router.
    pub(crate) async fn lone_session() -> zenoh::Session {
        let mut config = zenoh::Config::default();
        for (k, v) in [("scouting/multicast/enabled", "false"), ("listen/endpoints", "[]"), ("connect/endpoints", "[]")]
        {
            config.insert_json5(k, v).expect("config");
        }
        zenoh::open(config).await.expect("a lone session")
    }

    async fn call(params: &[(&str, Param)]) -> SkillCall {
        SkillCall {
            agent: "a".into(),
            action: "Act".into(),
            params: params.iter().map(|(k, v)| (k.to_string(), v.clone())).collect(),
            outputs: Vec::new(),
            session: lone_session().await,
            ctx: SkillContext::new().0,
        }
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 1)]
    async fn motion_succeeds_or_faults_as_configured() {
        let ok = SimulatedMotion.start(call(&[("ms", Param::Value(Value::Int(1)))]).await).await;
        assert_eq!(ok, Ok(()));
        let bad = SimulatedMotion
            .start(call(&[("ms", Param::Value(Value::Int(0))), ("fault_rate", Param::Value(Value::Real(1.0)))]).await)
            .await;
        assert!(bad.unwrap_err().contains("simulated fault"));
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 1)]
    async fn shell_reports_the_exit_status() {
        assert_eq!(ShellCommand.start(call(&[("cmd", Param::Str("true".into()))]).await).await, Ok(()));
        let err = ShellCommand.start(call(&[("cmd", Param::Str("exit 3".into()))]).await).await.unwrap_err();
        assert!(err.contains("exit status: 3"), "{err}");
        assert!(ShellCommand.start(call(&[]).await).await.unwrap_err().contains("needs `cmd"));
    }
}
