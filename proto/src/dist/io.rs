//! Chart variables bound to device signals (I/O bindings): a pragma right after a variable's declaration names
//! the agent that connects it and where:
//!
//! ```text
//! VAR
//!   door_closed : BOOL; {input := 'zenoh', agent := 'cell1', key := 'cell1/door/closed'}
//!   lamp : BOOL;        {output := 'zenoh', agent := 'cell1', key := 'cell1/lamp'}
//! END_VAR
//! ```
//!
//! An input is written by its agent alone, from the device's samples (the layout refuses a chart in which
//! anything else writes it); an output is written by the chart, wherever, and its agent sends every change of
//! it to the device. Declared in the chart, so that `baton check` sees the one-writer rule and the reviewer sees
//! the I/O beside the program; the agent does the protocol.

use std::collections::BTreeMap;

use crate::dist::layout::{is_valid_name, Param};
use crate::exec::program::{Program, VarId};
use crate::exec::types::Type;
use crate::front::diag::{Diagnostic, Span};
use crate::front::model::Chart;

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
    /// The pragma's other keys, lowercased (`key` for Zenoh).
    pub params: BTreeMap<String, Param>,
    pub span: Span,
}

impl IoBinding {
    /// The Zenoh key expression of a `zenoh` binding.
    pub fn key(&self) -> Option<&str> {
        self.params.get("key").and_then(Param::as_str)
    }
}

const KINDS: [&str; 3] = ["zenoh", "ros2", "opcua"];

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
            let err = |m: String| Diagnostic::error(pragma.span, m);
            let which = if dir == IoDir::Input { "input" } else { "output" };
            let kind = match pairs.iter().find(|(k, _)| k == which).and_then(|(_, v)| v.as_str()) {
                Some(k) if k.eq_ignore_ascii_case("zenoh") => IoKind::Zenoh,
                Some(k) if KINDS.contains(&k.to_ascii_lowercase().as_str()) => {
                    diags.push(err(format!(
                        "binding `{}` to {k} is not supported yet: bind it to a Zenoh key (`{which} := 'zenoh'`)",
                        decl.name.name
                    )));
                    continue;
                }
                _ => {
                    diags.push(err(format!("`{which}` names what the variable is bound to: '{}'", KINDS.join("', '"))));
                    continue;
                }
            };
            let Some(agent) =
                pairs.iter().find(|(k, _)| k == "agent").and_then(|(_, v)| v.as_str()).map(str::to_string)
            else {
                diags.push(err(format!(
                    "binding `{}` needs the agent that connects it: `agent := 'cell1'`",
                    decl.name.name
                )));
                continue;
            };
            if !is_valid_name(&agent) {
                diags.push(err("`agent` needs a quoted name of letters, digits, `_` or `-`".into()));
                continue;
            }
            let Some(var) = program.var_by_name(&decl.name.name) else {
                diags.push(err(format!(
                    "`{}` is not one variable: bind each element or field of a structured variable apart",
                    decl.name.name
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
            for key in params.keys() {
                if key != "key" {
                    diags.push(err(format!("unknown key `{key}` in a Zenoh binding: it takes `key := 'a/b'`")));
                }
            }
            match params.get("key").and_then(Param::as_str) {
                Some(k) if crate::dist::keys::is_key_expr(k, dir == IoDir::Input) => {}
                Some(k) if k.split('/').next() == Some("baton") => {
                    diags.push(err(format!(
                        "`{k}` is under `baton/`, which is Baton's own: bind to a key of the device"
                    )));
                    continue;
                }
                Some(k) => {
                    let what = if dir == IoDir::Input {
                        "a key expression: chunks of letters, digits, `-`, `_` and `.`, or `*` and `**`, between `/`"
                    } else {
                        "a key: chunks of letters, digits, `-`, `_` and `.` between `/`, with no wildcards"
                    };
                    diags.push(err(format!("`{k}` is not {what}")));
                    continue;
                }
                None => {
                    diags.push(err(format!("binding `{}` needs `key := 'cell1/door'`", decl.name.name)));
                    continue;
                }
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::front::check::check_source;

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
}
