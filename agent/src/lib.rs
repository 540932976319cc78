//! The Baton agent: runs the segments of a chart that a coordinator dispatches to it, with the same engine,
//! on its own clock, and hands the tokens back over Zenoh. Embed it in a robot program with your own skills:
//!
//! ```no_run
//! # async fn example() -> anyhow::Result<()> {
//! use baton_agent::{run, AgentConfig, Connections, Skills};
//! let config = AgentConfig {
//!     name: "robot1".into(),
//!     roles: vec!["picker".into()],
//!     connect: vec!["tcp/127.0.0.1:7447".into()],
//!     lease_ms: 10_000,
//!     verbose: false,
//!     zenoh_config: None,
//!     state_dir: None,
//! };
//! run(config, Skills::builtin(), Connections::default()).await
//! # }
//! ```
//!
//! # Where things are
//!
//! ARCHITECTURE.md's code map (`agent/`) is the one map of this crate; each module's documentation says what it
//! does.

pub mod connections;
pub mod host;
pub mod instances;
pub mod io;
pub mod opcua;
mod roles;
pub mod ros2;
pub mod scenario_skills;
pub mod skill;
mod terms;
pub mod trace;

pub use connections::Connections;
pub use host::{run, run_until, AgentConfig};
pub use skill::{Skill, SkillCall, SkillFuture, Skills};
