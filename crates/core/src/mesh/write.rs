//! Writing a mesh as a file: the forms in which `salient eval duplicates` disguises copies of
//! a collection's models (an asset library holds the same model as OBJ, STL of either kind
//! and GLB). OBJ and ASCII STL are a few lines of text; binary STL is `stl_io`'s; GLB is a
//! small document in `gltf`'s container writer (the crate has no builder).

use super::{Format, RawMesh};

/// A file form of a mesh.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Export {
    /// Positions in full (shortest round-trip) precision.
    Obj,
    /// Float32 corners, each triangle on its own.
    BinaryStl,
    /// Float32 corners as text.
    AsciiStl,
    /// Float32 positions, u32 indices.
    Glb,
}

impl Export {
    pub const ALL: [Export; 4] = [
        Export::Obj,
        Export::BinaryStl,
        Export::AsciiStl,
        Export::Glb,
    ];

    /// The format a loader reads it as.
    pub fn format(self) -> Format {
        match self {
            Export::Obj => Format::Obj,
            Export::BinaryStl | Export::AsciiStl => Format::Stl,
            Export::Glb => Format::Glb,
        }
    }

    /// A name for reports.
    pub fn name(self) -> &'static str {
        match self {
            Export::Obj => "obj",
            Export::BinaryStl => "binary stl",
            Export::AsciiStl => "ascii stl",
            Export::Glb => "glb",
        }
    }

    /// The file's bytes.
    pub fn write(self, mesh: &RawMesh) -> Vec<u8> {
        match self {
            Export::Obj => obj(mesh),
            Export::BinaryStl => binary_stl(mesh),
            Export::AsciiStl => ascii_stl(mesh),
            Export::Glb => glb(mesh),
        }
    }
}

fn obj(mesh: &RawMesh) -> Vec<u8> {
    let mut text = String::new();
    for p in &mesh.positions {
        text += &format!("v {} {} {}\n", p.x, p.y, p.z);
    }
    for t in &mesh.triangles {
        text += &format!("f {} {} {}\n", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    text.into_bytes()
}

/// Each triangle's unit normal and corners in float32.
fn facets(mesh: &RawMesh) -> impl Iterator<Item = ([f32; 3], [[f32; 3]; 3])> + '_ {
    mesh.triangles.iter().map(|t| {
        let [a, b, c] = t.map(|v| mesh.positions[v as usize]);
        let normal = (b - a)
            .cross(c - a)
            .normalize_or_zero()
            .as_vec3()
            .to_array();
        (normal, [a, b, c].map(|p| p.as_vec3().to_array()))
    })
}

fn binary_stl(mesh: &RawMesh) -> Vec<u8> {
    let triangles: Vec<stl_io::Triangle> = facets(mesh)
        .map(|(normal, corners)| stl_io::Triangle {
            normal: stl_io::Normal::new(normal),
            vertices: corners.map(stl_io::Vertex::new),
        })
        .collect();
    let mut bytes = Vec::new();
    stl_io::write_stl(&mut bytes, triangles.iter()).expect("writing to memory cannot fail");
    bytes
}

fn ascii_stl(mesh: &RawMesh) -> Vec<u8> {
    let mut text = String::from("solid salient\n");
    for (n, corners) in facets(mesh) {
        text += &format!(
            "  facet normal {:e} {:e} {:e}\n    outer loop\n",
            n[0], n[1], n[2]
        );
        for c in corners {
            text += &format!("      vertex {:e} {:e} {:e}\n", c[0], c[1], c[2]);
        }
        text += "    endloop\n  endfacet\n";
    }
    text += "endsolid salient\n";
    text.into_bytes()
}

fn glb(mesh: &RawMesh) -> Vec<u8> {
    let mut bin = Vec::with_capacity(mesh.positions.len() * 12 + mesh.triangles.len() * 12);
    let (mut lo, mut hi) = ([f32::INFINITY; 3], [f32::NEG_INFINITY; 3]);
    for p in &mesh.positions {
        let p = p.as_vec3().to_array();
        for k in 0..3 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
        p.iter().for_each(|c| bin.extend(c.to_le_bytes()));
    }
    let indices_at = bin.len();
    mesh.triangles
        .iter()
        .flatten()
        .for_each(|v| bin.extend(v.to_le_bytes()));
    const FLOAT: u32 = 5126;
    const UNSIGNED_INT: u32 = 5125;
    let document = serde_json::json!({
        "asset": {"version": "2.0", "generator": concat!("salient ", env!("CARGO_PKG_VERSION"))},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "mode": 4}]}],
        "accessors": [
            {"bufferView": 0, "componentType": FLOAT, "count": mesh.positions.len(), "type": "VEC3",
             "min": lo, "max": hi},
            {"bufferView": 1, "componentType": UNSIGNED_INT, "count": mesh.triangles.len() * 3,
             "type": "SCALAR"},
        ],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": indices_at},
            {"buffer": 0, "byteOffset": indices_at, "byteLength": bin.len() - indices_at},
        ],
        "buffers": [{"byteLength": bin.len()}],
    });
    gltf::binary::Glb {
        header: gltf::binary::Header {
            magic: *b"glTF",
            version: 2,
            length: 0, // computed by the writer
        },
        json: serde_json::to_vec(&document)
            .expect("a glTF document serialises")
            .into(),
        bin: Some(bin.into()),
    }
    .to_vec()
    .expect("writing to memory cannot fail")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::load::NoResources;
    use crate::mesh::{grid, load_bytes};
    use crate::params::Limits;

    #[test]
    fn every_export_reads_back_as_the_same_triangles() {
        let (positions, triangles) = grid(3);
        let mesh = RawMesh {
            positions: positions.into_iter().map(|p| p * 25.4 + 0.5).collect(),
            triangles,
        };
        for export in Export::ALL {
            let read = load_bytes(
                &export.write(&mesh),
                export.format(),
                &NoResources,
                &Limits::default(),
            )
            .unwrap_or_else(|e| panic!("{}: {e}", export.name()));
            assert_eq!(
                read.triangles.len(),
                mesh.triangles.len(),
                "{}",
                export.name()
            );
            let corners = |m: &RawMesh| -> Vec<f32> {
                m.triangles
                    .iter()
                    .flatten()
                    .flat_map(|&v| m.positions[v as usize].as_vec3().to_array())
                    .collect()
            };
            assert_eq!(corners(&read), corners(&mesh), "{}", export.name());
        }
    }
}
