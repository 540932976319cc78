//! Chart values to OPC UA variants and back. A method's arguments are converted to the data types its
//! InputArguments declare (a literal `3` becomes a UInt32 if that is what the method takes, and a value out of
//! its range is an error, not a wrap); what a server answers becomes a BOOL, an integer, a REAL, a TIME or a
//! STRING of the chart.

use baton_proto::front::literal::{show_path, Literal, PathPart};
use baton_proto::types::Value;
use opcua::types::{Array, NodeId, UAString, Variant, VariantScalarTypeId};

/// The built-in data types (namespace 0) that a chart's values convert to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DataType {
    Boolean,
    SByte,
    Byte,
    Int16,
    UInt16,
    Int32,
    UInt32,
    Int64,
    UInt64,
    Float,
    Double,
    String,
    /// Milliseconds as a Double (OPC UA's Duration).
    Duration,
    /// BaseDataType, Number, Integer…: any; the literal's own kind decides.
    Any,
}

impl DataType {
    /// The data type a node id names, if it is one a chart can give.
    pub fn of(id: &NodeId) -> Option<DataType> {
        if id.namespace != 0 {
            return None;
        }
        Some(match id.as_u32()? {
            1 => DataType::Boolean,
            2 => DataType::SByte,
            3 => DataType::Byte,
            4 => DataType::Int16,
            5 => DataType::UInt16,
            6 => DataType::Int32,
            7 => DataType::UInt32,
            8 => DataType::Int64,
            9 => DataType::UInt64,
            10 => DataType::Float,
            11 => DataType::Double,
            12 => DataType::String,
            290 => DataType::Duration,
            // BaseDataType, Number, Integer, UInteger.
            24 | 26 | 27 | 28 => DataType::Any,
            _ => return None,
        })
    }

    fn scalar_id(self) -> VariantScalarTypeId {
        match self {
            DataType::Boolean => VariantScalarTypeId::Boolean,
            DataType::SByte => VariantScalarTypeId::SByte,
            DataType::Byte => VariantScalarTypeId::Byte,
            DataType::Int16 => VariantScalarTypeId::Int16,
            DataType::UInt16 => VariantScalarTypeId::UInt16,
            DataType::Int32 => VariantScalarTypeId::Int32,
            DataType::UInt32 => VariantScalarTypeId::UInt32,
            DataType::Int64 => VariantScalarTypeId::Int64,
            DataType::UInt64 => VariantScalarTypeId::UInt64,
            DataType::Float => VariantScalarTypeId::Float,
            DataType::Double | DataType::Duration => VariantScalarTypeId::Double,
            DataType::String => VariantScalarTypeId::String,
            DataType::Any => VariantScalarTypeId::Variant,
        }
    }
}

/// The literal as a variant of `ty`; an array literal where the argument is an array (`value_rank` ≥ 1).
pub fn to_variant(lit: &Literal, ty: DataType, array: bool) -> Result<Variant, String> {
    match (lit, array) {
        (Literal::Array(items), true) => {
            let values = items.iter().map(|l| scalar(l, ty)).collect::<Result<Vec<_>, _>>()?;
            let kind = match ty {
                DataType::Any => values.first().and_then(|v| v.scalar_type_id()).unwrap_or(VariantScalarTypeId::Int64),
                _ => ty.scalar_id(),
            };
            Array::new(kind, values).map(Variant::from).map_err(|e| format!("an array of mixed types: {e:?}"))
        }
        (Literal::Array(_), false) => Err(format!("an array where a {ty:?} is expected")),
        (_, true) => Err(format!("a single value where an array of {ty:?} is expected")),
        (_, false) => scalar(lit, ty),
    }
}

fn scalar(lit: &Literal, ty: DataType) -> Result<Variant, String> {
    let out_of_range = |v: &dyn std::fmt::Display| format!("{v} does not fit a {ty:?}");
    let int = |i: i64| -> Result<Variant, String> {
        Ok(match ty {
            DataType::SByte => Variant::SByte(i8::try_from(i).map_err(|_| out_of_range(&i))?),
            DataType::Byte => Variant::Byte(u8::try_from(i).map_err(|_| out_of_range(&i))?),
            DataType::Int16 => Variant::Int16(i16::try_from(i).map_err(|_| out_of_range(&i))?),
            DataType::UInt16 => Variant::UInt16(u16::try_from(i).map_err(|_| out_of_range(&i))?),
            DataType::Int32 => Variant::Int32(i32::try_from(i).map_err(|_| out_of_range(&i))?),
            DataType::UInt32 => Variant::UInt32(u32::try_from(i).map_err(|_| out_of_range(&i))?),
            DataType::Int64 | DataType::Any => Variant::Int64(i),
            DataType::UInt64 => Variant::UInt64(u64::try_from(i).map_err(|_| out_of_range(&i))?),
            DataType::Float => Variant::Float(i as f32),
            DataType::Double | DataType::Duration => Variant::Double(i as f64),
            DataType::Boolean | DataType::String => return Err(format!("the number {i} where a {ty:?} is expected")),
        })
    };
    match lit {
        Literal::Scalar(Value::Bool(b)) => match ty {
            DataType::Boolean | DataType::Any => Ok(Variant::Boolean(*b)),
            _ => Err(format!("a BOOL where a {ty:?} is expected")),
        },
        Literal::Scalar(Value::Int(i)) => int(*i),
        Literal::Scalar(Value::Real(r)) => match ty {
            DataType::Float => Ok(Variant::Float(*r as f32)),
            DataType::Double | DataType::Duration | DataType::Any => Ok(Variant::Double(*r)),
            _ => Err(format!("the real {r} where a {ty:?} is expected")),
        },
        Literal::Scalar(Value::Time(ms)) => match ty {
            DataType::Duration | DataType::Double | DataType::Any => Ok(Variant::Double(*ms as f64)),
            _ => int(*ms),
        },
        Literal::Text(text) => match ty {
            DataType::String | DataType::Any => Ok(Variant::String(UAString::from(text.as_str()))),
            _ => Err(format!("a STRING where a {ty:?} is expected")),
        },
        Literal::Scalar(Value::Str(text)) => scalar(&Literal::Text(text.to_string()), ty),
        Literal::Struct(_) => Err(format!("a structure where a {ty:?} is expected (structures are not supported)")),
        Literal::Array(_) => Err(format!("an array where a single {ty:?} is expected")),
    }
}

/// A server's value as a chart value: numbers, booleans, strings; a Duration stays a REAL of milliseconds.
pub fn from_variant(v: &Variant) -> Result<Value, String> {
    Ok(match v {
        Variant::Boolean(b) => Value::Bool(*b),
        Variant::SByte(i) => Value::Int(*i as i64),
        Variant::Byte(i) => Value::Int(*i as i64),
        Variant::Int16(i) => Value::Int(*i as i64),
        Variant::UInt16(i) => Value::Int(*i as i64),
        Variant::Int32(i) => Value::Int(*i as i64),
        Variant::UInt32(i) => Value::Int(*i as i64),
        Variant::Int64(i) => Value::Int(*i),
        Variant::UInt64(i) => Value::Int(i64::try_from(*i).map_err(|_| format!("{i} does not fit a LINT"))?),
        Variant::Float(r) => Value::Real(*r as f64),
        Variant::Double(r) => Value::Real(*r),
        Variant::String(s) => Value::Str(std::sync::Arc::new(s.as_ref().to_string())),
        Variant::LocalizedText(t) => Value::Str(std::sync::Arc::new(t.text.as_ref().to_string())),
        Variant::Variant(inner) => from_variant(inner)?,
        Variant::Empty => return Err("the server gave no value".into()),
        Variant::Array(_) => return Err("an array: name one of its elements, such as `[0]`".into()),
        other => return Err(format!("a {:?}, which a chart variable cannot hold", other.scalar_type_id())),
    })
}

/// The part of `values` (a method's output arguments, or the values read from nodes) that `path` names:
/// `[1]` is the second, `[1][0]` the first element of the second, an array.
pub fn value_at(values: &[Variant], path: &[PathPart]) -> Result<Value, String> {
    let Some(PathPart::Index(first)) = path.first() else {
        return Err(format!("`{}` must start with an index, such as `[0]`", show_path(path)));
    };
    let mut here = values.get(*first).ok_or_else(|| format!("there is no `[{first}]`: {} values", values.len()))?;
    for (depth, part) in path.iter().enumerate().skip(1) {
        here = match (part, here) {
            (PathPart::Index(i), Variant::Array(a)) => a.values.get(*i).ok_or_else(|| {
                format!("`{}` is past the end ({} elements)", show_path(&path[..=depth]), a.values.len())
            })?,
            (PathPart::Index(_), _) => return Err(format!("`{}` is not an array", show_path(&path[..depth]))),
            (PathPart::Field(f), _) => {
                return Err(format!("`{}`: fields of structures are not supported (`{f}`)", show_path(&path[..=depth])))
            }
        };
    }
    from_variant(here).map_err(|e| format!("`{}`: {e}", show_path(path)))
}

#[cfg(test)]
mod tests {
    use super::*;
    use baton_proto::front::literal::parse;

    #[test]
    fn arguments_take_the_declared_types_and_refuse_what_does_not_fit() {
        let lit = parse("[3, 2.5, TRUE, 'ab', T#2s]").unwrap();
        let Literal::Array(items) = lit else { panic!() };
        assert_eq!(to_variant(&items[0], DataType::UInt32, false), Ok(Variant::UInt32(3)));
        assert_eq!(to_variant(&items[0], DataType::Int16, false), Ok(Variant::Int16(3)));
        assert_eq!(to_variant(&items[0], DataType::Double, false), Ok(Variant::Double(3.0)));
        assert_eq!(to_variant(&items[1], DataType::Float, false), Ok(Variant::Float(2.5)));
        assert_eq!(to_variant(&items[2], DataType::Boolean, false), Ok(Variant::Boolean(true)));
        assert_eq!(to_variant(&items[3], DataType::String, false), Ok(Variant::String("ab".into())));
        assert_eq!(to_variant(&items[4], DataType::Duration, false), Ok(Variant::Double(2000.0)));
        assert!(to_variant(&Literal::Scalar(Value::Int(300)), DataType::Byte, false)
            .unwrap_err()
            .contains("does not fit"));
        assert!(to_variant(&Literal::Scalar(Value::Int(-1)), DataType::UInt32, false).is_err());
        assert!(to_variant(&items[1], DataType::Int32, false).is_err(), "a real is not cut to an integer");
        assert!(to_variant(&items[3], DataType::Int32, false).is_err());
        let array = to_variant(&parse("[1, 2]").unwrap(), DataType::Int16, true).unwrap();
        let Variant::Array(a) = array else { panic!("{array:?}") };
        assert_eq!(a.values, vec![Variant::Int16(1), Variant::Int16(2)]);
        assert!(to_variant(&items[0], DataType::Int16, true).is_err());
    }

    #[test]
    fn answers_become_chart_values_by_path() {
        let inner =
            Variant::from(Array::new(VariantScalarTypeId::Int32, vec![Variant::Int32(7), Variant::Int32(9)]).unwrap());
        let values = vec![Variant::UInt16(4), inner, Variant::String("ok".into()), Variant::Empty];
        let at = |p: Vec<PathPart>| value_at(&values, &p);
        assert_eq!(at(vec![PathPart::Index(0)]), Ok(Value::Int(4)));
        assert_eq!(at(vec![PathPart::Index(1), PathPart::Index(1)]), Ok(Value::Int(9)));
        assert_eq!(at(vec![PathPart::Index(2)]), Ok(Value::Str("ok".to_string().into())));
        assert!(at(vec![PathPart::Index(1), PathPart::Index(2)]).unwrap_err().contains("past the end"));
        assert!(at(vec![PathPart::Index(4)]).is_err());
        assert!(at(vec![PathPart::Index(3)]).is_err());
        assert!(at(vec![PathPart::Field("x".into())]).is_err());
        assert!(at(vec![PathPart::Index(1)]).unwrap_err().contains("array"));
    }
}
