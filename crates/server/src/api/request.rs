//! The parts of a request every handler reads, as extractors whose rejections are
//! [`AppError`]s (axum's `examples/error-handling`): paths, queries, JSON bodies, a model's
//! `{id}` and a listing's page size.

use axum::extract::{FromRequest, FromRequestParts};
use serde::Deserialize;

use super::error::AppError;
use crate::model::ModelId;

/// `Path` with our rejection: a bad path is an [`AppError`] in the JSON shape.
#[derive(FromRequestParts)]
#[from_request(via(axum::extract::Path), rejection(AppError))]
pub struct AppPath<T>(pub T);

/// `Json` with our rejection.
#[derive(FromRequest)]
#[from_request(via(axum::Json), rejection(AppError))]
pub struct AppJson<T>(pub T);

/// `Query` with our rejection.
#[derive(FromRequestParts)]
#[from_request(via(axum::extract::Query), rejection(AppError))]
pub struct AppQuery<T>(pub T);

/// The `{id}` of a model's routes; the pattern states [`ModelId`]'s rule in the API
/// description.
#[derive(Debug, Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Path)]
pub struct ModelPath {
    /// Model id.
    #[param(pattern = "^[A-Za-z0-9_-][A-Za-z0-9._-]{0,127}$")]
    pub id: String,
}

impl ModelPath {
    pub fn id(&self) -> Result<ModelId, AppError> {
        Ok(ModelId::parse(&self.id)?)
    }
}

/// The page size of a listing: `limit`, 1–1000, 100 when not given.
pub fn page_size(limit: Option<usize>) -> Result<usize, AppError> {
    let limit = limit.unwrap_or(100);
    if !(1..=1000).contains(&limit) {
        return Err(AppError::bad_request(
            "invalid_query",
            "limit must be between 1 and 1000",
        ));
    }
    Ok(limit)
}
