//! Command-line interface: argument parsing, file I/O and exit codes around the pure core.

use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;

use anyhow::{bail, Context};
use baton_proto::exec::sim::{parse_inputs, simulate_watching, SimOutput};
use baton_proto::front::diag::LineIndex;
use baton_proto::front::source::{self, Decoded};
use baton_proto::pipeline::{check_source, CheckedChart, Report};
use clap::{Parser, Subcommand};

/// Exit status of `baton check` and `baton sim` when the chart has errors.
const EXIT_INVALID: u8 = 1;
/// Exit status for usage and I/O errors (clap uses it too).
const EXIT_USAGE: u8 = 2;

#[derive(Parser)]
#[command(name = "baton", version, about = "Sequential function charts (IEC 61131-3), checked and run")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum OnAgentLoss {
    Pause,
    Reassign,
    Fail,
}

#[derive(Subcommand)]
enum Command {
    /// Check a chart: syntax, names, types, safety and reachability. Exit 0 when valid, 1 on errors.
    Check {
        /// The chart: IEC 61131-3 textual SFC (`.st`).
        chart: PathBuf,
        /// Print one JSON object (the charts' steps, transitions and actions, and every diagnostic) instead.
        #[arg(long)]
        json: bool,
    },
    /// Run a chart on virtual time and print its events as JSON Lines.
    Sim {
        chart: PathBuf,
        /// Input script, JSON Lines: {"t_ms": 100, "set": {"start": true}}.
        #[arg(long)]
        inputs: Option<PathBuf>,
        /// Time between two scan cycles.
        #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u64).range(1..=baton_proto::limits::CYCLE_MS_MAX))]
        cycle_ms: u64,
        /// Time of the last cycle.
        #[arg(long, default_value_t = 1000)]
        until_ms: u64,
        /// Which chart to run when the file holds several PROGRAMs or FUNCTION_BLOCKs with SFC bodies.
        #[arg(long)]
        pou: Option<String>,
        /// Trace this variable's value (`t1.ET` for a block's output): a `value` record after the first cycle
        /// and after every cycle that changed it. Repeat for more.
        #[arg(long, value_name = "VARIABLE")]
        watch: Vec<String>,
    },
    /// Write a valid chart file out in another format: `--plcopen`, PLCopen TC6 v2.01 XML with positions, for
    /// Beremiz, OpenPLC Editor and other IEC 61131-3 tools. Every chart of the file, or the one `--pou` names.
    Export {
        chart: PathBuf,
        /// PLCopen TC6 v2.01 XML (the only format today).
        #[arg(long, required = true)]
        plcopen: bool,
        #[arg(long)]
        pou: Option<String>,
        /// Write here instead of to stdout.
        #[arg(long, short = 'o', value_name = "FILE")]
        output: Option<PathBuf>,
    },
    /// Coordinate a chart across agents over Zenoh; exit 0 when it reaches a terminal situation.
    Run {
        chart: PathBuf,
        /// Embed a Zenoh router listening here, such as tcp/127.0.0.1:7447.
        #[arg(long, value_name = "ENDPOINT", conflicts_with = "connect", required_unless_present = "connect")]
        listen: Vec<String>,
        /// Join the router (zenohd or another baton) at this endpoint.
        #[arg(long, value_name = "ENDPOINT")]
        connect: Vec<String>,
        /// Write the run's events as JSON Lines, flushed after every event.
        #[arg(long, value_name = "FILE")]
        trace: Option<PathBuf>,
        /// Write the final summary as JSON.
        #[arg(long, value_name = "FILE")]
        summary: Option<PathBuf>,
        /// Set an input before the first cycle (repeatable): --set parts=5.
        #[arg(long = "set", value_name = "NAME=VALUE", value_parser = crate::client::parse_assignment)]
        sets: Vec<(String, serde_json::Value)>,
        /// The run's scan cycle, on the coordinator and every agent (a resumed run keeps its own).
        #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u64).range(1..=baton_proto::limits::CYCLE_MS_MAX))]
        cycle_ms: u64,
        #[arg(long)]
        pou: Option<String>,
        /// Find routers and peers by multicast scouting too (off by default).
        #[arg(long)]
        multicast_scouting: bool,
        /// Print only warnings, errors and the summary.
        #[arg(long, short)]
        quiet: bool,
        /// A Zenoh configuration file (TLS, credentials…); Baton's own settings apply on top of it.
        #[arg(long, value_name = "FILE")]
        zenoh_config: Option<PathBuf>,
        /// What to do with the tokens of a lost agent: hold them until it is back, restart their segments on
        /// another agent (new epoch), or end the run with an error.
        #[arg(long, value_enum, default_value_t = OnAgentLoss::Pause)]
        on_agent_loss: OnAgentLoss,
        /// Record every change of the run in a journal in this folder, durably, before acting on it. If the
        /// folder holds the journal of a run that did not end (the coordinator crashed or was stopped), that
        /// run resumes where it was, with the tokens still out reconciled with their agents.
        #[arg(long, value_name = "DIR")]
        journal: Option<PathBuf>,
        /// Record the run for the Rerun viewer: off, save:PATH.rrd, connect[:URL] (a running viewer), or spawn
        /// (start one).
        #[arg(long, value_name = "SINK", default_value = "off")]
        rerun: crate::recording::Sink,
        /// Trace this variable's value, as `baton sim --watch` does: a `value` record after the first cycle and
        /// after every change. Repeat for more.
        #[arg(long, value_name = "VARIABLE")]
        watch: Vec<String>,
    },
    /// Rebuild a past run from its journal: its Rerun recording and its trace (no network, no agents).
    Replay {
        /// The folder given to `baton run --journal`.
        #[arg(long, value_name = "DIR")]
        journal: PathBuf,
        /// Where the recording goes: save:PATH.rrd, connect[:URL], spawn, or off.
        #[arg(long, value_name = "SINK", default_value = "off")]
        rerun: crate::recording::Sink,
        /// Write the run's trace as JSON Lines.
        #[arg(long, value_name = "FILE")]
        trace: Option<PathBuf>,
    },
    /// Set an input of a chart running behind a router: baton set --connect EP [--run ID] NAME=VALUE. With several
    /// runs behind the router, --run says which (nothing is set otherwise).
    Set {
        #[arg(long, value_name = "ENDPOINT", required = true)]
        connect: Vec<String>,
        /// The run, by its id as `baton status` lists it (or the start of it).
        #[arg(long, value_name = "ID")]
        run: Option<String>,
        #[arg(value_name = "NAME=VALUE", value_parser = crate::client::parse_assignment)]
        assignment: (String, serde_json::Value),
        /// A Zenoh configuration file (TLS, credentials…).
        #[arg(long, value_name = "FILE")]
        zenoh_config: Option<PathBuf>,
    },
    /// Run scenario files (*.test.toml) of your charts on a simulated cell, on virtual time: exit 0 when every
    /// expectation holds, 1 when one fails, 2 when a scenario could not run, 3 on a malformed scenario file
    Test {
        /// Scenario files, or folders to search for *.test.toml (default: the current folder).
        paths: Vec<PathBuf>,
        /// Run N schedules per scenario, seeds from its own `seed` on (durations, message order and delays, fault
        /// timing); a failure prints the command that replays its seed.
        #[arg(long, value_name = "N")]
        seeds: Option<u64>,
        /// Run exactly this seed: the replay of a failure.
        #[arg(long, value_name = "SEED", conflicts_with = "seeds")]
        seed: Option<u64>,
        /// Write a JUnit XML report here (one testsuite per file, one testcase per expectation).
        #[arg(long, value_name = "FILE")]
        junit: Option<PathBuf>,
        /// Where the traces and Rerun recordings of failing runs go (and, with --cluster, their processes' logs).
        #[arg(long, value_name = "DIR", default_value = "baton-test-failures")]
        out: PathBuf,
        /// Runs at once (default: the machine's cores).
        #[arg(long, value_name = "N")]
        jobs: Option<usize>,
        /// Print only failures and the total.
        #[arg(long, short)]
        quiet: bool,
        /// Print which steps, transitions and branches the scenarios exercised, and which steps faults struck.
        #[arg(long)]
        coverage: bool,
        /// Stop after this much wall time (`10min`, `90s`): what ran is reported and the JUnit file written;
        /// exit status 2. An interrupt (SIGINT, SIGTERM) does the same, with exit status 130.
        #[arg(long, value_name = "DURATION", value_parser = parse_wall_time)]
        timeout: Option<std::time::Duration>,
        /// Run on real processes on loopback, in real time: an embedded router, `baton run` and a
        /// `baton-agent --simulate` per agent; faults by signals, cut cables and a coordinator restarted on its
        /// journal.
        #[arg(long)]
        cluster: bool,
        /// Keep the trace and Rerun recording of every run under --out, not only of failing runs.
        #[arg(long)]
        keep: bool,
    },
    /// Run the bundled multi-robot cell: a router, a coordinator and simulated robots on loopback.
    Demo {
        /// Picking robots (each a `baton-agent` process); robot1 and robot2 also assemble.
        #[arg(long, default_value_t = 2)]
        agents: usize,
        /// Parts the cell makes before it stops.
        #[arg(long, default_value_t = 3)]
        parts: u32,
        /// Keep the chart, trace, summary and logs in this folder.
        #[arg(long, value_name = "DIR")]
        keep: Option<PathBuf>,
        /// Record the run for the Rerun viewer: save:PATH.rrd, connect[:URL], spawn, or off.
        #[arg(long, value_name = "SINK", default_value = "save:baton-demo.rrd")]
        rerun: crate::recording::Sink,
    },
    /// Measure the distributed runtime on loopback: Zenoh and token round trips, convergence, throughput.
    Bench {
        /// Round trips and convergences measured.
        #[arg(long, default_value_t = 2000)]
        samples: u32,
        /// Tokens in the throughput phase.
        #[arg(long, default_value_t = 40_000)]
        tokens: u32,
        /// Agents (processes) in the throughput phase.
        #[arg(long, default_value_t = 8)]
        agents: u32,
        /// Tokens in flight per agent in the throughput phase.
        #[arg(long, default_value_t = 4)]
        lanes_per_agent: u32,
        /// Parts of the demo chart in the recording phase.
        #[arg(long, default_value_t = 400)]
        parts: u32,
        /// Print the figures as JSON.
        #[arg(long)]
        json: bool,
    },
    /// The far end of the bench's raw Zenoh round trip.
    #[command(hide = true)]
    BenchEcho {
        #[arg(long, required = true)]
        connect: Vec<String>,
    },
    /// Print the active steps, tokens in flight and live agents of the charts running behind a router.
    Status {
        #[arg(long, value_name = "ENDPOINT", required = true)]
        connect: Vec<String>,
        /// One JSON object per running chart.
        #[arg(long)]
        json: bool,
        /// A Zenoh configuration file (TLS, credentials…).
        #[arg(long, value_name = "FILE")]
        zenoh_config: Option<PathBuf>,
    },
}

pub fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Check { chart, json: false } => check(&chart),
        Command::Export { chart, plcopen: _, pou, output } => export(&chart, pou.as_deref(), output.as_deref()),
        Command::Check { chart, json: true } => check_json(&chart),
        Command::Sim { chart, inputs, cycle_ms, until_ms, pou, watch } => {
            sim(&chart, inputs.as_deref(), cycle_ms, until_ms, pou.as_deref(), &watch)
        }
        Command::Run {
            chart,
            listen,
            connect,
            trace,
            summary,
            sets,
            cycle_ms,
            pou,
            multicast_scouting,
            quiet,
            zenoh_config,
            on_agent_loss,
            journal,
            rerun,
            watch,
        } => {
            use baton_proto::dist::runtime::coordinator::LossPolicy;
            let loss_policy = match on_agent_loss {
                OnAgentLoss::Pause => LossPolicy::Pause,
                OnAgentLoss::Reassign => LossPolicy::Reassign,
                OnAgentLoss::Fail => LossPolicy::Fail,
            };
            let opts = crate::run::RunOptions {
                chart,
                pou,
                listen,
                connect,
                trace,
                summary,
                cycle_ms,
                sets,
                multicast_scouting,
                quiet,
                zenoh_config,
                loss_policy,
                journal,
                rerun,
                watch,
            };
            block_on(async move {
                let summary = crate::run::run(opts).await?;
                summary.print();
                Ok(ExitCode::SUCCESS)
            })
        }
        Command::Set { connect, run, assignment: (name, value), zenoh_config } => block_on(async move {
            let taken = crate::client::set(&connect, zenoh_config.as_deref(), run.as_deref(), &name, value).await?;
            Ok(if taken { ExitCode::SUCCESS } else { ExitCode::from(EXIT_INVALID) })
        }),
        Command::Replay { journal, rerun, trace } => {
            crate::replay::replay(&crate::replay::ReplayOptions { journal, rerun, trace }).map(|()| ExitCode::SUCCESS)
        }
        Command::Test { paths, seeds, seed, junit, out, jobs, quiet, coverage, timeout, cluster, keep } => {
            let jobs = jobs.unwrap_or_else(|| std::thread::available_parallelism().map_or(1, |n| n.get()));
            crate::testing::test(&crate::testing::TestOptions {
                paths,
                seeds,
                seed,
                junit,
                out,
                jobs,
                quiet,
                coverage,
                timeout,
                cluster,
                keep,
            })
        }
        Command::Demo { agents, parts, keep, rerun } => {
            block_on(crate::demo::demo(crate::demo::DemoOptions { agents, parts, keep, rerun }))
        }
        Command::Bench { samples, tokens, agents, lanes_per_agent, parts, json } => block_on(async move {
            if samples == 0 || tokens == 0 || agents == 0 || lanes_per_agent == 0 || parts == 0 {
                bail!("--samples, --tokens, --agents, --lanes-per-agent and --parts must be at least 1");
            }
            let options = crate::bench::BenchOptions { samples, tokens, agents, lanes_per_agent, parts };
            let report = crate::bench::bench(options).await?;
            if json {
                println!("{}", serde_json::to_string_pretty(&report)?);
            } else {
                report.print();
            }
            Ok(ExitCode::SUCCESS)
        }),
        Command::BenchEcho { connect } => block_on(async move {
            crate::bench::echo(&connect).await?;
            Ok(ExitCode::SUCCESS)
        }),
        Command::Status { connect, json, zenoh_config } => block_on(async move {
            crate::client::status(&connect, zenoh_config.as_deref(), json).await?;
            Ok(ExitCode::SUCCESS)
        }),
    };
    match result {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(EXIT_USAGE)
        }
    }
}

/// Zenoh needs the multi-thread runtime (its blocking calls panic inside a current-thread one).
fn block_on(fut: impl std::future::Future<Output = anyhow::Result<ExitCode>>) -> anyhow::Result<ExitCode> {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .thread_stack_size(baton_proto::limits::CHART_STACK_BYTES)
        .enable_all()
        .build()
        .context("cannot start the runtime")?;
    runtime.block_on(fut)
}

fn read(path: &Path) -> anyhow::Result<String> {
    std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))
}

/// A chart file's text, decoded as its tool wrote it (`front::source`): its size is checked before it is read,
/// and how it was read, when not as UTF-8, is said as a warning at its place.
pub fn read_chart(path: &Path) -> anyhow::Result<Decoded> {
    let len = std::fs::metadata(path).with_context(|| format!("cannot read {}", path.display()))?.len();
    source::check_size(len).with_context(|| format!("cannot read {}", path.display()))?;
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let decoded = source::decode(&bytes).with_context(|| format!("cannot read {}", path.display()))?;
    if let Some(note) = &decoded.note {
        eprintln!("{}:{}:{}: warning: {}", path.display(), note.line, note.col, note.message);
    }
    Ok(decoded)
}

fn print_diagnostics(path: &Path, src: &str, report: &Report, keep: impl Fn(u32) -> bool) {
    let index = LineIndex::new(src);
    let shown = path.display().to_string();
    let mut err = std::io::stderr().lock();
    for d in report.diagnostics.iter().filter(|d| keep(d.span.start)) {
        let _ = write!(err, "{}", index.render(&shown, d));
    }
}

fn check(path: &Path) -> anyhow::Result<ExitCode> {
    let src = read_chart(path)?.text;
    let report = check_source(&src);
    print_diagnostics(path, &src, &report, |_| true);
    let errors = report.error_count();
    let warnings = report.diagnostics.len() - errors;
    if errors > 0 {
        eprintln!("{}: {errors} error(s), {warnings} warning(s)", path.display());
        return Ok(ExitCode::from(EXIT_INVALID));
    }
    for c in &report.charts {
        if let Some(p) = &c.program {
            println!(
                "{}: chart `{}` is valid: {} steps, {} transitions, {} actions, {} warning(s)",
                path.display(),
                p.name,
                p.steps.len(),
                p.transitions.len(),
                p.actions.len(),
                warnings
            );
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// `baton check --json`: the charts of the file and every diagnostic, as one JSON object; the exit status is
/// `baton check`'s.
fn check_json(path: &Path) -> anyhow::Result<ExitCode> {
    let file = path.display().to_string();
    // Always one JSON object, whatever happened: a file that cannot be read is an error diagnostic of its own.
    let read = std::fs::metadata(path)
        .map_err(anyhow::Error::from)
        .and_then(|m| source::check_size(m.len()).map_err(anyhow::Error::from))
        .and_then(|()| std::fs::read(path).map_err(anyhow::Error::from))
        .and_then(|bytes| source::decode(&bytes).map_err(anyhow::Error::from));
    let decoded = match read {
        Ok(d) => d,
        Err(e) => {
            let message = format!("cannot read {file}: {e}");
            let diagnostic =
                serde_json::json!({ "severity": "error", "file": file, "line": 0, "col": 0, "message": message });
            println!("{}", serde_json::json!({ "charts": [], "diagnostics": [diagnostic] }));
            return Ok(ExitCode::from(EXIT_USAGE));
        }
    };
    let src = decoded.text;
    let report = check_source(&src);
    let index = LineIndex::new(&src);
    let names = |ids: &[baton_proto::front::model::Ident]| ids.iter().map(|i| i.name.clone()).collect::<Vec<_>>();
    let charts: Vec<serde_json::Value> = report
        .charts
        .iter()
        .map(|c| {
            let chart = &c.chart;
            serde_json::json!({
                "pou": chart.name.name,
                "steps": chart.steps.iter().map(|s| s.name.name.clone()).collect::<Vec<_>>(),
                "initial_steps": chart.steps.iter().filter(|s| s.initial).map(|s| s.name.name.clone()).collect::<Vec<_>>(),
                "transitions": chart.transitions.iter().map(|t| serde_json::json!({
                    "name": t.name.as_ref().map(|n| n.name.clone()),
                    "from": names(&t.from),
                    "to": names(&t.to),
                })).collect::<Vec<_>>(),
                "actions": chart.actions.iter().map(|a| a.name.name.clone()).collect::<Vec<_>>(),
            })
        })
        .collect();
    let note = decoded.note.map(|n| {
        serde_json::json!({ "severity": "warning", "file": file, "line": n.line, "col": n.col, "message": n.message })
    });
    let diagnostics: Vec<serde_json::Value> = note
        .into_iter()
        .chain(report.diagnostics.iter().map(|d| {
            let (line, col) = index.line_col(d.span.start);
            let severity = if d.is_error() { "error" } else { "warning" };
            serde_json::json!({ "severity": severity, "file": file, "line": line, "col": col, "message": d.message })
        }))
        .collect();
    println!("{}", serde_json::json!({ "charts": charts, "diagnostics": diagnostics }));
    Ok(if report.error_count() > 0 { ExitCode::from(EXIT_INVALID) } else { ExitCode::SUCCESS })
}

/// `baton export --plcopen`: the file's charts as PLCopen XML; a chart with errors exports nothing.
fn export(path: &Path, pou: Option<&str>, output: Option<&Path>) -> anyhow::Result<ExitCode> {
    let src = read_chart(path)?.text;
    let report = check_source(&src);
    print_diagnostics(path, &src, &report, |_| true);
    if report.error_count() > 0 || report.charts.is_empty() {
        eprintln!("{}: nothing was exported: the file has errors or no chart", path.display());
        return Ok(ExitCode::from(EXIT_INVALID));
    }
    let chosen: Vec<&CheckedChart> = match pou {
        Some(_) => vec![pick(&report, pou)?],
        None => report.charts.iter().collect(),
    };
    let charts: Vec<_> = chosen.iter().filter_map(|c| Some((&c.chart, c.program.as_ref()?))).collect();
    let project = path.file_stem().map_or_else(|| "baton".to_string(), |s| s.to_string_lossy().into_owned());
    let xml = baton_proto::back::plcopen::export(&charts, &report.library, &report.types, &project, &utc_now());
    match output {
        Some(file) => std::fs::write(file, xml).with_context(|| format!("cannot write {}", file.display()))?,
        None => {
            let mut out = std::io::stdout().lock();
            match out.write_all(xml.as_bytes()).and_then(|()| out.flush()) {
                Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => {}
                other => other.context("cannot write the export")?,
            }
        }
    }
    Ok(ExitCode::SUCCESS)
}

/// The current UTC time as an `xsd:dateTime` (`2026-12-01T12:34:56`).
fn utc_now() -> String {
    let secs = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.as_secs()) as i64;
    let (days, rest) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    let (year, month, day) = baton_proto::types::civil_from_days(days);
    format!("{year:04}-{month:02}-{day:02}T{:02}:{:02}:{:02}", rest / 3600, rest % 3600 / 60, rest % 60)
}

fn parse_wall_time(s: &str) -> Result<std::time::Duration, String> {
    baton_proto::testing::scenario::parse_duration(s).map(std::time::Duration::from_millis)
}

pub fn pick<'r>(report: &'r Report, pou: Option<&str>) -> anyhow::Result<&'r CheckedChart> {
    let names = || report.charts.iter().map(|c| c.chart.name.name.as_str()).collect::<Vec<_>>().join(", ");
    match pou {
        Some(name) => report
            .charts
            .iter()
            .find(|c| c.chart.name.name.eq_ignore_ascii_case(name))
            .with_context(|| format!("no chart named `{name}` in this file (it has: {})", names())),
        None => match &report.charts[..] {
            [one] => Ok(one),
            [] => bail!("no sequential function chart in this file"),
            _ => bail!("this file holds several charts ({}): choose one with --pou NAME", names()),
        },
    }
}

fn sim(
    path: &Path,
    inputs: Option<&Path>,
    cycle_ms: u64,
    until_ms: u64,
    pou: Option<&str>,
    watch: &[String],
) -> anyhow::Result<ExitCode> {
    let src = read_chart(path)?.text;
    let report = check_source(&src);
    if report.charts.is_empty() {
        print_diagnostics(path, &src, &report, |_| true);
        return Ok(ExitCode::from(EXIT_INVALID));
    }
    let chosen = pick(&report, pou)?;
    let span = chosen.chart.span;
    let inside = |at: u32| span.start <= at && at <= span.end;
    print_diagnostics(path, &src, &report, inside);
    let Some(program) = &chosen.program else {
        eprintln!("{}: chart `{}` has errors; nothing was run", path.display(), chosen.chart.name.name);
        return Ok(ExitCode::from(EXIT_INVALID));
    };
    let program = Arc::new(program.clone());
    let records = match inputs {
        Some(p) => {
            let text = read(p)?;
            parse_inputs(&text, &program).with_context(|| format!("bad input script {}", p.display()))?
        }
        None => Vec::new(),
    };
    let mut watched = Vec::with_capacity(watch.len());
    for name in watch {
        match program.var_by_name(name) {
            Some(v) => watched.push(v),
            None => anyhow::bail!("--watch {name}: chart `{}` has no variable `{name}`", program.name),
        }
    }
    let mut out = BufWriter::new(std::io::stdout().lock());
    let mut write_error = None;
    simulate_watching(program, &records, cycle_ms, until_ms, &watched, |output| match output {
        SimOutput::Trace(record) => {
            if write_error.is_none() {
                let line = serde_json::to_string(&record).map_err(std::io::Error::other);
                if let Err(e) = line.and_then(|l| writeln!(out, "{l}")) {
                    write_error = Some(e);
                }
            }
        }
        SimOutput::Fault { t_ms, message } => eprintln!("warning: t_ms={t_ms}: {message}"),
    })?;
    match write_error.map_or_else(|| out.flush(), Err) {
        // A closed pipe (`baton sim … | head`) is the reader's choice, not an error.
        Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => Ok(ExitCode::SUCCESS),
        Err(e) => Err(e).context("cannot write the trace"),
        Ok(()) => Ok(ExitCode::SUCCESS),
    }
}
