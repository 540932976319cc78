//! Every Zenoh key expression Baton uses, built here and nowhere else.
//!
//! ```text
//! baton/alive/<agent>                 liveliness token of a live agent
//! baton/agent/<agent>/info            queryable: the agent's roles, lease and held tokens (AgentInfo)
//! baton/agent/<agent>/why             queryable: why its active steps wait (WhyReport per run)
//! baton/agent/<agent>/<incarnation>/cmd  coordinator → one process of the agent: Dispatch, Ack, Drop, Sync, Join
//!                                     (ToAgent); a second process of the same name hears none of it
//! baton/run/<run>/report              agents → coordinator: token reports (Report)
//! baton/run/<run>/vars/<writer>       variable updates from the coordinator or an agent (VarUpdate)
//! baton/run/<run>/devices/<agent>    agent → coordinator: the bound devices it cannot reach (DeviceReport)
//! baton/run/<run>/chart               queryable: the chart's source (ChartSource)
//! baton/run/<run>/status              queryable: active steps, tokens, agents (StatusReport)
//! baton/run/<run>/set                 queryable: set an input (SetRequest → SetReply)
//! baton/run/<run>/ctl                 queryable: an operator's command (CtlRequest → CtlReply)
//! ```
//! Agent names and roles are restricted to letters, digits, `_` and `-` (`is_valid_name`), so they are
//! always single chunks; a run is 32 hex digits.
//!
//! Every Zenoh key expression of Baton's own is built here (rmw_zenoh's are in `agent/src/ros2/rmw_keys.rs`).

use crate::dist::wire::RunId;
use uuid::Uuid;

/// Agent names and roles become key-expression chunks: keep them to letters, digits, `_` and `-`.
pub fn is_valid_name(name: &str) -> bool {
    !name.is_empty() && name.len() <= 64 && name.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-')
}

const ROOT: &str = "baton";

/// A key a chart binds a variable to (`cell1/door/closed`): chunks of letters, digits and `-_.` between `/`,
/// and, where `wildcards` (an input's subscription), `*` or `**` as whole chunks. Never under `baton/`, which
/// is Baton's own.
pub fn is_key_expr(key: &str, wildcards: bool) -> bool {
    let chunk_ok = |c: &str| {
        (wildcards && (c == "*" || c == "**"))
            || (!c.is_empty() && c.chars().all(|ch| ch.is_ascii_alphanumeric() || "-_.".contains(ch)))
    };
    key.len() <= 256 && !key.split('/').next().is_some_and(|c| c == ROOT || c == "**") && key.split('/').all(chunk_ok)
}

pub fn alive(agent: &str) -> String {
    format!("{ROOT}/alive/{agent}")
}

pub fn alive_any() -> String {
    format!("{ROOT}/alive/*")
}

/// The agent named by a liveliness key, if it is one of ours.
pub fn agent_of_alive(key: &str) -> Option<&str> {
    key.strip_prefix(ROOT)?.strip_prefix("/alive/").filter(|rest| !rest.is_empty() && !rest.contains('/'))
}

pub fn agent_info(agent: &str) -> String {
    format!("{ROOT}/agent/{agent}/info")
}

/// Queryable: why the agent's active steps wait (`WhyReport`, one per run it takes part in).
pub fn agent_why(agent: &str) -> String {
    format!("{ROOT}/agent/{agent}/why")
}

pub fn agent_cmd(agent: &str, incarnation: Uuid) -> String {
    format!("{ROOT}/agent/{agent}/{}/cmd", incarnation.simple())
}

/// The commands to every process of `agent` (`*` for every agent), for tools that watch.
pub fn agent_cmd_any(agent: &str) -> String {
    format!("{ROOT}/agent/{agent}/*/cmd")
}

/// An agent's reports to the run: the key names the agent, so that a router's access control can let each agent
/// publish only its own (`sender`).
pub fn report(run: RunId, agent: &str) -> String {
    format!("{ROOT}/run/{}/report/{agent}", run.key())
}

/// Every agent's reports to the run: what its coordinator subscribes to.
pub fn report_any(run: RunId) -> String {
    report(run, "*")
}

/// Who a run's report, variable update or device report claims to come from, as its key names it
/// (`baton/run/<run>/report/<agent>`, `…/vars/<writer>`, `…/devices/<agent>`).
pub fn sender(key: &str) -> Option<&str> {
    let rest = key.strip_prefix(ROOT)?.strip_prefix("/run/")?;
    let (_, rest) = rest.split_once('/')?;
    let (kind, name) = rest.split_once('/')?;
    (matches!(kind, "report" | "vars" | "devices") && !name.is_empty() && !name.contains('/')).then_some(name)
}

pub fn vars(run: RunId, writer: &str) -> String {
    format!("{ROOT}/run/{}/vars/{writer}", run.key())
}

/// The writer a variable update's key names (`baton/run/<run>/vars/<writer>`).
pub fn writer_of_vars(key: &str) -> Option<&str> {
    let rest = key.strip_prefix(ROOT)?.strip_prefix("/run/")?;
    let (_, writer) = rest.split_once("/vars/")?;
    (!writer.is_empty() && !writer.contains('/')).then_some(writer)
}

/// Variable updates of every run: an agent listens to all runs it takes part in.
pub fn vars_any_run() -> String {
    format!("{ROOT}/run/*/vars/*")
}

pub fn devices(run: RunId, agent: &str) -> String {
    format!("{ROOT}/run/{}/devices/{agent}", run.key())
}

pub fn chart(run: RunId) -> String {
    format!("{ROOT}/run/{}/chart", run.key())
}

pub fn status(run: RunId) -> String {
    format!("{ROOT}/run/{}/status", run.key())
}

pub fn status_any_run() -> String {
    format!("{ROOT}/run/*/status")
}

pub fn set(run: RunId) -> String {
    format!("{ROOT}/run/{}/set", run.key())
}

pub fn set_any_run() -> String {
    format!("{ROOT}/run/*/set")
}

/// Queryable: an operator's command to the run (`CtlRequest` → `CtlReply`).
pub fn ctl(run: RunId) -> String {
    format!("{ROOT}/run/{}/ctl", run.key())
}

pub fn ctl_any_run() -> String {
    format!("{ROOT}/run/*/ctl")
}

/// Everything under Baton's root, for tools that watch or test the whole protocol.
pub fn everything() -> String {
    format!("{ROOT}/**")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn liveliness_keys_name_their_agent() {
        assert_eq!(agent_of_alive(&alive("r1")), Some("r1"));
        assert_eq!(agent_of_alive("baton/alive/"), None);
        assert_eq!(agent_of_alive("baton/alive/a/b"), None);
        assert_eq!(agent_of_alive("other/alive/a"), None);
    }

    #[test]
    fn variable_keys_name_their_writer() {
        let run = RunId(Uuid::from_u128(3));
        assert_eq!(writer_of_vars(&vars(run, "r1")), Some("r1"));
        assert_eq!(sender(&vars(run, "r1")), Some("r1"));
        assert_eq!(sender(&report(run, "r2")), Some("r2"));
        assert_eq!(sender(&devices(run, "cell1")), Some("cell1"));
        assert_eq!(sender(&chart(run)), None);
        assert_eq!(sender(&format!("{}/x", report(run, "r2"))), None);
        assert_eq!(sender("baton/run/x/ctl/r1"), None);
        assert_eq!(writer_of_vars("baton/run/x/vars/"), None);
        assert_eq!(writer_of_vars("baton/run/x/vars/a/b"), None);
    }
}
