//! Mesh scenes simulated with real rapier worlds: elastic bodies keep their volume and deform,
//! rigid bodies stay rigid, everything stays in the box, generation is deterministic per seed
//! and independent of threads, and what is written reads back exactly.

use std::path::PathBuf;

use dynaserve_sim::mesh_scenes::stats::{max_edge_strain, max_outside, max_volume_change};
use dynaserve_sim::mesh_scenes::templates::CONVEX_TEMPLATES;
use dynaserve_sim::mesh_scenes::{
    MeshDatasetReader, MeshGenerateOptions, MeshMaterial, MeshObjectSpec, MeshPhysics,
    MeshSceneSpec, MeshSet, generate_mesh_dataset, generate_mesh_scene, simulate_mesh_scene,
    templates,
};
use dynaserve_sim::{DatasetReader, SimError};

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("dynaserve-mesh-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

fn template(name: &str) -> usize {
    templates()
        .unwrap()
        .iter()
        .position(|t| t.name == name)
        .unwrap()
}

const BOX: [[f32; 3]; 2] = [[-1.0; 3], [1.0; 3]];

#[test]
fn elastic_objects_deform_but_keep_their_volume() {
    // A cube and an L prism thrown at the floor and a wall, a rigid cube beside them.
    let phys = MeshPhysics::default();
    let spec = MeshSceneSpec {
        objects: vec![
            MeshObjectSpec {
                template: template("cube"),
                scale: 0.15,
                material: MeshMaterial::Elastic,
                position: [0.0, 0.0, 0.2],
                rotation: [0.0, 0.0, 0.0, 1.0],
                linvel: [2.0, 0.0, -1.0],
                angvel: [0.0, 3.0, 0.0],
            },
            MeshObjectSpec {
                template: template("l_prism"),
                scale: 0.14,
                material: MeshMaterial::Elastic,
                position: [-0.5, 0.5, -0.2],
                rotation: [0.3, 0.1, 0.0, 0.95],
                linvel: [-2.0, 1.5, 0.0],
                angvel: [0.0; 3],
            },
            MeshObjectSpec {
                template: template("cube"),
                scale: 0.12,
                material: MeshMaterial::Rigid,
                position: [0.5, -0.5, -0.5],
                rotation: [0.0, 0.0, 0.0, 1.0],
                linvel: [0.0, -2.0, 0.0],
                angvel: [0.0; 3],
            },
        ],
    };
    let s = simulate_mesh_scene(&spec, &phys).unwrap();
    assert_eq!(s.frames, 49);
    assert!((s.dt_frame - 5.0 / 240.0).abs() < 1e-7);
    for i in 0..2 {
        let strain = max_edge_strain(&s, i);
        let volume = max_volume_change(&s, i);
        assert!(strain > 0.01, "elastic object {i} hardly deforms: {strain}");
        assert!(
            volume < 0.05,
            "elastic object {i} volume changes by {volume}"
        );
        // It moved and fell: the impact really happened.
        let lowest = s.objects[i]
            .vertices
            .clone()
            .map(|v| s.position(v, s.frames - 1)[2])
            .fold(f32::INFINITY, f32::min);
        assert!(lowest < -0.98, "object {i} ends {lowest} m above the floor");
    }
    assert!(max_edge_strain(&s, 2) < 1e-5, "the rigid cube deforms");
    let out = max_outside(&s, BOX);
    assert!(out < 0.01, "a vertex gets {out} m outside the box");
    // Frame 0 is the initial state and its velocities are those of the spec.
    let v = s.objects[2].vertices.start;
    assert_eq!(s.initial_velocity(v), [0.0, -2.0, 0.0]);
}

#[test]
fn rigid_sets_stay_rigid_and_inside_the_box() {
    for (set, scenes) in [
        (MeshSet::D1, 0..3u64),
        (MeshSet::D2, 0..3),
        (MeshSet::D3, 0..4),
    ] {
        let opts = MeshGenerateOptions::new(set, 7, "test", 4);
        for i in scenes {
            let (s, start) = generate_mesh_scene(&opts, i).unwrap();
            assert!(!s.objects.is_empty() && s.objects.len() <= 10);
            assert_eq!(start.start == "airborne", set == MeshSet::D3, "{set:?}");
            for (k, o) in s.objects.iter().enumerate() {
                assert_eq!(o.material, MeshMaterial::Rigid);
                if set == MeshSet::D1 {
                    assert!((o.template_id as usize) < CONVEX_TEMPLATES);
                    assert!((4..=20).contains(&o.vertices.len()));
                }
                let e = max_edge_strain(&s, k);
                assert!(
                    e < 1e-4,
                    "{set:?} scene {i} object {k}: edges change by {e}"
                );
            }
            let out = max_outside(&s, BOX);
            assert!(out < 0.01, "{set:?} scene {i}: {out} m outside the box");
        }
    }
}

#[test]
fn sets_draw_what_they_promise() {
    let opts = |set| MeshGenerateOptions::new(set, 3, "train", 1);
    let rng_scene = |set: MeshSet, i: u64| {
        let mut rng = dynaserve_sim::random::scene_rng(3, "train", set.name(), i);
        set.sample(&mut rng, &opts(set).physics).unwrap()
    };
    let (mut many, mut spin, mut elastic, mut mixed, mut concave) = (0, 0, 0, 0, 0);
    for i in 0..60 {
        let (d3, start) = rng_scene(MeshSet::D3, i);
        many += usize::from(d3.objects.len() > 5);
        spin += usize::from(start.spin);
        assert_eq!(start.spin, d3.objects.iter().all(|o| o.angvel != [0.0; 3]));
        let (d4, _) = rng_scene(MeshSet::D4, i);
        let n_el = d4
            .objects
            .iter()
            .filter(|o| o.material == MeshMaterial::Elastic)
            .count();
        assert!(n_el >= 1, "a mesh-d4 scene without an elastic object");
        elastic += usize::from(n_el == d4.objects.len());
        mixed += usize::from(n_el < d4.objects.len());
        let (d2, _) = rng_scene(MeshSet::D2, i);
        concave += d2
            .objects
            .iter()
            .filter(|o| o.template >= CONVEX_TEMPLATES)
            .count();
    }
    assert!(
        many > 10 && many < 50,
        "{many} of 60 mesh-d3 scenes have 6-10 objects"
    );
    assert!(spin > 5 && spin < 45, "{spin} of 60 mesh-d3 scenes spin");
    assert!(
        elastic > 10 && mixed > 10,
        "{elastic} all-elastic, {mixed} mixed"
    );
    assert!(
        concave > 10,
        "{concave} concave objects in 60 mesh-d2 scenes"
    );
}

#[test]
fn splits_are_deterministic_thread_independent_and_read_back_exactly() {
    let (a, b) = (tmp("det-a"), tmp("det-b"));
    let mut opts = MeshGenerateOptions::new(MeshSet::D4, 11, "val", 5);
    opts.scenes_per_shard = 2;
    let one = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let two = rayon::ThreadPoolBuilder::new()
        .num_threads(2)
        .build()
        .unwrap();
    let sa = one
        .install(|| generate_mesh_dataset(&opts, &a, false, &|| {}))
        .unwrap();
    two.install(|| generate_mesh_dataset(&opts, &b, false, &|| {}))
        .unwrap();
    assert_eq!(sa.manifest.shards.len(), 3);
    for f in [
        "manifest.json",
        "shard-00000.safetensors",
        "shard-00002.safetensors",
    ] {
        assert_eq!(
            std::fs::read(a.join(f)).unwrap(),
            std::fs::read(b.join(f)).unwrap(),
            "{f} differs between 1 and 2 threads"
        );
    }
    let reader = MeshDatasetReader::open(&a).unwrap();
    assert_eq!(reader.len(), 5);
    let all = reader.read_all().unwrap();
    for (i, s) in all.iter().enumerate() {
        let (want, start) = generate_mesh_scene(&opts, i as u64).unwrap();
        assert_eq!(s, &want, "scene {i} does not read back as simulated");
        assert_eq!(reader.manifest().scene_starts[i], start);
        assert_eq!(s.positions.len(), s.num_vertices() * 49 * 3);
        assert_eq!(s.vertex_materials().len(), s.num_vertices());
    }
    assert_eq!(reader.get(3).unwrap(), all[3]);
    assert_eq!(reader.iter().count(), 5);
    // Another seed gives other scenes.
    let other = MeshGenerateOptions::new(MeshSet::D4, 12, "val", 5);
    assert_ne!(generate_mesh_scene(&other, 0).unwrap().0, all[0]);
    // A second run into the same directory is refused, and allowed with overwrite.
    assert!(generate_mesh_dataset(&opts, &a, false, &|| {}).is_err());
    generate_mesh_dataset(&opts, &a, true, &|| {}).unwrap();
    assert_eq!(
        MeshDatasetReader::open(&a).unwrap().read_all().unwrap(),
        all
    );
    let _ = std::fs::remove_dir_all(&a);
    let _ = std::fs::remove_dir_all(&b);
}

#[test]
fn bad_input_gives_errors_not_panics() {
    let dir = tmp("bad");
    let mut opts = MeshGenerateOptions::new(MeshSet::D1, 0, "train", 2);
    opts.scenes_per_shard = 1;
    generate_mesh_dataset(&opts, &dir, false, &|| {}).unwrap();
    let err = DatasetReader::open(&dir).unwrap_err();
    assert!(err.to_string().contains("mesh dataset"), "{err}");
    assert!(matches!(
        MeshDatasetReader::open(dir.join("missing")).unwrap_err(),
        SimError::Io { .. }
    ));
    let reader = MeshDatasetReader::open(&dir).unwrap();
    assert!(reader.get(2).is_err());
    let shard = dir.join("shard-00001.safetensors");
    let bytes = std::fs::read(&shard).unwrap();
    std::fs::write(&shard, &bytes[..bytes.len() / 2]).unwrap();
    assert!(matches!(reader.get(1).unwrap_err(), SimError::Shard { .. }));
    assert!(reader.get(0).is_ok());
    let bad = MeshSceneSpec {
        objects: vec![MeshObjectSpec {
            template: 999,
            scale: 0.1,
            material: MeshMaterial::Rigid,
            position: [0.0; 3],
            rotation: [0.0, 0.0, 0.0, 1.0],
            linvel: [0.0; 3],
            angvel: [0.0; 3],
        }],
    };
    assert!(simulate_mesh_scene(&bad, &MeshPhysics::default()).is_err());
    let _ = std::fs::remove_dir_all(&dir);
}
