//! One error type for every HTTP failure, ours or axum's, with one JSON shape:
//! `{"error": {"code": "…", "message": "…"}}` (SPEC §8; axum's `examples/error-handling`).
//!
//! An internal error's detail (a sled error, a corrupt signature, a path) is logged in the
//! request's span, whose `request_id` is the `x-request-id` the client got; the response
//! says only what happened in general terms.

use axum::extract::multipart::MultipartError;
use axum::extract::rejection::{BytesRejection, JsonRejection, PathRejection, QueryRejection};
use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::Json;
use serde::Serialize;

use super::evidence::DuplicateMatch;
use crate::model::InvalidId;
use crate::spool::CollectError;
use crate::store::StoreError;

/// Everything a request can fail with.
#[derive(Debug, thiserror::Error)]
pub enum AppError {
    /// Malformed request: parameters, JSON, ids, a mesh file that does not parse.
    #[error("{message}")]
    BadRequest { code: &'static str, message: String },
    /// No API key, or one that is not valid.
    #[error("{0}")]
    Unauthorized(String),
    /// A valid key whose scope is too small.
    #[error("{0}")]
    Forbidden(String),
    #[error("{0}")]
    NotFound(String),
    /// The model exists but lacks what the request needs (a descriptor from a newer format).
    #[error("{0}")]
    Conflict(String),
    /// The operation needs what this service was not set up with (a backup folder).
    #[error("{0}")]
    NotConfigured(String),
    /// The upload duplicates a stored model, and the client asked to reject duplicates.
    #[error("the upload duplicates model {:?} ({})", .0.id, .0.evidence)]
    Duplicate(DuplicateMatch),
    #[error("{0}")]
    PayloadTooLarge(String),
    #[error("{0}")]
    UnsupportedMediaType(String),
    /// A well-formed mesh that cannot be used (no triangles, degenerate, …).
    #[error("{0}")]
    Unprocessable(String),
    /// A file of a kind or with a feature salient does not read; the message says how to
    /// convert it.
    #[error("{0}")]
    UnsupportedFeature(String),
    /// The key made more requests than its rate allows: retry later.
    #[error("too many requests with this API key; retry in {retry_after_secs} s")]
    RateLimited { retry_after_secs: u64 },
    /// The extraction queue is full: retry later.
    #[error("the extraction queue is full; retry in {retry_after_secs} s")]
    Overloaded { retry_after_secs: u64 },
    #[error("extraction did not finish within {0} s")]
    Timeout(u64),
    /// The store cannot be reached now (a database restarting): retry. The text is for the
    /// log only.
    #[error("store unavailable: {0}")]
    StoreUnavailable(String),
    /// This replica has not applied the change a request waits for (`Salient-Position`) in
    /// time: retry.
    #[error("this replica has not yet applied change {0}; retry in {RETRY_BEHIND_SECS} s")]
    Behind(u64),
    /// Our fault. The text is for the log only.
    #[error("internal error: {0}")]
    Internal(String),
}

/// What a client is told of an internal error.
const INTERNAL_MESSAGE: &str =
    "internal error; the server log has the details under this response's x-request-id";

/// How long a client is told to wait before it retries when the store is unavailable.
const RETRY_STORE_SECS: u64 = 2;
/// … and when this replica is behind the position it asked for.
const RETRY_BEHIND_SECS: u64 = 1;

/// The JSON body of every error response.
#[derive(Debug, Serialize, serde::Deserialize, utoipa::ToSchema)]
pub struct ErrorBody {
    pub error: ErrorDetail,
}

#[derive(Debug, Serialize, serde::Deserialize, utoipa::ToSchema)]
pub struct ErrorDetail {
    /// Stable machine-readable code, e.g. `unsupported_format`.
    pub code: String,
    pub message: String,
    /// With `duplicate`: the stored model the upload duplicates.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub duplicate: Option<DuplicateMatch>,
}

impl AppError {
    /// The ranking index failed: the store a first stage in the database reads (its own
    /// error), or the shelf (`rank::shelf`), by its kind only, since an I/O error's text may
    /// name a file.
    pub fn index(e: std::io::Error) -> Self {
        match e.downcast::<StoreError>() {
            Ok(e) => AppError::from(e),
            Err(e) => AppError::Internal(format!("ranking index shelf: {}", e.kind())),
        }
    }

    pub fn bad_request(code: &'static str, message: impl Into<String>) -> Self {
        AppError::BadRequest {
            code,
            message: message.into(),
        }
    }

    /// The message a client may see: the error itself, except for internal ones.
    pub fn public_message(&self) -> String {
        match self {
            AppError::Internal(_) => INTERNAL_MESSAGE.to_string(),
            AppError::StoreUnavailable(_) => format!(
                "the store cannot be reached now; retry in {RETRY_STORE_SECS} s (what needs only this replica's memory still answers: with the in-memory index, rankings too)"
            ),
            other => other.to_string(),
        }
    }

    fn status_and_code(&self) -> (StatusCode, &'static str) {
        match self {
            AppError::BadRequest { code, .. } => (StatusCode::BAD_REQUEST, code),
            AppError::Unauthorized(_) => (StatusCode::UNAUTHORIZED, "unauthorized"),
            AppError::Forbidden(_) => (StatusCode::FORBIDDEN, "forbidden"),
            AppError::NotFound(_) => (StatusCode::NOT_FOUND, "not_found"),
            AppError::Conflict(_) => (StatusCode::CONFLICT, "missing_descriptor"),
            AppError::Duplicate(_) => (StatusCode::CONFLICT, "duplicate"),
            AppError::NotConfigured(_) => (StatusCode::CONFLICT, "not_configured"),
            AppError::PayloadTooLarge(_) => (StatusCode::PAYLOAD_TOO_LARGE, "payload_too_large"),
            AppError::UnsupportedMediaType(_) => {
                (StatusCode::UNSUPPORTED_MEDIA_TYPE, "unsupported_format")
            }
            AppError::Unprocessable(_) => (StatusCode::UNPROCESSABLE_ENTITY, "unusable_mesh"),
            AppError::UnsupportedFeature(_) => {
                (StatusCode::UNPROCESSABLE_ENTITY, "unsupported_mesh_feature")
            }
            AppError::RateLimited { .. } => (StatusCode::TOO_MANY_REQUESTS, "rate_limited"),
            AppError::Overloaded { .. } => (StatusCode::SERVICE_UNAVAILABLE, "overloaded"),
            AppError::Timeout(_) => (StatusCode::SERVICE_UNAVAILABLE, "timeout"),
            AppError::StoreUnavailable(_) => (StatusCode::SERVICE_UNAVAILABLE, "store_unavailable"),
            AppError::Behind(_) => (StatusCode::SERVICE_UNAVAILABLE, "behind"),
            AppError::Internal(_) => (StatusCode::INTERNAL_SERVER_ERROR, "internal"),
        }
    }
}

impl IntoResponse for AppError {
    fn into_response(self) -> Response {
        let (status, code) = self.status_and_code();
        if status.is_server_error() {
            tracing::error!(%status, error = %self, "request failed");
        }
        let body = Json(ErrorBody {
            error: ErrorDetail {
                code: code.to_string(),
                message: self.public_message(),
                duplicate: match &self {
                    AppError::Duplicate(found) => Some(found.clone()),
                    _ => None,
                },
            },
        });
        let retry_after = match &self {
            AppError::Overloaded { retry_after_secs }
            | AppError::RateLimited { retry_after_secs } => Some(*retry_after_secs),
            AppError::StoreUnavailable(_) => Some(RETRY_STORE_SECS),
            AppError::Behind(_) => Some(RETRY_BEHIND_SECS),
            _ => None,
        };
        let mut response = match self {
            AppError::Unauthorized(_) => (
                status,
                [(header::WWW_AUTHENTICATE, "Bearer realm=\"salient\"")],
                body,
            )
                .into_response(),
            _ => (status, body).into_response(),
        };
        if let Some(secs) = retry_after {
            response
                .headers_mut()
                .insert(header::RETRY_AFTER, HeaderValue::from(secs));
        }
        response
    }
}

/// Library errors: which are the client's fault and how (SPEC §8 statuses).
impl From<salient_core::Error> for AppError {
    fn from(e: salient_core::Error) -> Self {
        use salient_core::Error as E;
        match e {
            E::UnknownFormat(_) => AppError::UnsupportedMediaType(e.to_string()),
            E::Unsupported { .. } => AppError::UnsupportedFeature(e.to_string()),
            E::TooLarge { what, .. } => {
                AppError::PayloadTooLarge(format!("{e}: {}", limit_of(what)))
            }
            E::DecodesTooLarge(_) => AppError::PayloadTooLarge(format!(
                "{e}: {} and {}",
                limit_of("vertices"),
                limit_of("triangles")
            )),
            E::NoTriangles
            | E::OnlyDegenerate { .. }
            | E::TooFewVertices { .. }
            | E::NoFeatures
            | E::ExtentOutOfRange { .. } => AppError::Unprocessable(e.to_string()),
            E::Parse { .. }
            | E::IndexOutOfRange { .. }
            | E::NonFinite { .. }
            | E::MissingResource { .. }
            | E::Archive(_) => AppError::bad_request("bad_mesh", e.to_string()),
            E::InvalidParameter { .. } => AppError::bad_request("invalid_parameter", e.to_string()),
            E::Io { .. }
            | E::Labels { .. }
            | E::Manifest { .. }
            | E::Report { .. }
            | E::CorruptSignature { .. }
            | E::SignatureFormat { .. } => AppError::Internal(e.to_string()),
        }
    }
}

impl From<InvalidId> for AppError {
    fn from(e: InvalidId) -> Self {
        AppError::bad_request("invalid_id", e.to_string())
    }
}

impl From<StoreError> for AppError {
    fn from(e: StoreError) -> Self {
        match e {
            StoreError::Unavailable(_) => AppError::StoreUnavailable(e.to_string()),
            e => AppError::Internal(e.to_string()),
        }
    }
}

/// Which setting bounds the count a [`salient_core::Error::TooLarge`] names, and how an
/// operator raises it.
fn limit_of(what: &str) -> &'static str {
    match what {
        "vertices" => {
            "the server's `limits.max_input_vertices` (--max-vertices, SALIENT_MAX_VERTICES)"
        }
        "triangles" | "faces" => {
            "the server's `limits.max_input_triangles` (--max-triangles, SALIENT_MAX_TRIANGLES)"
        }
        "archive entries" => "the server's `limits.max_archive_entries`",
        "bytes unpacked" => "the server's `limits.max_unpacked_bytes`",
        _ => "the server's `limits`",
    }
}

/// What a 413 for a request body says: axum's rejection knows neither the limit nor its name.
pub const BODY_LIMIT: &str = "the request body is larger than the server's `max_body_bytes` (--max-body-bytes, SALIENT_MAX_BODY_BYTES)";

/// What a 413 for the body of a model being added says.
pub const UPLOAD_LIMIT: &str = "the model's file is larger than the server's `max_upload_bytes` (--max-upload-bytes, SALIENT_MAX_UPLOAD_BYTES)";

/// A rejection with axum's status: 413 for a body over the limit, else a bad request.
fn rejection(status: StatusCode, code: &'static str, message: String) -> AppError {
    if status == StatusCode::PAYLOAD_TOO_LARGE {
        AppError::PayloadTooLarge(BODY_LIMIT.to_string())
    } else if status == StatusCode::UNSUPPORTED_MEDIA_TYPE {
        AppError::UnsupportedMediaType(message)
    } else {
        AppError::bad_request(code, message)
    }
}

impl From<CollectError> for AppError {
    fn from(e: CollectError) -> Self {
        match e {
            CollectError::TooLarge => AppError::PayloadTooLarge(BODY_LIMIT.to_string()),
            // By its kind only: the text may name the spool's folder.
            CollectError::Spool(e) => AppError::Internal(format!("spooling a body: {}", e.kind())),
        }
    }
}

impl From<JsonRejection> for AppError {
    fn from(r: JsonRejection) -> Self {
        rejection(r.status(), "invalid_json", r.body_text())
    }
}

impl From<QueryRejection> for AppError {
    fn from(r: QueryRejection) -> Self {
        rejection(r.status(), "invalid_query", r.body_text())
    }
}

impl From<PathRejection> for AppError {
    fn from(r: PathRejection) -> Self {
        rejection(r.status(), "invalid_path", r.body_text())
    }
}

impl From<BytesRejection> for AppError {
    fn from(r: BytesRejection) -> Self {
        rejection(r.status(), "invalid_body", r.body_text())
    }
}

impl From<MultipartError> for AppError {
    fn from(e: MultipartError) -> Self {
        rejection(e.status(), "invalid_multipart", e.body_text())
    }
}
