//! Arrays and structures: their elements laid out as runs of variables, and element and field access.

use std::collections::HashMap;

use crate::exec::compile::typing::Ty;
use crate::exec::eval::{eval, is_constant, NoEnv};
use crate::exec::program::{CExpr, IndexExpr, VarId, VarInfo};
use crate::front::model::{ArraySpec, Expr, Ident, TypeKind, VarDecl};
use crate::types::library::StdFb;
use crate::types::{Type, Value};

use super::{ArrayInfo, Compiler, Storage};

impl<'a> Compiler<'a> {
    /// A structure variable: one variable per field, `s.field`, with the field's initial value or the one the
    /// declaration gives (`s : Point := (x := 1)`).
    pub(super) fn declare_struct(
        &mut self,
        decl: &VarDecl,
        fields: &[VarDecl],
        label: &str,
        hidden: bool,
        vars: &mut Vec<VarInfo>,
    ) {
        if self.struct_depth >= crate::limits::NESTING_DEPTH_MAX {
            let message = format!("structure `{}` holds itself, or nests too deep", decl.type_name.name);
            self.error(decl.type_name.span, message);
            return;
        }
        self.struct_depth += 1;
        let mut names = Vec::new();
        for f in fields {
            if StdFb::from_name(&f.type_name.key()).is_some() || self.library.contains_key(&f.type_name.key()) {
                let message = format!(
                    "field `{}` of `{}`: structures holding function block instances are not supported yet",
                    f.name.name, decl.type_name.name
                );
                self.error(f.type_name.span, message);
                continue;
            }
            // A field that is an array or a structure is a run of variables of its own, named by its path.
            let local = format!("{}.{}", decl.name.name, f.name.name);
            let path = format!("{label}.{}", f.name.name);
            if let Some(spec) = self.array_spec_of(f) {
                if let Some(info) = self.array_elements((&path, &local), &spec, Storage::of(decl, hidden), vars) {
                    self.arrays.insert(local.to_ascii_uppercase(), info);
                }
                names.push(f.name.name.clone());
                continue;
            }
            let structure = match self.types.get(&f.type_name.key()).copied().map(|t| &t.kind) {
                Some(TypeKind::Struct(inner)) => Some(inner),
                _ => None,
            };
            if let Some(inner) = structure {
                let sub = VarDecl {
                    name: Ident { name: local, span: f.name.span },
                    section: decl.section,
                    constant: decl.constant,
                    type_name: f.type_name.clone(),
                    init: None,
                    members: Vec::new(),
                    array: None,
                    pragmas: Vec::new(),
                    address: None,
                };
                self.declare_struct(&sub, inner, &path, hidden, vars);
                names.push(f.name.name.clone());
                continue;
            }
            let ty = self.resolve_type(&f.type_name);
            let given = decl.members.iter().find(|(m, _)| m.key() == f.name.key()).map(|(_, e)| e);
            let init = match given.or(f.init.as_ref()) {
                Some(e) => self.initial_value(e, &ty),
                None => self.default_of(&ty),
            };
            self.vars.insert(format!("{}.{}", decl.name.key(), f.name.key()), VarId(vars.len() as u32));
            vars.push(VarInfo {
                name: format!("{label}.{}", f.name.name),
                ty,
                init,
                constant: decl.constant,
                section: decl.section,
                hidden,
            });
            names.push(f.name.name.clone());
        }
        for (m, _) in &decl.members {
            if !fields.iter().any(|f| f.name.key() == m.key()) {
                self.error(m.span, format!("`{}` has no field `{}`", decl.type_name.name, m.name));
            }
        }
        self.structs.insert(decl.name.key(), (decl.type_name.name.clone(), names));
        self.struct_depth -= 1;
    }

    /// An array variable: one variable per element, `a[1]`, `a[1,2]`, row-major.
    pub(super) fn declare_array(&mut self, decl: &VarDecl, spec: &ArraySpec, vars: &mut Vec<VarInfo>) {
        let label = decl.name.name.clone();
        if let Some(info) = self.array_elements((&label, &label), spec, Storage::of(decl, false), vars) {
            self.arrays.insert(decl.name.key(), info);
        }
    }

    /// The array a declaration declares: `ARRAY […] OF …` in it, or an array type by name.
    pub(super) fn array_spec_of(&self, decl: &VarDecl) -> Option<ArraySpec> {
        decl.array.clone().or_else(|| match self.types.get(&decl.type_name.key()).map(|t| &t.kind) {
            Some(TypeKind::Array(spec)) => Some(spec.clone()),
            _ => None,
        })
    }

    /// An array's elements, as variables named `label[1,2]` (row-major, the last index fastest) with their
    /// initial values; `None` after an error.
    pub(super) fn array_elements(
        &mut self,
        (label, local): (&str, &str),
        spec: &ArraySpec,
        storage: Storage,
        vars: &mut Vec<VarInfo>,
    ) -> Option<ArrayInfo> {
        let Storage { constant, section, hidden } = storage;
        if let Some(&(low, high)) = spec.dims.iter().find(|(low, high)| high < low) {
            self.error(spec.span, format!("array `{label}` has an empty dimension {low}..{high}"));
            return None;
        }
        // In 128 bits: a dimension over the whole of LINT has 2^64 elements, which must not wrap to zero.
        let len = spec.elements().filter(|&n| n <= crate::limits::ARRAY_ELEMENTS_MAX as u64);
        let Some(len) = len.map(|n| n as usize) else {
            let size: String = spec.dims.iter().map(|(l, h)| format!("[{l}..{h}]")).collect();
            let message = format!(
                "array `{label}` {size} has more elements than the {} Baton holds",
                crate::limits::ARRAY_ELEMENTS_MAX
            );
            self.error(spec.span, message);
            return None;
        };
        if vars.len().saturating_add(len) > crate::limits::VARIABLES_MAX {
            let message = format!(
                "array `{label}` takes the chart past {} variables (elements of arrays, members of blocks)",
                crate::limits::VARIABLES_MAX
            );
            self.error(spec.span, message);
            return None;
        }
        if StdFb::from_name(&spec.elem.key()).is_some() || self.library.contains_key(&spec.elem.key()) {
            self.error(spec.elem.span, "arrays of function block instances are not supported yet");
            return None;
        }
        let structure = match self.types.get(&spec.elem.key()).copied().map(|t| &t.kind) {
            Some(TypeKind::Struct(fields)) => Some(fields),
            _ => None,
        };
        if let Some(fields) = structure {
            return self.struct_elements((label, local), spec, fields, len, storage, vars);
        }
        let elem = self.resolve_type(&spec.elem);
        if spec.init_len() > len as u64 {
            // The run that goes past the end: the values before it still count.
            let mut given = 0u64;
            let past = spec.init.iter().find(|r| {
                given = given.saturating_add(r.count);
                given > len as u64
            });
            if let Some(run) = past {
                self.error(run.value.span, format!("array `{label}` has {len} elements, and more initial values"));
            }
        }
        let base = VarId(vars.len() as u32);
        let default = self.default_of(&elem);
        let mut index: Vec<i64> = spec.dims.iter().map(|&(low, _)| low).collect();
        // Each run's value is computed once, then given to as many elements as it counts.
        let mut runs = spec.init.iter();
        let mut current: Option<(Value, u64)> = None;
        for _ in 0..len {
            if current.as_ref().is_none_or(|(_, left)| *left == 0) {
                current = runs.next().map(|r| (self.initial_value(&r.value, &elem), r.count));
            }
            let init = match current.as_mut() {
                Some((v, left)) if *left > 0 => {
                    *left -= 1;
                    v.clone()
                }
                _ => default.clone(),
            };
            let index_label: Vec<String> = index.iter().map(|i| i.to_string()).collect();
            vars.push(VarInfo {
                name: format!("{label}[{}]", index_label.join(",")),
                ty: elem.clone(),
                init,
                constant,
                section,
                hidden,
            });
            // The next index, the last dimension fastest.
            for d in (0..index.len()).rev() {
                if index[d] < spec.dims[d].1 {
                    index[d] += 1;
                    break;
                }
                index[d] = spec.dims[d].0;
            }
        }
        Some(ArrayInfo { base, dims: spec.dims.clone(), len: len as u32, elem, stride: 1, fields: HashMap::new() })
    }

    /// An array of structures: each element a run of field variables (`pts[2].x`, the fields of fields too),
    /// elements one after another, so that a field of an element indexed at run time is `base + field + i ·
    /// stride`.
    pub(super) fn struct_elements(
        &mut self,
        (label, local): (&str, &str),
        spec: &ArraySpec,
        fields: &[VarDecl],
        len: usize,
        Storage { constant, section, hidden }: Storage,
        vars: &mut Vec<VarInfo>,
    ) -> Option<ArrayInfo> {
        if let Some(first) = spec.init.first() {
            self.error(
                first.value.span,
                format!("initial values of `{label}`, an array of structures, are not supported yet"),
            );
        }
        let base = VarId(vars.len() as u32);
        let mut index: Vec<i64> = spec.dims.iter().map(|&(low, _)| low).collect();
        let (mut stride, mut at) = (0, HashMap::new());
        for k in 0..len {
            let idx = index.iter().map(|i| i.to_string()).collect::<Vec<_>>().join(",");
            let start = vars.len();
            let decl = VarDecl {
                name: Ident { name: format!("{local}[{idx}]"), span: spec.span },
                section,
                constant,
                type_name: spec.elem.clone(),
                init: None,
                members: Vec::new(),
                array: None,
                pragmas: Vec::new(),
                address: None,
            };
            self.declare_struct(&decl, fields, &format!("{label}[{idx}]"), hidden, vars);
            if k == 0 {
                stride = vars.len() - start;
                for f in fields {
                    let name = format!("{label}[{idx}].{}", f.name.name);
                    if let Some(i) = (start..vars.len()).find(|&i| vars[i].name.eq_ignore_ascii_case(&name)) {
                        at.insert(f.name.key(), ((i - start) as u32, vars[i].ty.clone()));
                    }
                }
            }
            let total = len.saturating_mul(stride);
            if stride == 0
                || total > crate::limits::ARRAY_ELEMENTS_MAX
                || start.saturating_add(total) > crate::limits::VARIABLES_MAX
            {
                let message = format!("array `{label}` holds structures with no field, or too many variables");
                self.error(spec.span, message);
                return None;
            }
            for d in (0..index.len()).rev() {
                if index[d] < spec.dims[d].1 {
                    index[d] += 1;
                    break;
                }
                index[d] = spec.dims[d].0;
            }
        }
        let elem = Type::Unsupported(spec.elem.name.clone());
        Some(ArrayInfo {
            base,
            dims: spec.dims.clone(),
            len: (len * stride) as u32,
            elem,
            stride: stride as u32,
            fields: at,
        })
    }

    /// An array element: a variable when every index is a constant (checked against the bounds), else an
    /// index computed at run time.
    pub(super) fn element(&mut self, name: &Ident, indices: &[Expr], vars: &[VarInfo]) -> Option<(CExpr, Ty)> {
        let Some(info) = self.arrays.get(&name.key()) else {
            if !self.chart.broken.var(&name.key()) {
                self.error(name.span, format!("`{}` is not an array", name.name));
            }
            return None;
        };
        if !info.fields.is_empty() {
            let first = info.fields.iter().min_by_key(|(_, (at, _))| *at).map(|(f, _)| f.clone()).unwrap_or_default();
            let message = format!(
                "`{}` holds structures: use one of their fields, such as `{}[…].{}`",
                name.name,
                name.name,
                first.to_ascii_lowercase()
            );
            self.error(name.span, message);
            return None;
        }
        self.indexed(name, indices, 0, None, vars)
    }

    /// A field of an array's structure element: `pts[i].x`.
    pub(super) fn element_field(
        &mut self,
        name: &Ident,
        indices: &[Expr],
        field: &Ident,
        vars: &[VarInfo],
    ) -> Option<(CExpr, Ty)> {
        let Some(info) = self.arrays.get(&name.key()) else {
            if !self.chart.broken.var(&name.key()) {
                self.error(name.span, format!("`{}` is not an array", name.name));
            }
            return None;
        };
        let Some((offset, ty)) = info.fields.get(&field.key()).cloned() else {
            let message = if info.fields.is_empty() {
                format!("`{}` holds {} values, which have no field `{}`", name.name, info.elem, field.name)
            } else {
                format!(
                    "the structures in `{}` have no field `{}` (fields of fields need constant indices)",
                    name.name, field.name
                )
            };
            self.error(field.span, message);
            return None;
        };
        self.indexed(name, indices, offset, Some(ty), vars)
    }

    /// Element `offset` of the element `indices` name: a variable when every index is a constant (checked
    /// against the bounds), else an index computed at run time.
    pub(super) fn indexed(
        &mut self,
        name: &Ident,
        indices: &[Expr],
        offset: u32,
        field: Option<Type>,
        vars: &[VarInfo],
    ) -> Option<(CExpr, Ty)> {
        let info = self.arrays.get(&name.key())?;
        let (base, dims, len, stride) = (info.base, info.dims.clone(), info.len, info.stride);
        let elem = field.unwrap_or_else(|| info.elem.clone());
        if indices.len() != dims.len() {
            let message = format!("`{}` has {} dimension(s), indexed with {}", name.name, dims.len(), indices.len());
            self.error(name.span, message);
            return None;
        }
        let mut compiled = Vec::with_capacity(indices.len());
        let mut constant = Some(0i64);
        for (e, &(low, high)) in indices.iter().zip(&dims) {
            let (c, ty) = self.expr(e, vars);
            if !ty.is_int() && ty != Ty::Err {
                self.error(e.span, format!("an array index must be an integer, found {}", ty.name()));
                return None;
            }
            match (constant, is_constant(&c).then(|| eval(&c, &NoEnv))) {
                (Some(acc), Some(Ok(v))) => {
                    let i = v.as_i64();
                    if i < low || i > high {
                        self.error(e.span, format!("index {i} is outside `{}`'s bounds {low}..{high}", name.name));
                        return None;
                    }
                    constant = Some(acc * (high - low + 1) + (i - low));
                }
                _ => constant = None,
            }
            compiled.push(c);
        }
        let ty = Ty::of(&elem);
        Some(match constant {
            Some(at) => (CExpr::Var(VarId(base.0 + offset + at as u32 * stride)), ty),
            None => (CExpr::Index(Box::new(IndexExpr { base, dims, indices: compiled, len, stride, offset })), ty),
        })
    }
}
