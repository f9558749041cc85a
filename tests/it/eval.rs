//! The evaluation harness end to end (SPEC §7) on generated collections: labels, the
//! retrieval report files, robustness and pictures.

use crate::shapes;

use std::path::Path;
use std::process::Command;

use glam::DVec3;
use salient_core::duplicate::Evidence;
use salient_core::mesh::RawMesh;
use salient_core::pipeline::extract;
use salient_core::render::{render, Camera, POINT_COLOUR};
use salient_core::salient::detect;
use salient_core::{Error, Params};
use salient_eval::robustness::{self, FACE_FRACTIONS, NOISE_LEVELS};
use salient_eval::study::{self, Change};
use salient_eval::LabelledCollection;
use serde_json::Value;

/// Three classes of three models each, every model moved and scaled at random: stars with
/// three tips, stars with five, and cones of different openings.
fn models() -> Vec<(&'static str, String, RawMesh)> {
    let (x, y, z) = (DVec3::X, DVec3::Y, DVec3::Z);
    let three = [
        vec![x, y, z],
        vec![x, -x, y],
        vec![x, y.lerp(z, 0.5).normalize(), -z],
    ];
    let five = [
        shapes::five_tips(),
        vec![x, -x, y, -y, -z],
        vec![x, -x, z, -z, y],
    ];
    let mut models = Vec::new();
    for (i, tips) in three.iter().enumerate() {
        models.push(("star3", format!("s3-{i}"), shapes::star(4, tips)));
    }
    for (i, tips) in five.iter().enumerate() {
        models.push(("star5", format!("s5-{i}"), shapes::star(4, tips)));
    }
    for (i, beta) in [0.4, 0.5, 0.6].into_iter().enumerate() {
        models.push(("cone", format!("c-{i}"), shapes::cone(beta, 24, 32)));
    }
    for (seed, (_, _, mesh)) in models.iter_mut().enumerate() {
        *mesh = shapes::transformed(mesh, shapes::random_motion(seed as u64));
    }
    models
}

fn write_collection(dir: &Path) {
    for (class, name, mesh) in models() {
        std::fs::create_dir_all(dir.join(class)).unwrap();
        shapes::write_obj(&dir.join(class).join(format!("{name}.obj")), &mesh);
    }
}

/// Runs `salient eval ARGS…`, which must succeed, and reads `REPORT` (a JSON file) back.
fn eval(args: &[&std::ffi::OsStr], report: &Path) -> Value {
    let run = Command::new(env!("CARGO_BIN_EXE_salient"))
        .arg("eval")
        .args(args)
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    serde_json::from_str(&std::fs::read_to_string(report).unwrap()).unwrap()
}

#[test]
fn retrieval_report_end_to_end() {
    let dir = tempfile::tempdir().unwrap();
    let (collection, out) = (dir.path().join("shapes"), dir.path().join("report"));
    write_collection(&collection);
    let json = eval(
        &[
            "retrieval".as_ref(),
            collection.as_ref(),
            "--out".as_ref(),
            out.as_ref(),
            "--methods".as_ref(),
            "hybrid,ecc,d2,lfd,geodesic,ecc-paper".as_ref(),
        ],
        &out.join("report.json"),
    );
    assert_eq!(json["models"], 9);
    assert_eq!(json["classes"], 3);
    assert!(json.get("perturbation").is_none());
    for method in ["hybrid", "ecc", "d2", "lfd", "geodesic", "ecc-paper"] {
        let m = &json["methods"][method];
        for measure in ["NN", "FT", "ST", "E", "DCG", "mAP"] {
            let x = m[measure]
                .as_f64()
                .unwrap_or_else(|| panic!("{method} {measure}"));
            assert!((0.0..=1.0).contains(&x), "{method} {measure} = {x}");
        }
        assert_eq!(m["pr"].as_array().unwrap().len(), 11);
        assert_eq!(m["per_class"].as_object().unwrap().len(), 3);
        assert_eq!(m["queries"], 9);
    }
    // A cone's one sharp apex is nothing like a star's round tips: ECC tells them apart
    // (D2, blind to tips, does not), and ranks better than D2 overall.
    let ecc = &json["methods"]["ecc"];
    assert_eq!(ecc["per_class"]["cone"]["FT"], 1.0);
    // Feature counts per class for the methods that rank by features: a cone has its apex,
    // a five-tip star its five tips.
    assert_eq!(ecc["features_per_class"]["star5"]["mean"], 5.0);
    assert!(json["methods"]["d2"].get("features_per_class").is_none());
    assert!(json["methods"]["lfd"].get("features_per_class").is_none());
    // Silhouettes tell a cone, a sphere-like star and a five-tip star apart.
    assert_eq!(json["methods"]["lfd"]["NN"], 1.0);
    assert!(ecc["mAP"].as_f64() > json["methods"]["d2"]["mAP"].as_f64());
    // Signatures were cached beside the collection, once per parameter set.
    let cached = std::fs::read_dir(collection.join(".salient-cache"))
        .unwrap()
        .count();
    assert_eq!(cached, 18);

    let markdown = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(markdown.contains("| method | NN | FT | ST | E | DCG | mAP |"));
    assert!(markdown.contains("| ecc-paper |"));
    let plot = image::open(out.join("pr.png")).unwrap();
    assert_eq!((plot.width(), plot.height()), (720, 540));
    let svg = std::fs::read_to_string(out.join("pr.svg")).unwrap();
    assert!(svg.contains("<svg") && svg.contains("ecc-paper") && svg.contains("lfd"));
    let csv = std::fs::read_to_string(out.join("distances-ecc.csv")).unwrap();
    assert_eq!(csv.lines().count(), 10);
    assert!(csv.starts_with("id,cone/c-0.obj,"));

    // A noisy copy: its own signatures, cached apart, and other distances.
    let noisy = dir.path().join("noisy");
    let json = eval(
        &[
            "retrieval".as_ref(),
            collection.as_ref(),
            "--out".as_ref(),
            noisy.as_ref(),
            "--methods".as_ref(),
            "ecc".as_ref(),
            "--perturb".as_ref(),
            "noise=0.01".as_ref(),
        ],
        &noisy.join("report.json"),
    );
    assert_eq!(json["perturbation"], "noise-0.01");
    let copies = std::fs::read_dir(collection.join(".salient-cache/noise-0.01")).unwrap();
    assert_eq!(copies.count(), 9);
    assert_ne!(
        std::fs::read_to_string(noisy.join("distances-ecc.csv")).unwrap(),
        csv
    );
    let bad = Command::new(env!("CARGO_BIN_EXE_salient"))
        .args(["eval", "retrieval"])
        .arg(&collection)
        .args(["--perturb", "noise=2"])
        .output()
        .unwrap();
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("noise=LEVEL"));
}

/// `salient eval tune` searches the hybrid's grid on the tuning halves: the setting it
/// chooses is at least as good there as each single method (all are in the grid), and its
/// parameter file loads.
#[test]
fn tune_chooses_hybrid_weights_on_the_tuning_halves() {
    let dir = tempfile::tempdir().unwrap();
    let (collection, out) = (dir.path().join("shapes"), dir.path().join("tune"));
    write_collection(&collection);
    let report = eval(
        &[
            "tune".as_ref(),
            collection.as_ref(),
            "--out".as_ref(),
            out.as_ref(),
        ],
        &out.join("tune.json"),
    );
    assert_eq!(report["settings_tried"], 5 * 1771);
    let tuned = report["chosen_tune_map"].as_f64().unwrap();
    let shapes = &report["collections"][0];
    assert_eq!(shapes["tune_models"], 6);
    let methods = shapes["methods"].as_array().unwrap();
    let names: Vec<&str> = methods
        .iter()
        .map(|m| m["method"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["hybrid", "ecc", "d2", "lfd", "geodesic"]);
    assert_eq!(methods[0]["tune"]["mAP"].as_f64().unwrap(), tuned);
    for m in &methods[1..] {
        assert!(m["tune"]["mAP"].as_f64().unwrap() <= tuned, "{m}");
    }
    let params: Params =
        serde_json::from_str(&std::fs::read_to_string(out.join("params.json")).unwrap()).unwrap();
    params.validate().unwrap();
    let weights: f64 = params
        .similarity
        .hybrid
        .terms()
        .iter()
        .map(|t| t.weight)
        .sum();
    assert!((weights - 1.0).abs() < 1e-9);
    assert!(std::fs::read_to_string(out.join("tune.md"))
        .unwrap()
        .contains("Overfit gap"));
}

#[test]
fn study_grid_halves_and_report() {
    let base = Params::default();
    let grid = study::grid(&base);
    assert!(grid.contains(&Change::EccWeight(1.0)) && grid.contains(&Change::Clusters(8)));
    // Every change changes something, and the defaults are not among the alternatives.
    for change in &grid {
        let mut params = base.clone();
        change.apply(&mut params);
        assert_ne!(params, base, "{change:?}");
    }
    assert!(!grid.contains(&Change::EccWeight(base.similarity.ecc_weight)));
    assert_eq!(
        Change::Height(salient_core::HeightRule::Paper).value(),
        "paper"
    );

    let dir = tempfile::tempdir().unwrap();
    let (collection, out) = (dir.path().join("shapes"), dir.path().join("study"));
    for (class, name, mesh) in models().into_iter().filter(|(c, _, _)| *c != "star3") {
        std::fs::create_dir_all(collection.join(class)).unwrap();
        let small = if class == "cone" {
            mesh
        } else {
            shapes::star(3, &shapes::five_tips())
        };
        shapes::write_obj(&collection.join(class).join(format!("{name}.obj")), &small);
    }
    let labelled = LabelledCollection::open(&collection).unwrap();
    let (tune, held_out) = study::halves(&labelled);
    // Three per class: the first and third tune, the second is held out.
    assert_eq!((tune, held_out), (vec![0, 2, 3, 5], vec![1, 4]));

    let json = eval(
        &[
            "study".as_ref(),
            collection.as_ref(),
            "--out".as_ref(),
            out.as_ref(),
        ],
        &out.join("study.json"),
    );
    // The baseline, each change, and maybe the recommended changes combined.
    let rows = json["results"].as_array().unwrap().len();
    assert!(rows == grid.len() + 1 || rows == grid.len() + 2, "{rows}");
    assert_eq!(
        (json["tune_models"].clone(), json["held_out_models"].clone()),
        (4.into(), 2.into())
    );
    let choices = json["choices"].as_array().unwrap();
    assert!(choices.iter().any(|c| c["parameter"] == "flat_max"));
    let markdown = std::fs::read_to_string(out.join("study.md")).unwrap();
    assert!(markdown.contains("| baseline | defaults |"));
}

#[test]
fn labels_come_from_labels_tsv_or_folders() {
    let dir = tempfile::tempdir().unwrap();
    write_collection(dir.path());
    let by_folder = LabelledCollection::open(dir.path()).unwrap();
    assert_eq!(by_folder.models.len(), 9);
    assert_eq!(by_folder.models[0].id, "cone/c-0.obj");
    assert_eq!(by_folder.models[0].class, "cone");

    // labels.tsv wins: here it merges both kinds of star into one class.
    let mut labels = String::from("path\tclass\n");
    for m in &by_folder.models {
        let class = if m.class == "cone" { "cone" } else { "star" };
        labels += &format!("{}\t{class}\n", m.id);
    }
    std::fs::write(dir.path().join("labels.tsv"), &labels).unwrap();
    let by_file = LabelledCollection::open(dir.path()).unwrap();
    assert_eq!(
        by_file.class_sizes().into_iter().collect::<Vec<_>>(),
        [("cone".to_string(), 3), ("star".to_string(), 6)]
    );

    std::fs::write(
        dir.path().join("labels.tsv"),
        labels + "star3/missing.obj\tstar\n",
    )
    .unwrap();
    let error = LabelledCollection::open(dir.path()).unwrap_err();
    assert!(matches!(error, Error::Labels { .. }), "{error}");
    assert!(error.to_string().contains("line 11"), "{error}");
}

#[test]
fn robustness_of_a_star() {
    let star = shapes::star(4, &shapes::five_tips());
    let report = robustness::run("star", &star, &Params::default(), 3).unwrap();
    let names: Vec<&str> = report.trials.iter().map(|t| t.name.as_str()).collect();
    assert_eq!(
        names.len(),
        1 + FACE_FRACTIONS.len() + NOISE_LEVELS.len() + 1,
        "{names:?}"
    );
    let original = &report.trials[0];
    assert_eq!((original.points, original.found, original.sim), (5, 5, 0.0));
    // Faces follow the fractions while edge collapses can reach them.
    for (t, fraction) in report.trials[1..5].iter().zip(FACE_FRACTIONS) {
        let target = (original.faces as f64 * fraction).round() as usize;
        assert!(t.faces <= target && t.faces + 10 >= target, "{t:?}");
    }
    // Mild simplification, noise and a rigid motion keep every tip; simplification and motion
    // keep the signature too (noise adds salient bumps of its own, so its SIM is larger).
    let motion = report.trials.last().unwrap();
    for t in [&report.trials[1], &report.trials[6], motion] {
        assert_eq!(t.found, 5, "{t:?}");
    }
    for t in [&report.trials[1], motion] {
        assert!(t.sim < 0.1, "{t:?}");
    }
    assert_eq!(motion.unmatched, 0, "{motion:?}");
    assert!(report.markdown().contains("| rigid motion + scale |"));
}

#[test]
fn render_marks_salient_points_in_red() {
    let params = Params::default();
    let extraction = extract(shapes::star(4, &shapes::five_tips()), &params).unwrap();
    let (points, _) = detect(&extraction, &params);
    let cameras = Camera::around();
    let picture = render(&extraction, &points, &cameras, 200);
    assert_eq!((picture.width(), picture.height()), (600, 200));
    let red = |x: u32, y: u32| *picture.get_pixel(x, y) == POINT_COLOUR;
    // The +y tip, up, faces every camera (they look from 25° above): a red dot marks it in
    // each view.
    let top = points
        .iter()
        .find(|p| extraction.mesh.positions[p.vertex as usize].y > 0.9)
        .expect("a salient point on the +y tip");
    for (k, camera) in cameras.iter().enumerate() {
        let q = camera.project(extraction.mesh.positions[top.vertex as usize], 200);
        assert!(
            red(k as u32 * 200 + q.x.round() as u32, q.y.round() as u32),
            "view {k}"
        );
    }
    // Regions are coloured, the rest shaded grey, the background left light.
    let colours: std::collections::HashSet<_> = picture.pixels().map(|p| p.0).collect();
    assert!(colours.len() > 50);

    let dir = tempfile::tempdir().unwrap();
    let (mesh, png) = (dir.path().join("star.obj"), dir.path().join("star.png"));
    shapes::write_obj(&mesh, &shapes::star(3, &shapes::five_tips()));
    let run = Command::new(env!("CARGO_BIN_EXE_salient"))
        .arg("render")
        .arg(&mesh)
        .arg("-o")
        .arg(&png)
        .args(["--size", "120"])
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let written = image::open(&png).unwrap().to_rgb8();
    assert_eq!(written.dimensions(), (360, 120));
    assert!(written.pixels().any(|p| *p == POINT_COLOUR));
}

/// `salient eval duplicates` makes every family of disguises and finds each copy with its
/// family's evidence, whichever of the pair comes first, and links no two models: stars of
/// thousands of vertices and cones, whose two equal moments leave their axes arbitrary, at
/// sizes from 0.01 to 100.
#[test]
fn duplicates_report_finds_every_family_with_its_evidence() {
    let dir = tempfile::tempdir().unwrap();
    let (collection, out) = (dir.path().join("shapes"), dir.path().join("duplicates"));
    write_collection(&collection);
    // The other five-tip stars are turns of s5-0: one asset for the eval.
    for turned in ["s5-1", "s5-2"] {
        std::fs::remove_file(collection.join("star5").join(format!("{turned}.obj"))).unwrap();
    }
    let report = eval(
        &[
            "duplicates".as_ref(),
            collection.as_ref(),
            "--half".as_ref(),
            "all".as_ref(),
            "--out".as_ref(),
            out.as_ref(),
        ],
        &out.join("duplicates.json"),
    );
    assert_eq!(report["models"], 7);
    let families = report["families"].as_array().unwrap();
    assert_eq!(families.len(), 9);
    for family in families {
        let name = family["disguise"].as_str().unwrap();
        assert_eq!(family["copies"], 7, "{name}");
        let wrong: Vec<(&String, &Value)> = family["evidence"]
            .as_object()
            .unwrap()
            .iter()
            // Evidence orders strongest first; a copy found with stronger evidence than its
            // family's is right too (a re-triangulated cone can be its model's very geometry).
            .filter(|(found, _)| {
                let found = found.parse::<Evidence>().ok();
                match family["expected"].as_str() {
                    Some(expected) => found.is_none_or(|f| f > expected.parse().unwrap()),
                    None => found.is_some(),
                }
            })
            .collect();
        assert!(
            wrong.is_empty(),
            "{name}: {wrong:?} against {}",
            family["expected"]
        );
        assert_eq!(family["one_way"], Value::Array(vec![]), "{name}");
        // No family damages these smooth shapes: every copy keeps most of the area, and a
        // re-export all of it.
        assert_eq!(family["damaged"], Value::Array(vec![]), "{name}");
        let area = family["area_kept"]["median"].as_f64().unwrap();
        if name == "reexported" {
            assert!((area - 1.0).abs() < 1e-9, "{area}");
        }
    }
    assert_eq!(report["false_links"], Value::Array(vec![]));
    assert!(std::fs::read_to_string(out.join("duplicates.md"))
        .unwrap()
        .contains("fast_quadric"));
}
