//! Dataset writing and reading: determinism, splits, round trips and clear errors.

use std::path::{Path, PathBuf};

use dynaserve_sim::SimError;
use dynaserve_sim::dataset::DatasetReader;
use dynaserve_sim::generators::{GenerateOptions, Generator, generate_scene};
use dynaserve_sim::writer::generate_dataset;

/// A fresh directory under the system temporary directory, removed on drop.
struct TempDir(PathBuf);

impl TempDir {
    fn new(name: &str) -> Self {
        let dir = std::env::temp_dir().join(format!(
            "dynaserve-sim-{}-{name}-{}",
            std::process::id(),
            std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map(|d| d.as_nanos())
                .unwrap_or(0)
        ));
        std::fs::create_dir_all(&dir).unwrap();
        TempDir(dir)
    }

    fn path(&self) -> &Path {
        &self.0
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn small(generator: Generator, seed: u64, split: &str, scenes: usize) -> GenerateOptions {
    let mut o = GenerateOptions::new(generator, seed, split, scenes);
    o.scenes_per_shard = 2;
    o.sim.frames = 25;
    o.points = 128;
    o
}

fn generate_with_threads(opts: &GenerateOptions, dir: &Path, threads: usize) {
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap();
    pool.install(|| generate_dataset(opts, dir, false, &|| {}))
        .unwrap();
}

fn files(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut out: Vec<(String, Vec<u8>)> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| {
            let e = e.unwrap();
            (
                e.file_name().to_string_lossy().into_owned(),
                std::fs::read(e.path()).unwrap(),
            )
        })
        .collect();
    out.sort();
    out
}

#[test]
fn same_seed_gives_byte_identical_shards_serial_or_parallel() {
    let opts = small(Generator::movi_b(), 3, "train", 5);
    let (a, b, c) = (
        TempDir::new("serial"),
        TempDir::new("parallel"),
        TempDir::new("other-seed"),
    );
    generate_with_threads(&opts, a.path(), 1);
    generate_with_threads(&opts, b.path(), 2);
    let fa = files(a.path());
    let fb = files(b.path());
    let names: Vec<&str> = fa.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(
        names,
        [
            "manifest.json",
            "shard-00000.safetensors",
            "shard-00001.safetensors",
            "shard-00002.safetensors"
        ]
    );
    assert!(
        fa == fb,
        "a parallel run wrote different bytes than a serial run"
    );
    let other = small(Generator::movi_b(), 4, "train", 5);
    generate_with_threads(&other, c.path(), 2);
    let fc = files(c.path());
    assert_ne!(fa[1].1, fc[1].1, "another seed gave the same shard");
}

#[test]
fn splits_and_generators_never_share_scenes() {
    let first_pose = |generator: Generator, split: &str, i: u64| {
        let opts = small(generator, 0, split, 1);
        let s = generate_scene(&opts, i).unwrap();
        (s.record.objects.len(), s.record.objects[0].positions[0])
    };
    let train: Vec<_> = (0..4)
        .map(|i| first_pose(Generator::movi_b(), "train", i))
        .collect();
    let test: Vec<_> = (0..4)
        .map(|i| first_pose(Generator::movi_b(), "test", i))
        .collect();
    let val: Vec<_> = (0..4)
        .map(|i| first_pose(Generator::movi_b(), "val", i))
        .collect();
    let movi_a: Vec<_> = (0..4)
        .map(|i| first_pose(Generator::movi_a(), "train", i))
        .collect();
    for a in &train {
        assert!(!test.contains(a) && !val.contains(a) && !movi_a.contains(a));
    }
    for a in &test {
        assert!(!val.contains(a));
    }
    // Scenes within a split differ too, and a scene is reproducible on its own.
    assert_ne!(train[0], train[1]);
    assert_eq!(train[2], first_pose(Generator::movi_b(), "train", 2));
}

#[test]
fn reader_streams_exactly_what_was_generated() {
    let opts = small(Generator::movi_a(), 9, "val", 5);
    let dir = TempDir::new("roundtrip");
    generate_with_threads(&opts, dir.path(), 2);
    let reader = DatasetReader::open(dir.path()).unwrap();
    assert_eq!(reader.len(), 5);
    let m = reader.manifest();
    assert_eq!(
        (m.generator.as_str(), m.split.as_str(), m.seed),
        ("movi-a", "val", 9)
    );
    assert_eq!((m.frames, m.reference_points, m.physics_hz), (25, 128, 240));
    assert_eq!(m.gravity, [0.0, 0.0, -10.0]);
    assert!((m.dt_frame - 1.0 / 24.0).abs() < 1e-7);
    assert_eq!(
        (m.axis.as_str(), m.quaternion_order.as_str()),
        ("z", "xyzw")
    );
    assert_eq!(m.shapes.len(), 3);
    assert_eq!(m.shards.len(), 3);
    assert!(m.reserved_tensors.contains(&"vertex_positions".to_string()));
    let scenes: Vec<_> = reader.iter().collect::<Result<_, _>>().unwrap();
    assert_eq!(scenes.len(), 5);
    for (i, s) in scenes.iter().enumerate() {
        let want = generate_scene(&opts, i as u64).unwrap().record;
        assert_eq!(s, &want, "scene {i}");
        assert_eq!(&reader.get(i).unwrap(), s);
        for o in &s.objects {
            let n: f32 = o.rotations[10].iter().map(|c| c * c).sum();
            assert!((n - 1.0).abs() < 1e-5, "rotation is not a unit quaternion");
            assert_eq!(o.material, 0);
        }
    }
    let objects: usize = scenes.iter().map(|s| s.objects.len()).sum();
    assert_eq!(objects, m.objects);
    assert!(reader.get(5).is_err());
}

#[test]
fn reader_rejects_bad_manifests_and_shards_clearly() {
    let opts = small(Generator::movi_a(), 2, "test", 3);
    let dir = TempDir::new("corrupt");
    generate_with_threads(&opts, dir.path(), 1);
    let manifest_path = dir.path().join("manifest.json");
    let good = std::fs::read_to_string(&manifest_path).unwrap();

    let missing = TempDir::new("empty");
    let err = DatasetReader::open(missing.path()).unwrap_err();
    assert!(matches!(err, SimError::Io { .. }), "{err}");
    assert!(err.to_string().contains("manifest.json"), "{err}");

    std::fs::write(&manifest_path, "{ not json").unwrap();
    let err = DatasetReader::open(dir.path()).unwrap_err();
    assert!(matches!(err, SimError::Manifest { .. }), "{err}");

    std::fs::write(
        &manifest_path,
        good.replace("\"format_version\": 1", "\"format_version\": 99"),
    )
    .unwrap();
    let err = DatasetReader::open(dir.path()).unwrap_err();
    assert!(err.to_string().contains("version 99"), "{err}");

    std::fs::write(
        &manifest_path,
        good.replace("\"scenes\": 3,", "\"scenes\": 4,"),
    )
    .unwrap();
    let err = DatasetReader::open(dir.path()).unwrap_err();
    assert!(err.to_string().contains("shards hold 3 scenes"), "{err}");

    // Frame count that disagrees with the shards: the shard error names the file and tensor.
    std::fs::write(
        &manifest_path,
        good.replace("\"frames\": 25", "\"frames\": 26"),
    )
    .unwrap();
    let reader = DatasetReader::open(dir.path()).unwrap();
    let err = reader.iter().next().unwrap().unwrap_err();
    let text = err.to_string();
    assert!(
        text.contains("shard-00000.safetensors") && text.contains("positions"),
        "{text}"
    );
    assert!(
        reader.iter().nth(1).is_none(),
        "the stream ends after an error"
    );

    // A truncated shard.
    std::fs::write(&manifest_path, &good).unwrap();
    let shard = dir.path().join("shard-00001.safetensors");
    let bytes = std::fs::read(&shard).unwrap();
    std::fs::write(&shard, &bytes[..bytes.len() / 2]).unwrap();
    let reader = DatasetReader::open(dir.path()).unwrap();
    let results: Vec<_> = reader.iter().collect();
    assert_eq!(results.len(), 3, "two good scenes, then the error");
    assert!(results[0].is_ok() && results[1].is_ok());
    let err = results[2].as_ref().unwrap_err();
    assert!(matches!(err, SimError::Shard { .. }), "{err}");
    assert!(err.to_string().contains("shard-00001"), "{err}");

    // A missing shard.
    std::fs::remove_file(&shard).unwrap();
    let err = reader.get(2).unwrap_err();
    assert!(err.to_string().contains("shard-00001"), "{err}");
}

#[test]
fn existing_dataset_is_kept_unless_overwrite() {
    let opts = small(Generator::movi_a(), 1, "train", 1);
    let dir = TempDir::new("overwrite");
    generate_dataset(&opts, dir.path(), false, &|| {}).unwrap();
    let err = generate_dataset(&opts, dir.path(), false, &|| {}).unwrap_err();
    assert!(err.to_string().contains("--overwrite"), "{err}");
    let more = small(Generator::movi_a(), 1, "train", 3);
    generate_dataset(&more, dir.path(), true, &|| {}).unwrap();
    assert_eq!(DatasetReader::open(dir.path()).unwrap().len(), 3);
}

#[test]
fn wrecking_ball_has_the_stack_and_the_ball() {
    let opts = small(Generator::wrecking_ball(5).unwrap(), 0, "test", 1);
    let s = generate_scene(&opts, 0).unwrap().record;
    assert_eq!(s.objects.len(), 126);
    let ball = s.objects.last().unwrap();
    assert_eq!(ball.shape_id, 1);
    assert!(
        ball.mass > 20.0 * s.objects[0].mass,
        "the ball is heavy: {} vs {}",
        ball.mass,
        s.objects[0].mass
    );
    assert!(s.objects[..125].iter().all(|o| o.shape_id == 0));
    assert!(Generator::wrecking_ball(0).is_err());
}

#[test]
fn inspect_and_preview_read_a_small_split() {
    let opts = small(Generator::movi_b(), 5, "val", 3);
    let dir = TempDir::new("inspect");
    generate_with_threads(&opts, dir.path(), 2);
    let reader = DatasetReader::open(dir.path()).unwrap();
    let stats = dynaserve_sim::stats::inspect(&reader, None).unwrap();
    let objects: usize = reader.iter().map(|s| s.unwrap().objects.len()).sum();
    assert_eq!((stats.scenes, stats.objects), (3, objects));
    assert_eq!(stats.shapes.values().sum::<usize>(), objects);
    assert!((0.0..=1.0).contains(&stats.resting_fraction));
    assert!(stats.initial_speed.max > 0.5, "objects are thrown");
    assert!(stats.max_height.max <= 5.0 + 1.0);
    let text = stats.to_string();
    assert!(text.contains("movi-b / val: 3 scenes"), "{text}");
    assert_eq!(
        dynaserve_sim::stats::inspect(&reader, Some(1))
            .unwrap()
            .scenes,
        1
    );

    let png = dir.path().join("preview.png");
    let scenes = vec![(0, reader.get(0).unwrap()), (1, reader.get(1).unwrap())];
    dynaserve_sim::preview::write_preview(&scenes, "test", &png).unwrap();
    let bytes = std::fs::read(&png).unwrap();
    assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n");
    assert!(
        bytes.len() > 10_000,
        "an almost empty picture: {} bytes",
        bytes.len()
    );
    assert!(dynaserve_sim::preview::write_preview(&[], "x", &png).is_err());
}
