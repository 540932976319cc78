//! The Rerun timeline in the console's page: Rerun's web viewer of the version Baton records with
//! (`re_web_viewer_server` carries it built: the wasm and its wasm-bindgen script), served from the console's own
//! origin behind its logins, with a page of ours around it (`viewer.html`) that the console's page frames and
//! drives. Their paths carry the version, so that a browser keeps the 40 MB of wasm until Baton's Rerun changes.

use std::sync::OnceLock;

use axum::body::Bytes;
use axum::http::{header, StatusCode};
use axum::response::{IntoResponse, Response};
use re_web_viewer_server::WebViewerData;

pub const VIEWER_PAGE: &str = "/rerun/0.36.3/viewer.html";
pub const VIEWER_JS: &str = "/rerun/0.36.3/re_viewer.js";
pub const VIEWER_WASM: &str = "/rerun/0.36.3/re_viewer_bg.wasm";

/// The frame around the viewer.
const PAGE: &str = include_str!("viewer.html");

/// A file whose path names its version does not change: the browser keeps it.
const FOREVER: &str = "public, max-age=31536000, immutable";

/// The viewer's files, embedded in this binary (the error, a build without them).
fn viewer() -> Result<&'static WebViewerData, &'static str> {
    static DATA: OnceLock<Result<WebViewerData, String>> = OnceLock::new();
    DATA.get_or_init(|| WebViewerData::load(None).map_err(|e| format!("the Rerun viewer is not in this build: {e}")))
        .as_ref()
        .map_err(String::as_str)
}

/// One of the viewer's files, of `kind`, which the browser keeps.
fn asset(kind: &'static str, bytes: impl Fn(&'static WebViewerData) -> &'static [u8]) -> Response {
    match viewer() {
        Ok(v) => ([(header::CONTENT_TYPE, kind), (header::CACHE_CONTROL, FOREVER)], Bytes::from_static(bytes(v)))
            .into_response(),
        Err(e) => (StatusCode::INTERNAL_SERVER_ERROR, e).into_response(),
    }
}

pub async fn page() -> impl IntoResponse {
    ([(header::CONTENT_TYPE, "text/html; charset=utf-8"), (header::CACHE_CONTROL, "no-cache")], PAGE)
}

pub async fn script() -> Response {
    asset("text/javascript", WebViewerData::viewer_js)
}

pub async fn wasm() -> Response {
    asset("application/wasm", WebViewerData::viewer_wasm)
}
