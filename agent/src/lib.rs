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
//! };
//! run(config, Skills::builtin(), Connections::default()).await
//! # }
//! ```
//!
//! # Where things are
//!
//! `many.rs` (`run_many`: several agents in one process, each its own session, for benchmarks and tests — `baton-agent
//! --instances N`); `scenario_skills.rs` (`--simulate SCENARIO`: every skill the scenario's chart binds does what the scenario says,
//! with `testing::run::skill_model`, in real time); `roles.rs` (whether the router took the role tokens the agent
//! announces: a role its identity may not serve is refused); `shell.rs`, the agent's Zenoh shell (refusal of a taken
//! name, liveliness token, info queryable, commands on its own process's key, chart fetch, one `AgentRun` per run, a timer at
//! the runs' `poll_timeout`, skill tasks (`drive_skill`: a skill's writes pass on in order before its end; a skill is
//! dropped when its action ends, or told to stop and awaited when it `stops_itself`), the watch on the router for the
//! lease fence; `ToAgent::Join`, which makes an agent with bound variables take part in a run before any token, and
//! answers its device report again); `io/`, the agent's end of bindings: `mod.rs` (`Devices`, one task per connection
//! of a run, dropped with it; `Sink`, where the tasks put input values and device states, the latest per binding,
//! waking the shell once for what piled up; `Latest`, the outputs' mailbox, a newer value replacing one not sent),
//! `zenoh_keys.rs` (Zenoh: a subscriber, a publisher, payload text to values and back), `topics.rs` (a ROS 2 topic's
//! field: a subscription whose reachability is the graph's publishers of its type; a publication with the field set,
//! again every `period_ms`), `nodes.rs` (OPC UA: one session per server for all its nodes, monitored items in, writes
//! converted to the node's DataType out, reconnecting with backoff and writing the outputs again); `skill/`, the
//! `Skill` trait, `SkillContext` (writes to the binding's mapped variables, the stop signal) and, in `builtin.rs`, the
//! built-in `motion` and `shell` skills; `connections.rs`, `Connections`, the ROS 2 and OPC UA protocols that skills
//! and bindings are both given. `ros2/` is ROS 2 over the agent's own session, spoken as rmw_zenoh or, with
//! `--ros-bridge`, as zenoh-bridge-ros2dds routes a DDS graph (`Via`): `interfaces` and `cdr` are the `baton-ros2`
//! crate's (the type library — built-in definitions that its `build.rs` embeds, hiroz's bundled Jazzy packages and its
//! `interfaces/` with Nav2's NavigateToPose, and `--ros-interfaces` folders, with the RIHS01 hashes of services, actions
//! and their sub-services; messages of run-time types: an IEC literal encoded field by field with hiroz-cdr's writer,
//! an answer decoded to a `RosValue` whose parts the mappings take), `rmw_keys.rs` (the
//! one place the key expressions, liveliness tokens and attachments of both are spelt), `client.rs` (the agent's node:
//! its tokens, waiting for a server in the graph, a service call as a query), `skills.rs` (`ros2_service`,
//! `ros2_action`: an action is its three services and its feedback topic, as rmw_zenoh and the bridge make it).
//! `opcua/` is OPC UA with async-opcua's client: `mod.rs` (`Endpoint`, the security and identity a binding asks for;
//! `OpcUa::connect`, a session opened within the deadline whose reconnects are then turned off, so a lost server ends
//! the `Link`), `convert.rs` (literals to variants of the data types a method declares, answers to chart values by
//! position), `skills.rs` (`opcua_method`: InputArguments read, the call, `done_node`/`fault_node` watched by a
//! subscription, `result_nodes` read, `cancel_method` on stop). No Rerun, no coordinator code; hiroz's node API is not
//! used, because its zenoh features would spread to every binary.

pub mod connections;
pub mod io;
pub mod many;
pub mod opcua;
mod roles;
pub mod ros2;
pub mod scenario_skills;
pub mod shell;
pub mod skill;

pub use connections::Connections;
pub use shell::{run, run_until, AgentConfig};
pub use skill::{Skill, SkillCall, SkillFuture, Skills};
