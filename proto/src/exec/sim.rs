//! Virtual-time simulation as `baton sim` runs it: a JSON Lines input script in, trace records out.
//!
//! The virtual-time loop and JSON formats of `baton sim`: the input script in, `TraceRecord`s out, with `value`
//! records for watched variables.

use std::sync::Arc;

use serde::Deserialize;

use crate::exec::engine::{Engine, Input};
use crate::exec::program::{Program, StepId, VarId};
use crate::exec::trace::{self, Output, TraceEvent, TraceRecord};
use crate::front::json_value;
use crate::types::Value;

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
            let value = json_value::parse(&var.ty, json)
                .ok_or_else(|| err(format!("`{}` is {}, and {json} is not a {} value", var.name, var.ty, var.ty)))?;
            set.push((id, value));
        }
        out.push(InputRecord { t_ms: parsed.t_ms, set });
    }
    Ok(out)
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
    sink: impl FnMut(Output),
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
    mut sink: impl FnMut(Output),
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
                    sink(Output::Fault { t_ms: now, message: e.to_string() });
                }
            }
        }
        if let Err(e) = engine.handle_cycle(now) {
            sink(Output::Fault { t_ms: now, message: e.to_string() });
        }
        drain(&mut engine, &mut sink);
        for (last, &var) in watched.iter_mut().zip(watch) {
            let value = engine.value(var);
            if last.as_ref() != Some(&value) {
                let mut record = TraceRecord::new(now, TraceEvent::Value, &program.vars[var.index()].name);
                record.value = Some(program.vars[var.index()].ty.show(&value));
                *last = Some(value);
                sink(Output::Trace(record));
            }
        }
        let Some(next) = now.checked_add(cycle_ms) else { break };
        now = next;
    }
    Ok(engine.active_steps().to_vec())
}

fn drain(engine: &mut Engine, sink: &mut impl FnMut(Output)) {
    while let Some(ev) = engine.poll_event() {
        sink(trace::of_event(engine.program(), ev));
    }
}
