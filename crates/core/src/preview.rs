//! What a person sees of a model: a compact copy of its prepared mesh with each vertex
//! labelled by the salient region it lies in (SPEC §3.3), from which thumbnails, comparison
//! pictures ([`crate::render`]) and the page's 3D view (a GLB) are made.
//!
//! A preview needs the prepared mesh and the signature's features, not an extraction: the
//! regions are re-grown from each feature's vertex with the same bounded Dijkstra and radius
//! the extraction used, so it costs a load and a preparation (tens of milliseconds) instead of
//! the ECC of every vertex. It is a cache, never data: [`Preview::key`] names what it was made
//! from, and an entry under another key (another upload, re-extracted features, a newer
//! preview layout) is simply made again.

use glam::DVec3;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use crate::display::{region_colour, UpAxis, SURFACE};
use crate::geodesic::{GeodesicScratch, Surface};
use crate::mesh::simplify::collapsed_triangles;
use crate::mesh::{PreparedMesh, Topology};
use crate::params::GeodesicRule;
use crate::signature::{Feature, Signature};

/// Bumped when the preview's layout or the way it is made changes: every cached preview is
/// then made again on first use.
pub const PREVIEW_VERSION: u32 = 1;

/// A preview has at most this many triangles: enough for a 3D view and a 1024-pixel picture,
/// small enough (≈ 150 KB as GLB) for a page showing many.
pub const MAX_TRIANGLES: usize = 6_000;

/// The region label of a vertex in no salient region.
pub const NO_REGION: u16 = u16::MAX;

/// A display mesh of a model with its salient regions.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Preview {
    /// Vertices in the model's own coordinates (single precision is plenty for display).
    pub positions: Vec<[f32; 3]>,
    pub triangles: Vec<[u32; 3]>,
    /// Per vertex, the index of the feature whose region holds it (the nearest, geodesically,
    /// where regions overlap), or [`NO_REGION`].
    pub regions: Vec<u16>,
    /// The salient points in feature order, own coordinates.
    pub points: Vec<[f32; 3]>,
    /// SPEC §1.4's normalisation, `normalised = (own − centre) · scale`.
    pub centre: [f64; 3],
    pub scale: f64,
}

impl Preview {
    /// The preview of a prepared mesh with the features its signature found on it.
    /// `rule` is the signature's, so that each region is regrown as it was found.
    pub fn new(
        mesh: &PreparedMesh,
        topology: &Topology,
        features: &[Feature],
        rule: GeodesicRule,
    ) -> Self {
        let n = mesh.positions.len();
        let mut label = vec![NO_REGION; n];
        let mut nearest = vec![f64::INFINITY; n];
        let mut scratch = GeodesicScratch::new(n, rule);
        let surface = Surface::new(mesh, topology);
        for (i, feature) in features.iter().enumerate().take(NO_REGION as usize) {
            let source = vertex_of(mesh, feature);
            let distances = scratch.run(surface, source, feature.region_size);
            for &v in distances.settled() {
                let d = distances.get(v);
                if d < feature.region_size && d < nearest[v as usize] {
                    nearest[v as usize] = d;
                    label[v as usize] = i as u16;
                }
            }
        }

        let kept = collapsed_triangles(&mesh.positions, &mesh.triangles, MAX_TRIANGLES);
        let mut remap = vec![u32::MAX; n];
        let mut preview = Preview {
            positions: Vec::new(),
            triangles: Vec::with_capacity(kept.len()),
            regions: Vec::new(),
            points: features
                .iter()
                .map(|f| f.position.map(|c| c as f32))
                .collect(),
            centre: mesh.centre.to_array(),
            scale: mesh.scale,
        };
        for t in kept {
            preview.triangles.push(t.map(|v| {
                if remap[v as usize] == u32::MAX {
                    remap[v as usize] = preview.positions.len() as u32;
                    let p = mesh.input_positions[v as usize];
                    preview.positions.push(p.as_vec3().to_array());
                    preview.regions.push(label[v as usize]);
                }
                remap[v as usize]
            }));
        }
        preview
    }

    /// What a preview of `signature`'s model holding the upload `content_hash` is made from:
    /// the layout version, the upload, the prepared mesh and each feature's vertex and radius.
    pub fn key(content_hash: &str, signature: &Signature) -> [u8; 32] {
        let mut hasher = Sha256::new();
        hasher.update(PREVIEW_VERSION.to_le_bytes());
        hasher.update(content_hash.as_bytes());
        hasher.update(signature.mesh_hash.0);
        for f in &signature.features {
            hasher.update(f.vertex.to_le_bytes());
            hasher.update(f.region_size.to_le_bytes());
        }
        hasher.finalize().into()
    }

    /// The cache entry of this preview made under `key`.
    pub fn to_cache_entry(&self, key: &[u8; 32]) -> Vec<u8> {
        let mut bytes = key.to_vec();
        bytes.extend(postcard::to_stdvec(self).expect("a preview serialises"));
        bytes
    }

    /// The preview in a cache entry, if it was made under `key` (else it must be made again).
    pub fn from_cache_entry(bytes: &[u8], key: &[u8; 32]) -> Option<Self> {
        let body = bytes.strip_prefix(key.as_slice())?;
        postcard::from_bytes(body).ok()
    }

    /// A vertex in normalised coordinates, where pictures are taken.
    pub fn normalised(&self, p: [f32; 3]) -> DVec3 {
        (DVec3::from(p.map(f64::from)) - DVec3::from(self.centre)) * self.scale
    }

    /// The region of each triangle: the label at least two of its corners share, else none.
    pub fn triangle_regions(&self) -> impl Iterator<Item = u16> + '_ {
        self.triangles.iter().map(|t| {
            let [a, b, c] = t.map(|v| self.regions[v as usize]);
            if a == b || a == c {
                a
            } else if b == c {
                b
            } else {
                NO_REGION
            }
        })
    }

    /// A binary glTF 2.0 of the preview: `POSITION`, `COLOR_0` (region colours baked in, for
    /// any viewer), `_REGION` (the labels, `UNSIGNED_SHORT`, 65535 = none, for a viewer that
    /// colours by its own rules) and the salient points under `asset.extras.salient.points`.
    ///
    /// Written with `serde_json` and `gltf::binary::Glb`: the `gltf` crate reads glTF but has
    /// no builder, and this document is small.
    ///
    /// glTF's up axis is +y; for a library whose models stand on +z the node is turned so
    /// that viewers show them upright, and `asset.extras.salient.up` says `"z"` (positions
    /// stay in the model's own coordinates, as explanations give them).
    pub fn to_glb(&self, up: UpAxis) -> Vec<u8> {
        let n = self.positions.len();
        let mut bin: Vec<u8> = Vec::with_capacity(n * 26 + self.triangles.len() * 12);
        let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
        for p in &self.positions {
            for k in 0..3 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
            }
            p.iter().for_each(|c| bin.extend(c.to_le_bytes()));
        }
        let colours_at = bin.len();
        for &r in &self.regions {
            let colour = if r == NO_REGION {
                SURFACE
            } else {
                region_colour(r as usize)
            };
            colour
                .iter()
                .for_each(|&c| bin.extend((c as f32).to_le_bytes()));
        }
        let regions_at = bin.len();
        self.regions
            .iter()
            .for_each(|r| bin.extend(r.to_le_bytes()));
        bin.resize(bin.len().next_multiple_of(4), 0);
        let indices_at = bin.len();
        self.triangles
            .iter()
            .flatten()
            .for_each(|v| bin.extend(v.to_le_bytes()));

        const ARRAY_BUFFER: u32 = 34962;
        const ELEMENT_ARRAY_BUFFER: u32 = 34963;
        const FLOAT: u32 = 5126;
        const UNSIGNED_SHORT: u32 = 5123;
        const UNSIGNED_INT: u32 = 5125;
        let view = |offset: usize, length: usize, target: u32| serde_json::json!({"buffer": 0, "byteOffset": offset, "byteLength": length, "target": target});
        let document = serde_json::json!({
            "asset": {
                "version": "2.0",
                "generator": concat!("salient ", env!("CARGO_PKG_VERSION")),
                "extras": {"salient": {"points": self.points, "up": up.as_str()}},
            },
            "scene": 0,
            "scenes": [{"nodes": [0]}],
            "nodes": [match up {
                UpAxis::Y => serde_json::json!({"mesh": 0}),
                // −90° about x: +z becomes +y.
                UpAxis::Z => serde_json::json!({"mesh": 0, "rotation": [-std::f64::consts::FRAC_1_SQRT_2, 0.0, 0.0, std::f64::consts::FRAC_1_SQRT_2]}),
            }],
            "meshes": [{"primitives": [{
                "attributes": {"POSITION": 0, "COLOR_0": 1, "_REGION": 2},
                "indices": 3,
                "mode": 4,
            }]}],
            "accessors": [
                {"bufferView": 0, "componentType": FLOAT, "count": n, "type": "VEC3",
                 "min": lo, "max": hi},
                {"bufferView": 1, "componentType": FLOAT, "count": n, "type": "VEC3"},
                {"bufferView": 2, "componentType": UNSIGNED_SHORT, "count": n, "type": "SCALAR"},
                {"bufferView": 3, "componentType": UNSIGNED_INT,
                 "count": self.triangles.len() * 3, "type": "SCALAR"},
            ],
            "bufferViews": [
                view(0, colours_at, ARRAY_BUFFER),
                view(colours_at, regions_at - colours_at, ARRAY_BUFFER),
                view(regions_at, 2 * n, ARRAY_BUFFER),
                view(indices_at, bin.len() - indices_at, ELEMENT_ARRAY_BUFFER),
            ],
            "buffers": [{"byteLength": bin.len()}],
        });
        let json = serde_json::to_vec(&document).expect("a glTF document serialises");
        gltf::binary::Glb {
            header: gltf::binary::Header {
                magic: *b"glTF",
                version: 2,
                length: 0, // computed by the writer
            },
            json: json.into(),
            bin: Some(bin.into()),
        }
        .to_vec()
        .expect("writing to memory cannot fail")
    }
}

/// The prepared mesh's index of a feature's vertex: its own, unless the mesh was prepared
/// differently from the one the signature was made on (a stale signature), then the nearest.
fn vertex_of(mesh: &PreparedMesh, feature: &Feature) -> u32 {
    let own = DVec3::from(feature.position);
    match mesh.input_positions.get(feature.vertex as usize) {
        Some(&p) if p == own => feature.vertex,
        _ => mesh
            .input_positions
            .iter()
            .enumerate()
            .min_by(|(_, a), (_, b)| a.distance_squared(own).total_cmp(&b.distance_squared(own)))
            .map_or(0, |(v, _)| v as u32),
    }
}
