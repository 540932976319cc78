//! `baton deploy`: what a cell needs before it runs.

use std::path::PathBuf;
use std::process::ExitCode;

/// The subcommands of `baton deploy`.
#[derive(clap::Subcommand)]
pub enum Deploy {
    /// Make a certificate authority in DIR (or reuse the one there) and a certificate and key per NAME, signed by
    /// it, the name as the certificate's common name: DIR/ca.pem, DIR/ca.key, DIR/NAME.pem, DIR/NAME.key (PEM), and
    /// DIR/NAME.json5, the Zenoh configuration NAME's process connects with (--zenoh-config). Give each process its
    /// own: an agent's name, the coordinator's, each operator's.
    Certs(Certs),
    /// Write a router's configuration for a chart's cell: deny by default, and each identity allowed only what its
    /// part needs (an agent its own keys and the chart's bindings on it; a coordinator the coordinator's keys;
    /// operators set and ctl). Works with `zenohd` and with `baton run --listen … --zenoh-config`.
    Acl(Acl),
    /// Write the users of `baton console --users FILE`: each NAME=ROLE (viewer, operator or maintenance) gets a new
    /// password, printed once — the file keeps only its Argon2id hash, readable by its owner alone. Users already in
    /// the file and not named stay as they are.
    Users(UsersArgs),
}

#[derive(clap::Args)]
pub struct UsersArgs {
    /// The users' file (made if missing).
    #[arg(value_name = "FILE")]
    pub file: PathBuf,
    /// Users to add, or to give a new password and role: anna=operator bob=viewer carl=maintenance.
    #[arg(value_name = "NAME=ROLE", value_parser = parse_user)]
    pub users: Vec<(String, crate::console::users::Role)>,
    /// Users to remove (repeatable).
    #[arg(long, value_name = "NAME")]
    pub remove: Vec<String>,
}

fn parse_user(text: &str) -> Result<(String, crate::console::users::Role), String> {
    use clap::ValueEnum;
    let (name, role) = text.split_once('=').ok_or_else(|| format!("`{text}`: give NAME=ROLE (anna=operator)"))?;
    let role = crate::console::users::Role::from_str(role.trim(), true)
        .map_err(|_| format!("`{role}`: a role is viewer, operator or maintenance"))?;
    Ok((name.trim().to_string(), role))
}

#[derive(clap::Args)]
pub struct Acl {
    /// The chart file: IEC 61131-3 textual SFC (`.st`) or PLCopen TC6 XML (`.xml`), as a PLC tool exports it.
    pub chart: PathBuf,
    /// Which chart to use when the file holds several PROGRAMs or FUNCTION_BLOCKs with SFC bodies.
    #[arg(long)]
    pub pou: Option<String>,
    // Each identity flag takes one name or several (`--agents robot1 robot2`, as the plural alias reads), and
    // repeats; several names after one flag come after CHART.
    /// A coordinator's identity (repeatable).
    #[arg(long = "coordinator", visible_alias = "coordinators", value_name = "NAME", num_args = 1..)]
    pub coordinators: Vec<String>,
    /// An agent's identity, and the roles it serves: --agent robot1 --agent assembler1=assembler,welder, or
    /// --agents robot1 assembler1=assembler,welder.
    #[arg(long = "agent", visible_alias = "agents", value_name = "NAME[=ROLE,…]", value_parser = parse_agent, num_args = 1..)]
    pub agents: Vec<(String, Vec<String>)>,
    /// An operator's identity: may set inputs and operate runs (repeatable).
    #[arg(long = "operator", visible_alias = "operators", value_name = "NAME", num_args = 1..)]
    pub operators: Vec<String>,
    /// A viewer's identity: may read status, charts, history and why, and hear runs' live trace (repeatable).
    #[arg(long = "viewer", visible_alias = "viewers", value_name = "NAME", num_args = 1..)]
    pub viewers: Vec<String>,
    /// A `baton console`'s identity: operates as an operator does, for the users logged in to it (repeatable).
    #[arg(long = "console", visible_alias = "consoles", value_name = "NAME", num_args = 1..)]
    pub consoles: Vec<String>,
    /// How the router knows a process: its certificate's common name, or its Zenoh user name.
    #[arg(long, value_enum, default_value_t = crate::deploy::acl::By::Cert)]
    pub by: crate::deploy::acl::By,
    /// Where the router listens (repeatable).
    #[arg(long, value_name = "ENDPOINT", default_value = "tls/0.0.0.0:7447")]
    pub listen: Vec<String>,
    /// Mutual TLS with the certificates of `baton deploy certs --ca DIR`: the router's are DIR/ROUTER.pem and .key.
    #[arg(long, value_name = "DIR")]
    pub pki: Option<PathBuf>,
    /// The router's name in --pki (the coordinator's, for a router embedded in `baton run`).
    #[arg(long, value_name = "NAME", default_value = "router")]
    pub router: String,
    /// Write the configuration here rather than to standard output.
    #[arg(long, short, value_name = "FILE")]
    pub output: Option<PathBuf>,
}

fn parse_agent(text: &str) -> Result<(String, Vec<String>), String> {
    let (name, roles) = text.split_once('=').unwrap_or((text, ""));
    let roles = roles.split(',').map(str::trim).filter(|r| !r.is_empty()).map(str::to_string).collect();
    Ok((name.trim().to_string(), roles))
}

#[derive(clap::Args)]
pub struct Certs {
    /// The folder of the cell's CA and certificates.
    #[arg(long = "ca", value_name = "DIR")]
    pub dir: PathBuf,
    /// The processes to certify: agents' names, the coordinator's, operators'.
    #[arg(value_name = "NAME", required = true)]
    pub names: Vec<String>,
    /// A further host name or address these certificates answer at (a router's), repeatable:
    /// --san router.cell4.local --san 10.0.4.2.
    #[arg(long, value_name = "HOST")]
    pub san: Vec<String>,
    /// Issue again the certificates of names that have one (the CA stays).
    #[arg(long)]
    pub renew: bool,
}

impl Deploy {
    pub fn run(self) -> anyhow::Result<ExitCode> {
        match self {
            Deploy::Certs(c) => {
                let made = crate::deploy::certs::certs(&c.dir, &c.names, &c.san, c.renew)?;
                let what = if made.ca_made { "made" } else { "kept" };
                println!("CA {what}: {}", made.ca.display());
                for i in &made.issued {
                    let what = if i.made { "issued" } else { "kept (--renew to issue again)" };
                    println!(
                        "{}: {what}: {} {}; connects with --zenoh-config {}",
                        i.name,
                        i.cert.display(),
                        i.key.display(),
                        i.config.display()
                    );
                }
                Ok(ExitCode::SUCCESS)
            }
            Deploy::Acl(a) => {
                let loaded = crate::chart_file::load(&a.chart, a.pou.as_deref())?;
                let ids = crate::deploy::acl::Identities {
                    coordinators: a.coordinators,
                    agents: a.agents,
                    operators: a.operators,
                    viewers: a.viewers,
                    consoles: a.consoles,
                };
                let acl = crate::deploy::acl::access_control(&loaded.program, &loaded.layout, &ids, a.by)?;
                let tls = a.pki.map(|dir| {
                    let file = |f: String| dir.join(f).display().to_string();
                    (file("ca.pem".into()), file(format!("{}.pem", a.router)), file(format!("{}.key", a.router)))
                });
                let config = crate::deploy::acl::router_config(acl, &a.listen, tls);
                let text = format!(
                    "// The router of chart `{}`'s cell: written by `baton deploy acl`; deny by default.\n{}\n",
                    loaded.pou,
                    serde_json::to_string_pretty(&config)?
                );
                match &a.output {
                    Some(p) => {
                        std::fs::write(p, text).map_err(|e| anyhow::anyhow!("cannot write {}: {e}", p.display()))?
                    }
                    None => print!("{text}"),
                }
                Ok(ExitCode::SUCCESS)
            }
            Deploy::Users(u) => {
                if u.users.is_empty() && u.remove.is_empty() {
                    anyhow::bail!("name the users: baton deploy users FILE anna=operator bob=viewer");
                }
                for (name, role, password) in crate::console::users::write(&u.file, &u.users, &u.remove)? {
                    println!("{name} ({}): {password}", role.name());
                }
                for name in &u.remove {
                    println!("{name}: removed");
                }
                println!("users: {} (hand each password over once: the file keeps only its hash)", u.file.display());
                Ok(ExitCode::SUCCESS)
            }
        }
    }
}
