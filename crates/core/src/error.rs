//! The library's error type: one enum, each variant saying what is wrong with the input
//! and, where it helps, how to fix it.

use std::path::PathBuf;

use crate::format::Format;

/// Everything that can go wrong turning user input into a mesh or a signature.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// Neither the extension, the content type nor the first bytes identify a format.
    #[error(
        "unrecognised mesh format ({0}); supported: OBJ, glTF (.gltf/.glb), OFF, PLY, STL, 3MF"
    )]
    UnknownFormat(String),

    /// The file is of a kind salient does not read (another application's format, glTF 1.0,
    /// a glTF extension that changes geometry): what it is, and how to convert it to one it
    /// reads. Not a corrupt file: the same bytes converted load.
    #[error("{feature} is not supported: {conversion}")]
    Unsupported {
        feature: String,
        conversion: &'static str,
    },

    /// A zip upload that cannot be used: not a zip, or not one mesh with its resources.
    #[error("unusable zip archive: {0}")]
    Archive(String),

    /// The file could not be read from disk.
    #[error("cannot read {path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },

    /// The bytes are not a valid file of the given format.
    #[error("malformed {format} file: {message}")]
    Parse { format: Format, message: String },

    /// A glTF file refers to a buffer that is neither embedded nor supplied.
    #[error("the glTF file needs the external resource `{uri}`, which was not supplied")]
    MissingResource { uri: String },

    /// A face refers to a vertex that does not exist.
    #[error("face {face} refers to vertex {index}, but the mesh has {vertex_count} vertices")]
    IndexOutOfRange {
        face: usize,
        index: u64,
        vertex_count: usize,
    },

    /// A coordinate is NaN or infinite.
    #[error("vertex {vertex} has a non-finite coordinate")]
    NonFinite { vertex: usize },

    /// The file holds no triangles at all (points, lines or an empty scene).
    #[error("the mesh has no triangles")]
    NoTriangles,

    /// Every triangle repeats a vertex or has zero area.
    #[error("all {count} triangles of the mesh are degenerate (repeated vertex or zero area)")]
    OnlyDegenerate { count: usize },

    /// After welding, too little is left to define a surface.
    #[error("the mesh welds to {count} vertices; at least 4 are needed for a surface")]
    TooFewVertices { count: usize },

    /// The mesh's extent is so large or so small that its geometry cannot be computed in
    /// double precision; rescale it.
    #[error(
        "the mesh's bounding-box diagonal is {diagonal:e}; it must lie between 1e-100 and 1e100"
    )]
    ExtentOutOfRange { diagonal: f64 },

    /// Stored signature bytes cannot be decoded.
    #[error("corrupt signature: {message}")]
    CorruptSignature { message: String },

    /// A stored signature was written by an incompatible version of the binary format;
    /// re-extract it from the mesh.
    #[error("signature format {found} is not supported (this version reads {supported}); re-extract the model")]
    SignatureFormat { found: u16, supported: u16 },

    /// A part has no salient feature at any size it was described at (`crate::partial`).
    #[error("the part has no salient feature at any size it was described at")]
    NoFeatures,

    /// A parameter is outside the range the method is defined for.
    #[error("invalid parameter `{name}`: {message}")]
    InvalidParameter {
        name: &'static str,
        message: &'static str,
    },

    /// An input exceeds a configured limit (see [`crate::params::Limits`]).
    #[error("the mesh has {count} {what}, above the limit of {limit}")]
    TooLarge {
        what: &'static str,
        count: usize,
        limit: usize,
    },

    /// A compressed stream (Draco) decodes to more than the limits allow; the decoder's
    /// message says what and how much.
    #[error("the compressed mesh decodes to more than the limits allow ({0})")]
    DecodesTooLarge(String),

    /// A labelled collection's labels cannot be used (SPEC §7): fix `labels.tsv` or lay the
    /// collection out as `CLASS/MODEL.ext`.
    #[error("bad labels in {path}: {message}")]
    Labels { path: PathBuf, message: String },

    /// A line of an ingest manifest cannot be used.
    #[error("{path}, line {line}: {message}")]
    Manifest {
        path: PathBuf,
        line: usize,
        message: String,
    },

    /// A report file (JSON, Markdown, CSV, a plot or a picture) could not be written.
    #[error("cannot write {path}: {message}")]
    Report { path: PathBuf, message: String },
}

/// Shorthand for results of this crate.
pub type Result<T, E = Error> = std::result::Result<T, E>;
