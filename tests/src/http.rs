//! The little of HTTP/1.1 the tests speak to `baton console`: one request, its status and body (chunked or not).

use tokio::io::{AsyncReadExt, AsyncWriteExt};

use crate::loopback::TIMEOUT;

/// One HTTP/1.1 exchange with a server at `addr` (`127.0.0.1:PORT`): (status, body).
pub async fn http(addr: &str, method: &str, path: &str, body: Option<&str>) -> (u16, String) {
    let mut stream = tokio::net::TcpStream::connect(addr).await.expect("connect to the console");
    let body = body.unwrap_or("");
    let request = format!(
        "{method} {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\nContent-Type: application/json\r\n\
         Content-Length: {}\r\n\r\n{body}",
        body.len()
    );
    stream.write_all(request.as_bytes()).await.expect("send");
    let mut answer = Vec::new();
    tokio::time::timeout(TIMEOUT, stream.read_to_end(&mut answer)).await.expect("an answer in time").expect("read");
    let answer = String::from_utf8_lossy(&answer).to_string();
    let (head, rest) = answer.split_once("\r\n\r\n").expect("a head and a body");
    let status = head.split(' ').nth(1).and_then(|s| s.parse().ok()).expect("a status");
    // Chunked bodies (axum's for some answers): their chunks joined.
    let body =
        if head.to_ascii_lowercase().contains("transfer-encoding: chunked") { unchunk(rest) } else { rest.to_string() };
    (status, body)
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
