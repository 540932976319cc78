//! Evaluates typed expressions and runs action bodies against the engine's state (or none, for constants).
//!
//! Evaluation of `CExpr` and execution of `CStmt` against the `Env`/`EnvMut` traits; loops (FOR, WHILE,
//! REPEAT) share one budget of `LOOP_ITERATIONS_MAX` per run of a body, past which it stops with `Fault::LoopLimit`;
//! EXIT and RETURN are control flow (`Flow`), not faults.

pub use crate::exec::env::{Env, EnvMut, Fault, NoEnv};
use crate::exec::program::{
    ArithOp, CExpr, CStmt, CmpOp, DurationSrc, LogicOp, NestedChart, NestedStep, UserCall, VarId,
};
use crate::exec::stdlib;
use crate::front::model::Qualifier;
use crate::limits::LOOP_ITERATIONS_MAX;
use crate::types::library::Func;
use crate::types::{IntKind, Type, Value};

/// The element an index expression names.
fn element(ix: &crate::exec::program::IndexExpr, env: &impl Env) -> Result<VarId, Fault> {
    let mut offset: i64 = 0;
    for (e, &(low, high)) in ix.indices.iter().zip(&ix.dims) {
        let i = eval(e, env)?.as_i64();
        if i < low || i > high {
            return Err(Fault::IndexOutOfRange);
        }
        offset = offset * (high - low + 1) + (i - low);
    }
    Ok(VarId(ix.base.0 + ix.offset + offset as u32 * ix.stride))
}

pub fn eval(e: &CExpr, env: &impl Env) -> Result<Value, Fault> {
    Ok(match e {
        CExpr::Const(v) => v.clone(),
        CExpr::Var(id) => env.var(*id),
        CExpr::StepX(id) => Value::Bool(env.step_x(*id)),
        CExpr::StepT(id) => Value::Time(env.step_t(*id)),
        CExpr::StepOverrun(id) => Value::Bool(env.step_overrun(*id)),
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
        CExpr::Cmp(op, a, b) => Value::Bool(compare(*op, &eval(a, env)?, &eval(b, env)?)),
        CExpr::Arith { op, wrap, lhs, rhs } => arith(*op, *wrap, &eval(lhs, env)?, &eval(rhs, env)?)?,
        CExpr::Call(c) => c.ty.coerce(call(&c.func, &c.args, &c.ty, env)?),
        CExpr::Index(ix) => env.var(element(ix, env)?),
        CExpr::NestedT(v) => {
            let [x, since, last] = **v;
            if env.var(x).as_bool() {
                Value::Time(env.now_ms() - env.var(since).as_i64())
            } else {
                env.var(last)
            }
        }
    })
}

fn call(func: &Func, args: &[CExpr], ty: &Type, env: &impl Env) -> Result<Value, Fault> {
    let arg = |i: usize| eval(&args[i], env);
    let wrap = match ty {
        Type::Int(k) => Some(*k),
        _ => None,
    };
    Ok(match func {
        Func::Abs => match arg(0)? {
            Value::Real(r) => Value::Real(r.abs()),
            v => int(v.as_i64().wrapping_abs(), wrap),
        },
        Func::Real(f) => Value::Real(f.apply(arg(0)?.as_f64())),
        Func::Atan2 => Value::Real(arg(0)?.as_f64().atan2(arg(1)?.as_f64())),
        // The REAL's integer part, saturated to i64; `coerce` wraps it to the result's type.
        Func::Trunc(_) => Value::Int(arg(0)?.as_f64().trunc() as i64),
        Func::BcdToInt(_) => int(stdlib::bcd_to_int(arg(0)?.as_i64()).unwrap_or(0), wrap),
        Func::IntToBcd(_) => int(stdlib::int_to_bcd(arg(0)?.as_i64()), wrap),
        Func::IsValid => Value::Bool(arg(0)?.as_f64().is_finite()),
        Func::IsValidBcd => Value::Bool(stdlib::bcd_to_int(arg(0)?.as_i64()).is_some()),
        Func::SwapBytes => {
            let kind = wrap.unwrap_or(IntKind::Lword);
            let swapped = (arg(0)?.as_i64() as u64).swap_bytes() >> (64 - kind.bits());
            int(swapped as i64, wrap)
        }
        Func::Date(f) => {
            let mut values = Vec::with_capacity(args.len());
            for a in args {
                values.push(eval(a, env)?);
            }
            stdlib::date(*f, &values)?
        }
        Func::Expt => arith(ArithOp::Pow, wrap, &arg(0)?, &arg(1)?)?,
        Func::Move => arg(0)?,
        Func::Sel => {
            if arg(0)?.as_bool() {
                arg(2)?
            } else {
                arg(1)?
            }
        }
        Func::Max | Func::Min => {
            let mut best = arg(0)?;
            for a in &args[1..] {
                let v = eval(a, env)?;
                let better = compare(if matches!(func, Func::Max) { CmpOp::Gt } else { CmpOp::Lt }, &v, &best);
                if better {
                    best = v;
                }
            }
            best
        }
        Func::Limit => {
            let (mn, x, mx) = (arg(0)?, arg(1)?, arg(2)?);
            if compare(CmpOp::Lt, &x, &mn) {
                mn
            } else if compare(CmpOp::Gt, &x, &mx) {
                mx
            } else {
                x
            }
        }
        Func::Mux => {
            let k = arg(0)?.as_i64();
            if k < 0 || k as usize >= args.len() - 1 {
                return Err(Fault::MuxSelector);
            }
            arg(k as usize + 1)?
        }
        Func::Shl | Func::Shr | Func::Rol | Func::Ror => {
            let kind = wrap.unwrap_or(IntKind::Lword);
            Value::Int(stdlib::shift(func, arg(0)?.as_i64(), arg(1)?.as_i64(), kind))
        }
        Func::Convert(to) => stdlib::convert(arg(0)?, to),
        Func::ToString(from) => Value::string(stdlib::to_string(from, &arg(0)?)),
        Func::Text(f) => {
            let mut values = Vec::with_capacity(args.len());
            for a in args {
                values.push(eval(a, env)?);
            }
            stdlib::text(*f, &values)
        }
        Func::BitAnd => int(arg(0)?.as_i64() & arg(1)?.as_i64(), wrap),
        Func::BitOr => int(arg(0)?.as_i64() | arg(1)?.as_i64(), wrap),
        Func::BitXor => int(arg(0)?.as_i64() ^ arg(1)?.as_i64(), wrap),
        Func::BitNot => int(!arg(0)?.as_i64(), wrap),
    })
}

fn int(v: i64, wrap: Option<IntKind>) -> Value {
    Value::Int(wrap.map_or(v, |k| k.wrap(v)))
}

fn compare(op: CmpOp, a: &Value, b: &Value) -> bool {
    let ord = match (a, b) {
        (Value::Str(x), Value::Str(y)) => Some(x.as_str().cmp(y.as_str())),
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

fn arith(op: ArithOp, wrap: Option<IntKind>, a: &Value, b: &Value) -> Result<Value, Fault> {
    match (a, b) {
        // TIME scaled by a number: TIME * n, n * TIME, TIME / n.
        (&Value::Time(t), n @ (Value::Int(_) | Value::Real(_)))
        | (n @ (Value::Int(_) | Value::Real(_)), &Value::Time(t)) => {
            let n = n.as_f64();
            match op {
                ArithOp::Mul | ArithOp::Pow => Ok(Value::Time((t as f64 * n).round() as i64)),
                _ if n == 0.0 => Err(Fault::DivisionByZero),
                _ => Ok(Value::Time((t as f64 / n).round() as i64)),
            }
        }
        (&Value::Time(x), &Value::Time(y)) => Ok(Value::Time(match op {
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
                ArithOp::Pow => x.powf(y),
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
                ArithOp::Pow => stdlib::int_pow(x, y, None),
            };
            Ok(int(v, wrap))
        }
    }
}

/// Runs a body; a fault stops it where it happened. Its loops' passes and its calls of user blocks and functions
/// together may number `LOOP_ITERATIONS_MAX`: past that the body stops with `Fault::LoopLimit`, so that no loop,
/// and no tree of calls, hangs a cycle.
pub fn run(body: &[CStmt], env: &mut impl EnvMut) -> Result<(), Fault> {
    let mut budget = LOOP_ITERATIONS_MAX;
    exec(body, env, &mut budget).map(|_| ())
}

/// How a run of statements ended.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Flow {
    Next,
    Exit,
    Return,
}

fn tick(budget: &mut usize) -> Result<(), Fault> {
    *budget = budget.checked_sub(1).ok_or(Fault::LoopLimit)?;
    Ok(())
}

/// One pass of a loop's body: `Some` of how the loop statement ends (EXIT ends only the loop, RETURN the body
/// around it too) when the body left the loop, `None` to go on.
fn iteration(body: &[CStmt], env: &mut impl EnvMut, budget: &mut usize) -> Result<Option<Flow>, Fault> {
    Ok(match exec(body, env, budget)? {
        Flow::Exit => Some(Flow::Next),
        Flow::Return => Some(Flow::Return),
        Flow::Next => None,
    })
}

/// `Q => x` and `NOT Q => y` of a call: the block's outputs copied out after it ran.
fn copy_outputs(outputs: &[crate::exec::program::FbOutput], env: &mut impl EnvMut) {
    for out in outputs {
        let v = env.var(out.member);
        env.set_var(out.target, if out.negated { Value::Bool(!v.as_bool()) } else { v });
    }
}

fn exec(body: &[CStmt], env: &mut impl EnvMut, budget: &mut usize) -> Result<Flow, Fault> {
    for stmt in body {
        let flow = match stmt {
            CStmt::Assign { var, value } => {
                let v = eval(value, env)?;
                env.set_var(*var, v);
                Flow::Next
            }
            CStmt::AssignIndex { target, value } => {
                let v = eval(value, env)?;
                let var = element(target, env)?;
                env.set_var(var, v);
                Flow::Next
            }
            CStmt::If { branches, otherwise } => {
                let mut taken = None;
                for (cond, stmts) in branches {
                    if eval(cond, env)?.as_bool() {
                        taken = Some(stmts);
                        break;
                    }
                }
                exec(taken.unwrap_or(otherwise), env, budget)?
            }
            CStmt::Fb { fb, base, en, inputs, outputs } => {
                for (member, value) in inputs {
                    let v = eval(value, env)?;
                    env.set_var(*member, v);
                }
                let enabled = match en {
                    Some(e) => eval(e, env)?.as_bool(),
                    None => true,
                };
                if enabled {
                    stdlib::run_fb(*fb, *base, env);
                }
                env.set_var(VarId(base.0 + fb.eno()), Value::Bool(enabled));
                copy_outputs(outputs, env);
                Flow::Next
            }
            CStmt::UserFb(call) => call_user(call, env, budget)?,
            CStmt::Case { selector, arms, otherwise } => {
                let k = eval(selector, env)?.as_i64();
                let arm = arms.iter().find(|(labels, _)| labels.iter().any(|&(lo, hi)| lo <= k && k <= hi));
                exec(arm.map_or(otherwise, |(_, b)| b), env, budget)?
            }
            CStmt::For { var, from, to, by, body } => for_loop(*var, (from, to, by), body, env, budget)?,
            CStmt::While { pre, condition, body } => loop {
                exec(pre, env, budget)?;
                if !eval(condition, env)?.as_bool() {
                    break Flow::Next;
                }
                tick(budget)?;
                if let Some(end) = iteration(body, env, budget)? {
                    break end;
                }
            },
            CStmt::Repeat { body, pre, until } => loop {
                tick(budget)?;
                if let Some(end) = iteration(body, env, budget)? {
                    break end;
                }
                exec(pre, env, budget)?;
                if eval(until, env)?.as_bool() {
                    break Flow::Next;
                }
            },
            CStmt::Chart(chart) => {
                scan(chart, env, budget)?;
                Flow::Next
            }
            CStmt::Exit => Flow::Exit,
            CStmt::Return => Flow::Return,
        };
        if flow != Flow::Next {
            return Ok(flow);
        }
    }
    Ok(Flow::Next)
}

/// A user block's call: its inputs and in-outs in, its body run (from the same budget as a loop's pass), ENO,
/// the in-outs and the outputs back.
fn call_user(call: &UserCall, env: &mut impl EnvMut, budget: &mut usize) -> Result<Flow, Fault> {
    for (member, value) in &call.inputs {
        let v = eval(value, env)?;
        env.set_var(*member, v);
    }
    for &(member, caller) in &call.inouts {
        let v = env.var(caller);
        env.set_var(member, v);
    }
    let enabled = match &call.en {
        Some(e) => eval(e, env)?.as_bool(),
        None => true,
    };
    if enabled {
        // A call costs from the same budget as a loop's pass: blocks that each call the next twice
        // would otherwise run 2^depth bodies in one scan.
        *budget = budget.checked_sub(1).ok_or(Fault::CallLimit)?;
        // RETURN ends the block's body, not the caller's.
        exec(&call.body, env, budget)?;
    }
    env.set_var(call.eno, Value::Bool(enabled));
    for &(member, caller) in &call.inouts {
        let v = env.var(member);
        env.set_var(caller, v);
    }
    copy_outputs(&call.outputs, env);
    Ok(Flow::Next)
}

/// `FOR var := from TO to BY by DO body END_FOR`.
fn for_loop(
    var: VarId,
    (from, to, by): (&CExpr, &CExpr, &CExpr),
    body: &[CStmt],
    env: &mut impl EnvMut,
    budget: &mut usize,
) -> Result<Flow, Fault> {
    let start = eval(from, env)?;
    env.set_var(var, start);
    let (to, by) = (eval(to, env)?.as_i64(), eval(by, env)?.as_i64());
    Ok(loop {
        let i = env.var(var).as_i64();
        let go_on = if by >= 0 { i <= to } else { i >= to };
        if !go_on {
            break Flow::Next;
        }
        tick(budget)?;
        if let Some(end) = iteration(body, env, budget)? {
            break end;
        }
        let i = env.var(var).as_i64();
        // A step that would overflow the variable's type ends the loop, as the bound was reached.
        let Some(next) = i.checked_add(by) else { break Flow::Next };
        env.set_var(var, Value::Int(next));
        if env.var(var).as_i64() != next {
            break Flow::Next;
        }
    })
}

/// A qualifier's duration in milliseconds: a literal, or a TIME variable's value (a negative one as 0).
pub fn duration_ms(d: Option<DurationSrc>, env: &impl Env) -> i64 {
    match d {
        Some(DurationSrc::Ms(ms)) => ms,
        Some(DurationSrc::Var(v)) => env.var(v).as_i64().max(0),
        None => 0,
    }
}

/// A nested chart put back before its first scan: every active step goes off (its time kept as `S.T`), and every
/// action it holds that is on or stored ends with its final run (Q FALSE), in order — a chart it holds resets in
/// turn —, but a CODESYS step action, which has none.
fn reset_chart(chart: &NestedChart, env: &mut impl EnvMut, budget: &mut usize) -> Result<(), Fault> {
    let now = env.now_ms();
    for s in &chart.steps {
        if env.var(s.x).as_bool() {
            let since = env.var(s.since).as_i64();
            env.set_var(s.x, Value::Bool(false));
            env.set_var(s.last, Value::Time(now - since));
        }
    }
    env.set_var(chart.started, Value::Bool(false));
    let mut ending = Vec::new();
    for a in &chart.actions {
        let on = env.var(a.q).as_bool();
        if on || env.var(a.stored).as_bool() {
            env.set_var(a.stored, Value::Bool(false));
            env.set_var(a.q, Value::Bool(false));
            if let Some(v) = a.bool_var.filter(|_| on) {
                env.set_var(v, Value::Bool(false));
            }
            ending.push((a, on));
        }
    }
    for (a, on) in ending {
        if on && a.final_run {
            exec(&a.body, env, budget)?;
        }
    }
    Ok(())
}

/// One scan of a nested chart (see `NestedChart`).
fn scan(chart: &NestedChart, env: &mut impl EnvMut, budget: &mut usize) -> Result<(), Fault> {
    if let Some(q) = &chart.q {
        if !eval(q, env)?.as_bool() {
            // The action's final run.
            return reset_chart(chart, env, budget);
        }
    }
    let flag = |env: &mut _, v: Option<VarId>| v.is_some_and(|v| Env::var(env, v).as_bool());
    let (sfc_init, sfc_reset) = (flag(env, chart.init), flag(env, chart.reset));
    if sfc_init || sfc_reset {
        reset_chart(chart, env, budget)?;
    }
    let now = env.now_ms();
    let x = |env: &mut _, s: &NestedStep| Env::var(env, s.x).as_bool();
    let n = chart.steps.len();
    // Steps just made active, and just left, in this scan.
    let mut entered = vec![false; n];
    let mut left = vec![false; n];
    if !env.var(chart.started).as_bool() {
        env.set_var(chart.started, Value::Bool(true));
        for (i, s) in chart.steps.iter().enumerate().filter(|(_, s)| s.initial) {
            env.set_var(s.x, Value::Bool(true));
            env.set_var(s.since, Value::Time(now));
            entered[i] = true;
        }
    } else {
        let mut taken = vec![false; n];
        let mut fired = Vec::new();
        for (i, t) in chart.transitions.iter().enumerate() {
            if !t.sources.iter().all(|&s| x(env, &chart.steps[s]) && !taken[s]) {
                continue;
            }
            exec(&t.calls, env, budget)?;
            if eval(&t.condition, env)?.as_bool() {
                t.sources.iter().for_each(|&s| taken[s] = true);
                fired.push(i);
            }
        }
        for &i in &fired {
            for &s in &chart.transitions[i].sources {
                let step = &chart.steps[s];
                let since = env.var(step.since).as_i64();
                env.set_var(step.x, Value::Bool(false));
                env.set_var(step.last, Value::Time(now - since));
                left[s] = true;
            }
        }
        for &i in &fired {
            for &s in &chart.transitions[i].targets {
                // A second token on an active step merges with the first, as in the engine.
                let step = &chart.steps[s];
                if !x(env, step) {
                    env.set_var(step.x, Value::Bool(true));
                    env.set_var(step.since, Value::Time(now));
                    entered[s] = true;
                }
            }
        }
    }
    if sfc_init {
        // Held at the initial steps, their actions not run, while SFCInit is TRUE.
        return Ok(());
    }
    // Every controlled action's Q from its associations, before any body runs, so that each sees this scan's.
    let mut runs = Vec::with_capacity(chart.actions.len());
    for a in &chart.actions {
        let (mut direct, mut set, mut reset) = (false, false, false);
        for &(s, qualifier, duration) in &a.associations {
            let step = &chart.steps[s];
            if !x(env, step) {
                direct |= matches!(qualifier, Qualifier::P0 | Qualifier::Exit) && left[s];
                continue;
            }
            let elapsed = now - env.var(step.since).as_i64();
            let dur = duration_ms(duration, env);
            match qualifier {
                Qualifier::N | Qualifier::Active => direct = true,
                Qualifier::S => set = true,
                Qualifier::R => reset = true,
                Qualifier::L => direct |= elapsed < dur,
                Qualifier::D => direct |= elapsed >= dur,
                Qualifier::P | Qualifier::P1 | Qualifier::Entry => direct |= entered[s],
                // P0 counts where its step was left, above; `compile` refuses the stored timed qualifiers here.
                Qualifier::P0 | Qualifier::Exit | Qualifier::SD | Qualifier::DS | Qualifier::SL => {}
            }
        }
        let stored = !reset && (set || env.var(a.stored).as_bool());
        env.set_var(a.stored, Value::Bool(stored));
        let q = direct || stored;
        let before = env.var(a.q).as_bool();
        env.set_var(a.q, Value::Bool(q));
        // A boolean action's variable follows Q where Q is or was on, and an overriding reset (R) writes FALSE.
        if let Some(v) = a.bool_var.filter(|_| q || before || reset) {
            env.set_var(v, Value::Bool(q));
        }
        runs.push(q || (before && a.final_run));
    }
    for (a, run) in chart.actions.iter().zip(runs) {
        if run {
            // RETURN in a controlled action ends that action's body only.
            exec(&a.body, env, budget)?;
        }
    }
    Ok(())
}

/// Whether an expression reads nothing but literals, so that it can be folded at compile time.
pub fn is_constant(e: &CExpr) -> bool {
    match e {
        CExpr::Const(_) => true,
        CExpr::Var(_) | CExpr::StepX(_) | CExpr::StepT(_) | CExpr::StepOverrun(_) | CExpr::ActionQ(_) => false,
        CExpr::Not(a) | CExpr::Neg(a, _) => is_constant(a),
        CExpr::Logic(_, a, b) | CExpr::Cmp(_, a, b) => is_constant(a) && is_constant(b),
        CExpr::Arith { lhs, rhs, .. } => is_constant(lhs) && is_constant(rhs),
        CExpr::Call(c) => c.args.iter().all(is_constant),
        CExpr::Index(_) | CExpr::NestedT(_) => false,
    }
}
