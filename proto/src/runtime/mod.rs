//! The pure halves of a distributed run: the coordinator's and the agent's state machines. The Zenoh shells in
//! `baton-coordinator` and `baton-agent` feed them decoded messages and the time, and carry out what they
//! output; a simulation can drive them just as well, in one thread.

pub mod agent;
pub mod coordinator;

/// The writer name the coordinator publishes its variables under.
pub const COORDINATOR: &str = "coordinator";

#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Level {
    Info,
    Warn,
    Error,
}
