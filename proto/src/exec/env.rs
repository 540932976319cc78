//! What compiled code runs against: the state an expression reads (`Env`), the state a body writes (`EnvMut`),
//! and the faults a run can raise. The evaluator and the standard library both take these, so neither depends on
//! the other's internals.

use crate::exec::program::{ActionId, StepId, VarId};
use crate::types::Value;

/// What an expression can read.
pub trait Env {
    fn var(&self, id: VarId) -> Value;
    fn step_x(&self, id: StepId) -> bool;
    /// `S.T` in milliseconds.
    fn step_t(&self, id: StepId) -> i64;
    fn action_q(&self, id: ActionId) -> bool;
    /// `S.overrun`: the step's supervision fault (its `max_ms` passed in this activation).
    fn step_overrun(&self, _id: StepId) -> bool {
        false
    }
    /// The cycle's time in milliseconds, as function blocks see it.
    fn now_ms(&self) -> i64;
}

/// Storage an action body writes to.
pub trait EnvMut: Env {
    fn set_var(&mut self, id: VarId, value: Value);
}

/// A run-time fault; the engine reports it and carries on.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Fault {
    DivisionByZero,
    /// A transition gave an active step a second token (the net is not safe); the tokens merged. Only a chart
    /// whose safety could not be proven (`unverified_net := TRUE`) can get here.
    SecondToken(crate::exec::program::StepId),
    /// A loop ran past the budget of `LOOP_ITERATIONS_MAX` loop passes and block calls of one run of a body.
    LoopLimit,
    /// A call of a user block or function ran past that budget (a tree of calls).
    CallLimit,
    /// MUX's selector named no input.
    MuxSelector,
    /// An array index outside the array's bounds.
    IndexOutOfRange,
    /// CONCAT_DATE, CONCAT_TOD or CONCAT_DT of a date or time that is not on the calendar.
    NoSuchDate,
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
    fn now_ms(&self) -> i64 {
        0
    }
}
