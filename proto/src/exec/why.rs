//! Why a transition does not clear (S7-GRAPH's criteria analysis, CODESYS's SFCErrorAnalyzation — which handles only
//! ST conditions; this handles every compiled condition, written in ST or imported from LD or FBD): the parts of its
//! condition that are FALSE now, each with the values it reads.
//!
//! A condition is taken apart along AND (every FALSE conjunct is a reason), OR (every disjunct, all FALSE), and
//! NOT over them; what is left — a comparison, a variable, a step's flag — is shown with its values.

use serde::{Deserialize, Serialize};

use crate::exec::env::Env;
use crate::exec::eval;
use crate::exec::program::{ArithOp, CExpr, CmpOp, LogicOp, Program};
use crate::types::Value;

/// The smallest parts of `condition` that make it FALSE in `env`, as text: "`picked1` is FALSE", "`done < parts`
/// is FALSE (done = 3, parts = 3)". Empty when it is TRUE. At most `limit` parts.
pub fn false_parts(program: &Program, condition: &CExpr, env: &impl Env, limit: usize) -> Vec<String> {
    let mut out = Vec::new();
    explain(program, condition, env, true, &mut out, limit);
    out
}

/// Collects why `e` is not `want`.
fn explain(program: &Program, e: &CExpr, env: &impl Env, want: bool, out: &mut Vec<String>, limit: usize) {
    if out.len() >= limit {
        return;
    }
    let is = |e: &CExpr| eval::eval(e, env).map(|v| v.as_bool());
    match e {
        CExpr::Not(inner) => explain(program, inner, env, !want, out, limit),
        // All of them must be TRUE: each FALSE one is a reason. (Wanting it FALSE: every part TRUE is.)
        CExpr::Logic(LogicOp::And, a, b) if want => {
            for part in [a, b] {
                if is(part) != Ok(true) {
                    explain(program, part, env, true, out, limit);
                }
            }
        }
        CExpr::Logic(LogicOp::Or, a, b) if !want => {
            for part in [a, b] {
                if is(part) != Ok(false) {
                    explain(program, part, env, false, out, limit);
                }
            }
        }
        // One of them would do: each is a reason as long as none is.
        CExpr::Logic(LogicOp::Or, a, b) if want => {
            if is(e) != Ok(true) {
                explain(program, a, env, true, out, limit);
                explain(program, b, env, true, out, limit);
            }
        }
        CExpr::Logic(LogicOp::And, a, b) => {
            if is(e) != Ok(false) {
                explain(program, a, env, false, out, limit);
                explain(program, b, env, false, out, limit);
            }
        }
        _ => match is(e) {
            Ok(v) if v == want => {}
            Ok(v) => {
                let mut reads = Vec::new();
                values(program, e, env, &mut reads);
                reads.dedup();
                let shown = show(program, e);
                let what = if v { "TRUE" } else { "FALSE" };
                // A lone flag or variable shows its own value already.
                let simple = matches!(e, CExpr::Var(_) | CExpr::StepX(_) | CExpr::ActionQ(_) | CExpr::StepOverrun(_));
                if simple || reads.is_empty() {
                    out.push(format!("`{shown}` is {what}"));
                } else {
                    out.push(format!("`{shown}` is {what} ({})", reads.join(", ")));
                }
            }
            Err(fault) => out.push(format!("`{}` faults: {fault:?}", show(program, e))),
        },
    }
}

/// `name = value` for every variable and step time `e` reads.
fn values(program: &Program, e: &CExpr, env: &impl Env, out: &mut Vec<String>) {
    match e {
        CExpr::Var(v) => {
            let info = &program.vars[v.index()];
            out.push(format!("{} = {}", info.name, info.ty.show(&env.var(*v))));
        }
        CExpr::StepT(s) => out.push(format!("{}.T = {}", program.steps[s.index()].name, Value::Time(env.step_t(*s)))),
        CExpr::StepX(s) => out.push(format!("{}.X = {}", program.steps[s.index()].name, bool_text(env.step_x(*s)))),
        CExpr::Not(a) | CExpr::Neg(a, _) => values(program, a, env, out),
        CExpr::Logic(_, a, b) | CExpr::Cmp(_, a, b) | CExpr::Arith { lhs: a, rhs: b, .. } => {
            values(program, a, env, out);
            values(program, b, env, out);
        }
        CExpr::Call(c) => c.args.iter().for_each(|a| values(program, a, env, out)),
        _ => {}
    }
}

fn bool_text(b: bool) -> &'static str {
    if b {
        "TRUE"
    } else {
        "FALSE"
    }
}

/// The expression as Structured Text, with the chart's names.
pub fn show(program: &Program, e: &CExpr) -> String {
    let paren = |e: &CExpr| match e {
        CExpr::Logic(..) | CExpr::Cmp(..) | CExpr::Arith { .. } => format!("({})", show(program, e)),
        _ => show(program, e),
    };
    match e {
        CExpr::Const(v) => v.to_string(),
        CExpr::Var(v) => program.vars[v.index()].name.clone(),
        CExpr::StepX(s) => format!("{}.X", program.steps[s.index()].name),
        CExpr::StepT(s) => format!("{}.T", program.steps[s.index()].name),
        CExpr::StepOverrun(s) => format!("{}.overrun", program.steps[s.index()].name),
        CExpr::ActionQ(a) => format!("{}.Q", program.actions[a.index()].name),
        CExpr::Not(a) => format!("NOT {}", paren(a)),
        CExpr::Neg(a, _) => format!("-{}", paren(a)),
        CExpr::Logic(op, a, b) => {
            let op = match op {
                LogicOp::And => "AND",
                LogicOp::Or => "OR",
                LogicOp::Xor => "XOR",
            };
            format!("{} {op} {}", paren(a), paren(b))
        }
        CExpr::Cmp(op, a, b) => {
            let op = match op {
                CmpOp::Eq => "=",
                CmpOp::Ne => "<>",
                CmpOp::Lt => "<",
                CmpOp::Le => "<=",
                CmpOp::Gt => ">",
                CmpOp::Ge => ">=",
            };
            format!("{} {op} {}", paren(a), paren(b))
        }
        CExpr::Arith { op, lhs, rhs, .. } => {
            let op = match op {
                ArithOp::Add => "+",
                ArithOp::Sub => "-",
                ArithOp::Mul => "*",
                ArithOp::Div => "/",
                ArithOp::Mod => "MOD",
                ArithOp::Pow => "**",
            };
            format!("{} {op} {}", paren(lhs), paren(rhs))
        }
        CExpr::Call(c) => {
            let args: Vec<String> = c.args.iter().map(|a| show(program, a)).collect();
            format!("{:?}({})", c.func, args.join(", ")).to_uppercase()
        }
        CExpr::Index(ix) => format!("{}[…]", program.vars[ix.base.index()].name),
        CExpr::NestedT(_) => "a nested step's T".to_string(),
    }
}

/// Why an active step's transitions do not clear (`baton status --why`): from the coordinator for its own steps
/// and the convergences it judges, from each agent for the steps that run there.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct StepWhy {
    pub step: String,
    /// Where it runs: the agent, or none for the coordinator.
    #[serde(default)]
    pub agent: Option<String>,
    /// `S.T` now.
    pub active_ms: u64,
    /// Held by an operator: nothing clears until it is released.
    #[serde(default)]
    pub held: bool,
    /// Past its maximum time, waiting for the alarm's acknowledgement.
    #[serde(default)]
    pub faulted: bool,
    /// How long until its minimum time is reached (0: reached, or none).
    #[serde(default)]
    pub min_left_ms: u64,
    /// Skills of its actions still running, and for how long.
    #[serde(default)]
    pub skills: Vec<SkillWhy>,
    pub transitions: Vec<TransitionWhy>,
}

impl StepWhy {
    /// One line: what each transition waits for (`Move->Moved: `moved` is FALSE`), and the skills still running.
    pub fn summary(&self) -> String {
        let mut parts: Vec<String> = self
            .transitions
            .iter()
            .map(|t| {
                let mut why: Vec<String> = Vec::new();
                if !t.missing.is_empty() {
                    why.push(format!("waits for {}", t.missing.join(", ")));
                }
                why.extend(t.false_parts.iter().cloned());
                if why.is_empty() {
                    why.push("TRUE".into());
                }
                format!("{}: {}", t.name, why.join(", "))
            })
            .collect();
        parts.extend(self.skills.iter().map(|s| format!("skill of `{}` running for {} ms", s.action, s.running_ms)));
        parts.join("; ")
    }
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SkillWhy {
    pub action: String,
    pub running_ms: u64,
}

#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct TransitionWhy {
    pub name: String,
    /// The parts of its condition that are FALSE now, with their values (empty: the condition is TRUE).
    pub false_parts: Vec<String>,
    /// A convergence's source steps not active yet (branches still running).
    #[serde(default)]
    pub missing: Vec<String>,
    /// TRUE, and waiting for `confirm` (step mode).
    #[serde(default)]
    pub waiting_confirm: bool,
}
