//! The executable form of a chart: names resolved to ids, expressions typed, transitions ranked by priority.
//! The engine runs a `Program`; only `compile` builds one, and only from a chart without errors.

use crate::model::{Pragma, Qualifier, VarSection};
use crate::types::{IntKind, Type, Value};

macro_rules! id {
    ($name:ident) => {
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
        pub struct $name(pub u32);

        impl $name {
            pub fn index(self) -> usize {
                self.0 as usize
            }
        }
    };
}

id!(StepId);
id!(TransitionId);
id!(ActionId);
id!(VarId);

#[derive(Clone, Debug)]
pub struct Program {
    pub name: String,
    pub vars: Vec<VarInfo>,
    pub steps: Vec<StepInfo>,
    pub transitions: Vec<TransitionInfo>,
    pub actions: Vec<ActionInfo>,
    pub initial_steps: Vec<StepId>,
}

#[derive(Clone, Debug)]
pub struct VarInfo {
    /// As first declared.
    pub name: String,
    pub ty: Type,
    pub init: Value,
    pub constant: bool,
    pub section: VarSection,
}

#[derive(Clone, Debug)]
pub struct StepInfo {
    pub name: String,
    pub initial: bool,
    /// Transitions leaving this step, in rank order.
    pub outgoing: Vec<TransitionId>,
    pub associations: Vec<Assoc>,
    pub pragmas: Vec<Pragma>,
}

#[derive(Clone, Debug)]
pub struct Assoc {
    pub action: ActionId,
    pub qualifier: Qualifier,
    pub duration: Option<DurationSrc>,
    pub indicators: Vec<VarId>,
}

#[derive(Clone, Copy, Debug)]
pub enum DurationSrc {
    Ms(i64),
    Var(VarId),
}

#[derive(Clone, Debug)]
pub struct TransitionInfo {
    /// Its name, or `FROM->TO`.
    pub name: String,
    pub sources: Vec<StepId>,
    pub targets: Vec<StepId>,
    pub condition: CExpr,
    /// Position in the clearing order: explicit priorities first (lower first), then declaration order.
    pub rank: u32,
    pub pragmas: Vec<Pragma>,
}

#[derive(Clone, Debug)]
pub struct ActionInfo {
    pub name: String,
    pub body: Vec<CStmt>,
    /// For a boolean action (no body, named after a BOOL variable): the variable its Q drives.
    pub bool_var: Option<VarId>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ArithOp {
    Add,
    Sub,
    Mul,
    Div,
    Mod,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CmpOp {
    Eq,
    Ne,
    Lt,
    Le,
    Gt,
    Ge,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LogicOp {
    And,
    Or,
    Xor,
}

/// A typed expression. Operands of arithmetic carry their values' own representation (an INT operand of a REAL
/// sum is converted at evaluation); `wrap` says which integer width an integer result wraps to.
#[derive(Clone, Debug)]
pub enum CExpr {
    Const(Value),
    Var(VarId),
    StepX(StepId),
    StepT(StepId),
    ActionQ(ActionId),
    Not(Box<CExpr>),
    Neg(Box<CExpr>, Option<IntKind>),
    Logic(LogicOp, Box<CExpr>, Box<CExpr>),
    Cmp(CmpOp, Box<CExpr>, Box<CExpr>),
    Arith { op: ArithOp, wrap: Option<IntKind>, lhs: Box<CExpr>, rhs: Box<CExpr> },
}

#[derive(Clone, Debug)]
pub enum CStmt {
    Assign { var: VarId, value: CExpr },
    If { branches: Vec<(CExpr, Vec<CStmt>)>, otherwise: Vec<CStmt> },
}

impl Program {
    pub fn step_by_name(&self, name: &str) -> Option<StepId> {
        self.steps.iter().position(|s| s.name.eq_ignore_ascii_case(name)).map(|i| StepId(i as u32))
    }

    pub fn var_by_name(&self, name: &str) -> Option<VarId> {
        self.vars.iter().position(|v| v.name.eq_ignore_ascii_case(name)).map(|i| VarId(i as u32))
    }
}
