//! The curriculum sets of mesh scenes and their scene samplers.
//!
//! | set | objects | templates | start | material |
//! |---|---|---|---|---|
//! | `mesh-d1` | 1-5 | the 15 convex | floor | rigid |
//! | `mesh-d2` | 1-5 | convex and concave (40% concave) | floor | rigid |
//! | `mesh-d3` | 1-5 (half the scenes) or 6-10 | convex and concave | airborne, 40% of scenes spinning | rigid |
//! | `mesh-d4` | 1-5 | convex and concave | floor or airborne (50/50) | all elastic (half) or mixed rigid/elastic |
//!
//! Floor starts: each object stands on the floor in its template's upright pose, turned about
//! the vertical by a uniform angle and tilted by up to 0.1 rad about a random horizontal axis
//! (so objects balanced on an edge or vertex topple), and slides off at 0.5-2.5 m/s in a uniform
//! horizontal direction (25% of objects start still). Airborne starts: uniform random attitude
//! anywhere in the box, velocity uniform in `[-2, 2]^3` m/s (25% still). Objects never overlap at
//! the start (their bounding spheres are apart by at least 2 cm) and lie inside the box.

use rand::Rng;
use serde_json::json;

use super::format::SceneStart;
use super::record::MeshMaterial;
use super::simulate::{MeshObjectSpec, MeshPhysics, MeshSceneSpec};
use super::templates::{CONVEX_TEMPLATES, MeshTemplate, templates};
use crate::random::random_rotation;
use crate::{Result, SimError};

/// A curriculum set of mesh scenes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum MeshSet {
    /// Rigid, floor start, 1-5 convex objects.
    D1,
    /// Rigid, floor start, 1-5 convex or concave objects.
    D2,
    /// Rigid, airborne start, 1-5 or 6-10 objects, some spinning.
    D3,
    /// Elastic or mixed rigid/elastic, 1-5 objects, floor or airborne start.
    D4,
}

/// Smallest and largest circumradius of an object, metres.
pub const SCALE_RANGE: (f32, f32) = (0.10, 0.16);
/// Gap kept between bounding spheres at the start, metres.
pub const SPAWN_GAP: f32 = 0.02;
const CONCAVE_FRACTION: f64 = 0.4;
const STILL_FRACTION: f64 = 0.25;
const FLOOR_SPEED: (f32, f32) = (0.5, 2.5);
const AIR_SPEED: f32 = 2.0;
const TILT: f32 = 0.1;
const SPIN_FRACTION: f64 = 0.4;
const SPIN_RANGE: (f32, f32) = (2.0, 8.0);

impl MeshSet {
    /// Every set, in curriculum order.
    pub const ALL: [MeshSet; 4] = [MeshSet::D1, MeshSet::D2, MeshSet::D3, MeshSet::D4];

    /// The generator name: `mesh-d1` ... `mesh-d4`.
    pub fn name(self) -> &'static str {
        match self {
            MeshSet::D1 => "mesh-d1",
            MeshSet::D2 => "mesh-d2",
            MeshSet::D3 => "mesh-d3",
            MeshSet::D4 => "mesh-d4",
        }
    }

    /// Every sampling parameter, for the manifest.
    pub fn parameters(self) -> serde_json::Value {
        let templates = match self {
            MeshSet::D1 => json!({"convex": CONVEX_TEMPLATES, "concave": 0}),
            _ => {
                json!({"convex": CONVEX_TEMPLATES, "concave": "all", "concave_fraction": CONCAVE_FRACTION})
            }
        };
        let (objects, start, material) = match self {
            MeshSet::D1 | MeshSet::D2 => (json!([1, 5]), json!("floor"), json!("rigid")),
            MeshSet::D3 => (
                json!({"half of the scenes": [1, 5], "other half": [6, 10]}),
                json!({"airborne": 1.0, "spin_fraction": SPIN_FRACTION, "spin_rad_per_s": [SPIN_RANGE.0, SPIN_RANGE.1]}),
                json!("rigid"),
            ),
            MeshSet::D4 => (
                json!([1, 5]),
                json!({"floor": 0.5, "airborne": 0.5}),
                json!(
                    "half the scenes all elastic; the others draw each object 50/50 with at least one elastic and (with 2+ objects) one rigid"
                ),
            ),
        };
        json!({
            "objects": objects,
            "templates": templates,
            "start": start,
            "material": material,
            "scale_circumradius_m": [SCALE_RANGE.0, SCALE_RANGE.1],
            "spawn_gap_m": SPAWN_GAP,
            "still_fraction": STILL_FRACTION,
            "floor_speed_m_per_s": [FLOOR_SPEED.0, FLOOR_SPEED.1],
            "floor_tilt_rad": TILT,
            "airborne_velocity_box_m_per_s": AIR_SPEED,
        })
    }

    /// Draws one scene of the set from `rng`.
    pub fn sample<R: Rng + ?Sized>(
        self,
        rng: &mut R,
        phys: &MeshPhysics,
    ) -> Result<(MeshSceneSpec, SceneStart)> {
        let lib = templates()?;
        let count = match self {
            MeshSet::D3 if rng.random_bool(0.5) => rng.random_range(6..=10),
            _ => rng.random_range(1..=5),
        };
        let airborne = match self {
            MeshSet::D1 | MeshSet::D2 => false,
            MeshSet::D3 => true,
            MeshSet::D4 => rng.random_bool(0.5),
        };
        let spin = self == MeshSet::D3 && rng.random_bool(SPIN_FRACTION);
        let materials = self.materials(rng, count);
        let mut objects: Vec<MeshObjectSpec> = Vec::with_capacity(count);
        for material in materials {
            let template = if self == MeshSet::D1 || !rng.random_bool(CONCAVE_FRACTION) {
                rng.random_range(0..CONVEX_TEMPLATES)
            } else {
                rng.random_range(CONVEX_TEMPLATES..lib.len())
            };
            let scale = rng.random_range(SCALE_RANGE.0..=SCALE_RANGE.1);
            let mut o = MeshObjectSpec {
                template,
                scale,
                material,
                position: [0.0; 3],
                rotation: [0.0, 0.0, 0.0, 1.0],
                linvel: [0.0; 3],
                angvel: [0.0; 3],
            };
            place(rng, &mut o, &lib[template], &objects, airborne, phys)?;
            if !rng.random_bool(STILL_FRACTION) {
                o.linvel = if airborne {
                    [0; 3].map(|_| rng.random_range(-AIR_SPEED..=AIR_SPEED))
                } else {
                    let a = rng.random_range(0.0..std::f32::consts::TAU);
                    let s = rng.random_range(FLOOR_SPEED.0..=FLOOR_SPEED.1);
                    [s * a.cos(), s * a.sin(), 0.0]
                };
            }
            if spin {
                let axis = random_unit(rng);
                let w = rng.random_range(SPIN_RANGE.0..=SPIN_RANGE.1);
                o.angvel = axis.map(|c| c * w);
            }
            objects.push(o);
        }
        let start = SceneStart {
            start: if airborne { "airborne" } else { "floor" }.into(),
            spin,
        };
        Ok((MeshSceneSpec { objects }, start))
    }

    fn materials<R: Rng + ?Sized>(self, rng: &mut R, count: usize) -> Vec<MeshMaterial> {
        if self != MeshSet::D4 {
            return vec![MeshMaterial::Rigid; count];
        }
        if count == 1 || rng.random_bool(0.5) {
            return vec![MeshMaterial::Elastic; count];
        }
        loop {
            let m: Vec<MeshMaterial> = (0..count)
                .map(|_| {
                    if rng.random_bool(0.5) {
                        MeshMaterial::Elastic
                    } else {
                        MeshMaterial::Rigid
                    }
                })
                .collect();
            if m.contains(&MeshMaterial::Elastic) && m.contains(&MeshMaterial::Rigid) {
                return m;
            }
        }
    }
}

fn random_unit<R: Rng + ?Sized>(rng: &mut R) -> [f32; 3] {
    loop {
        let v = [0; 3].map(|_| rng.random_range(-1.0f32..=1.0));
        let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        if n > 0.1 && n <= 1.0 {
            return v.map(|c| c / n);
        }
    }
}

fn quat_mul(a: [f32; 4], b: [f32; 4]) -> [f32; 4] {
    let [ax, ay, az, aw] = a;
    let [bx, by, bz, bw] = b;
    [
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    ]
}

fn axis_angle(axis: [f32; 3], angle: f32) -> [f32; 4] {
    let (s, c) = (0.5 * angle).sin_cos();
    [axis[0] * s, axis[1] * s, axis[2] * s, c]
}

/// Chooses the attitude and position of `o` (scale and template set) so that it lies inside
/// the box and its bounding sphere clears the objects already placed.
fn place<R: Rng + ?Sized>(
    rng: &mut R,
    o: &mut MeshObjectSpec,
    t: &MeshTemplate,
    placed: &[MeshObjectSpec],
    airborne: bool,
    phys: &MeshPhysics,
) -> Result<()> {
    let (h, r) = (phys.box_half, o.scale);
    let lift = if o.material == MeshMaterial::Elastic {
        phys.particle_radius
    } else {
        0.0
    } + 0.002;
    for _ in 0..1000 {
        o.rotation = if airborne {
            random_rotation(rng)
        } else {
            let yaw = axis_angle(
                [0.0, 0.0, 1.0],
                rng.random_range(0.0..std::f32::consts::TAU),
            );
            let a = rng.random_range(0.0..std::f32::consts::TAU);
            let tilt = axis_angle([a.cos(), a.sin(), 0.0], rng.random_range(0.0..=TILT));
            quat_mul(tilt, yaw)
        };
        let lim = h - r - SPAWN_GAP;
        let x = rng.random_range(-lim..=lim);
        let y = rng.random_range(-lim..=lim);
        o.position = [x, y, 0.0];
        let z = if airborne {
            rng.random_range(-lim..=lim)
        } else {
            // Lowest vertex just above the floor.
            let lowest = o
                .initial_particles(t)
                .iter()
                .map(|p| p.z)
                .fold(f32::INFINITY, f32::min);
            -h + lift - lowest
        };
        o.position[2] = z;
        let clear = placed.iter().all(|p| {
            let d: f32 = (0..3)
                .map(|k| (p.position[k] - o.position[k]).powi(2))
                .sum::<f32>()
                .sqrt();
            d >= p.scale + r + SPAWN_GAP
        });
        if clear {
            return Ok(());
        }
    }
    Err(SimError::Invalid(format!(
        "no room for a {} m object after {} placed",
        r,
        placed.len()
    )))
}
