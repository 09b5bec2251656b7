//! A simulated mesh scene in memory: per-vertex trajectories, faces, and per-object vertex
//! ranges and materials. This is what the writer stores and what the reader returns.

use std::ops::Range;

use serde::{Deserialize, Serialize};

/// How an object deforms.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MeshMaterial {
    /// A rigid body: distances between its vertices never change.
    Rigid,
    /// An elastic (FEM) body with the dataset's Young's modulus and Poisson ratio.
    Elastic,
}

impl MeshMaterial {
    /// The stored code: 0 rigid, 1 elastic.
    pub fn code(self) -> i32 {
        match self {
            MeshMaterial::Rigid => 0,
            MeshMaterial::Elastic => 1,
        }
    }

    /// The material of a stored code, `None` for an unknown code.
    pub fn from_code(code: i32) -> Option<Self> {
        match code {
            0 => Some(MeshMaterial::Rigid),
            1 => Some(MeshMaterial::Elastic),
            _ => None,
        }
    }

    /// `rigid` or `elastic`.
    pub fn name(self) -> &'static str {
        match self {
            MeshMaterial::Rigid => "rigid",
            MeshMaterial::Elastic => "elastic",
        }
    }
}

/// One object of a mesh scene: where its vertices and faces are in the scene's arrays.
#[derive(Clone, Debug, PartialEq)]
pub struct MeshObject {
    /// Rows of the scene's vertices that belong to the object.
    pub vertices: Range<usize>,
    /// Rows of the scene's faces that belong to the object.
    pub faces: Range<usize>,
    /// Rigid or elastic.
    pub material: MeshMaterial,
    /// Index into the manifest's `templates`.
    pub template_id: i32,
    /// Scale of the unit template (its circumradius), metres.
    pub scale: f32,
    /// Mass, kilograms.
    pub mass: f32,
    /// Friction coefficient.
    pub friction: f32,
    /// Restitution coefficient.
    pub restitution: f32,
}

/// One mesh scene: `V` vertices over `T` frames.
#[derive(Clone, Debug, PartialEq)]
pub struct MeshScene {
    /// Frames `T`, including the initial state.
    pub frames: usize,
    /// Interval between frames, seconds.
    pub dt_frame: f32,
    /// Vertex positions, world frame, metres, row-major `[V, T, 3]`.
    pub positions: Vec<f32>,
    /// Vertex velocities at frame 0, metres per second, row-major `[V, 3]`.
    pub initial_velocities: Vec<f32>,
    /// Triangles as indices into the scene's vertices `0..V`, counter-clockwise seen from
    /// outside: `[F]`.
    pub faces: Vec<[u32; 3]>,
    /// The objects, in order; their vertex ranges tile `0..V`.
    pub objects: Vec<MeshObject>,
}

impl MeshScene {
    /// Number of vertices `V`.
    pub fn num_vertices(&self) -> usize {
        self.initial_velocities.len() / 3
    }

    /// Position of vertex `v` at frame `t`, metres.
    pub fn position(&self, v: usize, t: usize) -> [f32; 3] {
        let i = 3 * (v * self.frames + t);
        [
            self.positions[i],
            self.positions[i + 1],
            self.positions[i + 2],
        ]
    }

    /// All vertex positions at frame `t`, metres: `[V]`.
    pub fn frame(&self, t: usize) -> Vec<[f32; 3]> {
        (0..self.num_vertices())
            .map(|v| self.position(v, t))
            .collect()
    }

    /// Velocity of vertex `v` at frame 0, metres per second.
    pub fn initial_velocity(&self, v: usize) -> [f32; 3] {
        let i = 3 * v;
        [
            self.initial_velocities[i],
            self.initial_velocities[i + 1],
            self.initial_velocities[i + 2],
        ]
    }

    /// Material code per vertex (0 rigid, 1 elastic): `[V]`.
    pub fn vertex_materials(&self) -> Vec<i32> {
        let mut m = vec![0; self.num_vertices()];
        for o in &self.objects {
            m[o.vertices.clone()].fill(o.material.code());
        }
        m
    }

    /// Object index per vertex: `[V]`.
    pub fn vertex_objects(&self) -> Vec<u32> {
        let mut m = vec![0; self.num_vertices()];
        for (i, o) in self.objects.iter().enumerate() {
            m[o.vertices.clone()].fill(i as u32);
        }
        m
    }

    /// The faces of object `i` with indices local to its vertex range.
    pub fn object_faces(&self, i: usize) -> Vec<[u32; 3]> {
        let o = &self.objects[i];
        let base = o.vertices.start as u32;
        self.faces[o.faces.clone()]
            .iter()
            .map(|f| f.map(|v| v - base))
            .collect()
    }

    /// Signed volume enclosed by object `i`'s surface at frame `t`, cubic metres.
    pub fn object_volume(&self, i: usize, t: usize) -> f64 {
        let o = &self.objects[i];
        let p = |v: u32| {
            let x = self.position(v as usize, t);
            [x[0] as f64, x[1] as f64, x[2] as f64]
        };
        self.faces[o.faces.clone()]
            .iter()
            .map(|f| {
                let (a, b, c) = (p(f[0]), p(f[1]), p(f[2]));
                (a[0] * (b[1] * c[2] - b[2] * c[1]) - a[1] * (b[0] * c[2] - b[2] * c[0])
                    + a[2] * (b[0] * c[1] - b[1] * c[0]))
                    / 6.0
            })
            .sum()
    }
}
