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
//!
//! The standard library's behaviour — each standard block's members (their order is the instance's
//! variable layout) and one call of it (`run_fb`, time from `Env::now_ms`), and the standard functions' evaluation
//! helpers (conversions, shifts, integer powers, BCD, the date functions `DateFn`). Counters follow the runtimes users
//! come from (CTD and CTUD stop counting down at 0, CTU counts to its type's maximum; the doc's "Where runtimes
//! differ"). Standard and nothing else: no I/O.

use crate::exec::env::{EnvMut, Fault};
use crate::exec::program::VarId;
use crate::types::library::{DateFn, DatePart, Func, StdFb, TextFn};
use crate::types::{IntKind, Type, Value};

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
        StdFb::Ton | StdFb::Tof | StdFb::Tp => timer(fb, now, &mut m),
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
                // minimum): docs/book/src/standard-library.md, Counters.
                cv -= 1;
            }
            m.set_int(4, cv);
            m.set_bool(3, cv <= 0);
        }
        StdFb::Ctud(k) => up_down_counter(k, &mut m),
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

/// TON, TOF and TP, on their members as `types::library` lays them out (IN, PT, Q, ET, then the state kept).
fn timer<E: EnvMut>(fb: StdFb, now: i64, m: &mut Instance<'_, E>) {
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
    let run = |m: &mut Instance<'_, E>, q_done: bool| {
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
                    state = run(m, true);
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
                    state = run(m, false);
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
                state = run(m, false);
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

/// CTUD, on its members as `types::library` lays them out (the inputs, QU, QD, CV, then the previous CU and CD).
fn up_down_counter<E: EnvMut>(k: IntKind, m: &mut Instance<'_, E>) {
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

const DAY_MS: i64 = 86_400_000;

/// One date function of its arguments (typed by `compile`): a date or time that is not on the calendar
/// (month 13, 30 February, hour 24, a year outside 1 to 9999) is a fault, not a value made up.
pub fn date(f: DateFn, args: &[Value]) -> Result<Value, Fault> {
    use crate::types::{civil_from_days, days_from_civil};
    use Fault;
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
