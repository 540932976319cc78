//! Finished runs' recordings (`baton console --recordings DIR`): the `.rrd` files of a folder, listed for the page
//! (`GET /api/recordings`) and streamed to its Rerun timeline (`GET /recordings/{name}`). Only a plain file name
//! ending in `.rrd` is served: nothing else of the folder, nothing outside it.

use std::path::{Path, PathBuf};

use axum::body::Body;
use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;

#[derive(serde::Serialize)]
pub struct Recording {
    name: String,
    bytes: u64,
    /// When the file was last written, in Unix ms.
    modified_unix_ms: u64,
}

/// The recordings of folder `dir`, newest first (none without `--recordings`).
pub async fn list(dir: Option<PathBuf>) -> Response {
    let Some(dir) = dir else { return Json(Vec::<Recording>::new()).into_response() };
    let found = tokio::task::spawn_blocking(move || -> std::io::Result<Vec<Recording>> {
        let mut out = Vec::new();
        for entry in std::fs::read_dir(&dir)? {
            let entry = entry?;
            let name = entry.file_name().to_string_lossy().into_owned();
            let meta = entry.metadata()?;
            if !meta.is_file() || !servable(&name) {
                continue;
            }
            let modified = meta.modified().ok().and_then(|m| m.duration_since(std::time::UNIX_EPOCH).ok());
            out.push(Recording {
                name,
                bytes: meta.len(),
                modified_unix_ms: modified.map_or(0, |d| d.as_millis() as u64),
            });
        }
        out.sort_by(|a, b| b.modified_unix_ms.cmp(&a.modified_unix_ms).then_with(|| a.name.cmp(&b.name)));
        Ok(out)
    })
    .await;
    match found {
        Ok(Ok(list)) => Json(list).into_response(),
        Ok(Err(e)) => (StatusCode::INTERNAL_SERVER_ERROR, format!("cannot list the recordings: {e}")).into_response(),
        Err(e) => (StatusCode::INTERNAL_SERVER_ERROR, e.to_string()).into_response(),
    }
}

/// Recording `name` of folder `dir`, streamed.
pub async fn file(dir: Option<&Path>, name: &str) -> Response {
    let Some(dir) = dir else {
        return (StatusCode::NOT_FOUND, "this console serves no recordings (baton console --recordings DIR)")
            .into_response();
    };
    if !servable(name) {
        return (StatusCode::NOT_FOUND, format!("`{name}` is not a recording")).into_response();
    }
    match tokio::fs::File::open(dir.join(name)).await {
        Ok(f) => {
            let length = f.metadata().await.map(|m| m.len()).ok();
            let body = Body::from_stream(tokio_util::io::ReaderStream::new(f));
            let mut response =
                ([(header::CONTENT_TYPE, "application/octet-stream"), (header::CACHE_CONTROL, "no-cache")], body)
                    .into_response();
            if let Some(n) = length {
                response.headers_mut().insert(header::CONTENT_LENGTH, n.into());
            }
            response
        }
        Err(e) => (StatusCode::NOT_FOUND, format!("no recording `{name}`: {e}")).into_response(),
    }
}

/// A plain file name (no folder, not hidden) ending in `.rrd`.
fn servable(name: &str) -> bool {
    name.ends_with(".rrd") && name.len() > 4 && !name.starts_with('.') && !name.contains(['/', '\\', '\0'])
}

#[cfg(test)]
mod tests {
    use super::servable;

    #[test]
    fn only_plain_rrd_names_are_served() {
        assert!(servable("run-1.rrd"));
        for bad in ["../secret.rrd", "a/b.rrd", ".rrd", ".hidden.rrd", "users.toml", "x.rrd/..", "a\\b.rrd"] {
            assert!(!servable(bad), "{bad}");
        }
    }
}
