//! ROS 2 messages of types known only at run time, in CDR (little endian, as rmw_zenoh sends them): a goal or a
//! request written in the chart as an IEC literal is encoded field by field from its definition, and an
//! answer is decoded into a `RosValue` tree, from which the binding's mappings take their parts. The byte
//! layout (alignment, strings, sequences) is hiroz-cdr's.

use std::sync::Arc;

use baton_proto::front::literal::{show_path, Literal, PathPart};
use baton_proto::types::Value;
use hiroz_cdr::{CdrReader, CdrWriter, LittleEndian};
use hiroz_codegen::types::DefaultValue;

use super::interfaces::{Field, Interfaces, MsgDef, Prim, Shape};

/// The encapsulation header of little-endian plain CDR.
const CDR_LE: [u8; 4] = [0x00, 0x01, 0x00, 0x00];
/// Nesting of messages in one message: real interfaces nest a handful deep.
const DEPTH_MAX: usize = 32;
/// Elements decoded from one message: an answer larger than this is refused rather than held.
const ELEMENTS_MAX: usize = 1_000_000;

/// A decoded value.
#[derive(Clone, Debug, PartialEq)]
pub enum RosValue {
    Bool(bool),
    Int(i64),
    UInt(u64),
    Float(f64),
    Str(String),
    List(Vec<RosValue>),
    /// A message: its type name and its fields in order.
    Msg(String, Vec<(String, RosValue)>),
}

impl RosValue {
    /// The part of the value at `path`, field names ignoring case.
    pub fn at(&self, path: &[PathPart]) -> Option<&RosValue> {
        let Some((first, rest)) = path.split_first() else { return Some(self) };
        let next = match (self, first) {
            (RosValue::Msg(_, fields), PathPart::Field(f)) => {
                fields.iter().find(|(n, _)| n.eq_ignore_ascii_case(f)).map(|(_, v)| v)?
            }
            (RosValue::List(items), PathPart::Index(i)) => items.get(*i)?,
            _ => return None,
        };
        next.at(rest)
    }

    /// The part at `path` as a chart value: numbers, booleans, strings, and a `builtin_interfaces` Time or
    /// Duration as a TIME.
    pub fn value_at(&self, path: &[PathPart]) -> Result<Value, String> {
        let part = self.at(path).ok_or_else(|| format!("the answer has no `{}`", show_path(path)))?;
        match part {
            RosValue::Bool(b) => Ok(Value::Bool(*b)),
            RosValue::Int(i) => Ok(Value::Int(*i)),
            RosValue::UInt(u) => Ok(Value::Int(i64::try_from(*u).unwrap_or(i64::MAX))),
            RosValue::Float(f) => Ok(Value::Real(*f)),
            RosValue::Str(s) => Ok(Value::string(s.clone())),
            RosValue::Msg(ty, fields) if is_time(ty) => {
                let get = |n: &str| fields.iter().find(|(f, _)| f == n).map_or(0, |(_, v)| v.as_i64());
                Ok(Value::Time(get("sec") * 1000 + get("nanosec") / 1_000_000))
            }
            RosValue::Msg(ty, _) => Err(format!("`{}` is a {ty} message: map one of its fields", show_path(path))),
            RosValue::List(items) => Err(format!(
                "`{}` is a list of {} elements: map one of them, such as `[0]`",
                show_path(path),
                items.len()
            )),
        }
    }

    fn as_i64(&self) -> i64 {
        match self {
            RosValue::Int(i) => *i,
            RosValue::UInt(u) => *u as i64,
            _ => 0,
        }
    }
}

fn is_time(ty: &str) -> bool {
    ty == "builtin_interfaces/msg/Time" || ty == "builtin_interfaces/msg/Duration"
}

/// Checks that `path` names one value of a `def` message — a number, a boolean, a string, a Time or Duration —
/// and returns it with the field names spelt as the definition spells them. An empty path names the message's
/// one field (`std_msgs/msg/Bool` has `data`). With `settable` (an output), no step is an element of a list.
pub fn resolve_path(
    lib: &Interfaces,
    def: &MsgDef,
    path: &[PathPart],
    settable: bool,
) -> Result<Vec<PathPart>, String> {
    let names = |d: &MsgDef| d.fields.iter().map(|f| f.name.as_str()).collect::<Vec<_>>().join(", ");
    let path: Vec<PathPart> = match (path.is_empty(), def.fields.as_slice()) {
        (false, _) => path.to_vec(),
        (true, [one]) => vec![PathPart::Field(one.name.clone())],
        (true, _) => {
            return Err(format!("a {} has fields {}: name one with `field := '…'`", def.name, names(def)));
        }
    };
    let mut out = Vec::with_capacity(path.len());
    let mut here = Arc::new(def.clone());
    let mut i = 0;
    while i < path.len() {
        let PathPart::Field(name) = &path[i] else {
            return Err(format!("`{}` is not a list", show_path(&path[..i])));
        };
        let field = here
            .fields
            .iter()
            .find(|f| f.name.eq_ignore_ascii_case(name))
            .cloned()
            .ok_or_else(|| format!("a {} has no field `{name}`: it has {}", here.name, names(&here)))?;
        out.push(PathPart::Field(field.name.clone()));
        i += 1;
        if field.shape != Shape::One {
            match path.get(i) {
                Some(PathPart::Index(n)) if !settable => {
                    if let Shape::Fixed(len) | Shape::Bounded(len) = field.shape {
                        if *n >= len {
                            return Err(format!("`{}` holds at most {len} elements", show_path(&out)));
                        }
                    }
                    out.push(PathPart::Index(*n));
                    i += 1;
                }
                Some(PathPart::Index(_)) => {
                    return Err(format!("`{}` is a list: an output sets a field, not an element", show_path(&out)))
                }
                _ => return Err(format!("`{}` is a list: name one of its elements, such as `[0]`", show_path(&out))),
            }
        }
        match &field.prim {
            Prim::Msg(name) if is_time(name) && i < path.len() => {
                return Err(format!("`{}` is a {name}: it is read whole, as a TIME", show_path(&out)));
            }
            Prim::Msg(name) if is_time(name) => {}
            Prim::Msg(name) => {
                here = lib
                    .msg(name)
                    .ok_or_else(|| format!("`{}` is a {name}, which the agent does not know", show_path(&out)))?;
                if i == path.len() {
                    return Err(format!(
                        "`{}` is a {name} message: name one of its fields ({})",
                        show_path(&out),
                        names(&here)
                    ));
                }
            }
            _ if i < path.len() => return Err(format!("`{}` has no fields", show_path(&out))),
            _ => {}
        }
    }
    Ok(out)
}

/// The structure literal that sets the value at `path` (fields only) to `value`, every other field at its
/// default.
pub fn literal_at(path: &[PathPart], value: Literal) -> Literal {
    path.iter().rev().fold(value, |inner, part| match part {
        PathPart::Field(f) => Literal::Struct(vec![(f.clone(), inner)]),
        PathPart::Index(_) => inner,
    })
}

/// Encodes a message of type `def` from `lit` (a structure literal; `None` for all defaults).
pub fn encode(lib: &Interfaces, def: &MsgDef, lit: Option<&Literal>) -> Result<Vec<u8>, String> {
    let mut buf = CDR_LE.to_vec();
    let mut w = CdrWriter::<LittleEndian>::new(&mut buf);
    write_msg(&mut w, lib, def, lit, "", 0)?;
    Ok(buf)
}

/// Encodes a message whose fields are given as values already (a goal id, a status): for the action protocol.
pub fn encode_with(lib: &Interfaces, def: &MsgDef, fields: Vec<(&str, Literal)>) -> Result<Vec<u8>, String> {
    let lit = Literal::Struct(fields.into_iter().map(|(n, l)| (n.to_string(), l)).collect());
    encode(lib, def, Some(&lit))
}

fn write_msg(
    w: &mut CdrWriter<LittleEndian>,
    lib: &Interfaces,
    def: &MsgDef,
    lit: Option<&Literal>,
    at: &str,
    depth: usize,
) -> Result<(), String> {
    if depth > DEPTH_MAX {
        return Err(format!("{} nests messages more than {DEPTH_MAX} deep", def.name));
    }
    let given = match lit {
        None => &[][..],
        Some(Literal::Struct(fields)) => &fields[..],
        Some(other) => {
            return Err(format!(
                "{} is a {} message: write it as (field := …, …), not {}",
                name_of(at),
                def.name,
                kind_of(other)
            ))
        }
    };
    for (name, _) in given {
        if !def.fields.iter().any(|f| f.name.eq_ignore_ascii_case(name)) {
            let names: Vec<&str> = def.fields.iter().map(|f| f.name.as_str()).collect();
            return Err(format!("{} has no field `{name}`: a {} has {}", name_of(at), def.name, names.join(", ")));
        }
    }
    if def.fields.is_empty() {
        // IDL has no empty structure: rosidl gives an empty message one byte.
        w.write_u8(0);
    }
    for field in &def.fields {
        let here = if at.is_empty() { field.name.clone() } else { format!("{at}.{}", field.name) };
        let value = given.iter().find(|(n, _)| n.eq_ignore_ascii_case(&field.name)).map(|(_, l)| l.clone());
        let value = value.or_else(|| field.default.as_ref().map(default_literal));
        write_field(w, lib, field, value.as_ref(), &here, depth)?;
    }
    Ok(())
}

fn write_field(
    w: &mut CdrWriter<LittleEndian>,
    lib: &Interfaces,
    field: &Field,
    lit: Option<&Literal>,
    at: &str,
    depth: usize,
) -> Result<(), String> {
    let items = || -> Result<&[Literal], String> {
        match lit {
            None => Ok(&[]),
            Some(Literal::Array(items)) => Ok(items),
            Some(other) => Err(format!("`{at}` is a list: write it as [a, b, …], not {}", kind_of(other))),
        }
    };
    match field.shape {
        Shape::One => write_prim(w, lib, &field.prim, lit, at, depth),
        Shape::Fixed(n) => {
            let items = items()?;
            if items.len() > n {
                return Err(format!("`{at}` holds exactly {n} elements, not {}", items.len()));
            }
            // Elements not given take their default, as in an IEC array's initial value.
            for i in 0..n {
                write_prim(w, lib, &field.prim, items.get(i), &format!("{at}[{i}]"), depth)?;
            }
            Ok(())
        }
        Shape::Bounded(_) | Shape::Unbounded => {
            let items = items()?;
            if let Shape::Bounded(n) = field.shape {
                if items.len() > n {
                    return Err(format!("`{at}` holds at most {n} elements, not {}", items.len()));
                }
            }
            w.write_sequence_length(items.len());
            for (i, item) in items.iter().enumerate() {
                write_prim(w, lib, &field.prim, Some(item), &format!("{at}[{i}]"), depth)?;
            }
            Ok(())
        }
    }
}

fn write_prim(
    w: &mut CdrWriter<LittleEndian>,
    lib: &Interfaces,
    prim: &Prim,
    lit: Option<&Literal>,
    at: &str,
    depth: usize,
) -> Result<(), String> {
    let int = |lo: i128, hi: i128, ty: &str| -> Result<i128, String> {
        match lit {
            None => Ok(0),
            Some(Literal::Scalar(Value::Int(i))) if (lo..=hi).contains(&(*i as i128)) => Ok(*i as i128),
            Some(Literal::Scalar(Value::Int(i))) => {
                Err(format!("`{at}` is a {ty}: {i} is out of its range {lo}..{hi}"))
            }
            Some(other) => Err(format!("`{at}` is a {ty}: write an integer, not {}", kind_of(other))),
        }
    };
    let float = |ty: &str| -> Result<f64, String> {
        match lit {
            None => Ok(0.0),
            Some(Literal::Scalar(Value::Int(i))) => Ok(*i as f64),
            Some(Literal::Scalar(Value::Real(r))) => Ok(*r),
            Some(other) => Err(format!("`{at}` is a {ty}: write a number, not {}", kind_of(other))),
        }
    };
    match prim {
        Prim::Bool => match lit {
            None => w.write_bool(false),
            Some(Literal::Scalar(Value::Bool(b))) => w.write_bool(*b),
            Some(other) => return Err(format!("`{at}` is a bool: write TRUE or FALSE, not {}", kind_of(other))),
        },
        Prim::U8 => w.write_u8(int(0, u8::MAX as i128, "uint8")? as u8),
        Prim::I8 => w.write_i8(int(i8::MIN as i128, i8::MAX as i128, "int8")? as i8),
        Prim::I16 => w.write_i16(int(i16::MIN as i128, i16::MAX as i128, "int16")? as i16),
        Prim::U16 => w.write_u16(int(0, u16::MAX as i128, "uint16")? as u16),
        Prim::I32 => w.write_i32(int(i32::MIN as i128, i32::MAX as i128, "int32")? as i32),
        Prim::U32 => w.write_u32(int(0, u32::MAX as i128, "uint32")? as u32),
        Prim::I64 => w.write_i64(int(i64::MIN as i128, i64::MAX as i128, "int64")? as i64),
        Prim::U64 => w.write_u64(int(0, u64::MAX as i128, "uint64")? as u64),
        Prim::F32 => w.write_f32(float("float32")? as f32),
        Prim::F64 => w.write_f64(float("float64")?),
        Prim::Str(bound) => match lit {
            None => w.write_string(""),
            Some(Literal::Text(s)) => {
                if let Some(n) = bound.filter(|n| s.chars().count() > *n) {
                    return Err(format!("`{at}` holds at most {n} characters"));
                }
                w.write_string(s)
            }
            Some(other) => return Err(format!("`{at}` is a string: write 'text', not {}", kind_of(other))),
        },
        Prim::Msg(name) => {
            // A TIME literal fills a Time or a Duration: T#1.5s is 1 s and 500,000,000 ns.
            if let (true, Some(Literal::Scalar(Value::Time(ms)))) = (is_time(name), lit) {
                w.write_i32(i32::try_from(ms.div_euclid(1000)).map_err(|_| format!("`{at}` is too long a time"))?);
                w.write_u32((ms.rem_euclid(1000) * 1_000_000) as u32);
                return Ok(());
            }
            let def =
                lib.msg(name).ok_or_else(|| format!("`{at}` is of type {name}, which the agent does not know"))?;
            write_msg(w, lib, &def, lit, at, depth + 1)?;
        }
    }
    Ok(())
}

fn default_literal(d: &DefaultValue) -> Literal {
    let list = |items: Vec<Literal>| Literal::Array(items);
    match d {
        DefaultValue::Bool(b) => Literal::Scalar(Value::Bool(*b)),
        DefaultValue::Int(i) => Literal::Scalar(Value::Int(*i)),
        DefaultValue::Float(f) => Literal::Scalar(Value::Real(*f)),
        DefaultValue::String(s) => Literal::Text(s.clone()),
        DefaultValue::BoolArray(v) => list(v.iter().map(|b| Literal::Scalar(Value::Bool(*b))).collect()),
        DefaultValue::IntArray(v) => list(v.iter().map(|i| Literal::Scalar(Value::Int(*i))).collect()),
        DefaultValue::FloatArray(v) => list(v.iter().map(|f| Literal::Scalar(Value::Real(*f))).collect()),
        DefaultValue::StringArray(v) => list(v.iter().map(|s| Literal::Text(s.clone())).collect()),
    }
}

fn name_of(at: &str) -> String {
    if at.is_empty() {
        "the message".to_string()
    } else {
        format!("`{at}`")
    }
}

fn kind_of(lit: &Literal) -> &'static str {
    match lit {
        Literal::Scalar(Value::Bool(_)) => "a boolean",
        Literal::Scalar(Value::Time(_)) => "a duration",
        Literal::Scalar(Value::Str(_)) | Literal::Text(_) => "a string",
        Literal::Scalar(_) => "a number",
        Literal::Struct(_) => "a structure",
        Literal::Array(_) => "a list",
    }
}

/// Decodes a message of type `def`.
pub fn decode(lib: &Interfaces, def: &MsgDef, bytes: &[u8]) -> Result<RosValue, String> {
    match bytes.get(..4) {
        Some(h) if h[..2] == CDR_LE[..2] => {}
        Some(h) if h[..2] == [0x00, 0x00] => {
            return Err("the answer is big-endian CDR, which Baton does not read".into())
        }
        _ => return Err("the answer is not CDR (no encapsulation header)".into()),
    }
    let mut r = CdrReader::<LittleEndian>::new(&bytes[4..]);
    let mut budget = ELEMENTS_MAX;
    read_msg(&mut r, lib, def, 0, &mut budget)
}

fn read_msg(
    r: &mut CdrReader<LittleEndian>,
    lib: &Interfaces,
    def: &MsgDef,
    depth: usize,
    budget: &mut usize,
) -> Result<RosValue, String> {
    if depth > DEPTH_MAX {
        return Err(format!("{} nests messages more than {DEPTH_MAX} deep", def.name));
    }
    if def.fields.is_empty() {
        r.read_u8().map_err(cut)?;
    }
    let mut fields = Vec::with_capacity(def.fields.len());
    for field in &def.fields {
        let value = match field.shape {
            Shape::One => read_prim(r, lib, &field.prim, depth, budget)?,
            Shape::Fixed(n) => read_list(r, lib, &field.prim, n, depth, budget)?,
            Shape::Bounded(_) | Shape::Unbounded => {
                let n = r.read_sequence_length().map_err(cut)?;
                // Every element takes at least a byte: a length past the end is a corrupt message.
                if n > r.remaining() {
                    return Err(format!("`{}` claims {n} elements in {} bytes", field.name, r.remaining()));
                }
                read_list(r, lib, &field.prim, n, depth, budget)?
            }
        };
        fields.push((field.name.clone(), value));
    }
    Ok(RosValue::Msg(def.name.clone(), fields))
}

fn read_list(
    r: &mut CdrReader<LittleEndian>,
    lib: &Interfaces,
    prim: &Prim,
    n: usize,
    depth: usize,
    budget: &mut usize,
) -> Result<RosValue, String> {
    if n > *budget {
        return Err(format!("the answer holds more than {ELEMENTS_MAX} elements"));
    }
    *budget -= n;
    let mut items = Vec::with_capacity(n);
    for _ in 0..n {
        items.push(read_prim(r, lib, prim, depth, budget)?);
    }
    Ok(RosValue::List(items))
}

fn read_prim(
    r: &mut CdrReader<LittleEndian>,
    lib: &Interfaces,
    prim: &Prim,
    depth: usize,
    budget: &mut usize,
) -> Result<RosValue, String> {
    Ok(match prim {
        Prim::Bool => RosValue::Bool(r.read_bool().map_err(cut)?),
        Prim::U8 => RosValue::UInt(r.read_u8().map_err(cut)? as u64),
        Prim::I8 => RosValue::Int(r.read_i8().map_err(cut)? as i64),
        Prim::I16 => RosValue::Int(r.read_i16().map_err(cut)? as i64),
        Prim::U16 => RosValue::UInt(r.read_u16().map_err(cut)? as u64),
        Prim::I32 => RosValue::Int(r.read_i32().map_err(cut)? as i64),
        Prim::U32 => RosValue::UInt(r.read_u32().map_err(cut)? as u64),
        Prim::I64 => RosValue::Int(r.read_i64().map_err(cut)?),
        Prim::U64 => RosValue::UInt(r.read_u64().map_err(cut)?),
        Prim::F32 => RosValue::Float(r.read_f32().map_err(cut)? as f64),
        Prim::F64 => RosValue::Float(r.read_f64().map_err(cut)?),
        Prim::Str(_) => RosValue::Str(r.read_string().map_err(cut)?),
        Prim::Msg(name) => {
            let def =
                lib.msg(name).ok_or_else(|| format!("the answer holds a {name}, which the agent does not know"))?;
            read_msg(r, lib, &def, depth + 1, budget)?
        }
    })
}

fn cut(e: hiroz_cdr::Error) -> String {
    format!("the answer does not match its type: {e}")
}

/// The fuzz target `cdr` (`fuzz/`): a message from a ROS 2 peer, of one of `FUZZ_TYPES` (the first byte picks),
/// decoded; it must never panic, and what decodes must read back whole at every path the type has.
pub fn fuzz_decode(lib: &Interfaces, data: &[u8]) {
    let Some((&pick, bytes)) = data.split_first() else { return };
    let name = FUZZ_TYPES[pick as usize % FUZZ_TYPES.len()];
    let Some(def) = lib.msg(name) else { panic!("{name} is not in the built-in library") };
    if let Ok(value) = decode(lib, &def, bytes) {
        for field in &def.fields {
            let path = [PathPart::Field(field.name.clone())];
            assert!(value.at(&path).is_some(), "{name} decoded without its field `{}`", field.name);
        }
    }
}

/// Message types the fuzzer decodes: strings, nested messages, fixed and bounded arrays, sequences of messages.
pub const FUZZ_TYPES: &[&str] = &[
    "std_msgs/msg/String",
    "std_msgs/msg/Header",
    "geometry_msgs/msg/PoseStamped",
    "geometry_msgs/msg/Twist",
    "sensor_msgs/msg/JointState",
    "sensor_msgs/msg/LaserScan",
    "nav_msgs/msg/Path",
    "trajectory_msgs/msg/JointTrajectory",
    "diagnostic_msgs/msg/DiagnosticArray",
    "action_msgs/msg/GoalStatusArray",
];

#[cfg(test)]
mod tests {
    use super::*;
    use crate::interfaces::Distro;
    use baton_proto::front::literal::parse;

    #[test]
    fn a_goal_round_trips_and_its_parts_come_out_as_chart_values() {
        let lib = Interfaces::load(Distro::Jazzy, &[]).unwrap();
        let pose = lib.msg("geometry_msgs/msg/PoseStamped").unwrap();
        let lit = parse("(header := (stamp := T#1.5s, frame_id := 'map'), pose := (position := (x := 1, y := 2.5)))")
            .unwrap();
        let bytes = encode(&lib, &pose, Some(&lit)).unwrap();
        let v = decode(&lib, &pose, &bytes).unwrap();
        let path = |p: &str| baton_proto::front::literal::parse_mapping(&format!("{p} => x")).unwrap().remove(0).0;
        assert_eq!(v.value_at(&path("pose.position.y")).unwrap(), Value::Real(2.5));
        assert_eq!(v.value_at(&path("pose.orientation.w")).unwrap(), Value::Real(1.0), "the .msg default");
        assert_eq!(v.value_at(&path("header.frame_id")).unwrap(), Value::string("map"));
        assert_eq!(v.value_at(&path("header.stamp")).unwrap(), Value::Time(1500));
        assert!(v.value_at(&path("pose")).unwrap_err().contains("map one of its fields"));
        assert!(v.value_at(&path("nope")).unwrap_err().contains("no `nope`"));
        let fib = lib.action("example_interfaces/action/Fibonacci").unwrap();
        let result = encode(&lib, &fib.result, Some(&parse("(sequence := [0, 1, 1, 2, 3, 5])").unwrap())).unwrap();
        // Header, u32 count, six i32.
        assert_eq!(result.len(), 4 + 4 + 6 * 4);
        let v = decode(&lib, &fib.result, &result).unwrap();
        assert_eq!(v.value_at(&path("sequence[5]")).unwrap(), Value::Int(5));
        assert!(v.value_at(&path("sequence")).unwrap_err().contains("list of 6"));
    }

    #[test]
    fn a_bound_field_is_checked_against_the_type_and_set_alone() {
        let lib = Interfaces::load(Distro::Jazzy, &[]).unwrap();
        let p = |t: &str| baton_proto::front::literal::parse_path(t).unwrap();
        let twist = lib.msg("geometry_msgs/msg/Twist").unwrap();
        assert_eq!(show_path(&resolve_path(&lib, &twist, &p("LINEAR.x"), true).unwrap()), "linear.x");
        assert!(resolve_path(&lib, &twist, &[], false).unwrap_err().contains("has fields linear, angular"));
        assert!(resolve_path(&lib, &twist, &p("linear"), false).unwrap_err().contains("name one of its fields"));
        assert!(resolve_path(&lib, &twist, &p("linear.w"), false).unwrap_err().contains("no field `w`"));
        assert!(resolve_path(&lib, &twist, &p("linear.x.y"), false).unwrap_err().contains("no fields"));
        let flag = lib.msg("std_msgs/msg/Bool").unwrap();
        assert_eq!(resolve_path(&lib, &flag, &[], false).unwrap(), vec![PathPart::Field("data".into())]);
        let header = lib.msg("std_msgs/msg/Header").unwrap();
        assert_eq!(show_path(&resolve_path(&lib, &header, &p("stamp"), false).unwrap()), "stamp");
        let array = lib.msg("std_msgs/msg/Float64MultiArray").unwrap();
        assert_eq!(show_path(&resolve_path(&lib, &array, &p("data[2]"), false).unwrap()), "data[2]");
        assert!(resolve_path(&lib, &array, &p("data"), false).unwrap_err().contains("name one of its elements"));
        assert!(resolve_path(&lib, &array, &p("data[2]"), true).unwrap_err().contains("not an element"));
        // An output sets its field, and every other field keeps its default.
        let lit = literal_at(&p("linear.x"), Literal::Scalar(Value::Real(0.25)));
        let v = decode(&lib, &twist, &encode(&lib, &twist, Some(&lit)).unwrap()).unwrap();
        assert_eq!(v.value_at(&p("linear.x")).unwrap(), Value::Real(0.25));
        assert_eq!(v.value_at(&p("angular.z")).unwrap(), Value::Real(0.0));
    }

    #[test]
    fn a_goal_that_does_not_fit_its_type_is_refused_by_name() {
        let lib = Interfaces::load(Distro::Jazzy, &[]).unwrap();
        let fib = lib.action("example_interfaces/action/Fibonacci").unwrap();
        let err = |text: &str| encode(&lib, &fib.goal, Some(&parse(text).unwrap())).unwrap_err();
        assert!(err("(ordre := 5)").contains("no field `ordre`: a example_interfaces/action/Fibonacci_Goal has order"));
        assert!(err("(order := 'five')").contains("`order` is a int32: write an integer"));
        assert!(err("(order := 5000000000)").contains("out of its range"));
        assert!(err("[5]").contains("write it as (field := …"));
    }

    #[test]
    fn corrupt_answers_are_errors_not_panics() {
        let lib = Interfaces::load(Distro::Jazzy, &[]).unwrap();
        let fib = lib.action("example_interfaces/action/Fibonacci").unwrap();
        assert!(decode(&lib, &fib.result, &[]).is_err());
        assert!(decode(&lib, &fib.result, &[0, 1, 0, 0, 0xff, 0xff, 0xff, 0x00]).unwrap_err().contains("claims"));
        assert!(decode(&lib, &fib.result, &[0, 1, 0, 0, 2, 0, 0, 0, 1]).is_err());
        let mut rng = 0x2545_f491_4f6c_dd1du64;
        for _ in 0..2000 {
            let len = (rng % 40) as usize;
            let mut bytes = vec![0u8, 1, 0, 0];
            for _ in 0..len {
                rng ^= rng << 13;
                rng ^= rng >> 7;
                rng ^= rng << 17;
                bytes.push(rng as u8);
            }
            let pose = lib.msg("geometry_msgs/msg/PoseStamped").unwrap();
            let _ = decode(&lib, &pose, &bytes);
        }
    }

    #[test]
    fn every_type_the_fuzzer_decodes_is_built_in_and_its_default_passes_the_target() {
        let lib = Interfaces::load(Distro::Jazzy, &[]).unwrap();
        for (i, name) in FUZZ_TYPES.iter().enumerate() {
            let def = lib.msg(name).unwrap_or_else(|| panic!("{name} is not built in"));
            let bytes = encode(&lib, &def, None).unwrap();
            assert!(decode(&lib, &def, &bytes).is_ok(), "{name}: its default does not decode");
            let mut input = vec![i as u8];
            input.extend(bytes);
            fuzz_decode(&lib, &input);
        }
    }
}
