//! The PlayCanvas compressed PLY (`.compressed.ply`, written by SuperSplat and
//! splat-transform), read and written.
//!
//! Layout (docs/formats.md#compressed-ply): a `chunk` element of float32 bounds per
//! 256 Gaussians (`min_x..max_z`, `min_scale_x..max_scale_z`, `min_r..max_b`), a
//! `vertex` element of four packed uint32 per Gaussian and an optional `sh` element of
//! uchar `f_rest_*` (channel-major, as in the INRIA PLY). Inside its chunk a Gaussian
//! stores
//! - position and log-scale as 11/10/11-bit fractions of the chunk's bounds;
//! - rotation as "largest three dropped": 2 bits naming the largest |component| of the
//!   normalised (w, x, y, z) quaternion (made positive), then the other three in order
//!   as 10-bit values of `v / √2 + ½`;
//! - colour `SH_C0·f_dc + ½` as 8-bit fractions of the chunk's colour bounds, and
//!   `sigmoid(opacity)` as 8 bits;
//! - every higher SH coefficient `v` as the byte `⌊(v/8 + ½)·256⌋` clamped to 0..=255.
//!
//! The writer orders the Gaussians along a Morton curve first, so that a chunk is a
//! compact region and its bounds are tight ([`morton_order`]); [`encode`] returns that
//! order so callers can permute per-Gaussian data alongside.

use super::{parse_header, Element, Format, Header, Kind, Scalar};
use crate::{atomic, opacity_logit_of_byte, Gaussians, SH_C0};

/// Gaussians per chunk.
pub const CHUNK: usize = 256;
/// The DC SH basis constant.
const SH_C0_F64: f64 = 0.282_094_791_773_878_14;
/// Log-scales are clamped to this range before quantising (a larger |log σ| is a
/// degenerate Gaussian anyway).
const LOG_SCALE_LIMIT: f32 = 20.0;

const CHUNK_PROPS: [&str; 18] = [
    "min_x",
    "min_y",
    "min_z",
    "max_x",
    "max_y",
    "max_z",
    "min_scale_x",
    "min_scale_y",
    "min_scale_z",
    "max_scale_x",
    "max_scale_y",
    "max_scale_z",
    "min_r",
    "min_g",
    "min_b",
    "max_r",
    "max_g",
    "max_b",
];
const VERTEX_PROPS: [&str; 4] = ["packed_position", "packed_rotation", "packed_scale", "packed_color"];

/// True when a parsed header has the compressed layout's `packed_*` vertex properties.
pub(super) fn is_compressed(h: &Header) -> bool {
    h.elements.iter().any(|e| e.name == "vertex" && e.props.iter().any(|p| p.name == "packed_position"))
}

/// The Morton (Z-order) curve order of the Gaussians' centres, 10 bits per axis over
/// their bounding box (x in the lowest bit of each triple), stable; a run of more than
/// a chunk of equal codes is ordered again within its own bounding box. This is the
/// order splat-transform writes, so our files match its byte for byte.
pub fn morton_order(g: &Gaussians) -> Vec<u32> {
    let mut idx: Vec<u32> = (0..g.len() as u32).collect();
    morton_sort(&g.means, &mut idx);
    idx
}

/// Puts the Gaussians `idx` (indices into `means`) in [`morton_order`], over their
/// own bounding box.
pub fn morton_sort(means: &[[f32; 3]], idx: &mut [u32]) {
    if idx.is_empty() {
        return;
    }
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for &i in idx.iter() {
        for a in 0..3 {
            lo[a] = lo[a].min(means[i as usize][a] as f64);
            hi[a] = hi[a].max(means[i as usize][a] as f64);
        }
    }
    let extent: [f64; 3] = std::array::from_fn(|a| hi[a] - lo[a]);
    if extent.iter().any(|e| !e.is_finite()) || extent.iter().all(|&e| e == 0.0) {
        return;
    }
    let mul: [f64; 3] = std::array::from_fn(|a| if extent[a] == 0.0 { 0.0 } else { 1024.0 / extent[a] });
    let code = |i: u32| -> u32 {
        let p = means[i as usize];
        let q = |a: usize| ((p[a] as f64 - lo[a]) * mul[a]).min(1023.0) as u32;
        (spread_bits(q(2)) << 2) + (spread_bits(q(1)) << 1) + spread_bits(q(0))
    };
    let mut coded: Vec<(u32, u32)> = idx.iter().map(|&i| (code(i), i)).collect();
    coded.sort_by_key(|&(c, _)| c);
    for (slot, &(_, i)) in idx.iter_mut().zip(&coded) {
        *slot = i;
    }
    let mut s = 0;
    while s < coded.len() {
        let e = s + coded[s..].iter().take_while(|(c, _)| *c == coded[s].0).count();
        if e - s > CHUNK {
            morton_sort(means, &mut idx[s..e]);
        }
        s = e;
    }
}

/// Inserts two zero bits between each of the low 10 bits of `v`.
fn spread_bits(v: u32) -> u32 {
    let mut x = v & 0x3ff;
    x = (x ^ (x << 16)) & 0xff0000ff;
    x = (x ^ (x << 8)) & 0x0300f00f;
    x = (x ^ (x << 4)) & 0x030c30c3;
    x = (x ^ (x << 2)) & 0x09249249;
    x
}

fn bounds(points: impl Iterator<Item = [f32; 3]>) -> ([f32; 3], [f32; 3]) {
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for p in points {
        for a in 0..3 {
            lo[a] = lo[a].min(p[a]);
            hi[a] = hi[a].max(p[a]);
        }
    }
    if lo[0] > hi[0] {
        return ([0.0; 3], [0.0; 3]);
    }
    (lo, hi)
}

/// `v` as a `bits`-bit fraction of `[lo, hi]` (in f64, as splat-transform does): 0 at
/// or below `lo`, all ones at or above `hi`, 0 for a range under 1e-5.
fn quantise(v: f64, lo: f64, hi: f64, bits: u32) -> u32 {
    let max = ((1u32 << bits) - 1) as f64;
    let t = if v <= lo {
        0.0
    } else if v >= hi {
        1.0
    } else if hi - lo < 1e-5 {
        0.0
    } else {
        (v - lo) / (hi - lo)
    };
    (t * max + 0.5).floor().clamp(0.0, max) as u32
}

/// The inverse of [`quantise`].
fn dequantise(q: u32, lo: f32, hi: f32, bits: u32) -> f32 {
    let max = (1u32 << bits) - 1;
    lo + (hi - lo) * ((q & max) as f32 / max as f32)
}

fn pack_111011(v: [f32; 3], lo: [f32; 3], hi: [f32; 3]) -> u32 {
    let q = |a: usize, bits| quantise(v[a] as f64, lo[a] as f64, hi[a] as f64, bits);
    (q(0, 11) << 21) | (q(1, 10) << 11) | q(2, 11)
}

fn unpack_111011(p: u32, lo: [f32; 3], hi: [f32; 3]) -> [f32; 3] {
    [
        dequantise(p >> 21, lo[0], hi[0], 11),
        dequantise(p >> 11, lo[1], hi[1], 10),
        dequantise(p, lo[2], hi[2], 11),
    ]
}

/// The "largest component dropped" rotation code (module doc).
fn pack_rotation(q: [f32; 4]) -> u32 {
    let q = q.map(|v| v as f64);
    let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    let q = if n > 0.0 { q.map(|v| v / n) } else { [0.0, 0.0, 0.0, 1.0] };
    // The first component of largest magnitude (ties keep the lower index).
    let largest = (1..4).fold(0, |l, k| if q[k].abs() > q[l].abs() { k } else { l });
    let sign = if q[largest] < 0.0 { -1.0 } else { 1.0 };
    let mut code = (largest as u32) << 30;
    let mut shift = 20;
    for (k, v) in q.iter().enumerate() {
        if k != largest {
            code |= quantise(sign * v * std::f64::consts::FRAC_1_SQRT_2 + 0.5, 0.0, 1.0, 10) << shift;
            shift -= 10;
        }
    }
    code
}

fn unpack_rotation(code: u32) -> [f32; 4] {
    let largest = (code >> 30) as usize;
    let mut q = [0.0f32; 4];
    let mut shift = 20;
    let mut sum = 0.0;
    for (k, v) in q.iter_mut().enumerate() {
        if k != largest {
            *v = (dequantise(code >> shift, 0.0, 1.0, 10) - 0.5) * std::f32::consts::SQRT_2;
            sum += *v * *v;
            shift -= 10;
        }
    }
    q[largest] = (1.0 - sum).max(0.0).sqrt();
    q
}

/// The byte of a higher SH coefficient.
fn sh_byte(v: f32) -> u8 {
    ((v as f64 / 8.0 + 0.5) * 256.0).trunc().clamp(0.0, 255.0) as u8
}

/// The inverse of [`sh_byte`] (the bucket's centre; 0 and 255 map to the range ends).
fn sh_value(b: u8) -> f32 {
    let n = match b {
        0 => 0.0,
        255 => 1.0,
        _ => (b as f32 + 0.5) / 256.0,
    };
    (n - 0.5) * 8.0
}

/// Encodes a scene in Morton order; returns the file bytes and the order used
/// (`order[k]` is the input index of the k-th Gaussian in the file).
pub fn encode(g: &Gaussians) -> (Vec<u8>, Vec<u32>) {
    let order = morton_order(g);
    (to_bytes(&g.select(&order)), order)
}

/// Encodes a scene in its own order (see [`encode`] for the usual, Morton-ordered
/// call). Extra properties are not stored. Assumes `g.validate()` passes.
pub fn to_bytes(g: &Gaussians) -> Vec<u8> {
    let n = g.len();
    let chunks = n.div_ceil(CHUNK);
    let rest = (g.sh_coeffs() - 1) * 3;
    let mut out = Vec::with_capacity(1024 + chunks * 72 + n * (16 + rest));
    let mut header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment written by transsplat\nelement chunk {chunks}\n"
    );
    for p in CHUNK_PROPS {
        header += &format!("property float {p}\n");
    }
    header += &format!("element vertex {n}\n");
    for p in VERTEX_PROPS {
        header += &format!("property uint {p}\n");
    }
    if rest > 0 {
        header += &format!("element sh {n}\n");
        for j in 0..rest {
            header += &format!("property uchar f_rest_{j}\n");
        }
    }
    header += "end_header\n";
    out.extend_from_slice(header.as_bytes());

    let k = g.sh_coeffs() * 3;
    let colour =
        |i: usize| -> [f32; 3] { std::array::from_fn(|c| (SH_C0_F64 * g.sh[i * k + c] as f64 + 0.5) as f32) };
    let log_scale = |i: usize| g.log_scales[i];
    let mut packed = Vec::with_capacity(n * 16);
    for c in 0..chunks {
        let range = c * CHUNK..((c + 1) * CHUNK).min(n);
        let (plo, phi) = bounds(range.clone().map(|i| g.means[i]));
        let (slo, shi) = bounds(range.clone().map(log_scale));
        let clamp = |v: [f32; 3]| v.map(|s| s.clamp(-LOG_SCALE_LIMIT, LOG_SCALE_LIMIT));
        let (slo, shi) = (clamp(slo), clamp(shi));
        let (clo, chi) = bounds(range.clone().map(colour));
        for v in plo.iter().chain(&phi).chain(&slo).chain(&shi).chain(&clo).chain(&chi) {
            out.extend_from_slice(&v.to_le_bytes());
        }
        for i in range {
            let col = colour(i);
            let q = |c: usize| quantise(col[c] as f64, clo[c] as f64, chi[c] as f64, 8);
            let opacity = 1.0 / (1.0 + (-(g.opacity_logits[i] as f64)).exp());
            let rgba = (q(0) << 24) | (q(1) << 16) | (q(2) << 8) | quantise(opacity, 0.0, 1.0, 8);
            for word in [
                pack_111011(g.means[i], plo, phi),
                pack_rotation(g.rotations[i]),
                pack_111011(log_scale(i), slo, shi),
                rgba,
            ] {
                packed.extend_from_slice(&word.to_le_bytes());
            }
        }
    }
    out.extend_from_slice(&packed);
    // Higher SH, channel-major (f_rest_{c·(K−1) + j} is coefficient j + 1 of channel c).
    let per = g.sh_coeffs() - 1;
    for i in 0..n {
        let sh = g.sh_of(i);
        for c in 0..3 {
            for j in 1..=per {
                out.push(sh_byte(sh[j * 3 + c]));
            }
        }
    }
    out
}

/// Where one element's rows lie in the body, and each property's byte offset in a row.
struct Layout<'a> {
    start: usize,
    row: usize,
    el: &'a Element,
}

impl Layout<'_> {
    fn offset(&self, name: &str) -> Result<usize, String> {
        let mut off = 0;
        for p in &self.el.props {
            let Kind::Scalar(s) = p.kind else { unreachable!("checked fixed size") };
            if p.name == name {
                return Ok(off);
            }
            off += s.size();
        }
        Err(format!("compressed PLY: element '{}' has no property '{name}'", self.el.name))
    }

    fn scalar_type(&self, name: &str) -> Option<Scalar> {
        self.el.props.iter().find(|p| p.name == name).and_then(|p| match p.kind {
            Kind::Scalar(s) => Some(s),
            Kind::List { .. } => None,
        })
    }
}

/// Decodes a compressed PLY whose header `h` [`is_compressed`].
pub(super) fn decode(bytes: &[u8], h: &Header) -> Result<Gaussians, String> {
    if h.format != Format::LittleEndian {
        return Err("compressed PLY must be binary_little_endian".into());
    }
    let mut pos = h.body;
    let mut layouts = Vec::new();
    for el in &h.elements {
        let row = el
            .fixed_size()
            .ok_or_else(|| format!("compressed PLY: element '{}' has a list property", el.name))?;
        let size = (el.count as u128) * row as u128;
        if size > (bytes.len() - pos.min(bytes.len())) as u128 {
            return Err(format!(
                "compressed PLY is truncated: element '{}' needs {size} bytes, {} remain",
                el.name,
                bytes.len().saturating_sub(pos)
            ));
        }
        layouts.push(Layout { start: pos, row, el });
        pos += size as usize;
    }
    let find = |name: &str| layouts.iter().find(|l| l.el.name == name);
    let chunk = find("chunk").ok_or("compressed PLY has no 'chunk' element")?;
    let vertex = find("vertex").ok_or("compressed PLY has no 'vertex' element")?;
    let n = vertex.el.count as usize;
    if chunk.el.count as usize != n.div_ceil(CHUNK) {
        return Err(format!(
            "compressed PLY has {} chunks for {n} Gaussians (expected {})",
            chunk.el.count,
            n.div_ceil(CHUNK)
        ));
    }
    for p in &CHUNK_PROPS[..12] {
        if chunk.scalar_type(p) != Some(Scalar::F32) {
            return Err(format!("compressed PLY: chunk property '{p}' is missing or not a float"));
        }
    }
    let has_colour = chunk.scalar_type("min_r").is_some();
    if has_colour && CHUNK_PROPS[12..].iter().any(|p| chunk.scalar_type(p) != Some(Scalar::F32)) {
        return Err("compressed PLY: chunk colour bounds are incomplete or not floats".into());
    }
    for p in VERTEX_PROPS {
        if vertex.scalar_type(p) != Some(Scalar::U32) {
            return Err(format!("compressed PLY: vertex property '{p}' is missing or not a uint"));
        }
    }
    let sh_layout = find("sh");
    let rest = sh_layout.map_or(0, |l| l.el.props.len());
    let sh_degree = match rest {
        0 => 0,
        9 => 1,
        24 => 2,
        45 => 3,
        k => return Err(format!("compressed PLY has {k} SH properties; expected 0, 9, 24 or 45")),
    };
    let mut sh_offsets = Vec::with_capacity(rest);
    if let Some(l) = sh_layout {
        if l.el.count as usize != n {
            return Err(format!("compressed PLY: 'sh' has {} rows for {n} Gaussians", l.el.count));
        }
        for j in 0..rest {
            let name = format!("f_rest_{j}");
            if l.scalar_type(&name) != Some(Scalar::U8) {
                return Err(format!("compressed PLY: SH property '{name}' is missing or not a uchar"));
            }
            sh_offsets.push(l.offset(&name)?);
        }
    }

    let f32_at = |at: usize| f32::from_le_bytes(bytes[at..at + 4].try_into().expect("4 bytes"));
    let u32_at = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().expect("4 bytes"));
    let chunk_offsets: Vec<usize> = CHUNK_PROPS
        .iter()
        .take(if has_colour { 18 } else { 12 })
        .map(|p| chunk.offset(p))
        .collect::<Result<_, _>>()?;
    let vertex_offsets: Vec<usize> =
        VERTEX_PROPS.iter().map(|p| vertex.offset(p)).collect::<Result<_, _>>()?;

    let ncoef = crate::sh_coeffs(sh_degree);
    let mut g = Gaussians { sh_degree, ..Default::default() };
    g.means.reserve_exact(n);
    g.log_scales.reserve_exact(n);
    g.rotations.reserve_exact(n);
    g.opacity_logits.reserve_exact(n);
    g.sh.reserve_exact(n * ncoef * 3);
    let mut bounds = [0.0f32; 18];
    for i in 0..n {
        if i % CHUNK == 0 {
            let base = chunk.start + (i / CHUNK) * chunk.row;
            for (b, &off) in bounds.iter_mut().zip(&chunk_offsets) {
                *b = f32_at(base + off);
            }
            if !has_colour {
                bounds[12..15].fill(0.0);
                bounds[15..18].fill(1.0);
            }
            if let Some(k) = bounds.iter().position(|v| !v.is_finite()) {
                return Err(format!(
                    "compressed PLY: chunk {} has a non-finite {}",
                    i / CHUNK,
                    CHUNK_PROPS[k]
                ));
            }
        }
        let base = vertex.start + i * vertex.row;
        let [pos, rot, scale, col] = [0, 1, 2, 3].map(|k| u32_at(base + vertex_offsets[k]));
        let b3 = |k: usize| [bounds[k], bounds[k + 1], bounds[k + 2]];
        g.means.push(unpack_111011(pos, b3(0), b3(3)));
        g.rotations.push(unpack_rotation(rot));
        g.log_scales.push(unpack_111011(scale, b3(6), b3(9)));
        g.opacity_logits.push(opacity_logit_of_byte(col as u8));
        let start = g.sh.len();
        for c in 0..3 {
            let v = dequantise(col >> (24 - 8 * c), bounds[12 + c], bounds[15 + c], 8);
            g.sh.push((v - 0.5) / SH_C0);
        }
        g.sh.resize(start + ncoef * 3, 0.0);
        if let Some(l) = sh_layout {
            let row = l.start + i * l.row;
            let per = ncoef - 1;
            for c in 0..3 {
                for j in 0..per {
                    g.sh[start + (j + 1) * 3 + c] = sh_value(bytes[row + sh_offsets[c * per + j]]);
                }
            }
        }
    }
    Ok(g)
}

/// Writes a scene atomically as a compressed PLY in Morton order (refusing NaN or
/// infinite parameters).
pub fn write(path: &std::path::Path, g: &Gaussians) -> crate::Result<()> {
    g.check_writable(path)?;
    atomic::write_bytes(path, &encode(g).0)
}

/// Parses compressed PLY bytes (for tests and tools that hold bytes).
pub fn parse(bytes: &[u8]) -> Result<Gaussians, String> {
    let h = parse_header(bytes)?;
    if !is_compressed(&h) {
        return Err("not a compressed PLY (no packed_position vertex property)".into());
    }
    decode(bytes, &h)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gaussians::random_scene;
    use crate::sigmoid;

    #[test]
    fn rotation_code_round_trips_within_quantisation() {
        for q in [[1.0, 0.0, 0.0, 0.0], [0.1, -0.7, 0.2, 0.3], [-0.5, 0.5, -0.5, 0.5], [0.0, 0.0, 0.0, -2.0]]
        {
            let n = (q.iter().map(|v: &f32| v * v).sum::<f32>()).sqrt();
            let qn = q.map(|v| v / n);
            let r = unpack_rotation(pack_rotation(q));
            // Same rotation up to sign: |<q, r>| ≈ 1.
            let dot: f32 = qn.iter().zip(&r).map(|(a, b)| a * b).sum();
            assert!(dot.abs() > 0.9999, "{q:?} -> {r:?}");
        }
    }

    #[test]
    fn hand_computed_codes() {
        // Identity: w is largest (index 0), the others encode ½ → round(0.5·1023) = 512.
        assert_eq!(pack_rotation([1.0, 0.0, 0.0, 0.0]), (512 << 20) | (512 << 10) | 512);
        // SH byte: v = 0 → ⌊0.5·256⌋ = 128; v = 4 → 255 (clamped); v = −4 → 0.
        assert_eq!((sh_byte(0.0), sh_byte(4.0), sh_byte(-4.0)), (128, 255, 0));
        assert_eq!(sh_value(128), (128.5 / 256.0 - 0.5) * 8.0);
        // 11/10/11: the top of the range is all ones.
        assert_eq!(pack_111011([1.0, 1.0, 1.0], [0.0; 3], [1.0; 3]), u32::MAX);
        assert_eq!(spread_bits(0b11), 0b1001);
    }

    #[test]
    fn round_trip_is_within_the_quantisation_and_stable() {
        for degree in 0..=3 {
            let g = random_scene(1000, degree, 12345);
            let (bytes, order) = encode(&g);
            let d = parse(&bytes).unwrap();
            assert_eq!((d.len(), d.sh_degree), (1000, degree));
            let k = crate::sh_coeffs(degree) * 3;
            for (j, &i) in order.iter().enumerate() {
                let i = i as usize;
                for (a, bits) in [11, 10, 11].into_iter().enumerate() {
                    // Half a step of the chunk's range, which is at most the scene's
                    // (2 for centres, 4 for log-scales) over 2^bits − 1 steps.
                    let step = |range: f32| range / ((1u32 << bits) - 1) as f32 * 0.51 + 1e-6;
                    assert!((d.means[j][a] - g.means[i][a]).abs() < step(2.0));
                    assert!((d.log_scales[j][a] - g.log_scales[i][a]).abs() < step(4.0));
                }
                assert!(
                    (sigmoid(d.opacity_logits[j]) - sigmoid(g.opacity_logits[i])).abs() < 0.5 / 255.0 + 1e-6
                );
                for c in 0..3 {
                    // DC colour: 8 bits of the chunk's colour range (≤ 2·C0 wide).
                    let dc = (d.sh[j * k + c] - g.sh[i * k + c]).abs() * SH_C0;
                    assert!(dc < 2.0 * SH_C0 / 255.0 * 0.51 + 1e-5, "dc {dc}");
                }
                for c in 3..k {
                    // Higher SH: 8 bits of [−4, 4], the bucket centre.
                    assert!((d.sh[j * k + c] - g.sh[i * k + c]).abs() <= 8.0 / 256.0 * 0.5 + 1e-5);
                }
            }
            // Encoding the decoded scene again moves nothing by more than float noise
            // (the quantisation is idempotent).
            let d2 = parse(&to_bytes(&d)).unwrap();
            let close = |a: &[f32], b: &[f32], tol: f32| a.iter().zip(b).all(|(x, y)| (x - y).abs() <= tol);
            assert!(close(d2.means.as_flattened(), d.means.as_flattened(), 1e-5), "degree {degree}");
            assert!(close(d2.log_scales.as_flattened(), d.log_scales.as_flattened(), 1e-5));
            assert!(close(&d2.opacity_logits, &d.opacity_logits, 1e-4));
            assert!(close(&d2.sh, &d.sh, 1e-4));
            let dots = d.rotations.iter().zip(&d2.rotations);
            assert!(dots
                .clone()
                .all(|(a, b)| a.iter().zip(b).map(|(x, y)| x * y).sum::<f32>().abs() > 0.99999));
        }
    }

    #[test]
    fn truncated_and_inconsistent_files_are_errors() {
        let (bytes, _) = encode(&random_scene(300, 1, 1));
        let e = parse(&bytes[..bytes.len() - 1]).unwrap_err();
        assert!(e.contains("truncated"), "{e}");
        let text = String::from_utf8_lossy(&bytes[..200]).to_string();
        let fewer = text.replacen("element chunk 2", "element chunk 1", 1);
        let mut b2 = fewer.into_bytes();
        b2.extend_from_slice(&bytes[200..]);
        let e = parse(&b2).unwrap_err();
        assert!(e.contains("1 chunks for 300 Gaussians"), "{e}");
    }
}
