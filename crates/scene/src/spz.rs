//! Niantic's SPZ scene file (`.spz`), read and written.
//!
//! Versions 2 and 3 are one gzip stream holding a 16-byte header (magic `NGSP`,
//! version, count, SH degree, fractional bits, flags, reserved) and then, Gaussian
//! after Gaussian within each block: positions as 24-bit fixed point, opacities
//! (`sigmoid · 255`), DC colours (`f_dc · 0.15 · 255 + 127.5`), log-scales
//! (`(log σ + 10) · 16`), rotations (v2: x, y, z bytes with w ≥ 0; v3: "smallest three"
//! in 32 bits, 9-bit magnitudes of `|q_i|/√½` with a sign bit each) and the higher SH
//! coefficients (coefficient-major, `round(v · 128) + 128` rounded to 5-bit buckets for
//! degree 1 and 4-bit buckets above). Version 4 (the reference's current default) is
//! an uncompressed 32-byte header, a table of stream sizes and one zstd frame per
//! block; it is read, not written. docs/formats.md#spz has the details.
//!
//! Axes: SPZ stores the RUB convention (x right, y up, z back) and the INRIA PLY RDF
//! (x right, y down, z forward), as Niantic's reference documents; the two differ by a
//! half turn about x, so positions, rotations and the odd SH coefficients change sign
//! on the way in and out ([`flip_rdf_rub`]). Files read back exactly as written, and
//! PlayCanvas splat-transform 2.x reads and writes the same convention.

use crate::{atomic, opacity_logit_of_byte, sigmoid, Error, Gaussians, Result};
use std::io::{Read, Write};
use std::path::Path;

const MAGIC: u32 = 0x5053_474e;
/// The 0.15 colour scale of the reference (DC colour `f_dc · 0.15 + ½`).
const COLOUR_SCALE: f32 = 0.15;
/// The version written.
pub const WRITE_VERSION: u32 = 3;
/// Most Gaussians a file may declare (bounded before allocating).
const MAX_POINTS: u64 = 1 << 28;

/// Sign of each higher SH coefficient (1..=15) under the half turn about x:
/// (x, y, z) → (x, −y, −z) negates the basis functions odd in y + z.
const SH_FLIP: [f32; 15] = [-1., -1., 1., -1., 1., 1., -1., 1., -1., 1., -1., -1., 1., -1., 1.];

/// Converts between the PLY's RDF axes and SPZ's RUB axes (its own inverse).
pub fn flip_rdf_rub(g: &mut Gaussians) {
    for m in &mut g.means {
        m[1] = -m[1];
        m[2] = -m[2];
    }
    for q in &mut g.rotations {
        q[2] = -q[2];
        q[3] = -q[3];
    }
    let k = g.sh_coeffs();
    for sh in g.sh.chunks_exact_mut(k * 3) {
        for j in 1..k {
            for c in 0..3 {
                sh[j * 3 + c] *= SH_FLIP[j - 1];
            }
        }
    }
}

/// Fractional bits for the positions: 12 (the reference's) unless the scene reaches
/// past ±2048, then fewer so every position fits 24 bits.
fn fractional_bits(g: &Gaussians) -> u8 {
    let reach = g.means.iter().flatten().fold(0.0f32, |m, v| m.max(v.abs())) as f64;
    let mut bits = 12u8;
    while bits > 0 && (reach * (1u64 << bits) as f64).round() > ((1 << 23) - 1) as f64 {
        bits -= 1;
    }
    bits
}

fn u8_of(v: f32) -> u8 {
    v.round().clamp(0.0, 255.0) as u8
}

/// An SH coefficient in `bits` bits (bucketed as the reference does).
fn sh_byte(v: f32, bits: u32) -> u8 {
    let bucket = 1i32 << (8 - bits);
    let q = (v * 128.0).round() as i32 + 128;
    let q = (q + bucket / 2) / bucket * bucket;
    q.clamp(0, 255) as u8
}

/// The v3 "smallest three" rotation code of a (w, x, y, z) quaternion.
fn pack_rotation(q: [f32; 4]) -> u32 {
    let n = q.iter().map(|v| v * v).sum::<f32>().sqrt();
    let [w, x, y, z] = if n > 0.0 { q.map(|v| v / n) } else { [1.0, 0.0, 0.0, 0.0] };
    let xyzw = [x, y, z, w];
    let largest = (1..4).fold(0, |l, k| if xyzw[k].abs() > xyzw[l].abs() { k } else { l });
    let negate = xyzw[largest] < 0.0;
    let mut code = largest as u32;
    for (i, v) in xyzw.iter().enumerate() {
        if i != largest {
            let sign = ((*v < 0.0) ^ negate) as u32;
            let mag = (511.0 * v.abs() / std::f32::consts::FRAC_1_SQRT_2 + 0.5).min(511.0) as u32;
            code = (code << 10) | (sign << 9) | mag;
        }
    }
    code
}

fn unpack_rotation(mut code: u32) -> [f32; 4] {
    let largest = (code >> 30) as usize;
    let mut xyzw = [0.0f32; 4];
    let mut sum = 0.0;
    for i in (0..4).rev() {
        if i != largest {
            let mag = (code & 511) as f32;
            let v = std::f32::consts::FRAC_1_SQRT_2 * mag / 511.0;
            xyzw[i] = if code & 512 != 0 { -v } else { v };
            sum += xyzw[i] * xyzw[i];
            code >>= 10;
        }
    }
    xyzw[largest] = (1.0 - sum).max(0.0).sqrt();
    [xyzw[3], xyzw[0], xyzw[1], xyzw[2]]
}

/// The uncompressed version-3 payload of a scene (header and blocks, before gzip).
fn payload(g: &Gaussians) -> Vec<u8> {
    let mut g = g.clone();
    flip_rdf_rub(&mut g);
    let n = g.len();
    let k = g.sh_coeffs();
    let fb = fractional_bits(&g);
    let mut out = Vec::with_capacity(16 + n * (20 + (k - 1) * 3));
    out.extend_from_slice(&MAGIC.to_le_bytes());
    out.extend_from_slice(&WRITE_VERSION.to_le_bytes());
    out.extend_from_slice(&(n as u32).to_le_bytes());
    out.extend_from_slice(&[g.sh_degree as u8, fb, 0, 0]);
    let scale = (1u64 << fb) as f32;
    for m in &g.means {
        for v in m {
            let q = (v * scale).round() as i32;
            out.extend_from_slice(&q.to_le_bytes()[..3]);
        }
    }
    out.extend(g.opacity_logits.iter().map(|&o| u8_of(sigmoid(o) * 255.0)));
    for i in 0..n {
        for c in 0..3 {
            out.push(u8_of(g.sh[i * k * 3 + c] * (COLOUR_SCALE * 255.0) + 0.5 * 255.0));
        }
    }
    for s in &g.log_scales {
        out.extend(s.iter().map(|&v| u8_of((v + 10.0) * 16.0)));
    }
    for q in &g.rotations {
        out.extend_from_slice(&pack_rotation(*q).to_le_bytes());
    }
    for i in 0..n {
        let sh = g.sh_of(i);
        for j in 1..k {
            let bits = if j < 4 { 5 } else { 4 };
            for c in 0..3 {
                out.push(sh_byte(sh[j * 3 + c], bits));
            }
        }
    }
    out
}

/// The `.spz` bytes (version 3, gzip) of a scene. Extra properties are not stored.
/// Assumes `g.validate()` passes.
pub fn to_bytes(g: &Gaussians) -> Vec<u8> {
    let mut enc = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    enc.write_all(&payload(g)).expect("writing to memory");
    enc.finish().expect("writing to memory")
}

/// Writes a scene atomically as `.spz` (refusing NaN or infinite parameters and
/// scenes SPZ cannot hold: no Gaussians, or more than 2³² − 1).
pub fn write(path: &Path, g: &Gaussians) -> Result<()> {
    g.check_writable(path)?;
    if g.is_empty() || g.len() > u32::MAX as usize {
        return Err(Error::format(path, format!("cannot write {} Gaussians as SPZ", g.len())));
    }
    let bytes = to_bytes(g);
    atomic::write_bytes(path, &bytes)
}

/// True when `bytes` start like an SPZ file (gzip, or the version-4 `NGSP` magic).
pub fn looks_like(bytes: &[u8]) -> bool {
    bytes.starts_with(&[0x1f, 0x8b]) || bytes.starts_with(b"NGSP")
}

/// Parses `.spz` bytes (versions 2, 3 and 4); `path` names the file in errors.
pub fn parse(bytes: &[u8], path: &Path) -> Result<Gaussians> {
    decode(bytes).map_err(|m| Error::format(path, format!("SPZ: {m}")))
}

fn decode(bytes: &[u8]) -> std::result::Result<Gaussians, String> {
    if bytes.starts_with(&[0x1f, 0x8b]) {
        // Bounded: a valid payload is at most 16 + 64 bytes a Gaussian.
        let mut raw = Vec::new();
        let limit = 16 + 64 * MAX_POINTS;
        flate2::read::GzDecoder::new(bytes)
            .take(limit + 1)
            .read_to_end(&mut raw)
            .map_err(|e| format!("not a valid gzip stream ({e})"))?;
        if raw.len() as u64 > limit {
            return Err("the decompressed data is larger than any valid file".into());
        }
        let h = Header::parse(&raw)?;
        if !(2..=3).contains(&h.version) {
            return Err(format!("version {} in a gzip stream; expected 2 or 3", h.version));
        }
        let blocks = h.block_sizes();
        let need: u64 = 16 + blocks.iter().sum::<u64>();
        if (raw.len() as u64) < need {
            return Err(format!(
                "truncated: {need} bytes needed for {} Gaussians, {} present",
                h.points,
                raw.len()
            ));
        }
        let mut at = 16usize;
        let parts: Vec<&[u8]> = blocks
            .iter()
            .map(|&s| {
                let p = &raw[at..at + s as usize];
                at += s as usize;
                p
            })
            .collect();
        return Ok(h.gaussians(&parts));
    }
    let h = Header::parse(bytes)?;
    if h.version != 4 {
        return Err(format!("unsupported version {}", h.version));
    }
    decode_v4(bytes, &h)
}

/// A version-4 file: header, table of contents, one zstd frame per non-empty block.
fn decode_v4(bytes: &[u8], h: &Header) -> std::result::Result<Gaussians, String> {
    if bytes.len() < 32 {
        return Err("truncated header".into());
    }
    let streams = bytes[15] as usize;
    let toc = u32::from_le_bytes(bytes[16..20].try_into().expect("4 bytes")) as usize;
    let blocks = h.block_sizes();
    let non_empty: Vec<usize> = (0..blocks.len()).filter(|&b| blocks[b] > 0).collect();
    if streams != non_empty.len() {
        return Err(format!("{streams} streams for {} expected", non_empty.len()));
    }
    let toc_end =
        toc.checked_add(16 * streams).filter(|&e| e <= bytes.len()).ok_or("truncated table of contents")?;
    let mut at = toc_end;
    let mut parts: Vec<Vec<u8>> = vec![Vec::new(); blocks.len()];
    for (s, &b) in non_empty.iter().enumerate() {
        let entry = &bytes[toc + 16 * s..toc + 16 * s + 16];
        let compressed = u64::from_le_bytes(entry[..8].try_into().expect("8 bytes"));
        let size = u64::from_le_bytes(entry[8..].try_into().expect("8 bytes"));
        if size != blocks[b] {
            return Err(format!("stream {s} holds {size} bytes, expected {}", blocks[b]));
        }
        let end = (at as u64)
            .checked_add(compressed)
            .filter(|&e| e <= bytes.len() as u64)
            .ok_or("truncated stream")?;
        let frame = &bytes[at..end as usize];
        let mut out = Vec::with_capacity(size as usize);
        ruzstd::decoding::StreamingDecoder::new(frame)
            .map_err(|e| format!("stream {s}: {e}"))?
            .take(size + 1)
            .read_to_end(&mut out)
            .map_err(|e| format!("stream {s}: {e}"))?;
        if out.len() as u64 != size {
            return Err(format!("stream {s} decompresses to {} bytes, expected {size}", out.len()));
        }
        parts[b] = out;
        at = end as usize;
    }
    let refs: Vec<&[u8]> = parts.iter().map(Vec::as_slice).collect();
    Ok(h.gaussians(&refs))
}

struct Header {
    version: u32,
    points: u64,
    sh_degree: u32,
    fractional_bits: u32,
}

impl Header {
    fn parse(b: &[u8]) -> std::result::Result<Header, String> {
        if b.len() < 16 {
            return Err("truncated header".into());
        }
        let word = |at: usize| u32::from_le_bytes(b[at..at + 4].try_into().expect("4 bytes"));
        if word(0) != MAGIC {
            return Err("not an SPZ file (no NGSP magic)".into());
        }
        let h = Header {
            version: word(4),
            points: word(8) as u64,
            sh_degree: b[12] as u32,
            fractional_bits: b[13] as u32,
        };
        if h.sh_degree > 3 {
            return Err(format!("SH degree {} is not supported (0 to 3)", h.sh_degree));
        }
        if h.fractional_bits > 23 {
            return Err(format!("{} fractional bits (at most 23)", h.fractional_bits));
        }
        if h.points > MAX_POINTS {
            return Err(format!("{} Gaussians is more than the limit of {MAX_POINTS}", h.points));
        }
        Ok(h)
    }

    /// Bytes of the position, opacity, colour, scale, rotation and SH blocks.
    fn block_sizes(&self) -> [u64; 6] {
        let n = self.points;
        let rot = if self.version == 2 { 3 } else { 4 };
        let rest = (crate::sh_coeffs(self.sh_degree) as u64 - 1) * 3;
        [9 * n, n, 3 * n, 3 * n, rot * n, rest * n]
    }

    /// The scene held by the six blocks (already checked to have their sizes).
    fn gaussians(&self, b: &[&[u8]]) -> Gaussians {
        let n = self.points as usize;
        let k = crate::sh_coeffs(self.sh_degree);
        let scale = 1.0 / (1u64 << self.fractional_bits) as f32;
        let mut g = Gaussians { sh_degree: self.sh_degree, ..Default::default() };
        g.means = (0..n)
            .map(|i| {
                std::array::from_fn(|a| {
                    let p = &b[0][9 * i + 3 * a..9 * i + 3 * a + 3];
                    let v = i32::from_le_bytes([0, p[0], p[1], p[2]]) >> 8;
                    v as f32 * scale
                })
            })
            .collect();
        g.opacity_logits = b[1].iter().map(|&a| opacity_logit_of_byte(a)).collect();
        g.log_scales =
            b[3].chunks_exact(3).map(|s| std::array::from_fn(|a| s[a] as f32 / 16.0 - 10.0)).collect();
        g.rotations = if self.version == 2 {
            b[4].chunks_exact(3)
                .map(|r| {
                    let v = [0, 1, 2].map(|a| r[a] as f32 / 127.5 - 1.0);
                    let w = (1.0 - v.iter().map(|x| x * x).sum::<f32>()).max(0.0).sqrt();
                    [w, v[0], v[1], v[2]]
                })
                .collect()
        } else {
            b[4].chunks_exact(4)
                .map(|r| unpack_rotation(u32::from_le_bytes(r.try_into().expect("4"))))
                .collect()
        };
        g.sh = Vec::with_capacity(n * k * 3);
        for i in 0..n {
            for c in 0..3 {
                g.sh.push((b[2][3 * i + c] as f32 / 255.0 - 0.5) / COLOUR_SCALE);
            }
            for j in 0..(k - 1) * 3 {
                g.sh.push((b[5][i * (k - 1) * 3 + j] as f32 - 128.0) / 128.0);
            }
        }
        flip_rdf_rub(&mut g);
        g
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The shared random scene, spread to ±10 so positions use the fixed-point range.
    fn scene(n: usize, degree: u32) -> Gaussians {
        let mut g = crate::gaussians::random_scene(n, degree, 99);
        g.means.iter_mut().flatten().for_each(|v| *v *= 10.0);
        g
    }

    #[test]
    fn hand_computed_header_and_codes() {
        let mut g = scene(1, 0);
        g.means[0] = [1.0, 0.5, -2.0];
        let p = payload(&g);
        assert_eq!(&p[..16], &[0x4e, 0x47, 0x53, 0x50, 3, 0, 0, 0, 1, 0, 0, 0, 0, 12, 0, 0]);
        // x = 1 → 4096 = 0x001000; y = 0.5 flipped → −2048 = 0xfff800; z = −2 → +8192.
        assert_eq!(&p[16..25], &[0x00, 0x10, 0x00, 0x00, 0xf8, 0xff, 0x00, 0x20, 0x00]);
        // Identity: w largest (index 3), x, y, z all zero.
        assert_eq!(pack_rotation([1.0, 0.0, 0.0, 0.0]), 3 << 30);
        // Degree-1 SH in 5 bits: 0.3 → round(38.4) + 128 = 166 → bucket 8 → 168.
        assert_eq!(sh_byte(0.3, 5), 168);
        assert_eq!(sh_byte(0.3, 4), 160);
    }

    #[test]
    fn round_trip_is_within_the_quantisation() {
        for degree in 0..=3 {
            let g = scene(500, degree);
            let d = parse(&to_bytes(&g), Path::new("t.spz")).unwrap();
            assert_eq!((d.len(), d.sh_degree), (g.len(), degree));
            let k = g.sh_coeffs() * 3;
            for i in 0..g.len() {
                for a in 0..3 {
                    assert!((d.means[i][a] - g.means[i][a]).abs() <= 0.5 / 4096.0 + 1e-6);
                    assert!((d.log_scales[i][a] - g.log_scales[i][a]).abs() <= 1.0 / 32.0 + 1e-5);
                }
                let qn = {
                    let q = g.rotations[i];
                    let n = q.iter().map(|v| v * v).sum::<f32>().sqrt();
                    q.map(|v| v / n)
                };
                let dot: f32 = qn.iter().zip(&d.rotations[i]).map(|(a, b)| a * b).sum();
                assert!(dot.abs() > 0.999, "rotation {i}: {dot}");
                assert!(
                    (sigmoid(d.opacity_logits[i]) - sigmoid(g.opacity_logits[i])).abs() <= 0.5 / 255.0 + 1e-6
                );
                for c in 0..3 {
                    assert!((d.sh[i * k + c] - g.sh[i * k + c]).abs() <= 0.5 / 255.0 / COLOUR_SCALE + 1e-5);
                }
                for j in 3..k {
                    let bucket = if j < 12 { 8.0 } else { 16.0 };
                    let err = (d.sh[i * k + j] - g.sh[i * k + j]).abs();
                    assert!(err <= (bucket / 2.0 + 0.5) / 128.0 + 1e-5, "sh {i} {j}: {err}");
                }
            }
        }
    }

    #[test]
    fn the_axis_flip_is_a_rotation_and_its_own_inverse() {
        let g = scene(50, 3);
        let mut f = g.clone();
        flip_rdf_rub(&mut f);
        assert_ne!(f, g);
        flip_rdf_rub(&mut f);
        assert_eq!(f, g);
    }

    #[test]
    fn far_scenes_use_fewer_fractional_bits() {
        let mut g = scene(10, 0);
        g.means[3] = [5000.0, 0.0, 0.0];
        assert_eq!(fractional_bits(&g), 10);
        let d = parse(&to_bytes(&g), Path::new("t.spz")).unwrap();
        assert!((d.means[3][0] - 5000.0).abs() < 1e-3);
    }

    #[test]
    fn bad_files_are_errors() {
        let bytes = to_bytes(&scene(100, 1));
        let e = parse(&bytes[..bytes.len() / 2], Path::new("t.spz")).unwrap_err().to_string();
        assert!(e.contains("t.spz") && e.contains("SPZ"), "{e}");
        let mut p = payload(&scene(100, 1));
        p[8..12].copy_from_slice(&u32::MAX.to_le_bytes());
        let mut enc = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::fast());
        enc.write_all(&p).unwrap();
        let e = parse(&enc.finish().unwrap(), Path::new("t.spz")).unwrap_err().to_string();
        assert!(e.contains("more than the limit"), "{e}");
    }
}
