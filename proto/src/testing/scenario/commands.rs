//! `[[commands]]`: an operator's commands in a scenario — `start`, `hold`, `unhold`, `suspend`, `unsuspend`, `stop`,
//! `abort`, `clear`, `reset`, the modes, `ack` and `shelve`, at a time or when a condition holds — checked against
//! the chart and the cell.

use std::ops::Range;

use toml::Spanned;

use crate::cluster::wire::CtlRequest;
use crate::exec::program::Program;

use super::raw::RawCommand;
use super::{Against, Command, Ctx, COMMANDS};

/// Who sends a scenario's commands, unless it says (`by`).
pub const SCENARIO_OPERATOR: &str = "baton test";

impl Ctx<'_> {
    /// The scenario's operator commands, each checked against the chart and the cell; what is wrong is an error
    /// of the scenario's.
    pub(super) fn commands(&mut self, against: &Against, raw: &[Spanned<RawCommand>], stay: bool) -> Vec<Command> {
        let cx = self;
        let program = against.program;
        let mut out = Vec::new();
        for c in raw {
            let span = c.span();
            let r = c.get_ref();
            let name = r.command.get_ref().to_ascii_lowercase();
            if !COMMANDS.contains(&name.as_str()) {
                cx.error(
                    &r.command.span(),
                    format!("`{}` is no command (they are: {})", r.command.get_ref(), COMMANDS.join(", ")),
                );
                continue;
            }
            if matches!(name.as_str(), "clear" | "reset") && !stay {
                cx.error(
                    &r.command.span(),
                    format!("`{name}` needs a run that stays at its end: `stay = true` in [run] (`baton run --stay`)"),
                );
                continue;
            }
            let Some(target) = cx.command_target(program, r, &span, &name) else { continue };
            let to = r.to.as_ref().map(|t| (t.span(), t.get_ref().clone()));
            match (&to, name.as_str()) {
                (None, "move") => {
                    cx.error(&span, "`move` names the step the token goes to: `to = \"Weld\"`");
                    continue;
                }
                (Some((at, _)), n) if n != "move" => {
                    cx.error(at, format!("`to` goes with move, not with `{n}`"));
                    continue;
                }
                (Some((at, st)), _) if program.step_by_name(st).is_none() => {
                    cx.error(at, super::super::cond::no_step(program, st));
                    continue;
                }
                _ => {}
            }
            if (r.agent.is_some() || r.step.is_some()) && !matches!(name.as_str(), "hold" | "unhold") {
                cx.error(&span, format!("`agent` and `step` go with hold and unhold, not with `{name}`"));
                continue;
            }
            if let Some(a) = &r.agent {
                cx.agent_known(against, &span, a);
            }
            if let Some(s) = &r.step {
                if program.step_by_name(s).is_none() {
                    cx.error(&span, super::super::cond::no_step(program, s));
                }
            }
            let for_ms = cx.opt_duration(&r.lasting);
            if (name == "shelve") != for_ms.is_some() {
                cx.error(&span, "`for` goes with shelve, which needs it: `for = \"10min\"`");
                continue;
            }
            let Some(trigger) = cx.trigger(against, "a command", &span, &r.at, &r.when, &r.after) else { continue };
            let (line, _) = cx.at(&span);
            let request = CtlRequest {
                command: name,
                target,
                agent: r.agent.clone(),
                step: r.step.clone(),
                for_ms,
                to: to.map(|(_, t)| t),
                reason: r.reason.clone().unwrap_or_default(),
                by: r.by.clone().unwrap_or_else(|| SCENARIO_OPERATOR.to_string()),
                user: None,
            };
            out.push(Command { trigger, request, line });
        }
        out
    }

    /// A command's `target`, checked against what the command takes and the chart; `None` after an error.
    fn command_target(
        &mut self,
        program: &Program,
        r: &RawCommand,
        span: &Range<usize>,
        name: &str,
    ) -> Option<Option<String>> {
        let target = match (&r.target, name) {
            (None, _) => None,
            (Some(t), "ack" | "shelve" | "unshelve") => match t.get_ref() {
                toml::Value::Integer(i) if *i > 0 => Some(i.to_string()),
                toml::Value::String(s) if s == "all" && name == "ack" => Some(s.clone()),
                _ => {
                    self.error(
                        &t.span(),
                        "`target` is an alarm's number (1, 2, …), or \"all\" to acknowledge every one",
                    );
                    return None;
                }
            },
            (Some(t), _) => match t.get_ref() {
                toml::Value::String(s) => Some(s.clone()),
                _ => {
                    self.error(&t.span(), format!("`target` of `{name}` is a name: `target = \"…\"`"));
                    return None;
                }
            },
        };
        let needs_target =
            matches!(name, "ack" | "shelve" | "unshelve" | "mode" | "force" | "activate" | "deactivate" | "move");
        let takes_target = needs_target || name == "confirm";
        if (needs_target && target.is_none()) || (!takes_target && target.is_some()) {
            let message = match name {
                "ack" | "shelve" | "unshelve" => {
                    format!("`{name}` names its alarm: `target = 1` (or \"all\" to acknowledge every one)")
                }
                "mode" => "`mode` names the mode: `target = \"step\"` (auto, step or manual)".to_string(),
                "force" => "`force` names its transition: `target = \"Load->Weld\"`".to_string(),
                "activate" | "deactivate" => format!("`{name}` names its step: `target = \"Weld\"`"),
                "move" => "`move` names the step the token leaves and the one it goes to: `target = \"Load\"`, \
                           `to = \"Weld\"`"
                    .to_string(),
                _ => format!("`{name}` takes no `target`"),
            };
            self.error(span, message);
            return None;
        }
        match (name, target.as_deref()) {
            ("mode", Some(m)) if crate::exec::engine::Mode::from_name(m).is_none() => {
                self.error(span, format!("`{m}` is no mode: auto, step or manual"));
                return None;
            }
            ("force" | "confirm", Some(t)) if program.transition_by_name(t).is_none() => {
                self.error(span, format!("the chart has no transition `{t}`"));
                return None;
            }
            ("activate" | "deactivate" | "move", Some(st)) if program.step_by_name(st).is_none() => {
                self.error(span, super::super::cond::no_step(program, st));
                return None;
            }
            _ => {}
        }
        Some(target)
    }
}
