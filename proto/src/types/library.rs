//! The catalogue of IEC 61131-3's standard library: which standard function blocks and functions exist, under
//! which names, and each block's members. The parser asks it whether a name is a block type; `compile` types
//! calls with it; `exec::stdlib` computes them.

use crate::types::{IntKind, Type};

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum StdFb {
    Ton,
    Tof,
    Tp,
    RTrig,
    FTrig,
    /// CTU and its typed variants (CTU_DINT, …): the counter's integer type.
    Ctu(IntKind),
    Ctd(IntKind),
    Ctud(IntKind),
    Sr,
    Rs,
}

/// What a member of a block is to its caller.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MemberKind {
    Input,
    Output,
    /// Internal state: not readable by name.
    State,
}

pub struct Member {
    pub name: &'static str,
    pub ty: Type,
    pub kind: MemberKind,
}

fn member(name: &'static str, ty: Type, kind: MemberKind) -> Member {
    Member { name, ty, kind }
}

const BOOL: Type = Type::Bool;
const TIME: Type = Type::Time;

impl StdFb {
    /// The block type with this (upper-case) name.
    pub fn from_name(upper: &str) -> Option<StdFb> {
        let counter = |suffix: &str| -> Option<IntKind> {
            Some(match suffix {
                "" | "_INT" => IntKind::Int,
                "_DINT" => IntKind::Dint,
                "_LINT" => IntKind::Lint,
                "_UDINT" => IntKind::Udint,
                "_ULINT" => IntKind::Ulint,
                _ => return None,
            })
        };
        Some(match upper {
            // IEC 61131-3 ed. 3 names the timers by their duration type too; LTIME is held in ms like TIME.
            "TON" | "TON_TIME" | "TON_LTIME" => StdFb::Ton,
            "TOF" | "TOF_TIME" | "TOF_LTIME" => StdFb::Tof,
            "TP" | "TP_TIME" | "TP_LTIME" => StdFb::Tp,
            "R_TRIG" => StdFb::RTrig,
            "F_TRIG" => StdFb::FTrig,
            "SR" => StdFb::Sr,
            "RS" => StdFb::Rs,
            _ => {
                if let Some(rest) = upper.strip_prefix("CTUD") {
                    StdFb::Ctud(counter(rest)?)
                } else if let Some(rest) = upper.strip_prefix("CTU") {
                    StdFb::Ctu(counter(rest)?)
                } else if let Some(rest) = upper.strip_prefix("CTD") {
                    StdFb::Ctd(counter(rest)?)
                } else {
                    return None;
                }
            }
        })
    }

    pub fn name(self) -> String {
        let counter = |base: &str, k: IntKind| match k {
            IntKind::Int => base.to_string(),
            k => format!("{base}_{}", Type::Int(k)),
        };
        match self {
            StdFb::Ton => "TON".into(),
            StdFb::Tof => "TOF".into(),
            StdFb::Tp => "TP".into(),
            StdFb::RTrig => "R_TRIG".into(),
            StdFb::FTrig => "F_TRIG".into(),
            StdFb::Ctu(k) => counter("CTU", k),
            StdFb::Ctd(k) => counter("CTD", k),
            StdFb::Ctud(k) => counter("CTUD", k),
            StdFb::Sr => "SR".into(),
            StdFb::Rs => "RS".into(),
        }
    }

    /// The members in variable order: inputs (in the order of a non-formal call), outputs, ENO, state.
    pub fn members(self) -> Vec<Member> {
        use MemberKind::*;
        let int = |k| Type::Int(k);
        match self {
            StdFb::Ton | StdFb::Tof | StdFb::Tp => vec![
                member("IN", BOOL, Input),
                member("PT", TIME, Input),
                member("Q", BOOL, Output),
                member("ET", TIME, Output),
                member("ENO", BOOL, Output),
                member("STATE", int(IntKind::Sint), State),
                member("PREV_IN", BOOL, State),
                member("START", TIME, State),
            ],
            StdFb::RTrig | StdFb::FTrig => vec![
                member("CLK", BOOL, Input),
                member("Q", BOOL, Output),
                member("ENO", BOOL, Output),
                member("M", BOOL, State),
            ],
            StdFb::Ctu(k) => vec![
                member("CU", BOOL, Input),
                member("R", BOOL, Input),
                member("PV", int(k), Input),
                member("Q", BOOL, Output),
                member("CV", int(k), Output),
                member("ENO", BOOL, Output),
                member("CU_M", BOOL, State),
            ],
            StdFb::Ctd(k) => vec![
                member("CD", BOOL, Input),
                member("LD", BOOL, Input),
                member("PV", int(k), Input),
                member("Q", BOOL, Output),
                member("CV", int(k), Output),
                member("ENO", BOOL, Output),
                member("CD_M", BOOL, State),
            ],
            StdFb::Ctud(k) => vec![
                member("CU", BOOL, Input),
                member("CD", BOOL, Input),
                member("R", BOOL, Input),
                member("LD", BOOL, Input),
                member("PV", int(k), Input),
                member("QU", BOOL, Output),
                member("QD", BOOL, Output),
                member("CV", int(k), Output),
                member("ENO", BOOL, Output),
                member("CU_M", BOOL, State),
                member("CD_M", BOOL, State),
            ],
            StdFb::Sr => vec![
                member("S1", BOOL, Input),
                member("R", BOOL, Input),
                member("Q1", BOOL, Output),
                member("ENO", BOOL, Output),
            ],
            StdFb::Rs => vec![
                member("S", BOOL, Input),
                member("R1", BOOL, Input),
                member("Q1", BOOL, Output),
                member("ENO", BOOL, Output),
            ],
        }
    }

    /// The index of ENO among the members.
    pub fn eno(self) -> u32 {
        match self {
            StdFb::Ton | StdFb::Tof | StdFb::Tp => 4,
            StdFb::RTrig | StdFb::FTrig => 2,
            StdFb::Ctu(_) | StdFb::Ctd(_) => 5,
            StdFb::Ctud(_) => 8,
            StdFb::Sr | StdFb::Rs => 3,
        }
    }

    /// How many variables an instance takes.
    pub fn size(self) -> u32 {
        match self {
            StdFb::Ton | StdFb::Tof | StdFb::Tp => 8,
            StdFb::RTrig | StdFb::FTrig | StdFb::Sr | StdFb::Rs => 4,
            StdFb::Ctu(_) | StdFb::Ctd(_) => 7,
            StdFb::Ctud(_) => 11,
        }
    }
}

/// An instance's members, read and written by index.
/// A standard function `compile` resolved; `ADD`, `GT` and their kin compile to operators instead.
#[derive(Clone, Debug, PartialEq)]
pub enum Func {
    Abs,
    /// SQRT, LN, LOG, EXP and the trigonometric functions: a REAL of a REAL.
    Real(RealFn),
    /// ATAN2(Y, X): the angle of the point (X, Y), in radians.
    Atan2,
    /// TRUNC, `TRUNC_<int>`, `<real>_TRUNC_<int>`: toward zero, to DINT or the named integer type.
    Trunc(IntKind),
    /// `BCD_TO_<int>`, `<bits>_BCD_TO_<int>`: the number a bit string writes in decimal, a digit a nibble, as the
    /// named type; 0 where a nibble is past 9 (matiec; CODESYS answers -1).
    BcdToInt(IntKind),
    /// `<int>_TO_BCD`, `<int>_TO_BCD_<bits>`: a number's decimal digits, a nibble each, as the named bit string,
    /// or for `<int>_TO_BCD` the one as wide as the integer (INT_TO_BCD gives a WORD), cut to its width.
    IntToBcd(IntKind),
    /// IS_VALID (a REAL neither NaN nor infinite) and IS_VALID_BCD (no nibble past 9).
    IsValid,
    IsValidBcd,
    /// TO_BIG_ENDIAN, FROM_BIG_ENDIAN (bytes swapped, as on the little-endian machines Baton runs on) and
    /// TO_LITTLE_ENDIAN, FROM_LITTLE_ENDIAN (unchanged), on integers and bit strings.
    SwapBytes,
    /// The date and time functions that are not operators: CONCAT_*, DAY_OF_WEEK, and the parts SPLIT_* writes.
    Date(DateFn),
    Expt,
    Sel,
    Max,
    Min,
    Limit,
    Mux,
    Move,
    Shl,
    Shr,
    Rol,
    Ror,
    /// `*_TO_*` and `TO_*`: the argument converted to this type.
    Convert(Type),
    /// `*_TO_STRING` and `TO_STRING`: the argument, of this type, as text (`compile` knows the type).
    ToString(Type),
    /// LEN, LEFT, RIGHT, MID, CONCAT, INSERT, DELETE, REPLACE, FIND.
    Text(TextFn),
    /// AND, OR, XOR and NOT on bit strings (the operators, on integer operands).
    BitAnd,
    BitOr,
    BitXor,
    BitNot,
}

impl Func {
    /// The function with this (upper-case) name, and the names of its parameters (`IN1`, `IN2`, … stand for the
    /// extensible ones).
    pub fn from_name(upper: &str) -> Option<(Func, &'static [&'static str])> {
        const IN: &[&str] = &["IN"];
        Some(match upper {
            "ABS" => (Func::Abs, IN),
            "SQRT" => (Func::Real(RealFn::Sqrt), IN),
            "LN" => (Func::Real(RealFn::Ln), IN),
            "LOG" => (Func::Real(RealFn::Log), IN),
            "EXP" => (Func::Real(RealFn::Exp), IN),
            "SIN" => (Func::Real(RealFn::Sin), IN),
            "COS" => (Func::Real(RealFn::Cos), IN),
            "TAN" => (Func::Real(RealFn::Tan), IN),
            "ASIN" => (Func::Real(RealFn::Asin), IN),
            "ACOS" => (Func::Real(RealFn::Acos), IN),
            "ATAN" => (Func::Real(RealFn::Atan), IN),
            "ATAN2" => (Func::Atan2, &["Y", "X"]),
            "TRUNC" => (Func::Trunc(IntKind::Dint), IN),
            "IS_VALID" => (Func::IsValid, IN),
            "IS_VALID_BCD" => (Func::IsValidBcd, IN),
            "TO_BIG_ENDIAN" | "FROM_BIG_ENDIAN" => (Func::SwapBytes, IN),
            "TO_LITTLE_ENDIAN" | "FROM_LITTLE_ENDIAN" => (Func::Move, IN),
            "CONCAT_DATE_TOD" | "CONCAT_DATE_LTOD" => (Func::Date(DateFn::ConcatDateTod), &["DATE", "TOD"]),
            "CONCAT_DATE" => (Func::Date(DateFn::ConcatDate), &["YEAR", "MONTH", "DAY"]),
            "CONCAT_TOD" | "CONCAT_LTOD" => {
                (Func::Date(DateFn::ConcatTod), &["HOUR", "MINUTE", "SECOND", "MILLISECOND"])
            }
            "CONCAT_DT" | "CONCAT_LDT" => {
                (Func::Date(DateFn::ConcatDt), &["YEAR", "MONTH", "DAY", "HOUR", "MINUTE", "SECOND", "MILLISECOND"])
            }
            "DAY_OF_WEEK" => (Func::Date(DateFn::DayOfWeek), IN),
            "MOVE" => (Func::Move, IN),
            "EXPT" => (Func::Expt, &["IN1", "IN2"]),
            "SEL" => (Func::Sel, &["G", "IN0", "IN1"]),
            "MAX" => (Func::Max, &["IN1", "IN2"]),
            "MIN" => (Func::Min, &["IN1", "IN2"]),
            "LIMIT" => (Func::Limit, &["MN", "IN", "MX"]),
            "MUX" => (Func::Mux, &["K", "IN0", "IN1"]),
            "SHL" => (Func::Shl, &["IN", "N"]),
            "SHR" => (Func::Shr, &["IN", "N"]),
            "ROL" => (Func::Rol, &["IN", "N"]),
            "ROR" => (Func::Ror, &["IN", "N"]),
            "LEN" => (Func::Text(TextFn::Len), IN),
            "LEFT" => (Func::Text(TextFn::Left), &["IN", "L"]),
            "RIGHT" => (Func::Text(TextFn::Right), &["IN", "L"]),
            "MID" => (Func::Text(TextFn::Mid), &["IN", "L", "P"]),
            "CONCAT" => (Func::Text(TextFn::Concat), &["IN1", "IN2"]),
            "INSERT" => (Func::Text(TextFn::Insert), &["IN1", "IN2", "P"]),
            "DELETE" => (Func::Text(TextFn::Delete), &["IN", "L", "P"]),
            "REPLACE" => (Func::Text(TextFn::Replace), &["IN1", "IN2", "L", "P"]),
            "FIND" => (Func::Text(TextFn::Find), &["IN1", "IN2"]),
            _ if upper.contains("BCD") => return Func::bcd(upper),
            _ if upper.contains("TRUNC_") => {
                // TRUNC_INT (CODESYS), REAL_TRUNC_INT (IEC 61131-3 ed. 3).
                let (from, to) = upper.split_once("TRUNC_")?;
                let from_real = matches!(from, "" | "REAL_" | "LREAL_");
                match Type::from_name(to) {
                    Some(Type::Int(k)) if from_real => (Func::Trunc(k), IN),
                    _ => return None,
                }
            }
            _ => {
                let to = match upper.split_once("_TO_") {
                    Some((from, to)) if Type::from_name(from).is_some() => to,
                    _ => upper.strip_prefix("TO_")?,
                };
                (Func::Convert(Type::from_name(to)?), IN)
            }
        })
    }

    /// The BCD conversions by name: `BCD_TO_INT`, `WORD_BCD_TO_UINT`, `INT_TO_BCD`, `UINT_TO_BCD_WORD` and their
    /// kin for every integer and bit string type.
    fn bcd(upper: &str) -> Option<(Func, &'static [&'static str])> {
        const IN: &[&str] = &["IN"];
        let int = |name: &str| match Type::from_name(name) {
            Some(Type::Int(k)) => Some(k),
            _ => None,
        };
        if let Some((from, to)) = upper.split_once("BCD_TO_") {
            let from_ok = from.is_empty() || from.strip_suffix('_').and_then(int).is_some();
            return from_ok.then_some((Func::BcdToInt(int(to)?), IN));
        }
        let (from, to) = upper.split_once("_TO_BCD")?;
        let from = int(from)?;
        let result = match to.strip_prefix('_') {
            Some(bits) => int(bits)?,
            None if to.is_empty() => match from.bits() {
                8 => IntKind::Byte,
                16 => IntKind::Word,
                32 => IntKind::Dword,
                _ => IntKind::Lword,
            },
            None => return None,
        };
        Some((Func::IntToBcd(result), IN))
    }

    /// Whether it takes any number of arguments past its declared ones.
    pub fn extensible(&self) -> bool {
        matches!(self, Func::Max | Func::Min | Func::Mux | Func::Text(TextFn::Concat))
    }
}

/// The date and time functions that are not operators (ADD_TOD_TIME and its kin compile to `+` and `-`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DateFn {
    /// CONCAT_DATE_TOD(DATE, TOD): the DATE_AND_TIME of that day at that time.
    ConcatDateTod,
    /// CONCAT_DATE(YEAR, MONTH, DAY), CONCAT_TOD(HOUR, MINUTE, SECOND, MILLISECOND), CONCAT_DT(all seven).
    ConcatDate,
    ConcatTod,
    ConcatDt,
    /// DAY_OF_WEEK(DATE): 0 for Sunday to 6 for Saturday (IEC 61131-3 ed. 3).
    DayOfWeek,
    /// One part of a DATE, TOD or DT, as SPLIT_DATE, SPLIT_TOD and SPLIT_DT write them.
    Part(DatePart),
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DatePart {
    Year,
    Month,
    Day,
    Hour,
    Minute,
    Second,
    Millisecond,
}

impl DatePart {
    /// The input type of SPLIT_DATE, SPLIT_TOD and SPLIT_DT, and their outputs, in order.
    pub fn of_split(upper: &str) -> Option<(Type, &'static [(&'static str, DatePart)])> {
        const DATE: &[(&str, DatePart)] =
            &[("YEAR", DatePart::Year), ("MONTH", DatePart::Month), ("DAY", DatePart::Day)];
        const TOD: &[(&str, DatePart)] = &[
            ("HOUR", DatePart::Hour),
            ("MINUTE", DatePart::Minute),
            ("SECOND", DatePart::Second),
            ("MILLISECOND", DatePart::Millisecond),
        ];
        const DT: &[(&str, DatePart)] = &[
            ("YEAR", DatePart::Year),
            ("MONTH", DatePart::Month),
            ("DAY", DatePart::Day),
            ("HOUR", DatePart::Hour),
            ("MINUTE", DatePart::Minute),
            ("SECOND", DatePart::Second),
            ("MILLISECOND", DatePart::Millisecond),
        ];
        Some(match upper {
            "SPLIT_DATE" | "SPLIT_LDATE" => (Type::Date, DATE),
            "SPLIT_TOD" | "SPLIT_LTOD" => (Type::Tod, TOD),
            "SPLIT_DT" | "SPLIT_LDT" => (Type::Dt, DT),
            _ => return None,
        })
    }
}

/// The standard's string functions. Positions count characters from 1; a length or a position outside the
/// string is clamped to it (LEFT('AB', 5) is 'AB', MID('AB', 2, 5) is ''), where the standard calls it an
/// error and leaves the result to the implementation.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TextFn {
    Len,
    Left,
    Right,
    Mid,
    Concat,
    Insert,
    Delete,
    Replace,
    Find,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RealFn {
    Sqrt,
    Ln,
    Log,
    Exp,
    Sin,
    Cos,
    Tan,
    Asin,
    Acos,
    Atan,
}

impl RealFn {
    /// The function's value; NaN and infinities are values, as on a PLC, never faults.
    pub fn apply(self, x: f64) -> f64 {
        match self {
            RealFn::Sqrt => x.sqrt(),
            RealFn::Ln => x.ln(),
            RealFn::Log => x.log10(),
            RealFn::Exp => x.exp(),
            RealFn::Sin => x.sin(),
            RealFn::Cos => x.cos(),
            RealFn::Tan => x.tan(),
            RealFn::Asin => x.asin(),
            RealFn::Acos => x.acos(),
            RealFn::Atan => x.atan(),
        }
    }
}
