//! The skills every agent has: `motion` (a simulated motion, for trying charts out) and `shell` (a command,
//! opt-in with `--allow-shell`).

use std::time::Duration;

use super::call::{Skill, SkillCall, SkillFuture};

/// A uniform random number in [0, 1), from the operating system's generator (through `uuid`).
fn uniform() -> f64 {
    (uuid::Uuid::new_v4().as_u128() >> 75) as f64 / (1u64 << 53) as f64
}

/// `{skill := 'motion', ms := 800, fault_rate := 0.1}`: takes `ms` milliseconds (default 500; 0 ends at the agent's
/// next turn), then fails with probability `fault_rate` (default 0).
pub struct SimulatedMotion;

impl Skill for SimulatedMotion {
    fn start(&self, call: SkillCall) -> SkillFuture {
        let ms = call.number("ms").unwrap_or(500.0).clamp(0.0, 86_400_000.0) as u64;
        let fault_rate = call.number("fault_rate").unwrap_or(0.0);
        Box::pin(async move {
            if ms > 0 {
                tokio::time::sleep(Duration::from_millis(ms)).await;
            } else {
                // Tokio's timers tick in milliseconds: a sleep of 0 ms would last until the next tick (about 1 ms),
                // and a motion of 0 ms (`baton bench`'s demo chart) would measure the timer wheel, not the chart.
                tokio::task::yield_now().await;
            }
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
    use crate::skill::SkillContext;
    use baton_proto::front::pragma::Param;
    use baton_proto::types::Value;

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
