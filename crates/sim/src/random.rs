//! Seeded randomness shared by every scene sampler: the generator of one scene, keyed by
//! `(seed, split, generator, index)`, and uniformly distributed rotations.
//!
//! Scene `i` of split `split` draws from a ChaCha8 generator keyed by its four inputs, so scenes
//! never repeat across splits or generators, and generating in parallel gives exactly the bytes
//! of a serial run.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Uniformly distributed unit quaternion `[x, y, z, w]` (Shoemake's method).
pub fn random_rotation<R: Rng + ?Sized>(rng: &mut R) -> [f32; 4] {
    let (u1, u2, u3) = (
        rng.random::<f64>(),
        rng.random::<f64>(),
        rng.random::<f64>(),
    );
    let (a, b) = ((1.0 - u1).sqrt(), u1.sqrt());
    let t2 = std::f64::consts::TAU * u2;
    let t3 = std::f64::consts::TAU * u3;
    [
        (a * t2.sin()) as f32,
        (a * t2.cos()) as f32,
        (b * t3.sin()) as f32,
        (b * t3.cos()) as f32,
    ]
}

fn mix(mut z: u64) -> u64 {
    // SplitMix64 finaliser: a bijection on u64 with good avalanche.
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

fn fnv1a(s: &str) -> u64 {
    s.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
        (h ^ b as u64).wrapping_mul(0x0000_0100_0000_01B3)
    })
}

/// The random generator of scene `index` of `split` for `generator` and `seed`: a ChaCha8 key
/// made of the four mixed inputs, so distinct inputs give independent streams.
pub fn scene_rng(seed: u64, split: &str, generator: &str, index: u64) -> ChaCha8Rng {
    let words = [
        mix(seed),
        mix(fnv1a(split) ^ 0x5350_4c49_5400_0000),
        mix(index ^ 0x5343_454e_4500_0000),
        mix(fnv1a(generator)),
    ];
    let mut key = [0u8; 32];
    for (chunk, w) in key.chunks_exact_mut(8).zip(words) {
        chunk.copy_from_slice(&w.to_le_bytes());
    }
    ChaCha8Rng::from_seed(key)
}
