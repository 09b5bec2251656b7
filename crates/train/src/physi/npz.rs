//! NumPy arrays as the official PhysiFormer data stores them: `.npy` files and `.npz` archives
//! (zip members stored or deflated, as `np.savez` and `np.savez_compressed` write them).
//! Numeric little-endian arrays in C order (`<f4`, `<f8`, `<i4`, `<i8`, `|u1`, `|b1`); other
//! members of an archive (strings) are left unread.

use std::collections::HashMap;
use std::io::Read;
use std::path::Path;

use anyhow::{Context, bail, ensure};

/// A numeric array: its values (converted to f64) and its shape (empty for a scalar).
#[derive(Clone, Debug, PartialEq)]
pub struct Array {
    /// Values in C order.
    pub values: Vec<f64>,
    /// Dimensions.
    pub shape: Vec<usize>,
}

impl Array {
    /// The values as f32.
    pub fn f32s(&self) -> Vec<f32> {
        self.values.iter().map(|&x| x as f32).collect()
    }
}

/// Parses the bytes of a `.npy` file; `what` names it in errors.
pub fn parse_npy(b: &[u8], what: &str) -> anyhow::Result<Array> {
    ensure!(
        b.len() > 10 && &b[..6] == b"\x93NUMPY",
        "{what} is not a .npy array"
    );
    let (hlen, start) = if b[6] == 1 {
        (u16::from_le_bytes([b[8], b[9]]) as usize, 10)
    } else {
        ensure!(b.len() > 12, "{what}: truncated header");
        (u32::from_le_bytes([b[8], b[9], b[10], b[11]]) as usize, 12)
    };
    ensure!(b.len() >= start + hlen, "{what}: truncated header");
    let header = std::str::from_utf8(&b[start..start + hlen])
        .with_context(|| format!("{what}: header is not text"))?;
    ensure!(
        !header.contains("'fortran_order': True"),
        "{what}: Fortran order is not supported"
    );
    let descr = header
        .split("'descr':")
        .nth(1)
        .and_then(|s| s.split('\'').nth(1))
        .with_context(|| format!("{what}: no dtype in the header"))?;
    let shape: Vec<usize> = header
        .split("'shape':")
        .nth(1)
        .and_then(|s| s.split(['(', ')']).nth(1))
        .map(|s| s.split(',').filter_map(|x| x.trim().parse().ok()).collect())
        .with_context(|| format!("{what}: no shape in the header"))?;
    let data = &b[start + hlen..];
    let n: usize = shape.iter().product();
    let size = match descr {
        "<f4" | "<i4" => 4,
        "<f8" | "<i8" => 8,
        "|u1" | "|b1" => 1,
        other => bail!("{what}: dtype {other} is not supported (float, int or byte arrays)"),
    };
    ensure!(
        data.len() >= n * size,
        "{what}: {} bytes of data for {n} values of {size} bytes",
        data.len()
    );
    let data = &data[..n * size];
    let values = match descr {
        "<f4" => data
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")) as f64)
            .collect(),
        "<i4" => data
            .chunks_exact(4)
            .map(|c| i32::from_le_bytes(c.try_into().expect("4 bytes")) as f64)
            .collect(),
        "<f8" => data
            .chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes")))
            .collect(),
        "<i8" => data
            .chunks_exact(8)
            .map(|c| i64::from_le_bytes(c.try_into().expect("8 bytes")) as f64)
            .collect(),
        _ => data.iter().map(|&x| x as f64).collect(),
    };
    Ok(Array { values, shape })
}

/// Reads a `.npy` file.
pub fn read_npy(path: &Path) -> anyhow::Result<Array> {
    let b = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    parse_npy(&b, &path.display().to_string())
}

/// The members of an `.npz` archive, by name without `.npy`.
pub fn npz_members(path: &Path) -> anyhow::Result<Vec<String>> {
    let file =
        std::fs::File::open(path).with_context(|| format!("cannot read {}", path.display()))?;
    let zip = zip::ZipArchive::new(file)
        .with_context(|| format!("{} is not an .npz archive", path.display()))?;
    Ok(zip
        .file_names_raw()
        .map(|n| {
            let n = String::from_utf8_lossy(n);
            n.strip_suffix(".npy").unwrap_or(&n).to_string()
        })
        .collect())
}

/// Reads the members `names` of an `.npz` archive; a name the archive lacks is absent from
/// the map (the caller says which are required).
pub fn read_npz(path: &Path, names: &[&str]) -> anyhow::Result<HashMap<String, Array>> {
    let file =
        std::fs::File::open(path).with_context(|| format!("cannot read {}", path.display()))?;
    let mut zip = zip::ZipArchive::new(file)
        .with_context(|| format!("{} is not an .npz archive", path.display()))?;
    let mut out = HashMap::new();
    for &name in names {
        let member = format!("{name}.npy");
        let Some(i) = zip.index_for_name(&member) else {
            continue;
        };
        let mut f = zip.by_index_raw(i)?;
        let method = f.compression();
        let mut raw = Vec::with_capacity(f.compressed_size() as usize);
        f.read_to_end(&mut raw)?;
        let what = format!("{}:{member}", path.display());
        let bytes = if method == zip::CompressionMethod::Stored {
            raw
        } else if method == zip::CompressionMethod::DEFLATE {
            miniz_oxide::inflate::decompress_to_vec(&raw)
                .map_err(|e| anyhow::anyhow!("{what}: cannot inflate: {e:?}"))?
        } else {
            bail!("{what}: compression {method:?} is not supported (stored or deflated)")
        };
        out.insert(name.to_string(), parse_npy(&bytes, &what)?);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A version-1 `.npy` of `descr` and `shape` holding `data`.
    fn npy(descr: &str, shape: &str, data: &[u8]) -> Vec<u8> {
        let mut h = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape}, }}");
        while !(10 + h.len() + 1).is_multiple_of(64) {
            h.push(' ');
        }
        h.push('\n');
        let mut b = b"\x93NUMPY\x01\x00".to_vec();
        b.extend((h.len() as u16).to_le_bytes());
        b.extend(h.as_bytes());
        b.extend(data);
        b
    }

    #[test]
    fn npy_dtypes_and_shapes() {
        let f: Vec<u8> = [1f32, -2.5].iter().flat_map(|x| x.to_le_bytes()).collect();
        let a = parse_npy(&npy("<f4", "(2,)", &f), "a").unwrap();
        assert_eq!(
            a,
            Array {
                values: vec![1.0, -2.5],
                shape: vec![2]
            }
        );
        let i: Vec<u8> = [3i64].iter().flat_map(|x| x.to_le_bytes()).collect();
        let s = parse_npy(&npy("<i8", "()", &i), "s").unwrap();
        assert_eq!(
            s,
            Array {
                values: vec![3.0],
                shape: vec![]
            }
        );
        let m = parse_npy(&npy("|u1", "(1, 3)", &[1, 0, 1]), "m").unwrap();
        assert_eq!(m.shape, [1, 3]);
        let err = parse_npy(&npy("<U5", "(1,)", &[0; 20]), "u").unwrap_err();
        assert!(err.to_string().contains("<U5"), "{err}");
        let err = parse_npy(&npy("<f4", "(3,)", &f), "short").unwrap_err();
        assert!(err.to_string().contains("bytes of data"), "{err}");
    }
}
