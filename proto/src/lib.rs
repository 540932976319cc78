//! Baton's pure core: the SFC chart model, the textual SFC parser, the validator and the engine.
//!
//! Nothing here does I/O or reads a clock: time comes in as milliseconds, events go out as values.

pub mod analysis;
pub mod check;
pub mod compile;
pub mod diag;
pub mod engine;
pub mod eval;
pub mod journal;
pub mod keys;
pub mod layout;
pub mod lexer;
pub mod limits;
pub mod model;
pub mod netconfig;
pub mod parser;
pub mod pragma;
pub mod program;
pub mod runtime;
pub mod sim;
pub mod types;
pub mod wire;
