//! Resolves a chart's names, type-checks its expressions and builds the `Program` the engine runs.

use std::collections::HashMap;

use crate::exec::eval::{eval, is_constant, NoEnv};
use crate::exec::program::*;
use crate::exec::types::{IntKind, Type, Value};
use crate::front::diag::{Diagnostic, Span};
use crate::front::model::*;

/// The result of compiling one chart: a program (with placeholders wherever an error was reported) and whether
/// its net of steps and transitions resolved well enough to be analysed.
pub struct Compiled {
    pub program: Program,
    pub net_ok: bool,
}

pub fn compile(chart: &Chart, diags: &mut Vec<Diagnostic>) -> Compiled {
    let mut c = Compiler { chart, diags, vars: HashMap::new(), steps: HashMap::new(), actions: HashMap::new() };
    c.run()
}

/// The static type of an expression. `IntLit` is an integer literal, which fits any numeric type; `Err` follows
/// an expression whose error is already reported, so that one mistake yields one message.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Ty {
    Bool,
    Int(IntKind),
    IntLit,
    Real { long: bool },
    Time,
    Err,
}

impl Ty {
    fn of(ty: &Type) -> Ty {
        match ty {
            Type::Bool => Ty::Bool,
            Type::Int(k) => Ty::Int(*k),
            Type::Real { long } => Ty::Real { long: *long },
            Type::Time => Ty::Time,
            Type::Unsupported(_) => Ty::Err,
        }
    }

    fn is_int(self) -> bool {
        matches!(self, Ty::Int(_) | Ty::IntLit)
    }

    fn is_num(self) -> bool {
        self.is_int() || matches!(self, Ty::Real { .. })
    }

    fn name(self) -> String {
        match self {
            Ty::Bool => "BOOL".into(),
            Ty::Int(k) => Type::Int(k).to_string(),
            Ty::IntLit => "an integer".into(),
            Ty::Real { long } => Type::Real { long }.to_string(),
            Ty::Time => "TIME".into(),
            Ty::Err => "an invalid expression".into(),
        }
    }

    fn wrap(self) -> Option<IntKind> {
        match self {
            Ty::Int(k) => Some(k),
            _ => None,
        }
    }
}

/// The common numeric type of two numeric operands.
fn join(a: Ty, b: Ty) -> Ty {
    match (a, b) {
        (Ty::Real { long: x }, Ty::Real { long: y }) => Ty::Real { long: x || y },
        (Ty::Real { long }, _) | (_, Ty::Real { long }) => Ty::Real { long },
        (Ty::Int(x), Ty::Int(y)) => Ty::Int(x.wider(y)),
        (Ty::Int(k), _) | (_, Ty::Int(k)) => Ty::Int(k),
        _ => Ty::IntLit,
    }
}

fn binary_type(op: BinOp, a: Ty, b: Ty) -> Option<Ty> {
    use BinOp::*;
    match op {
        Or | Xor | And => (a == Ty::Bool && b == Ty::Bool).then_some(Ty::Bool),
        Eq | Ne | Lt | Le | Gt | Ge => {
            let ok = (a.is_num() && b.is_num()) || (a == Ty::Time && b == Ty::Time) || (a == Ty::Bool && b == Ty::Bool);
            ok.then_some(Ty::Bool)
        }
        Add | Sub if a == Ty::Time && b == Ty::Time => Some(Ty::Time),
        Mul if (a == Ty::Time && b.is_num()) || (a.is_num() && b == Ty::Time) => Some(Ty::Time),
        Div if a == Ty::Time && b.is_num() => Some(Ty::Time),
        Mod => (a.is_int() && b.is_int()).then(|| join(a, b)),
        Add | Sub | Mul | Div => (a.is_num() && b.is_num()).then(|| join(a, b)),
    }
}

/// Whether a value of type `value` may be stored in a variable of type `target`.
fn assignable(target: Ty, value: Ty) -> bool {
    target == value
        || target == Ty::Err
        || value == Ty::Err
        || (target.is_int() && value.is_int())
        || (matches!(target, Ty::Real { .. }) && value.is_num())
}

struct Compiler<'a> {
    chart: &'a Chart,
    diags: &'a mut Vec<Diagnostic>,
    vars: HashMap<String, VarId>,
    steps: HashMap<String, StepId>,
    actions: HashMap<String, ActionId>,
}

const FALSE: CExpr = CExpr::Const(Value::Bool(false));

impl<'a> Compiler<'a> {
    fn error(&mut self, span: Span, message: impl Into<String>) {
        self.diags.push(Diagnostic::error(span, message));
    }

    fn run(&mut self) -> Compiled {
        let chart = self.chart;
        let vars = self.declare_vars();
        let mut net_ok = true;
        let mut steps = Vec::with_capacity(chart.steps.len());
        // The chart element behind each id: duplicates get no id of their own.
        let mut step_sources = Vec::with_capacity(chart.steps.len());
        for step in &chart.steps {
            if self.steps.contains_key(&step.name.key()) {
                self.error(step.name.span, format!("step `{}` is declared twice", step.name.name));
                net_ok = false;
                continue;
            }
            self.steps.insert(step.name.key(), StepId(steps.len() as u32));
            step_sources.push(step);
            steps.push(StepParts {
                info: StepInfo { name: step.name.name.clone(), initial: step.initial, pragmas: step.pragmas.clone() },
                associations: Vec::new(),
            });
        }
        let (mut actions, action_sources) = self.declare_actions();
        self.associate(&vars, &step_sources, &mut steps, &mut actions);
        let mut transitions = Vec::with_capacity(chart.transitions.len());
        net_ok &= self.transitions(&vars, &mut transitions);
        for (id, action) in action_sources.iter().enumerate() {
            actions[id].body = self.statements(&action.body, &vars);
        }
        self.warn_unused_actions();
        if !chart.steps.iter().any(|s| s.initial) && !chart.broken.initial_step {
            let message = format!("chart `{}` has no initial step: declare one with `INITIAL_STEP`", chart.name.name);
            self.error(chart.name.span, message);
        }
        let program = Program::assemble(chart.name.name.clone(), vars, steps, transitions, actions);
        Compiled { program, net_ok }
    }

    fn declare_vars(&mut self) -> Vec<VarInfo> {
        let mut vars = Vec::with_capacity(self.chart.vars.len());
        for decl in &self.chart.vars {
            if self.vars.contains_key(&decl.name.key()) {
                self.error(decl.name.span, format!("variable `{}` is declared twice", decl.name.name));
                continue;
            }
            let ty = Type::from_name(&decl.type_name.key())
                .unwrap_or_else(|| Type::Unsupported(decl.type_name.name.to_ascii_uppercase()));
            let init = match &decl.init {
                Some(e) => self.initial_value(e, &ty),
                None => ty.default_value(),
            };
            self.vars.insert(decl.name.key(), VarId(vars.len() as u32));
            vars.push(VarInfo {
                name: decl.name.name.clone(),
                ty,
                init,
                constant: decl.constant,
                section: decl.section,
            });
        }
        vars
    }

    fn initial_value(&mut self, e: &Expr, ty: &Type) -> Value {
        let (cexpr, vty) = self.expr(e, &[]);
        if vty == Ty::Err {
            return ty.default_value();
        }
        if !is_constant(&cexpr) {
            self.error(e.span, "an initial value must be a constant");
            return ty.default_value();
        }
        let Ok(value) = eval(&cexpr, &NoEnv) else {
            self.error(e.span, "division by zero in an initial value");
            return ty.default_value();
        };
        let target = Ty::of(ty);
        // `x : BOOL := 1;` is common in real projects.
        if target == Ty::Bool && vty == Ty::IntLit && matches!(value, Value::Int(0 | 1)) {
            return Value::Bool(value == Value::Int(1));
        }
        if !assignable(target, vty) {
            self.error(e.span, format!("initial value of type {} does not fit a {ty} variable", vty.name()));
            return ty.default_value();
        }
        if let (Type::Int(k), Value::Int(v)) = (ty, value) {
            if !k.contains(v) {
                self.error(e.span, format!("{v} does not fit in {ty}"));
                return ty.default_value();
            }
        }
        ty.coerce(value)
    }

    /// Declared actions, and the chart element behind each.
    fn declare_actions(&mut self) -> (Vec<ActionInfo>, Vec<&'a Action>) {
        let chart = self.chart;
        let mut actions = Vec::new();
        let mut sources = Vec::new();
        for action in &chart.actions {
            if self.actions.contains_key(&action.name.key()) {
                self.error(action.name.span, format!("action `{}` is declared twice", action.name.name));
                continue;
            }
            self.actions.insert(action.name.key(), ActionId(actions.len() as u32));
            sources.push(action);
            actions.push(ActionInfo {
                name: action.name.name.clone(),
                body: Vec::new(),
                bool_var: None,
                pragmas: action.pragmas.clone(),
            });
        }
        (actions, sources)
    }

    fn associate(
        &mut self,
        vars: &[VarInfo],
        sources: &[&Step],
        steps: &mut [StepParts],
        actions: &mut Vec<ActionInfo>,
    ) {
        for (parts, step) in steps.iter_mut().zip(sources) {
            let mut assocs = Vec::with_capacity(step.associations.len());
            for a in &step.associations {
                let Some(action) = self.action_for(a, vars, actions) else { continue };
                let duration = self.duration(a, vars);
                let mut indicators = Vec::new();
                for ind in &a.indicators {
                    match self.vars.get(&ind.key()) {
                        Some(&v) if vars[v.index()].ty == Type::Bool => indicators.push(v),
                        Some(&v) => {
                            let message =
                                format!("indicator variable `{}` must be BOOL, not {}", ind.name, vars[v.index()].ty);
                            self.error(ind.span, message);
                        }
                        None if self.chart.broken.var(&ind.key()) => {}
                        None => self.error(ind.span, format!("undeclared indicator variable `{}`", ind.name)),
                    }
                }
                assocs.push((Assoc { action, qualifier: a.qualifier, duration }, indicators));
            }
            parts.associations = assocs;
        }
    }

    /// The action an association names: a declared action, or a boolean action named after a BOOL variable.
    fn action_for(&mut self, a: &Association, vars: &[VarInfo], actions: &mut Vec<ActionInfo>) -> Option<ActionId> {
        if let Some(&id) = self.actions.get(&a.action.key()) {
            return Some(id);
        }
        match self.vars.get(&a.action.key()) {
            Some(&v) if vars[v.index()].ty == Type::Bool => {
                let id = ActionId(actions.len() as u32);
                self.actions.insert(a.action.key(), id);
                actions.push(ActionInfo {
                    name: vars[v.index()].name.clone(),
                    body: Vec::new(),
                    bool_var: Some(v),
                    pragmas: Vec::new(),
                });
                Some(id)
            }
            Some(&v) => {
                let message = format!(
                    "`{}` has no ACTION body and is a {} variable: a boolean action needs a BOOL variable",
                    a.action.name,
                    vars[v.index()].ty
                );
                self.error(a.action.span, message);
                None
            }
            None if self.chart.broken.action(&a.action.key()) || self.chart.broken.var(&a.action.key()) => None,
            None => {
                self.error(
                    a.action.span,
                    format!(
                        "unknown action `{}`: declare it with `ACTION {}: … END_ACTION` or as a BOOL variable",
                        a.action.name, a.action.name
                    ),
                );
                None
            }
        }
    }

    fn duration(&mut self, a: &Association, vars: &[VarInfo]) -> Option<DurationSrc> {
        match (&a.duration, a.qualifier.is_timed()) {
            (None, true) => {
                let message = format!(
                    "qualifier {:?} needs a duration, such as `{}({:?}, T#1s)`",
                    a.qualifier, a.action.name, a.qualifier
                );
                self.error(a.qualifier_span, message);
                None
            }
            (None, false) => None,
            (Some(Duration::Literal { ms, span }), _) => {
                if *ms < 0 {
                    self.error(*span, "a duration must not be negative");
                }
                Some(DurationSrc::Ms((*ms).max(0)))
            }
            (Some(Duration::Var(name)), _) => match self.vars.get(&name.key()) {
                Some(&v) if vars[v.index()].ty == Type::Time => Some(DurationSrc::Var(v)),
                Some(&v) => {
                    let message = format!("duration variable `{}` must be TIME, not {}", name.name, vars[v.index()].ty);
                    self.error(name.span, message);
                    None
                }
                None => {
                    if !self.chart.broken.var(&name.key()) {
                        self.error(name.span, format!("undeclared variable `{}`", name.name));
                    }
                    None
                }
            },
        }
    }

    fn step_list(&mut self, list: &[Ident]) -> Option<Vec<StepId>> {
        let mut ids = Vec::with_capacity(list.len());
        let mut ok = true;
        for name in list {
            match self.steps.get(&name.key()) {
                Some(&id) if ids.contains(&id) => {
                    self.error(name.span, format!("step `{}` appears twice in this list", name.name));
                    ok = false;
                }
                Some(&id) => ids.push(id),
                None => {
                    if !self.chart.broken.step(&name.key()) {
                        self.error(name.span, format!("unknown step `{}`", name.name));
                    }
                    ok = false;
                }
            }
        }
        ok.then_some(ids)
    }

    fn transitions(&mut self, vars: &[VarInfo], out: &mut Vec<TransitionParts>) -> bool {
        let chart = self.chart;
        let mut names: HashMap<String, Span> = HashMap::new();
        let mut net_ok = true;
        for t in &chart.transitions {
            if let Some(name) = &t.name {
                if names.insert(name.key(), name.span).is_some() {
                    self.error(name.span, format!("transition `{}` is declared twice", name.name));
                }
            }
            let sources = self.step_list(&t.from);
            let targets = self.step_list(&t.to);
            let (condition, ty) = self.expr(&t.condition, vars);
            if ty != Ty::Bool && ty != Ty::Err {
                self.error(t.condition.span, format!("a transition condition must be BOOL, found {}", ty.name()));
            } else if ty == Ty::Bool
                && is_constant(&condition)
                && eval(&condition, &NoEnv) == Ok(Value::Bool(false))
                && !self.chart.broken.conditions.contains(&t.condition.span)
            {
                let name = t.display_name();
                self.diags.push(Diagnostic::warning(
                    t.condition.span,
                    format!("transition `{name}` can never clear: its condition is always FALSE"),
                ));
            }
            let (Some(sources), Some(targets)) = (sources, targets) else {
                net_ok = false;
                continue;
            };
            let info = TransitionInfo { name: t.display_name(), condition, pragmas: t.pragmas.clone() };
            out.push(TransitionParts { info, sources, targets, rank: 0 });
        }
        // Clearing order: explicit priorities first, lower number first, then declaration order.
        if net_ok {
            let mut order: Vec<usize> = (0..out.len()).collect();
            order.sort_by_key(|&i| match chart.transitions[i].priority {
                Some((p, _)) => (0, p, i),
                None => (1, 0, i),
            });
            for (rank, i) in order.into_iter().enumerate() {
                out[i].rank = rank as u32;
            }
        }
        net_ok
    }

    fn statements(&mut self, body: &[Stmt], vars: &[VarInfo]) -> Vec<CStmt> {
        let mut out = Vec::with_capacity(body.len());
        for stmt in body {
            match stmt {
                Stmt::Assign { target, value, .. } => {
                    let (mut cvalue, mut vty) = self.expr(value, vars);
                    let Some(&id) = self.vars.get(&target.key()) else {
                        if self.chart.broken.var(&target.key()) {
                            continue;
                        }
                        let message = if self.steps.contains_key(&target.key()) {
                            format!("`{}` is a step: a step's state cannot be assigned", target.name)
                        } else {
                            format!("undeclared variable `{}`", target.name)
                        };
                        self.error(target.span, message);
                        continue;
                    };
                    let var = &vars[id.index()];
                    if var.constant {
                        self.error(target.span, format!("`{}` is a CONSTANT and cannot be assigned", var.name));
                        continue;
                    }
                    if self.reject_unsupported(target.span, var) {
                        continue;
                    }
                    // IEC 61131-3 writes BOOL literals as 0 and 1 too (`ORANGE_LIGHT := 1;` in Beremiz's examples).
                    if Ty::of(&var.ty) == Ty::Bool {
                        if let ExprKind::Int(v @ (0 | 1)) = value.kind {
                            (cvalue, vty) = (CExpr::Const(Value::Bool(v == 1)), Ty::Bool);
                        }
                    }
                    if !assignable(Ty::of(&var.ty), vty) {
                        let message = format!("cannot assign {} to `{}`, which is {}", vty.name(), var.name, var.ty);
                        self.error(value.span, message);
                        continue;
                    }
                    out.push(CStmt::Assign { var: id, value: cvalue });
                }
                Stmt::If { branches, otherwise, .. } => {
                    let mut cbranches = Vec::with_capacity(branches.len());
                    for (cond, stmts) in branches {
                        let (ccond, ty) = self.expr(cond, vars);
                        if ty != Ty::Bool && ty != Ty::Err {
                            self.error(cond.span, format!("an IF condition must be BOOL, found {}", ty.name()));
                        }
                        cbranches.push((ccond, self.statements(stmts, vars)));
                    }
                    let otherwise = self.statements(otherwise, vars);
                    out.push(CStmt::If { branches: cbranches, otherwise });
                }
            }
        }
        out
    }

    fn expr(&mut self, e: &Expr, vars: &[VarInfo]) -> (CExpr, Ty) {
        match &e.kind {
            ExprKind::Bool(b) => (CExpr::Const(Value::Bool(*b)), Ty::Bool),
            ExprKind::Int(v) => (CExpr::Const(Value::Int(*v)), Ty::IntLit),
            ExprKind::Real(v) => (CExpr::Const(Value::Real(*v)), Ty::Real { long: false }),
            ExprKind::Time(v) => (CExpr::Const(Value::Time(*v)), Ty::Time),
            ExprKind::Name(name) => self.name(name, vars),
            ExprKind::Field(base, field) => self.field(base, field),
            ExprKind::Unary(op, a) => {
                let (ca, ta) = self.expr(a, vars);
                match (op, ta) {
                    (_, Ty::Err) => (FALSE, Ty::Err),
                    (UnOp::Not, Ty::Bool) => (CExpr::Not(Box::new(ca)), Ty::Bool),
                    (UnOp::Neg, t) if t.is_num() || t == Ty::Time => (CExpr::Neg(Box::new(ca), t.wrap()), t),
                    (UnOp::Not, t) => {
                        self.error(e.span, format!("NOT needs a BOOL operand, found {}", t.name()));
                        (FALSE, Ty::Err)
                    }
                    (UnOp::Neg, t) => {
                        self.error(e.span, format!("unary minus needs a number or a TIME, found {}", t.name()));
                        (FALSE, Ty::Err)
                    }
                }
            }
            ExprKind::Binary(op, a, b) => {
                let (ca, ta) = self.expr(a, vars);
                let (cb, tb) = self.expr(b, vars);
                if ta == Ty::Err || tb == Ty::Err {
                    return (FALSE, Ty::Err);
                }
                let Some(ty) = binary_type(*op, ta, tb) else {
                    let message = format!("cannot apply `{}` to {} and {}", op.symbol(), ta.name(), tb.name());
                    self.error(e.span, message);
                    return (FALSE, Ty::Err);
                };
                let (ca, cb) = (Box::new(ca), Box::new(cb));
                let cexpr = match op {
                    BinOp::Or => CExpr::Logic(LogicOp::Or, ca, cb),
                    BinOp::Xor => CExpr::Logic(LogicOp::Xor, ca, cb),
                    BinOp::And => CExpr::Logic(LogicOp::And, ca, cb),
                    BinOp::Eq => CExpr::Cmp(CmpOp::Eq, ca, cb),
                    BinOp::Ne => CExpr::Cmp(CmpOp::Ne, ca, cb),
                    BinOp::Lt => CExpr::Cmp(CmpOp::Lt, ca, cb),
                    BinOp::Le => CExpr::Cmp(CmpOp::Le, ca, cb),
                    BinOp::Gt => CExpr::Cmp(CmpOp::Gt, ca, cb),
                    BinOp::Ge => CExpr::Cmp(CmpOp::Ge, ca, cb),
                    BinOp::Add => CExpr::Arith { op: ArithOp::Add, wrap: ty.wrap(), lhs: ca, rhs: cb },
                    BinOp::Sub => CExpr::Arith { op: ArithOp::Sub, wrap: ty.wrap(), lhs: ca, rhs: cb },
                    BinOp::Mul => CExpr::Arith { op: ArithOp::Mul, wrap: ty.wrap(), lhs: ca, rhs: cb },
                    BinOp::Div => CExpr::Arith { op: ArithOp::Div, wrap: ty.wrap(), lhs: ca, rhs: cb },
                    BinOp::Mod => CExpr::Arith { op: ArithOp::Mod, wrap: ty.wrap(), lhs: ca, rhs: cb },
                };
                (cexpr, ty)
            }
        }
    }

    /// Reports a use of a variable whose type Baton does not execute; true when it did.
    fn reject_unsupported(&mut self, span: Span, var: &VarInfo) -> bool {
        let Type::Unsupported(ty) = &var.ty else { return false };
        self.error(span, format!("variable `{}` has type {ty}, which Baton does not execute", var.name));
        true
    }

    fn name(&mut self, name: &Ident, vars: &[VarInfo]) -> (CExpr, Ty) {
        if let Some(&id) = self.vars.get(&name.key()) {
            let var = &vars[id.index()];
            if self.reject_unsupported(name.span, var) {
                return (FALSE, Ty::Err);
            }
            return (CExpr::Var(id), Ty::of(&var.ty));
        }
        let message = if self.steps.contains_key(&name.key()) {
            format!("`{}` is a step: write `{}.X` for its active flag", name.name, name.name)
        } else if self.chart.broken.var(&name.key()) {
            return (FALSE, Ty::Err);
        } else {
            format!("undeclared variable `{}`", name.name)
        };
        self.error(name.span, message);
        (FALSE, Ty::Err)
    }

    fn field(&mut self, base: &Ident, field: &Ident) -> (CExpr, Ty) {
        match field.key().as_str() {
            "X" | "T" => match self.steps.get(&base.key()) {
                Some(&id) if field.key() == "X" => (CExpr::StepX(id), Ty::Bool),
                Some(&id) => (CExpr::StepT(id), Ty::Time),
                None => {
                    if !self.chart.broken.step(&base.key()) {
                        self.error(base.span, format!("unknown step `{}`", base.name));
                    }
                    (FALSE, Ty::Err)
                }
            },
            "Q" => match self.actions.get(&base.key()) {
                Some(&id) => (CExpr::ActionQ(id), Ty::Bool),
                None => {
                    if !self.chart.broken.action(&base.key()) {
                        self.error(base.span, format!("unknown action `{}`", base.name));
                    }
                    (FALSE, Ty::Err)
                }
            },
            _ => {
                let message = format!("unknown field `.{}`: a step has `.X` and `.T`, an action has `.Q`", field.name);
                self.error(field.span, message);
                (FALSE, Ty::Err)
            }
        }
    }

    fn warn_unused_actions(&mut self) {
        let chart = self.chart;
        let mut used: HashMap<String, ()> = HashMap::new();
        for step in &chart.steps {
            for a in &step.associations {
                used.insert(a.action.key(), ());
            }
        }
        for action in &chart.actions {
            if !used.contains_key(&action.name.key()) {
                let message =
                    format!("action `{}` is never associated with a step, so it never runs", action.name.name);
                self.diags.push(Diagnostic::warning(action.name.span, message));
            }
        }
    }
}
