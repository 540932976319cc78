//! Virtual-time simulation as `baton sim` runs it: a JSON Lines input script in, trace records out.
//!
//! The virtual-time loop and JSON formats of `baton sim`: the input script in, `TraceRecord`s out, with `value`
//! records for watched variables.

use std::sync::Arc;

use serde::Deserialize;

use crate::exec::engine::{Engine, Event, EventKind, FaultSource, Input};
use crate::exec::eval::Fault;
use crate::exec::program::{Program, StepId, VarId};
use crate::exec::trace::{TraceEvent, TraceRecord};
use crate::front::lexer::{lex, Tok};
use crate::types::{Type, Value};

/// One line of an input script: `{"t_ms": 100, "set": {"start": true, "level": 42}}`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct InputLine {
    t_ms: u64,
    set: serde_json::Map<String, serde_json::Value>,
}

/// A resolved input: at `t_ms`, set these variables, in this order.
#[derive(Clone, Debug, PartialEq)]
pub struct InputRecord {
    pub t_ms: u64,
    pub set: Vec<(VarId, Value)>,
}

#[derive(Debug, thiserror::Error, PartialEq)]
#[error("line {line}: {message}")]
pub struct InputsError {
    pub line: usize,
    pub message: String,
}

/// Parses and resolves an input script against a program; every problem names its line.
pub fn parse_inputs(text: &str, program: &Program) -> Result<Vec<InputRecord>, InputsError> {
    let mut out = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let line = i + 1;
        if raw.trim().is_empty() {
            continue;
        }
        let err = |message: String| InputsError { line, message };
        let parsed: InputLine = serde_json::from_str(raw).map_err(|e| {
            err(format!("{e}; expected a record such as {{\"t_ms\": 100, \"set\": {{\"start\": true}}}}"))
        })?;
        let mut set = Vec::with_capacity(parsed.set.len());
        for (name, json) in &parsed.set {
            let id = program.var_by_name(name).ok_or_else(|| err(format!("unknown variable `{name}`")))?;
            let var = &program.vars[id.index()];
            if var.constant {
                return Err(err(format!("`{}` is a CONSTANT and cannot be set", var.name)));
            }
            let value = parse_value(&var.ty, json)
                .ok_or_else(|| err(format!("`{}` is {}, and {json} is not a {} value", var.name, var.ty, var.ty)))?;
            set.push((id, value));
        }
        out.push(InputRecord { t_ms: parsed.t_ms, set });
    }
    Ok(out)
}

/// A JSON value as a value of type `ty`: a boolean, an integer in range, a number, a duration as milliseconds or
/// a `T#…` literal, an enumeration value by name, or a string that fits the variable's length.
pub fn parse_value(ty: &Type, json: &serde_json::Value) -> Option<Value> {
    match ty {
        Type::Bool => json.as_bool().map(Value::Bool),
        Type::Int(k) => json.as_i64().filter(|v| k.contains(*v)).map(Value::Int),
        Type::Real { .. } => json.as_f64().map(|r| ty.coerce(Value::Real(r))),
        Type::Time | Type::Date | Type::Tod | Type::Dt => match json {
            serde_json::Value::String(s) => match lex(s).tokens[..] {
                [t, e] if e.tok == Tok::Eof => match (ty, t.tok) {
                    (Type::Time, Tok::Time(ms))
                    | (Type::Date, Tok::Date(ms))
                    | (Type::Tod, Tok::Tod(ms))
                    | (Type::Dt, Tok::Dt(ms)) => Some(Value::Time(ms)),
                    _ => None,
                },
                _ => None,
            },
            other => other.as_i64().map(Value::Time),
        },
        Type::Enum(e) => match json {
            serde_json::Value::String(s) => {
                let name = s.rsplit('#').next().unwrap_or(s);
                e.values.iter().position(|v| v.eq_ignore_ascii_case(name)).map(|i| Value::Int(i as i64))
            }
            other => other.as_i64().filter(|&i| i >= 0 && (i as usize) < e.values.len()).map(Value::Int),
        },
        // Text as it is, or as an ST literal (`'go'`, as value records show it); a number as its digits.
        Type::Str { .. } => {
            let text = match json {
                serde_json::Value::String(s) if s.len() >= 2 && s.starts_with('\'') && s.ends_with('\'') => {
                    crate::types::unquote_string(&s[1..s.len() - 1]).unwrap_or_else(|_| s.clone())
                }
                serde_json::Value::String(s) => s.clone(),
                serde_json::Value::Number(n) => n.to_string(),
                _ => return None,
            };
            Some(Value::string(text)).filter(|v| ty.fits(v))
        }
        Type::Unsupported(_) => None,
    }
}

/// Something the simulation reports: a trace record, or a run-time fault (which `baton sim` prints apart).
#[derive(Clone, Debug, PartialEq)]
pub enum SimOutput {
    Trace(TraceRecord),
    Fault { t_ms: u64, message: String },
}

#[derive(Debug, thiserror::Error, PartialEq)]
pub enum SimError {
    #[error("the cycle time must be at least 1 ms")]
    ZeroCycle,
}

/// Runs cycles at t = 0, cycle_ms, 2·cycle_ms, … up to and including `until_ms`. Before each cycle, every input
/// whose time has come is applied, in file order.
pub fn simulate(
    program: Arc<Program>,
    inputs: &[InputRecord],
    cycle_ms: u64,
    until_ms: u64,
    sink: impl FnMut(SimOutput),
) -> Result<(), SimError> {
    simulate_watching(program, inputs, cycle_ms, until_ms, &[], sink).map(|_| ())
}

/// `simulate`, with a `value` record after the first cycle for each watched variable, and after every cycle that
/// changed it; the steps active at the end.
pub fn simulate_watching(
    program: Arc<Program>,
    inputs: &[InputRecord],
    cycle_ms: u64,
    until_ms: u64,
    watch: &[VarId],
    mut sink: impl FnMut(SimOutput),
) -> Result<Vec<StepId>, SimError> {
    if cycle_ms == 0 {
        return Err(SimError::ZeroCycle);
    }
    let mut order: Vec<usize> = (0..inputs.len()).collect();
    order.sort_by_key(|&i| (inputs[i].t_ms, i));
    let mut next_input = 0;
    let mut batch = Vec::new();
    let mut engine = Engine::new(Arc::clone(&program));
    drain(&mut engine, &mut sink);
    let mut watched: Vec<Option<Value>> = vec![None; watch.len()];
    let mut now = 0u64;
    while now <= until_ms {
        batch.clear();
        while next_input < order.len() && inputs[order[next_input]].t_ms <= now {
            batch.push(order[next_input]);
            next_input += 1;
        }
        batch.sort_unstable();
        for &i in &batch {
            for (var, value) in &inputs[i].set {
                // Values were checked against the program when the script was parsed.
                if let Err(e) = engine.handle(Input::Set(*var, value.clone())) {
                    sink(SimOutput::Fault { t_ms: now, message: e.to_string() });
                }
            }
        }
        if let Err(e) = engine.handle_cycle(now) {
            sink(SimOutput::Fault { t_ms: now, message: e.to_string() });
        }
        drain(&mut engine, &mut sink);
        for (last, &var) in watched.iter_mut().zip(watch) {
            let value = engine.value(var);
            if last.as_ref() != Some(&value) {
                let mut record = TraceRecord::new(now, TraceEvent::Value, &program.vars[var.index()].name);
                record.value = Some(program.vars[var.index()].ty.show(&value));
                *last = Some(value);
                sink(SimOutput::Trace(record));
            }
        }
        let Some(next) = now.checked_add(cycle_ms) else { break };
        now = next;
    }
    Ok(engine.active_steps().to_vec())
}

fn drain(engine: &mut Engine, sink: &mut impl FnMut(SimOutput)) {
    while let Some(ev) = engine.poll_event() {
        sink(output_of(engine.program(), ev));
    }
}

/// An engine event as a trace record (or, for a fault, a message), with the program's names.
pub fn output_of(program: &Program, ev: Event) -> SimOutput {
    let (event, name) = match ev.kind {
        EventKind::Activate(s) => (TraceEvent::Activate, &program.steps[s.index()].name),
        EventKind::Deactivate(s) => (TraceEvent::Deactivate, &program.steps[s.index()].name),
        EventKind::Fire(t) => (TraceEvent::Fire, &program.transitions[t.index()].name),
        EventKind::ActionOn(a) => (TraceEvent::ActionOn, &program.actions[a.index()].name),
        EventKind::ActionOff(a) => (TraceEvent::ActionOff, &program.actions[a.index()].name),
        EventKind::Fault(source, fault) => {
            return SimOutput::Fault { t_ms: ev.t_ms, message: fault_message(program, source, fault) }
        }
        EventKind::Overrun(s) => {
            let mut rec = TraceRecord::new(ev.t_ms, TraceEvent::Alarm, &program.steps[s.index()].name);
            rec.message = Some(overrun_message(program, s));
            return SimOutput::Trace(rec);
        }
    };
    SimOutput::Trace(TraceRecord::new(ev.t_ms, event, name))
}

/// What a step's supervision alarm says.
pub fn overrun_message(program: &Program, s: crate::exec::program::StepId) -> String {
    let step = &program.steps[s.index()];
    format!("step `{}` has been active longer than its maximum time of {} ms", step.name, step.max_ms)
}

pub fn fault_message(program: &Program, source: FaultSource, fault: Fault) -> String {
    let what = match fault {
        Fault::DivisionByZero => "division by zero",
        Fault::MuxSelector => "a MUX selector past its inputs",
        Fault::IndexOutOfRange => "an array index outside its bounds",
        Fault::NoSuchDate => "a date or time of day that is not on the calendar (CONCAT_DATE, CONCAT_TOD, CONCAT_DT)",
        Fault::LoopLimit => {
            let FaultSource::Action(a) = source else { return "a loop past its limit".to_string() };
            return format!(
                "a loop in action `{}` ran more than {} iterations in one cycle: the rest of its body was skipped",
                program.actions[a.index()].name,
                crate::limits::LOOP_ITERATIONS_MAX
            );
        }
        Fault::CallLimit => {
            let FaultSource::Action(a) = source else { return "calls past their limit".to_string() };
            return format!(
                "action `{}` ran more than {} loop passes and calls of blocks and functions in one cycle: the rest \
                 of its body was skipped",
                program.actions[a.index()].name,
                crate::limits::LOOP_ITERATIONS_MAX
            );
        }
        Fault::SecondToken(s) => {
            let FaultSource::Transition(t) = source else { return "a second token".to_string() };
            return format!(
                "transition `{}` gave step `{}` a second token while it held one (the chart is not safe): the tokens merged",
                program.transitions[t.index()].name,
                program.steps[s.index()].name
            );
        }
    };
    match source {
        FaultSource::Transition(t) => {
            format!("{what} in the condition of transition `{}` (taken as FALSE)", program.transitions[t.index()].name)
        }
        FaultSource::Action(a) => {
            format!("{what} in action `{}` (the rest of its body was skipped)", program.actions[a.index()].name)
        }
    }
}
