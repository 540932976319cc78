//! The harness of the test binaries whose tests need something outside the repository — a peer Baton did not
//! write (a ROS 2 or OPC UA server, the PLCopen schema, the Rerun SDK, mdBook), the shared corpus, or root for a
//! network namespace. They run on libtest-mimic, so that a test whose prerequisite is missing shows as
//! *ignored, with its reason* — not as a pass that printed SKIPPED — while under CI (`CI` set), where
//! everything is installed, the same absence fails the test.
//!
//! A test says what it lacks with [`missing`], wherever it finds out; the binary's `main` is
//! [`harness_main!`](crate::harness_main), listing its tests as `sync name` or `tokio name` (an `async fn`, run
//! on a multi-thread runtime as `#[tokio::test(flavor = "multi_thread")]` runs it).

use std::future::Future;
use std::panic::{catch_unwind, resume_unwind, AssertUnwindSafe};

use libtest_mimic::{Arguments, Completion, Failed, Trial};

/// What [`missing`] unwinds with: the reason the test cannot run here.
struct Skip(String);

/// A test's prerequisite is missing: under CI (`CI` set) the test fails; elsewhere it ends here and is reported
/// as ignored, with `why`. (Unwinding with `resume_unwind` does not run the panic hook: nothing is printed.)
pub fn missing(why: &str) -> ! {
    assert!(std::env::var_os("CI").is_none(), "cannot run under CI: {why}");
    unavailable(why)
}

/// A test's input cannot be had on this machine, CI included: a file that `.ci/run` cannot install, because no
/// registry CI reaches serves it (a chart from a public repository that is not in the shared corpus). The test
/// is reported as ignored with `why`, which says how to provide it — under CI too: nothing CI does could make it
/// run, and what it checks is covered by tests on inputs CI has.
pub fn unavailable(why: &str) -> ! {
    resume_unwind(Box::new(Skip(why.to_string())))
}

/// An optional part of a test cannot be checked here: under CI (`CI` set) the test fails; elsewhere it goes on
/// without that part, and says so.
pub fn not_checked(why: &str) {
    assert!(std::env::var_os("CI").is_none(), "cannot run under CI: {why}");
    eprintln!("not checked here: {why}");
}

/// Runs `body`: a [`missing`] prerequisite makes it ignored with the reason, a panic makes it fail with the
/// panic's message.
fn outcome(body: impl FnOnce()) -> Result<Completion, Failed> {
    match catch_unwind(AssertUnwindSafe(body)) {
        Ok(()) => Ok(Completion::Completed),
        Err(payload) => match payload.downcast::<Skip>() {
            Ok(skip) => Ok(Completion::ignored_with(skip.0)),
            Err(payload) => {
                let message = payload
                    .downcast_ref::<String>()
                    .cloned()
                    .or_else(|| payload.downcast_ref::<&str>().map(|s| s.to_string()))
                    .unwrap_or_else(|| "the test panicked".to_string());
                Err(Failed::from(message))
            }
        },
    }
}

/// A plain test.
pub fn sync(name: &str, test: fn()) -> Trial {
    Trial::ignorable_test(name, move || outcome(test))
}

/// An `async fn` test, on a multi-thread Tokio runtime of its own.
pub fn tokio<F>(name: &str, test: fn() -> F) -> Trial
where
    F: Future<Output = ()> + 'static,
{
    Trial::ignorable_test(name, move || {
        outcome(|| {
            let runtime = tokio::runtime::Builder::new_multi_thread().enable_all().build().expect("a Tokio runtime");
            runtime.block_on(test())
        })
    })
}

/// Runs the trials as `cargo test` runs tests (filters, `--list`, `--include-ignored`, threads).
pub fn run(trials: Vec<Trial>) -> ! {
    libtest_mimic::run(&Arguments::from_args(), trials).exit()
}

/// The `main` of a test binary on this harness: `harness_main!(sync a_test, tokio an_async_test);`.
#[macro_export]
macro_rules! harness_main {
    ($($kind:ident $name:ident),* $(,)?) => {
        fn main() {
            $crate::harness::run(vec![$($crate::harness::$kind(stringify!($name), $name)),*])
        }
    };
}
