//! Who is at the console. Without a users' file (a console on loopback) nobody logs in and the page may do
//! everything; with one, a user logs in with name and password (`POST /api/login`) and gets a session cookie
//! (`HttpOnly`, `SameSite=Strict`, `Secure` over TLS, for a shift), and every other API request needs it. Failed
//! logins are traced; a name that fails `LOCKOUT_FAILURES` times in a row waits `LOCKOUT` before it may try again.
//! The console's own trace (`baton console --trace FILE`) records logins, refused logins and refused commands, one
//! JSON record per line as the coordinator's trace, `t_ms` in Unix time.

use std::collections::BTreeMap;
use std::io::Write;
use std::path::Path;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use anyhow::Context;
use axum::extract::{Request, State};
use axum::http::{header, HeaderMap, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use axum::Json;
use baton_proto::exec::trace::{TraceEvent, TraceRecord};

use super::users::{Role, Users};

/// How long a session lasts: a shift.
const SESSION_TTL: Duration = Duration::from_secs(12 * 3600);
const COOKIE: &str = "baton_session";
/// Failed logins in a row after which a name waits.
const LOCKOUT_FAILURES: u32 = 5;
const LOCKOUT: Duration = Duration::from_secs(60);
/// Sessions kept at most; the oldest go first.
const SESSIONS_MAX: usize = 1024;

/// Who sends a request: the user logged in (none where nobody logs in) and the role.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Who {
    pub user: Option<String>,
    pub role: Role,
}

struct Session {
    who: Who,
    until: Instant,
}

pub struct Auth {
    users: Option<Users>,
    /// Over TLS: cookies are `Secure`.
    tls: bool,
    sessions: Mutex<BTreeMap<String, Session>>,
    failures: Mutex<BTreeMap<String, (u32, Instant)>>,
    trace: Mutex<Option<std::io::BufWriter<std::fs::File>>>,
}

impl Auth {
    pub fn new(users: Option<Users>, tls: bool, trace: Option<&Path>) -> anyhow::Result<Auth> {
        let trace = match trace {
            Some(path) => Some(std::io::BufWriter::new(
                std::fs::OpenOptions::new()
                    .create(true)
                    .append(true)
                    .open(path)
                    .with_context(|| format!("cannot write the console's trace {}", path.display()))?,
            )),
            None => None,
        };
        Ok(Auth { users, tls, sessions: Mutex::default(), failures: Mutex::default(), trace: Mutex::new(trace) })
    }

    pub fn needs_login(&self) -> bool {
        self.users.is_some()
    }

    /// Writes a record to the console's trace, if it keeps one.
    pub fn trace(&self, event: TraceEvent, name: &str, by: Option<String>, message: String) {
        let Ok(mut trace) = self.trace.lock() else { return };
        let Some(w) = trace.as_mut() else { return };
        let mut rec = TraceRecord::new(baton_host::unix_ms(), event, name);
        rec.by = by;
        rec.message = Some(message);
        let line = serde_json::to_string(&rec).unwrap_or_default();
        if let Err(e) = writeln!(w, "{line}").and_then(|()| w.flush()) {
            eprintln!("warning: cannot write the console's trace: {e}");
        }
    }

    /// The session a request's cookie names, if it is live.
    fn session(&self, headers: &HeaderMap) -> Option<Who> {
        let token = cookie(headers)?;
        let mut sessions = self.sessions.lock().ok()?;
        match sessions.get(&token) {
            Some(s) if s.until > Instant::now() => Some(s.who.clone()),
            Some(_) => {
                sessions.remove(&token);
                None
            }
            None => None,
        }
    }

    /// Who a request comes from: anyone may do everything where nobody logs in; else the session's user.
    pub fn who(&self, headers: &HeaderMap) -> Option<Who> {
        if self.users.is_none() {
            return Some(Who { user: None, role: Role::Maintenance });
        }
        self.session(headers)
    }

    /// How long name `name` still waits after failed logins, if it does.
    fn locked(&self, name: &str) -> Option<Duration> {
        let failures = self.failures.lock().ok()?;
        let (count, last) = failures.get(name)?;
        let left = LOCKOUT.saturating_sub(last.elapsed());
        (*count >= LOCKOUT_FAILURES && !left.is_zero()).then_some(left)
    }

    fn failed(&self, name: &str) {
        if let Ok(mut failures) = self.failures.lock() {
            let entry = failures.entry(name.to_string()).or_insert((0, Instant::now()));
            // A lockout served starts the count again.
            if entry.0 >= LOCKOUT_FAILURES {
                entry.0 = 0;
            }
            *entry = (entry.0 + 1, Instant::now());
        }
    }

    fn open_session(&self, who: Who) -> String {
        let token = format!("{}{}", uuid::Uuid::new_v4().simple(), uuid::Uuid::new_v4().simple());
        if let Ok(mut sessions) = self.sessions.lock() {
            let now = Instant::now();
            sessions.retain(|_, s| s.until > now);
            if sessions.len() >= SESSIONS_MAX {
                let oldest = sessions.iter().min_by_key(|(_, s)| s.until).map(|(t, _)| t.clone());
                if let Some(t) = oldest {
                    sessions.remove(&t);
                }
            }
            sessions.insert(token.clone(), Session { who, until: now + SESSION_TTL });
        }
        token
    }
}

fn cookie(headers: &HeaderMap) -> Option<String> {
    headers
        .get_all(header::COOKIE)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(';'))
        .filter_map(|kv| kv.trim().split_once('='))
        .find(|(k, _)| *k == COOKIE)
        .map(|(_, v)| v.to_string())
}

#[derive(serde::Deserialize)]
pub struct Login {
    user: String,
    password: String,
}

/// `POST /api/login` `{"user", "password"}`: a session cookie and `{"user", "role"}`; 401 saying so for a wrong
/// name or password (which of the two is not said), 429 while the name waits after failed logins.
pub async fn login(State(auth): State<Arc<Auth>>, Json(login): Json<Login>) -> Response {
    if !auth.needs_login() {
        return (StatusCode::NOT_FOUND, "this console has no users: nobody logs in").into_response();
    }
    if let Some(left) = auth.locked(&login.user) {
        let why = format!("too many failed logins: `{}` may try again in {} s", login.user, left.as_secs() + 1);
        auth.trace(TraceEvent::LoginRefused, &login.user, None, why.clone());
        return (StatusCode::TOO_MANY_REQUESTS, why).into_response();
    }
    let checking = Arc::clone(&auth);
    let (name, password) = (login.user.clone(), login.password);
    // Argon2 takes its time on purpose: off the server's threads.
    let role = tokio::task::spawn_blocking(move || checking.users.as_ref().and_then(|u| u.check(&name, &password)))
        .await
        .ok()
        .flatten();
    let Some(role) = role else {
        auth.failed(&login.user);
        auth.trace(TraceEvent::LoginRefused, &login.user, None, "wrong user name or password".into());
        return (StatusCode::UNAUTHORIZED, "wrong user name or password").into_response();
    };
    if let Ok(mut failures) = auth.failures.lock() {
        failures.remove(&login.user);
    }
    auth.trace(TraceEvent::Login, &login.user, None, role.name().to_string());
    let who = Who { user: Some(login.user), role };
    let token = auth.open_session(who.clone());
    let secure = if auth.tls { "; Secure" } else { "" };
    let set = format!("{COOKIE}={token}; Path=/; HttpOnly; SameSite=Strict; Max-Age={}{secure}", SESSION_TTL.as_secs());
    ([(header::SET_COOKIE, set)], Json(who)).into_response()
}

/// `POST /api/logout`: the session ends.
pub async fn logout(State(auth): State<Arc<Auth>>, headers: HeaderMap) -> Response {
    if let (Some(token), Ok(mut sessions)) = (cookie(&headers), auth.sessions.lock()) {
        sessions.remove(&token);
    }
    let gone = format!("{COOKIE}=; Path=/; HttpOnly; SameSite=Strict; Max-Age=0");
    ([(header::SET_COOKIE, gone)], StatusCode::NO_CONTENT).into_response()
}

/// `GET /api/me`: `{"login": BOOL, "user", "role"}` — whether this console has users, and who this page is (401
/// while nobody is logged in on a console with users).
pub async fn me(State(auth): State<Arc<Auth>>, headers: HeaderMap) -> Response {
    let login = auth.needs_login();
    match auth.who(&headers) {
        Some(who) => Json(serde_json::json!({"login": login, "user": who.user, "role": who.role})).into_response(),
        None => (StatusCode::UNAUTHORIZED, Json(serde_json::json!({"login": login}))).into_response(),
    }
}

/// Every API request but logging in needs a session where users log in: 401 without one. The request carries
/// `Who` for the handlers.
pub async fn require(State(auth): State<Arc<Auth>>, mut request: Request, next: Next) -> Response {
    match auth.who(request.headers()) {
        Some(who) => {
            request.extensions_mut().insert(who);
            next.run(request).await
        }
        None => (StatusCode::UNAUTHORIZED, "log in first (POST /api/login)").into_response(),
    }
}
