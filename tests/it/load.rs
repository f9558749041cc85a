//! Mesh loading (SPEC §1.1): every format, glTF scene graphs, typed errors on bad input, and a
//! seeded fuzz run that must never panic.

use crate::common;

use std::collections::HashMap;
use std::path::Path;

use common::{
    fixture, normal, signed_volume, split_glb, GltfBuilder, CUBE_CORNERS, CUBE_QUADS,
    TETRA_CORNERS, TETRA_TRIANGLES,
};
use glam::DVec3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use salient_core::mesh::load::{DirResources, NoResources};
use salient_core::mesh::{load_bytes, load_path, Format, RawMesh, Resources};
use salient_core::{Error, Limits};
use serde_json::json;

fn load(bytes: &[u8], format: Format) -> salient_core::Result<RawMesh> {
    load_bytes(bytes, format, &NoResources, &Limits::default())
}

fn assert_close(a: DVec3, b: DVec3) {
    assert!(a.distance(b) < 1e-9, "{a} != {b}");
}

/// The unit cube as text OBJ: quads, texture/normal references, groups, materials, a polyline
/// and relative indices.
fn cube_obj() -> String {
    let mut s = String::from("# cube\nmtllib cube.mtl\no cube\n");
    for [x, y, z] in CUBE_CORNERS {
        s += &format!("v {x} {y} {z}\n");
    }
    s += "vt 0 0\nvt 1 0\nvn 0 0 1\ng sides\nusemtl red\ns off\n";
    for (k, q) in CUBE_QUADS.iter().enumerate() {
        let [a, b, c, d] = q.map(|i| i + 1);
        s += &match k {
            0 => format!("f {a}/1/1 {b}/2/1 {c}/1/1 {d}/2/1\n"),
            1 => format!("f {a}//1 {b}//1 {c}//1 {d}//1\n"),
            2 => "f -8 -7 -3 -4\n".to_string(),
            _ => format!("f {a} {b} {c} {d}\n"),
        };
    }
    s += "l 1 2 3\n";
    s
}

fn cube_off(header: &str) -> String {
    let mut s = format!("{header}# a cube\n\n8 6 12 # counts\n");
    for [x, y, z] in CUBE_CORNERS {
        s += &format!("{x} {y} {z}   0.5 0.5 0.5 1.0\n");
    }
    for [a, b, c, d] in CUBE_QUADS {
        s += &format!("4 {a} {b} {c} {d} 255 0 0\n");
    }
    s
}

fn cube_ply_ascii() -> String {
    let mut s = String::from(
        "ply\nformat ascii 1.0\ncomment a cube\nelement vertex 8\nproperty float x\n\
         property float y\nproperty float z\nproperty uchar red\nproperty uchar green\n\
         property uchar blue\nelement face 6\nproperty list uchar int vertex_indices\n\
         end_header\n",
    );
    for [x, y, z] in CUBE_CORNERS {
        s += &format!("{x} {y} {z} 255 0 0\n");
    }
    for [a, b, c, d] in CUBE_QUADS {
        s += &format!("4 {a} {b} {c} {d}\n");
    }
    s
}

/// The cube as binary little-endian PLY (double coordinates, `uint` indices named
/// `vertex_index`, a trailing element to skip).
fn cube_ply_le() -> Vec<u8> {
    let mut b = b"ply\nformat binary_little_endian 1.0\nelement vertex 8\nproperty double x\n\
                  property double y\nproperty double z\nelement face 6\n\
                  property list uchar uint vertex_index\nelement edge 1\nproperty int a\n\
                  end_header\n"
        .to_vec();
    for p in CUBE_CORNERS {
        for c in p {
            b.extend(c.to_le_bytes());
        }
    }
    for q in CUBE_QUADS {
        b.push(4);
        for i in q {
            b.extend(i.to_le_bytes());
        }
    }
    b.extend(7i32.to_le_bytes());
    b
}

/// The cube as binary big-endian PLY (an element before the vertices, `int` coordinates,
/// `ushort` indices).
fn cube_ply_be() -> Vec<u8> {
    let mut b = b"ply\nformat binary_big_endian 1.0\nelement material 1\nproperty uchar r\n\
                  element vertex 8\nproperty int x\nproperty int y\nproperty int z\n\
                  element face 6\nproperty list uchar ushort vertex_indices\nend_header\n"
        .to_vec();
    b.push(9);
    for p in CUBE_CORNERS {
        for c in p {
            b.extend((c as i32).to_be_bytes());
        }
    }
    for q in CUBE_QUADS {
        b.push(4);
        for i in q {
            b.extend((i as u16).to_be_bytes());
        }
    }
    b
}

fn tetra_triangles() -> impl Iterator<Item = [[f32; 3]; 3]> {
    TETRA_TRIANGLES
        .chunks(3)
        .map(|t| [0, 1, 2].map(|k| TETRA_CORNERS[t[k] as usize]))
}

fn tetra_stl_ascii(name: &str) -> String {
    let mut s = format!("  solid{name}\n");
    for t in tetra_triangles() {
        s += "facet normal 0 0 0\n  outer loop\n";
        for [x, y, z] in t {
            s += &format!("    vertex {x} {y} {z}\n");
        }
        s += "  endloop\nendfacet\n";
    }
    s + "endsolid\n"
}

fn tetra_stl_binary(header: &[u8]) -> Vec<u8> {
    let mut b = header.to_vec();
    b.resize(80, b' ');
    b.extend(4u32.to_le_bytes());
    for t in tetra_triangles() {
        b.extend([0u8; 12]);
        for c in t.iter().flatten() {
            b.extend(c.to_le_bytes());
        }
        b.extend([0u8; 2]);
    }
    b
}

fn tetra_builder() -> (GltfBuilder, usize) {
    let mut g = GltfBuilder::default();
    let positions = g.positions(&TETRA_CORNERS);
    let indices = g.indices(&TETRA_TRIANGLES);
    let mesh = g.mesh(positions, Some(indices), 4);
    (g, mesh)
}

fn tetra_glb() -> Vec<u8> {
    let (mut g, mesh) = tetra_builder();
    let node = g.node(json!({ "mesh": mesh }));
    g.scene(&[node]);
    g.glb()
}

fn tetra_gltf_data_uri() -> Vec<u8> {
    let (mut g, mesh) = tetra_builder();
    let node = g.node(json!({ "mesh": mesh }));
    g.scene(&[node]);
    g.gltf_data_uri()
}

fn assert_cube(mesh: &RawMesh) {
    assert_eq!(mesh.triangles.len(), 12);
    assert!((signed_volume(mesh) - 1.0).abs() < 1e-12);
    let mut corners: Vec<[f64; 3]> = mesh.positions.iter().map(|p| p.to_array()).collect();
    corners.sort_by(|a, b| a.partial_cmp(b).unwrap());
    corners.dedup();
    assert_eq!(corners.len(), 8);
}

fn assert_tetra(mesh: &RawMesh) {
    assert_eq!(mesh.triangles.len(), 4);
    assert_eq!(mesh.positions.len(), 4);
    assert!((signed_volume(mesh) - 1.0 / 6.0).abs() < 1e-12);
}

// ---------------------------------------------------------------------------------------
// Format detection

#[test]
fn formats_from_names_and_content_types() {
    assert_eq!(Format::from_extension("OBJ"), Some(Format::Obj));
    assert_eq!(Format::from_extension("glb"), Some(Format::Glb));
    assert_eq!(Format::from_extension("txt"), None);
    assert_eq!(
        Format::from_path(Path::new("a/b/model.GlTf")),
        Some(Format::Gltf)
    );
    assert_eq!(Format::from_path(Path::new("noext")), None);
    assert_eq!(
        Format::from_content_type("model/gltf-binary"),
        Some(Format::Glb)
    );
    assert_eq!(
        Format::from_content_type("Model/GLTF+JSON; charset=utf-8"),
        Some(Format::Gltf)
    );
    assert_eq!(Format::from_content_type("model/obj"), Some(Format::Obj));
    assert_eq!(Format::from_content_type("model/stl"), Some(Format::Stl));
    assert_eq!(Format::from_content_type("application/octet-stream"), None);
    assert_eq!(Format::Gltf.to_string(), "glTF");
    assert_eq!(Format::Glb.to_string(), "GLB");
    assert_eq!(serde_json::to_string(&Format::Ply).unwrap(), "\"ply\"");
}

#[test]
fn formats_sniffed_from_content() {
    assert_eq!(Format::sniff(&tetra_glb()), Some(Format::Glb));
    assert_eq!(Format::sniff(&tetra_gltf_data_uri()), Some(Format::Gltf));
    assert_eq!(Format::sniff(cube_obj().as_bytes()), Some(Format::Obj));
    assert_eq!(
        Format::sniff(b"\xEF\xBB\xBF# c\n\nv 1 2 3\n"),
        Some(Format::Obj)
    );
    assert_eq!(
        Format::sniff(cube_off("OFF\n").as_bytes()),
        Some(Format::Off)
    );
    assert_eq!(Format::sniff(b"COFF 8 6 0\n"), Some(Format::Off));
    assert_eq!(Format::sniff(b"STCNOFF\n"), Some(Format::Off));
    assert_eq!(
        Format::sniff(cube_ply_ascii().as_bytes()),
        Some(Format::Ply)
    );
    assert_eq!(Format::sniff(&cube_ply_le()), Some(Format::Ply));
    assert_eq!(
        Format::sniff(tetra_stl_ascii(" t").as_bytes()),
        Some(Format::Stl)
    );
    assert_eq!(
        Format::sniff(&tetra_stl_binary(b"solid x")),
        Some(Format::Stl)
    );
    assert_eq!(Format::sniff(b"hello world"), None);
    assert_eq!(Format::sniff(b""), None);
}

// ---------------------------------------------------------------------------------------
// Each format

#[test]
fn obj_cube_with_quads_groups_and_relative_indices() {
    let mesh = load(cube_obj().as_bytes(), Format::Obj).unwrap();
    assert_cube(&mesh);
    assert_eq!(mesh.positions.len(), 8);
}

#[test]
fn obj_objects_are_merged_with_offsets() {
    let obj = "o a\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\no b\nv 0 0 1\nv 1 0 1\nv 0 1 1\n\
               f 4 5 6\ng c\nf -3 -1 -2\n";
    let mesh = load(obj.as_bytes(), Format::Obj).unwrap();
    assert_eq!(mesh.triangles.len(), 3);
    let soup = common::soup(&mesh);
    assert_eq!(soup[0], [[0., 0., 0.], [1., 0., 0.], [0., 1., 0.]]);
    assert_eq!(soup[1], [[0., 0., 1.], [1., 0., 1.], [0., 1., 1.]]);
    assert_eq!(soup[2], [[0., 0., 1.], [0., 1., 1.], [1., 0., 1.]]);
}

/// A face continued on the next line with `\` is one face; errors name their line.
#[test]
fn obj_continued_lines_and_errors_with_line_numbers() {
    let continued = "v 0 0 0\r\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 \\\n  3 4\n";
    let mesh = load(continued.as_bytes(), Format::Obj).unwrap();
    assert_eq!(mesh.triangles.len(), 2);
    for (obj, line) in [
        ("v 0 0 0\nv 1 0\n", "line 2:"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\n# comment\nf 1 2 x\n", "line 5:"),
        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 \\\n 2 0\n", "line 4:"),
    ] {
        match load(obj.as_bytes(), Format::Obj) {
            Err(Error::Parse { message, .. }) => assert!(message.starts_with(line), "{message}"),
            other => panic!("{obj:?}: {other:?}"),
        }
    }
}

#[test]
fn gltf_with_sibling_bin_file() {
    let mesh = load_path(&fixture("gltf_external/tetra.gltf"), &Limits::default()).unwrap();
    assert_tetra(&mesh);
    // The same file as an upload, its buffer supplied in memory.
    let json = std::fs::read(fixture("gltf_external/tetra.gltf")).unwrap();
    let bin = std::fs::read(fixture("gltf_external/tetra.bin")).unwrap();
    let parts = HashMap::from([("tetra.bin".to_string(), bin)]);
    let upload = load_bytes(&json, Format::Gltf, &parts, &Limits::default()).unwrap();
    assert_eq!(upload, mesh);
}

#[test]
fn gltf_with_data_uri_and_glb() {
    let from_json = load(&tetra_gltf_data_uri(), Format::Gltf).unwrap();
    assert_tetra(&from_json);
    let from_glb = load(&tetra_glb(), Format::Glb).unwrap();
    assert_eq!(from_glb, from_json);
}

#[test]
fn gltf_percent_encoded_uri_is_decoded() {
    let (mut g, mesh) = tetra_builder();
    let node = g.node(json!({ "mesh": mesh }));
    g.scene(&[node]);
    let doc = serde_json::to_vec(&g.json(Some("my%20tetra.bin"))).unwrap();
    let parts = HashMap::from([("my tetra.bin".to_string(), g.bin.clone())]);
    let mesh = load_bytes(&doc, Format::Gltf, &parts, &Limits::default()).unwrap();
    assert_tetra(&mesh);
}

#[test]
fn gltf_node_transforms_compose() {
    let mut g = GltfBuilder::default();
    let positions = g.positions(&[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]);
    let mesh = g.mesh(positions, None, 4);
    let child =
        g.node(json!({ "mesh": mesh, "translation": [1.0, 0.0, 0.0], "scale": [2.0, 2.0, 2.0] }));
    let half = std::f32::consts::FRAC_1_SQRT_2;
    let parent = g.node(json!({ "rotation": [0.0, 0.0, half, half], "children": [child] }));
    let root = g.node(json!({
        "matrix": [1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 5.0, 1.0],
        "children": [parent]
    }));
    g.scene(&[root]);
    let loaded = load(&g.glb(), Format::Glb).unwrap();
    // p -> scale 2 -> translate x+1 -> rotate 90° about z -> translate z+5.
    assert_close(loaded.positions[0], DVec3::new(0.0, 1.0, 5.0));
    assert_close(loaded.positions[1], DVec3::new(0.0, 3.0, 5.0));
    assert_close(loaded.positions[2], DVec3::new(-2.0, 1.0, 5.0));
    assert!(normal(&loaded, 0).distance(DVec3::Z) < 1e-6);
}

#[test]
fn gltf_mirrored_node_flips_winding() {
    let (mut g, mesh) = tetra_builder();
    let plain = g.node(json!({ "mesh": mesh }));
    let mirrored = g.node(json!({ "mesh": mesh, "scale": [-1.0, 1.0, 1.0] }));
    g.scene(&[plain]);
    g.scene(&[mirrored]);
    g.scene = Some(1);
    let loaded = load(&g.glb(), Format::Glb).unwrap();
    assert_eq!(loaded.positions[1], DVec3::new(-1.0, 0.0, 0.0));
    // Mirrored positions with the original winding would enclose -1/6.
    assert!((signed_volume(&loaded) - 1.0 / 6.0).abs() < 1e-12);
}

#[test]
fn gltf_strips_and_fans_become_triangles() {
    let mut g = GltfBuilder::default();
    let quad = g.positions(&[[0., 0., 0.], [1., 0., 0.], [0., 1., 0.], [1., 1., 0.]]);
    let strip = g.mesh(quad, None, 5);
    let star = g.positions(&[
        [0., 0., 0.],
        [1., 0., 0.],
        [0., 1., 0.],
        [-1., 0., 0.],
        [0., -1., 0.],
    ]);
    let fan_indices = g.indices(&[0, 1, 2, 3, 4]);
    let fan = g.mesh(star, Some(fan_indices), 6);
    let points = g.mesh(quad, None, 0);
    let nodes = [strip, fan, points].map(|mesh| g.node(json!({ "mesh": mesh })));
    g.scene(&nodes);
    let loaded = load(&g.glb(), Format::Glb).unwrap();
    assert_eq!(loaded.triangles.len(), 2 + 3);
    assert_eq!(loaded.positions.len(), 4 + 5);
    for t in 0..5 {
        assert!(
            normal(&loaded, t).distance(DVec3::Z) < 1e-12,
            "triangle {t}"
        );
    }
    assert_eq!(loaded.triangles[1], [1, 3, 2]);
    assert_eq!(loaded.triangles[2], [5, 6, 4]);
}

#[test]
fn gltf_sparse_and_quantized_accessors() {
    let mut g = GltfBuilder::default();
    let targets = g.view(&[1u16, 2].map(u16::to_le_bytes).concat());
    let values: Vec<u8> = [1f32, 0., 0., 0., 1., 0.]
        .iter()
        .flat_map(|c| c.to_le_bytes())
        .collect();
    let values = g.view(&values);
    let sparse = g.accessor(json!({
        "componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0],
        "sparse": { "count": 2, "indices": { "bufferView": targets, "componentType": 5123 },
                    "values": { "bufferView": values } }
    }));
    // Three VEC3 elements with a stride of 8 bytes: 2 bytes of padding (999) each.
    let shorts: Vec<u8> = [0i16, 0, 0, 999, 32767, 0, 0, 999, 0, 32767, 0, 999]
        .iter()
        .flat_map(|c| c.to_le_bytes())
        .collect();
    let view = g.view(&shorts);
    g.views[view]["byteStride"] = json!(8);
    let quantized = g.accessor(json!({
        "bufferView": view, "componentType": 5122, "normalized": true, "count": 3,
        "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]
    }));
    let a = g.mesh(sparse, None, 4);
    let b = g.mesh(quantized, None, 4);
    let nodes = [a, b].map(|mesh| g.node(json!({ "mesh": mesh })));
    g.scene(&nodes);
    let mut doc = g.json(None);
    doc["extensionsUsed"] = json!(["KHR_mesh_quantization"]);
    doc["extensionsRequired"] = json!(["KHR_mesh_quantization"]);
    let loaded = load(&common::glb(&doc, &g.bin), Format::Glb).unwrap();
    let expected = [DVec3::ZERO, DVec3::X, DVec3::Y];
    for (k, p) in loaded.positions.iter().enumerate() {
        assert_close(*p, expected[k % 3]);
    }
}

#[test]
fn gltf_scene_selection() {
    let mut g = GltfBuilder::default();
    let positions = g.positions(&[[0., 0., 0.], [1., 0., 0.], [0., 1., 0.]]);
    let mesh = g.mesh(positions, None, 4);
    let leaf = g.node(json!({ "mesh": mesh, "translation": [0.0, 0.0, 2.0] }));
    let a = g.node(json!({ "mesh": mesh, "children": [leaf] }));
    let b = g.node(json!({ "mesh": mesh, "translation": [0.0, 0.0, 1.0] }));
    // No scenes: every node that is no node's child is a root.
    let all = load(&g.glb(), Format::Glb).unwrap();
    assert_eq!(all.triangles.len(), 3);
    // Without `scene`, the first scene; with it, that scene.
    g.scene(&[a]);
    g.scene(&[b]);
    assert_eq!(load(&g.glb(), Format::Glb).unwrap().triangles.len(), 2);
    g.scene = Some(1);
    let only_b = load(&g.glb(), Format::Glb).unwrap();
    assert_eq!(only_b.triangles.len(), 1);
    assert_eq!(only_b.positions[0], DVec3::Z);
}

#[test]
fn off_variants() {
    for header in ["OFF\n", "", "COFF\n"] {
        let mesh = load(cube_off(header).as_bytes(), Format::Off).unwrap();
        assert_cube(&mesh);
    }
    let fused = "OFF 4 4 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 2 1\n3 0 1 3\n3 0 3 2\n3 1 2 3\n";
    assert_tetra(&load(fused.as_bytes(), Format::Off).unwrap());
    let crlf = fused.replace('\n', "\r\n");
    assert_tetra(&load(crlf.as_bytes(), Format::Off).unwrap());
}

/// Classic range scans store their surface as triangle strips, runs separated by -1.
#[test]
fn ply_triangle_strips() {
    let ply = "ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\nproperty float y\n\
               property float z\nelement tristrips 1\nproperty list int int vertex_indices\n\
               end_header\n0 0 0\n1 0 0\n0 1 0\n1 1 0\n2 2 0\n8 0 1 2 3 -1 3 2 4\n";
    let mesh = load(ply.as_bytes(), Format::Ply).unwrap();
    assert_eq!(mesh.triangles, [[0, 1, 2], [2, 1, 3], [3, 2, 4]]);
    let bad = ply.replace("3 2 4\n", "3 2 9\n");
    assert!(matches!(
        load(bad.as_bytes(), Format::Ply),
        Err(Error::IndexOutOfRange { index: 9, .. })
    ));
    // A text element's error names its line: the header's 9, then the second vertex.
    match load(ply.replace("1 0 0\n", "1 zero 0\n").as_bytes(), Format::Ply) {
        Err(Error::Parse { message, .. }) => assert!(message.starts_with("line 11:"), "{message}"),
        other => panic!("{other:?}"),
    }
}

#[test]
fn ply_ascii_and_binary() {
    assert_cube(&load(cube_ply_ascii().as_bytes(), Format::Ply).unwrap());
    assert_cube(&load(&cube_ply_le(), Format::Ply).unwrap());
    assert_cube(&load(&cube_ply_be(), Format::Ply).unwrap());
    // A binary body under a header whose lines end in a lone `\r` (Rhino writes these), or in
    // `\r\n`.
    for ending in [&b"\r"[..], b"\r\n"] {
        let le = cube_ply_le();
        let end = le.windows(11).position(|w| w == b"end_header\n").unwrap() + 11;
        let mut file = Vec::new();
        for line in le[..end].split(|&b| b == b'\n').filter(|l| !l.is_empty()) {
            file.extend_from_slice(line);
            file.extend_from_slice(ending);
        }
        file.extend_from_slice(&le[end..]);
        assert_cube(&load(&file, Format::Ply).unwrap());
    }
}

#[test]
fn stl_ascii_and_binary() {
    assert_tetra(&load(tetra_stl_ascii("").as_bytes(), Format::Stl).unwrap());
    assert_tetra(&load(tetra_stl_ascii(" named").as_bytes(), Format::Stl).unwrap());
    // Binary STLs whose header starts with "solid" are common.
    assert_tetra(&load(&tetra_stl_binary(b"solid exported"), Format::Stl).unwrap());
    assert_tetra(&load(&tetra_stl_binary(b"binary"), Format::Stl).unwrap());
    let two = tetra_stl_ascii(" a") + &tetra_stl_ascii(" b");
    let mesh = load(two.as_bytes(), Format::Stl).unwrap();
    assert_eq!(mesh.triangles.len(), 8);
    assert!((signed_volume(&mesh) - 2.0 / 6.0).abs() < 1e-12);
}

#[test]
fn load_path_sniffs_without_extension() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("upload");
    std::fs::write(&path, tetra_glb()).unwrap();
    assert_tetra(&load_path(&path, &Limits::default()).unwrap());
    std::fs::write(&path, b"nothing known").unwrap();
    assert!(matches!(
        load_path(&path, &Limits::default()),
        Err(Error::UnknownFormat(_))
    ));
    let missing = dir.path().join("missing.obj");
    assert!(matches!(
        load_path(&missing, &Limits::default()),
        Err(Error::Io { .. })
    ));
}

// ---------------------------------------------------------------------------------------
// The CAPOD fixture and its seam-split GLB twin

const CAPOD_OBJ: &str = "capod_horse_m155.obj";
const CAPOD_SPLIT_GLB: &str = "capod_horse_m155_split.glb";

#[test]
fn capod_fixture_and_split_twin() {
    let obj = load_path(&fixture(CAPOD_OBJ), &Limits::default()).unwrap();
    assert_eq!(obj.positions.len(), 346);
    assert_eq!(obj.triangles.len(), 688);
    let glb = load_path(&fixture(CAPOD_SPLIT_GLB), &Limits::default()).unwrap();
    assert_eq!(glb.positions.len(), 3 * 688);
    assert_eq!(glb.triangles.len(), 688);
    // Same oriented triangles at bit-identical positions, only the vertex sharing differs.
    assert_eq!(common::soup(&glb), common::soup(&obj));
    // The committed file is what the generator writes.
    assert_eq!(
        std::fs::read(fixture(CAPOD_SPLIT_GLB)).unwrap(),
        split_glb(&obj)
    );
}

#[test]
fn gltf_external_fixture_is_up_to_date() {
    let (json, bin) = external_tetra();
    assert_eq!(
        std::fs::read(fixture("gltf_external/tetra.gltf")).unwrap(),
        json
    );
    assert_eq!(
        std::fs::read(fixture("gltf_external/tetra.bin")).unwrap(),
        bin
    );
}

fn external_tetra() -> (Vec<u8>, Vec<u8>) {
    let (mut g, mesh) = tetra_builder();
    let node = g.node(json!({ "mesh": mesh }));
    g.scene(&[node]);
    let mut json = serde_json::to_vec_pretty(&g.json(Some("tetra.bin"))).unwrap();
    json.push(b'\n');
    (json, g.bin)
}

/// Rewrites the generated fixtures: `cargo test --test it -- --ignored load::regenerate`.
#[test]
#[ignore]
fn regenerate_fixtures() {
    let obj = load_path(&fixture(CAPOD_OBJ), &Limits::default()).unwrap();
    std::fs::write(fixture(CAPOD_SPLIT_GLB), split_glb(&obj)).unwrap();
    let (json, bin) = external_tetra();
    std::fs::create_dir_all(fixture("gltf_external")).unwrap();
    std::fs::write(fixture("gltf_external/tetra.gltf"), json).unwrap();
    std::fs::write(fixture("gltf_external/tetra.bin"), bin).unwrap();
}

/// Loads every mesh of the shared data sets and checks the counts against their own
/// headers and statistics. Ignored by default: the data sets are not in a clone (the SHREC'07
/// files may not be committed); run it beside them, where it fails if they are missing:
/// `cargo test --test it -- --ignored load::shared_data_sets` (`SALIENT_SHARED_DATA` names
/// the folder; default `../shared/data`).
#[test]
#[ignore = "needs the shared data sets (../shared/data)"]
fn shared_data_sets() {
    let data = std::env::var_os("SALIENT_SHARED_DATA").map_or_else(
        || Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data"),
        std::path::PathBuf::from,
    );
    let stats = std::fs::read_to_string(data.join("capod/mesh_stats.tsv"))
        .unwrap_or_else(|e| panic!("the shared data sets are not at {}: {e}", data.display()));
    let mut checked = 0;
    for line in stats.lines().skip(1) {
        let fields: Vec<&str> = line.split('\t').collect();
        let mesh = load_path(&data.join("capod").join(fields[0]), &Limits::default()).unwrap();
        checked += 1;
        assert_eq!(mesh.triangles.len().to_string(), fields[2], "{}", fields[0]);
        assert!(
            mesh.positions.len() <= fields[1].parse().unwrap(),
            "{}",
            fields[0]
        );
    }
    let shrec = data.join("shrec07-watertight");
    let classes = std::fs::read_dir(&shrec)
        .unwrap_or_else(|e| panic!("no SHREC'07 folder at {}: {e}", shrec.display()));
    for class in classes.flatten().filter(|c| c.path().is_dir()) {
        for file in std::fs::read_dir(class.path()).unwrap().flatten() {
            let path = file.path();
            if Format::from_path(&path) != Some(Format::Off) {
                continue;
            }
            let text = std::fs::read_to_string(&path).unwrap();
            let counts: Vec<usize> = text
                .lines()
                .nth(1)
                .unwrap()
                .split_whitespace()
                .map(|w| w.parse().unwrap())
                .collect();
            let mesh = load_path(&path, &Limits::default()).unwrap();
            checked += 1;
            assert_eq!(
                [mesh.positions.len(), mesh.triangles.len()],
                [counts[0], counts[1]],
                "{}",
                path.display()
            );
        }
    }
    assert!(
        checked > 500,
        "only {checked} meshes found under {}",
        data.display()
    );
}

// ---------------------------------------------------------------------------------------
// Bad input: typed errors

#[test]
fn empty_input() {
    assert!(matches!(load(b"", Format::Obj), Err(Error::NoTriangles)));
    for format in [
        Format::Gltf,
        Format::Glb,
        Format::Off,
        Format::Ply,
        Format::Stl,
    ] {
        let result = load(b"", format);
        assert!(
            matches!(&result, Err(Error::Parse { format: f, .. }) if *f == format),
            "{format}: {result:?}"
        );
    }
}

#[test]
fn random_bytes() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    for format in Format::ALL {
        for _ in 0..20 {
            let bytes: Vec<u8> = (0..rng.gen_range(1..2000)).map(|_| rng.gen()).collect();
            let result = load(&bytes, format);
            assert!(
                matches!(
                    result,
                    Err(Error::Parse { .. } | Error::NoTriangles | Error::TooLarge { .. })
                ),
                "{format}: {result:?}"
            );
        }
    }
}

#[test]
fn truncated_glb() {
    let glb = tetra_glb();
    for len in [0, 3, 4, 11, 12, 19, 20, 40, glb.len() / 2, glb.len() - 1] {
        let result = load(&glb[..len], Format::Glb);
        assert!(
            matches!(result, Err(Error::Parse { .. })),
            "{len}: {result:?}"
        );
    }
    // A declared total length below the header's own 12 bytes (a panic inside `gltf`).
    let mut short = glb.clone();
    short[8..12].copy_from_slice(&4u32.to_le_bytes());
    assert!(matches!(
        load(&short, Format::Glb),
        Err(Error::Parse { .. })
    ));
}

#[test]
fn out_of_range_indices() {
    let obj = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 10\n";
    let result = load(obj.as_bytes(), Format::Obj);
    assert!(
        matches!(
            result,
            Err(Error::IndexOutOfRange {
                face: 1,
                index: 9,
                vertex_count: 3
            })
        ),
        "{result:?}"
    );
    for bad in ["f 1 2 -4", "f 0 1 2"] {
        let obj = format!("v 0 0 0\nv 1 0 0\nv 0 1 0\n{bad}\n");
        let result = load(obj.as_bytes(), Format::Obj);
        assert!(
            matches!(result, Err(Error::Parse { .. })),
            "{bad}: {result:?}"
        );
    }
    let off = "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 3\n";
    let result = load(off.as_bytes(), Format::Off);
    assert!(
        matches!(
            result,
            Err(Error::IndexOutOfRange {
                face: 0,
                index: 3,
                ..
            })
        ),
        "{result:?}"
    );
    let ply = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n\
               property float z\nelement face 1\nproperty list uchar int vertex_indices\n\
               end_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 -1\n";
    assert!(matches!(
        load(ply.as_bytes(), Format::Ply),
        Err(Error::Parse { .. })
    ));
    let ply = ply.replace("3 0 1 -1", "3 0 1 7");
    assert!(matches!(
        load(ply.as_bytes(), Format::Ply),
        Err(Error::IndexOutOfRange { index: 7, .. })
    ));
    let mut g = GltfBuilder::default();
    let positions = g.positions(&[[0., 0., 0.], [1., 0., 0.], [0., 1., 0.]]);
    let indices = g.indices(&[0, 1, 3]);
    let mesh = g.mesh(positions, Some(indices), 4);
    let node = g.node(json!({ "mesh": mesh }));
    g.scene(&[node]);
    assert!(matches!(
        load(&g.glb(), Format::Glb),
        Err(Error::IndexOutOfRange {
            face: 0,
            index: 3,
            vertex_count: 3
        })
    ));
}

#[test]
fn obj_hostile_texture_index_does_not_panic() {
    // tobj multiplies this relative texture index unchecked; such lines never reach it.
    let obj = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/-5 2/1 3/1\n";
    assert_eq!(
        load(obj.as_bytes(), Format::Obj).unwrap().triangles.len(),
        1
    );
}

#[test]
fn non_finite_coordinates() {
    let obj = "v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n";
    assert!(matches!(
        load(obj.as_bytes(), Format::Obj),
        Err(Error::NonFinite { vertex: 1 })
    ));
    let off = "OFF\n3 1 0\n0 0 0\n1 0 0\n0 inf 0\n3 0 1 2\n";
    assert!(matches!(
        load(off.as_bytes(), Format::Off),
        Err(Error::NonFinite { vertex: 2 })
    ));
    // Text PLY numbers are digits only (the crate's grammar refuses `inf`), so binary here.
    let mut ply = cube_ply_le();
    let data = ply.len() - 8 * 24 - 6 * 17 - 4;
    ply[data + 8..data + 16].copy_from_slice(&f64::INFINITY.to_le_bytes());
    assert!(matches!(
        load(&ply, Format::Ply),
        Err(Error::NonFinite { vertex: 0 })
    ));
    let mut stl = tetra_stl_binary(b"binary");
    stl[84 + 12..84 + 16].copy_from_slice(&f32::NAN.to_le_bytes());
    assert!(matches!(
        load(&stl, Format::Stl),
        Err(Error::NonFinite { .. })
    ));
    let mut g = GltfBuilder::default();
    let positions = g.positions(&[[0., 0., 0.], [f32::INFINITY, 0., 0.], [0., 1., 0.]]);
    let mesh = g.mesh(positions, None, 4);
    let node = g.node(json!({ "mesh": mesh }));
    g.scene(&[node]);
    let mut doc = g.json(None);
    doc["accessors"][0]["max"] = json!([1, 1, 0]);
    assert!(matches!(
        load(&common::glb(&doc, &g.bin), Format::Glb),
        Err(Error::NonFinite { vertex: 1 })
    ));
}

#[test]
fn no_triangles() {
    for obj in [
        "v 0 0 0\nv 1 0 0\np 1\nf 1\n",
        "v 0 0 0\nv 1 0 0\nl 1 2\nf 1 2\n",
    ] {
        assert!(matches!(
            load(obj.as_bytes(), Format::Obj),
            Err(Error::NoTriangles)
        ));
    }
    let off = "OFF\n3 0 0\n0 0 0\n1 0 0\n0 1 0\n";
    assert!(matches!(
        load(off.as_bytes(), Format::Off),
        Err(Error::NoTriangles)
    ));
    let ply = "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\n\
               property float z\nend_header\n0 0 0\n1 0 0\n";
    assert!(matches!(
        load(ply.as_bytes(), Format::Ply),
        Err(Error::NoTriangles)
    ));
    assert!(matches!(
        load(b"solid x\nendsolid x\n", Format::Stl),
        Err(Error::NoTriangles)
    ));
    let mut g = GltfBuilder::default();
    let positions = g.positions(&[[0., 0., 0.], [1., 0., 0.], [0., 1., 0.]]);
    let lines = g.mesh(positions, None, 1);
    let node = g.node(json!({ "mesh": lines }));
    g.scene(&[node]);
    assert!(matches!(
        load(&g.glb(), Format::Glb),
        Err(Error::NoTriangles)
    ));
}

#[test]
fn missing_and_escaping_resources() {
    let (mut g, mesh) = tetra_builder();
    let node = g.node(json!({ "mesh": mesh }));
    g.scene(&[node]);
    let dir = tempfile::tempdir().unwrap();
    let sub = dir.path().join("models");
    std::fs::create_dir(&sub).unwrap();
    std::fs::write(dir.path().join("secret.bin"), &g.bin).unwrap();
    let secret = dir.path().join("secret.bin").display().to_string();
    for uri in [
        "missing.bin",
        "../secret.bin",
        "models/../../secret.bin",
        secret.as_str(),
    ] {
        let path = sub.join("model.gltf");
        std::fs::write(&path, serde_json::to_vec(&g.json(Some(uri))).unwrap()).unwrap();
        let result = load_path(&path, &Limits::default());
        assert!(
            matches!(&result, Err(Error::MissingResource { uri: u }) if u == uri),
            "{uri}: {result:?}"
        );
    }
    let path = sub.join("encoded.gltf");
    let doc = serde_json::to_vec(&g.json(Some("%2E%2E/secret.bin"))).unwrap();
    std::fs::write(&path, doc).unwrap();
    let result = load_path(&path, &Limits::default());
    assert!(
        matches!(&result, Err(Error::MissingResource { uri }) if uri == "../secret.bin"),
        "{result:?}"
    );
    assert_eq!(DirResources(sub.clone()).get("../secret.bin"), None);
    assert!(DirResources(dir.path().to_path_buf())
        .get("secret.bin")
        .is_some());
    // A supplied buffer shorter than its declared length.
    let doc = serde_json::to_vec(&g.json(Some("short.bin"))).unwrap();
    let parts = HashMap::from([("short.bin".to_string(), g.bin[..10].to_vec())]);
    assert!(matches!(
        load_bytes(&doc, Format::Gltf, &parts, &Limits::default()),
        Err(Error::Parse { .. })
    ));
}

#[test]
fn huge_declared_counts_in_tiny_files() {
    let mut stl = vec![0u8; 80];
    stl.extend(4_000_000_000u32.to_le_bytes());
    let result = load(&stl, Format::Stl);
    assert!(matches!(result, Err(Error::TooLarge { .. })), "{result:?}");
    stl[80..84].copy_from_slice(&1000u32.to_le_bytes());
    assert!(matches!(load(&stl, Format::Stl), Err(Error::Parse { .. })));

    for format in ["binary_little_endian", "ascii"] {
        for (count, expect_too_large) in [(4_000_000_000u64, true), (1_000_000, false)] {
            let ply = format!(
                "ply\nformat {format} 1.0\nelement vertex {count}\nproperty float x\n\
                 property float y\nproperty float z\nend_header\n"
            );
            let result = load(ply.as_bytes(), Format::Ply);
            if expect_too_large {
                assert!(matches!(result, Err(Error::TooLarge { .. })), "{result:?}");
            } else {
                assert!(matches!(result, Err(Error::Parse { .. })), "{result:?}");
            }
        }
    }
    // Elements without properties take no bytes: still bounded.
    let ply = "ply\nformat binary_little_endian 1.0\nelement nothing 3000000\nend_header\n";
    assert!(matches!(
        load(ply.as_bytes(), Format::Ply),
        Err(Error::Parse { .. })
    ));

    let result = load(b"OFF\n4000000000 1 0\n", Format::Off);
    assert!(matches!(result, Err(Error::TooLarge { .. })), "{result:?}");
    let result = load(b"OFF\n1000000 1000000 0\n0 0 0\n", Format::Off);
    assert!(matches!(result, Err(Error::Parse { .. })), "{result:?}");
    let result = load(b"OFF BINARY\n\x00\x00\x00\x08", Format::Off);
    assert!(
        matches!(&result, Err(Error::Parse { message, .. }) if message.contains("binary OFF")),
        "{result:?}"
    );

    let mut g = GltfBuilder::default();
    let positions = g.positions(&[[0., 0., 0.], [1., 0., 0.], [0., 1., 0.]]);
    let mesh = g.mesh(positions, None, 4);
    let node = g.node(json!({ "mesh": mesh }));
    g.scene(&[node]);
    let mut doc = g.json(None);
    doc["accessors"][0]["count"] = json!(4_000_000_000u64);
    let result = load(&common::glb(&doc, &g.bin), Format::Glb);
    assert!(matches!(result, Err(Error::TooLarge { .. })), "{result:?}");
    doc["accessors"][0]["count"] = json!(3_000_000);
    let result = load(&common::glb(&doc, &g.bin), Format::Glb);
    assert!(matches!(result, Err(Error::Parse { .. })), "{result:?}");
    // Sparse accessors without a buffer view are all zeros: only the limit bounds them.
    doc["accessors"][0] = json!({
        "componentType": 5126, "count": 4_000_000_000u64, "type": "VEC3",
        "min": [0, 0, 0], "max": [0, 0, 0],
        "sparse": { "count": 0, "indices": { "bufferView": 0, "componentType": 5125 },
                    "values": { "bufferView": 0 } }
    });
    let result = load(&common::glb(&doc, &g.bin), Format::Glb);
    assert!(matches!(result, Err(Error::TooLarge { .. })), "{result:?}");
}

#[test]
fn configured_limits_apply() {
    let limits = Limits {
        max_input_vertices: 7,
        max_input_triangles: 100,
        ..Limits::default()
    };
    for (bytes, format) in [
        (cube_obj().into_bytes(), Format::Obj),
        (cube_off("OFF\n").into_bytes(), Format::Off),
        (cube_ply_le(), Format::Ply),
    ] {
        let result = load_bytes(&bytes, format, &NoResources, &limits);
        assert!(
            matches!(
                result,
                Err(Error::TooLarge {
                    what: "vertices",
                    count: 8,
                    limit: 7
                })
            ),
            "{format}: {result:?}"
        );
    }
    let limits = Limits {
        max_input_vertices: 100,
        max_input_triangles: 11,
        ..Limits::default()
    };
    for (bytes, format) in [
        (cube_obj().into_bytes(), Format::Obj),
        (cube_off("OFF\n").into_bytes(), Format::Off),
        (cube_ply_ascii().into_bytes(), Format::Ply),
    ] {
        let result = load_bytes(&bytes, format, &NoResources, &limits);
        assert!(
            matches!(result, Err(Error::TooLarge { .. })),
            "{format}: {result:?}"
        );
    }
    let limits = Limits {
        max_input_vertices: 100,
        max_input_triangles: 3,
        ..Limits::default()
    };
    for (bytes, format) in [
        (tetra_glb(), Format::Glb),
        (tetra_stl_binary(b"x"), Format::Stl),
        (tetra_stl_ascii(" x").into_bytes(), Format::Stl),
    ] {
        let result = load_bytes(&bytes, format, &NoResources, &limits);
        assert!(
            matches!(
                result,
                Err(Error::TooLarge {
                    what: "triangles",
                    ..
                })
            ),
            "{format}: {result:?}"
        );
    }
}

#[test]
fn malformed_gltf_structure() {
    let (mut g, mesh) = tetra_builder();
    let a = g.node(json!({ "mesh": mesh, "children": [1] }));
    let b = g.node(json!({ "children": [0] }));
    g.scene(&[a]);
    let cycle = load(&g.glb(), Format::Glb);
    assert!(matches!(cycle, Err(Error::Parse { .. })), "{cycle:?}");
    g.nodes[b] = json!({});
    g.nodes.push(json!({ "children": [1, 1] }));
    g.scenes[0] = json!({ "nodes": [2] });
    let shared = load(&g.glb(), Format::Glb);
    assert!(matches!(shared, Err(Error::Parse { .. })), "{shared:?}");

    let mut doc = tetra_builder().0.json(None);
    doc["nodes"] = json!([{ "mesh": 0 }]);
    // A POSITION index out of range makes `gltf`'s own validation panic.
    for (pointer, value) in [
        ("/meshes/0/primitives/0/attributes/POSITION", json!(9)),
        ("/meshes/0/primitives/0/indices", json!(9)),
        ("/accessors/0/bufferView", json!(9)),
        ("/accessors/0/byteOffset", json!(40)),
        ("/accessors/0/type", json!("VEC2")),
        ("/accessors/1/componentType", json!(5126)),
        ("/bufferViews/0/byteLength", json!(4000)),
        ("/bufferViews/0/byteStride", json!(4)),
        ("/bufferViews/0/buffer", json!(3)),
        ("/nodes/0/mesh", json!(5)),
        ("/scene", json!(2)),
    ] {
        let mut bad = doc.clone();
        let (parent, key) = pointer.rsplit_once('/').unwrap();
        bad.pointer_mut(parent).unwrap()[key] = value;
        let tetra = common::glb(&bad, &tetra_builder().0.bin);
        let result = load(&tetra, Format::Glb);
        assert!(
            matches!(result, Err(Error::Parse { .. })),
            "{pointer}: {result:?}"
        );
    }
}

/// Files salient does not read are refused as unsupported, naming what they are and a
/// conversion, not as malformed; extensions that cannot change geometry are ignored.
#[test]
fn unsupported_files_name_their_kind_and_a_conversion() {
    let unsupported = |result: salient_core::Result<RawMesh>, kind: &str| match result {
        Err(Error::Unsupported {
            feature,
            conversion,
        }) => {
            assert!(feature.contains(kind), "{feature}");
            assert!(!conversion.is_empty());
        }
        other => panic!("{kind}: {other:?}"),
    };
    let doc = tetra_builder().0.json(None);
    let with_required = |names: serde_json::Value| {
        let mut doc = doc.clone();
        doc["nodes"] = json!([{ "mesh": 0 }]);
        doc["extensionsRequired"] = names;
        common::glb(&doc, &tetra_builder().0.bin)
    };
    unsupported(
        load(
            &with_required(json!(["EXT_some_future_geometry"])),
            Format::Glb,
        ),
        "EXT_some_future_geometry",
    );
    let harmless = load(
        &with_required(json!(["KHR_techniques_webgl", "KHR_materials_unlit"])),
        Format::Glb,
    );
    assert_tetra(&harmless.expect("extensions that cannot change geometry are ignored"));

    let gltf_1 = json!({"asset": {"version": "1.0"}, "meshes": {"m": {"primitives": []}}});
    unsupported(
        load(gltf_1.to_string().as_bytes(), Format::Gltf),
        "glTF 1.0",
    );

    let dir = tempfile::tempdir().unwrap();
    for (name, bytes, kind) in [
        (
            "chair.fbx",
            b"Kaydara FBX Binary  \x00\x1a\x00".to_vec(),
            "FBX",
        ),
        ("chair.bin", b"; FBX 7.4.0 project file\n".to_vec(), "FBX"),
        ("chair.blend", b"BLENDER-v402REND".to_vec(), "Blender"),
        ("chair.usdz", b"PK\x03\x04....chair.usdc".to_vec(), "USD"),
    ] {
        let path = dir.path().join(name);
        std::fs::write(&path, &bytes).unwrap();
        unsupported(
            salient_core::mesh::load_path(&path, &Limits::default()),
            kind,
        );
    }
    assert!(salient_core::mesh::unsupported(b"solid cube\nfacet", None).is_none());
    assert!(salient_core::mesh::unsupported(b"v 0 0 0\n", Some("cube.obj")).is_none());
}

/// A zip of a `.gltf` in a folder with its buffer (and an archiver's clutter), or of one mesh
/// file, loads as its mesh; what is not one mesh, or is over the limits, is refused before
/// anything is inflated.
#[test]
fn zip_archives_of_one_mesh() {
    let read = |name: &str| std::fs::read(fixture(name)).unwrap();
    let (gltf, bin) = (
        read("gltf_external/tetra.gltf"),
        read("gltf_external/tetra.bin"),
    );
    let dir = tempfile::tempdir().unwrap();
    let write = |name: &str, bytes: Vec<u8>| {
        let path = dir.path().join(name);
        std::fs::write(&path, bytes).unwrap();
        path
    };
    let tetra = common::zip(&[
        ("tetra/", b""),
        ("tetra/tetra.gltf", &gltf),
        ("tetra/tetra.bin", &bin),
        ("__MACOSX/tetra/._tetra.gltf", b"metadata"),
    ]);
    assert_tetra(&load_path(&write("tetra.zip", tetra.clone()), &Limits::default()).unwrap());
    // Named by its content alone.
    assert_tetra(&load_path(&write("download", tetra), &Limits::default()).unwrap());
    let cube = common::zip(&[("cube.obj", cube_obj().as_bytes())]);
    assert_cube(&load_path(&write("cube.zip", cube), &Limits::default()).unwrap());

    let archive_error = |bytes: Vec<u8>, limits: Limits| {
        salient_core::mesh::load::archive::unpack(&bytes, &limits).unwrap_err()
    };
    let two = common::zip(&[("a.obj", cube_obj().as_bytes()), ("b.stl", b"solid")]);
    match archive_error(two, Limits::default()) {
        Error::Archive(message) => assert!(message.contains("a.obj, b.stl"), "{message}"),
        other => panic!("{other:?}"),
    }
    let fbx = common::zip(&[("chair.fbx", b"Kaydara FBX Binary  \x00")]);
    assert!(matches!(
        archive_error(fbx, Limits::default()),
        Error::Unsupported { .. }
    ));
    assert!(matches!(
        archive_error(b"PK\x03\x04 not a zip".to_vec(), Limits::default()),
        Error::Archive(_)
    ));
    // A bomb: 8 MB of zeros deflate to a few KB; refused by what it declares.
    let zeros = vec![0u8; 8 << 20];
    let bomb = common::zip(&[("bomb.obj", &zeros)]);
    assert!(bomb.len() < 64 << 10);
    let limits = Limits {
        max_unpacked_bytes: 1 << 20,
        ..Limits::default()
    };
    assert!(matches!(
        archive_error(bomb.clone(), limits),
        Error::TooLarge {
            what: "bytes unpacked",
            ..
        }
    ));
    // The same bomb declaring 10 bytes: it stops at 11 and is refused.
    let mut lying = bomb;
    for (signature, offset) in [(&b"PK\x03\x04"[..], 22), (&b"PK\x01\x02"[..], 24)] {
        let at = lying.windows(4).position(|w| w == signature).unwrap() + offset;
        lying[at..at + 4].copy_from_slice(&10u32.to_le_bytes());
    }
    assert!(matches!(
        archive_error(lying, Limits::default()),
        Error::Archive(_)
    ));
    let many = common::zip(&[("a.obj", b"v 0 0 0"), ("b.txt", b""), ("c.txt", b"")]);
    let limits = Limits {
        max_archive_entries: 2,
        ..Limits::default()
    };
    assert!(matches!(
        archive_error(many, limits),
        Error::TooLarge {
            what: "archive entries",
            ..
        }
    ));
}

// ---------------------------------------------------------------------------------------
// Fuzzing: mutated valid files and random bytes must give Ok or Err, never a panic.

/// A glTF using most of what the loader reads: a node hierarchy with matrix and TRS
/// transforms, a mirror, indexed triangles, a strip, a fan, a sparse accessor, points.
fn rich_gltf() -> (serde_json::Value, Vec<u8>) {
    let (mut g, tetra) = tetra_builder();
    let quad = g.positions(&[[0., 0., 0.], [1., 0., 0.], [0., 1., 0.], [1., 1., 0.]]);
    let strip = g.mesh(quad, None, 5);
    let fan_indices = g.indices(&[0, 1, 3, 2]);
    let fan = g.mesh(quad, Some(fan_indices), 6);
    let points = g.mesh(quad, None, 0);
    let targets = g.view(&[1u32.to_le_bytes(), 2u32.to_le_bytes()].concat());
    let values: Vec<u8> = [1f32, 0., 0., 0., 1., 0.]
        .iter()
        .flat_map(|c| c.to_le_bytes())
        .collect();
    let values = g.view(&values);
    let sparse = g.accessor(json!({
        "componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0],
        "sparse": { "count": 2, "indices": { "bufferView": targets, "componentType": 5125 },
                    "values": { "bufferView": values } }
    }));
    let sparse = g.mesh(sparse, None, 4);
    let leaves = [strip, fan, points, sparse].map(|mesh| g.node(json!({ "mesh": mesh })));
    let mirror = g.node(json!({ "mesh": tetra, "scale": [1.0, -2.0, 1.0], "children": leaves }));
    let root = g.node(json!({
        "matrix": [0.0, 1.0, 0.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 3.0, 0.0, 0.0, 1.0],
        "children": [mirror]
    }));
    let turned = g
        .node(json!({ "mesh": tetra, "rotation": [0.0, 0.6, 0.0, 0.8], "translation": [1, 2, 3] }));
    g.scene(&[root, turned]);
    g.scene = Some(0);
    (g.json(None), g.bin)
}

fn samples() -> Vec<(Format, Vec<u8>)> {
    let (rich, bin) = rich_gltf();
    vec![
        (Format::Obj, cube_obj().into_bytes()),
        (Format::Gltf, tetra_gltf_data_uri()),
        (Format::Glb, tetra_glb()),
        (Format::Glb, common::glb(&rich, &bin)),
        (Format::Off, cube_off("OFF\n").into_bytes()),
        (Format::Ply, cube_ply_ascii().into_bytes()),
        (Format::Ply, cube_ply_le()),
        (Format::Ply, cube_ply_be()),
        (Format::Stl, tetra_stl_ascii(" t").into_bytes()),
        (Format::Stl, tetra_stl_binary(b"solid")),
    ]
    .into_iter()
    .chain(COMPRESSED.map(|name| (Format::Glb, std::fs::read(fixture(name)).unwrap())))
    .chain([(
        Format::ThreeMf,
        std::fs::read(fixture("3mf/horse_production.3mf")).unwrap(),
    )])
    .collect()
}

/// Compressed glTF fixtures, fuzzed as files and in their binary chunk alone.
const COMPRESSED: [&str; 4] = [
    "web/horse_meshopt.glb",
    "web/horse_meshopt_khr.glb",
    "web/horse_draco.glb",
    "web/horse_instanced.glb",
];

fn mutate(rng: &mut ChaCha8Rng, input: &[u8]) -> Vec<u8> {
    const NUMBERS: [&[u8]; 8] = [
        b"0",
        b"-1",
        b"4294967295",
        b"4294967296",
        b"99999999999999999999",
        b"1e308",
        b"nan",
        b"-2147483648",
    ];
    let mut bytes = input.to_vec();
    for _ in 0..rng.gen_range(1..4) {
        let at = rng.gen_range(0..=bytes.len());
        match rng.gen_range(0..6) {
            0 if !bytes.is_empty() => {
                let i = rng.gen_range(0..bytes.len());
                bytes[i] ^= 1 << rng.gen_range(0..8);
            }
            1 => {
                let extra: Vec<u8> = (0..rng.gen_range(1..8)).map(|_| rng.gen()).collect();
                bytes.splice(at..at, extra);
            }
            2 => bytes.truncate(at),
            3 => {
                // Replace a run of digits by a hostile number.
                let digits: Vec<usize> = (0..bytes.len())
                    .filter(|&i| bytes[i].is_ascii_digit())
                    .collect();
                if let Some(&start) = digits.get(rng.gen_range(0..digits.len().max(1))) {
                    let end = (start..bytes.len())
                        .find(|&i| !bytes[i].is_ascii_digit())
                        .unwrap_or(bytes.len());
                    let number = NUMBERS[rng.gen_range(0..NUMBERS.len())];
                    bytes.splice(start..end, number.iter().copied());
                }
            }
            4 if bytes.len() >= 4 => {
                // Overwrite a little-endian word with an extreme value.
                let i = rng.gen_range(0..bytes.len() - 3);
                let word = [0u32, 1, 0xFFFF_FFFF, 0x8000_0000, 0x7FFF_FFFF][rng.gen_range(0..5)];
                bytes[i..i + 4].copy_from_slice(&word.to_le_bytes());
            }
            _ if !bytes.is_empty() => {
                let i = rng.gen_range(0..bytes.len());
                bytes.remove(i);
            }
            _ => {}
        }
    }
    bytes
}

#[test]
fn fuzz_never_panics() {
    // A longer local run: SALIENT_FUZZ_CASES=100000 SALIENT_FUZZ_SEED=7.
    let env = |name: &str, default: u64| {
        std::env::var(name)
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(default)
    };
    let per_sample = env("SALIENT_FUZZ_CASES", 300) as usize;
    let mut rng = ChaCha8Rng::seed_from_u64(env("SALIENT_FUZZ_SEED", 0x5a11e47));
    let mut cases: Vec<(Format, Vec<u8>)> = Vec::new();
    for format in Format::ALL {
        for _ in 0..per_sample / 3 {
            let len = rng.gen_range(0..600);
            cases.push((format, (0..len).map(|_| rng.gen()).collect()));
        }
    }
    for (format, sample) in samples() {
        assert!(load(&sample, format).is_ok(), "{format} sample must load");
        for _ in 0..per_sample {
            cases.push((format, mutate(&mut rng, &sample)));
        }
    }
    // The glTF JSON mutated inside a well-formed GLB container, to get past the chunk checks.
    let (rich, bin) = rich_gltf();
    let text = serde_json::to_vec(&rich).unwrap();
    for _ in 0..per_sample {
        let json = mutate(&mut rng, &text);
        cases.push((Format::Glb, common::glb_from_text(&json, &bin)));
    }
    // A 3MF model part mutated inside a well-formed package, to reach the XML reader.
    let part = format!(
        r#"<model><resources>{TETRA_3MF_OBJECT}<object id="2"><components><component objectid="1" transform="1 0 0 0 1 0 0 0 1 0 0 0"/></components></object></resources><build><item objectid="2"/></build></model>"#
    );
    assert!(load(&three_mf(&part), Format::ThreeMf).is_ok());
    for _ in 0..per_sample {
        let xml = mutate(&mut rng, part.as_bytes());
        cases.push((Format::ThreeMf, common::zip(&[("3D/3dmodel.model", &xml)])));
    }
    // The compressed streams mutated inside their well-formed containers, to reach the
    // meshopt and Draco decoders.
    for name in COMPRESSED {
        let (doc, bin) = common::split_glb_chunks(&std::fs::read(fixture(name)).unwrap());
        for _ in 0..per_sample {
            let mut bin = mutate(&mut rng, &bin);
            bin.resize(bin.len().max(8), 0);
            cases.push((Format::Glb, common::glb(&doc, &bin)));
        }
    }

    let mut panics = Vec::new();
    let mut loaded = 0;
    for (format, bytes) in &cases {
        // Whatever loads goes through preparation and ECC too: mutated files make odd meshes.
        let outcome = std::panic::catch_unwind(|| {
            Format::sniff(bytes);
            load(bytes, *format).map(|raw| {
                let _ = salient_core::pipeline::extract(&raw, &salient_core::Params::default());
            })
        });
        match outcome {
            Ok(Ok(())) => loaded += 1,
            Ok(Err(_)) => {}
            Err(_) => panics.push((*format, String::from_utf8_lossy(bytes).into_owned())),
        }
    }
    eprintln!(
        "fuzz: {} cases, {loaded} loaded, {} panicked",
        cases.len(),
        panics.len()
    );
    assert!(
        panics.is_empty(),
        "{} of {} cases panicked, first: {:?}",
        panics.len(),
        cases.len(),
        panics.first()
    );
}

// ---------------------------------------------------------------------------------------
// glTF as web pipelines write it: fixtures made by gltfpack and gltf-transform
// (`tests/fixtures/web/make.sh`)

/// The axis-aligned bounding box of a mesh's positions.
fn bounds(mesh: &RawMesh) -> (DVec3, DVec3) {
    mesh.positions.iter().fold(
        (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
        |(lo, hi), &p| (lo.min(p), hi.max(p)),
    )
}

/// Each compressed variant has its original's triangles, and its bounding box within the
/// quantisation step (14 bits of the extent for gltfpack, 16 for gltf-transform, Draco's 14).
#[test]
fn compressed_gltf_matches_its_original() {
    let web = |name: &str| load_path(&fixture(&format!("web/{name}")), &Limits::default());
    let plain = web("horse_plain.glb").unwrap();
    assert_eq!(plain.triangles.len(), 688);
    let (lo, hi) = bounds(&plain);
    let step = (hi - lo).max_element() / f64::from(1 << 13);
    for name in common::COMPRESSED_HORSES {
        let mesh = web(name).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(mesh.triangles.len(), plain.triangles.len(), "{name}");
        let (l, h) = bounds(&mesh);
        assert!(
            (l - lo).abs().max_element() <= step && (h - hi).abs().max_element() <= step,
            "{name}: {l}..{h} against {lo}..{hi}"
        );
        assert!(
            (signed_volume(&mesh) / signed_volume(&plain) - 1.0).abs() < 0.01,
            "{name}: the triangles keep their winding"
        );
    }
}

/// `EXT_mesh_gpu_instancing`: each instance is a placed copy, as the nodes it replaced.
#[test]
fn gpu_instances_are_placed_copies() {
    let web = |name: &str| load_path(&fixture(&format!("web/{name}")), &Limits::default()).unwrap();
    let nodes = web("horse_three.glb");
    let instanced = web("horse_instanced.glb");
    assert_eq!(nodes.triangles.len(), 3 * 688);
    assert_eq!(instanced.triangles.len(), nodes.triangles.len());
    let (lo, hi) = bounds(&nodes);
    let (l, h) = bounds(&instanced);
    let step = (hi - lo).max_element() / f64::from(1 << 12);
    assert!(
        (l - lo).abs().max_element() <= step && (h - hi).abs().max_element() <= step,
        "{l}..{h} against {lo}..{hi}"
    );
    assert!((signed_volume(&instanced) / signed_volume(&nodes) - 1.0).abs() < 0.01);
}

/// Hostile compressed files: counts a stream declares are checked against the limits before
/// anything is allocated, and parameters the decoders would assert on are refused.
#[test]
fn hostile_compressed_gltf_is_refused() {
    let bytes = std::fs::read(fixture("web/horse_meshopt.glb")).unwrap();
    let edit = |change: &dyn Fn(&mut serde_json::Value)| {
        let (mut doc, bin) = common::split_glb_chunks(&bytes);
        change(&mut doc);
        common::glb(&doc, &bin)
    };
    let meshopt = |view: usize| format!("/bufferViews/{view}/extensions/EXT_meshopt_compression");
    // A view that claims 2^40 vertices of 256 bytes.
    let huge = edit(&|doc| {
        let ext = doc.pointer_mut(&meshopt(0)).unwrap();
        ext["count"] = json!(1u64 << 40);
        ext["byteStride"] = json!(256);
    });
    match load(&huge, Format::Glb) {
        Err(Error::Parse { message, .. }) => assert!(message.contains("limits"), "{message}"),
        other => panic!("{other:?}"),
    }
    // Strides and counts meshoptimizer would abort on.
    for (field, value) in [
        ("byteStride", json!(6)),
        ("byteStride", json!(0)),
        ("mode", json!("TRIANGLES")),
    ] {
        let bad = edit(&|doc| {
            doc.pointer_mut(&meshopt(0)).unwrap()[field] = value.clone();
        });
        assert!(
            matches!(load(&bad, Format::Glb), Err(Error::Parse { .. })),
            "{field}={value}"
        );
    }
    let bad_filter = edit(&|doc| {
        doc.pointer_mut(&meshopt(1)).unwrap()["filter"] = json!("OCTAHEDRAL");
    });
    assert!(matches!(
        load(&bad_filter, Format::Glb),
        Err(Error::Parse { .. })
    ));
    // A compressed stream cut short, and one out of its buffer.
    let cut = edit(&|doc| {
        doc.pointer_mut(&meshopt(0)).unwrap()["byteLength"] = json!(100);
    });
    assert!(matches!(load(&cut, Format::Glb), Err(Error::Parse { .. })));
    let outside = edit(&|doc| {
        doc.pointer_mut(&meshopt(0)).unwrap()["byteOffset"] = json!(1u64 << 32);
    });
    assert!(matches!(
        load(&outside, Format::Glb),
        Err(Error::Parse { .. })
    ));

    // Draco: a triangle limit below the stream's is refused as too large, a corrupt stream
    // as malformed.
    let draco = std::fs::read(fixture("web/horse_draco.glb")).unwrap();
    let limits = Limits {
        max_input_triangles: 100,
        ..Limits::default()
    };
    assert!(matches!(
        load_bytes(&draco, Format::Glb, &NoResources, &limits),
        Err(Error::DecodesTooLarge(_))
    ));
    let (doc, mut bin) = common::split_glb_chunks(&draco);
    for byte in bin.iter_mut().skip(40).step_by(7) {
        *byte ^= 0x5A;
    }
    assert!(load(&common::glb(&doc, &bin), Format::Glb).is_err());
}

// ---------------------------------------------------------------------------------------
// 3MF: fixtures written by lib3mf, the 3MF Consortium's library (`tests/fixtures/3mf/make.py`)

/// The OBJ horse's positions, each moved by `f`.
fn horse_positions(f: impl Fn(DVec3) -> DVec3) -> Vec<DVec3> {
    let obj = load_path(&fixture(CAPOD_OBJ), &Limits::default()).unwrap();
    obj.positions.into_iter().map(f).collect()
}

fn assert_positions_close(actual: &[DVec3], expected: &[DVec3]) {
    assert_eq!(actual.len(), expected.len());
    for (a, e) in actual.iter().zip(expected) {
        assert!(a.distance(*e) < 1e-5 * e.length().max(1.0), "{a} != {e}");
    }
}

/// Two build items of one components object: two placed copies; the Production extension's
/// `p:path` part in inches: the horse in millimetres.
#[test]
fn three_mf_build_items_components_and_parts() {
    let two = load_path(&fixture("3mf/horse_two_items.3mf"), &Limits::default()).unwrap();
    assert_eq!(two.triangles.len(), 2 * 688);
    let mut expected = horse_positions(|p| p);
    // The second item's transform `0 1 0 -1 0 0 0 0 1 1 0 0`: x' = 1 - y, y' = x.
    expected.extend(horse_positions(|p| DVec3::new(1.0 - p.y, p.x, p.z)));
    assert_positions_close(&two.positions, &expected);
    assert!(signed_volume(&two) > 0.0, "windings kept");

    let inches = load_path(&fixture("3mf/horse_production.3mf"), &Limits::default()).unwrap();
    assert_eq!(inches.triangles.len(), 688);
    assert_positions_close(&inches.positions, &horse_positions(|p| p * 25.4));

    // Recognised by content, whatever the name.
    let dir = tempfile::tempdir().unwrap();
    let unnamed = dir.path().join("download");
    std::fs::copy(fixture("3mf/horse_two_items.3mf"), &unnamed).unwrap();
    assert_eq!(load_path(&unnamed, &Limits::default()).unwrap(), two);
    let bytes = std::fs::read(fixture("3mf/horse_two_items.3mf")).unwrap();
    assert_eq!(Format::sniff(&bytes), Some(Format::ThreeMf));
}

/// A minimal 3MF package around one model part.
fn three_mf(model: &str) -> Vec<u8> {
    common::zip(&[("3D/3dmodel.model", model.as_bytes())])
}

const TETRA_3MF_OBJECT: &str = r#"<object id="1"><mesh><vertices>
<vertex x="0" y="0" z="0"/><vertex x="1" y="0" z="0"/><vertex x="0" y="1" z="0"/><vertex x="0" y="0" z="1"/>
</vertices><triangles>
<triangle v1="0" v2="2" v3="1"/><triangle v1="0" v2="1" v3="3"/><triangle v1="0" v2="3" v3="2"/><triangle v1="1" v2="2" v3="3"/>
</triangles></mesh></object>"#;

/// What a 3MF may hold that cannot be read: required extensions that change geometry
/// (unsupported, with a conversion), component cycles, bad references and indices, support
/// objects (left out), and counts over the limits.
#[test]
fn three_mf_refusals_and_limits() {
    let model = |attributes: &str, resources: &str, build: &str| {
        three_mf(&format!(
            r#"<?xml version="1.0" encoding="UTF-8"?>
<model unit="millimeter" xmlns="http://schemas.microsoft.com/3dmanufacturing/core/2015/02" {attributes}>
<resources>{resources}</resources><build>{build}</build></model>"#
        ))
    };
    let tetra = load(
        &model("", TETRA_3MF_OBJECT, r#"<item objectid="1"/>"#),
        Format::ThreeMf,
    )
    .unwrap();
    assert_tetra(&tetra);

    let slices = model(
        r#"xmlns:s="http://schemas.microsoft.com/3dmanufacturing/slice/2015/07" requiredextensions="s""#,
        TETRA_3MF_OBJECT,
        r#"<item objectid="1"/>"#,
    );
    match load(&slices, Format::ThreeMf) {
        Err(Error::Unsupported { feature, .. }) => assert!(feature.contains("slice"), "{feature}"),
        other => panic!("{other:?}"),
    }
    let production = model(
        r#"xmlns:p="http://schemas.microsoft.com/3dmanufacturing/production/2015/06" requiredextensions="p""#,
        TETRA_3MF_OBJECT,
        r#"<item objectid="1"/>"#,
    );
    assert_tetra(&load(&production, Format::ThreeMf).unwrap());

    let parse_error = |bytes: Vec<u8>, expected: &str| match load(&bytes, Format::ThreeMf) {
        Err(Error::Parse { message, .. }) => assert!(message.contains(expected), "{message}"),
        other => panic!("{expected}: {other:?}"),
    };
    let cycle = r#"<object id="2"><components><component objectid="3"/></components></object>
        <object id="3"><components><component objectid="2"/></components></object>"#;
    parse_error(
        model("", cycle, r#"<item objectid="2"/>"#),
        "nest more than",
    );
    parse_error(
        model("", TETRA_3MF_OBJECT, r#"<item objectid="9"/>"#),
        "object 9",
    );
    parse_error(
        model(
            "",
            &TETRA_3MF_OBJECT.replace(r#"v3="3""#, r#"v3="7""#),
            r#"<item objectid="1"/>"#,
        ),
        "vertex 7",
    );
    parse_error(
        model(
            "",
            TETRA_3MF_OBJECT,
            r#"<item objectid="1" transform="1 0 0"/>"#,
        ),
        "twelve numbers",
    );
    parse_error(three_mf("<model><resources><object id=\"1\">"), "cut short");
    parse_error(
        common::zip(&[("3D/other.model", b"<model/>")]),
        "no model part",
    );
    // A support structure is not the design.
    let support =
        TETRA_3MF_OBJECT.replace(r#"<object id="1">"#, r#"<object id="1" type="support">"#);
    assert!(matches!(
        load(
            &model("", &support, r#"<item objectid="1"/>"#),
            Format::ThreeMf
        ),
        Err(Error::NoTriangles)
    ));
    // A placement that multiplies a mesh past the triangle limit is refused before it is
    // appended.
    let many: String = (0..50).map(|_| r#"<component objectid="1"/>"#).collect();
    let assembly =
        format!(r#"{TETRA_3MF_OBJECT}<object id="2"><components>{many}</components></object>"#);
    let limits = Limits {
        max_input_triangles: 100,
        ..Limits::default()
    };
    assert!(matches!(
        load_bytes(
            &model("", &assembly, r#"<item objectid="2"/>"#),
            Format::ThreeMf,
            &NoResources,
            &limits
        ),
        Err(Error::TooLarge {
            what: "triangles",
            ..
        })
    ));
}
