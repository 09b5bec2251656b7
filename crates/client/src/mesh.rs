//! Triangle mesh files: Wavefront OBJ and ASCII PLY. Polygons are fan-triangulated; texture
//! and normal data are ignored. Coordinates are taken as metres in the object's body frame.

use std::path::Path;

use dynaserve_api::json::TriangleMesh;

use crate::error::ClientError;

fn err(path: &Path, message: impl Into<String>) -> ClientError {
    ClientError::File {
        path: path.display().to_string(),
        message: message.into(),
    }
}

/// Loads an `.obj` or `.ply` file (by extension) as a mesh with `samples = 0` (the model's
/// default point count) and `seed = 0`.
pub fn load(path: impl AsRef<Path>) -> Result<TriangleMesh, ClientError> {
    let path = path.as_ref();
    let text = std::fs::read_to_string(path).map_err(|e| err(path, e.to_string()))?;
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    let (vertices, faces) = match ext.as_deref() {
        Some("obj") => parse_obj(&text),
        Some("ply") => parse_ply(&text),
        _ => Err("unknown mesh format (expected .obj or .ply)".to_string()),
    }
    .map_err(|m| err(path, m))?;
    Ok(TriangleMesh {
        vertices,
        faces,
        samples: 0,
        seed: 0,
    })
}

type Parsed = Result<(Vec<[f32; 3]>, Vec<[u32; 3]>), String>;

fn fan(poly: &[u32], faces: &mut Vec<[u32; 3]>) {
    for k in 1..poly.len().saturating_sub(1) {
        faces.push([poly[0], poly[k], poly[k + 1]]);
    }
}

fn floats3(parts: &[&str], line: usize) -> Result<[f32; 3], String> {
    if parts.len() < 3 {
        return Err(format!("line {line}: expected three coordinates"));
    }
    let mut v = [0.0f32; 3];
    for (k, p) in parts[..3].iter().enumerate() {
        v[k] = p
            .parse()
            .map_err(|_| format!("line {line}: {p:?} is not a number"))?;
    }
    Ok(v)
}

/// Parses Wavefront OBJ text: `v x y z` and `f a b c ...` lines (1-based or negative indices,
/// `a/b/c` forms accepted).
pub fn parse_obj(text: &str) -> Parsed {
    let mut vertices = Vec::new();
    let mut faces = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let n = i + 1;
        let mut parts = line.split_whitespace();
        match parts.next() {
            Some("v") => {
                let rest: Vec<&str> = parts.collect();
                vertices.push(floats3(&rest, n)?);
            }
            Some("f") => {
                let mut poly = Vec::new();
                for p in parts {
                    let idx = p.split('/').next().unwrap_or("");
                    let k: i64 = idx
                        .parse()
                        .map_err(|_| format!("line {n}: bad face index {p:?}"))?;
                    let nv = vertices.len() as i64;
                    let zero_based = if k > 0 { k - 1 } else { nv + k };
                    if k == 0 || zero_based < 0 || zero_based >= nv {
                        return Err(format!("line {n}: face index {k} is out of range"));
                    }
                    poly.push(zero_based as u32);
                }
                if poly.len() < 3 {
                    return Err(format!("line {n}: a face needs at least three vertices"));
                }
                fan(&poly, &mut faces);
            }
            _ => {}
        }
    }
    if vertices.is_empty() || faces.is_empty() {
        return Err("no vertices or no faces".into());
    }
    Ok((vertices, faces))
}

/// Parses ASCII PLY text with `element vertex` (first three properties x, y, z) and
/// `element face` (a list property of vertex indices). Binary PLY is not supported.
pub fn parse_ply(text: &str) -> Parsed {
    let mut lines = text.lines().enumerate();
    if lines.next().map(|(_, l)| l.trim()) != Some("ply") {
        return Err("not a PLY file".into());
    }
    let mut n_vertices = None;
    let mut n_faces = None;
    let mut vertex_props = 0usize;
    let mut current = "";
    for (i, line) in lines.by_ref() {
        let parts: Vec<&str> = line.split_whitespace().collect();
        match parts.as_slice() {
            ["format", fmt, ..] if *fmt != "ascii" => {
                return Err(format!("line {}: only ASCII PLY is supported", i + 1));
            }
            ["element", "vertex", n] => {
                n_vertices = Some(n.parse::<usize>().map_err(|_| "bad vertex count")?);
                current = "vertex";
            }
            ["element", "face", n] => {
                n_faces = Some(n.parse::<usize>().map_err(|_| "bad face count")?);
                current = "face";
            }
            ["element", ..] => current = "other",
            ["property", ..] if current == "vertex" => vertex_props += 1,
            ["end_header"] => break,
            _ => {}
        }
    }
    let nv = n_vertices.ok_or("no vertex element")?;
    let nf = n_faces.ok_or("no face element")?;
    if vertex_props < 3 {
        return Err("vertices need x, y, z properties".into());
    }
    let mut vertices = Vec::with_capacity(nv);
    let mut faces = Vec::with_capacity(nf);
    for _ in 0..nv {
        let (i, line) = lines.next().ok_or("file ends inside the vertex list")?;
        let parts: Vec<&str> = line.split_whitespace().collect();
        vertices.push(floats3(&parts, i + 1)?);
    }
    for _ in 0..nf {
        let (i, line) = lines.next().ok_or("file ends inside the face list")?;
        let nums: Vec<u32> = line
            .split_whitespace()
            .map(|p| p.parse::<u32>())
            .collect::<Result<_, _>>()
            .map_err(|_| format!("line {}: bad face", i + 1))?;
        let (count, idx) = nums
            .split_first()
            .ok_or_else(|| format!("line {}: empty face", i + 1))?;
        if idx.len() != *count as usize || idx.len() < 3 {
            return Err(format!("line {}: face vertex count mismatch", i + 1));
        }
        if idx.iter().any(|&k| k as usize >= nv) {
            return Err(format!("line {}: face index out of range", i + 1));
        }
        fan(idx, &mut faces);
    }
    Ok((vertices, faces))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn obj_quads_are_fan_triangulated() {
        let text = "# square\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvn 0 0 1\nf 1//1 2//1 3//1 4//1\nf -4 -3 -2\n";
        let (v, f) = parse_obj(text).unwrap();
        assert_eq!(v.len(), 4);
        assert_eq!(f, vec![[0, 1, 2], [0, 2, 3], [0, 1, 2]]);
        assert!(parse_obj("v 0 0 0\nf 1 2 3\n").is_err());
    }

    #[test]
    fn ascii_ply() {
        let text = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
        let (v, f) = parse_ply(text).unwrap();
        assert_eq!(v[1], [1.0, 0.0, 0.0]);
        assert_eq!(f, vec![[0, 1, 2]]);
        assert!(parse_ply(&text.replace("ascii", "binary_little_endian")).is_err());
    }
}
