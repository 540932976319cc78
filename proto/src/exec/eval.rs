//! Evaluates typed expressions and runs action bodies against the engine's state (or none, for constants).

use crate::exec::program::{ActionId, ArithOp, CExpr, CStmt, CmpOp, LogicOp, StepId, VarId};
use crate::exec::types::{IntKind, Value};

/// What an expression can read.
pub trait Env {
    fn var(&self, id: VarId) -> Value;
    fn step_x(&self, id: StepId) -> bool;
    /// `S.T` in milliseconds.
    fn step_t(&self, id: StepId) -> i64;
    fn action_q(&self, id: ActionId) -> bool;
}

/// Storage an action body writes to.
pub trait EnvMut: Env {
    fn set_var(&mut self, id: VarId, value: Value);
}

/// A run-time fault; the engine reports it and carries on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Fault {
    DivisionByZero,
    /// A transition gave an active step a second token (the net is not safe); the tokens merged. Only a chart
    /// whose safety could not be proven (`unverified_net := TRUE`) can get here.
    SecondToken(crate::exec::program::StepId),
}

pub fn eval(e: &CExpr, env: &impl Env) -> Result<Value, Fault> {
    Ok(match e {
        CExpr::Const(v) => *v,
        CExpr::Var(id) => env.var(*id),
        CExpr::StepX(id) => Value::Bool(env.step_x(*id)),
        CExpr::StepT(id) => Value::Time(env.step_t(*id)),
        CExpr::ActionQ(id) => Value::Bool(env.action_q(*id)),
        CExpr::Not(a) => Value::Bool(!eval(a, env)?.as_bool()),
        CExpr::Neg(a, wrap) => match eval(a, env)? {
            Value::Real(r) => Value::Real(-r),
            Value::Time(t) => Value::Time(t.wrapping_neg()),
            v => int(v.as_i64().wrapping_neg(), *wrap),
        },
        CExpr::Logic(op, a, b) => {
            let a = eval(a, env)?.as_bool();
            // No short-circuit is needed for correctness (expressions have no side effects), but it is cheaper.
            match op {
                LogicOp::And => Value::Bool(a && eval(b, env)?.as_bool()),
                LogicOp::Or => Value::Bool(a || eval(b, env)?.as_bool()),
                LogicOp::Xor => Value::Bool(a ^ eval(b, env)?.as_bool()),
            }
        }
        CExpr::Cmp(op, a, b) => Value::Bool(compare(*op, eval(a, env)?, eval(b, env)?)),
        CExpr::Arith { op, wrap, lhs, rhs } => arith(*op, *wrap, eval(lhs, env)?, eval(rhs, env)?)?,
    })
}

fn int(v: i64, wrap: Option<IntKind>) -> Value {
    Value::Int(wrap.map_or(v, |k| k.wrap(v)))
}

fn compare(op: CmpOp, a: Value, b: Value) -> bool {
    let ord = match (a, b) {
        (Value::Real(_), _) | (_, Value::Real(_)) => a.as_f64().partial_cmp(&b.as_f64()),
        _ => Some(a.as_i64().cmp(&b.as_i64())),
    };
    let Some(ord) = ord else {
        // NaN compares unequal to everything.
        return op == CmpOp::Ne;
    };
    match op {
        CmpOp::Eq => ord.is_eq(),
        CmpOp::Ne => ord.is_ne(),
        CmpOp::Lt => ord.is_lt(),
        CmpOp::Le => ord.is_le(),
        CmpOp::Gt => ord.is_gt(),
        CmpOp::Ge => ord.is_ge(),
    }
}

fn arith(op: ArithOp, wrap: Option<IntKind>, a: Value, b: Value) -> Result<Value, Fault> {
    match (a, b) {
        // TIME scaled by a number: TIME * n, n * TIME, TIME / n.
        (Value::Time(t), n @ (Value::Int(_) | Value::Real(_)))
        | (n @ (Value::Int(_) | Value::Real(_)), Value::Time(t)) => {
            let n = n.as_f64();
            match op {
                ArithOp::Mul => Ok(Value::Time((t as f64 * n).round() as i64)),
                _ if n == 0.0 => Err(Fault::DivisionByZero),
                _ => Ok(Value::Time((t as f64 / n).round() as i64)),
            }
        }
        (Value::Time(x), Value::Time(y)) => Ok(Value::Time(match op {
            ArithOp::Sub => x.wrapping_sub(y),
            _ => x.wrapping_add(y),
        })),
        (Value::Real(_), _) | (_, Value::Real(_)) => {
            let (x, y) = (a.as_f64(), b.as_f64());
            Ok(Value::Real(match op {
                ArithOp::Add => x + y,
                ArithOp::Sub => x - y,
                ArithOp::Mul => x * y,
                ArithOp::Div | ArithOp::Mod if y == 0.0 => return Err(Fault::DivisionByZero),
                ArithOp::Div => x / y,
                ArithOp::Mod => x % y,
            }))
        }
        _ => {
            let (x, y) = (a.as_i64(), b.as_i64());
            let v = match op {
                ArithOp::Add => x.wrapping_add(y),
                ArithOp::Sub => x.wrapping_sub(y),
                ArithOp::Mul => x.wrapping_mul(y),
                ArithOp::Div | ArithOp::Mod if y == 0 => return Err(Fault::DivisionByZero),
                ArithOp::Div => x.wrapping_div(y),
                ArithOp::Mod => x.wrapping_rem(y),
            };
            Ok(int(v, wrap))
        }
    }
}

/// Runs statements in order; a fault stops the body where it happened.
pub fn run(body: &[CStmt], env: &mut impl EnvMut) -> Result<(), Fault> {
    for stmt in body {
        match stmt {
            CStmt::Assign { var, value } => {
                let v = eval(value, env)?;
                env.set_var(*var, v);
            }
            CStmt::If { branches, otherwise } => {
                let mut taken = false;
                for (cond, stmts) in branches {
                    if eval(cond, env)?.as_bool() {
                        run(stmts, env)?;
                        taken = true;
                        break;
                    }
                }
                if !taken {
                    run(otherwise, env)?;
                }
            }
        }
    }
    Ok(())
}

/// Whether an expression reads nothing but literals, so that it can be folded at compile time.
pub fn is_constant(e: &CExpr) -> bool {
    match e {
        CExpr::Const(_) => true,
        CExpr::Var(_) | CExpr::StepX(_) | CExpr::StepT(_) | CExpr::ActionQ(_) => false,
        CExpr::Not(a) | CExpr::Neg(a, _) => is_constant(a),
        CExpr::Logic(_, a, b) | CExpr::Cmp(_, a, b) => is_constant(a) && is_constant(b),
        CExpr::Arith { lhs, rhs, .. } => is_constant(lhs) && is_constant(rhs),
    }
}

/// The environment of a constant expression: it reads nothing.
pub struct NoEnv;

impl Env for NoEnv {
    fn var(&self, _: VarId) -> Value {
        Value::Bool(false)
    }
    fn step_x(&self, _: StepId) -> bool {
        false
    }
    fn step_t(&self, _: StepId) -> i64 {
        0
    }
    fn action_q(&self, _: ActionId) -> bool {
        false
    }
}
