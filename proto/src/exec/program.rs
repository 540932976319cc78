//! The executable form of a chart: names resolved to ids, expressions typed, transitions ranked by priority.
//! The engine runs a `Program`; only `compile` builds one, and only from a chart without errors.
//!
//! The executable form: ids (`StepId`, `TransitionId`, `ActionId`, `VarId`), typed expressions (`CExpr`,
//! `CStmt`; a function call is boxed so that every other node stays small); the data the engine reads each cycle is
//! flat and id-ordered (`Program::assemble`); the function calls a condition needs (hoisted user function calls) are a
//! sparse table beside it (`calls(t)`), read only by programs that have some. `walk_body` is the one walk over
//! statements that says what they write and read (the layout's writers and readers use it).

use std::collections::BTreeMap;

use crate::front::model::{Pragma, Qualifier, VarSection};
use crate::types::library::{Func, StdFb};
use crate::types::{IntKind, Type, Value};

macro_rules! id {
    ($name:ident) => {
        #[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize, serde::Deserialize)]
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

/// A chart ready to run. What the engine reads every cycle (outgoing transitions, associations, arcs, ranks) is
/// kept flat, in id order, apart from what it rarely reads (names, pragmas): a cycle then touches a few
/// neighbouring cache lines per active step however large the chart is.
#[derive(Clone, Debug, Default)]
pub struct Program {
    pub name: String,
    pub vars: Vec<VarInfo>,
    pub steps: Vec<StepInfo>,
    pub transitions: Vec<TransitionInfo>,
    pub actions: Vec<ActionInfo>,
    pub initial_steps: Vec<StepId>,
    /// Step s leaves through `outgoing[outgoing_at[s]..outgoing_at[s + 1]]`, in rank order.
    outgoing_at: Vec<u32>,
    outgoing: Vec<TransitionId>,
    /// Step s's associations are `assocs[assoc_at[s]..assoc_at[s + 1]]`; `indicators` runs beside `assocs`.
    assoc_at: Vec<u32>,
    assocs: Vec<Assoc>,
    indicators: Vec<Vec<VarId>>,
    /// Transition t's sources are `arcs[arcs_at[2t]..arcs_at[2t + 1]]`, its targets up to `arcs_at[2t + 2]`.
    arcs_at: Vec<u32>,
    arcs: Vec<StepId>,
    /// Position in the clearing order: explicit priorities first (lower first), then declaration order.
    ranks: Vec<u32>,
    /// What each transition's condition reads.
    reads: Vec<Reads>,
    /// The block calls of transitions whose wired conditions need them, by transition (rare: kept apart so
    /// that the data a cycle reads stays dense).
    calls: Vec<(TransitionId, Vec<CStmt>)>,
}

/// What a condition reads: the engine judges a transition between cycles (in a reaction to a message) only if
/// its condition reads no step time, and only when something it reads changed.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Reads {
    pub vars: Vec<VarId>,
    /// It reads a step's `X` or an action's `Q`.
    pub steps_or_actions: bool,
    /// It reads a step's `T`, or calls a user function first (whose body may read the clock).
    pub step_time: bool,
    /// It reads a step's supervision fault (`S.overrun`): a transition of the chart's own recovery, which clears
    /// though the fault is not acknowledged.
    pub overrun: bool,
}

impl Reads {
    pub fn of(e: &CExpr) -> Reads {
        let mut reads = Reads::default();
        reads.walk(e);
        reads.vars.sort_unstable();
        reads.vars.dedup();
        reads
    }

    fn walk(&mut self, e: &CExpr) {
        match e {
            CExpr::Const(_) => {}
            CExpr::Var(v) => self.vars.push(*v),
            CExpr::StepX(_) | CExpr::ActionQ(_) => self.steps_or_actions = true,
            CExpr::StepT(_) => self.step_time = true,
            CExpr::StepOverrun(_) => {
                self.overrun = true;
                self.step_time = true;
            }
            CExpr::NestedT(v) => {
                self.vars.extend(v.iter());
                self.step_time = true;
            }
            CExpr::Not(a) | CExpr::Neg(a, _) => self.walk(a),
            CExpr::Logic(_, a, b) | CExpr::Cmp(_, a, b) | CExpr::Arith { lhs: a, rhs: b, .. } => {
                self.walk(a);
                self.walk(b);
            }
            CExpr::Call(c) => c.args.iter().for_each(|a| self.walk(a)),
            CExpr::Index(ix) => {
                self.vars.extend((0..ix.len).map(|i| VarId(ix.base.0 + i)));
                ix.indices.iter().for_each(|e| self.walk(e));
            }
        }
    }
}

/// A step as `compile` hands it to `Program::assemble`.
pub struct StepParts {
    pub info: StepInfo,
    pub associations: Vec<(Assoc, Vec<VarId>)>,
}

/// A transition as `compile` hands it to `Program::assemble`.
pub struct TransitionParts {
    pub info: TransitionInfo,
    /// The user function calls the condition needs, run before it is judged.
    pub calls: Vec<CStmt>,
    pub sources: Vec<StepId>,
    pub targets: Vec<StepId>,
    pub rank: u32,
}

#[derive(Clone, Debug)]
pub struct VarInfo {
    /// As first declared.
    pub name: String,
    pub ty: Type,
    pub init: Value,
    pub constant: bool,
    pub section: VarSection,
    /// Internal state of a function block instance (`t1.STATE`): not readable or settable by name.
    pub hidden: bool,
}

#[derive(Clone, Debug)]
pub struct StepInfo {
    pub name: String,
    pub initial: bool,
    pub pragmas: Vec<Pragma>,
    /// `{min_ms := 200}`: no transition out of the step clears before it has been active this long (step
    /// supervision's minimum time); 0 without it.
    pub min_ms: u64,
    /// `{max_ms := 5000}`: active longer than this, the step is faulted (`S.overrun`), and its outgoing transitions
    /// clear only once the fault is acknowledged — except those that read `S.overrun`, the chart's own recovery;
    /// 0 without it.
    pub max_ms: u64,
}

#[derive(Clone, Copy, Debug)]
pub struct Assoc {
    pub action: ActionId,
    pub qualifier: Qualifier,
    pub duration: Option<DurationSrc>,
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
    pub condition: CExpr,
    pub pragmas: Vec<Pragma>,
}

/// An action with no final scan: one that runs once when its step is left (`Exit`) or entered (`Entry`), or
/// every cycle while it is active (`Active`, CODESYS's main step action), in that order within a cycle and before
/// the others.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Once {
    Exit = 0,
    Entry = 1,
    Active = 2,
}

#[derive(Clone, Debug)]
pub struct ActionInfo {
    pub name: String,
    pub body: Vec<CStmt>,
    /// An action associated only as a step's entry, exit or main action (CODESYS vendor data): its body runs with
    /// no final scan, before the other actions of its cycle.
    pub once: Option<Once>,
    /// For a boolean action (no body, named after a BOOL variable): the variable its Q drives.
    pub bool_var: Option<VarId>,
    pub pragmas: Vec<Pragma>,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ArithOp {
    Add,
    Sub,
    Mul,
    Div,
    Mod,
    Pow,
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
    /// `S.overrun`: the step has been active longer than its `max_ms` (this activation).
    StepOverrun(StepId),
    ActionQ(ActionId),
    Not(Box<CExpr>),
    Neg(Box<CExpr>, Option<IntKind>),
    Logic(LogicOp, Box<CExpr>, Box<CExpr>),
    Cmp(CmpOp, Box<CExpr>, Box<CExpr>),
    Arith {
        op: ArithOp,
        wrap: Option<IntKind>,
        lhs: Box<CExpr>,
        rhs: Box<CExpr>,
    },
    /// A standard function (boxed: rare, and it would make every expression node larger).
    Call(Box<FnCall>),
    /// An array element whose index is known only at run time.
    Index(Box<IndexExpr>),
    /// `S.T` of a step of a nested chart, from its variables `[x, since, last]`: the time since it became active
    /// while it is, else how long it was active last.
    NestedT(Box<[VarId; 3]>),
}

/// `a[i, j]`: the element `base + offset`, the offset row-major from the indices and the bounds; an index
/// outside its bounds is a fault.
#[derive(Clone, Debug)]
pub struct IndexExpr {
    pub base: VarId,
    pub dims: Vec<(i64, i64)>,
    pub indices: Vec<CExpr>,
    /// Variables of the array (elements times `stride`).
    pub len: u32,
    /// Variables per element (1, or a structure's fields), and which of them is meant.
    pub stride: u32,
    pub offset: u32,
}

/// A standard function call; the result is converted to `ty` (its integer width, REAL's precision).
#[derive(Clone, Debug)]
pub struct FnCall {
    pub func: Func,
    pub args: Vec<CExpr>,
    pub ty: Type,
}

impl CExpr {
    pub fn call(func: Func, args: Vec<CExpr>, ty: Type) -> CExpr {
        CExpr::Call(Box::new(FnCall { func, args, ty }))
    }
}

#[derive(Clone, Debug)]
pub enum CStmt {
    Assign {
        var: VarId,
        value: CExpr,
    },
    /// `a[i] := value` with an index known only at run time.
    AssignIndex {
        target: Box<IndexExpr>,
        value: CExpr,
    },
    If {
        branches: Vec<(CExpr, Vec<CStmt>)>,
        otherwise: Vec<CStmt>,
    },
    /// A call of the standard block instance whose members start at `base`: inputs assigned in order, then (when
    /// `en` is absent or TRUE) the block runs and ENO is TRUE, else ENO is FALSE; then outputs are copied out.
    Fb {
        fb: StdFb,
        base: VarId,
        en: Option<CExpr>,
        inputs: Vec<(VarId, CExpr)>,
        outputs: Vec<FbOutput>,
    },
    /// A call of a user function block instance: inputs assigned, in-outs copied in, the instance's body run
    /// (when `en` is absent or TRUE), ENO set, in-outs copied back, outputs copied out.
    UserFb(Box<UserCall>),
    /// Arms in order; an arm's labels are inclusive ranges of selector values.
    Case {
        selector: CExpr,
        arms: Vec<CaseArm>,
        otherwise: Vec<CStmt>,
    },
    /// `FOR var := from TO to BY by`: `to` and `by` are evaluated once, before the first iteration.
    For {
        var: VarId,
        from: CExpr,
        to: CExpr,
        by: CExpr,
        body: Vec<CStmt>,
    },
    /// `pre` (the function calls the condition needs) runs before each evaluation of the condition.
    While {
        pre: Vec<CStmt>,
        condition: CExpr,
        body: Vec<CStmt>,
    },
    Repeat {
        body: Vec<CStmt>,
        pre: Vec<CStmt>,
        until: CExpr,
    },
    /// One scan of a chart that is an action's body (`NestedChart`).
    Chart(Box<NestedChart>),
    Exit,
    Return,
}

/// An action written in SFC, compiled: its state is variables (each step's X, when it became active, how long it
/// was last active; each controlled action's Q and stored S), so that it lives in the engine's flat array and
/// travels with the other variables. Each run of the action that holds it is one scan: judge the transitions
/// (clearing order, a step's token taken once), move the tokens, then compute the controlled actions' Q from
/// their associations and run the bodies whose Q is TRUE or has just fallen. Between runs it stands still; the
/// action's final run (its Q fell) resets it, as CODESYS does: its steps go off and the actions it holds end with
/// their final runs, so that the next activation starts at its initial steps.
#[derive(Clone, Debug)]
pub struct NestedChart {
    /// FALSE until the first scan, which activates the initial steps (their time counts from it).
    pub started: VarId,
    /// The Q of the action it is the body of, where it is associated with a step (the chart's, another nested
    /// chart's): a run with Q FALSE — the action's final run — resets the chart instead of scanning it. `None`
    /// for an action only called (`A();`, `inst.A();`), which every call scans.
    pub q: Option<CExpr>,
    /// CODESYS's SFC flags, where the POU declares and uses them: `SFCInit` TRUE holds the chart reset at its
    /// initial steps, running nothing; `SFCReset` TRUE resets it to them and runs their actions.
    pub init: Option<VarId>,
    pub reset: Option<VarId>,
    pub steps: Vec<NestedStep>,
    /// In clearing order.
    pub transitions: Vec<NestedTransition>,
    pub actions: Vec<NestedAction>,
}

#[derive(Clone, Debug)]
pub struct NestedStep {
    pub initial: bool,
    pub x: VarId,
    /// When the step became active (ms, the cycle's time).
    pub since: VarId,
    /// How long it was active the last time (`S.T` while it is inactive).
    pub last: VarId,
}

#[derive(Clone, Debug)]
pub struct NestedTransition {
    pub sources: Vec<usize>,
    pub targets: Vec<usize>,
    /// The user function calls the condition needs, run before it is judged.
    pub calls: Vec<CStmt>,
    pub condition: CExpr,
}

#[derive(Clone, Debug)]
pub struct NestedAction {
    pub q: VarId,
    pub stored: VarId,
    /// A boolean action's variable, which follows Q.
    pub bool_var: Option<VarId>,
    pub body: std::sync::Arc<Vec<CStmt>>,
    /// Whether its body runs once more when its Q falls: not where every association is a CODESYS step action
    /// (main, entry or exit), which has no final scan.
    pub final_run: bool,
    /// (step, qualifier, duration in ms for L and D).
    pub associations: Vec<(usize, crate::front::model::Qualifier, Option<DurationSrc>)>,
}

impl NestedChart {
    /// Every variable a scan may write, its own state first.
    pub fn state(&self) -> impl Iterator<Item = VarId> + '_ {
        let steps = self.steps.iter().flat_map(|s| [s.x, s.since, s.last]);
        let actions = self.actions.iter().flat_map(|a| [a.q, a.stored].into_iter().chain(a.bool_var));
        std::iter::once(self.started).chain(steps).chain(actions)
    }
}

/// How deep running `body` nests — a compound statement, an operator, a call, an index each one level; a leaf
/// none — counting the bodies it runs: user blocks and functions (`UserFb`) and nested charts, each at the level
/// of its call. The walk inside a body uses a stack of its own, and each shared body is measured once (`memo`,
/// by address), so a body called from many places costs one walk; what recursion remains follows the nesting of
/// blocks, functions and charts, which the compiler bounds.
pub fn exec_depth(body: &[CStmt], memo: &mut BTreeMap<*const Vec<CStmt>, usize>) -> usize {
    measure(vec![(Item::Stmts(body), 0)], memo)
}

/// The same for a transition: the calls its condition needs, and the condition.
pub fn condition_depth(calls: &[CStmt], condition: &CExpr, memo: &mut BTreeMap<*const Vec<CStmt>, usize>) -> usize {
    measure(vec![(Item::Stmts(calls), 0), (Item::Expr(condition), 0)], memo)
}

enum Item<'b> {
    Stmts(&'b [CStmt]),
    Expr(&'b CExpr),
    /// A shared body, run at this level.
    Body(&'b std::sync::Arc<Vec<CStmt>>),
}

fn measure(start: Vec<(Item, usize)>, memo: &mut BTreeMap<*const Vec<CStmt>, usize>) -> usize {
    let mut max = 0;
    let mut stack = start;
    while let Some((item, level)) = stack.pop() {
        max = max.max(level);
        match item {
            Item::Body(b) => {
                let key = std::sync::Arc::as_ptr(b);
                let d = match memo.get(&key) {
                    Some(&d) => d,
                    None => {
                        let d = exec_depth(b, memo);
                        memo.insert(key, d);
                        d
                    }
                };
                max = max.max(level + d);
            }
            Item::Expr(e) => {
                let inner = level + 1;
                match e {
                    CExpr::Not(c) | CExpr::Neg(c, _) => stack.push((Item::Expr(c), inner)),
                    CExpr::Logic(_, a, b) | CExpr::Cmp(_, a, b) | CExpr::Arith { lhs: a, rhs: b, .. } => {
                        stack.push((Item::Expr(a), inner));
                        stack.push((Item::Expr(b), inner));
                    }
                    CExpr::Call(call) => stack.extend(call.args.iter().map(|a| (Item::Expr(a), inner))),
                    CExpr::Index(ix) => stack.extend(ix.indices.iter().map(|a| (Item::Expr(a), inner))),
                    _ => {}
                }
            }
            Item::Stmts(stmts) => {
                let inner = level + 1;
                for stmt in stmts {
                    match stmt {
                        CStmt::Assign { value, .. } => stack.push((Item::Expr(value), level)),
                        CStmt::AssignIndex { target, value } => {
                            stack.push((Item::Expr(value), level));
                            stack.extend(target.indices.iter().map(|e| (Item::Expr(e), inner)));
                        }
                        CStmt::If { branches, otherwise } => {
                            for (c, b) in branches {
                                stack.push((Item::Expr(c), inner));
                                stack.push((Item::Stmts(b), inner));
                            }
                            stack.push((Item::Stmts(otherwise), inner));
                        }
                        CStmt::Fb { en, inputs, .. } => {
                            stack.extend(en.iter().map(|e| (Item::Expr(e), inner)));
                            stack.extend(inputs.iter().map(|(_, e)| (Item::Expr(e), inner)));
                        }
                        CStmt::UserFb(call) => {
                            stack.extend(call.en.iter().map(|e| (Item::Expr(e), inner)));
                            stack.extend(call.inputs.iter().map(|(_, e)| (Item::Expr(e), inner)));
                            stack.push((Item::Body(&call.body), inner));
                        }
                        CStmt::Case { selector, arms, otherwise } => {
                            stack.push((Item::Expr(selector), inner));
                            stack.extend(arms.iter().map(|(_, b)| (Item::Stmts(b), inner)));
                            stack.push((Item::Stmts(otherwise), inner));
                        }
                        CStmt::For { from, to, by, body, .. } => {
                            stack.extend([from, to, by].map(|e| (Item::Expr(e), inner)));
                            stack.push((Item::Stmts(body), inner));
                        }
                        CStmt::While { pre, condition: c, body } | CStmt::Repeat { body, pre, until: c } => {
                            stack.push((Item::Stmts(pre), inner));
                            stack.push((Item::Expr(c), inner));
                            stack.push((Item::Stmts(body), inner));
                        }
                        CStmt::Chart(chart) => {
                            stack.extend(chart.q.iter().map(|q| (Item::Expr(q), inner)));
                            for t in &chart.transitions {
                                stack.push((Item::Stmts(&t.calls), inner));
                                stack.push((Item::Expr(&t.condition), inner));
                            }
                            stack.extend(chart.actions.iter().map(|a| (Item::Body(&a.body), inner)));
                        }
                        CStmt::Exit | CStmt::Return => {}
                    }
                }
            }
        }
    }
    max
}

/// Walks statements: `write` gets every variable they may write, `read` every expression they evaluate (a block
/// call reads its instance's members too). A body shared by several calls (a user block's, a function's) is
/// walked once: what it may write and read does not depend on how often it runs, and a chain of blocks each
/// calling the next twice would otherwise cost 2^depth.
pub fn walk_body(body: &[CStmt], write: &mut impl FnMut(VarId), read: &mut impl FnMut(&CExpr)) {
    walk_body_once(body, write, read, &mut std::collections::BTreeSet::new());
}

fn walk_body_once(
    body: &[CStmt],
    write: &mut impl FnMut(VarId),
    read: &mut impl FnMut(&CExpr),
    seen: &mut std::collections::BTreeSet<*const Vec<CStmt>>,
) {
    for stmt in body {
        match stmt {
            CStmt::Assign { var, value } => {
                write(*var);
                read(value);
            }
            CStmt::AssignIndex { target, value } => {
                (0..target.len).for_each(|i| write(VarId(target.base.0 + i)));
                target.indices.iter().for_each(&mut *read);
                read(value);
            }
            CStmt::If { branches, otherwise } => {
                for (c, b) in branches {
                    read(c);
                    walk_body_once(b, write, read, seen);
                }
                walk_body_once(otherwise, write, read, seen);
            }
            CStmt::Fb { fb, base, en, inputs, outputs } => {
                en.iter().for_each(&mut *read);
                inputs.iter().for_each(|(_, e)| read(e));
                for i in 0..fb.size() {
                    let member = VarId(base.0 + i);
                    write(member);
                    read(&CExpr::Var(member));
                }
                outputs.iter().for_each(|o| write(o.target));
            }
            CStmt::UserFb(call) => {
                call.en.iter().for_each(&mut *read);
                for (member, e) in &call.inputs {
                    write(*member);
                    read(e);
                }
                for &(member, caller) in &call.inouts {
                    write(member);
                    write(caller);
                    read(&CExpr::Var(caller));
                }
                if seen.insert(std::sync::Arc::as_ptr(&call.body)) {
                    walk_body_once(&call.body, write, read, seen);
                }
                write(call.eno);
                call.outputs.iter().for_each(|o| write(o.target));
            }
            CStmt::Case { selector, arms, otherwise } => {
                read(selector);
                arms.iter().for_each(|(_, b)| walk_body_once(b, write, read, seen));
                walk_body_once(otherwise, write, read, seen);
            }
            CStmt::For { var, from, to, by, body } => {
                write(*var);
                read(&CExpr::Var(*var));
                read(from);
                read(to);
                read(by);
                walk_body_once(body, write, read, seen);
            }
            CStmt::While { pre, condition: c, body } | CStmt::Repeat { body, pre, until: c } => {
                walk_body_once(pre, write, read, seen);
                read(c);
                walk_body_once(body, write, read, seen);
            }
            CStmt::Chart(chart) => {
                for v in chart.state() {
                    write(v);
                    read(&CExpr::Var(v));
                }
                if let Some(q) = &chart.q {
                    read(q);
                }
                for v in chart.init.iter().chain(&chart.reset) {
                    read(&CExpr::Var(*v));
                }
                for t in &chart.transitions {
                    walk_body_once(&t.calls, write, read, seen);
                    read(&t.condition);
                }
                for a in &chart.actions {
                    for (_, _, d) in &a.associations {
                        if let Some(DurationSrc::Var(v)) = d {
                            read(&CExpr::Var(*v));
                        }
                    }
                    if seen.insert(std::sync::Arc::as_ptr(&a.body)) {
                        walk_body_once(&a.body, write, read, seen);
                    }
                }
            }
            CStmt::Exit | CStmt::Return => {}
        }
    }
}

#[derive(Clone, Debug)]
pub struct UserCall {
    /// The instance's body, compiled for its variables (shared by every call of the instance).
    pub body: std::sync::Arc<Vec<CStmt>>,
    pub en: Option<CExpr>,
    pub inputs: Vec<(VarId, CExpr)>,
    /// (the instance's variable, the caller's): copied in before the body, back after it.
    pub inouts: Vec<(VarId, VarId)>,
    pub outputs: Vec<FbOutput>,
    pub eno: VarId,
}

/// One CASE arm: its labels as inclusive ranges, and its body.
pub type CaseArm = (Vec<(i64, i64)>, Vec<CStmt>);

/// `Q => done` (or `NOT Q => waiting`) of a call: a member copied to a variable after the call.
#[derive(Clone, Copy, Debug)]
pub struct FbOutput {
    pub member: VarId,
    pub target: VarId,
    pub negated: bool,
}

fn range(at: &[u32], i: usize) -> std::ops::Range<usize> {
    at[i] as usize..at[i + 1] as usize
}

impl Program {
    pub fn assemble(
        name: String,
        vars: Vec<VarInfo>,
        steps: Vec<StepParts>,
        transitions: Vec<TransitionParts>,
        actions: Vec<ActionInfo>,
    ) -> Program {
        let initial_steps =
            steps.iter().enumerate().filter(|(_, s)| s.info.initial).map(|(i, _)| StepId(i as u32)).collect();
        let mut leaving: Vec<Vec<TransitionId>> = vec![Vec::new(); steps.len()];
        let mut by_rank: Vec<usize> = (0..transitions.len()).collect();
        by_rank.sort_by_key(|&i| transitions[i].rank);
        for i in by_rank {
            for s in &transitions[i].sources {
                leaving[s.index()].push(TransitionId(i as u32));
            }
        }
        let mut outgoing_at = Vec::with_capacity(steps.len() + 1);
        let mut outgoing = Vec::with_capacity(transitions.len());
        for list in leaving {
            outgoing_at.push(outgoing.len() as u32);
            outgoing.extend(list);
        }
        outgoing_at.push(outgoing.len() as u32);
        let (mut assoc_at, mut assocs, mut indicators) = (Vec::with_capacity(steps.len() + 1), Vec::new(), Vec::new());
        let mut infos = Vec::with_capacity(steps.len());
        for step in steps {
            assoc_at.push(assocs.len() as u32);
            for (assoc, inds) in step.associations {
                assocs.push(assoc);
                indicators.push(inds);
            }
            infos.push(step.info);
        }
        assoc_at.push(assocs.len() as u32);
        let (mut arcs_at, mut arcs, mut ranks) =
            (Vec::with_capacity(2 * transitions.len() + 1), Vec::new(), Vec::new());
        let reads = transitions
            .iter()
            .map(|t| {
                let mut reads = Reads::of(&t.info.condition);
                // A call may read the clock, and a source's minimum time is a reading of its step time: judged
                // in cycles only, never in a reaction.
                reads.step_time |= !t.calls.is_empty();
                reads.step_time |= t.sources.iter().any(|s| infos[s.index()].min_ms > 0);
                reads
            })
            .collect();
        let mut tinfos = Vec::with_capacity(transitions.len());
        let mut calls = Vec::new();
        for (i, t) in transitions.into_iter().enumerate() {
            if !t.calls.is_empty() {
                calls.push((TransitionId(i as u32), t.calls));
            }
            arcs_at.push(arcs.len() as u32);
            arcs.extend(t.sources);
            arcs_at.push(arcs.len() as u32);
            arcs.extend(t.targets);
            ranks.push(t.rank);
            tinfos.push(t.info);
        }
        arcs_at.push(arcs.len() as u32);
        Program {
            name,
            vars,
            steps: infos,
            transitions: tinfos,
            actions,
            initial_steps,
            outgoing_at,
            outgoing,
            assoc_at,
            assocs,
            indicators,
            arcs_at,
            arcs,
            ranks,
            reads,
            calls,
        }
    }

    /// The block calls transition t's condition needs first.
    pub fn calls(&self, t: TransitionId) -> &[CStmt] {
        match self.calls.binary_search_by_key(&t, |(u, _)| *u) {
            Ok(i) => &self.calls[i].1,
            Err(_) => &[],
        }
    }

    /// Whether any transition's condition calls a user function.
    pub fn has_calls(&self) -> bool {
        !self.calls.is_empty()
    }

    /// What transition t's condition reads.
    pub fn reads(&self, t: TransitionId) -> &Reads {
        &self.reads[t.index()]
    }

    /// Transitions leaving a step, in rank order.
    pub fn outgoing(&self, s: StepId) -> &[TransitionId] {
        &self.outgoing[range(&self.outgoing_at, s.index())]
    }

    pub fn associations(&self, s: StepId) -> &[Assoc] {
        &self.assocs[range(&self.assoc_at, s.index())]
    }

    /// The indicator variables of each of a step's associations, in the same order as `associations`.
    pub fn indicators(&self, s: StepId) -> &[Vec<VarId>] {
        &self.indicators[range(&self.assoc_at, s.index())]
    }

    pub fn sources(&self, t: TransitionId) -> &[StepId] {
        &self.arcs[range(&self.arcs_at, 2 * t.index())]
    }

    pub fn targets(&self, t: TransitionId) -> &[StepId] {
        &self.arcs[range(&self.arcs_at, 2 * t.index() + 1)]
    }

    pub fn rank(&self, t: TransitionId) -> u32 {
        self.ranks[t.index()]
    }

    /// A variable by name (`t1.Q` for an instance's member); hidden state has none.
    /// The step named `name` (steps' names are unique in a chart, case-insensitively).
    pub fn step_by_name(&self, name: &str) -> Option<StepId> {
        self.steps.iter().position(|s| s.name.eq_ignore_ascii_case(name)).map(|i| StepId(i as u32))
    }

    /// The transition named `name`.
    pub fn transition_by_name(&self, name: &str) -> Option<TransitionId> {
        self.transitions.iter().position(|t| t.name.eq_ignore_ascii_case(name)).map(|i| TransitionId(i as u32))
    }

    pub fn var_by_name(&self, name: &str) -> Option<VarId> {
        self.vars.iter().position(|v| !v.hidden && v.name.eq_ignore_ascii_case(name)).map(|i| VarId(i as u32))
    }
}
