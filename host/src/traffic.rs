//! Every Zenoh message a Baton process sends goes out through here: subscriptions, queryables, publishers and their
//! puts, gets and replies, liveliness tokens, queries and subscriptions. Nowhere else calls Zenoh's declarations,
//! gets or replies (`tests/tests/tidy.rs`, `every_zenoh_message_goes_through_traffic`), so that what each process
//! sends can be listed — and a router's access control (`baton deploy acl`) checked against the list.
//!
//! With `BATON_TRAFFIC=FILE` in its environment, a process appends each kind of message it sends on each key to FILE
//! (once per kind and key: `put baton/run/…/report/robot1`), by the names a Zenoh access control rule gives them.
//! `tests/tests/deploying.rs` reads those lists back from a cell behind the generated rules.

use std::collections::BTreeSet;
use std::io::Write;
use std::sync::{Mutex, OnceLock};

use zenoh::handlers::DefaultHandler;
use zenoh::liveliness::{LivelinessGetBuilder, LivelinessSubscriberBuilder, LivelinessTokenBuilder};
use zenoh::pubsub::{PublisherBuilder, SubscriberBuilder};
use zenoh::query::{Query, QueryableBuilder};
use zenoh::session::SessionGetBuilder;
use zenoh::Session;

/// What a process sends, as a Zenoh access control rule names it (`messages`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum Message {
    Put,
    Query,
    Reply,
    DeclareSubscriber,
    DeclareQueryable,
    LivelinessToken,
    LivelinessQuery,
    DeclareLivelinessSubscriber,
}

impl Message {
    pub const ALL: [Message; 8] = [
        Message::Put,
        Message::Query,
        Message::Reply,
        Message::DeclareSubscriber,
        Message::DeclareQueryable,
        Message::LivelinessToken,
        Message::LivelinessQuery,
        Message::DeclareLivelinessSubscriber,
    ];

    /// The name a Zenoh access control rule gives it.
    pub fn name(self) -> &'static str {
        match self {
            Message::Put => "put",
            Message::Query => "query",
            Message::Reply => "reply",
            Message::DeclareSubscriber => "declare_subscriber",
            Message::DeclareQueryable => "declare_queryable",
            Message::LivelinessToken => "liveliness_token",
            Message::LivelinessQuery => "liveliness_query",
            Message::DeclareLivelinessSubscriber => "declare_liveliness_subscriber",
        }
    }

    pub fn from_name(name: &str) -> Option<Message> {
        Message::ALL.into_iter().find(|m| m.name() == name)
    }
}

/// Where the list goes, and what it holds already.
struct Log {
    file: std::fs::File,
    seen: BTreeSet<(Message, String)>,
}

fn log() -> Option<&'static Mutex<Log>> {
    static LOG: OnceLock<Option<Mutex<Log>>> = OnceLock::new();
    LOG.get_or_init(|| {
        let path = std::env::var_os("BATON_TRAFFIC")?;
        let file = std::fs::OpenOptions::new().create(true).append(true).open(&path);
        match file {
            Ok(file) => Some(Mutex::new(Log { file, seen: BTreeSet::new() })),
            Err(e) => {
                eprintln!("warning: BATON_TRAFFIC: cannot open {}: {e}", std::path::Path::new(&path).display());
                None
            }
        }
    })
    .as_ref()
}

/// Notes that this process sends `message` on `key` (only with `BATON_TRAFFIC`).
pub fn note(message: Message, key: &str) {
    let Some(log) = log() else { return };
    let Ok(mut log) = log.lock() else { return };
    if log.seen.insert((message, key.to_string())) {
        let _ = writeln!(log.file, "{} {key}", message.name());
    }
}

pub fn subscriber(session: &Session, key: String) -> SubscriberBuilder<'_, 'static, DefaultHandler> {
    note(Message::DeclareSubscriber, &key);
    session.declare_subscriber(key)
}

pub fn queryable(session: &Session, key: String) -> QueryableBuilder<'_, 'static, DefaultHandler> {
    note(Message::DeclareQueryable, &key);
    session.declare_queryable(key)
}

/// A publisher: every put through it is on its key.
pub fn publisher(session: &Session, key: String) -> PublisherBuilder<'_, 'static> {
    note(Message::Put, &key);
    session.declare_publisher(key)
}

pub fn get(session: &Session, key: String) -> SessionGetBuilder<'_, 'static, DefaultHandler> {
    note(Message::Query, &key);
    session.get(key)
}

pub fn token(session: &Session, key: String) -> LivelinessTokenBuilder<'_, 'static> {
    note(Message::LivelinessToken, &key);
    session.liveliness().declare_token(key)
}

pub fn liveliness_get(session: &Session, key: String) -> LivelinessGetBuilder<'_, 'static, DefaultHandler> {
    note(Message::LivelinessQuery, &key);
    session.liveliness().get(key)
}

pub fn liveliness_subscriber(
    session: &Session,
    key: String,
) -> LivelinessSubscriberBuilder<'_, 'static, DefaultHandler> {
    note(Message::DeclareLivelinessSubscriber, &key);
    session.liveliness().declare_subscriber(key)
}

/// Answers `query` on `key` (at once: Zenoh's asynchronous reply resolves at once in the same way).
pub fn reply(query: &Query, key: String, payload: Vec<u8>) -> zenoh::Result<()> {
    use zenoh::Wait;
    note(Message::Reply, &key);
    query.reply(key, payload).wait()
}
