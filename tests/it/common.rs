//! Test support: a small glTF/GLB writer and mesh comparison helpers.

use base64::Engine;
use salient_core::mesh::RawMesh;
use serde_json::{json, Value};

/// Path of a file under `tests/fixtures`.
pub fn fixture(name: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(name)
}

/// Builds a glTF document with one binary buffer, accessor by accessor.
#[derive(Debug, Default)]
pub struct GltfBuilder {
    pub bin: Vec<u8>,
    pub accessors: Vec<Value>,
    pub views: Vec<Value>,
    pub meshes: Vec<Value>,
    pub nodes: Vec<Value>,
    pub scenes: Vec<Value>,
    pub scene: Option<usize>,
}

impl GltfBuilder {
    /// Appends bytes as a new buffer view (4-byte aligned) and returns its index.
    pub fn view(&mut self, bytes: &[u8]) -> usize {
        self.bin.resize(self.bin.len().next_multiple_of(4), 0);
        self.views.push(json!({
            "buffer": 0, "byteOffset": self.bin.len(), "byteLength": bytes.len()
        }));
        self.bin.extend_from_slice(bytes);
        self.views.len() - 1
    }

    /// A `VEC3`/`FLOAT` accessor (with the `min`/`max` the specification requires).
    pub fn positions(&mut self, points: &[[f32; 3]]) -> usize {
        let bytes: Vec<u8> = points
            .iter()
            .flatten()
            .flat_map(|c| c.to_le_bytes())
            .collect();
        let view = self.view(&bytes);
        let (mut min, mut max) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
        for p in points {
            for k in 0..3 {
                min[k] = min[k].min(p[k]);
                max[k] = max[k].max(p[k]);
            }
        }
        self.accessor(json!({
            "bufferView": view, "componentType": 5126, "count": points.len(), "type": "VEC3",
            "min": min, "max": max
        }))
    }

    /// A `SCALAR` index accessor, `UNSIGNED_SHORT` if every index fits, else `UNSIGNED_INT`.
    pub fn indices(&mut self, indices: &[u32]) -> usize {
        let (bytes, component_type): (Vec<u8>, u32) = if indices.iter().all(|&i| i < 65536) {
            let bytes = indices
                .iter()
                .flat_map(|&i| (i as u16).to_le_bytes())
                .collect();
            (bytes, 5123)
        } else {
            (indices.iter().flat_map(|i| i.to_le_bytes()).collect(), 5125)
        };
        let view = self.view(&bytes);
        self.accessor(json!({
            "bufferView": view, "componentType": component_type, "count": indices.len(),
            "type": "SCALAR"
        }))
    }

    pub fn accessor(&mut self, accessor: Value) -> usize {
        self.accessors.push(accessor);
        self.accessors.len() - 1
    }

    /// A mesh of one primitive (`mode` 4 = triangles, 5 = strip, 6 = fan, 0 = points).
    pub fn mesh(&mut self, positions: usize, indices: Option<usize>, mode: u32) -> usize {
        let mut primitive = json!({ "attributes": { "POSITION": positions }, "mode": mode });
        if let Some(indices) = indices {
            primitive["indices"] = json!(indices);
        }
        self.meshes.push(json!({ "primitives": [primitive] }));
        self.meshes.len() - 1
    }

    pub fn node(&mut self, node: Value) -> usize {
        self.nodes.push(node);
        self.nodes.len() - 1
    }

    pub fn scene(&mut self, nodes: &[usize]) -> usize {
        self.scenes.push(json!({ "nodes": nodes }));
        self.scenes.len() - 1
    }

    /// The JSON document; `uri` is the buffer's URI, `None` for the GLB binary chunk.
    pub fn json(&self, uri: Option<&str>) -> Value {
        let mut buffer = json!({ "byteLength": self.bin.len() });
        if let Some(uri) = uri {
            buffer["uri"] = json!(uri);
        }
        let mut doc = json!({
            "asset": { "version": "2.0", "generator": "salient tests" },
            "buffers": [buffer],
            "bufferViews": self.views,
            "accessors": self.accessors,
            "meshes": self.meshes,
            "nodes": self.nodes,
            "scenes": self.scenes,
        });
        if let Some(scene) = self.scene {
            doc["scene"] = json!(scene);
        }
        doc
    }

    /// A binary glTF.
    pub fn glb(&self) -> Vec<u8> {
        glb(&self.json(None), &self.bin)
    }

    /// A `.gltf` whose buffer is embedded as a base64 `data:` URI.
    pub fn gltf_data_uri(&self) -> Vec<u8> {
        let data = base64::engine::general_purpose::STANDARD.encode(&self.bin);
        let uri = format!("data:application/octet-stream;base64,{data}");
        serde_json::to_vec_pretty(&self.json(Some(&uri))).expect("JSON serialises")
    }
}

/// A GLB container: header, JSON chunk (space-padded), BIN chunk (zero-padded).
pub fn glb(json: &Value, bin: &[u8]) -> Vec<u8> {
    glb_from_text(&serde_json::to_vec(json).expect("JSON serialises"), bin)
}

/// The CAPOD horse compressed as web tools write it (`tests/fixtures/web/`, beside its
/// uncompressed original `horse_plain.glb`): meshopt in every form, Draco required and not.
pub const COMPRESSED_HORSES: [&str; 6] = [
    "horse_meshopt.glb",
    "horse_meshopt_khr.glb",
    "horse_meshopt_fallback.glb",
    "horse_gt_meshopt.glb",
    "horse_draco.glb",
    "horse_draco_optional.glb",
];

/// A GLB container's JSON and BIN chunks (the BIN chunk empty if there is none), to edit a
/// real file and write it again with [`glb`].
pub fn split_glb_chunks(bytes: &[u8]) -> (Value, Vec<u8>) {
    let word = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().unwrap()) as usize;
    let json_len = word(12);
    let json = serde_json::from_slice(&bytes[20..20 + json_len]).expect("a GLB's JSON chunk");
    let bin = match bytes.get(20 + json_len..20 + json_len + 8) {
        Some(header) if header.len() == 8 => {
            let len = word(20 + json_len);
            bytes[28 + json_len..28 + json_len + len].to_vec()
        }
        _ => Vec::new(),
    };
    (json, bin)
}

/// A GLB container around JSON text as it is (which need not be valid).
pub fn glb_from_text(json: &[u8], bin: &[u8]) -> Vec<u8> {
    let mut json = json.to_vec();
    json.resize(json.len().next_multiple_of(4), b' ');
    let mut bin = bin.to_vec();
    bin.resize(bin.len().next_multiple_of(4), 0);
    let total = 12 + 8 + json.len() + if bin.is_empty() { 0 } else { 8 + bin.len() };
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&json);
    if !bin.is_empty() {
        out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
        out.extend_from_slice(b"BIN\0");
        out.extend_from_slice(&bin);
    }
    out
}

/// `mesh` as a GLB in which every triangle has its own three vertices, as exporters write
/// meshes split at UV/normal seams (positions stored as `f32`, exactly as loaded).
pub fn split_glb(mesh: &RawMesh) -> Vec<u8> {
    let corners: Vec<[f32; 3]> = mesh
        .triangles
        .iter()
        .flatten()
        .map(|&i| mesh.positions[i as usize].as_vec3().to_array())
        .collect();
    let mut builder = GltfBuilder::default();
    let positions = builder.positions(&corners);
    let indices: Vec<u32> = (0..corners.len() as u32).collect();
    let indices = builder.indices(&indices);
    let mesh = builder.mesh(positions, Some(indices), 4);
    let node = builder.node(json!({ "mesh": mesh }));
    builder.scene(&[node]);
    builder.scene = Some(0);
    builder.glb()
}

/// The triangles of `mesh` as corner positions, for comparisons that ignore vertex numbering.
pub fn soup(mesh: &RawMesh) -> Vec<[[f64; 3]; 3]> {
    mesh.triangles
        .iter()
        .map(|t| t.map(|i| mesh.positions[i as usize].to_array()))
        .collect()
}

/// Signed volume enclosed by the mesh (positive when faces wind counter-clockwise seen from
/// outside).
pub fn signed_volume(mesh: &RawMesh) -> f64 {
    mesh.triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| mesh.positions[i as usize]);
            a.dot(b.cross(c)) / 6.0
        })
        .sum()
}

/// Unit normal of triangle `t`.
pub fn normal(mesh: &RawMesh, t: usize) -> glam::DVec3 {
    let [a, b, c] = mesh.triangles[t].map(|i| mesh.positions[i as usize]);
    (b - a).cross(c - a).normalize()
}

/// A unit cube `[0,1]³` as 8 corners and 6 outward quads (counter-clockwise from outside).
pub const CUBE_CORNERS: [[f64; 3]; 8] = [
    [0.0, 0.0, 0.0],
    [1.0, 0.0, 0.0],
    [1.0, 1.0, 0.0],
    [0.0, 1.0, 0.0],
    [0.0, 0.0, 1.0],
    [1.0, 0.0, 1.0],
    [1.0, 1.0, 1.0],
    [0.0, 1.0, 1.0],
];
pub const CUBE_QUADS: [[u32; 4]; 6] = [
    [0, 3, 2, 1],
    [4, 5, 6, 7],
    [0, 1, 5, 4],
    [1, 2, 6, 5],
    [2, 3, 7, 6],
    [3, 0, 4, 7],
];

/// A tetrahedron with outward winding.
pub const TETRA_CORNERS: [[f32; 3]; 4] = [
    [0.0, 0.0, 0.0],
    [1.0, 0.0, 0.0],
    [0.0, 1.0, 0.0],
    [0.0, 0.0, 1.0],
];
pub const TETRA_TRIANGLES: [u32; 12] = [0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3];

/// A zip archive of `entries` (name, bytes), deflated: what an asset library's download holds.
pub fn zip(entries: &[(&str, &[u8])]) -> Vec<u8> {
    use std::io::Write;
    let mut writer = zip::ZipWriter::new(std::io::Cursor::new(Vec::new()));
    let options = zip::write::SimpleFileOptions::default()
        .compression_method(zip::CompressionMethod::Deflated);
    for (name, bytes) in entries {
        writer.start_file(*name, options).unwrap();
        writer.write_all(bytes).unwrap();
    }
    writer.finish().unwrap().into_inner()
}
