//! What the commands share: their exit statuses, how they reach a running coordinator (`Reach`), the runtime an
//! async command runs on (`block_on`), and diagnostics printed against a chart's lines.

use std::io::Write;
use std::path::Path;
use std::process::ExitCode;

use anyhow::Context;
use baton_proto::front::diag::LineIndex;
use baton_proto::pipeline::Report;

/// Exit status of `baton check` and `baton sim` when the chart has errors.
pub(super) const EXIT_INVALID: u8 = 1;

/// Exit status for usage and I/O errors (clap uses it too).
pub(super) const EXIT_USAGE: u8 = 2;

/// Exit status of `baton run` when an operator stopped the run (`baton ctl stop`, an interrupt).
pub(super) const EXIT_STOPPED: u8 = 3;

/// Exit status of `baton run` when an operator aborted the run (`baton ctl abort`, a second interrupt).
pub(super) const EXIT_ABORTED: u8 = 4;

/// Exit status of `baton run` when SIGTERM took the process away from a journaled run, which its journal resumes
/// (`deploy/systemd/baton-run@.service` counts it a clean stop).
pub(super) const EXIT_LEFT: u8 = 5;

/// Where a one-shot client (`set`, `status`, `ctl`) reaches a cell: its router, and the Zenoh configuration a
/// secured one asks for.
#[derive(clap::Args)]
pub struct Reach {
    /// The router to reach: the coordinator's `--listen` endpoint or the cell's router, such as
    /// tcp/127.0.0.1:7447 or tls/router.cell4.local:7447 (repeat for several).
    #[arg(long, value_name = "ENDPOINT", required = true)]
    pub connect: Vec<String>,
    /// A Zenoh configuration file (TLS, credentials…).
    #[arg(long, value_name = "FILE")]
    pub zenoh_config: Option<std::path::PathBuf>,
}

/// Zenoh needs the multi-thread runtime (its blocking calls panic inside a current-thread one).
pub(super) fn block_on(fut: impl std::future::Future<Output = anyhow::Result<ExitCode>>) -> anyhow::Result<ExitCode> {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(1)
        .thread_stack_size(baton_proto::limits::CHART_STACK_BYTES)
        .enable_all()
        .build()
        .context("cannot start the runtime")?;
    runtime.block_on(fut)
}

pub(super) fn print_diagnostics(path: &Path, src: &str, report: &Report, keep: impl Fn(u32) -> bool) {
    let index = LineIndex::new(src);
    let shown = path.display().to_string();
    let mut err = std::io::stderr().lock();
    for d in report.diagnostics.iter().filter(|d| keep(d.span.start)) {
        let _ = write!(err, "{}", index.render(&shown, d));
    }
}
