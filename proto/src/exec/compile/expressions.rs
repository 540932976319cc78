//! ST expressions: operators, names and dotted paths (members, globals, step flags).

use crate::exec::compile::typing::{binary_type, bool_literal, Ty};
use crate::exec::program::{ArithOp, CExpr, CmpOp, LogicOp, VarInfo};
use crate::front::diag::Span;
use crate::front::model::{BinOp, Expr, ExprKind, Ident, UnOp};
use crate::types::library::Func;
use crate::types::{Type, Value};

use super::{Compiler, FALSE};

impl<'a> Compiler<'a> {
    pub(super) fn expr(&mut self, e: &Expr, vars: &[VarInfo]) -> (CExpr, Ty) {
        if let Some(plain) = self.unqualified(e) {
            return self.expr(&plain, vars);
        }
        match &e.kind {
            ExprKind::Bool(b) => (CExpr::Const(Value::Bool(*b)), Ty::Bool),
            ExprKind::Int(v) => (CExpr::Const(Value::Int(*v)), Ty::IntLit),
            ExprKind::Real(v) => (CExpr::Const(Value::Real(*v)), Ty::Real { long: false }),
            ExprKind::Time(v) => (CExpr::Const(Value::Time(*v)), Ty::Time),
            ExprKind::Date(v) => (CExpr::Const(Value::Time(*v)), Ty::Date),
            ExprKind::Tod(v) => (CExpr::Const(Value::Time(*v)), Ty::Tod),
            ExprKind::Dt(v) => (CExpr::Const(Value::Time(*v)), Ty::Dt),
            ExprKind::Str(text) => (CExpr::Const(Value::string(text.as_str())), Ty::Str),
            ExprKind::Name(name) => self.name(name, vars),
            ExprKind::Field(base, field) => self.field(base, field, vars),
            ExprKind::Call(callee, args) => self.call(e, callee, args, vars),
            ExprKind::Index(name, indices) => self.element(name, indices, vars).unwrap_or((FALSE, Ty::Err)),
            ExprKind::IndexField(name, indices, field) => {
                self.element_field(name, indices, field, vars).unwrap_or((FALSE, Ty::Err))
            }
            ExprKind::EnumValue(ty, value) => match self.enum_value(Some(ty), value) {
                Some(found) => found,
                None => {
                    self.error(value.span, format!("`{}` is not a value of enumeration `{}`", value.name, ty.name));
                    (FALSE, Ty::Err)
                }
            },
            ExprKind::Unary(op, a) => {
                let (ca, ta) = self.expr(a, vars);
                match (op, ta) {
                    (_, Ty::Err) => (FALSE, Ty::Err),
                    (UnOp::Not, Ty::Bool) => (CExpr::Not(Box::new(ca)), Ty::Bool),
                    (UnOp::Not, t) if t.is_int() => (CExpr::call(Func::BitNot, vec![ca], t.repr()), t),
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
            // A chain of one associative operator, however the source grouped it, compiles to one balanced tree of
            // its operands in their order: `(a AND b) AND (c AND d)` and `a AND b AND c AND d` are the same program
            // (a round trip through another format may group them otherwise), and no chain is deeper than it must.
            ExprKind::Binary(op, _, _) if op.associative() => {
                let mut operands = Vec::new();
                let mut stack = vec![e];
                while let Some(x) = stack.pop() {
                    match &x.kind {
                        ExprKind::Binary(o, a, b) if o == op => {
                            stack.push(b);
                            stack.push(a);
                        }
                        _ => operands.push(x),
                    }
                }
                // Every operand is compiled, for its own errors, before any is given up on.
                let level: Vec<(CExpr, Ty)> = operands.into_iter().map(|x| self.expr(x, vars)).collect();
                if level.iter().any(|(_, t)| *t == Ty::Err) {
                    return (FALSE, Ty::Err);
                }
                let joined = crate::front::model::fold_balanced(level, |a, b| {
                    let node = self.binary_node(*op, a, b, e.span);
                    (node.1 != Ty::Err).then_some(node)
                });
                joined.unwrap_or((FALSE, Ty::Err))
            }
            ExprKind::Binary(op, a, b) => {
                let a = self.expr(a, vars);
                let b = self.expr(b, vars);
                self.binary_node(*op, a, b, e.span)
            }
        }
    }

    /// `a op b`, typed; an error (at `span`) when the operator does not apply to their types.
    pub(super) fn binary_node(&mut self, op: BinOp, a: (CExpr, Ty), b: (CExpr, Ty), span: Span) -> (CExpr, Ty) {
        // A BOOL beside a literal 0 or 1 (`x = 1`, `a AND 0`): the literal is a BOOL.
        let (a, b) = match (a.1, b.1) {
            (Ty::Bool, Ty::IntLit) => (a, bool_literal(b)),
            (Ty::IntLit, Ty::Bool) => (bool_literal(a), b),
            _ => (a, b),
        };
        let ((ca, ta), (cb, tb)) = (a, b);
        if ta == Ty::Err || tb == Ty::Err {
            return (FALSE, Ty::Err);
        }
        let Some(ty) = binary_type(op, ta, tb) else {
            let message = format!("cannot apply `{}` to {} and {}", op.symbol(), ta.name(), tb.name());
            self.error(span, message);
            return (FALSE, Ty::Err);
        };
        if matches!(op, BinOp::And | BinOp::Or | BinOp::Xor) && ty != Ty::Bool {
            let func = match op {
                BinOp::And => Func::BitAnd,
                BinOp::Or => Func::BitOr,
                _ => Func::BitXor,
            };
            return (CExpr::call(func, vec![ca, cb], ty.repr()), ty);
        }
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
            BinOp::Pow => CExpr::Arith { op: ArithOp::Pow, wrap: ty.wrap(), lhs: ca, rhs: cb },
        };
        (cexpr, ty)
    }

    /// Reports a use of a variable whose type Baton does not execute; true when it did.
    pub(super) fn reject_unsupported(&mut self, span: Span, var: &VarInfo) -> bool {
        let Type::Unsupported(ty) = &var.ty else { return false };
        self.error(span, format!("variable `{}` has type {ty}, which Baton does not execute", var.name));
        true
    }

    pub(super) fn name(&mut self, name: &Ident, vars: &[VarInfo]) -> (CExpr, Ty) {
        if let Some(&id) = self.vars.get(&name.key()) {
            // Constant contexts (initial values, CASE labels) see no variables.
            let Some(var) = vars.get(id.index()) else {
                self.error(name.span, format!("`{}` is a variable, and a constant is needed here", name.name));
                return (FALSE, Ty::Err);
            };
            if self.reject_unsupported(name.span, var) {
                return (FALSE, Ty::Err);
            }
            return (CExpr::Var(id), Ty::of(&var.ty));
        }
        if let Some((ty_name, names)) = self.structs.get(&name.key()) {
            let first = names.first().cloned().unwrap_or_default();
            let message = format!(
                "`{}` is a {ty_name} structure: use one of its fields, such as `{}.{first}`",
                name.name, name.name
            );
            self.error(name.span, message);
            return (FALSE, Ty::Err);
        }
        if self.arrays.contains_key(&name.key()) {
            self.error(name.span, format!("`{}` is an array: index it, such as `{}[…]`", name.name, name.name));
            return (FALSE, Ty::Err);
        }
        if let Some(found) = self.enum_value(None, name) {
            return found;
        }
        let message = if self.steps.contains_key(&name.key()) {
            format!("`{}` is a step: write `{}.X` for its active flag", name.name, name.name)
        } else if let Some((fb, _)) = self.instances.get(&name.key()) {
            format!("`{}` is a {} instance: read one of its outputs, such as `{}.Q`", name.name, fb.name(), name.name)
        } else if let Some(&u) = self.user_of.get(&name.key()) {
            format!(
                "`{}` is a `{}` instance: read one of its outputs (`{}.NAME`)",
                name.name, self.users[u].def.name.name, name.name
            )
        } else if self.chart.broken.var(&name.key()) {
            return (FALSE, Ty::Err);
        } else {
            format!("undeclared variable `{}`{}", name.name, self.var_hint(&name.name))
        };
        self.error(name.span, message);
        (FALSE, Ty::Err)
    }

    /// Why a path naming no structure (`ln.c` in `ln.c.x`, `pts[4]` in `pts[4].x`) is wrong, when it starts
    /// with one: the field its structure lacks, or the index its array's bounds exclude.
    pub(super) fn bad_path(&self, base: &Ident) -> Option<String> {
        if let Some((array, rest)) = base.name.split_once('[') {
            let info = self.arrays.get(&array.to_ascii_uppercase())?;
            let indices = rest.strip_suffix(']')?.split(',').map(|i| i.trim().parse::<i64>().ok());
            for (i, &(low, high)) in indices.zip(&info.dims) {
                let i = i?;
                if i < low || i > high {
                    return Some(format!("index {i} is outside `{array}`'s bounds {low}..{high}"));
                }
            }
            return None;
        }
        let (prefix, last) = base.name.rsplit_once('.')?;
        self.structs.contains_key(&prefix.to_ascii_uppercase()).then(|| {
            let prefix = Ident { name: prefix.to_string(), span: base.span };
            self.missing_field(&prefix, &Ident { name: last.to_string(), span: base.span })
        })
    }

    /// Why `base.field` of a structure `base` is no variable: a structure or an array itself, or no field.
    pub(super) fn missing_field(&self, base: &Ident, field: &Ident) -> String {
        let path = format!("{}.{}", base.key(), field.key());
        let whole = format!("{}.{}", base.name, field.name);
        if let Some((inner, fields)) = self.structs.get(&path) {
            let first = fields.first().cloned().unwrap_or_default();
            return format!("`{whole}` is a {inner} structure: use one of its fields, such as `{whole}.{first}`");
        }
        if self.arrays.contains_key(&path) {
            return format!("`{whole}` is an array: index it, such as `{whole}[…]`");
        }
        let (ty_name, names) = self.structs.get(&base.key()).cloned().unwrap_or_default();
        format!("`{}` (a {ty_name}) has no field `{}`: it has {}", base.name, field.name, names.join(", "))
    }

    pub(super) fn field(&mut self, base: &Ident, field: &Ident, vars: &[VarInfo]) -> (CExpr, Ty) {
        let step_field = (matches!(field.key().as_str(), "X" | "T")
            && (self.steps.contains_key(&base.key())
                || self.nested.step(&base.key()).is_some()
                || self.nested.ambiguous(&base.key()).is_some()))
            || (field.key() == "OVERRUN" && self.steps.contains_key(&base.key()));
        // A variable of an instance inside an instance, `table.motor.speed` (an instance's own, `m.speed`, below:
        // its locals are in `vars` beside its parameters, as CODESYS reads them).
        if base.name.contains('.') {
            if let Some(&id) = self.vars.get(&format!("{}.{}", base.key(), field.key())).filter(|_| !step_field) {
                if let Some(v) = vars.get(id.index()) {
                    return (CExpr::Var(id), Ty::of(&v.ty));
                }
            }
        }
        if self.structs.contains_key(&base.key()) && !step_field {
            return match self.vars.get(&format!("{}.{}", base.key(), field.key())) {
                Some(&id) => match vars.get(id.index()) {
                    Some(v) => (CExpr::Var(id), Ty::of(&v.ty)),
                    None => {
                        self.error(base.span, format!("`{}` is a variable, and a constant is needed here", base.name));
                        (FALSE, Ty::Err)
                    }
                },
                None => {
                    let message = self.missing_field(base, field);
                    self.error(field.span, message);
                    (FALSE, Ty::Err)
                }
            };
        }
        if let Some(&u) = self.user_of.get(&base.key()).filter(|_| !step_field) {
            return self.user_member(u, base, field, vars);
        }
        if let Some(&(fb, inst)) = self.instances.get(&base.key()).filter(|_| !step_field) {
            return match self.member(fb, inst, base, field) {
                Some(id) => {
                    let ty = Ty::of(&fb.members()[(id.0 - inst.0) as usize].ty);
                    (CExpr::Var(id), ty)
                }
                None => (FALSE, Ty::Err),
            };
        }
        if let (Some(v), false) = (self.nested.step(&base.key()), self.steps.contains_key(&base.key())) {
            match field.key().as_str() {
                "X" => return (CExpr::Var(v[0]), Ty::Bool),
                "T" => return (CExpr::NestedT(Box::new(v)), Ty::Time),
                _ => {}
            }
        }
        if let (Some(owners), "X" | "T") = (self.nested.ambiguous(&base.key()), field.key().as_str()) {
            let message = format!(
                "the charts of actions {} each have a step `{}`: write `{}.{}.{}`",
                owners.iter().map(|o| format!("`{o}`")).collect::<Vec<_>>().join(", "),
                base.name,
                owners[0],
                base.name,
                field.name
            );
            self.error(base.span, message);
            return (FALSE, Ty::Err);
        }
        if let (Some(q), "Q") = (self.nested.q(&base.key()), field.key().as_str()) {
            return (CExpr::Var(q), Ty::Bool);
        }
        if let Some(message) = self.bad_path(base) {
            self.error(base.span, message);
            return (FALSE, Ty::Err);
        }
        match field.key().as_str() {
            "X" | "T" | "OVERRUN" => match self.steps.get(&base.key()) {
                Some(&id) if field.key() == "X" => (CExpr::StepX(id), Ty::Bool),
                Some(&id) if field.key() == "OVERRUN" => (CExpr::StepOverrun(id), Ty::Bool),
                Some(&id) => (CExpr::StepT(id), Ty::Time),
                None => {
                    if !self.chart.broken.step(&base.key()) {
                        let hint = self.step_hint(&base.name);
                        self.error(base.span, format!("unknown step `{}`{hint}", base.name));
                    }
                    (FALSE, Ty::Err)
                }
            },
            "Q" => match self.actions.get(&base.key()) {
                Some(&id) => (CExpr::ActionQ(id), Ty::Bool),
                None => {
                    if !self.chart.broken.action(&base.key()) {
                        let hint = self.action_hint(&base.name);
                        self.error(base.span, format!("unknown action `{}`{hint}", base.name));
                    }
                    (FALSE, Ty::Err)
                }
            },
            _ if !self.known_name(base) && !self.chart.broken.var(&base.key()) => {
                let message = self.foreign_name(base, field);
                self.error(base.span.to(field.span), message);
                (FALSE, Ty::Err)
            }
            _ => {
                let message = format!(
                    "unknown field `.{}`: a step has `.X`, `.T` and `.overrun`, an action has `.Q`, a function block instance its outputs",
                    field.name
                );
                self.error(field.span, message);
                (FALSE, Ty::Err)
            }
        }
    }

    /// `m.NAME` of user block instance `u`: a parameter (or ENO) it has.
    fn user_member(&mut self, u: usize, base: &Ident, field: &Ident, vars: &[VarInfo]) -> (CExpr, Ty) {
        match self.vars.get(&format!("{}.{}", base.key(), field.key())) {
            Some(&id) => match vars.get(id.index()) {
                Some(v) => (CExpr::Var(id), Ty::of(&v.ty)),
                None => {
                    self.error(base.span, format!("`{}` is an instance, and a constant is needed here", base.name));
                    (FALSE, Ty::Err)
                }
            },
            None => {
                let def = self.users[u].def;
                let names: Vec<String> = self.users[u].params.iter().map(|p| p.0.clone()).collect();
                let message = format!(
                    "function block `{}` has no parameter `{}`: `{}` has {} and ENO",
                    def.name.name,
                    field.name,
                    base.name,
                    names.join(", ")
                );
                self.error(field.span, message);
                (FALSE, Ty::Err)
            }
        }
    }

    /// Whether `base` (before its last `.`) is something of this scope: a variable, an instance, a step, an
    /// action, a structure or an array.
    pub(super) fn known_name(&self, base: &Ident) -> bool {
        let key = base.key();
        let root = key.split(['.', '[']).next().unwrap_or(&key).to_string();
        [&key, &root].iter().any(|k| {
            self.vars.contains_key(*k)
                || self.instances.contains_key(*k)
                || self.user_of.contains_key(*k)
                || self.steps.contains_key(*k)
                || self.actions.contains_key(*k)
                || self.structs.contains_key(*k)
                || self.arrays.contains_key(*k)
        }) || self.vars.keys().any(|v| v.starts_with(&format!("{root}.")))
    }

    /// `GVL.x`, `GVL.s.f`, `GVL.a[i]`: an expression naming a variable by one of the project's global variable
    /// lists, as the same expression without the list's name (the list's variables are the chart's VAR_GLOBAL).
    /// `None` for any other expression, and where the scope declares a variable of the list's name.
    pub(super) fn unqualified(&self, e: &Expr) -> Option<Expr> {
        if self.chart.global_lists.is_empty() {
            return None;
        }
        let kind = match &e.kind {
            ExprKind::Field(base, field) if self.in_global_list(&base.name, &field.name) => {
                ExprKind::Name(field.clone())
            }
            ExprKind::Field(base, field) => ExprKind::Field(self.unqualified_name(base)?, field.clone()),
            ExprKind::Name(name) => ExprKind::Name(self.unqualified_name(name)?),
            ExprKind::Index(name, indices) => ExprKind::Index(self.unqualified_name(name)?, indices.clone()),
            ExprKind::IndexField(name, indices, field) => {
                ExprKind::IndexField(self.unqualified_name(name)?, indices.clone(), field.clone())
            }
            _ => return None,
        };
        Some(Expr { kind, span: e.span })
    }

    /// `GVL.x.y` as `x.y` where `x` is a variable of global list `GVL`.
    pub(super) fn unqualified_name(&self, name: &Ident) -> Option<Ident> {
        let (list, rest) = name.name.split_once('.')?;
        let root = rest.split(['.', '[']).next()?;
        self.in_global_list(list, root).then(|| Ident { name: rest.to_string(), span: name.span })
    }

    pub(super) fn in_global_list(&self, list: &str, var: &str) -> bool {
        !self.declared_name(&list.to_ascii_uppercase())
            && self.declared_name(&var.to_ascii_uppercase())
            && self.chart.global_lists.iter().any(|l| {
                l.name.name.eq_ignore_ascii_case(list) && l.vars.iter().any(|v| v.name.eq_ignore_ascii_case(var))
            })
    }

    /// `GVL.x`, `Main.x`: a name qualified by something this chart does not have — a global variable list, or
    /// another program — which Baton does not read: said as such.
    pub(super) fn foreign_name(&self, base: &Ident, field: &Ident) -> String {
        if let Some(list) = self.chart.global_lists.iter().find(|l| l.name.key() == base.key()) {
            let names: Vec<&str> = list.vars.iter().map(|v| v.name.as_str()).collect();
            return format!(
                "global variable list `{}` has no variable `{}` (it has {})",
                list.name.name,
                field.name,
                if names.is_empty() { "none".to_string() } else { names.join(", ") }
            );
        }
        format!(
            "`{}.{}` qualifies `{}` by `{}`, which chart `{}` does not have: Baton reads a global variable list \
             (`GVL.x`) from the PLCopen project that declares it, and no other program's variables (`Main.x`); \
             declare `{}` in chart `{}` (as VAR_GLOBAL, VAR or an input)",
            base.name, field.name, field.name, base.name, self.chart.name.name, field.name, self.chart.name.name
        )
    }
}
