//! Chart variables bound to device signals (I/O bindings): a pragma right after a variable's declaration names
//! the agent that connects it and where:
//!
//! ```text
//! VAR
//!   door_closed : BOOL; {input := 'zenoh', agent := 'cell1', key := 'cell1/door/closed'}
//!   lamp : BOOL;        {output := 'zenoh', agent := 'cell1', key := 'cell1/lamp'}
//!   estop : BOOL;       {input := 'ros2', agent := 'arm', topic := '/estop', type := 'std_msgs/msg/Bool'}
//!   speed : REAL;       {output := 'ros2', agent := 'arm', topic := '/cmd_vel', type := 'geometry_msgs/msg/Twist',
//!                        field := 'linear.x'}
//!   parts : DINT;       {input := 'opcua', agent := 'cell1', endpoint := 'opc.tcp://10.0.0.5:4840',
//!                        node := 'ns=2;s=Cell.Count'}
//! END_VAR
//! ```
//!
//! An input is written by its agent alone, from the device's samples (the layout refuses a chart in which
//! anything else writes it); an output is written by the chart, wherever, and its agent sends every change of
//! it to the device. Declared in the chart, so that `baton check` sees the one-writer rule and the reviewer sees
//! the I/O beside the program; the agent does the protocol. What only the agent can know (a ROS 2 type's
//! fields, an OPC UA node's data type) it checks when it joins the run, and reports as a device it cannot reach.
//!
//! Chart variables bound to device signals (`IoBinding`, read from a declaration's pragmas: a Zenoh key, a ROS
//! 2 topic's field, an OPC UA node; each kind's parameters checked as far as `proto` can, without ROS types or an OPC
//! UA stack): an input's agent is its one writer (the layout adds it to the writers and refuses any other), and every
//! bound variable is published (`read_by_agents`), so inputs reach the coordinator and outputs their agent.
//!
//! # Rules bindings keep
//!
//! - A skill's answer reaches the chart only through variables the layout gave its agent: the binding's mappings
//!   (`SkillOutput`) make the agent their one writer, so `baton check` refuses a chart where anything else writes them;
//!   a skill that no longer runs (its action's Q fell) writes nothing.
//!
//! - Goals, requests and mappings are IEC literals (`front/literal.rs`), read by `baton check`; ROS 2 types are
//!   resolved on the agent only, which knows its robots' interfaces: the coordinator needs no ROS knowledge.
//!
//! - A bound input has one writer, its agent, fed by its device: `baton check` refuses a chart where anything else
//!   writes it, and a sample that is not a value of its type changes nothing. A device that cannot be reached changes
//!   no variable either: it is a state (`AgentRun::handle_device`), reported, never a value.

use std::collections::BTreeMap;

use crate::cluster::keys::is_valid_name;
use crate::exec::program::{Program, VarId};
use crate::front::diag::{Diagnostic, Span};
use crate::front::literal::{self, FieldPath, PathPart};
use crate::front::model::Chart;
use crate::front::pragma::Param;
use crate::types::Type;

/// Which way a bound variable's value goes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum IoDir {
    /// Device to chart: the agent writes the variable from the device's samples.
    Input,
    /// Chart to device: the agent sends the variable's changes.
    Output,
}

/// What a variable is bound to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum IoKind {
    /// A Zenoh key expression: samples in, puts out (MQTT devices through Zenoh's MQTT bridge, anything on
    /// Zenoh). Payloads are text: `true`/`false`, numbers, strings as they are.
    Zenoh,
    /// A field of a ROS 2 topic's messages, over rmw_zenoh: a subscription in, a publication out.
    Ros2,
    /// An OPC UA node's value: a monitored item in, a write out.
    OpcUa,
}

impl IoKind {
    pub fn name(self) -> &'static str {
        match self {
            IoKind::Zenoh => "zenoh",
            IoKind::Ros2 => "ros2",
            IoKind::OpcUa => "opcua",
        }
    }

    /// The keys a binding of this kind takes, besides `input`/`output` and `agent`; the first ones are needed.
    fn keys(self) -> (&'static [&'static str], &'static [&'static str]) {
        match self {
            IoKind::Zenoh => (&["key"], &["period_ms"]),
            IoKind::Ros2 => (&["topic", "type"], &["field", "period_ms"]),
            IoKind::OpcUa => (&["endpoint", "node"], &["security", "policy", "user", "password", "interval_ms"]),
        }
    }
}

/// One bound variable.
#[derive(Clone, Debug, PartialEq)]
pub struct IoBinding {
    pub var: VarId,
    /// The variable's name, as declared.
    pub name: String,
    pub dir: IoDir,
    pub kind: IoKind,
    /// The agent that connects it (by name: one process is the input's one writer).
    pub agent: String,
    /// The pragma's other keys, lowercased (`key` for Zenoh; `topic`, `type`, `field` for ROS 2; `endpoint`,
    /// `node`… for OPC UA).
    pub params: BTreeMap<String, Param>,
    pub span: Span,
}

impl IoBinding {
    fn text(&self, key: &str) -> Option<&str> {
        self.params.get(key).and_then(Param::as_str)
    }

    /// The Zenoh key expression of a `zenoh` binding.
    pub fn key(&self) -> Option<&str> {
        self.text("key")
    }

    /// The topic and message type of a `ros2` binding.
    pub fn topic(&self) -> Option<(&str, &str)> {
        Some((self.text("topic")?, self.text("type")?))
    }

    /// How often a `zenoh` or `ros2` output sends its value again, unchanged (`period_ms`): for robots whose
    /// drivers stop when commands stop coming (a `cmd_vel` watchdog), devices that expect a heartbeat, and
    /// subscribers that join late.
    pub fn period_ms(&self) -> Option<u64> {
        self.params.get("period_ms").and_then(Param::as_f64).map(|ms| ms as u64)
    }

    /// The field of a `ros2` binding's messages (`linear.x`); empty when not given: the message's one field.
    pub fn field(&self) -> FieldPath {
        self.text("field").and_then(|f| literal::parse_path(f).ok()).unwrap_or_default()
    }

    /// The endpoint and node of an `opcua` binding.
    pub fn node(&self) -> Option<(&str, &str)> {
        Some((self.text("endpoint")?, self.text("node")?))
    }

    /// What the binding reaches, for messages: `cell1/door`, `/estop (std_msgs/msg/Bool)`, `ns=2;s=Door on
    /// opc.tcp://…`.
    pub fn device(&self) -> String {
        match self.kind {
            IoKind::Zenoh => format!("Zenoh key {}", self.key().unwrap_or("?")),
            IoKind::Ros2 => {
                let (topic, ty) = self.topic().unwrap_or(("?", "?"));
                match self.text("field") {
                    Some(f) => format!("ROS 2 topic {topic} ({ty}, field {f})"),
                    None => format!("ROS 2 topic {topic} ({ty})"),
                }
            }
            IoKind::OpcUa => {
                let (endpoint, node) = self.node().unwrap_or(("?", "?"));
                format!("OPC UA node {node} on {endpoint}")
            }
        }
    }
}

/// The bindings of the chart's declarations, reported where they cannot be read.
pub fn io_bindings(chart: &Chart, program: &Program, diags: &mut Vec<Diagnostic>) -> Vec<IoBinding> {
    let mut out: Vec<IoBinding> = Vec::new();
    for decl in &chart.vars {
        for pragma in &decl.pragmas {
            let pairs = match crate::front::pragma::read(&pragma.text) {
                crate::front::pragma::Pragma::Pairs(pairs) => pairs,
                crate::front::pragma::Pragma::Malformed { keys, why } => {
                    if keys.iter().any(|k| k == "input" || k == "output") {
                        diags.push(Diagnostic::error(pragma.span, format!("this binding cannot be read: {why}")));
                    }
                    continue;
                }
                crate::front::pragma::Pragma::Foreign => continue,
            };
            let dir = match (pairs.iter().any(|(k, _)| k == "input"), pairs.iter().any(|(k, _)| k == "output")) {
                (true, false) => IoDir::Input,
                (false, true) => IoDir::Output,
                (true, true) => {
                    diags.push(Diagnostic::error(pragma.span, "a binding is an `input` or an `output`, not both"));
                    continue;
                }
                (false, false) => continue,
            };
            let name = &decl.name.name;
            let err = |m: String| Diagnostic::error(pragma.span, m);
            let which = if dir == IoDir::Input { "input" } else { "output" };
            let kind = match pairs.iter().find(|(k, _)| k == which).and_then(|(_, v)| v.as_str()) {
                Some(k) if k.eq_ignore_ascii_case("zenoh") => IoKind::Zenoh,
                Some(k) if k.eq_ignore_ascii_case("ros2") => IoKind::Ros2,
                Some(k) if k.eq_ignore_ascii_case("opcua") => IoKind::OpcUa,
                _ => {
                    diags.push(err(format!(
                        "`{which}` names what the variable is bound to: 'zenoh', 'ros2' or 'opcua'"
                    )));
                    continue;
                }
            };
            let Some(agent) =
                pairs.iter().find(|(k, _)| k == "agent").and_then(|(_, v)| v.as_str()).map(str::to_string)
            else {
                diags.push(err(format!("binding `{name}` needs the agent that connects it: `agent := 'cell1'`")));
                continue;
            };
            if !is_valid_name(&agent) {
                diags.push(err("`agent` needs a quoted name of letters, digits, `_` or `-`".into()));
                continue;
            }
            let Some(var) = program.var_by_name(name) else {
                diags.push(err(format!(
                    "`{name}` is not one variable: bind each element or field of a structured variable apart"
                )));
                continue;
            };
            let info = &program.vars[var.index()];
            let elementary =
                matches!(info.ty, Type::Bool | Type::Int(_) | Type::Real { .. } | Type::Time | Type::Str { .. });
            if !elementary {
                diags.push(err(format!(
                    "`{}` is a {}: only BOOL, integer, REAL, TIME and STRING variables are bound",
                    info.name, info.ty
                )));
                continue;
            }
            if info.constant {
                diags.push(err(format!("`{}` is a constant: it cannot be bound", info.name)));
                continue;
            }
            let params: BTreeMap<String, Param> =
                pairs.into_iter().filter(|(k, _)| k != which && k != "agent").collect();
            let problems = check_params(kind, dir, &params);
            if !problems.is_empty() {
                diags.extend(problems.into_iter().map(|m| err(format!("binding `{name}`: {m}"))));
                continue;
            }
            if out.iter().any(|b| b.var == var) {
                diags.push(err(format!("`{}` is bound twice: a variable has one binding", info.name)));
                continue;
            }
            out.push(IoBinding { var, name: info.name.clone(), dir, kind, agent, params, span: pragma.span });
        }
    }
    out
}

/// What is wrong with a binding's parameters, one message per problem.
fn check_params(kind: IoKind, dir: IoDir, params: &BTreeMap<String, Param>) -> Vec<String> {
    let mut problems = Vec::new();
    let (needed, optional) = kind.keys();
    let unknown: Vec<&String> =
        params.keys().filter(|k| !needed.contains(&k.as_str()) && !optional.contains(&k.as_str())).collect();
    let text = |k: &str| params.get(k).and_then(Param::as_str);
    let missing: Vec<&str> = needed.iter().copied().filter(|k| text(k).is_none()).collect();
    let takes = || {
        let needed: Vec<String> = needed.iter().map(|k| format!("`{k}`")).collect();
        let optional: Vec<String> = optional.iter().map(|k| format!("`{k}`")).collect();
        match optional.is_empty() {
            true => format!("a {} binding takes {}", kind.name(), needed.join(" and ")),
            false => format!(
                "a {} binding takes {}, and may take {}",
                kind.name(),
                needed.join(" and "),
                optional.join(", ")
            ),
        }
    };
    if !unknown.is_empty() {
        // One message: a binding of one kind written with another's keys misses some and has others.
        let unknown: Vec<String> = unknown.iter().map(|k| format!("`{k}`")).collect();
        return vec![format!("{}, not {}", takes(), unknown.join(", "))];
    }
    for key in missing {
        let example = match key {
            "key" => "'cell1/door'",
            "topic" => "'/door/closed'",
            "type" => "'std_msgs/msg/Bool'",
            "endpoint" => "'opc.tcp://10.0.0.5:4840'",
            _ => "'ns=2;s=Cell.Door'",
        };
        problems.push(format!("it needs `{key} := {example}`"));
    }
    if !problems.is_empty() {
        return problems;
    }
    if let Some(ms) = params.get("period_ms") {
        if !ms.as_f64().is_some_and(|ms| (1.0..=3_600_000.0).contains(&ms)) {
            problems.push("`period_ms` is a number of milliseconds between 1 and 3600000".into());
        }
        if dir == IoDir::Input {
            problems.push("`period_ms` is how often an output is sent again: an input takes every sample".into());
        }
    }
    match kind {
        IoKind::Zenoh => {
            let k = text("key").unwrap_or_default();
            if k.split('/').next() == Some("baton") {
                problems.push(format!("`{k}` is under `baton/`, which is Baton's own: bind to a key of the device"));
            } else if !crate::cluster::keys::is_key_expr(k, dir == IoDir::Input) {
                problems.push(if dir == IoDir::Input {
                    format!("`{k}` is not a key expression: chunks of letters, digits, `-`, `_` and `.`, or `*` and `**`, between `/`")
                } else {
                    format!("`{k}` is not a key: chunks of letters, digits, `-`, `_` and `.` between `/`, with no wildcards")
                });
            }
        }
        IoKind::Ros2 => {
            let topic = text("topic").unwrap_or_default();
            if !is_ros_name(topic) {
                problems.push(format!(
                    "`{topic}` is not a ROS 2 topic name: words of letters, digits and `_` between `/`, such as '/door/closed'"
                ));
            }
            let ty = text("type").unwrap_or_default();
            let parts: Vec<&str> = ty.split('/').collect();
            if parts.len() != 3 || parts[1] != "msg" || !parts.iter().all(|p| is_ros_word(p)) {
                problems.push(format!(
                    "`{ty}` is not a message type: write it as <package>/msg/<Name>, such as std_msgs/msg/Bool"
                ));
            }
            match params.get("field") {
                None => {}
                Some(Param::Str(f)) => match literal::parse_path(f) {
                    Ok(path) if dir == IoDir::Output && path.iter().any(|p| matches!(p, PathPart::Index(_))) => {
                        problems.push(format!(
                            "`field := '{f}'`: an output sets a field, not an element of a list (the message would \
                             need the whole list)"
                        ));
                    }
                    Ok(_) => {}
                    Err(e) => problems.push(format!("`field := '{f}'` is not a field path such as 'linear.x': {e}")),
                },
                Some(Param::Value(v)) => {
                    problems.push(format!("`field` is a field path in quotes, such as 'linear.x', not {v}"))
                }
            }
        }
        IoKind::OpcUa => {
            let endpoint = text("endpoint").unwrap_or_default();
            if !endpoint.starts_with("opc.tcp://") || endpoint.len() <= "opc.tcp://".len() {
                problems.push(format!("`endpoint` must be an opc.tcp:// address, not `{endpoint}`"));
            }
            let node = text("node").unwrap_or_default();
            if !is_node_id(node) {
                problems.push(format!("`{node}` is not a node id (such as 'ns=2;s=Cell.Door' or 'ns=3;i=1002')"));
            }
            match text("security") {
                None => {}
                Some(s) if ["none", "sign", "signandencrypt"].contains(&s.to_ascii_lowercase().as_str()) => {}
                Some(s) => problems.push(format!("`security` must be None, Sign or SignAndEncrypt, not `{s}`")),
            }
            if params.contains_key("user") != params.contains_key("password") {
                problems.push("`user` and `password` go together".into());
            }
            if let Some(ms) = params.get("interval_ms") {
                if !ms.as_f64().is_some_and(|ms| (1.0..=3_600_000.0).contains(&ms)) {
                    problems.push("`interval_ms` is a number of milliseconds between 1 and 3600000".into());
                }
                if dir == IoDir::Output {
                    problems
                        .push("`interval_ms` is how often an input is sampled: an output is written on change".into());
                }
            }
        }
    }
    problems
}

fn is_ros_word(w: &str) -> bool {
    w.chars().next().is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
        && w.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
}

/// A fully qualified or relative ROS 2 name: `/door/closed`, `cmd_vel` (relative names are in the agent's
/// namespace, `/`).
pub fn is_ros_name(name: &str) -> bool {
    let rest = name.strip_prefix('/').unwrap_or(name);
    name.len() <= 255 && !rest.is_empty() && rest.split('/').all(is_ros_word)
}

/// An OPC UA node id as its text form writes it: `ns=2;s=Cell.Door`, `i=2258`, `ns=1;g=…`, `ns=1;b=…`, or
/// with the namespace's URI, `nsu=urn:x;s=Door`.
pub fn is_node_id(text: &str) -> bool {
    let t = text.trim();
    let id = match t.split_once(';') {
        Some((ns, id)) if ns.starts_with("nsu=") && ns.len() > 4 => id,
        Some((ns, id)) => match ns.strip_prefix("ns=") {
            Some(n) if !n.is_empty() && n.parse::<u16>().is_ok() => id,
            _ => return false,
        },
        None => t,
    };
    match id.split_at_checked(2) {
        Some(("i=", n)) => n.parse::<u32>().is_ok(),
        Some(("s=" | "b=", v)) => !v.is_empty(),
        Some(("g=", g)) => g.len() == 36 && g.chars().all(|c| c.is_ascii_hexdigit() || c == '-'),
        _ => false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::check_source;

    fn bindings(src: &str) -> (Vec<IoBinding>, Vec<String>) {
        let report = check_source(src);
        let diags = report.diagnostics.iter().map(|d| d.message.clone()).collect();
        let io = report.charts.first().and_then(|c| c.layout.as_ref()).map_or(Vec::new(), |l| l.io.clone());
        (io, diags)
    }

    #[test]
    fn declarations_bind_variables_to_keys_on_agents() {
        let (io, diags) = bindings(
            "PROGRAM P\nVAR\n  door : BOOL; {input := 'zenoh', agent := 'cell1', key := 'cell1/door'}\n  \
             lamp : BOOL; {output := 'zenoh', agent := 'cell1', key := 'cell1/lamp'}\nEND_VAR\n\
             INITIAL_STEP A: L(N); END_STEP\nTRANSITION FROM A TO B := door; END_TRANSITION\nSTEP B: END_STEP\n\
             ACTION L: lamp := TRUE; END_ACTION\nEND_PROGRAM",
        );
        assert!(diags.is_empty(), "{diags:?}");
        assert_eq!(io.len(), 2);
        assert_eq!(
            (io[0].name.as_str(), io[0].dir, io[0].agent.as_str(), io[0].key()),
            ("door", IoDir::Input, "cell1", Some("cell1/door"))
        );
        assert_eq!((io[1].name.as_str(), io[1].dir), ("lamp", IoDir::Output));
    }

    #[test]
    fn ros2_and_opcua_bindings_are_read_and_their_mistakes_named() {
        let decl = |pragma: &str| {
            format!(
                "PROGRAM P\nVAR\n  x : REAL; {pragma}\nEND_VAR\nINITIAL_STEP A: END_STEP\n\
                 TRANSITION FROM A TO B := x > 1.0; END_TRANSITION\nSTEP B: END_STEP\nEND_PROGRAM"
            )
        };
        let (io, diags) = bindings(&decl(
            "{input := 'ros2', agent := 'arm', topic := '/odom', type := 'nav_msgs/msg/Odometry', field := 'pose.pose.position.x'}",
        ));
        assert!(diags.is_empty(), "{diags:?}");
        assert_eq!(io[0].kind, IoKind::Ros2);
        assert_eq!(io[0].topic(), Some(("/odom", "nav_msgs/msg/Odometry")));
        assert_eq!(literal::show_path(&io[0].field()), "pose.pose.position.x");
        let (io, diags) = bindings(&decl(
            "{input := 'OPCUA', agent := 'cell1', endpoint := 'opc.tcp://127.0.0.1:4840', node := 'ns=2;s=Cell.Speed', interval_ms := 50}",
        ));
        assert!(diags.is_empty(), "{diags:?}");
        assert_eq!(
            (io[0].kind, io[0].node()),
            (IoKind::OpcUa, Some(("opc.tcp://127.0.0.1:4840", "ns=2;s=Cell.Speed")))
        );
        for (pragma, says) in [
            ("{input := 'ros2', agent := 'a', topic := '/odom'}", "needs `type := 'std_msgs/msg/Bool'`"),
            ("{input := 'ros2', agent := 'a', topic := 'a//b', type := 'std_msgs/msg/Bool'}", "not a ROS 2 topic name"),
            ("{input := 'ros2', agent := 'a', topic := '/x', type := 'std_msgs/Bool'}", "not a message type"),
            ("{input := 'ros2', agent := 'a', topic := '/x', type := 'std_msgs/msg/Bool', field := 'a b'}", "not a field path"),
            ("{output := 'ros2', agent := 'a', topic := '/x', type := 'std_msgs/msg/Float64MultiArray', field := 'data[0]'}", "not an element"),
            ("{input := 'opcua', agent := 'a', endpoint := 'http://x', node := 'ns=2;s=X'}", "opc.tcp://"),
            ("{input := 'opcua', agent := 'a', endpoint := 'opc.tcp://x:4840', node := 'Cell.X'}", "not a node id"),
            ("{input := 'opcua', agent := 'a', endpoint := 'opc.tcp://x:4840', node := 'i=1', security := 'Strong'}", "`security`"),
            ("{input := 'opcua', agent := 'a', endpoint := 'opc.tcp://x:4840', node := 'i=1', user := 'u'}", "go together"),
            ("{output := 'opcua', agent := 'a', endpoint := 'opc.tcp://x:4840', node := 'i=1', interval_ms := 10}", "on change"),
            ("{input := 'opcua', agent := 'a', endpoint := 'opc.tcp://x:4840', node := 'i=1', key := 'a/b'}", "not `key`"),
            ("{input := 'modbus', agent := 'a'}", "'zenoh', 'ros2' or 'opcua'"),
        ] {
            let (io, diags) = bindings(&decl(pragma));
            assert!(io.is_empty(), "{pragma}");
            assert!(diags.iter().any(|d| d.contains(says)), "{pragma}: {diags:?}");
        }
    }

    #[test]
    fn node_ids_and_ros_names() {
        for ok in [
            "ns=2;s=Cell.Door",
            "i=2258",
            "ns=1;i=5",
            "nsu=urn:x;s=a",
            "ns=1;g=09087e75-8e5e-499b-954f-f2a9603db28a",
            "ns=1;b=M/RbKBsRVkePCePcx24oRA==",
        ] {
            assert!(is_node_id(ok), "{ok}");
        }
        for bad in ["", "s=", "ns=x;i=1", "ns=2;Door", "Door", "i=-1", "ns=70000;i=1", "g=1234"] {
            assert!(!is_node_id(bad), "{bad}");
        }
        assert!(is_ros_name("/door/closed") && is_ros_name("cmd_vel") && is_ros_name("/_x/y2"));
        assert!(
            !is_ros_name("/")
                && !is_ros_name("/a/")
                && !is_ros_name("/2a")
                && !is_ros_name("a-b")
                && !is_ros_name("~/x")
        );
    }
}
