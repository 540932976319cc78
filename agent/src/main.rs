//! `baton-agent`: runs chart segments dispatched by a Baton coordinator, with the built-in skills.

use std::process::ExitCode;

use baton_agent::{run, AgentConfig, Skills};
use clap::Parser;

/// Runs the segments of Baton charts placed on this agent (by name or by role) and hands the tokens back.
#[derive(Parser, Debug)]
#[command(name = "baton-agent", version)]
struct Args {
    /// The router to join, such as tcp/127.0.0.1:7447 (repeat for several).
    #[arg(long, required = true, value_name = "ENDPOINT")]
    connect: Vec<String>,
    /// This agent's name, as charts pin steps to it: {agent := 'NAME'}.
    #[arg(long)]
    name: String,
    /// A role this agent serves, as charts place steps on it: {role := 'ROLE'} (repeatable).
    #[arg(long = "role", value_name = "ROLE")]
    roles: Vec<String>,
    /// The lease this agent announces: a hung or cut-off agent is declared lost after this long.
    #[arg(long, default_value_t = 10_000, value_name = "MS")]
    lease_ms: u64,
    /// Offer the `shell` skill, which runs the command a chart names: only for charts you trust.
    #[arg(long)]
    allow_shell: bool,
    /// Log every event, not only warnings and errors.
    #[arg(long, short)]
    verbose: bool,
    /// A Zenoh configuration file (TLS, credentials…); Baton's own settings apply on top of it.
    #[arg(long, value_name = "FILE")]
    zenoh_config: Option<std::path::PathBuf>,
}

fn main() -> ExitCode {
    let args = Args::parse();
    let config = AgentConfig {
        name: args.name,
        roles: args.roles,
        connect: args.connect,
        lease_ms: args.lease_ms,
        verbose: args.verbose,
        zenoh_config: args.zenoh_config,
    };
    let skills = if args.allow_shell { Skills::builtin().with_shell() } else { Skills::builtin() };
    let runtime = match tokio::runtime::Builder::new_multi_thread().worker_threads(1).enable_all().build() {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("error: cannot start the runtime: {e}");
            return ExitCode::from(1);
        }
    };
    match runtime.block_on(run(config, skills)) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(2)
        }
    }
}
