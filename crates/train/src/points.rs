//! Plain point-cloud PLY files (`x y z` plus optional colour), as named by a
//! nerfstudio `transforms.json` (`ply_file_path`) or written by COLMAP / Open3D.
//!
//! `transsplat_scene::ply` reads 3DGS scenes and requires the Gaussian properties; this
//! reader takes the same file's vertex table ([`VertexTable`]: one header parser for
//! every PLY, `ascii` and both binary orders, any scalar type, elements before `vertex`
//! skipped, allocation bounded by the file size) and keeps the plain case: colour from
//! `red green blue` (integer types scaled by their maximum, floats taken as they are)
//! or, for a 3DGS file, from `f_dc_0..2` (`0.5 + C0 · f_dc`); grey when there is none.
//! Points with NaN or infinite coordinates are dropped; nothing panics on bad input.

use std::path::Path;
use transsplat_scene::ply::{Scalar, VertexTable};
use transsplat_scene::{atomic, Error, Result, SH_C0};

/// Points with colours in [0, 1].
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PointCloud {
    pub positions: Vec<[f32; 3]>,
    pub colors: Vec<[f32; 3]>,
}

impl PointCloud {
    /// Number of points.
    pub fn len(&self) -> usize {
        self.positions.len()
    }
    /// True when there are no points.
    pub fn is_empty(&self) -> bool {
        self.positions.is_empty()
    }
}

/// Scale that maps an integer type's range to [0, 1] for colours (floats as they are).
fn colour_scale(t: Scalar) -> f32 {
    match t {
        Scalar::U8 => 1.0 / 255.0,
        Scalar::U16 => 1.0 / 65535.0,
        Scalar::I8 => 1.0 / 127.0,
        Scalar::I16 => 1.0 / 32767.0,
        _ => 1.0,
    }
}

/// Reads a point-cloud PLY file.
pub fn read(path: &Path) -> Result<PointCloud> {
    let bytes = atomic::read(path)?;
    parse(&bytes, path)
}

/// Parses point-cloud PLY bytes (`path` is used in messages only), through the scene
/// reader's header parser and vertex table ([`VertexTable`]).
pub fn parse(bytes: &[u8], path: &Path) -> Result<PointCloud> {
    let err = |m: &str| Error::format(path, m);
    let table = VertexTable::parse(bytes, path)?;
    if table.columns.iter().any(|c| c.1.is_none()) {
        return Err(err("vertex element has list properties, which a point cloud does not use"));
    }
    let [Some(x), Some(y), Some(z)] = [table.column(&["x"]), table.column(&["y"]), table.column(&["z"])]
    else {
        return Err(err("vertex element lacks x, y or z"));
    };
    let rgb = [
        table.column(&["red", "r", "diffuse_red"]),
        table.column(&["green", "g", "diffuse_green"]),
        table.column(&["blue", "b", "diffuse_blue"]),
    ];
    let dc = [table.column(&["f_dc_0"]), table.column(&["f_dc_1"]), table.column(&["f_dc_2"])];
    let colour = |row: &[f32]| -> [f32; 3] {
        if let [Some(r), Some(g), Some(b)] = rgb {
            [r, g, b].map(|(k, t)| (row[k] * colour_scale(t)).clamp(0.0, 1.0))
        } else if let [Some(r), Some(g), Some(b)] = dc {
            [r, g, b].map(|(k, _)| (0.5 + SH_C0 * row[k]).clamp(0.0, 1.0))
        } else {
            [0.5; 3]
        }
    };
    let mut cloud = PointCloud::default();
    let mut dropped = 0usize;
    for i in 0..table.rows() {
        let row = table.row(i);
        let p = [row[x.0], row[y.0], row[z.0]];
        if p.iter().all(|c| c.is_finite()) {
            cloud.positions.push(p);
            cloud.colors.push(colour(row));
        } else {
            dropped += 1;
        }
    }
    if dropped > 0 {
        tracing::warn!("{}: dropped {dropped} points with NaN or infinite coordinates", path.display());
    }
    Ok(cloud)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ascii_and_binary_points_with_colours() {
        let p = Path::new("pts.ply");
        let ascii =
            b"ply\nformat ascii 1.0\ncomment x\nelement vertex 2\nproperty float x\nproperty float y\n\
property float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n\
1 2 3 255 0 51\n4 5 6 0 255 0\n";
        let c = parse(ascii, p).unwrap();
        assert_eq!(c.positions, vec![[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]);
        assert!((c.colors[0][2] - 0.2).abs() < 1e-6);
        let mut bin = b"ply\nformat binary_big_endian 1.0\nelement vertex 1\nproperty double x\n\
property double y\nproperty double z\nproperty float f_dc_0\nproperty float f_dc_1\nproperty float f_dc_2\nend_header\n"
            .to_vec();
        for v in [1.5f64, -2.0, 0.25] {
            bin.extend_from_slice(&v.to_be_bytes());
        }
        for v in [0.0f32, 1.0, -1.0] {
            bin.extend_from_slice(&v.to_be_bytes());
        }
        let c = parse(&bin, p).unwrap();
        assert_eq!(c.positions, vec![[1.5, -2.0, 0.25]]);
        assert!((c.colors[0][1] - (0.5 + SH_C0)).abs() < 1e-6 && c.colors[0][0] == 0.5);
    }

    #[test]
    fn bad_files_are_errors_naming_the_file() {
        let p = Path::new("bad.ply");
        for bytes in [
            &b"hello"[..],
            b"ply\nformat binary_little_endian 1.0\nelement vertex 1000000000\nproperty float x\nproperty float y\nproperty float z\nend_header\n\x00\x00",
            b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n",
            b"ply\nformat ascii 1.0\nelement face 1\nproperty float x\nend_header\n1\n",
            b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n1\n",
        ] {
            let e = parse(bytes, p).unwrap_err().to_string();
            assert!(e.starts_with("bad.ply: "), "{e}");
        }
        let empty = b"ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\nend_header\n";
        assert!(parse(empty, p).unwrap().is_empty());
    }
}
