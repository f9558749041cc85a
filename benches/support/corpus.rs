//! Real signatures for the benches: the load bench's base store of both shared collections
//! (every fifth model held out), and the perturbed copies that fill large stores.
#![allow(dead_code)] // each bench uses a part of it

use std::path::{Path, PathBuf};

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use salient_core::descriptor::LightFieldDescriptor;
use salient_core::rank::Method;
use salient_core::{Params, Signature};
use salient_server::store::{SledStore, Store};

/// The shared collections (`../shared/data`, or `SALIENT_BENCH_DATA`).
pub fn data_dir() -> PathBuf {
    std::env::var_os("SALIENT_BENCH_DATA").map_or_else(
        || PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../shared/data"),
        PathBuf::from,
    )
}

/// Where the load bench keeps its base store, per set of extraction parameters and sources;
/// `<path>.complete` exists once the store is whole.
pub fn base_store_path(real: bool) -> PathBuf {
    let key = format!(
        "{}-{}",
        if real { "real" } else { "stars" },
        hex_key(&Params::default().extraction_key())
    );
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("target/salient-bench")
        .join(format!("base-{key}"))
}

/// A short stable name for a byte string (FNV-1a).
fn hex_key(bytes: &[u8]) -> String {
    let hash = bytes.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &b| {
        (h ^ b as u64).wrapping_mul(0x0100_0000_01b3)
    });
    format!("{hash:016x}")
}

/// The base store's records, signatures and uploads, in id order.
pub fn load_base(
    base: &Path,
) -> Vec<(
    salient_server::model::ModelRecord,
    Signature,
    salient_server::model::Upload,
)> {
    let source = SledStore::open(base).expect("the base store");
    source
        .load_all()
        .map(|loaded| {
            let loaded = loaded.expect("loads");
            let upload = source
                .upload(loaded.record.id.as_str())
                .expect("reads")
                .expect("stored");
            let signature = Signature::from_bytes(&loaded.signature).expect("decodes");
            (loaded.record, signature, upload)
        })
        .collect()
}

/// The signature with every descriptor perturbed: ECC values and D2 and geodesic bins scaled
/// by up to ±`amount` (histograms renormalised), LFD coefficients moved by up to ±3 of 255,
/// and, as `tests/synthetic` does, sometimes a feature fewer: copies spread around their
/// original like the members of a class rather than piling up on it (which would let the
/// ranking's bounds prune almost everything).
pub fn perturbed(signature: &Signature, rng: &mut ChaCha8Rng, amount: f64) -> Signature {
    let mut s = signature.clone();
    if s.features.len() > 2 && rng.gen_bool(0.3) {
        let drop = rng.gen_range(0..s.features.len());
        s.features.remove(drop);
    }
    for f in &mut s.features {
        f.ecc
            .iter_mut()
            .for_each(|a| *a *= 1.0 + rng.gen_range(-amount..amount));
        jitter_histogram(&mut f.d2, rng, amount);
    }
    jitter_histogram(&mut s.d2, rng, amount);
    if let Some(g) = &mut s.geodesic {
        jitter_histogram(&mut g.distances, rng, amount);
        jitter_histogram(&mut g.eccentricity, rng, amount);
    }
    if let Some(lfd) = &s.lfd {
        // Its images are opaque; their serialised form is the coefficients.
        let mut images: Vec<Vec<u8>> =
            serde_json::from_value(serde_json::to_value(lfd).expect("serialises")).expect("bytes");
        for c in images.iter_mut().flatten() {
            *c = (*c as i32 + rng.gen_range(-3..=3)).clamp(0, 255) as u8;
        }
        let images = serde_json::to_value(images).expect("serialises");
        s.lfd = Some(serde_json::from_value::<LightFieldDescriptor>(images).expect("an LFD"));
    }
    s
}

/// Each bin scaled by up to ±`amount`, then the histogram renormalised.
fn jitter_histogram(bins: &mut [f32], rng: &mut ChaCha8Rng, amount: f64) {
    for v in bins.iter_mut() {
        *v *= (1.0 + rng.gen_range(-amount..amount)) as f32;
    }
    let sum: f32 = bins.iter().sum();
    if sum > 0.0 {
        bins.iter_mut().for_each(|v| *v /= sum);
    }
}

/// The methods named, comma-separated, in the environment variable `name`; every method when
/// it is not set. Narrows a bench's table (to profile one method).
pub fn methods_from_env(name: &str) -> Vec<Method> {
    std::env::var(name).map_or_else(
        |_| Method::ALL.to_vec(),
        |names| {
            names
                .split(',')
                .map(|m| m.trim().parse().unwrap_or_else(|e| panic!("{name}: {e}")))
                .collect()
        },
    )
}
