//! `baton-agent`: runs chart segments dispatched by a Baton coordinator, with the built-in skills.

use std::process::ExitCode;

use baton_proto::limits::CHART_STACK_BYTES;
use std::sync::Arc;

use baton_agent::{run, AgentConfig, Connections, Skills};
use clap::Parser;

/// Runs the segments of Baton charts placed on this agent (by name or by role) and hands the tokens back.
#[derive(Parser, Debug)]
#[command(name = "baton-agent", version)]
struct Args {
    /// The router to join, such as tcp/127.0.0.1:7447 (repeat for several).
    #[arg(long, required_unless_present = "list_skills", value_name = "ENDPOINT")]
    connect: Vec<String>,
    /// This agent's name, as charts pin steps to it: {agent := 'NAME'}.
    #[arg(long, required_unless_present = "list_skills")]
    name: Option<String>,
    /// Print the skills this agent would offer with these options (TOML, as `baton check --skills FILE` reads
    /// it), and exit.
    #[arg(long)]
    list_skills: bool,
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
    /// The ROS 2 domain the `ros2_*` skills speak on.
    #[arg(long, env = "ROS_DOMAIN_ID", default_value_t = 0, value_name = "ID", value_parser = clap::value_parser!(u32).range(0..=232))]
    ros_domain_id: u32,
    /// A folder of ROS 2 interface definitions (<package>/msg/*.msg, srv/*.srv, action/*.action) for types the
    /// agent does not know out of the box (repeatable); they win over the built-in ones of the same name.
    #[arg(long = "ros-interfaces", value_name = "DIR")]
    ros_interfaces: Vec<std::path::PathBuf>,
    /// The robots run DDS and are reached through a zenoh-bridge-ros2dds: topics, services and actions on the
    /// bridge's keys (the ROS name alone), not rmw_zenoh's. The ROS domain is then the bridge's own setting.
    #[arg(long)]
    ros_bridge: bool,
    /// Simulate the skills as this `baton test` scenario says (durations, outcomes, hangs, written values), in
    /// real time: every skill the scenario's chart binds is simulated, none reaches a device.
    #[arg(long, value_name = "SCENARIO")]
    simulate: Option<std::path::PathBuf>,
    /// With --simulate: the seed that draws durations within their ranges (default: the scenario's).
    #[arg(long, value_name = "SEED", requires = "simulate")]
    seed: Option<u64>,
    /// The ROS 2 distribution of the robots: jazzy, kilted (the same type hashes) or humble (none).
    #[arg(long, default_value = "jazzy", value_name = "DISTRO")]
    ros_distro: String,
    /// The OPC UA certificate folder: own/cert.der and private/private.pem (made self-signed the first time a
    /// secure endpoint is used), trusted/ for the servers' certificates, rejected/ for those not trusted yet.
    /// Default: $XDG_STATE_HOME/baton-agent/pki, else ~/.local/state/baton-agent/pki.
    #[arg(long, value_name = "DIR")]
    opcua_pki: Option<std::path::PathBuf>,
    /// Where the agent remembers, across restarts, the highest coordinator term each run has shown it, so that a
    /// restarted agent still refuses a deposed coordinator (terms/NAME.json). Default: $XDG_STATE_HOME/baton-agent,
    /// else ~/.local/state/baton-agent.
    #[arg(long, value_name = "DIR")]
    state_dir: Option<std::path::PathBuf>,
    /// Write this agent's trace to FILE (appended to), one JSON record per line, as programs read it: its start,
    /// its contact with the router, each skill's start, end, cancel and stop, an input refused (`t_ms` is Unix
    /// time).
    #[arg(long, value_name = "FILE")]
    trace: Option<std::path::PathBuf>,
    /// For benchmarks and tests: host N agents in this process, named NAME1 … NAMEN, each its own session.
    #[arg(long, hide = true, value_name = "N", value_parser = clap::value_parser!(u32).range(1..=4096))]
    instances: Option<u32>,
}

/// Where the agent keeps its state unless told: $XDG_STATE_HOME/baton-agent, else ~/.local/state/baton-agent.
fn default_state_dir() -> std::path::PathBuf {
    let state = std::env::var_os("XDG_STATE_HOME")
        .map(std::path::PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| std::path::PathBuf::from(h).join(".local/state")))
        .unwrap_or_else(std::env::temp_dir);
    state.join("baton-agent")
}

/// Where the agent keeps its OPC UA certificates unless told.
fn default_pki_dir() -> std::path::PathBuf {
    default_state_dir().join("pki")
}

fn main() -> ExitCode {
    // Zenoh's own log, when `RUST_LOG` asks for it (`RUST_LOG=zenoh=debug`): what its sessions, links and routing do.
    zenoh::try_init_log_from_env();
    // The whole agent runs on a thread of the stack a chart may need (`limits::CHART_STACK_BYTES`), as do its
    // runtime's threads, where fetched charts are compiled: whatever `baton check` accepts runs here.
    let main = std::thread::Builder::new().name("baton-agent".into()).stack_size(CHART_STACK_BYTES).spawn(agent_main);
    match main.map(std::thread::JoinHandle::join) {
        Ok(Ok(code)) => code,
        Ok(Err(_)) => ExitCode::from(101),
        Err(e) => {
            eprintln!("error: cannot start the agent's thread: {e}");
            ExitCode::from(1)
        }
    }
}

fn agent_main() -> ExitCode {
    let args = Args::parse();
    let config = AgentConfig {
        name: args.name.unwrap_or_default(),
        roles: args.roles,
        connect: args.connect,
        lease_ms: args.lease_ms,
        verbose: args.verbose,
        zenoh_config: args.zenoh_config,
        state_dir: Some(args.state_dir.unwrap_or_else(default_state_dir)),
    };
    let Some(distro) = baton_agent::ros2::Distro::parse(&args.ros_distro) else {
        eprintln!("error: --ros-distro must be jazzy, kilted or humble, not `{}`", args.ros_distro);
        return ExitCode::from(2);
    };
    let interfaces = match baton_agent::ros2::Interfaces::load(distro, &args.ros_interfaces) {
        Ok(i) => Arc::new(i),
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::from(2);
        }
    };
    let via = if args.ros_bridge { baton_agent::ros2::Via::Bridge } else { baton_agent::ros2::Via::RmwZenoh };
    let ros2 = Arc::new(baton_agent::ros2::Ros2::new(interfaces, args.ros_domain_id, via, &config.name));
    let opcua = Arc::new(baton_agent::opcua::OpcUa {
        pki_dir: args.opcua_pki.unwrap_or_else(default_pki_dir),
        agent: config.name.clone(),
    });
    let (skills, connections) = match &args.simulate {
        Some(path) => match baton_proto::testing::scenario::load(path, &|p| std::fs::read_to_string(p)) {
            Ok(sc) => {
                let seed = args.seed.unwrap_or(sc.seed);
                (baton_agent::scenario_skills::Simulated::new(sc, seed).skills(), Connections::default())
            }
            Err(baton_proto::testing::scenario::LoadError::Malformed(errors)) => {
                for e in errors {
                    eprintln!("{}:{}:{}: error: {}", path.display(), e.line, e.col, e.message);
                }
                return ExitCode::from(2);
            }
            Err(baton_proto::testing::scenario::LoadError::CannotRun(why)) => {
                eprintln!("error: {why}");
                return ExitCode::from(2);
            }
        },
        None => (Skills::builtin(), Connections::default().with_ros2(ros2).with_opcua(opcua)),
    };
    let skills = if args.allow_shell { skills.with_shell() } else { skills };
    if args.list_skills {
        print!("{}", connections.skills(skills).catalogue().to_toml());
        return ExitCode::SUCCESS;
    }
    if let Some(path) = &args.trace {
        if let Err(e) = baton_agent::trace::open(path) {
            eprintln!("error: {e}");
            return ExitCode::from(2);
        }
    }
    let runtime = match tokio::runtime::Builder::new_multi_thread()
        .worker_threads(if args.instances.is_some() { 2 } else { 1 })
        .thread_stack_size(CHART_STACK_BYTES)
        .enable_all()
        .build()
    {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("error: cannot start the runtime: {e}");
            return ExitCode::from(1);
        }
    };
    let agents = match args.instances {
        Some(n) => runtime.block_on(baton_agent::instances::run_many(
            baton_agent::instances::configs(&config, n),
            skills,
            connections,
        )),
        None => runtime.block_on(run(config, skills, connections)),
    };
    match agents {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(2)
        }
    }
}
