//! Convex hull of a point set (3D quickhull in `f64`).

use std::collections::HashMap;

use super::TriMesh;
use super::vec3::{cross, dot, norm, sub, to64};
use crate::{GeometryError, Point};

/// Convex hull of a point set (metres) as a closed, outward-oriented triangle mesh whose
/// vertices are a subset of the input (3D quickhull in `f64`). Points within a relative
/// tolerance of a hull face are treated as lying on it, so coplanar faces come out triangulated
/// and interior or coplanar points are dropped. Errors on fewer than four points, non-finite
/// coordinates, or a flat (coplanar, collinear or coincident) set.
pub fn convex_hull(points: &[Point]) -> Result<TriMesh, GeometryError> {
    if points.len() < 4 {
        return Err(GeometryError::Invalid(format!(
            "convex hull needs at least 4 points, got {}",
            points.len()
        )));
    }
    if points.iter().flatten().any(|c| !c.is_finite()) {
        return Err(GeometryError::NonFinite("convex hull points"));
    }
    Quickhull::new(points)?.run()
}

struct HullFace {
    v: [u32; 3],
    normal: [f64; 3],
    offset: f64,
    outside: Vec<u32>,
    alive: bool,
}

struct Quickhull {
    pts: Vec<[f64; 3]>,
    faces: Vec<HullFace>,
    edges: HashMap<(u32, u32), usize>,
    eps: f64,
}

impl Quickhull {
    fn new(points: &[Point]) -> Result<Self, GeometryError> {
        let pts: Vec<[f64; 3]> = points.iter().map(|&p| to64(p)).collect();
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        let mut extent = 0.0f64;
        for p in &pts {
            for k in 0..3 {
                lo[k] = lo[k].min(p[k]);
                hi[k] = hi[k].max(p[k]);
                extent = extent.max(p[k].abs());
            }
        }
        let diag = norm(sub(hi, lo));
        // Points closer than this to a face plane count as on it.
        let eps = 1e-9 * extent.max(diag).max(1e-30) * 3.0;
        if diag <= eps {
            return Err(GeometryError::Invalid(
                "convex hull of coincident points".into(),
            ));
        }
        Ok(Self {
            pts,
            faces: Vec::new(),
            edges: HashMap::new(),
            eps,
        })
    }

    fn plane(&self, v: [u32; 3]) -> ([f64; 3], f64) {
        let [a, b, c] = v.map(|i| self.pts[i as usize]);
        let n = cross(sub(b, a), sub(c, a));
        let l = norm(n);
        let n = if l > 0.0 {
            [n[0] / l, n[1] / l, n[2] / l]
        } else {
            [0.0; 3]
        };
        (n, dot(n, a))
    }

    fn dist(&self, f: usize, p: u32) -> f64 {
        let face = &self.faces[f];
        dot(face.normal, self.pts[p as usize]) - face.offset
    }

    fn add_face(&mut self, v: [u32; 3]) -> usize {
        let (normal, offset) = self.plane(v);
        let id = self.faces.len();
        self.faces.push(HullFace {
            v,
            normal,
            offset,
            outside: Vec::new(),
            alive: true,
        });
        for k in 0..3 {
            self.edges.insert((v[k], v[(k + 1) % 3]), id);
        }
        id
    }

    fn initial_simplex(&self) -> Result<[u32; 4], GeometryError> {
        let n = self.pts.len() as u32;
        // Extreme points along the axes; the farthest pair among them starts the simplex.
        let mut extremes = Vec::with_capacity(6);
        for k in 0..3 {
            let (mut imin, mut imax) = (0u32, 0u32);
            for i in 0..n {
                if self.pts[i as usize][k] < self.pts[imin as usize][k] {
                    imin = i;
                }
                if self.pts[i as usize][k] > self.pts[imax as usize][k] {
                    imax = i;
                }
            }
            extremes.push(imin);
            extremes.push(imax);
        }
        let (mut a, mut b, mut best) = (0u32, 0u32, -1.0f64);
        for &i in &extremes {
            for &j in &extremes {
                let d = norm(sub(self.pts[i as usize], self.pts[j as usize]));
                if d > best {
                    (a, b, best) = (i, j, d);
                }
            }
        }
        let pa = self.pts[a as usize];
        let ab = sub(self.pts[b as usize], pa);
        let lab = norm(ab);
        let (mut c, mut best) = (0u32, -1.0f64);
        for i in 0..n {
            let d = norm(cross(ab, sub(self.pts[i as usize], pa))) / lab;
            if d > best {
                (c, best) = (i, d);
            }
        }
        if best <= self.eps {
            return Err(GeometryError::Invalid(
                "convex hull of collinear points".into(),
            ));
        }
        let nrm = cross(ab, sub(self.pts[c as usize], pa));
        let lnrm = norm(nrm);
        let (mut d, mut best) = (0u32, -1.0f64);
        for i in 0..n {
            let h = (dot(nrm, sub(self.pts[i as usize], pa)) / lnrm).abs();
            if h > best {
                (d, best) = (i, h);
            }
        }
        if best <= self.eps {
            return Err(GeometryError::Invalid(
                "convex hull of coplanar points".into(),
            ));
        }
        Ok([a, b, c, d])
    }

    fn run(mut self) -> Result<TriMesh, GeometryError> {
        let [a, b, c, d] = self.initial_simplex()?;
        // Orient the base so the fourth point lies behind it.
        let (normal, offset) = self.plane([a, b, c]);
        let (a, b) = if dot(normal, self.pts[d as usize]) - offset > 0.0 {
            (b, a)
        } else {
            (a, b)
        };
        let initial = [
            self.add_face([a, b, c]),
            self.add_face([a, d, b]),
            self.add_face([b, d, c]),
            self.add_face([c, d, a]),
        ];
        let simplex = [a, b, c, d];
        for p in 0..self.pts.len() as u32 {
            if simplex.contains(&p) {
                continue;
            }
            if let Some(&f) = initial.iter().find(|&&f| self.dist(f, p) > self.eps) {
                self.faces[f].outside.push(p);
            }
        }
        let mut cursor = 0usize;
        loop {
            while cursor < self.faces.len()
                && (!self.faces[cursor].alive || self.faces[cursor].outside.is_empty())
            {
                cursor += 1;
            }
            if cursor >= self.faces.len() {
                break;
            }
            let start = cursor;
            let eye = *self.faces[start]
                .outside
                .iter()
                .max_by(|&&p, &&q| self.dist(start, p).total_cmp(&self.dist(start, q)))
                .ok_or(GeometryError::Numerical("empty outside set"))?;
            // Faces visible from the eye, by flood fill from the starting face.
            let mut visible = vec![start];
            let mut is_visible: HashMap<usize, bool> = HashMap::from([(start, true)]);
            let mut i = 0;
            while i < visible.len() {
                let f = visible[i];
                i += 1;
                let v = self.faces[f].v;
                for k in 0..3 {
                    let Some(&g) = self.edges.get(&(v[(k + 1) % 3], v[k])) else {
                        return Err(GeometryError::Numerical("convex hull lost an edge"));
                    };
                    if let std::collections::hash_map::Entry::Vacant(e) = is_visible.entry(g) {
                        let vis = self.dist(g, eye) > self.eps;
                        e.insert(vis);
                        if vis {
                            visible.push(g);
                        }
                    }
                }
            }
            // Horizon: edges of visible faces whose neighbour is not visible.
            let mut horizon = Vec::new();
            for &f in &visible {
                let v = self.faces[f].v;
                for k in 0..3 {
                    let (p, q) = (v[k], v[(k + 1) % 3]);
                    let g = self.edges[&(q, p)];
                    if !is_visible[&g] {
                        horizon.push((p, q));
                    }
                }
            }
            let mut orphans = Vec::new();
            for &f in &visible {
                self.faces[f].alive = false;
                orphans.append(&mut self.faces[f].outside);
                let v = self.faces[f].v;
                for k in 0..3 {
                    let key = (v[k], v[(k + 1) % 3]);
                    if self.edges.get(&key) == Some(&f) {
                        self.edges.remove(&key);
                    }
                }
            }
            let new_faces: Vec<usize> = horizon
                .iter()
                .map(|&(p, q)| self.add_face([p, q, eye]))
                .collect();
            for p in orphans {
                if p == eye {
                    continue;
                }
                if let Some(&f) = new_faces.iter().find(|&&f| self.dist(f, p) > self.eps) {
                    self.faces[f].outside.push(p);
                }
            }
            cursor = 0;
        }
        // Keep the vertices used by live faces, in input order.
        let mut remap = vec![u32::MAX; self.pts.len()];
        let live: Vec<[u32; 3]> = self.faces.iter().filter(|f| f.alive).map(|f| f.v).collect();
        for f in &live {
            for &i in f {
                remap[i as usize] = 0;
            }
        }
        let mut vertices = Vec::new();
        for (i, r) in remap.iter_mut().enumerate() {
            if *r == 0 {
                *r = vertices.len() as u32;
                let p = self.pts[i];
                vertices.push([p[0] as f32, p[1] as f32, p[2] as f32]);
            }
        }
        let faces = live.iter().map(|f| f.map(|i| remap[i as usize])).collect();
        Ok(TriMesh { vertices, faces })
    }
}
