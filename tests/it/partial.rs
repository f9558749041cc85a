//! Partial retrieval (`docs/results/partial/`), with known answers: a piece cut from a generated model
//! finds that model among others, the pruned ranking equals a full scan, and over HTTP
//! `mode=partial` answers with the sizes it tried and rejects what does not apply.

use axum::http::StatusCode;
use glam::DVec3;
use salient_core::descriptor::patch::{piece, piece_distance, Layout, Packed, Patches, LEN};
use salient_core::mesh::cut::cut;
use salient_core::mesh::RawMesh;
use salient_core::params::Params;
use std::sync::Arc;

use salient_core::descriptor::patch::PackedPiece;
use salient_core::part_search::{self, Library, PartQuery, SearchError};
use salient_core::partial::{stored_patches, Part, Probe, Target};
use salient_core::pipeline::compute;
use salient_core::rank::{Index, Request, Scope, Search};
use salient_core::register::Surface;
use salient_core::similarity::{part_in, CostMatrix, Features};
use salient_server::store::{Derived, InMemoryStore, Store};
use serde_json::Value;

use crate::app::TestApp;
use crate::server::obj;
use crate::shapes;
use crate::stores::{stores, Stores};
use rstest_reuse::apply;

/// A library whose patches are not made yet.
const NO_PATCHES: &[(f64, String)] = &[];

/// The collection: a star with five spikes, and shapes without them.
pub(crate) fn collection() -> Vec<(&'static str, RawMesh)> {
    vec![
        ("star", shapes::star(4, &shapes::five_tips())),
        ("sphere", shapes::icosphere(4)),
        ("tube", shapes::tube(0.3, 30, 24)),
        ("bowl", shapes::bowl(4)),
    ]
}

/// The star's +x spike and the body around its root: the surface within 0.6 of the spike's
/// middle (the star's radius is 1.3).
pub(crate) fn spike() -> RawMesh {
    let star = &collection()[0].1;
    cut(star, DVec3::new(0.9, 0.0, 0.0), 0.6).expect("the ball holds part of the star")
}

#[test]
fn a_cut_is_the_largest_piece_inside_the_ball() {
    let star = &collection()[0].1;
    let part = spike();
    assert!(part.triangles.len() < star.triangles.len() / 4);
    assert!(
        part.positions.iter().all(|p| p.x > 0.2),
        "only the +x spike"
    );
    // Two unit spheres 2.5 apart, a ball between them nearer the first: of the two pieces
    // inside it, the first's is the larger and the only one kept.
    let mut pair = shapes::icosphere(3);
    let second = shapes::transformed(
        &pair,
        glam::DMat4::from_translation(DVec3::new(2.5, 0.0, 0.0)),
    );
    let offset = pair.positions.len() as u32;
    pair.positions.extend(second.positions);
    pair.triangles
        .extend(second.triangles.iter().map(|t| t.map(|v| v + offset)));
    let piece = cut(&pair, DVec3::new(1.1, 0.0, 0.0), 0.6).unwrap();
    assert!(!piece.triangles.is_empty());
    assert!(
        piece.positions.iter().all(|p| p.x < 1.25),
        "the first sphere's piece"
    );
    assert!(cut(star, DVec3::splat(10.0), 0.5).is_none());

    // On a coarse sphere (edges ~0.6) the cut still follows a ball of 0.5: triangles across
    // the sphere are split to a sixteenth of its radius before the centroids are tested.
    let coarse = shapes::icosphere(1);
    let centre = coarse.positions[0];
    let piece = cut(&coarse, centre, 0.5).unwrap();
    let farthest = piece
        .positions
        .iter()
        .map(|p| p.distance(centre))
        .fold(0.0, f64::max);
    assert!(farthest <= 0.5 * (1.0 + 1.0 / 16.0) + 1e-9, "{farthest}");
    assert!(farthest > 0.45, "{farthest}");
}

#[test]
fn a_piece_is_described_alike_however_it_is_moved_and_a_model_holds_its_own_pieces() {
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    let corners = |mesh: &RawMesh| -> Vec<[DVec3; 3]> {
        mesh.triangles
            .iter()
            .map(|t| t.map(|v| mesh.positions[v as usize]))
            .collect()
    };
    let part = spike();
    let moved = shapes::transformed(&part, shapes::random_motion(3));
    let described = |mesh: &RawMesh| {
        piece(&corners(mesh), &mut ChaCha8Rng::seed_from_u64(1))
            .unwrap()
            .description
    };
    let (a, b) = (described(&part), described(&moved));
    assert!(piece_distance(&a, &b) < 1e-3, "{}", piece_distance(&a, &b));

    // The spike is among the star's patches, not among the sphere's or the tube's.
    let params = Params::default();
    let patches = |mesh: &RawMesh| {
        let prepared = salient_core::mesh::prepare(mesh, &params.mesh).unwrap();
        Patches::compute(&prepared.positions, &prepared.triangles, 5, Layout::FRAMES)
    };
    let models = collection();
    let star = patches(&models[0].1).nearest(&a);
    for (id, mesh) in &models[1..] {
        let other = patches(mesh).nearest(&a);
        assert!(star < other, "{id}: {other} vs the star's {star}");
    }

    // So it is among the patches stored for partial search (fewer, a byte a value).
    let stored = |mesh: &RawMesh| stored_patches(mesh, &params.mesh).unwrap();
    let packed = Packed::piece(&a);
    let nearest = |mesh: &RawMesh| {
        let by_radius = stored(mesh).nearest(&packed);
        assert_eq!(by_radius.len(), Layout::STORED.radii.len());
        by_radius.into_iter().fold(f64::INFINITY, f64::min)
    };
    let star = nearest(&models[0].1);
    for (id, mesh) in &models[1..] {
        let other = nearest(mesh);
        assert!(star < other, "{id}: {other} vs the star's {star}");
    }
}

/// A partial search's candidates: the nearest by each radius's pieces in turn, each model
/// once, with its nearest of any radius.
#[test]
fn candidates_are_taken_radius_by_radius_in_turn() {
    let models = vec![
        (vec![0.1, 0.9], "a"),
        (vec![0.2, 0.1], "b"),
        (vec![0.3, 0.5], "c"),
        (vec![0.05, 0.95], "d"),
    ];
    assert_eq!(
        part_search::candidates(models),
        [(0.05, "d"), (0.1, "b"), (0.1, "a"), (0.3, "c")]
    );
    // Without pieces: every model, by id.
    let bare = vec![(vec![], "x"), (vec![], "a")];
    assert_eq!(
        part_search::candidates(bare),
        [(f64::INFINITY, "a"), (f64::INFINITY, "x")]
    );
}

#[test]
fn packed_patches_measure_as_the_descriptions_within_their_rounding_and_read_back() {
    let params = Params::default();
    let prepared = salient_core::mesh::prepare(&collection()[0].1, &params.mesh).unwrap();
    let patches = Patches::compute(&prepared.positions, &prepared.triangles, 5, Layout::STORED);
    let packed = Packed::of(&patches, Layout::STORED);
    assert_eq!(
        patches.len(),
        Layout::STORED.centres * Layout::STORED.radii.len()
    );
    let least = |d: Vec<f64>| d.into_iter().fold(f64::INFINITY, f64::min);
    // Each value rounds by at most half a step: 24 distribution values in 1/255ths, halved,
    // and 3 spreads in 1/127ths.
    let rounding = 24.0 / 255.0 / 2.0 + 3.0 / 127.0;
    let first = &patches.values[..LEN];
    for (i, part) in patches.values.chunks_exact(LEN).enumerate().step_by(7) {
        let exact = patches.nearest(part);
        let rounded = packed.nearest(&Packed::piece(part));
        assert!(exact == 0.0, "a patch is its own nearest");
        // Its own radius holds it.
        assert_eq!(rounded[usize::from(patches.radii[i])], 0.0, "{rounded:?}");
        let other = Packed::piece(first);
        let (exact, rounded) = (
            piece_distance(part, first),
            Packed::of(
                &Patches {
                    values: part.to_vec(),
                    frames: Vec::new(),
                    radii: vec![0],
                },
                Layout::STORED,
            )
            .nearest(&other),
        );
        assert_eq!(
            rounded[1..],
            [f64::INFINITY; 3],
            "no pieces of the other radii"
        );
        let rounded = least(rounded);
        assert!((exact - rounded).abs() <= rounding, "{exact} vs {rounded}");
    }
    let bytes = packed.to_bytes();
    assert_eq!(bytes.len(), 2 + 64 * 4 * (1 + LEN));
    assert_eq!(Packed::from_bytes(&bytes), Some(packed));
    // Another layout's entry (the first release's: 64 pieces of one radius), or a damaged
    // one, is made again.
    let mut first_release = vec![1];
    first_release.extend(&bytes[3..3 + 64 * LEN]);
    assert_eq!(Packed::from_bytes(&first_release), None);
    assert_eq!(Packed::from_bytes(&bytes[..bytes.len() - 1]), None);
    let mut far_radius = bytes.clone();
    far_radius[2] = 4;
    assert_eq!(Packed::from_bytes(&far_radius), None);
    assert_eq!(Packed::from_bytes(&[]), None);
}

#[test]
fn a_part_registers_into_its_source_however_it_is_moved_and_not_into_other_shapes() {
    let params = Params::default();
    let models = collection();
    let targets: Vec<Target> = models
        .iter()
        .map(|(_, mesh)| Target::new(mesh, &params.mesh).unwrap())
        .collect();
    // Turned, moved and in other units (inches to millimetres): the same part.
    let disguised = shapes::transformed(
        &spike(),
        shapes::random_motion(3) * glam::DMat4::from_scale(DVec3::splat(25.4)),
    );
    for part in [spike(), disguised] {
        let probe = Probe::new(&part).unwrap();
        let residuals: Vec<f64> = targets.iter().map(|t| probe.residual(t)).collect();
        assert!(residuals[0] < 0.01, "{residuals:?}");
        for (&other, (id, _)) in residuals[1..].iter().zip(&models[1..]) {
            assert!(
                other > 4.0 * residuals[0] && other > 0.02,
                "{id}: {residuals:?}"
            );
        }
    }
    assert!(Probe::new(&RawMesh::default()).is_none());
}

/// Each verified model is a registration: the count is bounded.
#[test]
fn too_many_verified_models_are_refused() {
    let mut params = Params::default();
    params.similarity.partial.verified = 101;
    assert!(matches!(
        params.validate(),
        Err(salient_core::Error::InvalidParameter {
            name: "similarity.partial.verified",
            ..
        })
    ));
}

#[test]
fn a_part_fits_where_its_features_are_and_the_whole_model_emd_does_not() {
    let params = Params::default();
    let star = compute(&collection()[0].1, &params).unwrap();
    let whole = Features::of(&star.features);
    let one = Features::of(&star.features[..1]);
    let similarity = &params.similarity;
    // One of the model's own features fits at no cost; the rest of the model is free.
    assert!(star.features.len() > 1);
    assert_eq!(part_in(&CostMatrix::new(&one, &whole, similarity)), 0.0);
    // The whole-model EMD moves the part's mass over every feature.
    let emd = salient_core::similarity::compare(
        &salient_core::signature::Signature {
            features: star.features[..1].to_vec(),
            ..star.clone()
        },
        &star,
        similarity,
    );
    assert!(emd.emd > 0.0);
    // More part features than the model has: all the part's mass still moves.
    let reversed = CostMatrix::new(&whole, &one, similarity);
    assert!(part_in(&reversed) > 0.0);
    assert!(reversed.nearest_bound() <= part_in(&reversed));
}

#[test]
fn a_piece_cut_from_a_model_finds_it_and_the_pruned_ranking_equals_a_full_scan() {
    let params = Params::default();
    let mut index = Index::new(params.similarity.clone());
    let mut stored = Vec::new();
    for (id, mesh) in collection() {
        let signature = compute(&mesh, &params).unwrap();
        index.insert(id, &signature).unwrap();
        stored.push((id, Features::of(&signature.features)));
    }
    let scales = &params.similarity.partial.scales;
    let part = Part::extract(&spike(), &params, scales, &params.similarity).unwrap();
    assert_eq!(part.sizes().count(), scales.len());

    let ranked = index
        .search(&Request::part(&part, NO_PATCHES, 0, 4))
        .unwrap();
    let ids: Vec<&str> = ranked.hits.iter().map(|h| h.id.as_str()).collect();
    assert_eq!(ids[0], "star", "{ranked:?}");

    // Every model's exact fit, sorted: the pruned ranking's order and distances.
    let mut full: Vec<(f64, &str)> = stored
        .iter()
        .map(|(id, features)| {
            let fit = part
                .fit(features, &params.similarity, f64::INFINITY)
                .unwrap();
            assert!(
                part.bound(&salient_core::similarity::Summary::of(
                    features,
                    &params.similarity
                )) <= fit.distance
            );
            (fit.distance, *id)
        })
        .collect();
    full.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(b.1)));
    let expected: Vec<(f64, &str)> = full.into_iter().take(4).collect();
    let got: Vec<(f64, &str)> = ranked
        .hits
        .iter()
        .map(|h| (h.distance, h.id.as_str()))
        .collect();
    assert_eq!(got, expected);
    assert!(ranked
        .hits
        .iter()
        .all(|h| h.part_scale.is_some_and(|s| scales.contains(&s))));

    // The top hit alone, with a smaller k, is pruned to it.
    let top = index
        .search(&Request::part(&part, NO_PATCHES, 0, 1))
        .unwrap();
    assert_eq!(top.hits[0].id, "star");
}

/// `mode=partial`'s candidates: the stored patches' nearest that the part fits, then the
/// fit's own best among the models without patches, each once; then the fit's ranking.
#[test]
fn the_patches_nearest_are_verified_first_then_the_fits_best_of_the_models_without() {
    let params = Params::default();
    let mut index = Index::new(params.similarity.clone());
    for (id, mesh) in collection() {
        index.insert(id, &compute(&mesh, &params).unwrap()).unwrap();
    }
    let scales = &params.similarity.partial.scales;
    let part = Part::extract(&spike(), &params, scales, &params.similarity).unwrap();
    let fit = index
        .search(&Request::part(&part, NO_PATCHES, 0, 4))
        .unwrap();
    let order: Vec<&str> = fit.hits.iter().map(|h| h.id.as_str()).collect();
    assert_eq!((order.len(), order[0], fit.candidates), (4, "star", 0));
    let distance = |id: &str| fit.hits.iter().find(|h| h.id == id).unwrap().distance;

    // The fit's last two have patches, the tube's the nearest; "lost" is no model.
    let (third, last) = (order[2], order[3]);
    let nearest = [(0.1, "lost"), (0.2, last), (0.3, third)].map(|(d, id)| (d, id.to_string()));
    let ranked = index.search(&Request::part(&part, &nearest, 1, 4)).unwrap();
    let ids: Vec<&str> = ranked.hits.iter().map(|h| h.id.as_str()).collect();
    // The patches' nearest model, the fit's best (unpatched), then the rest in the fit's order.
    assert_eq!(ranked.candidates, 2);
    assert_eq!(ids, [last, "star", order[1], third]);
    for hit in &ranked.hits {
        assert_eq!(
            hit.distance,
            distance(&hit.id),
            "{}: the fit's distance",
            hit.id
        );
    }
    assert!(ranked.hits.iter().all(|h| h.part_scale.is_some()));
    assert_eq!(
        ranked.evaluated, fit.evaluated,
        "no fit outside the fit's 4"
    );

    // Every model patched: the fit's best is verified only if the patches choose it.
    let all: Vec<(f64, String)> = order
        .iter()
        .rev()
        .enumerate()
        .map(|(i, &id)| (i as f64, id.to_string()))
        .collect();
    let ranked = index.search(&Request::part(&part, &all, 2, 2)).unwrap();
    let ids: Vec<&str> = ranked.hits.iter().map(|h| h.id.as_str()).collect();
    assert_eq!(ranked.candidates, 2);
    assert_eq!(ids, [last, third, "star", order[1]]);
    let top2 = index
        .search(&Request::part(&part, NO_PATCHES, 2, 2))
        .unwrap();
    assert_eq!(
        ranked.evaluated,
        top2.evaluated + 2,
        "the patches' two are fitted besides the fit's own"
    );
}

/// A library held in memory, as the evaluation holds one: every model's target and stored
/// patches; `unprepared` models have patches but no target (their upload no longer loads),
/// and a `down` library fails as a store that went away.
struct Shelf {
    models: Vec<(&'static str, Arc<Target>, Packed)>,
    unprepared: &'static [&'static str],
    down: bool,
}

impl Shelf {
    fn of(models: &[(&'static str, RawMesh)], params: &Params) -> Self {
        let models = models
            .iter()
            .map(|(id, mesh)| {
                let target = Target::new(mesh, &params.mesh).unwrap();
                (
                    *id,
                    Arc::new(target),
                    stored_patches(mesh, &params.mesh).unwrap(),
                )
            })
            .collect();
        Self {
            models,
            unprepared: &[],
            down: false,
        }
    }
}

impl Library for Shelf {
    type Error = &'static str;

    fn nearest(&self, piece: &PackedPiece) -> Result<Vec<(Vec<f64>, String)>, &'static str> {
        if self.down {
            return Err("the store is down");
        }
        let distances = self
            .models
            .iter()
            .map(|(id, _, p)| (p.nearest(piece), id.to_string()));
        Ok(distances.collect())
    }

    fn target(&self, id: &str) -> Result<Option<Arc<Target>>, &'static str> {
        let found = self.models.iter().find(|(m, ..)| *m == id);
        Ok(found
            .filter(|_| !self.unprepared.contains(&id))
            .map(|(_, t, _)| t.clone()))
    }
}

/// How far the farthest vertex of `part`, moved by `placement`, lies off `model`'s surface.
fn farthest_off(model: &RawMesh, placement: glam::DMat4, part: &RawMesh) -> f32 {
    let narrow = |p: DVec3| glamx::Vec3::new(p.x as f32, p.y as f32, p.z as f32);
    let positions = model.positions.iter().map(|&p| narrow(p)).collect();
    let surface = Surface::new(positions, model.triangles.clone()).unwrap();
    part.positions
        .iter()
        .map(|&p| surface.distance(narrow(placement.transform_point3(p))))
        .fold(0.0, f32::max)
}

fn indexed(models: &[(&'static str, RawMesh)], params: &Params) -> Index {
    let mut index = Index::new(params.similarity.clone());
    for (id, mesh) in models {
        index.insert(*id, &compute(mesh, params).unwrap()).unwrap();
    }
    index
}

/// The one partial search: the patches' nearest registered and ranked by residual, the source
/// first wherever the part is moved; a model that cannot be prepared ranks after them,
/// unverified; a library that fails fails the search.
#[test]
fn a_partial_search_registers_the_patches_nearest_and_ranks_the_source_first() {
    let params = Params::default();
    let models = collection();
    let index = indexed(&models, &params);
    let mut shelf = Shelf::of(&models, &params);
    let scales = &params.similarity.partial.scales;
    let disguise = shapes::random_motion(5) * glam::DMat4::from_scale(DVec3::splat(0.1));
    let disguised = shapes::transformed(&spike(), disguise);
    for (part, moved) in [(spike(), glam::DMat4::IDENTITY), (disguised, disguise)] {
        let query = PartQuery::extract(&part, &params, scales).unwrap();
        let ranking = part_search::search(&query, &index, Scope::default(), &shelf, 4, 3).unwrap();
        assert_eq!(ranking.verified, 4);
        assert_eq!(ranking.hits.len(), 3, "truncated to k after verification");
        assert_eq!(ranking.hits[0].id, "star", "{ranking:?}");
        let residuals: Vec<f64> = ranking.hits.iter().map(|h| h.residual().unwrap()).collect();
        assert!(residuals[0] < 0.01, "{residuals:?}");
        assert!(residuals.windows(2).all(|w| w[0] <= w[1]), "{residuals:?}");
        // Placed in the star, the part lies on its surface (on one of its five like tips;
        // the star's radius is 1.3).
        let placement = ranking.hits[0].registration.unwrap().placement;
        let off = farthest_off(&models[0].1, placement * moved, &spike());
        assert!(off < 0.03, "{off}");
    }

    let query = PartQuery::extract(&spike(), &params, scales).unwrap();
    shelf.unprepared = &["star"];
    let ranking = part_search::search(&query, &index, Scope::default(), &shelf, 4, 4).unwrap();
    assert_eq!(ranking.hits[3].id, "star", "{ranking:?}");
    assert_eq!(ranking.hits[3].registration, None);
    assert!(ranking.hits[..3].iter().all(|h| h.registration.is_some()));

    shelf.down = true;
    let failed = part_search::search(&query, &index, Scope::default(), &shelf, 4, 4);
    assert!(matches!(
        failed,
        Err(SearchError::Library("the store is down"))
    ));
}

/// What the evaluation counts as featureless: a flat disc from a tube's cap, a plane and a
/// cap of a sphere are plain; a spike and a piece of the tube's side (curved one way) are not.
#[test]
fn plain_parts_are_told_from_parts_with_relief() {
    let models = collection();
    let tube = &models[2].1;
    let disc = cut(tube, DVec3::new(0.0, 0.0, 1.0), 0.28).unwrap();
    let side = cut(tube, DVec3::new(0.3, 0.0, 0.0), 0.5).unwrap();
    let ball = cut(&models[1].1, DVec3::new(0.0, 0.0, 1.0), 0.6).unwrap();
    for (name, part, plain) in [
        ("disc", disc, true),
        ("plane", shapes::plane(8, 1), true),
        ("ball", ball, true),
        ("spike", spike(), false),
        ("side", side, false),
    ] {
        assert_eq!(Probe::new(&part).unwrap().is_plain(), plain, "{name}");
    }
}

#[test]
fn part_sizes_out_of_range_are_refused() {
    let params = Params::default();
    for scales in [vec![], vec![0.1], vec![1.5], vec![0.5; 9]] {
        let result = Part::extract(&spike(), &params, &scales, &params.similarity);
        assert!(
            matches!(result, Err(salient_core::Error::InvalidParameter { .. })),
            "{scales:?}"
        );
    }
}

async fn json(response: crate::app::TestResponse) -> Value {
    response.json()
}

#[apply(stores)]
#[tokio::test]
async fn a_part_is_searched_over_http(#[case] store: Stores) {
    let app = TestApp::on(store);
    for (id, mesh) in collection() {
        let response = app.add(&format!("id={id}"), "model/obj", obj(&mesh)).await;
        assert_eq!(response.status(), StatusCode::CREATED, "{id}");
    }
    let search = |query: &str| {
        app.post(format!("/v1/search?{query}"))
            .header("content-type", "model/obj")
            .body(obj(&spike()))
            .send()
    };
    let response = search("mode=partial&k=2").await;
    assert_eq!(response.status(), StatusCode::OK);
    let body = json(response).await;
    assert_eq!(body["mode"], "partial");
    assert_eq!(body["method"], "ecc");
    assert_eq!(body["results"][0]["id"], "star", "{body}");
    assert_eq!(body["results"].as_array().unwrap().len(), 2);
    assert!(body["results"][0]["part_scale"].is_f64());
    assert_eq!(body["part_sizes"].as_array().unwrap().len(), 4);
    // Both verified (`similarity.partial.verified` is 50), the source lying on its surface.
    let residuals: Vec<f64> = body["results"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| r["residual"].as_f64().unwrap())
        .collect();
    assert!(
        residuals[0] < 0.05 && residuals[0] * 4.0 < residuals[1],
        "{body}"
    );

    assert!(
        body["results"][0].get("placement").is_none(),
        "only explained"
    );

    // Explained: where the part lies in each model it was registered into, which puts it on
    // the star's surface.
    let body = json(search("mode=partial&k=2&explain=true").await).await;
    let placement: Vec<f64> = body["results"][0]["placement"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let placement = glam::DMat4::from_cols_slice(&placement);
    let off = farthest_off(&collection()[0].1, placement, &spike());
    assert!(off < 0.03, "{off}: {body}");
    assert_eq!(
        body["results"][1]["placement"].as_array().unwrap().len(),
        16
    );

    // A known size is the only one tried.
    let body = json(search("mode=partial&part_scale=0.5").await).await;
    assert_eq!(body["part_sizes"][0]["scale"], 0.5);
    assert_eq!(body["part_sizes"].as_array().unwrap().len(), 1);
    assert_eq!(body["results"][0]["part_scale"], 0.5);

    // Whole-model search is unchanged, and says so.
    let body = json(search("k=1").await).await;
    assert_eq!(body["mode"], "whole");
    assert!(body.get("part_sizes").is_none());

    for bad in [
        "mode=partial&method=ecc",
        "mode=partial&part_scale=0.1",
        "part_scale=0.5",
        "mode=parts",
    ] {
        let response = search(bad).await;
        assert_eq!(response.status(), StatusCode::BAD_REQUEST, "{bad}");
        assert!(json(response).await["error"]["code"].is_string(), "{bad}");
    }
    let response = app.get("/v1/models/star/similar?mode=partial").send().await;
    assert_eq!(response.status(), StatusCode::BAD_REQUEST);
}

/// Every model gets its stored patches in the background, from the start for those stored
/// before and after each upload; they pick which models a partial search verifies, and go
/// with their model.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn patches_are_made_in_the_background_and_pick_what_a_partial_search_verifies() {
    let store = std::sync::Arc::new(InMemoryStore::new());
    let mut config = salient_server::api::Config::default();
    config.params.similarity.partial.verified = 1;
    let app = TestApp::build(config, store.clone(), None);
    let models = collection();
    for (id, mesh) in &models[..3] {
        let response = app.add(&format!("id={id}"), "model/obj", obj(mesh)).await;
        assert_eq!(response.status(), StatusCode::CREATED, "{id}");
    }
    let search = || {
        app.post("/v1/search?mode=partial&k=3")
            .header("content-type", "model/obj")
            .body(obj(&spike()))
            .send()
    };
    let verified = |body: &Value| -> Vec<String> {
        body["results"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|r| r["residual"].is_f64())
            .map(|r| r["id"].as_str().unwrap().to_string())
            .collect()
    };
    // Before any patches: the fit's best alone is verified.
    let body = json(search().await).await;
    assert_eq!(verified(&body), ["star"], "{body}");
    assert!(store.all_derived(Derived::Patches).next().is_none());
    // The tube's patches as the first release stored them (one radius, no radius a piece):
    // another layout, made again.
    let tube = json(app.get("/v1/models/tube").send().await).await;
    let hash = tube["content_hash"].as_str().expect("a hash");
    let first_release: Vec<u8> = std::iter::once(1).chain([7; 64 * LEN]).collect();
    assert!(store
        .put_derived(Derived::Patches, "tube", hash, &first_release)
        .unwrap());

    let mut pending = app.app.patches_pending();
    app.app.start_background();
    pending.wait_for(|p| *p == Some(0)).await.unwrap();
    let made: Vec<String> = store
        .all_derived(Derived::Patches)
        .map(|entry| {
            let (id, bytes) = entry.unwrap();
            assert!(Packed::from_bytes(&bytes).is_some(), "{id}");
            id.to_string()
        })
        .collect();
    assert_eq!(made, ["sphere", "star", "tube"]);

    // One added after the start gets its patches too.
    let (id, mesh) = &models[3];
    let response = app.add(&format!("id={id}"), "model/obj", obj(mesh)).await;
    assert_eq!(response.status(), StatusCode::CREATED);
    pending.wait_for(|p| *p == Some(0)).await.unwrap();
    assert!(store.derived(Derived::Patches, id).unwrap().is_some());
    let metrics = app.get("/metrics").send().await.text();
    assert!(metrics.contains("salient_patches_pending 0"), "{metrics}");

    // The verified model is the patches' nearest: the star, first by its residual.
    let body = json(search().await).await;
    assert_eq!(verified(&body), ["star"], "{body}");
    assert_eq!(body["results"][0]["id"], "star");

    // A deleted model's patches go with it.
    let response = app.delete("/v1/models/star").send().await;
    assert_eq!(response.status(), StatusCode::NO_CONTENT);
    assert!(store.derived(Derived::Patches, "star").unwrap().is_none());
}
