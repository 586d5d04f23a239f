//! PlayCanvas SOG (`.sog`), read and written: the Gaussians as lossless WebP textures
//! described by a `meta.json` (version 2), bundled in a zip file.
//!
//! Layout, as PlayCanvas splat-transform 2.7.1 writes and reads it (its `write-sog` and
//! `read-sog`; docs/formats.md#sog): the Gaussians in Morton order
//! ([`crate::ply::compressed::morton_order`]), one texel each, row by row, in textures
//! `ceil(√n / 4)·4` wide and `ceil(n / width / 4)·4` tall, in the PLY's own axes:
//! - `means_l.webp`, `means_u.webp`: each coordinate as `l(v) = sign(v)·ln(|v| + 1)`,
//!   16-bit between the per-axis minimum and maximum of `l` (`meta.means.mins/maxs`),
//!   truncated; low bytes in the first texture, high bytes in the second (RGB = x, y, z);
//! - `quats.webp`: the normalised (w, x, y, z) quaternion made positive in its first
//!   largest component, the other three in order as bytes of `255·(q·√2·½ + ½)`
//!   (truncated) and alpha `252 +` that component's index;
//! - `scales.webp`: per axis, the index of the log-scale in a 256-entry codebook
//!   (`meta.scales.codebook`);
//! - `sh0.webp`: per channel, the index of `f_dc` in a 256-entry codebook
//!   (`meta.sh0.codebook`), and alpha `⌊255·sigmoid(opacity)⌋`;
//! - with SH above degree 0, `shN_labels.webp` (a 16-bit palette index, low byte in R,
//!   high in G) and `shN_centroids.webp`: the palette, `64·K` texels wide (K = higher
//!   coefficients per channel), one row per 64 entries, entry e's coefficient j at texel
//!   `(e mod 64)·K + j` of row `e / 64`, its RGB the indices of the three channels'
//!   values in a 256-entry codebook (`meta.shN.codebook`); `meta.shN.count` entries,
//!   `meta.shN.bands` the degree.
//!
//! The codebooks and the palette are ours (the format only fixes how they are read): a
//! 1D k-means with 256 entries for scales, colours and palette values, and a median-cut
//! palette (recursive splits of the SH vectors at the median of their widest dimension)
//! of splat-transform's size for the higher SH. Extra per-Gaussian properties are not
//! stored.

use crate::ply::compressed::morton_order;
use crate::{atomic, opacity_logit_of_byte, sigmoid, Error, Gaussians, Result};
use serde::{Deserialize, Serialize};
use std::io::{Cursor, Read, Write};
use std::path::Path;

/// Entries of each scalar codebook.
const CODEBOOK: usize = 256;
/// Lloyd iterations of the 1D k-means.
const KMEANS_ITERATIONS: usize = 12;
/// Palette entries per row of `shN_centroids.webp`.
const PALETTE_ROW: usize = 64;
/// Most Gaussians a file may declare per byte of the file: a real SOG takes several bytes
/// a Gaussian, so this only bounds what a short file can make the reader allocate.
const MAX_POINTS_PER_BYTE: u64 = 64;
/// The zip bundle's magic.
const ZIP_MAGIC: &[u8; 4] = b"PK\x03\x04";

/// `meta.json`, version 2.
#[derive(Serialize, Deserialize, Debug, Clone, PartialEq)]
#[serde(rename_all = "camelCase")]
pub struct Meta {
    /// 2 (version 1, with per-channel ranges instead of codebooks, has no field).
    pub version: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub asset: Option<serde_json::Value>,
    pub count: u64,
    pub means: Means,
    pub scales: Coded,
    pub quats: Files,
    pub sh0: Coded,
    #[serde(rename = "shN", default, skip_serializing_if = "Option::is_none")]
    pub sh_n: Option<ShN>,
}

#[derive(Serialize, Deserialize, Debug, Clone, PartialEq)]
pub struct Means {
    pub mins: [f64; 3],
    pub maxs: [f64; 3],
    pub files: Vec<String>,
}

#[derive(Serialize, Deserialize, Debug, Clone, PartialEq)]
pub struct Coded {
    pub codebook: Vec<f32>,
    pub files: Vec<String>,
}

#[derive(Serialize, Deserialize, Debug, Clone, PartialEq)]
pub struct Files {
    pub files: Vec<String>,
}

#[derive(Serialize, Deserialize, Debug, Clone, PartialEq)]
pub struct ShN {
    /// Palette entries.
    pub count: u64,
    /// SH degree (1 to 3).
    pub bands: u32,
    pub codebook: Vec<f32>,
    pub files: Vec<String>,
}

/// An RGBA texture.
struct Texture {
    width: usize,
    height: usize,
    rgba: Vec<u8>,
}

impl Texture {
    fn new(width: usize, height: usize) -> Texture {
        Texture { width, height, rgba: vec![0; width * height * 4] }
    }

    fn texel(&self, i: usize) -> &[u8] {
        &self.rgba[i * 4..i * 4 + 4]
    }

    fn lossless_webp(&self) -> Vec<u8> {
        let mut out = Vec::new();
        image_webp::WebPEncoder::new(&mut out)
            .encode(&self.rgba, self.width as u32, self.height as u32, image_webp::ColorType::Rgba8)
            .expect("encoding a texture in memory");
        out
    }
}

/// Width and height of the textures of `n` Gaussians (splat-transform's rule).
fn texture_size(n: usize) -> (usize, usize) {
    let width = ((n as f64).sqrt() / 4.0).ceil() as usize * 4;
    let height = (n as f64 / width.max(1) as f64 / 4.0).ceil() as usize * 4;
    (width.max(4), height.max(4))
}

/// `sign(v)·ln(|v| + 1)`, the transform of the centres before quantising.
fn log_transform(v: f64) -> f64 {
    v.signum() * (v.abs() + 1.0).ln()
}

/// The inverse of [`log_transform`].
fn inverse_log_transform(v: f64) -> f64 {
    v.signum() * (v.abs().exp() - 1.0)
}

/// A 256-entry codebook of `values` (1D k-means: Lloyd iterations from the quantiles,
/// over the sorted values, so clusters are runs) and each value's entry. The codebook
/// is ascending; a value's entry is the nearest.
fn codebook(values: &[f32]) -> (Vec<f32>, Vec<u8>) {
    let mut sorted: Vec<f32> = values.to_vec();
    sorted.sort_by(f32::total_cmp);
    let n = sorted.len();
    let mut centres: Vec<f64> = (0..CODEBOOK)
        .map(|k| sorted.get((2 * k + 1) * n / (2 * CODEBOOK)).map_or(0.0, |&v| v as f64))
        .collect();
    for _ in 0..KMEANS_ITERATIONS {
        let mut sums = vec![(0.0f64, 0usize); CODEBOOK];
        let mut k = 0;
        for &v in &sorted {
            while k + 1 < CODEBOOK && (v as f64) >= (centres[k] + centres[k + 1]) / 2.0 {
                k += 1;
            }
            sums[k].0 += v as f64;
            sums[k].1 += 1;
        }
        for (c, (s, m)) in centres.iter_mut().zip(&sums) {
            if *m > 0 {
                *c = s / *m as f64;
            }
        }
        centres.sort_by(f64::total_cmp);
    }
    let book: Vec<f32> = centres.iter().map(|&c| c as f32).collect();
    let labels = values.iter().map(|&v| nearest(&book, v)).collect();
    (book, labels)
}

/// The index of the entry of an ascending codebook nearest to `v`.
fn nearest(book: &[f32], v: f32) -> u8 {
    let k = book.partition_point(|&c| c < v);
    let best = match k {
        0 => 0,
        k if k == book.len() => k - 1,
        k if (v - book[k - 1]) <= (book[k] - v) => k - 1,
        k => k,
    };
    best as u8
}

/// The palette size for `n` Gaussians: splat-transform's
/// `min(64, 2^⌊log2(n / 1024)⌋)·1024`, at most `n`.
fn palette_size(n: usize) -> usize {
    let p = (n as f64 / 1024.0).log2().floor().exp2().min(64.0) * 1024.0;
    (p as usize).clamp(1, n.max(1))
}

/// A median-cut palette of the rows of `data` (`dim` values each): `leaves` entries
/// (fewer when there are fewer rows), each the mean of its rows, and each row's entry.
fn median_cut(data: &[f32], dim: usize, leaves: usize) -> (Vec<Vec<f32>>, Vec<u32>) {
    fn split(data: &[f32], dim: usize, idx: &mut [u32], leaves: usize, out: &mut (Vec<Vec<f32>>, Vec<u32>)) {
        let row = |i: u32| &data[i as usize * dim..(i as usize + 1) * dim];
        if leaves <= 1 || idx.len() <= 1 {
            let mut mean = vec![0.0f64; dim];
            idx.iter().for_each(|&i| row(i).iter().zip(&mut mean).for_each(|(v, m)| *m += *v as f64));
            let label = out.0.len() as u32;
            out.0.push(mean.iter().map(|m| (m / idx.len() as f64) as f32).collect());
            idx.iter().for_each(|&i| out.1[i as usize] = label);
            return;
        }
        let widest = (0..dim)
            .map(|d| {
                let (lo, hi) = idx.iter().fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &i| {
                    (lo.min(row(i)[d]), hi.max(row(i)[d]))
                });
                (hi - lo, d)
            })
            .fold((-1.0, 0), |a, b| if b.0 > a.0 { b } else { a })
            .1;
        let left = leaves / 2;
        let at = idx.len() * left / leaves;
        idx.select_nth_unstable_by(at, |&a, &b| row(a)[widest].total_cmp(&row(b)[widest]));
        let (a, b) = idx.split_at_mut(at);
        split(data, dim, a, left, out);
        split(data, dim, b, leaves - left, out);
    }
    let rows = data.len() / dim;
    let mut idx: Vec<u32> = (0..rows as u32).collect();
    let mut out = (Vec::new(), vec![0u32; rows]);
    split(data, dim, &mut idx, leaves.min(rows), &mut out);
    out
}

/// The `.sog` bundle's files: texture name → WebP bytes, and `meta.json`.
fn files(g: &Gaussians) -> (Meta, Vec<(&'static str, Vec<u8>)>) {
    let g = g.select(&morton_order(g));
    let n = g.len();
    let (w, h) = texture_size(n);
    let mut textures = Vec::new();
    let (means, lo, hi) = means_textures(&g, w, h);
    textures.push(("means_l.webp", lo));
    textures.push(("means_u.webp", hi));
    textures.push(("quats.webp", quats_texture(&g, w, h)));
    let (scales, tex) = coded_texture(g.log_scales.as_flattened(), 3, w, h, |_| 255);
    textures.push(("scales.webp", tex));
    let k = g.sh_coeffs() * 3;
    let dc: Vec<f32> = (0..n).flat_map(|i| g.sh[i * k..i * k + 3].iter().copied()).collect();
    let opacity = |i: usize| (sigmoid(g.opacity_logits[i]) as f64 * 255.0).clamp(0.0, 255.0) as u8;
    let (sh0, tex) = coded_texture(&dc, 3, w, h, opacity);
    textures.push(("sh0.webp", tex));
    let sh_n = (g.sh_degree > 0).then(|| {
        let (meta, centroids, labels) = sh_textures(&g, w, h);
        textures.push(("shN_centroids.webp", centroids));
        textures.push(("shN_labels.webp", labels));
        meta
    });
    let meta = Meta {
        version: Some(2),
        asset: Some(serde_json::json!({ "generator": "transsplat" })),
        count: n as u64,
        means,
        scales: Coded { codebook: scales, files: vec!["scales.webp".into()] },
        quats: Files { files: vec!["quats.webp".into()] },
        sh0: Coded { codebook: sh0, files: vec!["sh0.webp".into()] },
        sh_n,
    };
    (meta, textures.into_iter().map(|(name, t)| (name, t.lossless_webp())).collect())
}

/// The two 16-bit halves of the log-transformed centres (module doc).
fn means_textures(g: &Gaussians, w: usize, h: usize) -> (Means, Texture, Texture) {
    let mut mins = [f64::INFINITY; 3];
    let mut maxs = [f64::NEG_INFINITY; 3];
    for m in &g.means {
        for a in 0..3 {
            mins[a] = mins[a].min(log_transform(m[a] as f64));
            maxs[a] = maxs[a].max(log_transform(m[a] as f64));
        }
    }
    let (mut lo, mut hi) = (Texture::new(w, h), Texture::new(w, h));
    for (i, m) in g.means.iter().enumerate() {
        for a in 0..3 {
            let t = (log_transform(m[a] as f64) - mins[a]) / (maxs[a] - mins[a]);
            let q = if t.is_finite() { (65535.0 * t) as u16 } else { 0 };
            lo.rgba[i * 4 + a] = q as u8;
            hi.rgba[i * 4 + a] = (q >> 8) as u8;
        }
        lo.rgba[i * 4 + 3] = 255;
        hi.rgba[i * 4 + 3] = 255;
    }
    let files = vec!["means_l.webp".into(), "means_u.webp".into()];
    (Means { mins, maxs, files }, lo, hi)
}

/// The rotations, largest component dropped (module doc).
fn quats_texture(g: &Gaussians, w: usize, h: usize) -> Texture {
    let mut t = Texture::new(w, h);
    for (i, q) in g.rotations.iter().enumerate() {
        let q = q.map(|v| v as f64);
        let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
        let largest = (1..4).fold(0, |l, k| if q[k].abs() > q[l].abs() { k } else { l });
        let s = std::f64::consts::SQRT_2 / n * if q[largest] < 0.0 { -1.0 } else { 1.0 };
        let px = &mut t.rgba[i * 4..i * 4 + 4];
        for (slot, k) in (0..4).filter(|&k| k != largest).enumerate() {
            px[slot] = (255.0 * (q[k] * s * 0.5 + 0.5)) as u8;
        }
        px[3] = 252 + largest as u8;
    }
    t
}

/// A texture of codebook entries, `per` values a Gaussian in RGB and `alpha(i)` in A,
/// with its codebook.
fn coded_texture(
    values: &[f32],
    per: usize,
    w: usize,
    h: usize,
    alpha: impl Fn(usize) -> u8,
) -> (Vec<f32>, Texture) {
    let (book, labels) = codebook(values);
    let mut t = Texture::new(w, h);
    for (i, l) in labels.chunks_exact(per).enumerate() {
        t.rgba[i * 4..i * 4 + per].copy_from_slice(l);
        t.rgba[i * 4 + 3] = alpha(i);
    }
    (book, t)
}

/// The higher-SH palette, its codebook and textures (module doc).
fn sh_textures(g: &Gaussians, w: usize, h: usize) -> (ShN, Texture, Texture) {
    let k = g.sh_coeffs();
    let per = k - 1;
    // Rows channel-major, as splat-transform's f_rest_*: channel c, coefficient j.
    let rows: Vec<f32> = (0..g.len())
        .flat_map(|i| {
            let sh = g.sh_of(i);
            (0..3).flat_map(move |c| (1..k).map(move |j| sh[j * 3 + c]))
        })
        .collect();
    let (palette, labels) = median_cut(&rows, 3 * per, palette_size(g.len()));
    let (book, codes) = codebook(&palette.concat());
    let rows_tall = palette.len().div_ceil(PALETTE_ROW);
    let mut centroids = Texture::new(PALETTE_ROW * per, rows_tall);
    for (e, code) in codes.chunks_exact(3 * per).enumerate() {
        for j in 0..per {
            let at = ((e / PALETTE_ROW) * PALETTE_ROW * per + (e % PALETTE_ROW) * per + j) * 4;
            centroids.rgba[at..at + 4].copy_from_slice(&[code[j], code[per + j], code[2 * per + j], 255]);
        }
    }
    let mut label_tex = Texture::new(w, h);
    for (i, &l) in labels.iter().enumerate() {
        label_tex.rgba[i * 4..i * 4 + 4].copy_from_slice(&[l as u8, (l >> 8) as u8, 0, 255]);
    }
    let files = vec!["shN_centroids.webp".into(), "shN_labels.webp".into()];
    let meta = ShN { count: palette.len() as u64, bands: g.sh_degree, codebook: book, files };
    (meta, centroids, label_tex)
}

/// The `.sog` bytes of a scene: a zip of `meta.json` and the textures, stored (WebP is
/// already compressed), as splat-transform bundles them. Assumes `g.validate()` passes
/// and the scene is not empty.
pub fn to_bytes(g: &Gaussians) -> Vec<u8> {
    let (meta, textures) = files(g);
    bundle(&meta, textures)
}

/// The zip bundle of `meta` and the textures.
fn bundle(meta: &Meta, textures: Vec<(&str, Vec<u8>)>) -> Vec<u8> {
    let mut zip = zip::ZipWriter::new(Cursor::new(Vec::new()));
    let options = zip::write::SimpleFileOptions::default().compression_method(zip::CompressionMethod::Stored);
    let json = serde_json::to_vec(meta).expect("serialising meta.json in memory");
    for (name, bytes) in std::iter::once(("meta.json", json)).chain(textures) {
        zip.start_file(name, options).expect("writing a zip in memory");
        zip.write_all(&bytes).expect("writing a zip in memory");
    }
    zip.finish().expect("writing a zip in memory").into_inner()
}

/// Writes a scene atomically as `.sog` (refusing NaN or infinite parameters, scenes
/// without Gaussians and scenes past the 16-bit palette's reach of textures).
pub fn write(path: &Path, g: &Gaussians) -> Result<()> {
    g.check_writable(path)?;
    if g.is_empty() || g.len() > u32::MAX as usize / 4 {
        return Err(Error::format(path, format!("cannot write {} Gaussians as SOG", g.len())));
    }
    atomic::write_bytes(path, &to_bytes(g))
}

/// True when `bytes` start like a zip file (a `.sog` bundle).
pub fn looks_like(bytes: &[u8]) -> bool {
    bytes.starts_with(ZIP_MAGIC)
}

/// Parses `.sog` bytes (a zip bundle of `meta.json` and its textures); `path` names the
/// file in errors.
pub fn parse(bytes: &[u8], path: &Path) -> Result<Gaussians> {
    let err = |m: String| Error::format(path, format!("SOG: {m}"));
    let mut zip =
        zip::ZipArchive::new(Cursor::new(bytes)).map_err(|e| err(format!("not a valid zip bundle ({e})")))?;
    let mut load = |name: &str| -> std::result::Result<Vec<u8>, String> {
        let mut f = zip.by_name(name).map_err(|_| format!("the bundle has no {name}"))?;
        // Bounded: deflate expands at most 1032-fold; a stored entry is its size.
        let limit = f.size().min(f.compressed_size().saturating_mul(1032) + 64);
        let mut out = Vec::new();
        f.by_ref().take(limit + 1).read_to_end(&mut out).map_err(|e| format!("{name}: {e}"))?;
        if out.len() as u64 != f.size() {
            return Err(format!("{name} holds {} bytes, its entry says {}", out.len(), f.size()));
        }
        Ok(out)
    };
    let meta: Meta = serde_json::from_slice(&load("meta.json").map_err(err)?)
        .map_err(|e| err(format!("meta.json is invalid: {e}")))?;
    decode(&meta, bytes.len() as u64, &mut load).map_err(err)
}

/// The scene `meta` describes, its textures read through `load`; `size` is the file's
/// length, which bounds the count before anything is allocated.
fn decode(
    meta: &Meta,
    size: u64,
    load: &mut dyn FnMut(&str) -> std::result::Result<Vec<u8>, String>,
) -> std::result::Result<Gaussians, String> {
    match meta.version {
        Some(2) => {}
        None => return Err("meta.json has no version: SOG version 1 is not supported".into()),
        Some(v) => return Err(format!("meta.json version {v} is not supported (2)")),
    }
    let n = meta.count;
    if n == 0 || n > MAX_POINTS_PER_BYTE * size {
        return Err(format!("meta.json declares {n} Gaussians for a {size}-byte file"));
    }
    let n = n as usize;
    for (what, book) in [("scales", &meta.scales.codebook), ("sh0", &meta.sh0.codebook)] {
        if book.len() != CODEBOOK {
            return Err(format!(
                "meta.json's {what} codebook has {} entries; expected {CODEBOOK}",
                book.len()
            ));
        }
    }
    let mut texture = |files: &[String], k: usize, what: &str, texels: (u64, u64)| {
        let name = files.get(k).ok_or_else(|| format!("meta.json lists no texture {} for {what}", k + 1))?;
        decode_webp(&load(name)?, name, texels)
    };
    let per_gaussian = (n as u64, 4 * n as u64 + 4096);
    let lo = texture(&meta.means.files, 0, "means", per_gaussian)?;
    let hi = texture(&meta.means.files, 1, "means", per_gaussian)?;
    let quats = texture(&meta.quats.files, 0, "quats", per_gaussian)?;
    let scales = texture(&meta.scales.files, 0, "scales", per_gaussian)?;
    let sh0 = texture(&meta.sh0.files, 0, "sh0", per_gaussian)?;
    let degree = meta.sh_n.as_ref().map_or(0, |s| s.bands);
    if degree > 3 {
        return Err(format!("meta.json's shN has {degree} bands (1 to 3)"));
    }
    let mut g = Gaussians { sh_degree: degree, ..Default::default() };
    // An empty range (every centre equal on an axis) stores 0 and reads as the minimum.
    let span = |a: usize| match meta.means.maxs[a] - meta.means.mins[a] {
        0.0 => 1.0,
        s => s,
    };
    for i in 0..n {
        let (l, u) = (lo.texel(i), hi.texel(i));
        g.means.push(std::array::from_fn(|a| {
            let q = (l[a] as u16 | (u[a] as u16) << 8) as f64 / 65535.0;
            inverse_log_transform(meta.means.mins[a] + span(a) * q) as f32
        }));
        g.rotations.push(unpack_quat(quats.texel(i)).map_err(|m| format!("quats.webp texel {i}: {m}"))?);
        let s = scales.texel(i);
        g.log_scales.push([0, 1, 2].map(|a| meta.scales.codebook[s[a] as usize]));
        let c = sh0.texel(i);
        g.opacity_logits.push(opacity_logit_of_byte(c[3]));
        g.sh.extend([0, 1, 2].map(|a| meta.sh0.codebook[c[a] as usize]));
        g.sh.resize(g.sh.len() + (g.sh_coeffs() - 1) * 3, 0.0);
    }
    if let Some(s) = &meta.sh_n {
        let labels = texture(&s.files, 1, "shN", per_gaussian)?;
        let per = g.sh_coeffs() as u64 - 1;
        if s.count == 0 || s.count > 1 << 16 {
            return Err(format!("meta.json's shN has {} palette entries (1 to 65536)", s.count));
        }
        let centroids = texture(&s.files, 0, "shN", (1, PALETTE_ROW as u64 * per * (1 << 10)))?;
        read_sh_n(&mut g, s, &centroids, &labels)?;
    }
    Ok(g)
}

/// The inverse of the quats texture's code (module doc); an alpha outside 252..=255 is
/// an error.
fn unpack_quat(t: &[u8]) -> std::result::Result<[f32; 4], String> {
    let largest = t[3]
        .checked_sub(252)
        .filter(|&l| l < 4)
        .ok_or_else(|| format!("alpha {} is not 252 to 255", t[3]))?;
    let mut q = [0.0f64; 4];
    let mut slot = 0;
    for (k, v) in q.iter_mut().enumerate() {
        if k != largest as usize {
            *v = (t[slot] as f64 / 255.0 * 2.0 - 1.0) / std::f64::consts::SQRT_2;
            slot += 1;
        }
    }
    q[largest as usize] = (1.0 - q.iter().map(|v| v * v).sum::<f64>()).max(0.0).sqrt();
    Ok(q.map(|v| v as f32))
}

/// Fills the higher SH from the palette (module doc), checking the palette against
/// `meta.json`: its codebook, the centroid texture's width and rows, every label.
fn read_sh_n(
    g: &mut Gaussians,
    s: &ShN,
    centroids: &Texture,
    labels: &Texture,
) -> std::result::Result<(), String> {
    let per = g.sh_coeffs() - 1;
    if s.codebook.len() != CODEBOOK {
        return Err(format!(
            "meta.json's shN codebook has {} entries; expected {CODEBOOK}",
            s.codebook.len()
        ));
    }
    if centroids.width != PALETTE_ROW * per || (centroids.height as u64) * (PALETTE_ROW as u64) < s.count {
        return Err(format!(
            "{} is {}x{}; {} palette entries of degree {} need {}x{}",
            s.files[0],
            centroids.width,
            centroids.height,
            s.count,
            s.bands,
            PALETTE_ROW * per,
            s.count.div_ceil(PALETTE_ROW as u64)
        ));
    }
    let k = g.sh_coeffs() * 3;
    for i in 0..g.len() {
        let t = labels.texel(i);
        let e = t[0] as usize | (t[1] as usize) << 8;
        if e as u64 >= s.count {
            return Err(format!("{} texel {i} names palette entry {e} of {}", s.files[1], s.count));
        }
        for j in 0..per {
            let c = centroids.texel((e / PALETTE_ROW) * centroids.width + (e % PALETTE_ROW) * per + j);
            for (ch, &code) in c[..3].iter().enumerate() {
                g.sh[i * k + (j + 1) * 3 + ch] = s.codebook[code as usize];
            }
        }
    }
    Ok(())
}

/// A lossless (or lossy) WebP texture as RGBA, refused before decoding when its texel
/// count is outside `texels` (per-Gaussian textures: at least one texel a Gaussian, at
/// most four, plus a margin; a writer makes no other sizes).
fn decode_webp(bytes: &[u8], name: &str, texels: (u64, u64)) -> std::result::Result<Texture, String> {
    let mut d = image_webp::WebPDecoder::new(Cursor::new(bytes))
        .map_err(|e| format!("{name} is not a valid WebP image ({e})"))?;
    let (w, h) = d.dimensions();
    let have = w as u64 * h as u64;
    if have < texels.0 || have > texels.1 {
        return Err(format!(
            "{name} is {w}x{h} = {have} texels; meta.json's count needs {} to {}",
            texels.0, texels.1
        ));
    }
    let size = d.output_buffer_size().ok_or_else(|| format!("{name} is too large"))?;
    let mut buf = vec![0u8; size];
    d.read_image(&mut buf).map_err(|e| format!("{name}: {e}"))?;
    let rgba =
        if d.has_alpha() { buf } else { buf.chunks_exact(3).flat_map(|p| [p[0], p[1], p[2], 255]).collect() };
    Ok(Texture { width: w as usize, height: h as usize, rgba })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gaussians::random_scene;

    fn parse_t(bytes: &[u8]) -> std::result::Result<Gaussians, String> {
        parse(bytes, Path::new("t.sog")).map_err(|e| e.to_string())
    }

    #[test]
    fn round_trip_is_within_the_quantisation() {
        for degree in 0..=3 {
            let g = random_scene(3000, degree, 21);
            let order = morton_order(&g);
            let d = parse_t(&to_bytes(&g)).unwrap();
            let g = g.select(&order);
            assert_eq!((d.len(), d.sh_degree), (g.len(), degree));
            let k = g.sh_coeffs() * 3;
            let (mut scale_err, mut rest_err) = (0.0f64, 0.0f64);
            for i in 0..g.len() {
                for a in 0..3 {
                    // 16 bits of ln(|v| + 1) over [−ln 2, ln 2]: a step of 2.1e-5.
                    assert!((d.means[i][a] - g.means[i][a]).abs() < 5e-5, "centre {i}");
                    scale_err += (d.log_scales[i][a] - g.log_scales[i][a]).abs() as f64;
                }
                let q = g.rotations[i];
                let n = q.iter().map(|v| v * v).sum::<f32>().sqrt();
                let dot: f32 = q.iter().zip(&d.rotations[i]).map(|(a, b)| a / n * b).sum();
                assert!(dot.abs() > 0.999, "rotation {i}: {dot}");
                let o = (sigmoid(d.opacity_logits[i]) - sigmoid(g.opacity_logits[i])).abs();
                assert!(o <= 1.0 / 255.0 + 1e-6, "opacity {i}");
                for c in 0..3 {
                    assert!((d.sh[i * k + c] - g.sh[i * k + c]).abs() < 0.02, "DC {i}");
                }
                rest_err += (3..k).map(|j| (d.sh[i * k + j] - g.sh[i * k + j]).abs() as f64).sum::<f64>();
            }
            // 256 log-scale entries over [−6, −2): a mean error well under a step.
            assert!(scale_err / (3.0 * g.len() as f64) < 0.01, "log-scales {scale_err}");
            if degree > 0 {
                // A 2048-entry palette of 3000 random SH vectors: a coarse approximation.
                let mean = rest_err / ((k - 3) * g.len()) as f64;
                assert!(mean < 0.35, "degree {degree}: mean higher-SH error {mean}");
            }
        }
    }

    #[test]
    fn hand_computed_layout() {
        assert_eq!(texture_size(1), (4, 4));
        assert_eq!(texture_size(46416), (216, 216));
        assert_eq!(texture_size(17), (8, 4));
        assert_eq!(palette_size(46416), 32768);
        assert_eq!(palette_size(3000), 2048);
        assert_eq!(palette_size(100), 64);
        // The identity: w largest (tag 252), x, y, z zero → ⌊255·½⌋ = 127.
        let g = Gaussians {
            means: vec![[1.0, -1.0, 0.0]],
            log_scales: vec![[-3.0, -3.0, -3.0]],
            rotations: vec![[1.0, 0.0, 0.0, 0.0]],
            opacity_logits: vec![0.0],
            sh_degree: 0,
            sh: vec![0.5, 0.5, 0.5],
            ..Default::default()
        };
        let t = quats_texture(&g, 4, 4);
        assert_eq!(t.texel(0), &[127, 127, 127, 252]);
        assert!((unpack_quat(&[127, 127, 127, 252]).unwrap()[0] - 1.0).abs() < 2e-5);
        let (means, lo, hi) = means_textures(&g, 4, 4);
        assert_eq!(means.mins, [2f64.ln(), -(2f64.ln()), 0.0]);
        // One Gaussian: each range is empty and stores 0.
        assert_eq!((lo.texel(0), hi.texel(0)), (&[0, 0, 0, 255][..], &[0, 0, 0, 255][..]));
        let (book, labels) = codebook(&[1.0, 2.0, 3.0, 2.0]);
        assert_eq!((book.len(), book[nearest(&book, 2.2) as usize]), (256, book[labels[1] as usize]));
        assert_eq!(book[labels[2] as usize], 3.0);
        let d = parse_t(&to_bytes(&g)).unwrap();
        assert_eq!(d.means, vec![[1.0, -1.0, 0.0]]);
        assert_eq!(d.log_scales, g.log_scales);
        assert_eq!(d.sh, g.sh);
        // Opacity ½ → ⌊127.5⌋ = 127.
        assert_eq!(d.opacity_logits[0], opacity_logit_of_byte(127));
    }

    /// The bundle of `g` with its meta and files changed by `f`.
    fn edited(g: &Gaussians, f: impl FnOnce(&mut Meta, &mut Vec<(&'static str, Vec<u8>)>)) -> Vec<u8> {
        let (mut meta, mut textures) = files(g);
        f(&mut meta, &mut textures);
        bundle(&meta, textures)
    }

    #[test]
    fn bad_bundles_are_one_line_errors() {
        let g = random_scene(100, 1, 4);
        let small = Texture::new(4, 4).lossless_webp();
        let mut bad_tag = Texture::new(12, 12);
        bad_tag.rgba.iter_mut().for_each(|v| *v = 7);
        let bad_tag = bad_tag.lossless_webp();
        let cases: Vec<(Vec<u8>, &str)> = vec![
            (b"PK\x03\x04 not a zip".to_vec(), "not a valid zip bundle"),
            (edited(&g, |_, t| t.retain(|(n, _)| *n != "quats.webp")), "the bundle has no quats.webp"),
            (
                edited(&g, |m, _| m.count = 1000),
                "means_l.webp is 12x12 = 144 texels; meta.json's count needs 1000",
            ),
            (
                edited(&g, |m, _| m.scales.codebook.pop().map(|_| ()).unwrap()),
                "scales codebook has 255 entries",
            ),
            (edited(&g, |m, _| m.version = None), "SOG version 1 is not supported"),
            (edited(&g, |m, _| m.quats.files.clear()), "meta.json lists no texture 1 for quats"),
            (edited(&g, |m, _| m.sh_n.as_mut().unwrap().count = 3), "names palette entry"),
            (
                edited(&g, |m, _| m.sh_n.as_mut().unwrap().bands = 2),
                "shN_centroids.webp is 192x1; 64 palette entries of degree 2 need 512x1",
            ),
            (
                edited(&g, |_, t| t.iter_mut().find(|(n, _)| *n == "sh0.webp").unwrap().1 = small.clone()),
                "sh0.webp is 4x4 = 16 texels",
            ),
            (
                edited(&g, |_, t| {
                    t.iter_mut().find(|(n, _)| *n == "quats.webp").unwrap().1 = bad_tag.clone()
                }),
                "quats.webp texel 0: alpha 7",
            ),
            (
                edited(&g, |_, t| {
                    t.iter_mut().find(|(n, _)| *n == "scales.webp").unwrap().1 = b"RIFF".to_vec()
                }),
                "scales.webp is not a valid WebP",
            ),
            (edited(&g, |m, _| m.count = 1 << 40), "declares 1099511627776 Gaussians"),
        ];
        for (bytes, want) in cases {
            let e = parse_t(&bytes).unwrap_err();
            assert!(
                e.starts_with("t.sog: SOG: ") && e.contains(want) && !e.contains('\n'),
                "{e:?} lacks {want:?}"
            );
        }
    }
}
