//! The official PhysiFormer data readers: an example scene folder written from a rapier mesh
//! scene in the official layout reads back as that scene; a material variant beside it takes
//! its trajectory from `vertices.npz` and its materials from its name; a precomputed
//! evaluation sample written by NumPy (compressed, padded, objects interleaved) reads as its
//! present vertices grouped by object.

use std::path::{Path, PathBuf};

use candle_core::{Device, Tensor};
use dynaserve_model::physiformer::scene::Material;
use dynaserve_sim::mesh_scenes::{MeshGenerateOptions, MeshSet, generate_mesh_dataset};
use dynaserve_train::physi::data::load_scenes;
use dynaserve_train::physi::eval::PhysiEvalOptions;
use dynaserve_train::physi::official_data::{is_official_examples, load_examples};
use dynaserve_train::physi::official_eval::run_on_dataset;

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("dynaserve-official-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/official-npz")
}

#[test]
fn a_precomputed_sample_reads_as_its_present_vertices_grouped_by_object() {
    let root = fixture();
    assert!(is_official_examples(&root));
    let ex = load_examples(&root).unwrap().examples;
    assert_eq!(ex.len(), 1);
    let e = &ex[0];
    assert_eq!(e.name, "2obj_rigid/sample_000000.npz");
    assert_eq!(e.masses, [2.0, 3.5]);
    let s = &e.scene;
    assert_eq!(s.frames, 3);
    assert_eq!(s.scene.vertex_offsets, [0, 3, 6]);
    assert_eq!(s.scene.materials, [Material::Rigid; 2]);
    // Object 0 holds slots 1, 2, 5 and object 1 slots 0, 3, 4; slot 6 is padding.
    let slots = [1usize, 2, 5, 0, 3, 4];
    let close = |a: f32, b: f64| (a as f64 - b).abs() < 1e-6;
    for (k, &i) in slots.iter().enumerate() {
        for c in 0..3 {
            let v = s.scene.velocities[k][c];
            assert!(
                close(v, -(i as f64) - 0.5 * c as f64),
                "velocity {k} {c}: {v}"
            );
            for f in 0..3 {
                let x = s.trajectory[(f * 6 + k) * 3 + c];
                assert!(
                    close(x, i as f64 + 0.1 * c as f64 + 0.01 * f as f64),
                    "{f} {k} {c}: {x}"
                );
            }
            assert_eq!(s.scene.positions[k][c], s.trajectory[k * 3 + c]);
        }
    }
}

/// Writes `scene`'s first mesh scene in the official folder layout (no faces: masses 0).
fn write_folder(dir: &Path, s: &dynaserve_model::physiformer::flow::TrainScene) {
    std::fs::create_dir_all(dir.join("meshes")).unwrap();
    std::fs::create_dir_all(dir.join("vertex_velocities")).unwrap();
    let objects: Vec<serde_json::Value> = s
        .scene
        .vertex_offsets
        .windows(2)
        .zip(&s.scene.materials)
        .enumerate()
        .map(|(o, (w, m))| {
            let kind = if *m == Material::Rigid {
                "rigid"
            } else {
                "elastic"
            };
            serde_json::json!({"name": format!("object{o}"), "vertex_count": w[1] - w[0],
                               "material": {"kind": kind}})
        })
        .collect();
    let meta = serde_json::json!({"objects": objects, "density": 1000.0});
    std::fs::write(dir.join("metadata.json"), meta.to_string()).unwrap();
    let v = s.scene.vertices();
    for f in 0..s.frames {
        let mut obj = String::new();
        for p in s.trajectory[f * v * 3..(f + 1) * v * 3].chunks(3) {
            obj.push_str(&format!("v {} {} {}\n", p[0], p[1], p[2]));
        }
        std::fs::write(dir.join(format!("meshes/combined_frame_{f:03}.obj")), obj).unwrap();
    }
    let vel: Vec<f32> = s.scene.velocities.iter().flatten().copied().collect();
    Tensor::from_vec(vel, (v, 3), &Device::Cpu)
        .unwrap()
        .write_npy(dir.join("vertex_velocities/combined_frame_000.npy"))
        .unwrap();
}

#[test]
fn a_scene_folder_and_its_material_variant_read_back() {
    let dir = tmp("folder");
    let data = dir.join("d1");
    let opts = MeshGenerateOptions::new(MeshSet::D1, 1, "test", 5);
    generate_mesh_dataset(&opts, &data, false, &|| {}).unwrap();
    let src = load_scenes(&[data]).unwrap().remove(0);
    let root = dir.join("official");
    let scene = root.join("2obj/4_blender");
    write_folder(&scene, &src);
    // A variant: every object elastic, the trajectory shifted up by 1 cm.
    let v = src.scene.vertices();
    let shifted: Vec<f32> = src
        .trajectory
        .iter()
        .enumerate()
        .map(|(i, x)| if i % 3 == 2 { x + 0.01 } else { *x })
        .collect();
    std::fs::create_dir_all(scene.join("all_elastic")).unwrap();
    let t = Tensor::from_vec(shifted.clone(), (src.frames, v, 3), &Device::Cpu).unwrap();
    Tensor::write_npz(&[("vertices", &t)], scene.join("all_elastic/vertices.npz")).unwrap();
    let ex = load_examples(&root).unwrap().examples;
    assert_eq!(ex.len(), 2);
    let (folder, variant) = (&ex[0], &ex[1]);
    assert_eq!(folder.name, "2obj/4_blender");
    assert_eq!(variant.name, "2obj/4_blender/all_elastic");
    let close = |a: &[f32], b: &[f32]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-5);
    assert_eq!(folder.scene.frames, src.frames);
    assert!(close(&folder.scene.trajectory, &src.trajectory));
    assert_eq!(folder.scene.scene.vertex_offsets, src.scene.vertex_offsets);
    assert_eq!(folder.scene.scene.materials, src.scene.materials);
    assert!(close(
        &folder.scene.scene.velocities.concat(),
        &src.scene.velocities.concat()
    ));
    let n = src.scene.materials.len();
    assert_eq!(variant.scene.scene.materials, vec![Material::Elastic; n]);
    assert!(close(&variant.scene.trajectory, &shifted));
    assert_eq!(variant.scene.scene.positions, folder.scene.scene.positions);

    std::fs::create_dir_all(scene.join("1_elastic_1_rigid")).unwrap();
    Tensor::write_npz(
        &[("vertices", &t)],
        scene.join("1_elastic_1_rigid/vertices.npz"),
    )
    .unwrap();
    // A mixed variant whose name does not say which object is elastic is skipped, by name.
    let data = load_examples(&root).unwrap();
    assert_eq!(data.examples.len(), 2);
    assert_eq!(data.skipped.len(), 1);
    assert!(
        data.skipped[0].contains("1_elastic_1_rigid"),
        "{:?}",
        data.skipped
    );
    // A corrupt variant is an error naming it.
    std::fs::write(scene.join("all_elastic/vertices.npz"), b"not a zip").unwrap();
    let err = load_examples(&root).err().map(|e| format!("{e:#}"));
    assert!(
        err.as_deref().is_some_and(|e| e.contains("all_elastic")),
        "{err:?}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// `dynaserve eval --official-metrics` on a mesh dataset of ours: the bundled model against
/// the baselines, with each object's simulated mass for the momentum metric.
#[test]
fn the_official_metrics_score_a_mesh_dataset_of_ours() {
    let dir = tmp("metrics");
    let data = dir.join("d3");
    let opts = MeshGenerateOptions::new(MeshSet::D3, 2, "test", 9);
    generate_mesh_dataset(&opts, &data, false, &|| {}).unwrap();
    let model = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/physiformer-small");
    let report = run_on_dataset(&PhysiEvalOptions {
        model,
        data,
        scenes: 2,
        samples: 1,
        steps: 2,
        seed: 0,
        plot: None,
        device: "cpu".into(),
    })
    .unwrap();
    let row = |name: &str| *report.rows.iter().find(|r| r.0 == name).unwrap();
    let (m, cv, ff) = (row("model"), row("constant velocity"), row("free flight"));
    assert!(m.1.is_finite() && m.3.is_finite(), "{m:?}");
    // Constant velocity keeps every object's momentum; free flight under gravity does not.
    assert!(cv.3.abs() < 1e-4, "{cv:?}");
    assert!(ff.3 > 0.0, "{ff:?}");
    // Falling objects (D3 starts in the air) leave free flight behind at the floor; the model,
    // correcting the object-wise prior, is far closer than unclamped free flight.
    assert!(m.1 < ff.1, "model {m:?}, free flight {ff:?}");
    std::fs::remove_dir_all(&dir).unwrap();
}
