//! A host's state, shared by its main loop and the Zenoh callbacks that take a run's messages.
//!
//! A run's messages (a coordinator's reports, variable updates and device reports; an agent's commands and variable
//! updates) are handled in the callback Zenoh calls on the thread that read them off the link, under the host's
//! lock: decoded, fed to the state machine, and what it asks for published, before the callback returns (or, if
//! another thread holds the state, by that thread before it lets go: the callback only queues it). Handing
//! each sample through a channel to the main loop instead woke a second thread per message, and on a loaded machine
//! a wake-up is most of a message's cost: on this project's two-core VM, 30–50 µs of a 280 µs round trip at each
//! end (`docs/book/src/benchmarks.md`, issue 36). The main loop keeps what is not a run's message — queries, timers,
//! skills' events, signals — and takes the same lock.
//!
//! Rules that come with it:
//! - A message's handling never waits on anything but a put (which waits only while its link's queue is full, as a
//!   put from the main loop always did): no query, no sleep, no `.await`, no lock but the host's own.
//! - Subscribers whose callback takes the lock accept only remote samples (`Locality::Remote`): a put made under
//!   the lock that matched the process's own subscriber would be delivered to it on the same thread, inside the
//!   lock.
//! - What a callback spawns or the timers it makes belong to the host's own runtime (it enters the runtime's
//!   context), never to Zenoh's.
//! - A callback that makes the main loop's next deadline earlier says so (`handle`'s closure returns `true`), and
//!   the main loop looks at its deadline again (`rearmed`).

use std::collections::VecDeque;
use std::ops::{Deref, DerefMut};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};

use baton_proto::limits::RECEIVE_QUEUE_MAX;
use tokio::runtime::Handle;
use tokio::sync::Notify;

/// A message's handling, waiting for the state: it returns whether the deadline may have become earlier.
type Job<S> = Box<dyn FnOnce(&mut S) -> bool + Send>;

pub struct Shared<S> {
    /// `None` once the main loop took the state back (`take`): callbacks still under way then do nothing.
    state: Mutex<Option<S>>,
    /// Messages not handled yet, in the order they came. A callback queues its message and, if nobody holds the
    /// state, takes it and handles the queue; if somebody does, it returns at once and the holder handles it when it
    /// lets go (the main loop, woken for it, only if the holder spent its budget): a callback never sleeps on the
    /// lock while its link has more to read (a sleep and a wake-up on every contended message cost the coordinator a
    /// fifth of its throughput), and the main loop is not woken for messages a callback can handle (issue 36). At most
    /// `RECEIVE_QUEUE_MAX`; a callback that finds it full waits for the state.
    queued: Mutex<VecDeque<Job<S>>>,
    /// The main loop waits for the state: callbacks leave their messages queued for it, and a callback handling the
    /// queue stops after the message under way, so that a steady stream of messages on Zenoh's threads cannot keep
    /// the main loop (timers, queries, commands) from the state — at 10,000 tokens a second, one did for 100–400 ms,
    /// long enough for agents to send their reports again.
    main_waits: AtomicBool,
    rearm: Notify,
    runtime: Handle,
}

impl<S: Send + 'static> Shared<S> {
    /// `state`, shared; called in the runtime the host's main loop runs on.
    pub fn new(state: S) -> Arc<Shared<S>> {
        Arc::new(Shared {
            state: Mutex::new(Some(state)),
            queued: Mutex::new(VecDeque::new()),
            main_waits: AtomicBool::new(false),
            rearm: Notify::new(),
            runtime: Handle::current(),
        })
    }

    /// The state, for the main loop, with what had come before it took the state handled first. A poisoned lock
    /// means a callback panicked, a bug: the host stops with it.
    pub fn lock(&self) -> anyhow::Result<Held<'_, S>> {
        self.main_waits.store(true, Ordering::SeqCst);
        let guard = self.state.lock();
        self.main_waits.store(false, Ordering::SeqCst);
        let mut guard = guard.map_err(|_| broken())?;
        if guard.is_none() {
            anyhow::bail!("the host's state was taken back");
        }
        let waiting = self.queued_len();
        if self.run_queued(&mut guard, waiting, false).1 {
            self.rearm.notify_one();
        }
        Ok(Held { shared: self, guard: Some(guard) })
    }

    /// The state back, for the main loop once it is done: a callback Zenoh is still running (its subscriber
    /// undeclared) finds nothing to do, and what was queued is dropped with the run it was for.
    pub fn take(&self) -> anyhow::Result<S> {
        let mut guard = self.state.lock().map_err(|_| broken())?;
        if let Ok(mut queued) = self.queued.lock() {
            queued.clear();
        }
        guard.take().ok_or_else(|| anyhow::anyhow!("the host's state was taken back already"))
    }

    /// Handles `input` with `f` in a Zenoh callback, in the host's runtime context; `f` returns whether the main
    /// loop's deadline may have become earlier. The message joins the queue; if nobody holds the state, this
    /// callback takes it and handles the queue (`COMBINE_MAX` messages at most, and none once the main loop waits);
    /// if somebody does, the callback returns at once and the holder handles it. After a panic in an earlier
    /// callback, nothing runs: the main loop reports it.
    pub fn handle<T: Send + 'static>(&self, input: T, f: impl FnOnce(&mut S, T) -> bool + Send + 'static) {
        self.submit(input, f);
    }

    /// As `handle`, for a message whose handling does not depend on the order of the others and that a later one
    /// repeats (the journal's "more is durable"), from a thread with work of its own, which it never holds up: if the
    /// state is free, this message alone is handled (the queue stays for the callbacks and the main loop, so that
    /// the journal's writer does not handle reports while commits wait); if it is held, the message is queued for
    /// the holder, and the main loop is woken in case the holder let go before it was queued.
    pub fn handle_alone<T: Send + 'static>(&self, input: T, f: impl FnOnce(&mut S, T) -> bool + Send + 'static) {
        let _context = self.runtime.enter();
        if !self.main_waits.load(Ordering::SeqCst) {
            if let Ok(mut guard) = self.state.try_lock() {
                let earlier = guard.as_mut().is_some_and(|state| f(state, input));
                self.let_go(guard, earlier);
                return;
            }
        }
        if let Ok(mut queued) = self.queued.lock() {
            if queued.len() < RECEIVE_QUEUE_MAX {
                queued.push_back(Box::new(move |state| f(state, input)));
            }
        }
        self.rearm.notify_one();
    }

    fn submit<T: Send + 'static>(&self, input: T, f: impl FnOnce(&mut S, T) -> bool + Send + 'static) {
        let _context = self.runtime.enter();
        let job: Job<S> = Box::new(move |state| f(state, input));
        let full = match self.queued.lock() {
            Ok(mut queued) if queued.len() < RECEIVE_QUEUE_MAX => {
                queued.push_back(job);
                None
            }
            Ok(_) => Some(job),
            Err(_) => return,
        };
        if let Some(job) = full {
            // The queue is full: this callback waits for the state, handles what came before its message (its own
            // thread's earlier ones among them), then its own.
            if let Ok(mut guard) = self.state.lock() {
                let waiting = self.queued_len();
                let mut earlier = self.run_queued(&mut guard, waiting, false).1;
                if let Some(state) = guard.as_mut() {
                    earlier |= job(state);
                }
                self.hand_on(guard, earlier);
            }
            return;
        }
        self.combine(COMBINE_MAX);
    }

    /// Takes the state while it is free and messages wait, and handles them, `budget` at most in all. Whoever
    /// lets go of the state looks at the queue after, so a message queued while the state was held is handled by
    /// the holder, or by the next callback to come; the main loop is woken for it only once the budget is spent
    /// (a callback busy with other links' messages is not reading its own). None is handled once the main loop
    /// waits for the state: it handles the queue first.
    fn combine(&self, mut budget: usize) {
        while budget > 0 && !self.main_waits.load(Ordering::SeqCst) {
            // Held: its holder looks at the queue when it lets go.
            let Ok(mut guard) = self.state.try_lock() else { return };
            let (handled, earlier) = self.run_queued(&mut guard, budget, true);
            budget -= handled;
            drop(guard);
            if earlier {
                self.rearm.notify_one();
            }
            if self.queued_len() == 0 {
                return;
            }
        }
        if self.queued_len() > 0 && !self.main_waits.load(Ordering::SeqCst) {
            self.rearm.notify_one();
        }
    }

    fn queued_len(&self) -> usize {
        self.queued.lock().map_or(0, |q| q.len())
    }

    /// Handles at most `max` queued messages, in order — none more once the main loop waits, if `yielding`;
    /// how many it handled, and whether one made the deadline earlier.
    fn run_queued(&self, state: &mut Option<S>, max: usize, yielding: bool) -> (usize, bool) {
        let mut earlier = false;
        for handled in 0..max {
            if yielding && self.main_waits.load(Ordering::SeqCst) {
                return (handled, earlier);
            }
            let next = self.queued.lock().ok().and_then(|mut q| q.pop_front());
            let Some(job) = next else { return (handled, earlier) };
            if let Some(state) = state.as_mut() {
                earlier |= job(state);
            }
        }
        (max, earlier)
    }

    /// Lets go of the state and handles what came meanwhile (`combine`): a callback that found the state held
    /// has queued its message by the time the holder looks.
    fn hand_on(&self, guard: MutexGuard<'_, Option<S>>, earlier: bool) {
        drop(guard);
        if earlier {
            self.rearm.notify_one();
        }
        self.combine(COMBINE_MAX);
    }

    /// Lets go of the state, for a thread that does not handle others' messages (the journal's writer). A message
    /// still queued (it came while the state was held) is the main loop's to handle, woken for it, unless it waits
    /// for the state already — or a callback that comes meanwhile finds the state free and handles the queue first.
    /// Looked at after letting go, so that a callback that found the state held has queued its message by then.
    fn let_go(&self, guard: MutexGuard<'_, Option<S>>, earlier: bool) {
        drop(guard);
        let left = self.queued_len() > 0 && !self.main_waits.load(Ordering::SeqCst);
        if earlier || left {
            self.rearm.notify_one();
        }
    }

    /// Completes when a callback made the deadline earlier, or left messages for the main loop to handle, since
    /// the main loop last looked (at once if one did while the main loop was busy).
    pub async fn rearmed(&self) {
        self.rearm.notified().await
    }
}

/// The most queued messages a callback handles in all, taking the state again while more came, before it leaves
/// the rest to the main loop (or the next callback): a callback busy with other links' messages is not reading its
/// own.
const COMBINE_MAX: usize = 64;

fn broken() -> anyhow::Error {
    anyhow::anyhow!("the host's state was left broken by a panic")
}

/// The main loop's hold on the state (`Shared::lock`). What came meanwhile is handled when it lets go.
pub struct Held<'a, S: Send + 'static> {
    shared: &'a Shared<S>,
    guard: Option<MutexGuard<'a, Option<S>>>,
}

impl<S: Send + 'static> Deref for Held<'_, S> {
    type Target = S;
    fn deref(&self) -> &S {
        self.guard.as_ref().and_then(|g| g.as_ref()).expect("`lock` hands out only a state that is there")
    }
}

impl<S: Send + 'static> DerefMut for Held<'_, S> {
    fn deref_mut(&mut self) -> &mut S {
        self.guard.as_mut().and_then(|g| g.as_mut()).expect("`lock` hands out only a state that is there")
    }
}

impl<S: Send + 'static> Drop for Held<'_, S> {
    fn drop(&mut self) {
        if let Some(mut guard) = self.guard.take() {
            let waiting = self.shared.queued_len();
            let earlier = self.shared.run_queued(&mut guard, waiting, false).1;
            self.shared.hand_on(guard, earlier);
        }
    }
}

/// Whether deadline `a` comes before `b`, `None` being never.
pub fn earlier<T: Ord>(a: Option<T>, b: Option<T>) -> bool {
    match (a, b) {
        (Some(a), Some(b)) => a < b,
        (Some(_), None) => true,
        (None, _) => false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn never_is_after_every_deadline() {
        assert!(earlier(Some(1), Some(2)));
        assert!(!earlier(Some(2), Some(2)));
        assert!(earlier(Some(5), None));
        assert!(!earlier(None, Some(5)));
        assert!(!earlier::<u8>(None, None));
    }

    /// Callbacks on four threads and a main loop taking the state between them: every message is handled once,
    /// each thread's in the order it came (a message queued while another thread held the state is handled by that
    /// holder, or by the next to take the state — never left behind).
    #[test]
    fn contended_messages_are_each_handled_once_in_their_threads_order() {
        let runtime = tokio::runtime::Builder::new_multi_thread().worker_threads(1).build().expect("a runtime");
        let shared = runtime.block_on(async { Shared::new(Vec::<(u32, u32)>::new()) });
        const PER_THREAD: u32 = 20_000;
        let threads: Vec<_> = (0..4)
            .map(|t| {
                let s = Arc::clone(&shared);
                std::thread::spawn(move || {
                    for i in 0..PER_THREAD {
                        s.handle((t, i), |v, m| {
                            v.push(m);
                            false
                        });
                    }
                })
            })
            .collect();
        while threads.iter().any(|t| !t.is_finished()) {
            drop(shared.lock().expect("lock"));
        }
        for t in threads {
            t.join().expect("a callback's thread");
        }
        // What the last callbacks left queued is the main loop's (they woke it for it).
        drop(shared.lock().expect("lock"));
        let handled = shared.take().expect("taken");
        assert_eq!(handled.len(), 4 * PER_THREAD as usize, "some messages were lost or handled twice");
        for t in 0..4 {
            let order: Vec<u32> = handled.iter().filter(|m| m.0 == t).map(|m| m.1).collect();
            assert_eq!(order, (0..PER_THREAD).collect::<Vec<_>>(), "thread {t}'s messages out of order");
        }
    }

    /// Messages that come while the main loop holds the state do not wait for a callback's thread: they are queued
    /// at once, and handled, in order, when the main loop lets go.
    #[test]
    fn messages_that_come_while_the_main_loop_holds_the_state_are_handled_when_it_lets_go() {
        let runtime = tokio::runtime::Builder::new_multi_thread().worker_threads(1).build().expect("a runtime");
        let shared = runtime.block_on(async { Shared::new(Vec::<u32>::new()) });
        let held = shared.lock().expect("lock");
        let s = Arc::clone(&shared);
        std::thread::spawn(move || {
            for i in 0..3 {
                s.handle(i, |v, x| {
                    v.push(x);
                    false
                });
            }
        })
        .join()
        .expect("the callbacks returned while the state was held");
        assert!(held.is_empty(), "a message was handled while the main loop held the state");
        drop(held);
        assert_eq!(shared.take().expect("taken"), vec![0, 1, 2]);
    }

    /// A message that comes while another callback holds the state is handled by that callback when it lets go,
    /// not left for the main loop: the main loop is not woken for it.
    #[tokio::test(flavor = "multi_thread", worker_threads = 1)]
    async fn a_message_queued_behind_a_callback_is_handled_by_it_without_waking_the_main_loop() {
        let shared = Shared::new(Vec::<u32>::new());
        let (queued_tx, queued_rx) = std::sync::mpsc::channel::<()>();
        let (holding_tx, holding_rx) = std::sync::mpsc::channel::<()>();
        let s = Arc::clone(&shared);
        let holder = std::thread::spawn(move || {
            s.handle(1, move |v, x| {
                holding_tx.send(()).expect("the test waits");
                // Held until the other callback has queued its message.
                queued_rx.recv().expect("the other callback returned");
                v.push(x);
                false
            })
        });
        holding_rx.recv().expect("the first callback holds the state");
        // It returns while the state is held.
        callback_on_a_thread(&shared, 2, false);
        queued_tx.send(()).expect("the holder waits");
        holder.join().expect("the holder's thread");
        assert_eq!(shared.queued_len(), 0, "the holder left a message queued");
        assert!(!woken(&shared).await, "the main loop was woken for a message the holder could handle");
        assert_eq!(shared.take().expect("taken"), vec![1, 2]);
    }

    /// The journal writer's "more is durable" (`handle_alone`): with the state free it is handled at once and alone
    /// (what callbacks queued stays theirs); with the state held it is left for the holder, never lost.
    #[test]
    fn a_message_handled_alone_runs_at_once_or_is_left_for_the_holder() {
        let runtime = tokio::runtime::Builder::new_multi_thread().worker_threads(1).build().expect("a runtime");
        let shared = runtime.block_on(async { Shared::new(Vec::<u32>::new()) });
        shared.handle_alone(1, |v, x| {
            v.push(x);
            false
        });
        assert_eq!(*shared.lock().expect("lock"), vec![1], "handled at once with the state free");
        let held = shared.lock().expect("lock");
        let s = Arc::clone(&shared);
        std::thread::spawn(move || {
            s.handle_alone(2, |v, x| {
                v.push(x);
                false
            })
        })
        .join()
        .expect("it returned while the state was held");
        assert_eq!(*held, vec![1]);
        drop(held);
        assert_eq!(shared.take().expect("taken"), vec![1, 2]);
    }

    /// A Zenoh callback, on a thread of its own, that pushes `x` and says whether it made the deadline `earlier`;
    /// returns once the callback did.
    fn callback_on_a_thread(shared: &Arc<Shared<Vec<u32>>>, x: u32, earlier: bool) {
        let s = Arc::clone(shared);
        std::thread::spawn(move || {
            s.handle(x, move |v, x| {
                v.push(x);
                earlier
            })
        })
        .join()
        .expect("the callback's thread");
    }

    /// Whether the main loop would wake now: the callbacks have all returned, so a wake-up is there already or
    /// never comes.
    async fn woken<S: Send + 'static>(shared: &Shared<S>) -> bool {
        tokio::select! {
            biased;
            () = shared.rearmed() => true,
            () = std::future::ready(()) => false,
        }
    }

    /// A callback on another thread that makes the deadline earlier wakes the main loop, even when it does so
    /// before the main loop waits; one that does not, does not.
    #[tokio::test(flavor = "multi_thread", worker_threads = 1)]
    async fn a_callback_that_moves_the_deadline_earlier_wakes_the_main_loop() {
        let shared = Shared::new(Vec::<u32>::new());
        callback_on_a_thread(&shared, 7, true);
        assert!(woken(&shared).await, "a callback that moved the deadline earlier did not wake the main loop");
        assert_eq!(*shared.lock().expect("lock"), vec![7]);
        callback_on_a_thread(&shared, 8, false);
        assert!(!woken(&shared).await, "a callback that left the deadline as it was woke the main loop");
        assert_eq!(*shared.lock().expect("lock"), vec![7, 8]);
        // Taken back, the state is no longer the callbacks' to change.
        assert_eq!(shared.take().expect("taken"), vec![7, 8]);
        shared.handle(9, |v, x| {
            v.push(x);
            true
        });
        assert!(!woken(&shared).await, "a callback after the state was taken back did something");
        assert!(shared.lock().is_err() && shared.take().is_err());
    }
}
