//! Contact wrench ([`crate::DynamicsConfig::contact_wrench`]): every point predicts a force,
//! and each object moves by the mean force and turns by the mean moment of those forces about
//! its cloud's centroid, divided by the cloud's inertia.
//!
//! A contact's torque is a sum over the points it touches of lever arm times force. The
//! per-anchor head can only form it by agreeing on a pattern of eight outputs, each computed
//! from its own query; here the cross products and the inertia are fixed geometry and the
//! network learns one local function, the force at a point, that every contact shares.
//!
//! The geometry is computed on the host per step ([`wrench_geometry`]); the forward pass
//! ([`ContactWrench::forward`]) is candle ops, differentiable in the force.

use candle_core::{Device, Tensor};
use nalgebra::{Matrix3, Vector3};

use super::batch::BatchInputs;
use super::{host_index, host_tensor};
use crate::layers::{Linear, ParamStore};
use crate::{ModelConfig, ModelError};

/// Hidden width of the force MLP.
pub(crate) const WRENCH_HIDDEN: usize = 64;

/// `[r]_x` flattened row-major: the matrix with `[r]_x f = r x f`.
fn skew(r: Vector3<f32>) -> [f32; 9] {
    [0.0, -r.z, r.y, r.z, 0.0, -r.x, -r.y, r.x, 0.0]
}

/// One object's wrench geometry at t, offsets scaled by `inv_scale` (1 / the model's position
/// scale): the lever matrices `[n, 9]` (`[r_i]_x` for each point of `world` (`[n, 3]` metres)
/// less the cloud's world `centroid`, so that `L_i f` is point `i`'s moment about it) and the
/// anchor matrices `[K, 9]` (`-[r_k]_x J^-1` for each scaled anchor offset of `anchor_rel`
/// (`[K, 3]`), so that `A_k tau` is `alpha x r_k` for `alpha = J^-1 tau`), with
/// `J^-1 = R inertia_inv R^T` the body-frame [`super::inertia::floored_inertia_inverse`]
/// turned by the object's rotation `rotation`. Both row-major 3 x 3.
pub(crate) fn wrench_geometry(
    world: &[[f32; 3]],
    centroid: Vector3<f32>,
    anchor_rel: &[f32],
    inertia_inv: &Matrix3<f32>,
    rotation: &Matrix3<f32>,
    inv_scale: f32,
) -> (Vec<f32>, Vec<f32>) {
    let mut levers = Vec::with_capacity(world.len() * 9);
    for p in world {
        levers.extend_from_slice(&skew((Vector3::from(*p) - centroid) * inv_scale));
    }
    // Metres^-2 to scaled units^-2.
    let inverse = rotation * inertia_inv * rotation.transpose() / (inv_scale * inv_scale);
    let mut spin = Vec::with_capacity(anchor_rel.len() * 3);
    for r in anchor_rel.chunks(3) {
        let m = -Matrix3::from_row_slice(&skew(Vector3::new(r[0], r[1], r[2]))) * inverse;
        for row in 0..3 {
            for col in 0..3 {
                spin.push(m[(row, col)]);
            }
        }
    }
    (levers, spin)
}

/// The unit's layers (`anchors.wrench.*` parameters): a point layer on the encoder's point
/// feature (`C1 -> H`), an object layer on the anchor head's projection of the object's token
/// (`D -> H`, no bias), and an output layer (`H -> 3`, starting at zero).
pub(crate) struct ContactWrench {
    point: Linear,
    object: Linear,
    out: Linear,
    device: Device,
}

impl ContactWrench {
    /// Creates or loads the unit's parameters for configuration `c`.
    pub fn new(
        p: &mut ParamStore,
        c: &ModelConfig,
        device: &Device,
    ) -> Result<ContactWrench, ModelError> {
        Ok(ContactWrench {
            point: p.linear("anchors.wrench.point", c.point_dim, WRENCH_HIDDEN, true)?,
            object: p.linear("anchors.wrench.object", c.width, WRENCH_HIDDEN, false)?,
            out: p.linear_init("anchors.wrench.out", WRENCH_HIDDEN, 3, true, 0.0)?,
            device: device.clone(),
        })
    }

    /// The wrench's acceleration of every anchor, `[O, K, 3]` in the head's output unit, from
    /// the packed point features (`[P, C1]`) and the objects' projected tokens (`[O, D]`):
    /// each object's mean point force plus `alpha x r_k`.
    pub fn forward(
        &self,
        inp: &BatchInputs,
        anchors: usize,
        point_features: &Tensor,
        object_tokens: &Tensor,
    ) -> Result<Tensor, ModelError> {
        let (device, o, p) = (&self.device, inp.o, inp.points);
        if inp.point_lever.len() != p * 9 || inp.anchor_spin.len() != o * anchors * 9 {
            return Err(ModelError::Internal(
                "contact wrench: the batch has no wrench geometry".into(),
            ));
        }
        let mut object_of = Vec::with_capacity(p);
        let mut inv_count = Vec::with_capacity(o);
        for (j, &(_, n)) in inp.object_points.iter().enumerate() {
            object_of.extend(std::iter::repeat_n(j as u32, n));
            inv_count.push(1.0 / n.max(1) as f32);
        }
        let object_of = host_index(device, &object_of)?;
        // The force at every point: [P, 3].
        let per_object = self.object.forward(object_tokens)?; // [O, H]
        let hidden =
            (self.point.forward(point_features)? + per_object.index_select(&object_of, 0)?)?;
        let force = self.out.forward(&hidden.silu()?)?;
        // Its moment about the centroid, r_i x f_i: [P, 3].
        let lever = host_tensor(device, &inp.point_lever, &[p, 3, 3])?;
        let moment = lever.broadcast_mul(&force.unsqueeze(1)?)?.sum(2)?;
        // Means over each object's points: [O, 6].
        let both = Tensor::cat(&[force, moment], 1)?;
        let sums = Tensor::zeros((o, 6), both.dtype(), device)?.index_add(&object_of, &both, 0)?;
        let means = sums.broadcast_mul(&host_tensor(device, &inv_count, &[o, 1])?)?;
        let (mean_force, torque) = (means.narrow(1, 0, 3)?, means.narrow(1, 3, 3)?);
        // alpha x r_k = A_k tau: [O, K, 3].
        let spin = host_tensor(device, &inp.anchor_spin, &[o, anchors, 3, 3])?;
        let tangential = spin.broadcast_mul(&torque.reshape((o, 1, 1, 3))?)?.sum(3)?;
        Ok(tangential.broadcast_add(&mean_force.unsqueeze(1)?)?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rigidformer::inertia::{INERTIA_FLOOR, floored_inertia_inverse};

    fn apply(m: &[f32], v: Vector3<f32>) -> Vector3<f32> {
        Matrix3::from_row_slice(m) * v
    }

    fn centroid_of(points: &[[f32; 3]]) -> [f32; 3] {
        let c = points
            .iter()
            .map(|p| Vector3::from(*p))
            .sum::<Vector3<f32>>()
            / points.len() as f32;
        [c.x, c.y, c.z]
    }

    /// The geometry of a cloud given in the body frame and turned into the world: the lever
    /// matrices give each point's moment about the world centroid, and the anchor matrices
    /// `alpha x r_k` for `alpha` the world inertia's answer to the torque.
    #[test]
    fn geometry_gives_moments_and_the_spin_they_cause() {
        let body = [
            [1.0f32, 0.2, 0.3],
            [0.0, 0.5, 0.1],
            [0.4, -0.3, 0.9],
            [-0.2, 0.1, -0.4],
            [0.3, 0.8, 0.2],
        ];
        let rotation = *nalgebra::Rotation3::from_euler_angles(0.3, -0.7, 1.1).matrix();
        let shift = Vector3::new(2.0, -1.0, 0.5);
        let world: Vec<[f32; 3]> = body
            .iter()
            .map(|p| {
                let w = rotation * Vector3::from(*p) + shift;
                [w.x, w.y, w.z]
            })
            .collect();
        let (scale, anchors) = (0.5f32, [0usize, 2, 4]);
        let c = Vector3::from(centroid_of(&world));
        let rel = |i: usize| (Vector3::from(world[i]) - c) / scale;
        let anchor_rel: Vec<f32> = anchors
            .iter()
            .flat_map(|&a| rel(a).iter().copied().collect::<Vec<_>>())
            .collect();
        let inertia_inv = floored_inertia_inverse(&body, centroid_of(&body));
        let (levers, spin) =
            wrench_geometry(&world, c, &anchor_rel, &inertia_inv, &rotation, 1.0 / scale);
        assert_eq!((levers.len(), spin.len()), (5 * 9, 3 * 9));
        let f = Vector3::new(0.3, -1.2, 0.7);
        for i in 0..5 {
            let got = apply(&levers[i * 9..(i + 1) * 9], f);
            assert!((got - rel(i).cross(&f)).norm() < 1e-5, "point {i}");
        }
        // alpha from J alpha = tau, J the floored inertia of the world cloud in scaled units.
        let mut j = Matrix3::zeros();
        for i in 0..5 {
            let r = rel(i);
            j += Matrix3::identity() * r.norm_squared() - r * r.transpose();
        }
        j /= 5.0;
        j += Matrix3::identity() * (INERTIA_FLOOR * j.trace() / 3.0);
        let tau = Vector3::new(0.5, 0.1, -0.8);
        let alpha = j.try_inverse().unwrap() * tau;
        for (k, &a) in anchors.iter().enumerate() {
            let got = apply(&spin[k * 9..(k + 1) * 9], tau);
            let want = alpha.cross(&rel(a));
            assert!(
                (got - want).norm() < 1e-4 * want.norm().max(1.0),
                "anchor {k}"
            );
        }
    }

    /// A uniform force has no moment about the centroid, and a one-point cloud has no spin.
    #[test]
    fn uniform_forces_do_not_turn_and_a_point_does_not_spin() {
        let world = [
            [0.1f32, 0.0, 0.0],
            [0.0, 0.3, 0.0],
            [0.0, 0.0, 0.2],
            [0.4, 0.4, 0.4],
        ];
        let c = Vector3::from(centroid_of(&world));
        let eye = Matrix3::identity();
        let (levers, _) = wrench_geometry(&world, c, &[], &eye, &eye, 1.0);
        let f = Vector3::new(1.0, 2.0, 3.0);
        let total: Vector3<f32> = levers.chunks(9).map(|m| apply(m, f)).sum();
        assert!(total.norm() < 1e-5, "{total:?}");
        let point = [[1.0f32, 2.0, 3.0]];
        assert_eq!(floored_inertia_inverse(&point, point[0]), Matrix3::zeros());
    }
}
