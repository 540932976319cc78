//! `baton run`: coordinate a chart across agents over Zenoh.

use std::path::PathBuf;
use std::process::ExitCode;

use baton_proto::cluster::runtime::coordinator::LossPolicy;

use super::common::{block_on, EXIT_ABORTED, EXIT_LEFT, EXIT_STOPPED};

#[derive(Clone, Copy, clap::ValueEnum)]
pub enum OnAgentLoss {
    Pause,
    Reassign,
    Fail,
}

/// The arguments of `baton run`.
#[derive(clap::Args)]
pub struct Run {
    /// The chart file: IEC 61131-3 textual SFC (`.st`) or PLCopen TC6 XML (`.xml`), as a PLC tool exports it.
    pub chart: PathBuf,
    /// Embed a Zenoh router listening here, such as tcp/127.0.0.1:7447.
    #[arg(long, value_name = "ENDPOINT", conflicts_with = "connect", required_unless_present = "connect")]
    pub listen: Vec<String>,
    /// Join the router (zenohd or another baton) at this endpoint.
    #[arg(long, value_name = "ENDPOINT")]
    pub connect: Vec<String>,
    /// Write the run's events as JSON Lines, flushed after every event.
    #[arg(long, value_name = "FILE")]
    pub trace: Option<PathBuf>,
    /// Write the final summary as JSON.
    #[arg(long, value_name = "FILE")]
    pub summary: Option<PathBuf>,
    /// Set an input before the first cycle (repeatable): --set parts=5.
    #[arg(long = "set", value_name = "NAME=VALUE", value_parser = crate::client::parse_assignment)]
    pub sets: Vec<(String, serde_json::Value)>,
    /// The run's scan cycle, on the coordinator and every agent (a resumed run keeps its own).
    #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u64).range(1..=baton_proto::limits::CYCLE_MS_MAX))]
    pub cycle_ms: u64,
    /// Which chart to use when the file holds several PROGRAMs or FUNCTION_BLOCKs with SFC bodies.
    #[arg(long)]
    pub pou: Option<String>,
    /// Find routers and peers by multicast scouting too (off by default).
    #[arg(long)]
    pub multicast_scouting: bool,
    /// Print only warnings, errors and the summary.
    #[arg(long, short)]
    pub quiet: bool,
    /// A Zenoh configuration file (TLS, credentials…); Baton's own settings apply on top of it.
    #[arg(long, value_name = "FILE")]
    pub zenoh_config: Option<PathBuf>,
    /// What to do with the tokens of a lost agent: hold them until it is back, restart their segments on
    /// another agent (new epoch), or end the run with an error.
    #[arg(long, value_enum, default_value_t = OnAgentLoss::Pause)]
    pub on_agent_loss: OnAgentLoss,
    /// Record every change of the run in a journal in this folder, durably, before acting on it. If the
    /// folder holds the journal of a run that did not end (the coordinator crashed or was stopped), that
    /// run resumes where it was, with the tokens still out reconciled with their agents. etcd://HOST:PORT[,…]/PREFIX
    /// keeps it in etcd instead, for standby coordinators on other machines: it implies --election at the same
    /// place, and each write holds only while this coordinator holds the election. etcds://…?cacert=FILE[&cert=FILE&
    /// key=FILE] reaches etcd over TLS; either form takes user=NAME&password-file=FILE where etcd's auth is on.
    #[arg(long, value_name = "DIR|etcd://…/PREFIX")]
    pub journal: Option<crate::journal::Place>,
    /// With --journal: snapshot the coordinator's state after this many records since the last snapshot, and
    /// start a new journal segment with it; a resume then replays only the records after the last snapshot
    /// (0: never).
    #[arg(long, value_name = "RECORDS", default_value_t = crate::journal::SNAPSHOT_EVERY, requires = "journal")]
    pub snapshot_every: u64,
    /// With --journal: how many segments to keep, the last one included (`all`: every one, so that `baton replay`
    /// rebuilds the whole run). Older segments are deleted when a snapshot starts a new one.
    #[arg(long, value_name = "N|all", default_value = "2", requires = "journal")]
    pub journal_keep: crate::journal::Keep,
    /// Serve the operator console for this run's cell on ADDR (a loopback address such as 127.0.0.1:8080), as
    /// `baton console` does.
    #[arg(long, value_name = "ADDR")]
    pub console: Option<std::net::SocketAddr>,
    /// Record the run for the Rerun viewer: off, save:PATH.rrd, connect or connect:URL (a running viewer), spawn
    /// (start one), or serve or serve:ADDR (serve it, by default on 127.0.0.1:9876, for viewers and the operator
    /// console's timeline, live).
    #[arg(long, value_name = "SINK", default_value = "off")]
    pub rerun: crate::recording::Sink,
    /// With --rerun serve: a web page origin (https://console.plant:8443) allowed to read the served recording, as
    /// a console beyond loopback is; loopback pages are allowed without it. Repeat for more.
    #[arg(long, value_name = "ORIGIN")]
    pub rerun_origin: Vec<String>,
    /// Trace this variable's value, as `baton sim --watch` does: a `value` record after the first cycle and
    /// after every change. Repeat for more.
    #[arg(long, value_name = "VARIABLE")]
    pub watch: Vec<String>,
    /// Wait in the Idle state, the chart not started, until an operator sends `baton ctl start` (PackML's Idle →
    /// Starting → Execute); inputs may be set meanwhile.
    #[arg(long)]
    pub wait_start: bool,
    /// Stay at the run's end (Complete, Stopped, Aborted) for PackML's `baton ctl clear` and `reset`, which start
    /// the chart again from its initial steps as a new run in the same journal; an interrupt then ends the
    /// process, with the exit status of the state it was in.
    #[arg(long)]
    pub stay: bool,
    /// After an abort, how long `baton run` waits to tell the agents it could not reach (cut off, lost) of the
    /// abort, if they come back meanwhile: one told stops what it still runs of the run.
    #[arg(long, value_name = "DURATION", default_value = "30s", value_parser = super::ctl::parse_duration_ms)]
    pub abort_wait: u64,
    /// Stand in an election on etcd with the other coordinators of this run (the same chart, journal and PREFIX),
    /// and coordinate only while winning it: etcd://HOST:PORT[,HOST:PORT…]/PREFIX. A standby waits, then takes the
    /// run over from the journal when the active coordinator's lease ends.
    #[arg(long, value_name = "etcd://…/PREFIX", requires = "journal")]
    pub election: Option<crate::election::Election>,
    /// With --election (or a journal in etcd): the lease's time to live, in seconds (default 2). A standby takes
    /// over about this long after the active coordinator died or was cut off from etcd; one cut off stops acting a
    /// third of it earlier.
    #[arg(long, value_name = "SECONDS", value_parser = clap::value_parser!(u64).range(2..=60))]
    pub lease: Option<u64>,
}

impl Run {
    pub fn run(self) -> anyhow::Result<ExitCode> {
        let loss_policy = match self.on_agent_loss {
            OnAgentLoss::Pause => LossPolicy::Pause,
            OnAgentLoss::Reassign => LossPolicy::Reassign,
            OnAgentLoss::Fail => LossPolicy::Fail,
        };
        let opts = crate::run::RunOptions {
            chart: self.chart,
            pou: self.pou,
            listen: self.listen,
            connect: self.connect,
            trace: self.trace,
            summary: self.summary,
            cycle_ms: self.cycle_ms,
            sets: self.sets,
            multicast_scouting: self.multicast_scouting,
            quiet: self.quiet,
            zenoh_config: self.zenoh_config,
            loss_policy,
            election: election_of(self.journal.as_ref(), self.election, self.lease)?,
            journal: self.journal,
            journal_settings: crate::journal::Settings { snapshot_every: self.snapshot_every, keep: self.journal_keep },
            rerun: with_origins(self.rerun, self.rerun_origin)?,
            watch: self.watch,
            wait_start: self.wait_start,
            stay: self.stay,
            abort_wait_ms: self.abort_wait,
            console: self.console,
        };
        let standing = opts.election.is_some();
        block_on(async move {
            let summary = loop {
                let summary = match crate::run::run(opts.clone()).await {
                    Err(e) if standing && e.downcast_ref::<crate::run::RunOver>().is_some() => {
                        let over = e.downcast_ref::<crate::run::RunOver>().map(|o| o.0.clone()).unwrap_or_default();
                        eprintln!("baton: won the election, but {over}: there is nothing to take over");
                        return Ok(ExitCode::SUCCESS);
                    }
                    ran => ran?,
                };
                // Deposed, it acts on nothing any more: it stands again, and takes the run up if it wins again.
                if !summary.deposed {
                    break summary;
                }
                eprintln!("baton: standing in the election again");
            };
            summary.print();
            Ok(match summary.state.as_str() {
                _ if summary.left => ExitCode::from(EXIT_LEFT),
                "stopped" => ExitCode::from(EXIT_STOPPED),
                "aborted" => ExitCode::from(EXIT_ABORTED),
                _ => ExitCode::SUCCESS,
            })
        })
    }
}

/// The election a run stands in: `--election`, or the place of a journal in etcd (which only the election's winner
/// may write). Both given, they must agree.
fn election_of(
    journal: Option<&crate::journal::Place>,
    election: Option<crate::election::Election>,
    lease: Option<u64>,
) -> anyhow::Result<Option<(crate::election::Election, u64)>> {
    let election = match (journal, election) {
        (Some(crate::journal::Place::Etcd(place)), Some(e)) if *place != e => anyhow::bail!(
            "--journal {place} and --election {e} name different places: a journal in etcd is written under the              election at its own place (leave --election out)"
        ),
        (Some(crate::journal::Place::Etcd(place)), _) => Some(place.clone()),
        (_, e) => e,
    };
    if election.is_none() && lease.is_some() {
        anyhow::bail!("--lease is the lease of an election: give --election, or --journal etcd://…");
    }
    Ok(election.map(|e| (e, lease.unwrap_or(2))))
}

/// `--rerun-origin` belongs to `--rerun serve`.
fn with_origins(sink: crate::recording::Sink, more: Vec<String>) -> anyhow::Result<crate::recording::Sink> {
    match sink {
        crate::recording::Sink::Serve { addr, mut origins } => {
            origins.extend(more);
            Ok(crate::recording::Sink::Serve { addr, origins })
        }
        _ if more.is_empty() => Ok(sink),
        _ => Err(anyhow::anyhow!(
            "--rerun-origin is for --rerun serve: it says which pages may read the served recording"
        )),
    }
}
