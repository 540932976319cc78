//! Conditions of a scenario: when an input is set or a fault strikes, and what must always (or never) hold.
//!
//! A condition is `step Load active`, `step Load active on robot2`, `step Load inactive`, `state held` (the run's
//! PackML state, as its `state` records say), or an ST boolean
//! expression over the chart's step flags and variables, read by the chart's own parser: `Pick1.X AND
//! Weld.X`, `done >= 2 AND NOT Idle.X`. A step's name alone stands for its flag when no variable has that name.
//! It is evaluated on the coordinator's view of the run: the steps active anywhere (and where), the values of
//! the variables.

use crate::exec::program::{Program, VarId};
use crate::front::model::{BinOp, ExprKind, UnOp};
use crate::front::parser::{parse_fragment, Fragment, FragmentKind};
use crate::types::Value;

#[derive(Clone, Debug)]
pub enum Cond {
    Bool(bool),
    Num(f64),
    Str(String),
    /// A step is active (on this agent, if given).
    Step(usize, Option<String>),
    /// The run is in this PackML state.
    State(crate::cluster::runtime::packml::State),
    Var(VarId),
    Not(Box<Cond>),
    Neg(Box<Cond>),
    Bin(BinOp, Box<Cond>, Box<Cond>),
}

/// What a condition reads.
pub trait View {
    /// Where step `index` is active: `Some(None)` on the coordinator, `Some(Some(agent))` on an agent.
    fn step(&self, index: usize) -> Option<Option<&str>>;
    fn value(&self, var: VarId) -> Value;
    /// The run's PackML state, if known.
    fn state(&self) -> Option<crate::cluster::runtime::packml::State> {
        None
    }
}

#[derive(Clone, Debug, PartialEq)]
enum V {
    Bool(bool),
    Num(f64),
    Str(String),
}

impl V {
    fn truth(&self) -> bool {
        match self {
            V::Bool(b) => *b,
            V::Num(n) => *n != 0.0,
            V::Str(s) => !s.is_empty(),
        }
    }

    fn num(&self) -> f64 {
        match self {
            V::Bool(b) => *b as i64 as f64,
            V::Num(n) => *n,
            V::Str(_) => f64::NAN,
        }
    }
}

fn step_index(program: &Program, name: &str) -> Option<usize> {
    program.steps.iter().position(|s| s.name.eq_ignore_ascii_case(name))
}

impl Cond {
    /// Reads `text` against `program`; `agents` are the scenario's agent names.
    pub fn parse(text: &str, program: &Program, agents: &[String]) -> Result<Cond, String> {
        let words: Vec<&str> = text.split_whitespace().collect();
        if let ["state" | "STATE" | "State", name] = words[..] {
            use crate::cluster::runtime::packml::State;
            return State::ALL.into_iter().find(|s| s.name().eq_ignore_ascii_case(name)).map(Cond::State).ok_or_else(
                || {
                    let names: Vec<&str> = State::ALL.iter().map(|s| s.name()).collect();
                    format!("`{text}`: `{name}` is not a run state ({})", names.join(", "))
                },
            );
        }
        if words.first().is_some_and(|w| w.eq_ignore_ascii_case("step")) {
            let bad =
                || format!("`{text}`: write `step NAME active`, `step NAME active on AGENT` or `step NAME inactive`");
            let (name, state) = match words[..] {
                [_, name, state] | [_, name, state, _, _] => (name, state),
                _ => return Err(bad()),
            };
            let index = step_index(program, name).ok_or_else(|| no_step(program, name))?;
            let on = match words[..] {
                [_, _, _, on, agent] if on.eq_ignore_ascii_case("on") => {
                    if !agents.iter().any(|a| a == agent) {
                        return Err(format!("`{text}`: no agent named `{agent}` in the scenario"));
                    }
                    Some(agent.to_string())
                }
                [_, _, _] => None,
                _ => return Err(bad()),
            };
            return match state.to_ascii_lowercase().as_str() {
                "active" => Ok(Cond::Step(index, on)),
                "inactive" if on.is_none() => Ok(Cond::Not(Box::new(Cond::Step(index, None)))),
                _ => Err(bad()),
            };
        }
        let parsed = parse_fragment(text, |i| i, FragmentKind::Expr);
        // Any error counts, the lexer's too: `first != 1` is not IEC (`<>` is), and read without its `!` it
        // would be `first = 1`, the opposite.
        if let Some(d) = parsed.diagnostics.iter().find(|d| d.is_error()) {
            return Err(format!("`{text}` is not an expression: {}", d.message));
        }
        let Some(Fragment::Expr(expr)) = parsed.fragment else {
            return Err(format!("`{text}` is not an expression: a syntax error"));
        };
        Cond::of(&expr, program)
    }

    fn of(e: &crate::front::model::Expr, program: &Program) -> Result<Cond, String> {
        Ok(match &e.kind {
            ExprKind::Bool(b) => Cond::Bool(*b),
            ExprKind::Int(i) => Cond::Num(*i as f64),
            ExprKind::Real(r) => Cond::Num(*r),
            ExprKind::Time(ms) => Cond::Num(*ms as f64),
            ExprKind::Str(s) => Cond::Str(s.clone()),
            ExprKind::Name(id) => match program.var_by_name(&id.name) {
                Some(v) if !program.vars[v.index()].hidden => Cond::Var(v),
                _ => match step_index(program, &id.name) {
                    Some(s) => Cond::Step(s, None),
                    None => return Err(format!("the chart has no variable or step `{}`", id.name)),
                },
            },
            ExprKind::Field(base, field) if field.name.eq_ignore_ascii_case("X") => {
                Cond::Step(step_index(program, &base.name).ok_or_else(|| no_step(program, &base.name))?, None)
            }
            ExprKind::Field(base, field) => {
                let name = format!("{}.{}", base.name, field.name);
                match program.var_by_name(&name) {
                    Some(v) => Cond::Var(v),
                    None => return Err(format!("`{name}`: a scenario reads a step's flag (`.X`) or a variable")),
                }
            }
            ExprKind::Unary(UnOp::Not, inner) => Cond::Not(Box::new(Cond::of(inner, program)?)),
            ExprKind::Unary(UnOp::Neg, inner) => Cond::Neg(Box::new(Cond::of(inner, program)?)),
            ExprKind::Binary(op, a, b) => {
                Cond::Bin(*op, Box::new(Cond::of(a, program)?), Box::new(Cond::of(b, program)?))
            }
            _ => return Err("a scenario's condition uses steps, variables, literals and operators only".to_string()),
        })
    }

    /// The truth of a condition that reads no step and no variable (`TRUE`, `1 = 1`): it is the same at every
    /// moment. `None` for one that reads the run.
    pub fn constant(&self) -> Option<bool> {
        let mut stack = vec![self];
        while let Some(c) = stack.pop() {
            match c {
                Cond::Step(..) | Cond::Var(_) | Cond::State(_) => return None,
                Cond::Not(x) | Cond::Neg(x) => stack.push(x),
                Cond::Bin(_, a, b) => {
                    stack.push(a);
                    stack.push(b);
                }
                Cond::Bool(_) | Cond::Num(_) | Cond::Str(_) => {}
            }
        }
        struct Nothing;
        impl View for Nothing {
            fn step(&self, _: usize) -> Option<Option<&str>> {
                None
            }
            fn value(&self, _: VarId) -> Value {
                Value::Bool(false)
            }
        }
        Some(self.holds(&Nothing))
    }

    pub fn holds(&self, view: &impl View) -> bool {
        self.eval(view).truth()
    }

    fn eval(&self, view: &impl View) -> V {
        match self {
            Cond::Bool(b) => V::Bool(*b),
            Cond::Num(n) => V::Num(*n),
            Cond::Str(s) => V::Str(s.clone()),
            Cond::Step(i, on) => V::Bool(match (view.step(*i), on) {
                (Some(_), None) => true,
                (Some(Some(at)), Some(agent)) => at == agent,
                _ => false,
            }),
            Cond::State(s) => V::Bool(view.state() == Some(*s)),
            Cond::Var(v) => match view.value(*v) {
                Value::Bool(b) => V::Bool(b),
                Value::Int(i) | Value::Time(i) => V::Num(i as f64),
                Value::Real(r) => V::Num(r),
                Value::Str(s) => V::Str(s.to_string()),
            },
            Cond::Not(c) => V::Bool(!c.eval(view).truth()),
            Cond::Neg(c) => V::Num(-c.eval(view).num()),
            Cond::Bin(op, a, b) => {
                let (a, b) = (a.eval(view), b.eval(view));
                let cmp = |f: fn(std::cmp::Ordering) -> bool| {
                    let ord = match (&a, &b) {
                        (V::Str(x), V::Str(y)) => Some(x.cmp(y)),
                        _ => a.num().partial_cmp(&b.num()),
                    };
                    V::Bool(ord.is_some_and(f))
                };
                match op {
                    BinOp::Or => V::Bool(a.truth() || b.truth()),
                    BinOp::And => V::Bool(a.truth() && b.truth()),
                    BinOp::Xor => V::Bool(a.truth() != b.truth()),
                    BinOp::Eq => cmp(|o| o.is_eq()),
                    BinOp::Ne => cmp(|o| o.is_ne()),
                    BinOp::Lt => cmp(|o| o.is_lt()),
                    BinOp::Le => cmp(|o| o.is_le()),
                    BinOp::Gt => cmp(|o| o.is_gt()),
                    BinOp::Ge => cmp(|o| o.is_ge()),
                    BinOp::Add => V::Num(a.num() + b.num()),
                    BinOp::Sub => V::Num(a.num() - b.num()),
                    BinOp::Mul => V::Num(a.num() * b.num()),
                    BinOp::Div => V::Num(a.num() / b.num()),
                    BinOp::Mod => V::Num(a.num() % b.num()),
                    BinOp::Pow => V::Num(a.num().powf(b.num())),
                }
            }
        }
    }
}

/// The error for a step the chart lacks, naming those it has.
pub(super) fn no_step(program: &Program, name: &str) -> String {
    let all: Vec<&str> = program.steps.iter().map(|s| s.name.as_str()).collect();
    format!("the chart has no step `{name}` (it has: {})", all.join(", "))
}
