//! `EXT_meshopt_compression` and `KHR_meshopt_compression`: buffer views stored compressed
//! by meshoptimizer's codecs (what `gltfpack -c` and `gltf-transform optimize` write).
//!
//! The decoders are meshoptimizer's own, through the `meshopt` crate's `ffi`: its safe
//! wrappers fix the element size to a Rust type, while a file gives each view its own stride.
//! meshoptimizer *asserts* on a stride or count it does not accept (an abort, not an error),
//! so every parameter is checked here first, as the extensions' specifications constrain
//! them. The decoders themselves are safe on hostile bytes: they bound every read by the
//! encoded length and report a malformed stream.

use serde::Deserialize;

/// The extension names, the ratified one first.
pub(super) const NAMES: [&str; 2] = ["KHR_meshopt_compression", "EXT_meshopt_compression"];

/// A buffer view's compressed form: where its bytes are and how to decode them.
#[derive(Debug, Deserialize)]
#[serde(rename_all = "camelCase")]
pub(super) struct Compressed {
    pub buffer: usize,
    #[serde(default)]
    pub byte_offset: u64,
    pub byte_length: u64,
    byte_stride: u64,
    count: u64,
    mode: Mode,
    #[serde(default)]
    filter: Filter,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "SCREAMING_SNAKE_CASE")]
enum Mode {
    Attributes,
    Triangles,
    Indices,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "SCREAMING_SNAKE_CASE")]
enum Filter {
    #[default]
    None,
    Octahedral,
    Quaternion,
    Exponential,
    Color,
}

impl Compressed {
    /// The compressed form a view's extensions declare, if any.
    pub(super) fn of(
        extensions: Option<&::gltf::json::extensions::buffer::View>,
    ) -> Option<Result<Self, String>> {
        let others = &extensions?.others;
        let value = NAMES.iter().find_map(|name| others.get(*name))?;
        Some(
            serde_json::from_value(value.clone())
                .map_err(|e| format!("invalid meshopt compression of a buffer view: {e}")),
        )
    }

    /// The size of the decoded view, once its parameters are known to be ones the codecs
    /// accept; `max_bytes` bounds it before anything is allocated.
    pub(super) fn decoded_len(&self, max_bytes: usize) -> Result<usize, String> {
        let stride = self.byte_stride;
        let stride_ok = match self.mode {
            Mode::Attributes => stride.is_multiple_of(4) && (4..=256).contains(&stride),
            Mode::Triangles | Mode::Indices => stride == 2 || stride == 4,
        };
        if !stride_ok {
            return Err(format!(
                "a meshopt {:?} stream has a byte stride of {stride}",
                self.mode
            ));
        }
        if self.mode == Mode::Triangles && !self.count.is_multiple_of(3) {
            return Err(format!(
                "a meshopt TRIANGLES stream has {} indices, not a multiple of 3",
                self.count
            ));
        }
        let filter_ok = match (self.mode, self.filter) {
            (_, Filter::None) => true,
            (Mode::Attributes, Filter::Octahedral | Filter::Color) => stride == 4 || stride == 8,
            (Mode::Attributes, Filter::Quaternion) => stride == 8,
            (Mode::Attributes, Filter::Exponential) => true,
            _ => false,
        };
        if !filter_ok {
            return Err(format!(
                "a meshopt {:?} stream with a byte stride of {stride} cannot use the {:?} filter",
                self.mode, self.filter
            ));
        }
        let len = self
            .count
            .checked_mul(stride)
            .and_then(|n| usize::try_from(n).ok())
            .unwrap_or(usize::MAX);
        if len > max_bytes {
            return Err(format!(
                "a meshopt stream decodes to {len} bytes, more than the {max_bytes} the \
                 server's vertex and triangle limits allow"
            ));
        }
        Ok(len)
    }

    /// Decodes `encoded` (the `byteLength` bytes at `byteOffset` of the source buffer) into
    /// `len` bytes ([`Compressed::decoded_len`]).
    pub(super) fn decode(&self, encoded: &[u8], len: usize) -> Result<Vec<u8>, String> {
        // Decoded in u32 words: the filters read 16- and 32-bit values in place.
        let mut words = vec![0u32; len.div_ceil(4)];
        let count = self.count as usize;
        let stride = self.byte_stride as usize;
        let out = words.as_mut_ptr().cast::<std::ffi::c_void>();
        // SAFETY: `out` holds at least count × stride bytes, 4-aligned; `encoded` is read
        // only within its length; stride, count and filter were checked against what
        // meshoptimizer accepts (`decoded_len`).
        let status = unsafe {
            match self.mode {
                Mode::Attributes => meshopt::ffi::meshopt_decodeVertexBuffer(
                    out,
                    count,
                    stride,
                    encoded.as_ptr(),
                    encoded.len(),
                ),
                Mode::Triangles => meshopt::ffi::meshopt_decodeIndexBuffer(
                    out,
                    count,
                    stride,
                    encoded.as_ptr(),
                    encoded.len(),
                ),
                Mode::Indices => meshopt::ffi::meshopt_decodeIndexSequence(
                    out,
                    count,
                    stride,
                    encoded.as_ptr(),
                    encoded.len(),
                ),
            }
        };
        if status != 0 {
            return Err(format!(
                "a meshopt {:?} stream of {} bytes does not decode (code {status})",
                self.mode,
                encoded.len()
            ));
        }
        // SAFETY: as above; the filters transform count × stride bytes in place.
        unsafe {
            match self.filter {
                Filter::None => {}
                Filter::Octahedral => meshopt::ffi::meshopt_decodeFilterOct(out, count, stride),
                Filter::Quaternion => meshopt::ffi::meshopt_decodeFilterQuat(out, count, stride),
                Filter::Exponential => meshopt::ffi::meshopt_decodeFilterExp(out, count, stride),
                Filter::Color => meshopt::ffi::meshopt_decodeFilterColor(out, count, stride),
            }
        }
        let mut bytes: Vec<u8> = bytemuck::cast_slice(&words).to_vec();
        bytes.truncate(len);
        Ok(bytes)
    }
}
