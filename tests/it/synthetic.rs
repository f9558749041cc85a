//! Synthetic signatures for ranking tests and benchmarks: `classes` prototypes of salient
//! features, and members that perturb a prototype and drop or repeat some of its features,
//! so that, as in a real collection, models cluster by class.
#![allow(dead_code)] // the benches include this file and use a part of it

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use salient_core::{Feature, Params, Signature};

fn histogram(rng: &mut ChaCha8Rng, bins: usize) -> Vec<f32> {
    // Region D2 histograms are unimodal bumps; their position and width vary with the region.
    let centre = rng.gen_range(0.1..0.7) * bins as f64;
    let width = rng.gen_range(0.05..0.2) * bins as f64;
    let raw: Vec<f64> = (0..bins)
        .map(|k| (-((k as f64 - centre) / width).powi(2)).exp() + 1e-3)
        .collect();
    let sum: f64 = raw.iter().sum();
    raw.into_iter().map(|x| (x / sum) as f32).collect()
}

fn feature(rng: &mut ChaCha8Rng) -> Feature {
    // ECC vectors are smooth curves in the wave index: α_i ≈ s·(i/N)^γ.
    let (s, gamma) = (rng.gen_range(-0.3..1.4), rng.gen_range(0.3..1.5));
    Feature {
        vertex: rng.gen_range(0..10_000),
        position: [rng.gen(), rng.gen(), rng.gen()],
        position_normalized: [rng.gen(), rng.gen(), rng.gen()],
        ecc: (1..=10)
            .map(|i| s * (i as f64 / 10.0).powf(gamma))
            .collect(),
        d2: histogram(rng, 64),
        region_size: 0.3,
        region_area: rng.gen(),
    }
}

fn jitter(rng: &mut ChaCha8Rng, f: &Feature, amount: f64) -> Feature {
    let mut g = f.clone();
    for a in &mut g.ecc {
        *a += rng.gen_range(-amount..amount) * 0.3;
    }
    let raw: Vec<f64> =
        g.d2.iter()
            .map(|&h| (h as f64 * (1.0 + rng.gen_range(-amount..amount))).max(0.0))
            .collect();
    let sum: f64 = raw.iter().sum();
    g.d2 = raw.into_iter().map(|x| (x / sum) as f32).collect();
    g
}

/// `count` signatures named `m000000…`, drawn from `classes` prototypes.
pub fn collection(count: usize, classes: usize, seed: u64) -> Vec<(String, Signature)> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let prototypes: Vec<Vec<Feature>> = (0..classes)
        .map(|_| {
            let n = rng.gen_range(2..14);
            (0..n).map(|_| feature(&mut rng)).collect()
        })
        .collect();
    (0..count)
        .map(|i| {
            let prototype = &prototypes[rng.gen_range(0..classes)];
            let mut features: Vec<Feature> = prototype
                .iter()
                .map(|f| jitter(&mut rng, f, 0.15))
                .collect();
            if features.len() > 2 && rng.gen_bool(0.3) {
                features.pop();
            }
            if rng.gen_bool(0.2) {
                let extra = jitter(&mut rng, &prototype[0], 0.3);
                features.push(extra);
            }
            let signature = Signature {
                mesh_hash: salient_core::signature::MeshHash(std::array::from_fn(|b| {
                    (i >> (8 * (b % 8))) as u8
                })),
                features,
                d2: histogram(&mut rng, 64),
                lfd: None,
                geodesic: None,
                params: Params::default(),
                stats: Default::default(),
            };
            (format!("m{i:06}"), signature)
        })
        .collect()
}

/// Gives every signature the global descriptors: a light field, one of `classes` random
/// prototypes (by position, `i % classes`) with each coefficient moved by up to ±6
/// quantisation steps, and geodesic histograms like the region D2's.
pub fn with_descriptors(collection: &mut [(String, Signature)], classes: usize, seed: u64) {
    use salient_core::descriptor::lfd::{ImageFeatures, COEFFICIENTS, IMAGES};
    use salient_core::descriptor::{geodesic, GeodesicDescriptor, LightFieldDescriptor};
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let prototypes: Vec<Vec<u8>> = (0..classes)
        .map(|_| (0..COEFFICIENTS * IMAGES).map(|_| rng.gen()).collect())
        .collect();
    for (i, (_, signature)) in collection.iter_mut().enumerate() {
        let images = prototypes[i % classes]
            .chunks(COEFFICIENTS)
            .map(|c| {
                let bytes = c
                    .iter()
                    .map(|&b| (b as i32 + rng.gen_range(-6..=6)).clamp(0, 255) as u8)
                    .collect::<Vec<u8>>();
                ImageFeatures::try_from(bytes).expect("a whole image")
            })
            .collect::<Vec<_>>();
        signature.lfd = Some(LightFieldDescriptor::try_from(images).expect("every image"));
        signature.geodesic = Some(GeodesicDescriptor {
            distances: histogram(&mut rng, geodesic::BINS),
            eccentricity: histogram(&mut rng, geodesic::BINS),
        });
    }
}
