//! Baton's pure core: the SFC chart model, the textual SFC and PLCopen XML front ends, the validator, the
//! engine, and the state machines of a distributed run.
//!
//! Nothing here does I/O or reads a clock: time comes in as milliseconds, events go out as values. The crate is
//! grouped by layer: `types`, `front` (source text to checked chart), `exec` (compiled program and engine), `back`
//! (a chart written out), `cluster` (placement, wire protocol, journal and the runtimes' state machines) and
//! `testing` (the simulated cluster, `baton test`'s scenarios, the fuzz targets' bodies), with `limits` under all.
//! ARCHITECTURE.md's code map is the one map of the crate.

/// Above the layers it calls: parse, compile, analyse and lay out every chart of a source text (`check_source`).
pub mod pipeline;

pub mod limits;
pub mod testing;

/// What every layer shares: IEC 61131-3's elementary types and values, and the catalogue of the standard
/// library (which functions and blocks exist, and under which names).
pub mod types;

/// From source text to the chart model: lexer, parsers (textual and PLCopen XML), pragmas and diagnostics.
pub mod front {
    pub mod diag;
    pub mod json_value;
    pub mod lexer;
    pub mod literal;
    pub mod model;
    pub mod parser;
    pub mod plcopen;
    pub mod pragma;
    pub mod source;
}

/// Back ends: a checked chart written out in other formats (Structured Text, PLCopen TC6 XML).
pub mod back {
    pub mod diagram;
    pub mod plcopen;
    pub mod st;
    pub mod svg;
}

/// Execution: the compiled program, values and types, evaluation, the engine, the net analysis and `sim`.
pub mod exec {
    pub mod analysis;
    pub mod compile;
    pub mod engine;
    pub mod env;
    pub mod eval;
    pub mod program;
    pub mod sim;
    pub mod stdlib;
    pub mod trace;
    pub mod why;
}

/// The distributed part: where each part of a chart runs, the wire protocol and key space, the journal, the
/// Zenoh settings, and the coordinator's and agent's state machines (the simulated cluster that runs them on
/// virtual time is `testing`'s).
pub mod cluster {
    pub mod bindings;
    pub mod journal;
    pub mod keys;
    pub mod layout;
    pub mod netconfig;
    pub mod runtime;
    pub mod skills;
    pub mod wire;
}
