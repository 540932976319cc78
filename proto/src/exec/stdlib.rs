//! IEC 61131-3's standard library as Baton executes it: the standard function blocks (their members and their
//! behaviour on each call) and the standard functions (their evaluation; `compile` types them).
//!
//! An instance of a standard function block is a run of consecutive variables, one per member (inputs,
//! outputs, ENO, then hidden state), so that its state lives in the engine's flat variable array like any other
//! value: a call reads and writes those variables, a transition reads `t1.Q` as a variable, and a distributed run
//! moves them like any other variable.
//!
//! Time inside a block is the cycle's time (`Env::now_ms`), so a timer's resolution is the cycle, and the same
//! chart gives the same values on one engine and on many. Where the standard is silent, matiec's library is the
//! reference, with one deliberate difference: a timer compares its elapsed time with PT in the same call in which
//! it starts, so TON with PT = T#0s sets Q in the call where IN rises (as CODESYS does; matiec sets it one call
//! later).

use crate::exec::eval::EnvMut;
use crate::exec::program::VarId;
use crate::exec::types::{IntKind, Type, Value};

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
struct Instance<'e, E> {
    base: u32,
    env: &'e mut E,
}

impl<E: EnvMut> Instance<'_, E> {
    fn get(&self, i: u32) -> Value {
        self.env.var(VarId(self.base + i))
    }
    fn bool(&self, i: u32) -> bool {
        self.get(i).as_bool()
    }
    fn int(&self, i: u32) -> i64 {
        self.get(i).as_i64()
    }
    fn set(&mut self, i: u32, v: Value) {
        self.env.set_var(VarId(self.base + i), v);
    }
    fn set_bool(&mut self, i: u32, b: bool) {
        self.set(i, Value::Bool(b));
    }
    fn set_int(&mut self, i: u32, v: i64) {
        self.set(i, Value::Int(v));
    }
    fn set_time(&mut self, i: u32, ms: i64) {
        self.set(i, Value::Time(ms));
    }
}

// Timer states (the STATE member), as in matiec.
const IDLE: i64 = 0;
const RUNNING: i64 = 1;
const DONE: i64 = 2;

/// Runs one call of the block whose members start at `base` (its inputs already assigned).
pub fn run_fb(fb: StdFb, base: VarId, env: &mut impl EnvMut) {
    let now = env.now_ms();
    let mut m = Instance { base: base.0, env };
    match fb {
        StdFb::Ton | StdFb::Tof | StdFb::Tp => {
            const IN: u32 = 0;
            const PT: u32 = 1;
            const Q: u32 = 2;
            const ET: u32 = 3;
            const STATE: u32 = 5;
            const PREV: u32 = 6;
            const START: u32 = 7;
            let input = m.bool(IN);
            let pt = m.int(PT).max(0);
            let prev = m.bool(PREV);
            let mut state = m.int(STATE);
            // A running timer: ET counts from START; once it reaches PT the timer is DONE, Q takes `q_done` and
            // ET stays at PT. (A TON's Q is FALSE while it runs, a TOF's and a TP's TRUE.)
            let run = |m: &mut Instance<'_, _>, q_done: bool| {
                let et = now - m.int(START);
                if et >= pt {
                    m.set_bool(Q, q_done);
                    m.set_time(ET, pt);
                    DONE
                } else {
                    m.set_time(ET, et);
                    RUNNING
                }
            };
            match fb {
                StdFb::Ton => {
                    if !input {
                        state = IDLE;
                        m.set_bool(Q, false);
                        m.set_time(ET, 0);
                    } else {
                        if !prev && state == IDLE {
                            state = RUNNING;
                            m.set_time(START, now);
                        }
                        if state == RUNNING {
                            state = run(&mut m, true);
                        }
                    }
                }
                StdFb::Tof => {
                    if input {
                        state = IDLE;
                        m.set_bool(Q, true);
                        m.set_time(ET, 0);
                    } else {
                        if prev && state == IDLE {
                            state = RUNNING;
                            m.set_time(START, now);
                        }
                        if state == RUNNING {
                            state = run(&mut m, false);
                        }
                    }
                }
                _ => {
                    if state == IDLE && input && !prev {
                        state = RUNNING;
                        m.set_bool(Q, true);
                        m.set_time(START, now);
                    }
                    if state == RUNNING {
                        state = run(&mut m, false);
                    }
                    if state == DONE && !input {
                        state = IDLE;
                        m.set_time(ET, 0);
                    }
                }
            }
            m.set_int(STATE, state);
            m.set_bool(PREV, input);
        }
        StdFb::RTrig => {
            let clk = m.bool(0);
            let q = clk && !m.bool(3);
            m.set_bool(1, q);
            m.set_bool(3, clk);
        }
        StdFb::FTrig => {
            // As the standard defines it: Q := NOT CLK AND NOT M; M := NOT CLK.
            let clk = m.bool(0);
            let q = !clk && !m.bool(3);
            m.set_bool(1, q);
            m.set_bool(3, !clk);
        }
        StdFb::Ctu(k) => {
            let cu = m.bool(0);
            let rising = cu && !m.bool(6);
            m.set_bool(6, cu);
            let mut cv = m.int(4);
            if m.bool(1) {
                cv = 0;
            } else if rising && cv < k.max_value() {
                cv += 1;
            }
            m.set_int(4, cv);
            let q = cv >= m.int(2);
            m.set_bool(3, q);
        }
        StdFb::Ctd(_) => {
            let cd = m.bool(0);
            let rising = cd && !m.bool(6);
            m.set_bool(6, cd);
            let mut cv = m.int(4);
            if m.bool(1) {
                cv = m.int(2);
            } else if rising && cv > 0 {
                // Stops at 0, as matiec, CODESYS and TwinCAT do (the standard's text counts down to the type's
                // minimum): docs/standard-library.md, Counters.
                cv -= 1;
            }
            m.set_int(4, cv);
            m.set_bool(3, cv <= 0);
        }
        StdFb::Ctud(k) => {
            let (cu, cd) = (m.bool(0), m.bool(1));
            let cu_rising = cu && !m.bool(9);
            let cd_rising = cd && !m.bool(10);
            m.set_bool(9, cu);
            m.set_bool(10, cd);
            let mut cv = m.int(7);
            if m.bool(2) {
                cv = 0;
            } else if m.bool(3) {
                cv = m.int(4);
            } else if !(cu_rising && cd_rising) {
                if cu_rising && cv < k.max_value() {
                    cv += 1;
                } else if cd_rising && cv > 0 {
                    cv -= 1;
                }
            }
            m.set_int(7, cv);
            let qu = cv >= m.int(4);
            m.set_bool(5, qu);
            m.set_bool(6, cv <= 0);
        }
        StdFb::Sr => {
            let q = m.bool(0) || (!m.bool(1) && m.bool(2));
            m.set_bool(2, q);
        }
        StdFb::Rs => {
            let q = !m.bool(1) && (m.bool(0) || m.bool(2));
            m.set_bool(2, q);
        }
    }
}

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

const DAY_MS: i64 = 86_400_000;

/// One date function of its arguments (typed by `compile`): a date or time that is not on the calendar
/// (month 13, 30 February, hour 24, a year outside 1 to 9999) is a fault, not a value made up.
pub fn date(f: DateFn, args: &[Value]) -> Result<Value, crate::exec::eval::Fault> {
    use crate::exec::eval::Fault;
    use crate::exec::types::{civil_from_days, days_from_civil};
    let n = |i: usize| args[i].as_i64();
    let day = |y: i64, m: i64, d: i64| -> Result<i64, Fault> {
        let valid = (1..=9999).contains(&y)
            && (1..=12).contains(&m)
            && d >= 1
            && civil_from_days(days_from_civil(y, m, d)) == (y, m, d);
        if valid {
            Ok(days_from_civil(y, m, d) * DAY_MS)
        } else {
            Err(Fault::NoSuchDate)
        }
    };
    let time = |h: i64, m: i64, s: i64, ms: i64| -> Result<i64, Fault> {
        let valid = (0..24).contains(&h) && (0..60).contains(&m) && (0..60).contains(&s) && (0..1000).contains(&ms);
        if valid {
            Ok(((h * 60 + m) * 60 + s) * 1000 + ms)
        } else {
            Err(Fault::NoSuchDate)
        }
    };
    Ok(Value::Time(match f {
        DateFn::ConcatDateTod => n(0).wrapping_add(n(1)),
        DateFn::ConcatDate => day(n(0), n(1), n(2))?,
        DateFn::ConcatTod => time(n(0), n(1), n(2), n(3))?,
        DateFn::ConcatDt => day(n(0), n(1), n(2))? + time(n(3), n(4), n(5), n(6))?,
        // 1970-01-01 was a Thursday (4).
        DateFn::DayOfWeek => return Ok(Value::Int((n(0).div_euclid(DAY_MS) + 4).rem_euclid(7))),
        DateFn::Part(part) => {
            let v = n(0);
            let (y, m, d) = civil_from_days(v.div_euclid(DAY_MS));
            let ms = v.rem_euclid(DAY_MS);
            return Ok(Value::Int(match part {
                DatePart::Year => y,
                DatePart::Month => m,
                DatePart::Day => d,
                DatePart::Hour => ms / 3_600_000,
                DatePart::Minute => ms / 60_000 % 60,
                DatePart::Second => ms / 1000 % 60,
                DatePart::Millisecond => ms % 1000,
            }));
        }
    }))
}

/// The number a bit string writes in BCD, `None` where a nibble is past 9.
pub fn bcd_to_int(v: i64) -> Option<i64> {
    let (mut bits, mut out, mut factor) = (v as u64, 0i64, 1i64);
    while bits != 0 {
        let digit = (bits & 0xf) as i64;
        if digit > 9 {
            return None;
        }
        out = out.wrapping_add(digit.wrapping_mul(factor));
        factor = factor.wrapping_mul(10);
        bits >>= 4;
    }
    Some(out)
}

/// A number's decimal digits, one per nibble (as an unsigned number, as matiec converts it).
pub fn int_to_bcd(v: i64) -> i64 {
    let (mut n, mut out, mut shift) = (v as u64, 0u64, 0u32);
    while n != 0 && shift < 64 {
        out |= (n % 10) << shift;
        n /= 10;
        shift += 4;
    }
    out as i64
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

/// One string function of its arguments, which `compile` typed (strings, and integers for lengths and
/// positions).
pub fn text(f: TextFn, args: &[Value]) -> Value {
    let chars = |i: usize| -> Vec<char> { args[i].as_str().chars().collect() };
    // A count or a position (from 1) as an index into `len` characters.
    let clamp = |v: &Value, len: usize| v.as_i64().clamp(0, len as i64) as usize;
    let string = |c: &[char]| Value::string(c.iter().collect::<String>());
    match f {
        TextFn::Len => Value::Int(args[0].as_str().chars().count() as i64),
        TextFn::Left => {
            let c = chars(0);
            string(&c[..clamp(&args[1], c.len())])
        }
        TextFn::Right => {
            let c = chars(0);
            string(&c[c.len() - clamp(&args[1], c.len())..])
        }
        TextFn::Mid => {
            let c = chars(0);
            let p = args[2].as_i64();
            if p < 1 || p as usize > c.len() {
                return Value::string("");
            }
            let start = p as usize - 1;
            string(&c[start..start + clamp(&args[1], c.len() - start)])
        }
        TextFn::Concat => Value::string(args.iter().map(Value::as_str).collect::<String>()),
        TextFn::Insert => {
            let c = chars(0);
            let at = clamp(&args[2], c.len());
            let mut out: String = c[..at].iter().collect();
            out.push_str(args[1].as_str());
            out.extend(&c[at..]);
            Value::string(out)
        }
        TextFn::Delete | TextFn::Replace => {
            let (l, p, with) = if f == TextFn::Delete { (1, 2, "") } else { (2, 3, args[1].as_str()) };
            let c = chars(0);
            let p = args[p].as_i64();
            if p < 1 || p as usize > c.len() {
                return args[0].clone();
            }
            let start = p as usize - 1;
            let end = start + clamp(&args[l], c.len() - start);
            let mut out: String = c[..start].iter().collect();
            out.push_str(with);
            out.extend(&c[end..]);
            Value::string(out)
        }
        TextFn::Find => {
            let (hay, needle) = (args[0].as_str(), args[1].as_str());
            let at = if needle.is_empty() { None } else { hay.find(needle) };
            Value::Int(at.map_or(0, |b| hay[..b].chars().count() as i64 + 1))
        }
    }
}

/// A value of type `from` as `*_TO_STRING` writes it: TRUE/FALSE, decimal numbers, durations as `T#1s500ms`,
/// dates and times as their literals.
pub fn to_string(from: &Type, v: &Value) -> String {
    match (from, v) {
        (Type::Real { long: false }, &Value::Real(r)) => (r as f32).to_string(),
        (Type::Time, &Value::Time(ms)) => show_duration(ms),
        (Type::Str { .. }, Value::Str(s)) => s.to_string(),
        (from, v) => from.show(v),
    }
}

/// `T#1d2h3m4s5ms`, the largest units first, zero units left out (`T#0s` for zero).
pub fn show_duration(ms: i64) -> String {
    let mut out = String::from(if ms < 0 { "T#-" } else { "T#" });
    let mut rest = ms.unsigned_abs();
    if rest == 0 {
        out.push_str("0s");
    }
    for (unit, size) in [("d", 86_400_000u64), ("h", 3_600_000), ("m", 60_000), ("s", 1000), ("ms", 1)] {
        if rest >= size {
            out.push_str(&format!("{}{unit}", rest / size));
            rest %= size;
        }
    }
    out
}

/// `STRING_TO_*`: the literal a string holds (blanks around it ignored) as a value of `to`; the type's default
/// when it holds none, as PLCs answer.
fn parse_text(s: &str, to: &Type) -> Value {
    use crate::front::lexer::{lex, Kw, Tok};
    let lexed = lex(s.trim());
    let toks: Vec<Tok> = lexed.tokens.iter().map(|t| t.tok).collect();
    let (negative, tok) = match toks[..] {
        [Tok::Minus, t, Tok::Eof] => (true, t),
        [t, Tok::Eof] => (false, t),
        _ => return to.default_value(),
    };
    let value = match (to, tok) {
        (Type::Bool, Tok::Kw(Kw::True)) | (Type::Bool, Tok::Int(1)) => Value::Bool(true),
        (Type::Bool, Tok::Kw(Kw::False)) | (Type::Bool, Tok::Int(0)) => Value::Bool(false),
        (Type::Int(k), Tok::Int(i)) => Value::Int(k.wrap(if negative { i.wrapping_neg() } else { i })),
        (Type::Real { .. }, Tok::Int(i)) => to.coerce(Value::Real(if negative { -i as f64 } else { i as f64 })),
        (Type::Real { .. }, Tok::Real(r)) => to.coerce(Value::Real(if negative { -r } else { r })),
        (Type::Time, Tok::Time(ms)) => Value::Time(if negative { -ms } else { ms }),
        (Type::Date, Tok::Date(ms)) | (Type::Tod, Tok::Tod(ms)) | (Type::Dt, Tok::Dt(ms)) if !negative => {
            Value::Time(ms)
        }
        _ => return to.default_value(),
    };
    if negative && matches!(to, Type::Bool) {
        return to.default_value();
    }
    value
}

/// A value converted to a type, as the `*_TO_*` functions do: REAL to an integer rounds to the nearest (half
/// away from zero), integers wrap to the target's width, TIME converts to and from milliseconds, a number is
/// TRUE when it is not zero.
pub fn convert(v: Value, to: &Type) -> Value {
    // Text is read as a literal of the target type; text to text stays as it is (cut to the target's length).
    match (&v, to) {
        (Value::Str(_), Type::Str { .. }) => return to.coerce(v),
        (Value::Str(s), _) => return parse_text(s, to),
        _ => {}
    }
    match to {
        Type::Bool => Value::Bool(match v {
            Value::Bool(b) => b,
            Value::Real(r) => r != 0.0,
            other => other.as_i64() != 0,
        }),
        Type::Int(k) => Value::Int(k.wrap(match v {
            Value::Real(r) => r.round() as i64,
            other => other.as_i64(),
        })),
        Type::Real { .. } => to.coerce(Value::Real(v.as_f64())),
        Type::Time | Type::Dt => Value::Time(match v {
            Value::Real(r) => r.round() as i64,
            other => other.as_i64(),
        }),
        // DT_TO_TOD keeps the time of day, DT_TO_DATE the day.
        Type::Tod => Value::Time(v.as_i64().rem_euclid(86_400_000)),
        Type::Date => Value::Time(v.as_i64() - v.as_i64().rem_euclid(86_400_000)),
        Type::Str { .. } => Value::string(v.to_string()),
        Type::Enum(_) | Type::Unsupported(_) => v,
    }
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

/// `a ** b` on integers: the power wrapped to the type (`wrap`), 0 for a negative exponent of a base other than
/// ±1 (the integer part of the real result).
pub fn int_pow(a: i64, b: i64, wrap: Option<IntKind>) -> i64 {
    let v = if b < 0 {
        match a {
            1 => 1,
            -1 if b % 2 == 0 => 1,
            -1 => -1,
            _ => 0,
        }
    } else {
        let mut result: i64 = 1;
        let mut base = a;
        let mut e = b as u64;
        while e > 0 {
            if e & 1 == 1 {
                result = result.wrapping_mul(base);
            }
            base = base.wrapping_mul(base);
            e >>= 1;
        }
        result
    };
    wrap.map_or(v, |k| k.wrap(v))
}

/// SHL, SHR, ROL and ROR on a bit string of the kind's width.
pub fn shift(f: &Func, v: i64, n: i64, kind: IntKind) -> i64 {
    let bits = kind.bits() as u64;
    let mask: u64 = if bits == 64 { u64::MAX } else { (1u64 << bits) - 1 };
    let x = (v as u64) & mask;
    let n = n.max(0) as u64;
    let out = match f {
        Func::Shl if n >= bits => 0,
        Func::Shl => (x << n) & mask,
        Func::Shr if n >= bits => 0,
        Func::Shr => x >> n,
        Func::Rol | Func::Ror => {
            let n = n % bits;
            if n == 0 {
                x
            } else if matches!(f, Func::Rol) {
                ((x << n) | (x >> (bits - n))) & mask
            } else {
                ((x >> n) | (x << (bits - n))) & mask
            }
        }
        _ => x,
    };
    kind.wrap(out as i64)
}
