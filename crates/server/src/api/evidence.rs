//! A duplicate as the API shows it: what `/v1/duplicates/check`, an upload's 409 and its
//! error body share.

use salient_core::duplicate::Evidence;
use serde::{Deserialize, Serialize};

/// [`Evidence`]'s schema in the API's description, written here so that the core needs no
/// description crate: its names and order are the core's own ([`Evidence::ALL`]).
pub struct EvidenceSchema;

impl utoipa::PartialSchema for EvidenceSchema {
    fn schema() -> utoipa::openapi::RefOr<utoipa::openapi::schema::Schema> {
        use utoipa::openapi::schema::{ObjectBuilder, SchemaType, Type};
        ObjectBuilder::new()
            .schema_type(SchemaType::new(Type::String))
            .description(Some(
                "Why two models are taken for one asset, strongest first (the order of the variants).",
            ))
            .enum_values(Some(Evidence::ALL.map(Evidence::as_str)))
            .into()
    }
}

impl utoipa::ToSchema for EvidenceSchema {
    fn name() -> std::borrow::Cow<'static, str> {
        "Evidence".into()
    }
}

/// A stored model found to be the same asset as something else.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
pub struct DuplicateMatch {
    pub id: String,
    #[schema(value_type = EvidenceSchema)]
    pub evidence: Evidence,
    /// 1 for identical, falling to 0 at the evidence's threshold.
    pub score: f64,
}
