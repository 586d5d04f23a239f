//! Plain point-cloud PLY files (`x y z` plus optional colour), as named by a
//! nerfstudio `transforms.json` (`ply_file_path`) or written by COLMAP / Open3D.
//!
//! `transsplat_scene::ply` reads 3DGS scenes and requires the Gaussian properties, so
//! this small reader covers the plain case: `ascii`, `binary_little_endian` and
//! `binary_big_endian`; any scalar type; colour from `red green blue` (integer
//! types scaled by their maximum, floats taken as they are) or, for a 3DGS file,
//! from `f_dc_0..2` (`0.5 + C0 · f_dc`); grey when there is none. Elements before
//! `vertex` are skipped (binary: only when they have no list properties). Points
//! with NaN or infinite coordinates are dropped. Allocation is bounded by the file
//! size whatever the header claims; nothing panics on bad input.

use std::path::Path;
use transsplat_scene::ply::Scalar;
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

#[derive(Clone, Debug)]
struct Element {
    name: String,
    count: usize,
    props: Vec<(String, Scalar)>,
    has_list: bool,
}

/// Reads a point-cloud PLY file.
pub fn read(path: &Path) -> Result<PointCloud> {
    let bytes = atomic::read(path)?;
    parse(&bytes, path)
}

/// Parses point-cloud PLY bytes (`path` is used in messages only).
pub fn parse(bytes: &[u8], path: &Path) -> Result<PointCloud> {
    let err = |m: String| Error::format(path, m);
    let end = find(bytes, b"end_header").ok_or_else(|| err("not a PLY file: no end_header".into()))?;
    let mut body = end + b"end_header".len();
    if bytes.get(body) == Some(&b'\r') {
        body += 1;
    }
    if bytes.get(body) != Some(&b'\n') {
        return Err(err("not a PLY file: end_header is not followed by a newline".into()));
    }
    body += 1;
    let header = std::str::from_utf8(&bytes[..end]).map_err(|_| err("PLY header is not text".into()))?;
    let mut lines = header.lines().map(str::trim);
    if lines.next() != Some("ply") {
        return Err(err("not a PLY file: missing the \"ply\" magic".into()));
    }
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    for line in lines {
        let t: Vec<&str> = line.split_whitespace().collect();
        match t.as_slice() {
            [] | ["comment", ..] | ["obj_info", ..] => {}
            ["format", f, _] => format = Some(f.to_string()),
            ["element", name, count] => {
                let count =
                    count.parse::<usize>().map_err(|_| err(format!("bad element count {count:?}")))?;
                elements.push(Element { name: name.to_string(), count, props: Vec::new(), has_list: false });
            }
            ["property", "list", ..] => {
                let e = elements.last_mut().ok_or_else(|| err("property before any element".into()))?;
                e.has_list = true;
            }
            ["property", ty, name] => {
                let e = elements.last_mut().ok_or_else(|| err("property before any element".into()))?;
                let ty = Scalar::parse(ty).ok_or_else(|| err(format!("unknown property type {ty:?}")))?;
                e.props.push((name.to_string(), ty));
            }
            _ => return Err(err(format!("unrecognised PLY header line {line:?}"))),
        }
    }
    let format = format.ok_or_else(|| err("PLY header has no format line".into()))?;
    let vi = elements
        .iter()
        .position(|e| e.name == "vertex")
        .ok_or_else(|| err("PLY file has no vertex element".into()))?;
    let v = &elements[vi];
    if v.has_list {
        return Err(err("vertex element has list properties, which a point cloud does not use".into()));
    }
    let find_prop = |names: &[&str]| -> Option<(usize, Scalar)> {
        names.iter().find_map(|n| v.props.iter().position(|p| p.0 == *n).map(|k| (k, v.props[k].1)))
    };
    let xyz = [find_prop(&["x"]), find_prop(&["y"]), find_prop(&["z"])];
    let [Some(x), Some(y), Some(z)] = xyz else {
        return Err(err("vertex element lacks x, y or z".into()));
    };
    let rgb = [
        find_prop(&["red", "r", "diffuse_red"]),
        find_prop(&["green", "g", "diffuse_green"]),
        find_prop(&["blue", "b", "diffuse_blue"]),
    ];
    let dc = [find_prop(&["f_dc_0"]), find_prop(&["f_dc_1"]), find_prop(&["f_dc_2"])];
    let colour = |row: &dyn Fn(usize) -> f64| -> [f32; 3] {
        if let [Some(r), Some(g), Some(b)] = rgb {
            [r, g, b].map(|(k, t)| (row(k) as f32 * colour_scale(t)).clamp(0.0, 1.0))
        } else if let [Some(r), Some(g), Some(b)] = dc {
            [r, g, b].map(|(k, _)| (0.5 + SH_C0 * row(k) as f32).clamp(0.0, 1.0))
        } else {
            [0.5; 3]
        }
    };
    let mut cloud = PointCloud::default();
    let mut dropped = 0usize;
    let mut push = |row: &dyn Fn(usize) -> f64, cloud: &mut PointCloud| {
        let p = [row(x.0) as f32, row(y.0) as f32, row(z.0) as f32];
        if p.iter().all(|c| c.is_finite()) {
            cloud.positions.push(p);
            cloud.colors.push(colour(row));
        } else {
            dropped += 1;
        }
    };
    match format.as_str() {
        "ascii" => {
            let text =
                std::str::from_utf8(&bytes[body..]).map_err(|_| err("ASCII PLY body is not text".into()))?;
            let mut rows = text.lines().filter(|l| !l.trim().is_empty());
            for e in &elements[..vi] {
                for _ in 0..e.count {
                    rows.next().ok_or_else(|| err(format!("file ends inside element {:?}", e.name)))?;
                }
            }
            for i in 0..v.count {
                let line =
                    rows.next().ok_or_else(|| err(format!("file ends at vertex {i} of {}", v.count)))?;
                let vals: Vec<f64> = line
                    .split_whitespace()
                    .map(|s| s.parse::<f64>())
                    .collect::<std::result::Result<_, _>>()
                    .map_err(|_| err(format!("vertex {i}: not a number in {line:?}")))?;
                if vals.len() != v.props.len() {
                    return Err(err(format!(
                        "vertex {i} has {} values, expected {}",
                        vals.len(),
                        v.props.len()
                    )));
                }
                push(&|k| vals[k], &mut cloud);
            }
        }
        "binary_little_endian" | "binary_big_endian" => {
            let big = format == "binary_big_endian";
            let mut off = body;
            for e in &elements[..vi] {
                if e.has_list {
                    return Err(err(format!(
                        "element {:?} before the vertices has list properties; cannot skip it",
                        e.name
                    )));
                }
                let row: usize = e.props.iter().map(|p| p.1.size()).sum();
                off = e.count.checked_mul(row).and_then(|s| off.checked_add(s)).unwrap_or(usize::MAX);
            }
            let offsets: Vec<usize> = v
                .props
                .iter()
                .scan(0usize, |acc, p| {
                    let o = *acc;
                    *acc += p.1.size();
                    Some(o)
                })
                .collect();
            let row: usize = v.props.iter().map(|p| p.1.size()).sum();
            let need = v.count.checked_mul(row).and_then(|s| s.checked_add(off));
            if need.is_none_or(|n| n > bytes.len()) {
                return Err(err(format!("file is truncated: the header promises {} vertices", v.count)));
            }
            cloud.positions.reserve(v.count);
            cloud.colors.reserve(v.count);
            for i in 0..v.count {
                let r = &bytes[off + i * row..off + (i + 1) * row];
                push(&|k| v.props[k].1.decode(&r[offsets[k]..], big) as f64, &mut cloud);
            }
        }
        f => return Err(err(format!("unknown PLY format {f:?}"))),
    }
    if dropped > 0 {
        tracing::warn!("{}: dropped {dropped} points with NaN or infinite coordinates", path.display());
    }
    Ok(cloud)
}

fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).take(1 << 16).position(|w| w == needle)
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
