//! `baton test`: runs users' scenario files (`*.test.toml`) on the simulated cell — or, with `--cluster`, on
//! real processes (`cluster.rs`) — in parallel, and says what held and what did not — with, for each failure,
//! the events around it, the trace and a Rerun recording of the failing run, and the one command that replays
//! it.
//!
//! Exit status: 0 every expectation held; 1 one failed; 2 a scenario could not run; 3 a scenario file is
//! malformed (`FILE:LINE:COL`). The highest applies.

pub mod real_processes;

use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use baton_proto::testing::coverage::Coverage;
use baton_proto::testing::junit;
use baton_proto::testing::run::{describe_record, run_until, Outcome};
use baton_proto::testing::scenario::{self, show_ms, LoadError, RunState, Scenario};

pub const EXIT_FAILED: u8 = 1;
pub const EXIT_CANNOT_RUN: u8 = 2;
pub const EXIT_MALFORMED: u8 = 3;

pub struct TestOptions {
    pub paths: Vec<PathBuf>,
    /// Run this many seeds per scenario, from its own `seed` up.
    pub seeds: Option<u64>,
    /// Run exactly this seed (the replay of a failure).
    pub seed: Option<u64>,
    pub junit: Option<PathBuf>,
    /// Where failing runs' traces and recordings go.
    pub out: PathBuf,
    pub jobs: usize,
    pub quiet: bool,
    /// Print what the scenarios exercised of each chart.
    pub coverage: bool,
    /// Stop after this much wall time; the report (and JUnit file) says what ran.
    pub timeout: Option<Duration>,
    /// Real processes on loopback, in real time, instead of the simulated cell.
    pub cluster: bool,
    /// Keep every run's trace and recording under `out`, not only failing runs'.
    pub keep: bool,
}

/// Set by SIGINT or SIGTERM: the runs stop, and what ran is reported (and written to the JUnit file).
static INTERRUPTED: AtomicBool = AtomicBool::new(false);

extern "C" fn on_signal(_: libc::c_int) {
    INTERRUPTED.store(true, Ordering::SeqCst);
}

fn catch_interrupts() {
    let handler = on_signal as extern "C" fn(libc::c_int) as libc::sighandler_t;
    // SAFETY: the handler only stores to an atomic, which is async-signal-safe.
    unsafe {
        libc::signal(libc::SIGINT, handler);
        libc::signal(libc::SIGTERM, handler);
    }
}

/// Exit status of an interrupted `baton test` (128 + SIGINT), as shells expect.
const EXIT_INTERRUPTED: u8 = 130;

/// Every `*.test.toml` under `path` (itself, when it is a file), sorted; hidden folders and `target` skipped.
fn collect(path: &Path, found: &mut Vec<PathBuf>) -> std::io::Result<()> {
    if path.is_file() {
        found.push(path.to_path_buf());
        return Ok(());
    }
    let mut entries: Vec<PathBuf> = std::fs::read_dir(path)?.filter_map(|e| e.ok().map(|e| e.path())).collect();
    entries.sort();
    for p in entries {
        let name = p.file_name().map(|n| n.to_string_lossy().to_string()).unwrap_or_default();
        if p.is_dir() {
            if !name.starts_with('.') && name != "target" {
                collect(&p, found)?;
            }
        } else if name.ends_with(".test.toml") {
            found.push(p);
        }
    }
    Ok(())
}

/// One scenario's runs, as they came back.
struct Verdict {
    path: PathBuf,
    /// Could not run, or malformed.
    problem: Option<(u8, String)>,
    scenario: Option<Arc<Scenario>>,
    outcomes: Vec<Outcome>,
    wall: Duration,
}

impl Verdict {
    /// A file that is not run: it is malformed, or cannot run (`code`), for the reason `text`.
    fn refused(path: &Path, code: u8, text: String) -> Verdict {
        Verdict {
            path: path.to_path_buf(),
            problem: Some((code, text)),
            scenario: None,
            outcomes: Vec::new(),
            wall: Duration::ZERO,
        }
    }
}

fn thousands(n: f64) -> String {
    let s = format!("{:.0}", n);
    let mut out = String::new();
    for (i, c) in s.chars().enumerate() {
        if i > 0 && (s.len() - i) % 3 == 0 {
            out.push(',');
        }
        out.push(c);
    }
    out
}

/// A run's trace (JSON Lines) and Rerun recording, under `out`: every failing run's, and with `--keep` every
/// run's.
fn keep_run(opts: &TestOptions, sc: &Scenario, o: &Outcome) -> (Option<PathBuf>, Option<PathBuf>) {
    if std::fs::create_dir_all(&opts.out).is_err() {
        return (None, None);
    }
    let stem = format!("{}-seed{}", sc.file_stem(), o.seed);
    let trace_path = opts.out.join(format!("{stem}.trace.jsonl"));
    let trace = std::fs::File::create(&trace_path).ok().and_then(|mut f| {
        for r in &o.trace {
            serde_json::to_writer(&mut f, r).ok()?;
            f.write_all(b"\n").ok()?;
        }
        Some(trace_path.clone())
    });
    let rrd_path = opts.out.join(format!("{stem}.rrd"));
    let recorded = crate::recording::RecordedRun {
        program: Arc::clone(&sc.program),
        layout: Arc::clone(&sc.layout),
        run: stem.clone(),
        started_unix_ms: 0,
    };
    let rrd = match crate::recording::Recorder::start(&crate::recording::Sink::Save(rrd_path.clone()), recorded) {
        Ok(Some(mut rec)) => {
            for r in &o.trace {
                rec.trace(r.t_ms / sc.cycle_ms, r);
            }
            rec.finish();
            Some(rrd_path)
        }
        _ => None,
    };
    (trace, rrd)
}

/// What a failure prints: expected against actual, then the events around it, where steps ran, the variables
/// and the faults in effect, and where its trace and recording are.
fn failure_report(opts: &TestOptions, sc: &Scenario, o: &Outcome) -> String {
    let mut s = String::new();
    let file = sc.path.display();
    for c in o.cases.iter().filter(|c| c.failure.is_some()) {
        s.push_str(&format!("  {file}:{}: {}\n", c.line, c.title));
        s.push_str(&format!("    {}\n", c.failure.as_deref().unwrap_or_default()));
    }
    for e in &o.errors {
        s.push_str(&format!("  {file}: could not run as written: {e}\n"));
    }
    let at = o.cases.iter().filter(|c| c.failure.is_some()).filter_map(|c| c.at_ms).min().unwrap_or(o.chart_ms);
    s.push_str(&format!("  events up to {}:\n", show_ms(at)));
    for line in o.timeline_around(at, 12) {
        s.push_str(&format!("    {line}\n"));
    }
    let (when, active) = match &o.active_at_failure {
        Some((t, a)) if *t <= at => (format!("at {}", show_ms(*t)), a.clone()),
        _ => ("at the end".to_string(), o.active.clone()),
    };
    let steps: Vec<String> =
        active.iter().map(|(step, agent)| format!("{step} ({})", agent.as_deref().unwrap_or("coordinator"))).collect();
    s.push_str(&format!(
        "  active steps {when}: {}\n",
        if steps.is_empty() { "none".into() } else { steps.join(", ") }
    ));
    let vars: Vec<String> = o.vars.iter().map(|(n, v)| format!("{n} = {v}")).collect();
    s.push_str(&format!("  variables at the end: {}\n", vars.join(", ")));
    if o.faults.is_empty() {
        s.push_str("  faults: none\n");
    } else {
        let faults: Vec<String> = o.faults.iter().map(|(t, f)| format!("{} {f}", show_ms(*t))).collect();
        s.push_str(&format!("  faults: {}\n", faults.join("; ")));
    }
    let (trace, rrd) = keep_run(opts, sc, o);
    if let Some(t) = trace {
        s.push_str(&format!("  trace: {}\n", t.display()));
    }
    if let Some(r) = rrd {
        s.push_str(&format!("  recording: rerun {}\n", r.display()));
    }
    if let Some(dir) = &o.logs {
        s.push_str(&format!("  processes' logs: {dir}\n"));
    }
    let cluster = if opts.cluster { " --cluster" } else { "" };
    s.push_str(&format!("  replay: baton test {} --seed {}{cluster}\n", sc.path.display(), o.seed));
    s
}

fn state_word(s: &RunState) -> &'static str {
    match s {
        RunState::Finished => "finished",
        RunState::Failed => "failed",
        RunState::Running => "still running",
        RunState::Stopped => "stopped",
        RunState::Aborted => "aborted",
    }
}

pub fn test(opts: &TestOptions) -> anyhow::Result<ExitCode> {
    let files = match find(opts)? {
        Ok(files) => files,
        Err(code) => return Ok(code),
    };
    // Read every file first: a malformed one is said before anything runs.
    let (mut verdicts, runnable) = load(opts, &files);
    let bins = if opts.cluster {
        match real_processes::Binaries::find() {
            Ok(b) => Some(b),
            Err(e) => {
                eprintln!("error: {e:#}");
                return Ok(ExitCode::from(EXIT_CANNOT_RUN));
            }
        }
    } else {
        None
    };
    let ran = run(opts, &verdicts, &runnable, bins.as_ref());
    report(opts, &mut verdicts, ran)
}

/// The scenario files the paths name (a folder: its `*.test.toml`, recursively), or the exit status when there are
/// none.
fn find(opts: &TestOptions) -> anyhow::Result<Result<Vec<PathBuf>, ExitCode>> {
    let mut files = Vec::new();
    let paths = if opts.paths.is_empty() { vec![PathBuf::from(".")] } else { opts.paths.clone() };
    for p in &paths {
        if !p.exists() {
            eprintln!("error: {} does not exist", p.display());
            return Ok(Err(ExitCode::from(EXIT_CANNOT_RUN)));
        }
        collect(p, &mut files).map_err(|e| anyhow::anyhow!("cannot read {}: {e}", p.display()))?;
    }
    if files.is_empty() {
        eprintln!(
            "error: no scenario (*.test.toml) in {}",
            paths.iter().map(|p| p.display().to_string()).collect::<Vec<_>>().join(", ")
        );
        return Ok(Err(ExitCode::from(EXIT_CANNOT_RUN)));
    }
    Ok(Ok(files))
}

/// Every file read and checked: a verdict each (refused ones decided already), and the scenarios that run, with
/// their first seed.
fn load(opts: &TestOptions, files: &[PathBuf]) -> (Vec<Verdict>, Vec<(usize, u64)>) {
    let mut verdicts: Vec<Verdict> = Vec::new();
    // The scenarios that run, with their first seed.
    let mut runnable: Vec<(usize, u64)> = Vec::new();
    for path in files {
        let v = match scenario::load(path, &|p| std::fs::read_to_string(p)) {
            Ok(sc) => match opts.cluster.then(|| real_processes::unsupported(&sc)).flatten() {
                Some(why) => Verdict::refused(path, EXIT_CANNOT_RUN, format!("{}: {why}", path.display())),
                None => {
                    let i = verdicts.len();
                    runnable.push((i, opts.seed.unwrap_or(sc.seed)));
                    Verdict {
                        path: path.clone(),
                        problem: None,
                        scenario: Some(Arc::new(sc)),
                        outcomes: Vec::new(),
                        wall: Duration::ZERO,
                    }
                }
            },
            Err(LoadError::Malformed(errors)) => {
                let text: Vec<String> = errors
                    .iter()
                    .map(|e| format!("{}:{}:{}: error: {}", path.display(), e.line, e.col, e.message))
                    .collect();
                Verdict::refused(path, EXIT_MALFORMED, text.join("\n"))
            }
            Err(LoadError::CannotRun(why)) => Verdict::refused(path, EXIT_CANNOT_RUN, why),
        };
        if let Some((_, text)) = &v.problem {
            eprintln!("{text}");
        }
        verdicts.push(v);
    }
    (verdicts, runnable)
}

/// What the runs gave: each scenario's outcomes with their run times, its internal errors, its coverage, and what
/// stopped the runs early, if anything did.
struct Ran {
    results: BTreeMap<usize, Vec<(Outcome, Duration)>>,
    panics: BTreeMap<usize, String>,
    coverages: BTreeMap<usize, Coverage>,
    interrupted: Option<String>,
    timed_out: bool,
}

/// Runs every (scenario, seed) on a pool of `--jobs` threads, until done, interrupted or out of time.
fn run(
    opts: &TestOptions,
    verdicts: &[Verdict],
    runnable: &[(usize, u64)],
    bins: Option<&real_processes::Binaries>,
) -> Ran {
    // Job k is the (k / scenarios)-th seed of scenario k % scenarios: every scenario's first seed, then every
    // second one…, so that stopped early each scenario has had its share; nothing is listed in advance.
    let per = if opts.seed.is_some() { 1 } else { opts.seeds.unwrap_or(1).max(1) };
    let total = (runnable.len() as u64).saturating_mul(per);
    let job = |k: u64| -> Option<(usize, u64)> {
        if k >= total {
            return None;
        }
        let (i, first) = runnable[(k % runnable.len() as u64) as usize];
        Some((i, first.wrapping_add(k / runnable.len() as u64)))
    };
    // Run every (scenario, seed) on a pool of threads; a scenario's runs are independent.
    let results: Mutex<BTreeMap<usize, Vec<(Outcome, Duration)>>> = Mutex::new(BTreeMap::new());
    let panics: Mutex<BTreeMap<usize, String>> = Mutex::new(BTreeMap::new());
    let coverages: Mutex<BTreeMap<usize, Coverage>> = Mutex::new(BTreeMap::new());
    let next = AtomicU64::new(0);
    let stop = AtomicBool::new(false);
    let finished = AtomicUsize::new(0);
    let timed_out = AtomicBool::new(false);
    let run_one = |sc: &Scenario, seed: u64, stop: &AtomicBool| match bins {
        Some(b) => real_processes::run_until(sc, seed, stop, b, &opts.out),
        None => run_until(sc, seed, stop),
    };
    catch_interrupts();
    if !opts.quiet {
        println!(
            "running {} run(s) of {} scenario(s) on {} thread(s){}",
            total,
            verdicts.iter().filter(|v| v.scenario.is_some()).count(),
            (opts.jobs.max(1) as u64).min(total.max(1)),
            if opts.cluster { ", each on real processes on loopback, in real time" } else { "" }
        );
        let _ = std::io::stdout().flush();
    }
    let started_all = Instant::now();
    let scenarios: Vec<Option<Arc<Scenario>>> = verdicts.iter().map(|v| v.scenario.clone()).collect();
    let jobs = (opts.jobs.max(1) as u64).min(total.max(1)) as usize;
    std::thread::scope(|scope| {
        // The watchdog: an interrupt or the time limit stops every run where it is.
        scope.spawn(|| watch(opts, started_all, jobs, &finished, &stop, &timed_out));
        for _ in 0..jobs {
            // Each on the stack a chart may need: whatever `baton check` accepts runs here.
            let worker = std::thread::Builder::new().stack_size(baton_proto::limits::CHART_STACK_BYTES);
            let spawned = worker.spawn_scoped(scope, || loop {
                let k = next.fetch_add(1, Ordering::Relaxed);
                let Some((i, seed)) = job(k).filter(|_| !stop.load(Ordering::Relaxed)) else {
                    finished.fetch_add(1, Ordering::Relaxed);
                    return;
                };
                let sc = scenarios[i].as_ref().expect("loaded");
                let started = Instant::now();
                match std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| run_one(sc, seed, &stop))) {
                    // A run cut short by the stop is a run not made.
                    Ok(_) if stop.load(Ordering::Relaxed) => {}
                    Ok(mut o) => {
                        if opts.coverage {
                            let c = Coverage::of(&sc.program, &o);
                            coverages.lock().expect("coverage").entry(i).or_default().add(&c);
                        }
                        if opts.keep && o.passed() {
                            keep_run(opts, sc, &o);
                        }
                        // A passing run is remembered by its verdicts and times only: a million seeds fit.
                        if o.passed() {
                            o.trace = Vec::new();
                            o.vars = Vec::new();
                            o.active = Vec::new();
                        }
                        results.lock().expect("results").entry(i).or_default().push((o, started.elapsed()))
                    }
                    Err(p) => {
                        let why = p
                            .downcast_ref::<String>()
                            .cloned()
                            .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                            .unwrap_or_else(|| "a panic".into());
                        panics.lock().expect("panics").insert(i, format!("seed {seed}: internal error: {why}"));
                    }
                }
            });
            if let Err(e) = spawned {
                // One worker fewer: the others take its runs.
                eprintln!("warning: cannot start a worker thread: {e}");
                finished.fetch_add(1, Ordering::Relaxed);
            }
        }
    });
    let interrupted: Option<String> = if timed_out.load(Ordering::Relaxed) {
        Some(format!("the time limit of {}", show_ms(opts.timeout.unwrap_or_default().as_millis() as u64)))
    } else if stop.load(Ordering::Relaxed) {
        Some("an interrupt".to_string())
    } else {
        None
    };
    Ran {
        results: results.into_inner().expect("results"),
        panics: panics.into_inner().expect("panics"),
        coverages: coverages.into_inner().expect("coverage"),
        interrupted,
        timed_out: timed_out.load(Ordering::Relaxed),
    }
}

/// Until every worker has finished: stops the runs on an interrupt, or once the time limit is up.
fn watch(
    opts: &TestOptions,
    started_all: Instant,
    jobs: usize,
    finished: &AtomicUsize,
    stop: &AtomicBool,
    timed_out: &AtomicBool,
) {
    while finished.load(Ordering::Relaxed) < jobs {
        if INTERRUPTED.load(Ordering::Relaxed) {
            stop.store(true, Ordering::Relaxed);
            return;
        }
        if opts.timeout.is_some_and(|t| started_all.elapsed() >= t) {
            timed_out.store(true, Ordering::Relaxed);
            stop.store(true, Ordering::Relaxed);
            return;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Says each scenario's verdict (and writes the JUnit file): the exit status is the worst of them.
fn report(opts: &TestOptions, verdicts: &mut [Verdict], ran: Ran) -> anyhow::Result<ExitCode> {
    let Ran { mut results, panics, coverages, interrupted, timed_out } = ran;
    let mut code = 0u8;
    let mut suites = Vec::new();
    let (mut passed_n, mut failed_n) = (0usize, 0usize);
    for (i, v) in verdicts.iter_mut().enumerate() {
        let (c, suite, passed) = verdict(opts, v, results.remove(&i).unwrap_or_default(), panics.get(&i), &interrupted);
        code = code.max(c);
        suites.push(suite);
        match passed {
            Some(true) => passed_n += 1,
            Some(false) => failed_n += 1,
            None => {}
        }
    }
    if opts.coverage {
        print!("{}", coverage_report(verdicts, &coverages));
    }
    let count = |c: u8| verdicts.iter().filter(|v| v.problem.as_ref().is_some_and(|p| p.0 == c)).count();
    let (malformed, cannot) = (count(EXIT_MALFORMED), count(EXIT_CANNOT_RUN) + panics.len());
    let mut total = format!("{} scenario(s): {passed_n} passed, {failed_n} failed", verdicts.len());
    if cannot > 0 {
        total.push_str(&format!(", {cannot} could not run"));
    }
    if malformed > 0 {
        total.push_str(&format!(", {malformed} malformed"));
    }
    if let Some(why) = &interrupted {
        total.push_str(&format!(" — stopped by {why}: runs not made are not counted"));
        code = code.max(if timed_out { EXIT_CANNOT_RUN } else { EXIT_INTERRUPTED });
    }
    println!("{total}");
    if let Some(path) = &opts.junit {
        std::fs::write(path, junit::write(&suites, interrupted.as_deref()))
            .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", path.display()))?;
    }
    Ok(ExitCode::from(code))
}

/// One scenario's verdict from its runs: the exit status it asks for, its JUnit suite, and whether it passed
/// (`None`: it did not run, or could not).
fn verdict(
    opts: &TestOptions,
    v: &mut Verdict,
    mut runs: Vec<(Outcome, Duration)>,
    panic: Option<&String>,
    interrupted: &Option<String>,
) -> (u8, junit::Suite, Option<bool>) {
    let mut code = 0u8;
    let file = v.path.display().to_string();
    if let Some((c, text)) = &v.problem {
        code = code.max(*c);
        return (code, junit::Suite::error(&file, &file, 0.0, text), None);
    }
    let sc = v.scenario.clone().expect("loaded");
    if let (Some(why), true) = (interrupted, runs.is_empty()) {
        code = code.max(EXIT_CANNOT_RUN);
        let text = format!("not run: stopped by {why}");
        println!("ERROR {} ({file}): {text}", sc.name);
        return (code, junit::Suite::error(&sc.name, &file, 0.0, &text), None);
    }
    runs.sort_by_key(|(o, _)| o.seed);
    // The runs' own times, summed (they run side by side on `--jobs` threads): "run time", not wall time.
    v.wall = runs.iter().map(|(_, w)| *w).sum();
    v.outcomes = runs.into_iter().map(|(o, _)| o).collect();
    if let Some(why) = panic {
        code = code.max(EXIT_CANNOT_RUN);
        println!("ERROR {} ({file}): could not run: {why}", sc.name);
        return (code, junit::Suite::error(&sc.name, &file, v.wall.as_secs_f64(), why), None);
    }
    let failing: Vec<&Outcome> = v.outcomes.iter().filter(|o| !o.passed()).collect();
    let chart_ms: u64 = v.outcomes.iter().map(|o| o.chart_ms).sum();
    let wall_ms = v.wall.as_secs_f64() * 1000.0;
    let speed = if opts.cluster {
        "real time".to_string()
    } else if wall_ms > 0.0 {
        format!("{}× faster", thousands(chart_ms as f64 / wall_ms))
    } else {
        "∞× faster".into()
    };
    let seeds = v.outcomes.len();
    let seeds_text = if seeds == 1 { format!("seed {}", v.outcomes[0].seed) } else { format!("{seeds} seeds") };
    let chart_text = if seeds == 1 {
        format!("chart {} ({})", show_ms(chart_ms), state_word(&v.outcomes[0].state))
    } else {
        let lo = v.outcomes.iter().map(|o| o.chart_ms).min().unwrap_or(0);
        let hi = v.outcomes.iter().map(|o| o.chart_ms).max().unwrap_or(0);
        format!("chart {}–{} each", show_ms(lo), show_ms(hi))
    };
    let cases = sc.expects.len();
    let mut system_out = String::new();
    if failing.is_empty() {
        if !opts.quiet {
            println!(
                "PASS {} ({file}): {cases} expectation(s), {seeds_text}, {chart_text} in {:.0} ms of run time ({speed})",
                sc.name, wall_ms
            );
        }
    } else {
        let errors = failing.iter().any(|o| !o.errors.is_empty());
        code = code.max(if errors { EXIT_CANNOT_RUN } else { EXIT_FAILED });
        let seeds_failing: Vec<String> = failing.iter().take(10).map(|o| o.seed.to_string()).collect();
        println!(
            "FAIL {} ({file}): {} of {seeds} run(s) failed (seed {}{}), {chart_text} in {:.0} ms of run time",
            sc.name,
            failing.len(),
            seeds_failing.join(", "),
            if failing.len() > 10 { ", …" } else { "" },
            wall_ms
        );
        let first = failing[0];
        let report = failure_report(opts, &sc, first);
        print!("{report}");
        system_out = format!("seed {}\n{report}\ntimeline:\n", first.seed);
        for r in &first.trace {
            system_out.push_str(&describe_record(r));
            system_out.push('\n');
        }
    }
    // One test case per expectation: failed when it failed under any seed (the first such seed's message).
    let cases: Vec<junit::Case> = sc
        .expects
        .iter()
        .enumerate()
        .map(|(k, e)| {
            let failure =
                v.outcomes.iter().find_map(|o| o.cases[k].failure.as_ref().map(|f| format!("seed {}: {f}", o.seed)));
            junit::Case { name: e.title(), line: e.line, failure }
        })
        .collect();
    let error = failing.iter().find(|o| !o.errors.is_empty()).map(|o| o.errors.join("\n"));
    let suite = junit::Suite { name: sc.name.clone(), file, time_s: v.wall.as_secs_f64(), error, cases, system_out };
    (code, suite, Some(failing.is_empty()))
}

/// Per chart: what each scenario of it exercised (over all its seeds), what they all did together, and which
/// steps each fault struck.
fn coverage_report(verdicts: &[Verdict], coverages: &BTreeMap<usize, Coverage>) -> String {
    let mut charts: BTreeMap<PathBuf, Vec<(&Verdict, Coverage)>> = BTreeMap::new();
    for (i, v) in verdicts.iter().enumerate() {
        let Some(sc) = &v.scenario else { continue };
        let c = coverages.get(&i).cloned().unwrap_or_default();
        let chart = std::fs::canonicalize(&sc.chart_path).unwrap_or_else(|_| sc.chart_path.clone());
        charts.entry(chart).or_default().push((v, c));
    }
    let mut s = String::new();
    for (chart, scenarios) in &charts {
        let program = &scenarios[0].0.scenario.as_ref().expect("loaded").program;
        s.push_str(&format!("coverage of chart `{}` ({}):\n", program.name, chart.display()));
        let mut total = Coverage::default();
        for (v, c) in scenarios {
            let name = &v.scenario.as_ref().expect("loaded").name;
            s.push_str(&format!("  {name}: {}\n", c.summary(program)));
            total.add(c);
        }
        s.push_str(&format!("  all {} scenario(s): {}\n", scenarios.len(), total.summary(program)));
        for (v, c) in scenarios {
            let name = &v.scenario.as_ref().expect("loaded").name;
            let mut by_fault: BTreeMap<&str, Vec<&str>> = BTreeMap::new();
            for (fault, step) in &c.fault_hits {
                by_fault.entry(fault).or_default().push(step);
            }
            for (fault, steps) in by_fault {
                s.push_str(&format!("  fault `{fault}` ({name}) struck: {}\n", steps.join(", ")));
            }
        }
    }
    s
}
