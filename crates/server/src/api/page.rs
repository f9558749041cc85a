//! The page at `/` (SPEC §8): a search and browse interface written against the same
//! public API a client uses. Its files are compiled into the binary, so it works offline and
//! needs no build step; the hand-written WebGL view keeps it free of JavaScript libraries.

use axum::extract::Path;
use axum::http::{header, HeaderValue};
use axum::response::{IntoResponse, Response};

use super::error::AppError;

/// The page's files: name, media type, contents.
const FILES: &[(&str, &str, &str)] = &[
    (
        "app.js",
        "text/javascript; charset=utf-8",
        include_str!("page/app.js"),
    ),
    (
        "view.js",
        "text/javascript; charset=utf-8",
        include_str!("page/view.js"),
    ),
    (
        "style.css",
        "text/css; charset=utf-8",
        include_str!("page/style.css"),
    ),
];

/// Only the page's own scripts, styles and API; images from object URLs (an image that needs
/// the API key is fetched with it and shown from a `blob:`).
const POLICY: &str = "default-src 'self'; img-src 'self' blob: data:; connect-src 'self'; \
    style-src 'self'; script-src 'self'; object-src 'none'; base-uri 'none'; \
    frame-ancestors 'none'";

fn serve(media_type: &'static str, body: &'static str) -> Response {
    (
        [
            (header::CONTENT_TYPE, HeaderValue::from_static(media_type)),
            (
                header::CONTENT_SECURITY_POLICY,
                HeaderValue::from_static(POLICY),
            ),
            (
                header::X_CONTENT_TYPE_OPTIONS,
                HeaderValue::from_static("nosniff"),
            ),
            // A new binary may bring a new page: revalidate rather than run an old script.
            (header::CACHE_CONTROL, HeaderValue::from_static("no-cache")),
        ],
        body,
    )
        .into_response()
}

/// `GET /`.
pub async fn index() -> Response {
    serve("text/html; charset=utf-8", include_str!("page/index.html"))
}

/// `GET /page/{file}`.
pub async fn file(Path(name): Path<String>) -> Result<Response, AppError> {
    FILES
        .iter()
        .find(|(n, _, _)| *n == name)
        .map(|&(_, media_type, body)| serve(media_type, body))
        .ok_or_else(|| AppError::NotFound(format!("no page file {name:?}")))
}
