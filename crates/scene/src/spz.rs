//! Niantic's SPZ scene file (`.spz`), read and written.
//!
//! Versions 2 and 3 are one gzip stream holding a 16-byte header (magic `NGSP`,
//! version, count, SH degree, fractional bits, flags, reserved) and then, Gaussian
//! after Gaussian within each block: positions as 24-bit fixed point, opacities
//! (`sigmoid · 255`), DC colours (`f_dc · 0.15 · 255 + 127.5`), log-scales
//! (`(log σ + 10) · 16`), rotations (v2: x, y, z bytes with w ≥ 0; v3: "smallest three"
//! in 32 bits, 9-bit magnitudes of `|q_i|/√½` with a sign bit each) and the higher SH
//! coefficients (coefficient-major, `round(v · 128) + 128` rounded to 5-bit buckets for
//! degree 1 and 4-bit buckets above). Version 4 (the reference's current default, and
//! ours) is an uncompressed 32-byte header (the same 16 bytes, then the number of
//! streams in byte 15, the table's offset at 16 and zeros), a table of (compressed,
//! uncompressed) sizes as two u64 per non-empty block, and one zstd frame per block.
//! Both are read and written ([`Options::version`]). docs/formats.md#spz has the details.
//!
//! Axes ([`Axes`]): Niantic's reference documents SPZ as RUB (x right, y up, z back)
//! and the INRIA PLY as RDF (x right, y down, z forward); the two differ by a half turn
//! about x, so positions, rotations and the odd SH coefficients change sign on the way
//! in and out ([`flip_rdf_rub`]). PlayCanvas splat-transform 2.x does the same
//! ([`Axes::Rub`], the default). splat-transform 3.x and Niantic's `ply_to_spz` store the
//! PLY's axes unconverted ([`Axes::Rdf`]). Files read back exactly as written under
//! the same axes.

use crate::{atomic, opacity_logit_of_byte, sigmoid, Error, Gaussians, Result};
use std::io::{Read, Write};
use std::path::Path;

const MAGIC: u32 = 0x5053_474e;
/// The 0.15 colour scale of the reference (DC colour `f_dc · 0.15 + ½`).
const COLOUR_SCALE: f32 = 0.15;
/// The version written unless asked otherwise.
pub const WRITE_VERSION: u32 = 4;

/// Which axes an SPZ file's coordinates are in.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Axes {
    /// Niantic's documented RUB (x right, y up, z back), a half turn about x from the
    /// PLY: what splat-transform 2.x writes and reads.
    #[default]
    Rub,
    /// The PLY's own RDF axes, unconverted: what splat-transform 3.x and Niantic's
    /// `ply_to_spz` write.
    Rdf,
}

impl Axes {
    /// `rub` or `rdf`.
    pub fn parse(s: &str) -> std::result::Result<Self, String> {
        match s.trim() {
            "rub" => Ok(Axes::Rub),
            "rdf" => Ok(Axes::Rdf),
            t => Err(format!("expected rub or rdf, got {t:?}")),
        }
    }

    /// Moves `g` between the PLY's axes and these (its own inverse).
    fn convert(self, g: &mut Gaussians) {
        if self == Axes::Rub {
            flip_rdf_rub(g);
        }
    }
}

/// How an SPZ file is written.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Options {
    /// 3 (gzip) or 4 (zstd streams; the default).
    pub version: u32,
    pub axes: Axes,
}

impl Default for Options {
    fn default() -> Self {
        Options { version: WRITE_VERSION, axes: Axes::Rub }
    }
}

impl Options {
    /// Parses a version flag value: 3 or 4.
    pub fn parse_version(s: &str) -> std::result::Result<u32, String> {
        match s.trim() {
            "3" => Ok(3),
            "4" => Ok(4),
            t => Err(format!("expected 3 or 4, got {t:?}")),
        }
    }
}
/// The zstd level of version 4's streams: 19, high, as files are written once and
/// zstd's decoding speed does not depend on the level (on the 46k-Gaussian tabletop
/// at SH 1: 5.8 bytes a Gaussian, against 6.7 for splat-transform 2.7.1's own v4).
const ZSTD_LEVEL: i32 = 19;
/// Most Gaussians a file may declare (bounded before allocating).
const MAX_POINTS: u64 = 1 << 28;

/// Converts between the PLY's RDF axes and SPZ's RUB axes (its own inverse): a half
/// turn about x, the quaternion's y and z negated (the turn's conjugation, which
/// equals turning the Gaussian's frame up to the sign of axes its scale is symmetric in).
pub fn flip_rdf_rub(g: &mut Gaussians) {
    g.half_turn_means_and_sh(0);
    for q in &mut g.rotations {
        q[2] = -q[2];
        q[3] = -q[3];
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

/// The first 16 header bytes (magic, version, count, SH degree, fractional bits, flags
/// 0, one byte that version 4 fills with the number of streams) and the six blocks of
/// a scene already in the file's axes: positions, opacities, colours, scales,
/// rotations, higher SH.
fn blocks(g: &Gaussians, version: u32) -> ([u8; 16], [Vec<u8>; 6]) {
    let n = g.len();
    let k = g.sh_coeffs();
    let fb = fractional_bits(g);
    let mut header = [0u8; 16];
    header[..4].copy_from_slice(&MAGIC.to_le_bytes());
    header[4..8].copy_from_slice(&version.to_le_bytes());
    header[8..12].copy_from_slice(&(n as u32).to_le_bytes());
    header[12] = g.sh_degree as u8;
    header[13] = fb;
    let scale = (1u64 << fb) as f32;
    let mut positions = Vec::with_capacity(9 * n);
    for m in &g.means {
        for v in m {
            let q = (v * scale).round() as i32;
            positions.extend_from_slice(&q.to_le_bytes()[..3]);
        }
    }
    let opacities = g.opacity_logits.iter().map(|&o| u8_of(sigmoid(o) * 255.0)).collect();
    let mut colours = Vec::with_capacity(3 * n);
    for i in 0..n {
        for c in 0..3 {
            colours.push(u8_of(g.sh[i * k * 3 + c] * (COLOUR_SCALE * 255.0) + 0.5 * 255.0));
        }
    }
    let scales = g.log_scales.iter().flat_map(|s| s.map(|v| u8_of((v + 10.0) * 16.0))).collect();
    let rotations = g.rotations.iter().flat_map(|q| pack_rotation(*q).to_le_bytes()).collect();
    let mut rest = Vec::with_capacity(n * (k - 1) * 3);
    for i in 0..n {
        let sh = g.sh_of(i);
        for j in 1..k {
            let bits = if j < 4 { 5 } else { 4 };
            for c in 0..3 {
                rest.push(sh_byte(sh[j * 3 + c], bits));
            }
        }
    }
    (header, [positions, opacities, colours, scales, rotations, rest])
}

/// The `.spz` bytes of a scene in the default layout (version 4, RUB axes). Extra
/// properties are not stored. Assumes `g.validate()` passes.
pub fn to_bytes(g: &Gaussians) -> Vec<u8> {
    to_bytes_with(g, &Options::default())
}

/// The `.spz` bytes of a scene written as `options` say.
pub fn to_bytes_with(g: &Gaussians, options: &Options) -> Vec<u8> {
    let mut g = g.clone();
    options.axes.convert(&mut g);
    let (mut header, blocks) = blocks(&g, options.version);
    if options.version == 3 {
        let mut enc = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
        enc.write_all(&header).expect("writing to memory");
        blocks.iter().for_each(|b| enc.write_all(b).expect("writing to memory"));
        return enc.finish().expect("writing to memory");
    }
    // Version 4: header, table of contents, one zstd frame per non-empty block.
    let frames: Vec<(Vec<u8>, usize)> = blocks
        .iter()
        .filter(|b| !b.is_empty())
        .map(|b| (zstd::bulk::compress(b, ZSTD_LEVEL).expect("compressing in memory"), b.len()))
        .collect();
    header[15] = frames.len() as u8;
    let mut out = header.to_vec();
    out.extend_from_slice(&32u32.to_le_bytes());
    out.resize(32, 0);
    for (frame, size) in &frames {
        out.extend_from_slice(&(frame.len() as u64).to_le_bytes());
        out.extend_from_slice(&(*size as u64).to_le_bytes());
    }
    frames.iter().for_each(|(f, _)| out.extend_from_slice(f));
    out
}

/// Writes a scene atomically as `.spz` in the default layout.
pub fn write(path: &Path, g: &Gaussians) -> Result<()> {
    write_with(path, g, &Options::default())
}

/// Writes a scene atomically as `.spz` as `options` say (refusing NaN or infinite
/// parameters and scenes SPZ cannot hold: no Gaussians, or more than 2³² − 1).
pub fn write_with(path: &Path, g: &Gaussians, options: &Options) -> Result<()> {
    g.check_writable(path)?;
    if g.is_empty() || g.len() > u32::MAX as usize {
        return Err(Error::format(path, format!("cannot write {} Gaussians as SPZ", g.len())));
    }
    if !(3..=4).contains(&options.version) {
        return Err(Error::format(
            path,
            format!("SPZ version {} cannot be written (3 or 4)", options.version),
        ));
    }
    atomic::write_bytes(path, &to_bytes_with(g, options))
}

/// True when `bytes` start like an SPZ file (gzip, or the version-4 `NGSP` magic).
pub fn looks_like(bytes: &[u8]) -> bool {
    bytes.starts_with(&[0x1f, 0x8b]) || bytes.starts_with(b"NGSP")
}

/// Parses `.spz` bytes (versions 2, 3 and 4) in the default RUB axes; `path` names
/// the file in errors.
pub fn parse(bytes: &[u8], path: &Path) -> Result<Gaussians> {
    parse_with(bytes, path, Axes::Rub)
}

/// Parses `.spz` bytes whose coordinates are in `axes`.
pub fn parse_with(bytes: &[u8], path: &Path, axes: Axes) -> Result<Gaussians> {
    let mut g = decode(bytes).map_err(|m| Error::format(path, format!("SPZ: {m}")))?;
    axes.convert(&mut g);
    Ok(g)
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
        g
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The uncompressed version-3 payload of a scene (header and blocks, before gzip).
    fn payload(g: &Gaussians) -> Vec<u8> {
        let mut g = g.clone();
        Axes::Rub.convert(&mut g);
        let (header, blocks) = blocks(&g, 3);
        let mut out = header.to_vec();
        blocks.iter().for_each(|b| out.extend_from_slice(b));
        out
    }

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

    /// `d` is `g` decoded: every value within SPZ's quantisation of it.
    fn assert_within_quantisation(g: &Gaussians, d: &Gaussians) {
        assert_eq!((d.len(), d.sh_degree), (g.len(), g.sh_degree));
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

    #[test]
    fn round_trip_is_within_the_quantisation() {
        for degree in 0..=3 {
            for version in [3, 4] {
                let g = scene(500, degree);
                let bytes = to_bytes_with(&g, &Options { version, ..Default::default() });
                assert_within_quantisation(&g, &parse(&bytes, Path::new("t.spz")).unwrap());
            }
        }
    }

    #[test]
    fn version_4_holds_what_version_3_holds_in_zstd_streams() {
        for degree in [0, 1, 3] {
            let g = scene(300, degree);
            let v3 = to_bytes_with(&g, &Options { version: 3, ..Default::default() });
            let v4 = to_bytes_with(&g, &Options { version: 4, ..Default::default() });
            assert_eq!(to_bytes(&g), v4, "version 4 is the default");
            let (a, b) = (parse(&v3, Path::new("a")).unwrap(), parse(&v4, Path::new("b")).unwrap());
            assert!(a == b, "degree {degree}: versions 3 and 4 decode differently");
            // The header by hand: magic, version 4, count, degree, 12 fractional bits
            // (±10 fits), flags 0, the streams (no SH block at degree 0), the table at 32.
            let streams = if degree == 0 { 5 } else { 6 };
            assert_eq!(
                &v4[..16],
                &[0x4e, 0x47, 0x53, 0x50, 4, 0, 0, 0, 44, 1, 0, 0, degree as u8, 12, 0, streams]
            );
            assert_eq!(&v4[16..32], &[32, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]);
            // The table's uncompressed sizes are the blocks' sizes.
            let size =
                |s: usize| u64::from_le_bytes(v4[32 + 16 * s + 8..32 + 16 * s + 16].try_into().unwrap());
            assert_eq!((size(0), size(1), size(4)), (9 * 300, 300, 4 * 300));
        }
    }

    #[test]
    fn rdf_files_hold_the_plys_axes_and_read_back_under_them() {
        let g = scene(100, 2);
        let options = Options { axes: Axes::Rdf, ..Default::default() };
        let rdf = to_bytes_with(&g, &options);
        let back = parse_with(&rdf, Path::new("t.spz"), Axes::Rdf).unwrap();
        assert_within_quantisation(&g, &back);
        // The positions are stored as they are in the PLY: x = 1 stays 4096 at 12 bits,
        // y = 0.5 stays +2048 (RUB would store −2048).
        let mut one = scene(1, 0);
        one.means[0] = [1.0, 0.5, -2.0];
        let raw = to_bytes_with(&one, &Options { version: 3, axes: Axes::Rdf });
        let mut payload = Vec::new();
        flate2::read::GzDecoder::new(raw.as_slice()).read_to_end(&mut payload).unwrap();
        assert_eq!(&payload[16..25], &[0x00, 0x10, 0x00, 0x00, 0x08, 0x00, 0x00, 0xe0, 0xff]);
        // Read as RUB, an RDF file comes out turned a half turn about x.
        let mut turned = parse(&rdf, Path::new("t.spz")).unwrap();
        flip_rdf_rub(&mut turned);
        assert!(turned == back, "the two readings differ by more than the half turn");
        assert_eq!(Axes::parse("rdf"), Ok(Axes::Rdf));
        assert!(Axes::parse("lub").is_err() && Options::parse_version("5").is_err());
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
