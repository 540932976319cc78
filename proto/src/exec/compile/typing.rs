//! Type names resolved (aliases, subranges, enumerations), and `Ty`, the compiler's view of an expression's type.
//!
//! Types: `resolve_type` turns a declared type (`TypeDef`, from a TYPE block or PLCopen `dataTypes`, kept in
//! `Parsed::types`) into a `Type`: an enumeration becomes `Type::Enum` (values held as ordinals, shown by name), a
//! subrange or an alias its base type; `STRING[n]` is a type name of its own (`Type::Str`), which both parsers write
//! so. Enumeration values resolve after variables, alone or as `T#V`. An array variable is a run of element variables
//! (`a[1,2]`, row-major, `declare_array`); an element with constant indices compiles to that variable, one with a
//! run-time index to `CExpr::Index` / `CStmt::AssignIndex`, which read (and write) every element as far as `Reads` and
//! the layout know. A structure variable is a run of field variables (`s.f`, `declare_struct`), recursively: a field
//! that is a structure or an array is a run of its own (`s.a.x`, `s.tags[1]`), and an array of structures holds its
//! elements' runs one after another (`struct_elements`), so that `pts[i].x` is `CExpr::Index` with a stride and the
//! field's offset. The parser reads a path as one name up to its last member (`s.a` in `s.a.x`, and `pts[2]` when the
//! indices are literals), which is how those variables are named; only `pts[i].x` with a run-time index is an
//! `ExprKind::IndexField`.

use crate::exec::program::CExpr;
use crate::front::diag::Span;
use crate::front::model::{BinOp, Ident, TypeKind};
use crate::types::{IntKind, Type, Value};

use super::{Compiler, FALSE};

/// The static type of an expression. `IntLit` is an integer literal, which fits any numeric type; `Err` follows
/// an expression whose error is already reported, so that one mistake yields one message.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Ty {
    Bool,
    Int(IntKind),
    IntLit,
    Real {
        long: bool,
    },
    Time,
    Date,
    Tod,
    Dt,
    /// A value of the enumeration with this id.
    Enum(u32),
    /// A STRING of any length: a variable's own length cuts what is stored in it.
    Str,
    Err,
}

impl Ty {
    pub(super) fn of(ty: &Type) -> Ty {
        match ty {
            Type::Enum(e) => Ty::Enum(e.id),
            Type::Date => Ty::Date,
            Type::Tod => Ty::Tod,
            Type::Dt => Ty::Dt,
            Type::Bool => Ty::Bool,
            Type::Int(k) => Ty::Int(*k),
            Type::Real { long } => Ty::Real { long: *long },
            Type::Time => Ty::Time,
            Type::Str { .. } => Ty::Str,
            Type::Unsupported(_) => Ty::Err,
        }
    }

    pub(super) fn is_int(self) -> bool {
        matches!(self, Ty::Int(_) | Ty::IntLit)
    }

    pub(super) fn is_num(self) -> bool {
        self.is_int() || matches!(self, Ty::Real { .. })
    }

    pub(super) fn name(self) -> String {
        match self {
            Ty::Bool => "BOOL".into(),
            Ty::Int(k) => Type::Int(k).to_string(),
            Ty::IntLit => "an integer".into(),
            Ty::Real { long } => Type::Real { long }.to_string(),
            Ty::Time => "TIME".into(),
            Ty::Enum(_) => "an enumeration value".into(),
            Ty::Date => "DATE".into(),
            Ty::Tod => "TIME_OF_DAY".into(),
            Ty::Dt => "DATE_AND_TIME".into(),
            Ty::Str => "STRING".into(),
            Ty::Err => "an invalid expression".into(),
        }
    }

    pub(super) fn wrap(self) -> Option<IntKind> {
        match self {
            Ty::Int(k) => Some(k),
            _ => None,
        }
    }

    /// The run-time type a result of this static type is held as.
    pub(super) fn repr(self) -> Type {
        match self {
            Ty::Bool | Ty::Err => Type::Bool,
            Ty::Int(k) => Type::Int(k),
            Ty::IntLit => Type::Int(IntKind::Lint),
            Ty::Real { long } => Type::Real { long },
            Ty::Time => Type::Time,
            Ty::Enum(_) => Type::Int(IntKind::Dint),
            Ty::Date => Type::Date,
            Ty::Tod => Type::Tod,
            Ty::Dt => Type::Dt,
            Ty::Str => Type::Str { max: crate::limits::STRING_LENGTH_MAX as u32 },
        }
    }
}

/// The common numeric type of two numeric operands.
pub(super) fn join(a: Ty, b: Ty) -> Ty {
    match (a, b) {
        (Ty::Real { long: x }, Ty::Real { long: y }) => Ty::Real { long: x || y },
        (Ty::Real { long }, _) | (_, Ty::Real { long }) => Ty::Real { long },
        (Ty::Int(x), Ty::Int(y)) => Ty::Int(x.wider(y)),
        (Ty::Int(k), _) | (_, Ty::Int(k)) => Ty::Int(k),
        _ => Ty::IntLit,
    }
}

pub(super) fn binary_type(op: BinOp, a: Ty, b: Ty) -> Option<Ty> {
    use BinOp::*;
    match op {
        Or | Xor | And if a.is_int() && b.is_int() => Some(join(a, b)),
        Or | Xor | And => (a == Ty::Bool && b == Ty::Bool).then_some(Ty::Bool),
        Pow => (a.is_num() && b.is_num()).then(|| join(a, b)),
        Eq | Ne | Lt | Le | Gt | Ge => {
            let ok = (a.is_num() && b.is_num())
                || (a == b && matches!(a, Ty::Time | Ty::Date | Ty::Tod | Ty::Dt | Ty::Str))
                || (a == Ty::Bool && b == Ty::Bool)
                || (matches!(a, Ty::Enum(_)) && a == b);
            ok.then_some(Ty::Bool)
        }
        Add | Sub if a == Ty::Time && b == Ty::Time => Some(Ty::Time),
        // A time of day or a date and time moved by a duration; the duration between two of them.
        Add if matches!((a, b), (Ty::Tod | Ty::Dt, Ty::Time)) => Some(a),
        Add if matches!((a, b), (Ty::Time, Ty::Tod | Ty::Dt)) => Some(b),
        Sub if matches!((a, b), (Ty::Tod | Ty::Dt, Ty::Time)) => Some(a),
        Sub if a == b && matches!(a, Ty::Tod | Ty::Dt | Ty::Date) => Some(Ty::Time),
        Mul if (a == Ty::Time && b.is_num()) || (a.is_num() && b == Ty::Time) => Some(Ty::Time),
        Div if a == Ty::Time && b.is_num() => Some(Ty::Time),
        Mod => (a.is_int() && b.is_int()).then(|| join(a, b)),
        Add | Sub | Mul | Div => (a.is_num() && b.is_num()).then(|| join(a, b)),
    }
}

/// The standard's functions of durations, times of day and dates that are operators on them (IEC 61131-3
/// table 30): the operator and the types of its two operands (`None`: any number). The LTIME forms are the same
/// functions: Baton holds every duration in milliseconds.
pub(super) fn time_function(upper: &str) -> Option<(BinOp, [Option<Ty>; 2])> {
    let plain: Vec<&str> = upper
        .split('_')
        .map(|w| match w {
            "LTIME" => "TIME",
            "LTOD" => "TOD",
            "LDT" => "DT",
            "LDATE" => "DATE",
            w => w,
        })
        .collect();
    let (t, tod, dt, date) = (Some(Ty::Time), Some(Ty::Tod), Some(Ty::Dt), Some(Ty::Date));
    Some(match plain.join("_").as_str() {
        "ADD_TIME" => (BinOp::Add, [t, t]),
        "ADD_TOD_TIME" => (BinOp::Add, [tod, t]),
        "ADD_DT_TIME" => (BinOp::Add, [dt, t]),
        "SUB_TIME" => (BinOp::Sub, [t, t]),
        "SUB_DATE_DATE" => (BinOp::Sub, [date, date]),
        "SUB_TOD_TIME" => (BinOp::Sub, [tod, t]),
        "SUB_TOD_TOD" => (BinOp::Sub, [tod, tod]),
        "SUB_DT_TIME" => (BinOp::Sub, [dt, t]),
        "SUB_DT_DT" => (BinOp::Sub, [dt, dt]),
        "MUL_TIME" => (BinOp::Mul, [t, None]),
        "DIV_TIME" => (BinOp::Div, [t, None]),
        _ => return None,
    })
}

/// IEC 61131-3 writes BOOL literals as 0 and 1 too (a transition `:= 1;`, `ORANGE_LIGHT := 1;` in Beremiz's
/// examples): an untyped integer 0 or 1 where a BOOL is wanted is that BOOL; anything else is left as it is.
pub(super) fn bool_literal((c, ty): (CExpr, Ty)) -> (CExpr, Ty) {
    match (&c, ty) {
        (CExpr::Const(Value::Int(v @ (0 | 1))), Ty::IntLit) => (CExpr::Const(Value::Bool(*v == 1)), Ty::Bool),
        _ => (c, ty),
    }
}

/// Whether a value of type `value` may be stored in a variable of type `target`.
pub(super) fn assignable(target: Ty, value: Ty) -> bool {
    target == value
        || target == Ty::Err
        || value == Ty::Err
        || (target.is_int() && value.is_int())
        || (matches!(target, Ty::Real { .. }) && value.is_num())
}

impl<'a> Compiler<'a> {
    /// A type by name: elementary, or declared in the file (an enumeration; a subrange or an alias as its base).
    pub(super) fn resolve_type(&mut self, name: &Ident) -> Type {
        self.resolve_depth(name, 0)
    }

    pub(super) fn resolve_depth(&mut self, name: &Ident, depth: usize) -> Type {
        let key = name.key();
        if let Some(t) = Type::from_name(&key) {
            return t;
        }
        if let Some(t) = self.resolved.get(&key) {
            return t.clone();
        }
        let unsupported = || Type::Unsupported(name.name.to_ascii_uppercase());
        let Some(&def) = self.types.get(&key) else { return unsupported() };
        if depth > 16 {
            self.error(name.span, format!("type `{}` is defined through itself", name.name));
            return unsupported();
        }
        let ty = match &def.kind {
            TypeKind::Enum { values, init } => {
                let id = self.enums.len() as u32;
                let et = crate::types::EnumType {
                    id,
                    name: def.name.name.clone(),
                    values: values.iter().map(|v| v.name.clone()).collect(),
                };
                let start = match init {
                    Some(i) => match values.iter().position(|v| v.key() == i.key()) {
                        Some(p) => p as i64,
                        None => {
                            self.error(i.span, format!("`{}` is not a value of `{}`", i.name, def.name.name));
                            0
                        }
                    },
                    None => 0,
                };
                let et = std::sync::Arc::new(et);
                self.enums.push((std::sync::Arc::clone(&et), start));
                Type::Enum(et)
            }
            TypeKind::Subrange { base, .. } | TypeKind::Alias(base) => self.resolve_depth(base, depth + 1),
            // Arrays and structures are laid out where a variable is declared with them.
            TypeKind::Array(_) | TypeKind::Struct(_) => unsupported(),
            TypeKind::Unsupported(_) => unsupported(),
        };
        self.resolved.insert(key, ty.clone());
        ty
    }

    /// A variable's initial value when its declaration gives none: an enumeration's declared one, or the type's.
    /// The range of a subrange type (through aliases of it), with the type's name.
    pub(super) fn subrange(&self, name: &Ident) -> Option<(i64, i64, String)> {
        let mut key = name.key();
        for _ in 0..crate::limits::NESTING_DEPTH_MAX {
            match &self.types.get(&key)?.kind {
                TypeKind::Subrange { low, high, .. } => return Some((*low, *high, name.name.clone())),
                TypeKind::Alias(base) => key = base.key(),
                _ => return None,
            }
        }
        None
    }

    /// A constant stored in a subrange variable must be in its range (IEC 61131-3 calls anything else an error;
    /// like matiec and CODESYS without its CheckRange functions, Baton checks constants, not run-time values).
    pub(super) fn check_range(&mut self, span: Span, v: &Value, (low, high, ty): &(i64, i64, String)) {
        if let Value::Int(i) = *v {
            if i < *low || i > *high {
                self.error(span, format!("{i} is outside the range of {ty} ({low}..{high})"));
            }
        }
    }

    pub(super) fn default_of(&self, ty: &Type) -> Value {
        match ty {
            Type::Enum(e) => Value::Int(self.enums.get(e.id as usize).map_or(0, |(_, start)| *start)),
            other => other.default_value(),
        }
    }

    /// An enumeration value by name (alone, or with its type: `VALVE#OPEN`).
    pub(super) fn enum_value(&mut self, ty: Option<&Ident>, value: &Ident) -> Option<(CExpr, Ty)> {
        let mut found = Vec::new();
        if let Some(t) = ty {
            if let Type::Enum(e) = self.resolve_type(t) {
                found.extend(e.values.iter().position(|v| v.eq_ignore_ascii_case(&value.name)).map(|i| (e.id, i)));
            }
        } else {
            for (e, _) in &self.enums {
                found.extend(e.values.iter().position(|v| v.eq_ignore_ascii_case(&value.name)).map(|i| (e.id, i)));
            }
        }
        match found.as_slice() {
            [(id, i)] => Some((CExpr::Const(Value::Int(*i as i64)), Ty::Enum(*id))),
            [] => None,
            _ => {
                let message = format!(
                    "`{}` is a value of several enumerations: write it with its type, `TYPE#{}`",
                    value.name, value.name
                );
                self.error(value.span, message);
                Some((FALSE, Ty::Err))
            }
        }
    }
}
