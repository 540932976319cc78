//! Function calls: user functions and the standard library's functions, typed, and their arguments bound.

use std::collections::HashMap;
use std::sync::Arc;

use crate::exec::compile::binding::{Dir, Params};
use crate::exec::compile::typing::{assignable, bool_literal, join, time_function, Ty};
use crate::exec::program::{CExpr, CStmt, FbOutput, UserCall, VarId, VarInfo};
use crate::front::model::{Arg, BinOp, Expr, ExprKind, FbDef, Ident, TypeKind, VarSection};
use crate::limits::NESTING_DEPTH_MAX;
use crate::types::library::{DateFn, DatePart, Func, StdFb, TextFn};
use crate::types::{IntKind, Type, Value};

use super::{Compiler, Function, Storage, FALSE};

impl<'a> Compiler<'a> {
    /// Every user function's frame: a hidden VAR_TEMP variable per input and local, and its result. Frames are
    /// scratch (written and read within one call), so several places may write them.
    pub(super) fn declare_functions(&mut self, vars: &mut Vec<VarInfo>) {
        let library: Vec<&'a FbDef> = self.library.values().copied().filter(|d| d.returns.is_some()).collect();
        let mut library = library;
        library.sort_by_key(|d| d.span.start);
        for def in library {
            let returns = def.returns.as_ref().expect("a function");
            let mut scope = HashMap::new();
            let mut arrays = HashMap::new();
            let (mut inputs, mut resets) = (Vec::new(), Vec::new());
            let declare =
                |c: &mut Self, name: String, type_name: &Ident, init: Option<&Expr>, vars: &mut Vec<VarInfo>| {
                    let ty = c.resolve_type(type_name);
                    let init = match init {
                        Some(e) => c.initial_value(e, &ty),
                        None => c.default_of(&ty),
                    };
                    let id = VarId(vars.len() as u32);
                    vars.push(VarInfo {
                        name,
                        ty,
                        init: init.clone(),
                        constant: false,
                        section: VarSection::Temp,
                        hidden: true,
                    });
                    (id, init)
                };
            for d in def.vars.iter().filter(|d| d.section != VarSection::External) {
                if let Some(spec) = self.array_spec_of(d) {
                    let of_structs =
                        matches!(self.types.get(&spec.elem.key()).map(|t| &t.kind), Some(TypeKind::Struct(_)));
                    if d.section == VarSection::Input || of_structs {
                        let what = if of_structs { "an array of structures" } else { "an array input" };
                        let message = format!(
                            "`{}` of function `{}` is {what}, which Baton does not support yet",
                            d.name.name, def.name.name
                        );
                        self.error(d.name.span, message);
                    } else {
                        let label = format!("{}.{}", def.name.name, d.name.name);
                        let before = vars.len();
                        if let Some(info) = self.array_elements((&label, &d.name.name), &spec, Storage::frame(), vars) {
                            // A function's locals start again at every call.
                            resets.extend((before..vars.len()).map(|i| (VarId(i as u32), vars[i].init.clone())));
                            arrays.insert(d.name.key(), info);
                        }
                    }
                    continue;
                }
                let (id, init) =
                    declare(self, format!("{}.{}", def.name.name, d.name.name), &d.type_name, d.init.as_ref(), vars);
                scope.insert(d.name.key(), id);
                match d.section {
                    VarSection::Input => inputs.push((d.name.name.clone(), id)),
                    _ => resets.push((id, init)),
                }
            }
            let (result, init) = declare(self, def.name.name.clone(), returns, None, vars);
            resets.push((result, init));
            scope.insert(def.name.key(), result);
            let (eno, _) = declare(
                self,
                format!("{}.ENO", def.name.name),
                &Ident { name: "BOOL".into(), span: def.name.span },
                None,
                vars,
            );
            let function = Function { def, inputs, resets, result, eno, scope, arrays, body: None, compiling: false };
            self.functions.insert(def.name.key(), function);
        }
    }

    /// A user function's body, compiled at its first call in the function's own scope.
    pub(super) fn function_body(&mut self, key: &str, callee: &Ident, vars: &[VarInfo]) -> Option<Arc<Vec<CStmt>>> {
        let f = self.functions.get(key)?;
        if let Some(body) = &f.body {
            return Some(Arc::clone(body));
        }
        let def = f.def;
        if self.functions_compiling >= NESTING_DEPTH_MAX {
            let message = format!(
                "calls of functions nested more than {NESTING_DEPTH_MAX} levels deep (here, through `{}`)",
                callee.name
            );
            self.error(callee.span, message);
            return None;
        }
        if f.compiling {
            let message = format!(
                "function `{}` calls itself (here, through `{}`): IEC functions do not recurse",
                def.name.name, callee.name
            );
            self.error(callee.span, message);
            return None;
        }
        if !def.problems.is_empty() && !self.reported.contains(&key.to_string()) {
            self.reported.push(key.to_string());
            self.diags.extend(def.problems.iter().cloned());
        }
        let mut names = self.functions[key].scope.clone();
        let arrays = self.functions[key].arrays.clone();
        for d in def.vars.iter().filter(|d| d.section == VarSection::External) {
            if let Some(&id) = self.vars.get(&d.name.key()) {
                names.insert(d.name.key(), id);
            }
        }
        self.functions.get_mut(key).expect("declared").compiling = true;
        self.functions_compiling += 1;
        let chart = self.set_names_aside(names);
        let saved = (
            std::mem::take(&mut self.hoisted),
            std::mem::take(&mut self.loops),
            std::mem::replace(&mut self.arrays, arrays),
        );
        let body = Arc::new(self.statements(&def.body, vars));
        (self.hoisted, self.loops, self.arrays) = saved;
        self.restore_names(chart);
        self.functions_compiling -= 1;
        let f = self.functions.get_mut(key).expect("declared");
        f.compiling = false;
        f.body = Some(Arc::clone(&body));
        Some(body)
    }

    /// A call of a user function in an expression: the call is hoisted before the statement, its result kept in
    /// a variable of its own, which the expression reads.
    pub(super) fn function_call(&mut self, key: &str, callee: &Ident, args: &[Arg], vars: &[VarInfo]) -> (CExpr, Ty) {
        if vars.len() < self.declared {
            self.error(
                callee.span,
                format!("a call of function `{}` is not a constant, and a constant is needed here", callee.name),
            );
            return (FALSE, Ty::Err);
        }
        let (inputs, resets, result, eno) = {
            let f = &self.functions[key];
            (f.inputs.clone(), f.resets.clone(), f.result, f.eno)
        };
        let names: Vec<String> = inputs.iter().map(|(n, _)| n.to_ascii_uppercase()).collect();
        let params: Vec<&str> = names.iter().map(String::as_str).collect();
        let Some(values) = self.positional(callee, args, &params, false) else { return (FALSE, Ty::Err) };
        let mut assigned = Vec::with_capacity(values.len() + resets.len());
        for ((name, id), value) in inputs.iter().zip(&values) {
            let target = Ty::of(&vars[id.index()].ty);
            let (c, ty) = self.expr(value, vars);
            let (c, ty) = if target == Ty::Bool { bool_literal((c, ty)) } else { (c, ty) };
            if !assignable(target, ty) {
                let message =
                    format!("input `{name}` of `{}` is {}, found {}", callee.name, vars[id.index()].ty, ty.name());
                self.error(value.span, message);
                return (FALSE, Ty::Err);
            }
            assigned.push((*id, c));
        }
        assigned.extend(resets.iter().map(|(id, init)| (*id, CExpr::Const(init.clone()))));
        let Some(body) = self.function_body(key, callee, vars) else { return (FALSE, Ty::Err) };
        let ty = vars[result.index()].ty.clone();
        let temp = VarId((self.declared + self.temps.len()) as u32);
        self.temps.push(VarInfo {
            name: format!("{}#{}", callee.name, self.temps.len() + 1),
            ty: ty.clone(),
            init: ty.default_value(),
            constant: false,
            section: VarSection::Temp,
            hidden: true,
        });
        let outputs = vec![FbOutput { member: result, target: temp, negated: false }];
        let call = UserCall { body, en: None, inputs: assigned, inouts: Vec::new(), outputs, eno };
        self.hoisted.push(CStmt::UserFb(Box::new(call)));
        (CExpr::Var(temp), Ty::of(&ty))
    }

    /// `SPLIT_DATE(IN := d, YEAR => y, MONTH => m, DAY => dd);` (and SPLIT_TOD, SPLIT_DT): a function whose
    /// results are output parameters, written formally or in order (`SPLIT_DATE(d, y, m, dd)`); outputs left out
    /// are not written.
    pub(super) fn split_call(
        &mut self,
        callee: &Ident,
        args: &[Arg],
        input: Ty,
        parts: &[(&str, DatePart)],
        vars: &[VarInfo],
    ) -> Option<CStmt> {
        let name = callee.key();
        let mut names = vec![("IN".to_string(), Dir::Input)];
        names.extend(parts.iter().map(|(p, _)| (p.to_string(), Dir::Output)));
        let outputs: Vec<&str> = parts.iter().map(|(p, _)| *p).collect();
        let params = Params {
            shown: name.clone(),
            positional: (0..names.len()).collect(),
            params: names,
            en: false,
            too_many: format!("{name} takes IN and {} outputs", parts.len()),
        };
        let bound = self.bind(&params, args, vars, &mut |c: &mut Self, n: &Ident| {
            let message = format!("{name} has no parameter `{}`: it has IN and {}", n.name, outputs.join(", "));
            c.error(n.span, message);
        })?;
        let value = bound.args.iter().find(|(p, _)| *p == 0).map(|(_, arg)| &arg.value);
        let targets: Vec<(DatePart, &Expr)> =
            bound.args.iter().filter(|(p, _)| *p > 0).map(|(p, arg)| (parts[p - 1].1, &arg.value)).collect();
        let Some(value) = value else {
            self.error(callee.span, format!("{name} needs its input `IN`"));
            return None;
        };
        let (c, ty) = self.expr(value, vars);
        if ty != input && ty != Ty::Err {
            self.error(value.span, format!("IN of {name} must be {}, found {}", input.name(), ty.name()));
            return None;
        }
        let mut assigns = Vec::with_capacity(targets.len());
        for (part, target) in targets {
            let id = self.place(target, vars)?;
            if !Ty::of(&vars[id.index()].ty).is_int() {
                let message = format!(
                    "an output of {name} is an integer, and `{}` is {}",
                    vars[id.index()].name,
                    vars[id.index()].ty
                );
                self.error(target.span, message);
                return None;
            }
            let part = CExpr::call(Func::Date(DateFn::Part(part)), vec![c.clone()], vars[id.index()].ty.clone());
            assigns.push(CStmt::Assign { var: id, value: part });
        }
        // The outputs as one statement.
        Some(CStmt::If { branches: vec![(CExpr::Const(Value::Bool(true)), assigns)], otherwise: Vec::new() })
    }

    /// A standard function call in an expression.
    pub(super) fn call(&mut self, e: &Expr, callee: &Ident, args: &[Arg], vars: &[VarInfo]) -> (CExpr, Ty) {
        let key = callee.key();
        if self.functions.contains_key(&key) {
            return self.function_call(&key, callee, args, vars);
        }
        if self.instance_called(callee, &key) {
            return (FALSE, Ty::Err);
        }
        // ADD, SUB, …, GT, EQ, …, AND, OR, XOR: the operators, folded over the arguments.
        let op = match key.as_str() {
            "AND" => Some((BinOp::And, true)),
            "OR" => Some((BinOp::Or, true)),
            "XOR" => Some((BinOp::Xor, true)),
            "ADD" => Some((BinOp::Add, true)),
            "MUL" => Some((BinOp::Mul, true)),
            "SUB" => Some((BinOp::Sub, false)),
            "DIV" => Some((BinOp::Div, false)),
            "MOD" => Some((BinOp::Mod, false)),
            "GT" => Some((BinOp::Gt, true)),
            "GE" => Some((BinOp::Ge, true)),
            "EQ" => Some((BinOp::Eq, true)),
            "LE" => Some((BinOp::Le, true)),
            "LT" => Some((BinOp::Lt, true)),
            "NE" => Some((BinOp::Ne, false)),
            _ => None,
        };
        if let Some((op, extensible)) = op {
            return self.operator_call(e, callee, &key, op, extensible, args, vars);
        }
        // ADD_TIME, SUB_DT_DT, MUL_TIME and their kin: the operators on the types their names give.
        if let Some((op, wanted)) = time_function(&key) {
            return self.time_call(e, callee, &key, (op, wanted), args, vars);
        }
        self.standard_call(callee, &key, args, vars)
    }

    /// A block instance called in an expression, which is an error (said here): whether `callee` is one.
    fn instance_called(&mut self, callee: &Ident, key: &str) -> bool {
        if let Some(&u) = self.user_of.get(key) {
            let message = format!(
                "`{}` is a `{}` instance: call it as a statement in an action (`{}(…);`) and read its outputs here",
                callee.name, self.users[u].def.name.name, callee.name
            );
            self.error(callee.span, message);
            return true;
        }
        if let Some((fb, _)) = self.instances.get(key) {
            let message = format!(
                "`{}` is a {} instance: call it as a statement in an action (`{}(…);`) and read its outputs here (`{}.Q`)",
                callee.name,
                fb.name(),
                callee.name,
                callee.name
            );
            self.error(callee.span, message);
            return true;
        }
        false
    }

    /// ADD, GT and the other operators written as functions, folded over their arguments.
    #[allow(clippy::too_many_arguments)]
    fn operator_call(
        &mut self,
        e: &Expr,
        callee: &Ident,
        key: &str,
        op: BinOp,
        extensible: bool,
        args: &[Arg],
        vars: &[VarInfo],
    ) -> (CExpr, Ty) {
        let Some(values) = self.positional(callee, args, &["IN1", "IN2"], extensible) else {
            return (FALSE, Ty::Err);
        };
        let comparison = matches!(op, BinOp::Gt | BinOp::Ge | BinOp::Eq | BinOp::Le | BinOp::Lt | BinOp::Ne);
        let mut folded = if comparison {
            // GT(a, b, c) is a > b AND b > c.
            let pairs: Vec<Expr> = values
                .windows(2)
                .map(|w| Expr {
                    kind: ExprKind::Binary(op, Box::new(w[0].clone()), Box::new(w[1].clone())),
                    span: e.span,
                })
                .collect();
            Expr::balanced(BinOp::And, pairs)
        } else if op.associative() {
            Expr::balanced(op, values)
        } else if values.len() > NESTING_DEPTH_MAX {
            // ADD(a, b, c) is (a + b) + c, in that order (REAL sums and the widths of mixed integers depend
            // on it): its arguments nest as deep as they are many.
            let message = format!(
                "{key} with {} arguments nests them {} levels deep, more than {NESTING_DEPTH_MAX}: add them in \
                 parts, each with a name of its own",
                values.len(),
                values.len() - 1
            );
            self.error(callee.span, message);
            return (FALSE, Ty::Err);
        } else {
            let mut it = values.into_iter();
            let first = it.next().expect("two arguments at least");
            it.fold(first, |acc, v| Expr { kind: ExprKind::Binary(op, Box::new(acc), Box::new(v)), span: e.span })
        };
        folded.span = e.span;
        self.expr(&folded, vars)
    }

    /// ADD_TIME and its kin: `op` on operands of the types `wanted` (`None`: any number).
    fn time_call(
        &mut self,
        e: &Expr,
        callee: &Ident,
        key: &str,
        (op, wanted): (BinOp, [Option<Ty>; 2]),
        args: &[Arg],
        vars: &[VarInfo],
    ) -> (CExpr, Ty) {
        let Some(values) = self.positional(callee, args, &["IN1", "IN2"], false) else {
            return (FALSE, Ty::Err);
        };
        let operands = [self.expr(&values[0], vars), self.expr(&values[1], vars)];
        for (i, ((_, t), want)) in operands.iter().zip(wanted).enumerate() {
            let fits = match want {
                Some(w) => *t == w,
                None => t.is_num(),
            };
            if !fits && *t != Ty::Err {
                let name = want.map_or_else(|| "a number".to_string(), |w| w.name());
                let message = format!("argument {} of {key} must be {name}, found {}", i + 1, t.name());
                self.error(values[i].span, message);
                return (FALSE, Ty::Err);
            }
        }
        let [a, b] = operands;
        self.binary_node(op, a, b, e.span)
    }

    /// A function of the standard library (`Func`): its arguments compiled and its result's type checked.
    fn standard_call(&mut self, callee: &Ident, key: &str, args: &[Arg], vars: &[VarInfo]) -> (CExpr, Ty) {
        let Some((func, params)) = Func::from_name(key) else {
            let message = if StdFb::from_name(key).is_some() {
                format!("`{0}` is a function block type: declare an instance (`t1 : {0};`), call it in an action and read `t1.Q`", key)
            } else {
                format!("unknown function `{}`", callee.name)
            };
            self.error(callee.span, message);
            return (FALSE, Ty::Err);
        };
        let Some((values, cargs, tys)) = self.standard_args(&func, callee, args, params, vars) else {
            return (FALSE, Ty::Err);
        };
        let bad = |c: &mut Self, i: usize, want: &str| {
            let message = format!("argument {} of {} must be {want}, found {}", i + 1, key, tys[i].name());
            c.error(values[i].span, message);
            (FALSE, Ty::Err)
        };
        // The common type of some arguments: all numbers, or all of one other type.
        let common = |c: &mut Self, from: usize| -> Option<Ty> {
            let mut acc = tys[from];
            for (i, &t) in tys.iter().enumerate().skip(from + 1) {
                acc = if acc.is_num() && t.is_num() {
                    join(acc, t)
                } else if acc == t {
                    t
                } else {
                    let message = format!("arguments of {} must have one type: {} and {}", key, acc.name(), t.name());
                    c.error(values[i].span, message);
                    return None;
                };
            }
            Some(acc)
        };
        let ty = match &func {
            Func::Abs if tys[0].is_num() => tys[0],
            Func::Abs => return bad(self, 0, "a number"),
            Func::Real(_) if tys[0].is_num() => real_of(tys[0]),
            Func::Real(_) => return bad(self, 0, "a number"),
            Func::Trunc(k) if tys[0].is_num() => Ty::Int(*k),
            Func::Trunc(_) => return bad(self, 0, "a REAL"),
            Func::Atan2 if !tys[0].is_num() => return bad(self, 0, "a number"),
            Func::Atan2 if !tys[1].is_num() => return bad(self, 1, "a number"),
            Func::Atan2 => real_of(join(tys[0], tys[1])),
            Func::BcdToInt(_) | Func::IntToBcd(_) | Func::IsValidBcd | Func::SwapBytes if !tys[0].is_int() => {
                return bad(self, 0, "an integer or a bit string")
            }
            Func::BcdToInt(k) | Func::IntToBcd(k) => Ty::Int(*k),
            Func::IsValidBcd => Ty::Bool,
            Func::IsValid if !tys[0].is_num() => return bad(self, 0, "a REAL"),
            Func::IsValid => Ty::Bool,
            Func::SwapBytes => match tys[0] {
                Ty::IntLit => Ty::Int(IntKind::Dword),
                t => t,
            },
            Func::Date(f) => match date_type(*f, &tys) {
                Ok(t) => t,
                Err((i, want)) => return bad(self, i, &want),
            },
            Func::Expt if !tys[0].is_num() => return bad(self, 0, "a number"),
            Func::Expt if !tys[1].is_num() => return bad(self, 1, "a number"),
            Func::Expt => join(tys[0], tys[1]),
            Func::Move => tys[0],
            Func::Sel if tys[0] != Ty::Bool => return bad(self, 0, "BOOL"),
            Func::Sel => match common(self, 1) {
                Some(t) => t,
                None => return (FALSE, Ty::Err),
            },
            Func::Max | Func::Min | Func::Limit => match common(self, 0) {
                Some(t) => t,
                None => return (FALSE, Ty::Err),
            },
            Func::Mux if !tys[0].is_int() => return bad(self, 0, "an integer"),
            Func::Mux => match common(self, 1) {
                Some(t) => t,
                None => return (FALSE, Ty::Err),
            },
            Func::Shl | Func::Shr | Func::Rol | Func::Ror if !tys[0].is_int() => {
                return bad(self, 0, "a bit string or an integer")
            }
            Func::Shl | Func::Shr | Func::Rol | Func::Ror if !tys[1].is_int() => return bad(self, 1, "an integer"),
            Func::Shl | Func::Shr | Func::Rol | Func::Ror => match tys[0] {
                Ty::IntLit => Ty::Int(IntKind::Dword),
                t => t,
            },
            Func::Text(f) => match text_type(*f, &tys) {
                Ok(t) => t,
                Err((i, want)) => return bad(self, i, want),
            },
            Func::ToString(_) => unreachable!("from_name gives Convert"),
            Func::Convert(to) => {
                if let Some((from, _)) = key.split_once("_TO_") {
                    let from_ty = Type::from_name(from).map(|t| Ty::of(&t));
                    let fits = match from_ty {
                        Some(f) if f.is_int() => tys[0].is_int(),
                        Some(f @ Ty::Real { .. }) => tys[0].is_num() || tys[0] == f,
                        Some(f) => tys[0] == f,
                        None => true,
                    };
                    if !fits {
                        return bad(self, 0, from);
                    }
                }
                // To a STRING, the text depends on the argument's type (a DATE and a TIME are both held in ms).
                if let Type::Str { .. } = to {
                    if matches!(tys[0], Ty::Enum(_)) {
                        return bad(self, 0, "a number, a BOOL, a duration, a date or a time");
                    }
                    return (CExpr::call(Func::ToString(tys[0].repr()), cargs, Ty::Str.repr()), Ty::Str);
                }
                Ty::of(to)
            }
            Func::BitAnd | Func::BitOr | Func::BitXor | Func::BitNot => tys[0],
        };
        (CExpr::call(func, cargs, ty.repr()), ty)
    }

    /// A standard function's arguments in parameter order, as written and compiled, with their types; `None` once
    /// one is wrong (said).
    fn standard_args(
        &mut self,
        func: &Func,
        callee: &Ident,
        args: &[Arg],
        params: &[&str],
        vars: &[VarInfo],
    ) -> Option<(Vec<Expr>, Vec<CExpr>, Vec<Ty>)> {
        let values = self.positional(callee, args, params, func.extensible())?;
        let mut cargs = Vec::with_capacity(values.len());
        let mut tys = Vec::with_capacity(values.len());
        for (i, v) in values.iter().enumerate() {
            let (c, t) = self.expr(v, vars);
            // SEL's selector is a BOOL, which may be written 0 or 1.
            let (c, t) = if i == 0 && *func == Func::Sel { bool_literal((c, t)) } else { (c, t) };
            if t == Ty::Err {
                return None;
            }
            cargs.push(c);
            tys.push(t);
        }
        Some((values, cargs, tys))
    }

    /// A call's arguments in parameter order: non-formal as written, or formal matched to the parameter names
    /// (`IN1`, `IN2`, … beyond the declared ones for an extensible function).
    pub(super) fn positional(
        &mut self,
        callee: &Ident,
        args: &[Arg],
        params: &[&str],
        extensible: bool,
    ) -> Option<Vec<Expr>> {
        let formal = args.iter().any(|a| a.name.is_some());
        let name = callee.name.to_ascii_uppercase();
        if args.iter().any(|a| a.output) {
            let arg = args.iter().find(|a| a.output).expect("an output argument");
            self.error(arg.span, format!("{name} is a function: it has no outputs to write with `=>`"));
            return None;
        }
        let values: Vec<Expr> = if formal {
            let mut slots: Vec<Option<Expr>> = vec![None; params.len().max(args.len())];
            for arg in args {
                let Some(n) = &arg.name else {
                    self.error(
                        arg.span,
                        "a call mixes formal (`IN := x`) and non-formal arguments: name every argument",
                    );
                    return None;
                };
                let key = n.key();
                let index = params.iter().position(|p| *p == key).or_else(|| {
                    // IN3, IN4, … of an extensible function; MUX numbers its inputs from IN0.
                    let number: usize = key.strip_prefix("IN")?.parse().ok()?;
                    let first_in = params.iter().position(|p| p.starts_with("IN"))?;
                    let offset = if params[first_in] == "IN0" { number } else { number.checked_sub(1)? };
                    extensible.then_some(first_in + offset)
                });
                let Some(index) = index.filter(|&i| i < slots.len()) else {
                    self.error(n.span, format!("{name} has no parameter `{}`", n.name));
                    return None;
                };
                slots[index] = Some(arg.value.clone());
            }
            while slots.len() > params.len() && slots.last().is_some_and(|s| s.is_none()) {
                slots.pop();
            }
            if let Some(missing) = slots.iter().position(|s| s.is_none()) {
                let p = params.get(missing).map_or_else(|| format!("IN{missing}"), |p| p.to_string());
                self.error(callee.span, format!("{name} needs its parameter `{p}`"));
                return None;
            }
            slots.into_iter().map(|s| s.expect("every slot is filled")).collect()
        } else {
            args.iter().map(|a| a.value.clone()).collect()
        };
        let ok = if extensible { values.len() >= params.len() } else { values.len() == params.len() };
        if !ok {
            let n = params.len();
            let message = if extensible {
                format!("{name} takes {n} arguments or more, found {}", values.len())
            } else {
                format!("{name} takes {n} argument{}, found {}", if n == 1 { "" } else { "s" }, values.len())
            };
            self.error(callee.span, message);
            return None;
        }
        Some(values)
    }
}

/// A REAL of `t`'s width: LREAL stays LREAL, anything else is REAL.
fn real_of(t: Ty) -> Ty {
    match t {
        Ty::Real { long } => Ty::Real { long },
        _ => Ty::Real { long: false },
    }
}

/// The result of a date function on arguments of types `tys`, or the argument that does not fit and what it must be.
fn date_type(f: DateFn, tys: &[Ty]) -> Result<Ty, (usize, String)> {
    let (wanted, result): (&[Ty], Ty) = match f {
        DateFn::ConcatDateTod => (&[Ty::Date, Ty::Tod], Ty::Dt),
        DateFn::DayOfWeek => (&[Ty::Date], Ty::Int(IntKind::Usint)),
        DateFn::ConcatDate => (&[], Ty::Date),
        DateFn::ConcatTod => (&[], Ty::Tod),
        DateFn::ConcatDt | DateFn::Part(_) => (&[], Ty::Dt),
    };
    for (i, t) in tys.iter().enumerate() {
        match wanted.get(i) {
            Some(w) if t != w => return Err((i, w.name())),
            None if !t.is_int() => return Err((i, "an integer".to_string())),
            _ => {}
        }
    }
    Ok(result)
}

/// The result of a text function on arguments of types `tys`, or the argument that does not fit and what it must be.
fn text_type(f: TextFn, tys: &[Ty]) -> Result<Ty, (usize, &'static str)> {
    // Which arguments are strings; the others are lengths or positions.
    let strings: &[usize] = match f {
        TextFn::Len | TextFn::Left | TextFn::Right | TextFn::Mid | TextFn::Delete => &[0],
        TextFn::Insert | TextFn::Replace | TextFn::Find => &[0, 1],
        TextFn::Concat => &[],
    };
    for (i, t) in tys.iter().enumerate() {
        let string = strings.contains(&i) || f == TextFn::Concat;
        if string && *t != Ty::Str {
            return Err((i, "a STRING"));
        }
        if !string && !t.is_int() {
            return Err((i, "an integer"));
        }
    }
    Ok(match f {
        TextFn::Len | TextFn::Find => Ty::Int(IntKind::Int),
        _ => Ty::Str,
    })
}
