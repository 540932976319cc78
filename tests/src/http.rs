//! The little of HTTP/1.1 the tests speak to `baton console` — one request, its status and body (chunked or not),
//! over TLS too, keeping a login's cookie — its server-sent events, and the browser its page is tested in.

use tokio::io::{AsyncReadExt, AsyncWriteExt};

use crate::loopback::TIMEOUT;

/// One HTTP/1.1 exchange with a server at `addr` (`127.0.0.1:PORT`): (status, body).
pub async fn http(addr: &str, method: &str, path: &str, body: Option<&str>) -> (u16, String) {
    Client::plain(addr).send(method, path, body).await
}

/// A client of one console, over plain HTTP or HTTPS trusting a CA, which keeps the session cookie a login set.
pub struct Client {
    addr: String,
    tls: Option<tokio_rustls::TlsConnector>,
    cookie: Option<String>,
}

impl Client {
    pub fn plain(addr: &str) -> Client {
        Client { addr: addr.to_string(), tls: None, cookie: None }
    }

    /// HTTPS, trusting only the certificates `ca` (PEM) signed, the server's name checked against its address.
    pub fn tls(addr: &str, ca: &std::path::Path) -> Client {
        use rustls_pki_types::pem::PemObject;
        let mut roots = tokio_rustls::rustls::RootCertStore::empty();
        for cert in rustls_pki_types::CertificateDer::pem_file_iter(ca).expect("the CA") {
            roots.add(cert.expect("a certificate")).expect("a CA certificate");
        }
        let provider = std::sync::Arc::new(tokio_rustls::rustls::crypto::ring::default_provider());
        let config = tokio_rustls::rustls::ClientConfig::builder_with_provider(provider)
            .with_safe_default_protocol_versions()
            .expect("TLS versions")
            .with_root_certificates(roots)
            .with_no_client_auth();
        Client { addr: addr.to_string(), tls: Some(std::sync::Arc::new(config).into()), cookie: None }
    }

    /// One request: (status, body). A `Set-Cookie` in the answer is kept and sent from then on.
    pub async fn send(&mut self, method: &str, path: &str, body: Option<&str>) -> (u16, String) {
        let tcp = tokio::net::TcpStream::connect(&self.addr).await.expect("connect to the console");
        let (status, cookie, body) = match &self.tls {
            Some(connector) => {
                let host = self.addr.rsplit_once(':').map_or(self.addr.as_str(), |(h, _)| h).to_string();
                let name = rustls_pki_types::ServerName::try_from(host).expect("a server name");
                let tls = connector.connect(name, tcp).await.expect("a TLS handshake the CA vouches for");
                exchange(tls, &self.addr, method, path, body, self.cookie.as_deref()).await
            }
            None => exchange(tcp, &self.addr, method, path, body, self.cookie.as_deref()).await,
        };
        if let Some(c) = cookie {
            self.cookie = Some(c);
        }
        (status, body)
    }
}

/// One exchange on `stream`: (status, the cookie a `Set-Cookie` sets, body).
async fn exchange<S: tokio::io::AsyncRead + tokio::io::AsyncWrite + Unpin>(
    mut stream: S,
    addr: &str,
    method: &str,
    path: &str,
    body: Option<&str>,
    cookie: Option<&str>,
) -> (u16, Option<String>, String) {
    let body = body.unwrap_or("");
    let cookie = cookie.map(|c| format!("Cookie: {c}\r\n")).unwrap_or_default();
    let request = format!(
        "{method} {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\nContent-Type: application/json\r\n\
         {cookie}Content-Length: {}\r\n\r\n{body}",
        body.len()
    );
    stream.write_all(request.as_bytes()).await.expect("send");
    let mut answer = Vec::new();
    // A TLS peer may close without its close_notify once the answer is whole: what was read is the answer.
    let _ = tokio::time::timeout(TIMEOUT, stream.read_to_end(&mut answer)).await.expect("an answer in time");
    let answer = String::from_utf8_lossy(&answer).to_string();
    let (head, rest) = answer.split_once("\r\n\r\n").expect("a head and a body");
    let status = head.split(' ').nth(1).and_then(|s| s.parse().ok()).expect("a status");
    let set = head
        .lines()
        .filter_map(|l| l.split_once(':'))
        .find(|(k, _)| k.eq_ignore_ascii_case("set-cookie"))
        .and_then(|(_, v)| v.trim().split(';').next().map(str::to_string));
    // Chunked bodies (axum's for some answers): their chunks joined.
    let body =
        if head.to_ascii_lowercase().contains("transfer-encoding: chunked") { unchunk(rest) } else { rest.to_string() };
    (status, set, body)
}

fn unchunk(mut rest: &str) -> String {
    let mut out = String::new();
    while let Some((size, after)) = rest.split_once("\r\n") {
        let Ok(n) = usize::from_str_radix(size.trim(), 16) else { break };
        if n == 0 {
            break;
        }
        out.push_str(&after[..n]);
        rest = &after[n + 2..];
    }
    out
}

/// A page's server-sent events (`GET /api/events`), one at a time.
pub struct Events {
    lines: tokio::io::Lines<tokio::io::BufReader<tokio::net::TcpStream>>,
}

impl Events {
    pub async fn open(addr: &str) -> Events {
        use tokio::io::AsyncBufReadExt;
        let mut stream = tokio::net::TcpStream::connect(addr).await.expect("connect to the console");
        let request = format!("GET /api/events HTTP/1.1\r\nHost: {addr}\r\nAccept: text/event-stream\r\n\r\n");
        stream.write_all(request.as_bytes()).await.expect("send");
        Events { lines: tokio::io::BufReader::new(stream).lines() }
    }

    /// The next event, (name, data); none once the stream ended or after `TIMEOUT` without one.
    pub async fn next(&mut self) -> Option<(String, String)> {
        let mut name = String::new();
        let next = async {
            while let Ok(Some(line)) = self.lines.next_line().await {
                if let Some(n) = line.strip_prefix("event: ") {
                    name = n.to_string();
                } else if let Some(data) = line.strip_prefix("data: ") {
                    return Some((std::mem::take(&mut name), data.to_string()));
                }
            }
            None
        };
        tokio::time::timeout(TIMEOUT, next).await.ok().flatten()
    }
}

/// The browser, its WebDriver and Selenium's bindings, or why the test cannot run here.
pub fn require_browser() {
    for file in ["/usr/bin/chromium", "/usr/bin/chromedriver"] {
        if !std::path::Path::new(file).is_file() {
            crate::missing(&format!("{file} is absent: .ci/run installs Debian's chromium and chromium-driver"));
        }
    }
    crate::peer::require_python("selenium", "selenium");
}

/// `baton console --connect ENDPOINT` with `args`, on a free loopback port: its process and the address it said it
/// serves on (`127.0.0.1:PORT`).
pub async fn console(endpoint: &str, args: &[&str]) -> (tokio::process::Child, String) {
    use tokio::io::AsyncBufReadExt;
    let mut console = tokio::process::Command::new(crate::loopback::bin("baton"))
        .args(["console", "--connect", endpoint, "--listen", "127.0.0.1:0"])
        .args(args)
        .stdout(std::process::Stdio::piped())
        .kill_on_drop(true)
        .spawn()
        .expect("start baton console");
    let mut said = tokio::io::BufReader::new(console.stdout.take().expect("piped")).lines();
    let line = tokio::time::timeout(TIMEOUT, said.next_line()).await.expect("the console says where").expect("read");
    let line = line.expect("a line");
    let addr = line.split("://").nth(1).and_then(|r| r.split('/').next()).expect("an address").to_string();
    (console, addr)
}

/// Drives the page of the console at `addr` in the browser (`tests/scripts/console_browser.py http://ADDR/ ARGS…`)
/// to the script's end: each line it printed, as JSON. A script that fails fails the test, with what it said.
pub async fn browse(addr: &str, args: &[&str]) -> Vec<serde_json::Value> {
    browse_for(addr, args, TIMEOUT * 2).await
}

/// `browse`, for a script that may take up to `limit` (Rerun's viewer, drawn in software, takes its time).
pub async fn browse_for(addr: &str, args: &[&str], limit: std::time::Duration) -> Vec<serde_json::Value> {
    let out = tokio::process::Command::new("python3")
        .arg(crate::loopback::repo("tests/scripts/console_browser.py"))
        .arg(format!("http://{addr}/"))
        .args(args)
        .kill_on_drop(true)
        .output();
    let out = tokio::time::timeout(limit, out).await.expect("the browser finished in time").expect("python3");
    let said = String::from_utf8_lossy(&out.stdout).to_string();
    assert!(out.status.success(), "{said}\n{}", String::from_utf8_lossy(&out.stderr));
    said.lines().map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("`{l}`: {e}"))).collect()
}
