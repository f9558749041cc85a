//! Salient points, signatures and their comparison on generated shapes with known answers
//! (SPEC §3–5).

use crate::shapes;

use salient_core::pipeline::compute;
use salient_core::signature::Staleness;
use salient_core::similarity::compare;
use salient_core::{Error, Params, Signature};

fn signature(raw: &salient_core::mesh::RawMesh) -> Signature {
    compute(raw, &Params::default()).expect("generated meshes extract")
}

#[test]
fn one_salient_point_on_each_tip_of_a_star() {
    let tips = shapes::five_tips();
    let s = signature(&shapes::star(4, &tips));
    assert_eq!(s.features.len(), tips.len(), "{:?}", s.stats.salient);
    for tip in &tips {
        let near: Vec<_> = s
            .features
            .iter()
            .filter(|f| glam::DVec3::from(f.position).angle_between(*tip) < 0.2)
            .collect();
        assert_eq!(near.len(), 1, "tip {tip}");
    }
    for f in &s.features {
        // On a tip: far from the body (radius 0.5) and sharply convex.
        assert!(glam::DVec3::from(f.position).length() > 1.0);
        assert!(f.ecc.iter().sum::<f64>() > 0.0);
        assert!((f.d2.iter().map(|&h| h as f64).sum::<f64>() - 1.0).abs() < 1e-6);
        assert!(f.region_area > 0.0 && f.region_size > 0.0);
    }
}

#[test]
fn the_same_mesh_gives_the_same_bytes_on_any_thread_count() {
    let raw = shapes::star(4, &shapes::five_tips());
    let on = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| signature(&raw))
    };
    let (one, two, again) = (on(1), on(2), on(2));
    let strip = |mut s: Signature| {
        // Timings differ from run to run; everything else must not.
        s.stats = Default::default();
        s.to_bytes()
    };
    let bytes = strip(one);
    assert_eq!(bytes, strip(two));
    assert_eq!(bytes, strip(again));
}

#[test]
fn rigid_motion_and_scale_barely_change_the_signature() {
    let star = shapes::star(4, &shapes::five_tips());
    let original = signature(&star);
    let moved = signature(&shapes::transformed(&star, shapes::random_motion(9)));
    let others = [
        signature(&shapes::cone(0.5, 40, 48)),
        signature(&shapes::tube(0.2, 60, 24)),
        signature(&shapes::icosphere(4)),
    ];
    let params = Params::default().similarity;
    let same = compare(&original, &moved, &params).sim;
    let different = others
        .iter()
        .map(|o| compare(&original, o, &params).sim)
        .fold(f64::INFINITY, f64::min);
    eprintln!("SIM moved {same:.5}, nearest other shape {different:.5}");
    assert_eq!(moved.features.len(), original.features.len());
    assert!(same < 0.02, "{same}");
    assert!(same * 10.0 < different, "{same} vs {different}");
    assert_eq!(compare(&original, &original, &params).sim, 0.0);
}

#[test]
fn penalty_multiplies_the_emd() {
    let five = signature(&shapes::star(4, &shapes::five_tips()));
    let three = signature(&shapes::star(4, &shapes::five_tips()[..3]));
    let mut params = Params::default().similarity;
    let with = compare(&five, &three, &params);
    params.penalty = false;
    let without = compare(&five, &three, &params);
    assert_eq!((with.m, with.n), (5, 3));
    assert_eq!(with.emd, without.emd);
    assert!((with.sim - with.emd * 5.0 / 3.0).abs() < 1e-12);
    assert_eq!(without.sim, without.emd);
}

#[test]
fn binary_form_round_trips_compactly_and_refuses_garbage() {
    let fixture = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/capod_horse_m155.obj");
    let raw = salient_core::mesh::load_path(&fixture, &Default::default()).unwrap();
    let s = signature(&raw);
    let bytes = s.to_bytes();
    let without_lfd = Signature {
        lfd: None,
        ..s.clone()
    }
    .to_bytes();
    eprintln!(
        "{} features, {} bytes ({} without the light field descriptor)",
        s.features.len(),
        bytes.len(),
        without_lfd.len()
    );
    assert!(without_lfd.len() < 2048);
    // The light field's 4 500 coefficients, compressed (uncompressed, its section took 4 604
    // bytes; here about 3 570).
    assert!(bytes.len() - without_lfd.len() < 4000);
    let back = Signature::from_bytes(&bytes).unwrap();
    assert_eq!(back.lfd, s.lfd);
    let (g, h) = (back.geodesic.clone().unwrap(), s.geodesic.clone().unwrap());
    for (a, b) in [
        (&g.distances, &h.distances),
        (&g.eccentricity, &h.eccentricity),
    ] {
        assert_eq!(a.len(), salient_core::descriptor::geodesic::BINS);
        assert!(a
            .iter()
            .zip(b)
            .all(|(x, y)| (x - y).abs() <= 0.5 / 65535.0 + 1e-7));
    }
    assert_eq!(back.mesh_hash, s.mesh_hash);
    assert_eq!(back.params, s.params);
    assert_eq!(back.features.len(), s.features.len());
    for (a, b) in back.features.iter().zip(&s.features) {
        assert_eq!(a.vertex, b.vertex);
        assert!(a.ecc.iter().zip(&b.ecc).all(|(x, y)| (x - y).abs() < 1e-6));
        assert!(a
            .d2
            .iter()
            .zip(&b.d2)
            .all(|(x, y)| (x - y).abs() <= 0.5 / 65535.0 + 1e-7));
    }
    // Re-encoding the decoded form is stable.
    assert_eq!(back.to_bytes(), bytes);
    // Comparing through the binary form changes nothing that matters.
    let params = Params::default().similarity;
    assert!(compare(&back, &s, &params).sim < 1e-4);

    assert!(matches!(
        Signature::from_bytes(b"nope"),
        Err(Error::CorruptSignature { .. })
    ));
    assert!(matches!(
        Signature::from_bytes(&bytes[..bytes.len() / 2]),
        Err(Error::CorruptSignature { .. })
    ));
    let mut future = bytes.clone();
    future[4] = 99;
    assert!(matches!(
        Signature::from_bytes(&future),
        Err(Error::SignatureFormat { found: 99, .. })
    ));

    let json = serde_json::to_string(&s).unwrap();
    assert_eq!(serde_json::from_str::<Signature>(&json).unwrap(), s);
}

/// Format 3 (uncompressed sections) still reads, and says what today's extraction says: the
/// golden file of the horse fixture equals its extraction now, through the binary form.
#[test]
fn format_3_signatures_read_as_extracted_today() {
    let golden = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/golden/format-3/capod-horse-m155.sig");
    let v3 = std::fs::read(golden).unwrap();
    assert_eq!(Signature::format_of(&v3), Some(3));
    let mut stored = Signature::from_bytes(&v3).unwrap();
    assert_eq!(stored.staleness(&Params::default()), None);
    let fixture = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/capod_horse_m155.obj");
    let raw = salient_core::mesh::load_path(&fixture, &Default::default()).unwrap();
    let today = signature(&raw).to_bytes();
    assert_eq!(
        Signature::format_of(&today),
        Some(salient_core::signature::SIGNATURE_FORMAT)
    );
    assert!(
        today.len() < v3.len() * 3 / 4,
        "{} against {}",
        today.len(),
        v3.len()
    );
    let mut today = Signature::from_bytes(&today).unwrap();
    // Timings differ from run to run, and ranking parameters are not the signature's (the
    // file holds those of its day); everything else must not differ.
    (stored.stats, today.stats) = Default::default();
    assert!(stored.params.same_extraction(&today.params));
    stored.params = today.params.clone();
    assert_eq!(stored, today);
}

/// Format 4's dictionary is part of the format: changed, every stored format-4 signature would
/// be unreadable.
#[test]
fn the_format_4_dictionary_never_changes() {
    use sha2::{Digest, Sha256};
    assert_eq!(
        hex::encode(Sha256::digest(salient_core::signature::DICTIONARY)),
        "de0e481ede4927790fdb30d3c2dacd09d1998e99e2d794a60d9a053915d55a72"
    );
}

/// Format 1 (release 0.1.0 before the light field descriptor) is format 2 without the
/// optional descriptor at its end: cut from a golden format-2 file, it reads without one.
#[test]
fn format_1_signatures_read_without_a_light_field_descriptor() {
    let v2 = std::fs::read(crate::golden::golden().join("tetra.sig")).unwrap();
    let s = Signature::from_bytes(&v2).unwrap();
    assert!(s.lfd.is_some());
    // `Some` (one byte) and the descriptor: its length and 100 × (length byte + 45 bytes).
    let descriptor = 1 + 1 + 100 * 46;
    let mut v1 = v2[..v2.len() - descriptor].to_vec();
    v1[4..6].copy_from_slice(&1u16.to_le_bytes());
    let old = Signature::from_bytes(&v1).unwrap();
    assert_eq!(old.lfd, None);
    assert_eq!(old.features, s.features);
    assert_eq!(
        old.staleness(&Params::default()),
        Some(Staleness::Parameters)
    );
    // Trailing bytes in a format-1 record, or a descriptor with images missing, are corrupt.
    let mut trailing = v1.clone();
    trailing.push(7);
    assert!(matches!(
        Signature::from_bytes(&trailing),
        Err(Error::CorruptSignature { .. })
    ));
    let mut json = serde_json::to_value(&s).unwrap();
    json["lfd"].as_array_mut().unwrap().pop();
    let error = serde_json::from_value::<Signature>(json.clone()).unwrap_err();
    assert!(error.to_string().contains("100 images"), "{error}");
    let mut short = v2[..v2.len() - descriptor].to_vec();
    short.extend(postcard_descriptor(&json));
    assert!(matches!(
        Signature::from_bytes(&short),
        Err(Error::CorruptSignature { .. })
    ));
}

/// `Some(descriptor)` in postcard, with the images the JSON holds.
fn postcard_descriptor(json: &serde_json::Value) -> Vec<u8> {
    let images = json["lfd"].as_array().unwrap();
    let mut bytes = vec![1, images.len() as u8];
    for image in images {
        let coefficients = image.as_array().unwrap();
        bytes.push(coefficients.len() as u8);
        bytes.extend(coefficients.iter().map(|c| c.as_u64().unwrap() as u8));
    }
    bytes
}

/// The staleness rule: extraction parameters and the extraction version make a signature
/// stale; ranking parameters never do, so retuning them forces no re-extraction.
#[test]
fn only_extraction_parameters_make_a_signature_stale() {
    let s = signature(&shapes::cone(0.5, 12, 24));
    let current = Params::default();
    assert_eq!(s.staleness(&current), None);
    let mut ranking = current.clone();
    ranking.similarity.ecc_weight = 0.9;
    ranking.similarity.penalty = false;
    assert_eq!(s.staleness(&ranking), None);
    let mut extraction = current.clone();
    extraction.ecc.local_size = 0.3;
    assert_eq!(s.staleness(&extraction), Some(Staleness::Parameters));
    let mut older = s.clone();
    older.params.version -= 1;
    assert_eq!(older.staleness(&current), Some(Staleness::Parameters));
    let without = Signature {
        lfd: None,
        ..s.clone()
    };
    assert_eq!(
        without.staleness(&current),
        Some(Staleness::MissingDescriptor)
    );
    let without = Signature {
        geodesic: None,
        ..s
    };
    assert_eq!(
        without.staleness(&current),
        Some(Staleness::MissingDescriptor)
    );
}
