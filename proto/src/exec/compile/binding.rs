//! Arguments bound to parameters: the one binder of every call with outputs — standard and user function block
//! instances, and the `SPLIT_*` functions. It matches formal (`IN := x`, `Q => y`, `NOT Q => y`) and non-formal
//! arguments to the callee's parameters, takes EN, and refuses what no parameter takes, with the same words for
//! every kind of callee; the caller then types each bound argument against its parameter and builds its
//! statement.

use crate::exec::compile::typing::{assignable, bool_literal, Ty};
use crate::exec::program::{CExpr, VarId, VarInfo};
use crate::front::model::{Arg, Ident};
use crate::types::Type;

use super::Compiler;

/// Which way a parameter passes its value.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Dir {
    Input,
    /// VAR_IN_OUT: a variable, passed by reference.
    InOut,
    Output,
}

/// A callee's parameters as the binder sees them.
pub(super) struct Params {
    /// The callee as messages name it: `TON`, or a user block's name in backquotes.
    pub shown: String,
    /// Each parameter's (upper-case) name and direction.
    pub params: Vec<(String, Dir)>,
    /// The parameters non-formal arguments fill, in order.
    pub positional: Vec<usize>,
    /// Whether `EN := condition` is taken (function block calls).
    pub en: bool,
    /// What is said of a non-formal argument past the last positional parameter.
    pub too_many: String,
}

impl Params {
    /// The parameters, in order, with non-formal arguments filling every input and in-out (a block's call).
    pub fn block(shown: String, params: Vec<(String, Dir)>) -> Params {
        let positional: Vec<usize> = (0..params.len()).filter(|&i| params[i].1 != Dir::Output).collect();
        let too_many = format!("too many arguments: {shown} takes {} inputs", positional.len());
        Params { shown, params, positional, en: true, too_many }
    }
}

/// A call's arguments, bound: EN's condition, and each argument with the index of its parameter.
pub(super) struct Bound<'a> {
    pub en: Option<CExpr>,
    pub args: Vec<(usize, &'a Arg)>,
}

impl<'a> Compiler<'a> {
    /// Binds `args` to `p`'s parameters, reporting every argument no parameter takes. An unknown parameter name is
    /// reported by `unknown`, which knows what the callee has. `None` when anything was reported.
    pub(super) fn bind<'g>(
        &mut self,
        p: &Params,
        args: &'g [Arg],
        vars: &[VarInfo],
        unknown: &mut dyn FnMut(&mut Self, &Ident),
    ) -> Option<Bound<'g>> {
        let formal = args.iter().any(|a| a.name.is_some());
        let (mut en, mut bound) = (None, Vec::with_capacity(args.len()));
        let mut ok = true;
        let mut positional = 0;
        for arg in args {
            if formal && arg.name.is_none() {
                self.error(arg.span, "a call mixes formal (`IN := x`) and non-formal arguments: name every argument");
                ok = false;
                continue;
            }
            if p.en && arg.name.as_ref().is_some_and(|n| n.key() == "EN") {
                if arg.output {
                    self.error(arg.span, "EN is an input: write `EN := condition`");
                    ok = false;
                } else {
                    en = Some(self.condition(&arg.value, vars, "EN"));
                }
                continue;
            }
            let index = match &arg.name {
                Some(n) => match p.params.iter().position(|(name, _)| name.eq_ignore_ascii_case(&n.name)) {
                    Some(i) => i,
                    None => {
                        unknown(self, n);
                        ok = false;
                        continue;
                    }
                },
                None => match p.positional.get(positional) {
                    Some(&i) => {
                        positional += 1;
                        i
                    }
                    None => {
                        self.error(arg.span, p.too_many.clone());
                        ok = false;
                        continue;
                    }
                },
            };
            // Formal arguments say their direction; a non-formal one takes its parameter's.
            let (name, dir) = &p.params[index];
            if arg.name.is_some() {
                let wrong = match (dir, arg.output) {
                    (Dir::Output, false) => {
                        Some(format!("`{name}` is an output of {}: write `{name} => variable`", p.shown))
                    }
                    (Dir::Input | Dir::InOut, true) => {
                        Some(format!("`{name}` is an input of {}: write `{name} := value`", p.shown))
                    }
                    _ => None,
                };
                if let Some(message) = wrong {
                    self.error(arg.span, message);
                    ok = false;
                    continue;
                }
            }
            bound.push((index, arg));
        }
        ok.then_some(Bound { en, args: bound })
    }

    /// An input argument's value, typed against its parameter's type `to`: a literal 0 or 1 is a BOOL where a
    /// BOOL is wanted. `None` (reported, naming the parameter `what`) when the value does not fit.
    pub(super) fn input_value(&mut self, arg: &Arg, to: &Type, what: &str, vars: &[VarInfo]) -> Option<CExpr> {
        let target = Ty::of(to);
        let (value, ty) = self.expr(&arg.value, vars);
        let (value, ty) = if target == Ty::Bool { bool_literal((value, ty)) } else { (value, ty) };
        if !assignable(target, ty) {
            self.error(arg.value.span, format!("{what} is {to}, found {}", ty.name()));
            return None;
        }
        Some(value)
    }

    /// An output argument's target, typed against its parameter (`name`, of type `from`): the variable the value
    /// is written to, and whether it is written negated (`NOT Q => y`, BOOL outputs only).
    pub(super) fn output_target(&mut self, arg: &Arg, name: &str, from: &Type, vars: &[VarInfo]) -> Option<VarId> {
        let target = self.place(&arg.value, vars)?;
        let (target_ty, from_ty) = (Ty::of(&vars[target.index()].ty), Ty::of(from));
        if arg.negated && from_ty != Ty::Bool {
            self.error(arg.span, format!("NOT applies to BOOL outputs, and `{name}` is {from}"));
            return None;
        }
        if !assignable(target_ty, from_ty) {
            let message = format!(
                "`{name}` is {from} and cannot be written to `{}`, which is {}",
                vars[target.index()].name,
                vars[target.index()].ty
            );
            self.error(arg.value.span, message);
            return None;
        }
        Some(target)
    }
}
