//! Every Zenoh key expression Baton uses, built here and nowhere else.
//!
//! ```text
//! baton/alive/<agent>                 liveliness token of a live agent
//! baton/alive/<agent>/role/<role>     liveliness token: a role the agent serves (a router's access control lets
//!                                     each agent announce only the roles its deployment gives it)
//! baton/agent/<agent>/info            queryable: the agent's roles, lease and held tokens (AgentInfo)
//! baton/agent/<agent>/why             queryable: why its active steps wait (WhyReport per run)
//! baton/agent/<agent>/<incarnation>/cmd  coordinator → one process of the agent: Dispatch, Ack, Drop, Sync, Join
//!                                     (ToAgent); a second process of the same name hears none of it
//! baton/run/<run>/report              agents → coordinator: token reports (Report)
//! baton/run/<run>/vars/<writer>       variable updates from the coordinator or an agent (VarUpdate)
//! baton/run/<run>/devices/<agent>    agent → coordinator: the bound devices it cannot reach (DeviceReport)
//! baton/run/<run>/chart               queryable: the chart's source (ChartSource)
//! baton/run/<run>/status              queryable: active steps, tokens, agents (StatusReport)
//! baton/run/<run>/set/<sender>        queryable: set an input (SetRequest → SetReply)
//! baton/run/<run>/ctl/<sender>        queryable: an operator's command (CtlRequest → CtlReply)
//! ```
//! Agent names and roles are restricted to letters, digits, `_` and `-` (`is_valid_name`), so they are
//! always single chunks; a run is 32 hex digits. A `set` or `ctl` names who sends it (`is_valid_sender`): the
//! coordinator records that name as who asked, and a router's access control lets each operator ask only on its
//! own — so the name recorded is the one the router checked.
//!
//! Every Zenoh key expression of Baton's own is built here (rmw_zenoh's are in `agent/src/ros2/rmw_keys.rs`).

use crate::cluster::wire::RunId;
use uuid::Uuid;

/// Agent names and roles become key-expression chunks: keep them to letters, digits, `_` and `-`.
pub fn is_valid_name(name: &str) -> bool {
    !name.is_empty() && name.len() <= 64 && name.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-')
}

/// Who sends a `set` or `ctl` (an operator's Zenoh identity, `user@host`, `baton test`): one key chunk of at most
/// 128 bytes, with no control character, none of `/*$#?"\`, no space at either end, and not starting with `@` (a
/// Zenoh chunk that starts with it matches no wildcard).
pub fn is_valid_sender(name: &str) -> bool {
    !name.is_empty()
        && name.len() <= 128
        && !name.starts_with(['@', ' '])
        && !name.ends_with(' ')
        && name.chars().all(sender_char)
}

fn sender_char(c: char) -> bool {
    !c.is_control() && !"/*$#?\"\\".contains(c)
}

/// `name` made a sender's name: each character it cannot hold becomes `_`.
pub fn sender_name(name: &str) -> String {
    let mut out = String::new();
    for c in name.trim().chars().map(|c| if sender_char(c) { c } else { '_' }) {
        if out.len() + c.len_utf8() > 128 {
            break;
        }
        out.push(c);
    }
    if out.is_empty() || out.starts_with('@') {
        out.insert(0, '_');
        while out.len() > 128 {
            out.pop();
        }
    }
    out
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

/// The liveliness token of a role an agent serves.
pub fn alive_role(agent: &str, role: &str) -> String {
    format!("{ROOT}/alive/{agent}/role/{role}")
}

/// Every role token of `agent`.
pub fn alive_roles(agent: &str) -> String {
    alive_role(agent, "*")
}

/// The role a role token announces, if the key is one of `agent`'s.
pub fn role_of_alive<'k>(key: &'k str, agent: &str) -> Option<&'k str> {
    let role = key.strip_prefix(&alive_role(agent, ""))?;
    (!role.is_empty() && !role.contains('/')).then_some(role)
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

/// The run's trace records, live, as the coordinator makes them (for consoles; dropped rather than waited for).
pub fn trace(run: RunId) -> String {
    format!("{ROOT}/run/{}/trace", run.key())
}

pub fn trace_any_run() -> String {
    format!("{ROOT}/run/*/trace")
}

/// The run of a `trace` key (`baton/run/<run>/trace`), by its key as `RunId::key` writes it.
pub fn run_of_trace(key: &str) -> Option<&str> {
    key.strip_prefix(ROOT)?.strip_prefix("/run/")?.strip_suffix("/trace").filter(|r| !r.contains('/'))
}

/// The run's history — commands, state and mode changes, alarms, agents lost and back — as far back as the
/// coordinator keeps it: a queryable of the coordinator, for a console that joins a run under way.
pub fn history(run: RunId) -> String {
    format!("{ROOT}/run/{}/history", run.key())
}

pub fn status(run: RunId) -> String {
    format!("{ROOT}/run/{}/status", run.key())
}

pub fn status_any_run() -> String {
    format!("{ROOT}/run/*/status")
}

/// `baton set` of `sender` to the run; `set(run, "*")` is the coordinator's queryable.
pub fn set(run: RunId, sender: &str) -> String {
    format!("{ROOT}/run/{}/set/{sender}", run.key())
}

pub fn set_any_run(sender: &str) -> String {
    format!("{ROOT}/run/*/set/{sender}")
}

/// An operator's command to the run (`CtlRequest` → `CtlReply`), sent by `sender`; `ctl(run, "*")` is the
/// coordinator's queryable.
pub fn ctl(run: RunId, sender: &str) -> String {
    format!("{ROOT}/run/{}/ctl/{sender}", run.key())
}

pub fn ctl_any_run(sender: &str) -> String {
    format!("{ROOT}/run/*/ctl/{sender}")
}

/// Who a request is recorded as sent by: the `sender` its key names (which a router's access control checked),
/// and, for a console, the person it was sent for — `anna via console`. The person's name is the console's word,
/// and the record says whose word it is.
pub fn by_whom(sender: &str, user: Option<&str>) -> String {
    match user.filter(|u| !u.trim().is_empty()).map(sender_name) {
        Some(user) if !user.is_empty() => format!("{user} via {sender}"),
        _ => sender.to_string(),
    }
}

/// Who a `set` or `ctl` query's key says sent it (`baton/run/<run>/set/<sender>`, `…/ctl/<sender>`).
pub fn sender_of_request(key: &str) -> Option<&str> {
    let rest = key.strip_prefix(ROOT)?.strip_prefix("/run/")?;
    let (_, rest) = rest.split_once('/')?;
    let (kind, name) = rest.split_once('/')?;
    (matches!(kind, "set" | "ctl") && is_valid_sender(name)).then_some(name)
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
    fn a_console_request_is_recorded_as_its_user_via_the_sender() {
        assert_eq!(by_whom("console", Some("anna")), "anna via console");
        assert_eq!(by_whom("console", None), "console");
        assert_eq!(by_whom("console", Some("")), "console");
        // A user's name cannot pose as another sender's: it is made a sender's name first.
        assert_eq!(by_whom("console", Some("x/y*")), "x_y_ via console");
    }

    #[test]
    fn trace_keys_name_their_run() {
        let run = RunId(Uuid::from_u128(7));
        assert_eq!(run_of_trace(&trace(run)), Some(run.key().as_str()));
        assert_eq!(run_of_trace(&status(run)), None);
        assert_eq!(run_of_trace("baton/run/a/b/trace"), None);
        assert_eq!(run_of_trace("other/run/a/trace"), None);
    }

    #[test]
    fn requests_name_their_sender_and_roles_their_agent() {
        let run = RunId(Uuid::from_u128(3));
        assert_eq!(sender_of_request(&ctl(run, "anna")), Some("anna"));
        assert_eq!(sender_of_request(&set(run, "op@host-1.cell")), Some("op@host-1.cell"));
        assert_eq!(sender_of_request(&ctl(run, "*")), None);
        assert_eq!(sender_of_request(&format!("{}/x", ctl(run, "anna"))), None);
        assert_eq!(sender_of_request(&status(run)), None);
        for bad in ["", "@anna", " anna", "a*", "a/b", "a$b", "a#", "a?", "a\nb", &"x".repeat(129), &"é".repeat(65)] {
            assert!(!is_valid_sender(bad), "{bad:?}");
            assert!(is_valid_sender(&sender_name(bad)), "{bad:?} made {:?}", sender_name(bad));
        }
        for good in ["anna", "baton test", "jo smith@plc-room.cell4", "Zoë"] {
            assert!(is_valid_sender(good), "{good:?}");
            assert_eq!(sender_name(good), good);
        }
        assert_eq!(sender_name("a/b*c"), "a_b_c");
        assert_eq!(role_of_alive(&alive_role("r1", "welder"), "r1"), Some("welder"));
        assert_eq!(role_of_alive(&alive_role("r1", "welder"), "r2"), None);
        assert_eq!(role_of_alive(&alive("r1"), "r1"), None);
        assert_eq!(agent_of_alive(&alive_role("r1", "welder")), None, "a role token is not an agent's");
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
