//! A mesh scene's condition (initial positions, velocities, objects, materials) and its
//! validation.

use serde::{Deserialize, Serialize};

use super::config::{ELASTIC_MATERIAL, PhysiConfig, RIGID_MATERIAL};
use crate::ModelError;

/// How an object deforms.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Material {
    /// Keeps its shape.
    Rigid,
    /// Deforms elastically (one fixed Young's modulus, as in the training data).
    Elastic,
}

impl Material {
    /// The material code of the data format (0 rigid, 1 elastic).
    pub fn from_code(code: i64) -> Result<Material, ModelError> {
        match code {
            0 => Ok(Material::Rigid),
            1 => Ok(Material::Elastic),
            other => Err(ModelError::InvalidInput(format!(
                "material code {other} is neither 0 (rigid) nor 1 (elastic)"
            ))),
        }
    }

    /// The network's material input `(softness, friction)`.
    pub fn features(self) -> [f32; 2] {
        match self {
            Material::Rigid => RIGID_MATERIAL,
            Material::Elastic => ELASTIC_MATERIAL,
        }
    }
}

/// The condition of one mesh scene: every vertex's position and velocity at frame 0, which
/// object each vertex belongs to, and each object's material. Positions in metres, velocities
/// in m/s, world coordinates of the model's box.
#[derive(Clone, Debug, PartialEq)]
pub struct MeshScene {
    /// Vertex positions at frame 0, `[V]` of xyz, metres.
    pub positions: Vec<[f32; 3]>,
    /// Vertex velocities at frame 0, `[V]` of xyz, m/s.
    pub velocities: Vec<[f32; 3]>,
    /// Object `o` owns vertices `vertex_offsets[o]..vertex_offsets[o + 1]`; `[O + 1]`, starting
    /// at 0 and ending at V.
    pub vertex_offsets: Vec<usize>,
    /// Material of each object, `[O]`.
    pub materials: Vec<Material>,
}

/// Largest accepted speed of a vertex at frame 0, m/s.
pub const MAX_SPEED: f32 = 50.0;

impl MeshScene {
    /// Number of vertices V.
    pub fn vertices(&self) -> usize {
        self.positions.len()
    }

    /// Number of objects O.
    pub fn objects(&self) -> usize {
        self.materials.len()
    }

    /// Object index of every vertex, `[V]`.
    pub fn object_of_vertex(&self) -> Vec<u32> {
        let mut out = Vec::with_capacity(self.vertices());
        for o in 0..self.objects() {
            let n = self.vertex_offsets[o + 1] - self.vertex_offsets[o];
            out.extend(std::iter::repeat_n(o as u32, n));
        }
        out
    }

    /// Checks the scene against the model's limits; the error names the field.
    pub fn validate(&self, config: &PhysiConfig) -> Result<(), ModelError> {
        let bad = |m: String| Err(ModelError::InvalidInput(m));
        let v = self.vertices();
        if v == 0 {
            return bad("positions: the scene has no vertices".into());
        }
        if v > config.max_vertices {
            return bad(format!(
                "positions: {v} vertices exceed the model's limit of {}",
                config.max_vertices
            ));
        }
        if self.velocities.len() != v {
            return bad(format!(
                "velocities: {} entries for {v} vertices",
                self.velocities.len()
            ));
        }
        let o = self.objects();
        if o == 0 {
            return bad("materials: the scene has no objects".into());
        }
        if o > config.max_objects {
            return bad(format!(
                "materials: {o} objects exceed the model's limit of {}",
                config.max_objects
            ));
        }
        if self.vertex_offsets.len() != o + 1 {
            return bad(format!(
                "vertex_offsets: {} entries for {o} objects (expected {})",
                self.vertex_offsets.len(),
                o + 1
            ));
        }
        if self.vertex_offsets[0] != 0 || self.vertex_offsets[o] != v {
            return bad(format!("vertex_offsets must start at 0 and end at {v}"));
        }
        for i in 0..o {
            if self.vertex_offsets[i + 1] <= self.vertex_offsets[i] {
                return bad(format!("vertex_offsets: object {i} has no vertices"));
            }
        }
        let limit = 2.0 * config.box_half_extent;
        for (i, p) in self.positions.iter().enumerate() {
            if p.iter().any(|c| !c.is_finite() || c.abs() > limit) {
                return bad(format!(
                    "positions[{i}] = {p:?} is not finite or lies outside [-{limit}, {limit}]^3"
                ));
            }
        }
        for (i, u) in self.velocities.iter().enumerate() {
            if u.iter().any(|c| !c.is_finite() || c.abs() > MAX_SPEED) {
                return bad(format!(
                    "velocities[{i}] = {u:?} is not finite or faster than {MAX_SPEED} m/s"
                ));
            }
        }
        Ok(())
    }
}
