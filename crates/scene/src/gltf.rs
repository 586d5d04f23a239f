//! glTF 2.0 binary files (`.glb`) holding Gaussian splats with the Khronos
//! `KHR_gaussian_splatting` extension (release candidate, 2026), read and written.
//!
//! One point primitive (`mode` 0) carries the splats as float32 vertex attributes
//! (extension README, "Ellipse Kernel › Attributes"):
//! - `POSITION`: the centre, with `min` / `max` (glTF 2.0, "Accessors Bounds");
//! - `KHR_gaussian_splatting:ROTATION`: the unit quaternion in glTF's (x, y, z, w) order;
//! - `KHR_gaussian_splatting:SCALE`: linear standard deviations, `exp(log σ)`;
//! - `KHR_gaussian_splatting:OPACITY`: opacity after the sigmoid, in [0, 1];
//! - `KHR_gaussian_splatting:SH_DEGREE_0_COEF_0` and `SH_DEGREE_l_COEF_n`: one RGB
//!   triple per coefficient, ordered m = −l..l within a degree. The extension's basis
//!   (real SH with the Condon–Shortley phase, "Lighting") is the INRIA renderer's, so
//!   the PLY's `f_dc_*` and `f_rest_*` map over unchanged apart from the axes below;
//! - `COLOR_0` (the fallback for viewers without the extension, "Fallback Behavior"):
//!   `clamp(SH_C0·f_dc + ½)` decoded from sRGB to linear, and the opacity, as
//!   normalised bytes. Not read back.
//!
//! **Axes.** glTF is right-handed with +Y up, the asset's front facing +Z and its left
//! +X (glTF 2.0, "Coordinate System and Units"), i.e. LUF; the INRIA PLY is RDF. The
//! extension asks converters to rotate pre-trained data into glTF's axes; the rotation
//! from RDF to LUF is a half turn about z: x and y change sign, the SH coefficients odd
//! in exactly one of x, y change sign, and the quaternion is multiplied on the left by
//! the turn's quaternion `k` (what splat-transform 2.7.1 does too). Reading undoes it
//! exactly (the products only permute and negate components).
//!
//! The writer keeps the Gaussians' order and drops extra properties; the reader accepts
//! the component types the extension allows for rotation, scale and opacity (float or
//! normalised integers), interleaved buffer views, and one splat primitive whose nodes
//! carry no transform.

use crate::{atomic, sigmoid, Error, Gaussians, Result, SH_C0};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;

const MAGIC: &[u8; 4] = b"glTF";
const CHUNK_JSON: u32 = 0x4E4F_534A;
const CHUNK_BIN: u32 = 0x004E_4942;
/// The extension's name, also the prefix of its attribute semantics.
pub const EXTENSION: &str = "KHR_gaussian_splatting";
const BYTE: u32 = 5120;
const UNSIGNED_BYTE: u32 = 5121;
const SHORT: u32 = 5122;
const UNSIGNED_SHORT: u32 = 5123;
const FLOAT: u32 = 5126;
const ARRAY_BUFFER: u32 = 34962;
const POINTS: u32 = 0;
/// glTF's default primitive mode (TRIANGLES) when `mode` is absent.
const DEFAULT_MODE: u32 = 4;

/// The glTF JSON document: the properties this crate writes and reads (glTF 2.0,
/// "Properties Reference"); any other property is ignored on reading.
#[derive(Serialize, Deserialize, Debug, Default, Clone, PartialEq)]
#[serde(rename_all = "camelCase")]
pub struct Document {
    pub asset: Asset,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub extensions_used: Vec<String>,
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub extensions_required: Vec<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scene: Option<usize>,
    #[serde(default)]
    pub scenes: Vec<SceneNodes>,
    #[serde(default)]
    pub nodes: Vec<Node>,
    #[serde(default)]
    pub meshes: Vec<Mesh>,
    #[serde(default)]
    pub accessors: Vec<Accessor>,
    #[serde(default)]
    pub buffer_views: Vec<BufferView>,
    #[serde(default)]
    pub buffers: Vec<Buffer>,
}

#[derive(Serialize, Deserialize, Debug, Default, Clone, PartialEq)]
#[serde(rename_all = "camelCase")]
pub struct Asset {
    pub version: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub generator: Option<String>,
}

#[derive(Serialize, Deserialize, Debug, Default, Clone, PartialEq)]
pub struct SceneNodes {
    #[serde(default)]
    pub nodes: Vec<usize>,
}

#[derive(Serialize, Deserialize, Debug, Default, Clone, PartialEq)]
pub struct Node {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mesh: Option<usize>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub matrix: Option<Vec<f64>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub translation: Option<Vec<f64>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rotation: Option<Vec<f64>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scale: Option<Vec<f64>>,
}

#[derive(Serialize, Deserialize, Debug, Default, Clone, PartialEq)]
pub struct Mesh {
    pub primitives: Vec<Primitive>,
}

#[derive(Serialize, Deserialize, Debug, Default, Clone, PartialEq)]
pub struct Primitive {
    pub attributes: BTreeMap<String, usize>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mode: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub extensions: Option<PrimitiveExtensions>,
}

#[derive(Serialize, Deserialize, Debug, Default, Clone, PartialEq)]
pub struct PrimitiveExtensions {
    #[serde(rename = "KHR_gaussian_splatting", default, skip_serializing_if = "Option::is_none")]
    pub gaussian_splatting: Option<Splatting>,
}

/// The extension object (extension README, "Extending Mesh Primitives").
#[derive(Serialize, Deserialize, Debug, Default, Clone, PartialEq)]
#[serde(rename_all = "camelCase")]
pub struct Splatting {
    pub kernel: String,
    pub color_space: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub projection: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sorting_method: Option<String>,
}

#[derive(Serialize, Deserialize, Debug, Default, Clone, PartialEq)]
#[serde(rename_all = "camelCase")]
pub struct Accessor {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub buffer_view: Option<usize>,
    #[serde(default)]
    pub byte_offset: u64,
    pub component_type: u32,
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub normalized: bool,
    pub count: u64,
    #[serde(rename = "type")]
    pub kind: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub min: Option<Vec<f64>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max: Option<Vec<f64>>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sparse: Option<serde_json::Value>,
}

#[derive(Serialize, Deserialize, Debug, Default, Clone, PartialEq)]
#[serde(rename_all = "camelCase")]
pub struct BufferView {
    pub buffer: usize,
    #[serde(default)]
    pub byte_offset: u64,
    pub byte_length: u64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub byte_stride: Option<u64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub target: Option<u32>,
}

#[derive(Serialize, Deserialize, Debug, Default, Clone, PartialEq)]
#[serde(rename_all = "camelCase")]
pub struct Buffer {
    pub byte_length: u64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub uri: Option<String>,
}

/// The semantic of an extension attribute.
fn semantic(name: &str) -> String {
    format!("{EXTENSION}:{name}")
}

/// The semantic of SH coefficient `j` (0 = DC, INRIA order) of a degree-`l` band:
/// `SH_DEGREE_l_COEF_n` with `n = j − l²` (extension README, "Spherical Harmonics
/// Attributes": coefficients from m = −l to l).
fn sh_semantic(j: usize) -> String {
    let l = (j as f64).sqrt() as usize;
    semantic(&format!("SH_DEGREE_{l}_COEF_{}", j - l * l))
}

/// The turn's quaternion `k` times `q`, both (w, x, y, z): the Gaussian's frame turned
/// half a turn about z with the scene.
fn turn_z(q: [f32; 4]) -> [f32; 4] {
    let [w, x, y, z] = q;
    [-z, -y, x, w]
}

/// The inverse of [`turn_z`]: `−k` times `q`.
fn unturn_z(q: [f32; 4]) -> [f32; 4] {
    let [w, x, y, z] = q;
    [z, y, -x, -w]
}

/// sRGB-encoded to linear (IEC 61966-2-1), for `COLOR_0`.
fn srgb_to_linear(c: f64) -> f64 {
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// One attribute's data in the binary chunk.
struct Segment {
    semantic: String,
    bytes: Vec<u8>,
    component_type: u32,
    kind: &'static str,
    normalized: bool,
    bounds: Option<(Vec<f64>, Vec<f64>)>,
}

impl Segment {
    fn floats(semantic: String, kind: &'static str, values: impl Iterator<Item = f32>) -> Segment {
        // `+ 0.0` turns −0 into +0, so that negated zeros do not show in the file.
        let bytes = values.flat_map(|v| (v + 0.0).to_le_bytes()).collect();
        Segment { semantic, bytes, component_type: FLOAT, kind, normalized: false, bounds: None }
    }
}

/// The per-component minimum and maximum of the centres (glTF 2.0, "Accessors
/// Bounds": required for `POSITION`, equal to the stored float32 values).
fn position_bounds(means: &[[f32; 3]]) -> (Vec<f64>, Vec<f64>) {
    let mut lo = [f32::INFINITY; 3];
    let mut hi = [f32::NEG_INFINITY; 3];
    for m in means {
        for a in 0..3 {
            lo[a] = lo[a].min(m[a] + 0.0);
            hi[a] = hi[a].max(m[a] + 0.0);
        }
    }
    (lo.map(f64::from).to_vec(), hi.map(f64::from).to_vec())
}

/// The attributes of a scene already in glTF's axes (extension README, "Ellipse Kernel
/// › Attributes" and "Fallback Behavior").
fn segments(g: &Gaussians) -> Vec<Segment> {
    let k = g.sh_coeffs();
    let mut position = Segment::floats("POSITION".into(), "VEC3", g.means.iter().flatten().copied());
    position.bounds = Some(position_bounds(&g.means));
    let colour = (0..g.len()).flat_map(|i| {
        let dc = &g.sh[i * k * 3..i * k * 3 + 3];
        let rgb = [0, 1, 2].map(|c| srgb_to_linear((SH_C0 as f64 * dc[c] as f64 + 0.5).clamp(0.0, 1.0)));
        let a = sigmoid(g.opacity_logits[i]) as f64;
        [rgb[0], rgb[1], rgb[2], a].map(|v| (v * 255.0).round().clamp(0.0, 255.0) as u8)
    });
    let colour = Segment {
        semantic: "COLOR_0".into(),
        bytes: colour.collect(),
        component_type: UNSIGNED_BYTE,
        kind: "VEC4",
        normalized: true,
        bounds: None,
    };
    let rotation = g.rotations.iter().flat_map(|q| {
        let n = q.iter().map(|v| (*v as f64).powi(2)).sum::<f64>().sqrt();
        let [w, x, y, z] = q.map(|v| (v as f64 / n) as f32);
        [x, y, z, w]
    });
    let scale = g.log_scales.iter().flatten().map(|s| s.exp());
    let opacity = g.opacity_logits.iter().map(|&o| sigmoid(o));
    let mut out = vec![
        position,
        colour,
        Segment::floats(semantic("ROTATION"), "VEC4", rotation),
        Segment::floats(semantic("SCALE"), "VEC3", scale),
        Segment::floats(semantic("OPACITY"), "SCALAR", opacity),
    ];
    for j in 0..k {
        let values = (0..g.len()).flat_map(|i| g.sh[(i * k + j) * 3..(i * k + j) * 3 + 3].iter().copied());
        out.push(Segment::floats(sh_semantic(j), "VEC3", values));
    }
    out
}

/// The document and binary chunk of a scene already in glTF's axes: one buffer view
/// and accessor per attribute, each starting on a 4-byte boundary (glTF 2.0, "Data
/// Alignment"), one node, one POINTS primitive with the extension object.
fn document(g: &Gaussians) -> (Document, Vec<u8>) {
    let mut doc = Document {
        asset: Asset { version: "2.0".into(), generator: Some("transsplat".into()) },
        extensions_used: vec![EXTENSION.into()],
        scene: Some(0),
        scenes: vec![SceneNodes { nodes: vec![0] }],
        nodes: vec![Node { mesh: Some(0), ..Default::default() }],
        ..Default::default()
    };
    let mut bin = Vec::new();
    let mut attributes = BTreeMap::new();
    for (i, s) in segments(g).into_iter().enumerate() {
        bin.resize(bin.len().next_multiple_of(4), 0);
        doc.buffer_views.push(BufferView {
            buffer: 0,
            byte_offset: bin.len() as u64,
            byte_length: s.bytes.len() as u64,
            byte_stride: None,
            target: Some(ARRAY_BUFFER),
        });
        bin.extend_from_slice(&s.bytes);
        let (min, max) = s.bounds.map_or((None, None), |(lo, hi)| (Some(lo), Some(hi)));
        doc.accessors.push(Accessor {
            buffer_view: Some(i),
            component_type: s.component_type,
            normalized: s.normalized,
            count: g.len() as u64,
            kind: s.kind.into(),
            min,
            max,
            ..Default::default()
        });
        attributes.insert(s.semantic, i);
    }
    bin.resize(bin.len().next_multiple_of(4), 0);
    doc.buffers.push(Buffer { byte_length: bin.len() as u64, uri: None });
    let splatting = Splatting {
        kernel: "ellipse".into(),
        color_space: "srgb_rec709_display".into(),
        projection: Some("perspective".into()),
        sorting_method: Some("cameraDistance".into()),
    };
    doc.meshes.push(Mesh {
        primitives: vec![Primitive {
            attributes,
            mode: Some(POINTS),
            extensions: Some(PrimitiveExtensions { gaussian_splatting: Some(splatting) }),
        }],
    });
    (doc, bin)
}

/// A GLB container of `json` and `bin` (glTF 2.0, "Binary glTF Layout": the 12-byte
/// header, then the JSON chunk padded with spaces and the BIN chunk padded with zeros,
/// each to 4 bytes).
fn container(json: &[u8], bin: &[u8]) -> Vec<u8> {
    let (jl, bl) = (json.len().next_multiple_of(4), bin.len().next_multiple_of(4));
    let total = 12 + 8 + jl + 8 + bl;
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(MAGIC);
    for word in [2, total as u32, jl as u32, CHUNK_JSON] {
        out.extend_from_slice(&word.to_le_bytes());
    }
    out.extend_from_slice(json);
    out.resize(20 + jl, b' ');
    out.extend_from_slice(&(bl as u32).to_le_bytes());
    out.extend_from_slice(&CHUNK_BIN.to_le_bytes());
    out.extend_from_slice(bin);
    out.resize(total, 0);
    out
}

/// The `.glb` bytes of a scene (turned into glTF's axes). Assumes `g.validate()` passes.
pub fn to_bytes(g: &Gaussians) -> Vec<u8> {
    let mut g = g.clone();
    g.half_turn_means_and_sh(2);
    g.rotations.iter_mut().for_each(|q| *q = turn_z(*q));
    let (doc, bin) = document(&g);
    let json = serde_json::to_vec(&doc).expect("serialising a document in memory");
    container(&json, &bin)
}

/// Writes a scene atomically as `.glb` (refusing NaN or infinite parameters, scenes
/// without Gaussians, and scenes whose binary chunk would pass glTF's 2³² byte limit).
pub fn write(path: &Path, g: &Gaussians) -> Result<()> {
    g.check_writable(path)?;
    let per = 12 + 4 + 16 + 12 + 4 + 12 * g.sh_coeffs();
    if g.is_empty() || (g.len() as u64) * per as u64 > u32::MAX as u64 - 4096 {
        return Err(Error::format(path, format!("cannot write {} Gaussians as glTF", g.len())));
    }
    atomic::write_bytes(path, &to_bytes(g))
}

/// True when `bytes` start with the GLB magic `glTF`.
pub fn looks_like(bytes: &[u8]) -> bool {
    bytes.starts_with(MAGIC)
}

/// Parses `.glb` bytes holding a `KHR_gaussian_splatting` primitive; `path` names the
/// file in errors. Values are converted back to the PLY's axes and parameterisation
/// (log-scales, logits); a NaN, infinite or out-of-range value comes back as a NaN or
/// infinite parameter for the caller to refuse or drop.
pub fn parse(bytes: &[u8], path: &Path) -> Result<Gaussians> {
    decode(bytes).map_err(|m| Error::format(path, format!("glTF: {m}")))
}

fn decode(bytes: &[u8]) -> std::result::Result<Gaussians, String> {
    let (json, bin) = chunks(bytes)?;
    let doc: Document =
        serde_json::from_slice(json).map_err(|e| format!("the JSON chunk is invalid: {e}"))?;
    if !doc.asset.version.starts_with("2.") {
        return Err(format!("asset version {:?}; expected 2.x", doc.asset.version));
    }
    let mesh = splat_mesh(&doc)?;
    let prim = &doc.meshes[mesh].primitives[0];
    let mode = prim.mode.unwrap_or(DEFAULT_MODE);
    if mode != POINTS {
        return Err(format!("the splat primitive's mode is {mode}; the extension requires POINTS (0)"));
    }
    let reader = Reader { doc: &doc, bin, attributes: &prim.attributes };
    let mut g = reader.gaussians()?;
    g.half_turn_means_and_sh(2);
    g.rotations.iter_mut().for_each(|q| *q = unturn_z(*q));
    Ok(g)
}

fn u32_at(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes(b[at..at + 4].try_into().expect("4 bytes"))
}

/// The JSON and BIN chunks of a GLB (glTF 2.0, "Binary glTF Layout › Header" and
/// "Chunks"): magic, version 2, the total length equal to the file's, then chunks whose
/// lengths stay inside the file; JSON first, BIN (optional) second, others ignored.
fn chunks(bytes: &[u8]) -> std::result::Result<(&[u8], Option<&[u8]>), String> {
    if bytes.len() < 12 || !looks_like(bytes) {
        return Err("not a GLB file (no glTF magic)".into());
    }
    let version = u32_at(bytes, 4);
    if version != 2 {
        return Err(format!("GLB container version {version}; expected 2"));
    }
    let length = u32_at(bytes, 8) as usize;
    if length != bytes.len() {
        return Err(format!("the header gives a length of {length} bytes; the file has {}", bytes.len()));
    }
    let mut at = 12;
    let mut found = Vec::new();
    while at < bytes.len() {
        if bytes.len() - at < 8 {
            return Err(format!("truncated chunk header at byte {at}"));
        }
        let (len, kind) = (u32_at(bytes, at) as usize, u32_at(bytes, at + 4));
        if len > bytes.len() - at - 8 {
            return Err(format!(
                "chunk at byte {at} claims {len} bytes; {} remain in the file",
                bytes.len() - at - 8
            ));
        }
        found.push((kind, &bytes[at + 8..at + 8 + len]));
        at += 8 + len;
    }
    match found.as_slice() {
        [(CHUNK_JSON, json), rest @ ..] => {
            Ok((json, rest.first().filter(|(k, _)| *k == CHUNK_BIN).map(|(_, b)| *b)))
        }
        _ => Err("the first chunk is not the JSON chunk".into()),
    }
}

/// The mesh holding the one splat primitive (a primitive with the extension object),
/// checking that no node instantiating it carries a transform (which would have to be
/// applied to the covariances and SH, "Ellipse Kernel › Dependencies on glTF").
fn splat_mesh(doc: &Document) -> std::result::Result<usize, String> {
    let splats: Vec<(usize, usize)> = doc
        .meshes
        .iter()
        .enumerate()
        .flat_map(|(m, mesh)| mesh.primitives.iter().enumerate().map(move |(p, prim)| (m, p, prim)))
        .filter(|(_, _, prim)| prim.extensions.as_ref().is_some_and(|e| e.gaussian_splatting.is_some()))
        .map(|(m, p, _)| (m, p))
        .collect();
    let (mesh, prim) = match splats.as_slice() {
        [] => {
            return Err(format!(
                "no mesh primitive has the {EXTENSION} extension (not a Gaussian-splat glTF)"
            ))
        }
        [one] => *one,
        more => return Err(format!("{} splat primitives; reading one is supported", more.len())),
    };
    if prim != 0 || doc.meshes[mesh].primitives.len() != 1 {
        return Err(format!("mesh {mesh} mixes the splat primitive with others; reading one is supported"));
    }
    for (i, node) in doc.nodes.iter().enumerate().filter(|(_, n)| n.mesh == Some(mesh)) {
        let identity = [1., 0., 0., 0., 0., 1., 0., 0., 0., 0., 1., 0., 0., 0., 0., 1.];
        let moved = node.matrix.as_ref().is_some_and(|m| m.as_slice() != identity)
            || node.translation.as_ref().is_some_and(|t| t.iter().any(|&v| v != 0.0))
            || node.rotation.as_ref().is_some_and(|r| r.as_slice() != [0., 0., 0., 1.])
            || node.scale.as_ref().is_some_and(|s| s.iter().any(|&v| v != 1.0));
        if moved {
            return Err(format!(
                "node {i} places the splats with a transform; only untransformed splats are read"
            ));
        }
    }
    Ok(mesh)
}

/// One accessor layout the extension allows for an attribute: component type and
/// whether the values are normalised integers.
type Layout = (u32, bool);
const F32_ONLY: &[Layout] = &[(FLOAT, false)];
const ROTATION_TYPES: &[Layout] = &[(FLOAT, false), (BYTE, true), (SHORT, true)];
const SCALE_TYPES: &[Layout] = &[
    (FLOAT, false),
    (UNSIGNED_BYTE, false),
    (UNSIGNED_BYTE, true),
    (UNSIGNED_SHORT, false),
    (UNSIGNED_SHORT, true),
];
const OPACITY_TYPES: &[Layout] = &[(FLOAT, false), (UNSIGNED_BYTE, true), (UNSIGNED_SHORT, true)];

struct Reader<'a> {
    doc: &'a Document,
    bin: Option<&'a [u8]>,
    attributes: &'a BTreeMap<String, usize>,
}

impl Reader<'_> {
    /// The scene of the splat primitive's attributes, in the file's axes.
    fn gaussians(&self) -> std::result::Result<Gaussians, String> {
        let means = self.read("POSITION", "VEC3", F32_ONLY)?;
        let n = means.len() / 3;
        let rot = self.read_n(&semantic("ROTATION"), "VEC4", ROTATION_TYPES, n)?;
        let scale = self.read_n(&semantic("SCALE"), "VEC3", SCALE_TYPES, n)?;
        let opacity = self.read_n(&semantic("OPACITY"), "SCALAR", OPACITY_TYPES, n)?;
        let degree = self.sh_degree()?;
        let k = crate::sh_coeffs(degree);
        let bands: Vec<Vec<f32>> = (0..k)
            .map(|j| self.read_n(&sh_semantic(j), "VEC3", F32_ONLY, n))
            .collect::<std::result::Result<_, _>>()?;
        let mut g = Gaussians { sh_degree: degree, ..Default::default() };
        g.means = means.chunks_exact(3).map(|m| [m[0], m[1], m[2]]).collect();
        g.rotations = rot.chunks_exact(4).map(|q| [q[3], q[0], q[1], q[2]]).collect();
        g.log_scales = scale.chunks_exact(3).map(|s| [0, 1, 2].map(|a| s[a].ln())).collect();
        g.opacity_logits = opacity.iter().map(|&o| logit(o)).collect();
        g.sh = Vec::with_capacity(n * k * 3);
        for i in 0..n {
            bands.iter().for_each(|b| g.sh.extend_from_slice(&b[i * 3..i * 3 + 3]));
        }
        Ok(g)
    }

    /// The SH degree the attributes define: every coefficient of each degree up to it
    /// and none above (extension README, "Spherical Harmonics Attributes").
    fn sh_degree(&self) -> std::result::Result<u32, String> {
        let has = |j: usize| self.attributes.contains_key(&sh_semantic(j));
        let degree = (1..=3u32).take_while(|&l| has(crate::sh_coeffs(l - 1))).last().unwrap_or(0);
        for j in 0..16 {
            if has(j) != (j < crate::sh_coeffs(degree)) {
                return Err(format!(
                    "SH degree {} is partly defined: {} is {}",
                    (j as f64).sqrt() as usize,
                    sh_semantic(j),
                    if has(j) { "present" } else { "missing" }
                ));
            }
        }
        Ok(degree)
    }

    /// [`Reader::read`] of an attribute that must have `n` elements.
    fn read_n(
        &self,
        name: &str,
        kind: &str,
        allowed: &[Layout],
        n: usize,
    ) -> std::result::Result<Vec<f32>, String> {
        let v = self.read(name, kind, allowed)?;
        let per = components(kind).expect("known type");
        if v.len() != n * per {
            return Err(format!("{name} has {} elements; POSITION has {n}", v.len() / per));
        }
        Ok(v)
    }

    /// The values of attribute `name` as floats (normalised integers mapped to [0, 1]
    /// or [−1, 1], glTF 2.0 "Animations › normalized" table), after checking its
    /// accessor against glTF 2.0 "Accessors" and "Data Alignment": its type, an allowed
    /// component type, a buffer view, and every element inside the view, the view inside
    /// the GLB-stored buffer and the buffer inside the BIN chunk.
    fn read(&self, name: &str, kind: &str, allowed: &[Layout]) -> std::result::Result<Vec<f32>, String> {
        let &index =
            self.attributes.get(name).ok_or_else(|| format!("the required attribute {name} is missing"))?;
        let a = self
            .doc
            .accessors
            .get(index)
            .ok_or_else(|| format!("{name}: accessor {index} does not exist"))?;
        if a.kind != kind {
            return Err(format!("{name}: accessor {index} is {}; expected {kind}", a.kind));
        }
        if !allowed.contains(&(a.component_type, a.normalized)) {
            return Err(format!(
                "{name}: component type {}{} is not allowed by the extension",
                a.component_type,
                if a.normalized { " (normalized)" } else { "" }
            ));
        }
        if a.sparse.is_some() {
            return Err(format!("{name}: sparse accessors are not supported"));
        }
        let vi = a.buffer_view.ok_or_else(|| format!("{name}: accessor {index} has no buffer view"))?;
        let view = self
            .doc
            .buffer_views
            .get(vi)
            .ok_or_else(|| format!("{name}: buffer view {vi} does not exist"))?;
        let data = self.view_bytes(name, vi, view)?;
        let size = component_size(a.component_type);
        let elem = (size * components(kind).expect("known type")) as u64;
        let stride = view.byte_stride.unwrap_or(elem);
        if stride < elem || stride % size as u64 != 0 {
            return Err(format!("{name}: byte stride {stride} does not fit {elem}-byte elements"));
        }
        let need = (a.count as u128)
            .checked_sub(1)
            .map_or(0, |c| a.byte_offset as u128 + c * stride as u128 + elem as u128);
        if need > data.len() as u128 {
            return Err(format!(
                "{name}: {} elements from byte {} need {need} bytes; buffer view {vi} has {}",
                a.count,
                a.byte_offset,
                data.len()
            ));
        }
        let mut out = Vec::with_capacity(a.count as usize * components(kind).expect("known type"));
        for e in 0..a.count as usize {
            let at = a.byte_offset as usize + e * stride as usize;
            for c in data[at..at + elem as usize].chunks_exact(size) {
                out.push(component(c, a.component_type, a.normalized));
            }
        }
        Ok(out)
    }

    /// The bytes of buffer view `vi`: inside buffer 0, which must be the GLB's BIN
    /// chunk (glTF 2.0, "GLB-stored Buffer": no `uri`, at most the chunk's length).
    fn view_bytes(&self, name: &str, vi: usize, view: &BufferView) -> std::result::Result<&[u8], String> {
        let buffer = self
            .doc
            .buffers
            .get(view.buffer)
            .ok_or_else(|| format!("{name}: buffer {} does not exist", view.buffer))?;
        if view.buffer != 0 || buffer.uri.is_some() {
            return Err(format!(
                "{name}: buffer {} is not the GLB's binary chunk (external buffers are not read)",
                view.buffer
            ));
        }
        let bin = self.bin.ok_or_else(|| format!("{name}: the file has no binary chunk"))?;
        if buffer.byte_length > bin.len() as u64 {
            return Err(format!(
                "buffer 0 claims {} bytes; the binary chunk has {}",
                buffer.byte_length,
                bin.len()
            ));
        }
        let end = view.byte_offset as u128 + view.byte_length as u128;
        if end > buffer.byte_length as u128 {
            return Err(format!(
                "{name}: buffer view {vi} (bytes {}..{end}) is outside buffer 0 ({} bytes)",
                view.byte_offset, buffer.byte_length
            ));
        }
        Ok(&bin[view.byte_offset as usize..end as usize])
    }
}

fn components(kind: &str) -> Option<usize> {
    match kind {
        "SCALAR" => Some(1),
        "VEC3" => Some(3),
        "VEC4" => Some(4),
        _ => None,
    }
}

fn component_size(component_type: u32) -> usize {
    match component_type {
        BYTE | UNSIGNED_BYTE => 1,
        SHORT | UNSIGNED_SHORT => 2,
        _ => 4,
    }
}

/// One component as a float (glTF 2.0, "Animations", the table of normalised integer
/// to float: `max(c / 127, −1)`, `c / 255`, `max(c / 32767, −1)`, `c / 65535`);
/// unnormalised unsigned integers (allowed for scale) are their value.
fn component(c: &[u8], component_type: u32, normalized: bool) -> f32 {
    let (v, max) = match component_type {
        BYTE => (c[0] as i8 as f32, 127.0),
        SHORT => (i16::from_le_bytes([c[0], c[1]]) as f32, 32767.0),
        UNSIGNED_BYTE => (c[0] as f32, 255.0),
        UNSIGNED_SHORT => (u16::from_le_bytes([c[0], c[1]]) as f32, 65535.0),
        _ => return f32::from_le_bytes(c.try_into().expect("4 bytes")),
    };
    if normalized {
        (v / max).max(-1.0)
    } else {
        v
    }
}

/// The logit of a stored opacity: NaN outside [0, 1] (invalid, extension README
/// "Attributes"); 0 and 1 kept finite at the ends of float32's resolution.
fn logit(o: f32) -> f32 {
    if !(0.0..=1.0).contains(&o) {
        return f32::NAN;
    }
    let o = (o as f64).clamp(f32::MIN_POSITIVE as f64, 1.0 - f32::EPSILON as f64 / 2.0);
    (o / (1.0 - o)).ln() as f32
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gaussians::random_scene;

    fn parse_t(bytes: &[u8]) -> std::result::Result<Gaussians, String> {
        parse(bytes, Path::new("t.glb")).map_err(|e| e.to_string())
    }

    /// The file with its document changed by `f` (the binary chunk kept).
    fn edited(bytes: &[u8], f: impl FnOnce(&mut Document, &mut Vec<u8>)) -> Vec<u8> {
        let (json, bin) = chunks(bytes).unwrap();
        let mut doc: Document = serde_json::from_slice(json).unwrap();
        let mut bin = bin.unwrap().to_vec();
        f(&mut doc, &mut bin);
        container(&serde_json::to_vec(&doc).unwrap(), &bin)
    }

    fn attribute(doc: &Document, name: &str) -> usize {
        doc.meshes[0].primitives[0].attributes[name]
    }

    #[test]
    fn round_trip_is_exact_for_centres_and_sh_and_float_close_for_the_rest() {
        for degree in 0..=3 {
            let mut g = random_scene(300, degree, 7);
            g.means[5] = [0.0, -0.0, 0.0];
            let d = parse_t(&to_bytes(&g)).unwrap();
            assert_eq!((d.len(), d.sh_degree), (g.len(), degree));
            assert_eq!(d.means, g.means, "centres are stored as float32");
            assert_eq!(d.sh, g.sh, "SH coefficients are stored as float32");
            for i in 0..g.len() {
                let q = g.rotations[i];
                let n = q.iter().map(|v| v * v).sum::<f32>().sqrt();
                for (r, v) in d.rotations[i].iter().zip(q) {
                    assert!((r - v / n).abs() < 1e-6, "rotation {i}");
                }
                for a in 0..3 {
                    assert!((d.log_scales[i][a] - g.log_scales[i][a]).abs() < 1e-5);
                }
                assert!((d.opacity_logits[i] - g.opacity_logits[i]).abs() < 1e-4);
            }
        }
    }

    #[test]
    fn one_gaussian_by_hand() {
        let g = Gaussians {
            means: vec![[1.0, 2.0, 3.0]],
            log_scales: vec![[0.0, 0.0, 0.0]],
            rotations: vec![[1.0, 0.0, 0.0, 0.0]],
            opacity_logits: vec![0.0],
            sh_degree: 0,
            sh: vec![0.0, 0.0, 0.0],
            ..Default::default()
        };
        let b = to_bytes(&g);
        assert_eq!(&b[..8], b"glTF\x02\x00\x00\x00");
        assert_eq!(u32_at(&b, 8) as usize, b.len());
        let jl = u32_at(&b, 12) as usize;
        assert_eq!((jl % 4, u32_at(&b, 16)), (0, 0x4E4F534A));
        let doc: Document = serde_json::from_slice(&b[20..20 + jl]).unwrap();
        assert_eq!(doc.extensions_used, [EXTENSION]);
        let prim = &doc.meshes[0].primitives[0];
        assert_eq!(prim.mode, Some(0));
        let ext = prim.extensions.as_ref().unwrap().gaussian_splatting.as_ref().unwrap();
        assert_eq!((ext.kernel.as_str(), ext.color_space.as_str()), ("ellipse", "srgb_rec709_display"));
        let pos = &doc.accessors[attribute(&doc, "POSITION")];
        // (1, 2, 3) turned half a turn about z: (−1, −2, 3).
        assert_eq!(
            (pos.min.as_deref(), pos.max.as_deref()),
            (Some(&[-1.0, -2.0, 3.0][..]), Some(&[-1.0, -2.0, 3.0][..]))
        );
        assert_eq!((u32_at(&b, 20 + jl), u32_at(&b, 24 + jl)), (60, 0x004E4942));
        let bin = &b[28 + jl..];
        let f = |at: usize| f32::from_le_bytes(bin[at..at + 4].try_into().unwrap());
        // POSITION at 0, COLOR_0 at 12, ROTATION at 16, SCALE at 32, OPACITY at 44, SH at 48.
        assert_eq!([f(0), f(4), f(8)], [-1.0, -2.0, 3.0]);
        // DC 0 → colour ½ → linear ((0.5 + 0.055) / 1.055)^2.4 = 0.2140 → 55; opacity ½ → 128.
        assert_eq!(&bin[12..16], &[55, 55, 55, 128]);
        // The identity turned half a turn about z: k = (x 0, y 0, z 1, w 0).
        assert_eq!([f(16), f(20), f(24), f(28)], [0.0, 0.0, 1.0, 0.0]);
        assert_eq!(bin[16..20], [0, 0, 0, 0], "no negative zero");
        assert_eq!([f(32), f(36), f(40), f(44)], [1.0, 1.0, 1.0, 0.5]);
        assert_eq!([f(48), f(52), f(56)], [0.0; 3]);
        let names: Vec<&str> = prim.attributes.keys().map(String::as_str).collect();
        assert_eq!(
            names,
            [
                "COLOR_0",
                "KHR_gaussian_splatting:OPACITY",
                "KHR_gaussian_splatting:ROTATION",
                "KHR_gaussian_splatting:SCALE",
                "KHR_gaussian_splatting:SH_DEGREE_0_COEF_0",
                "POSITION"
            ]
        );
        assert_eq!(parse_t(&b).unwrap(), g);
    }

    #[test]
    fn sh_attributes_are_named_by_degree_and_order() {
        assert_eq!(sh_semantic(0), "KHR_gaussian_splatting:SH_DEGREE_0_COEF_0");
        assert_eq!(sh_semantic(3), "KHR_gaussian_splatting:SH_DEGREE_1_COEF_2");
        assert_eq!(sh_semantic(4), "KHR_gaussian_splatting:SH_DEGREE_2_COEF_0");
        assert_eq!(sh_semantic(15), "KHR_gaussian_splatting:SH_DEGREE_3_COEF_6");
        // The half turn about z: a degree-1 coefficient along y (m = −1) changes sign,
        // along z (m = 0) does not.
        let mut g = random_scene(1, 1, 3);
        let before = g.sh.clone();
        g.half_turn_means_and_sh(2);
        assert_eq!((g.sh[3], g.sh[6], g.sh[9]), (-before[3], before[6], -before[9]));
        assert_eq!(unturn_z(turn_z([0.1, 0.2, 0.3, 0.4])), [0.1, 0.2, 0.3, 0.4]);
    }

    #[test]
    fn normalised_integer_attributes_are_read() {
        let g = random_scene(3, 0, 5);
        let b = edited(&to_bytes(&g), |doc, bin| {
            // Opacity as normalised unsigned bytes: 0, 255, 51 (0.2) in a new view.
            bin.extend_from_slice(&[0, 255, 51, 0]);
            doc.buffer_views.push(BufferView {
                buffer: 0,
                byte_offset: bin.len() as u64 - 4,
                byte_length: 3,
                ..Default::default()
            });
            doc.buffers[0].byte_length = bin.len() as u64;
            let a = attribute(doc, "KHR_gaussian_splatting:OPACITY");
            doc.accessors[a] = Accessor {
                buffer_view: Some(doc.buffer_views.len() - 1),
                component_type: UNSIGNED_BYTE,
                normalized: true,
                count: 3,
                kind: "SCALAR".into(),
                ..Default::default()
            };
        });
        let d = parse_t(&b).unwrap();
        let o: Vec<f32> = d.opacity_logits.iter().map(|&l| sigmoid(l)).collect();
        assert!(o[0] < 1e-30 && o[1] > 0.9999 && (o[2] - 0.2).abs() < 1e-6, "{o:?}");
        assert!(d.opacity_logits.iter().all(|l| l.is_finite()));
    }

    #[test]
    fn bad_files_are_one_line_errors() {
        let good = to_bytes(&random_scene(10, 1, 2));
        let cases: Vec<(Vec<u8>, &str)> = vec![
            (b"ply\nformat binary_little_endian 1.0\n".to_vec(), "not a GLB file"),
            (good[..good.len() - 4].to_vec(), "the header gives a length"),
            (
                {
                    let mut b = good.clone();
                    b[12..16].copy_from_slice(&u32::MAX.to_le_bytes());
                    b
                },
                "claims 4294967295 bytes",
            ),
            (
                edited(&good, |d, _| d.meshes[0].primitives[0].extensions = None),
                "no mesh primitive has the KHR_gaussian_splatting",
            ),
            (edited(&good, |d, _| d.meshes[0].primitives[0].mode = None), "mode is 4"),
            (
                edited(&good, |d, _| {
                    d.meshes[0].primitives[0].attributes.remove("KHR_gaussian_splatting:SCALE");
                }),
                "required attribute KHR_gaussian_splatting:SCALE is missing",
            ),
            (
                edited(&good, |d, _| {
                    d.meshes[0].primitives[0].attributes.insert("POSITION".into(), 99);
                }),
                "accessor 99 does not exist",
            ),
            (
                edited(&good, |d, _| {
                    let a = attribute(d, "KHR_gaussian_splatting:ROTATION");
                    d.buffer_views[a].byte_length -= 4;
                }),
                "need 160 bytes; buffer view 2 has 156",
            ),
            (
                edited(&good, |d, _| {
                    let a = attribute(d, "KHR_gaussian_splatting:OPACITY");
                    d.accessors[a].count = 9;
                }),
                "OPACITY has 9 elements; POSITION has 10",
            ),
            (
                edited(&good, |d, _| {
                    let a = attribute(d, "KHR_gaussian_splatting:OPACITY");
                    d.accessors[a].count = 1 << 40;
                }),
                "1099511627776 elements from byte 0 need",
            ),
            (edited(&good, |d, _| d.buffers[0].byte_length += 4), "buffer 0 claims"),
            (
                edited(&good, |d, _| {
                    d.meshes[0].primitives[0].attributes.remove("KHR_gaussian_splatting:SH_DEGREE_1_COEF_1");
                }),
                "SH degree 1 is partly defined",
            ),
            (
                edited(&good, |d, _| d.nodes[0].translation = Some(vec![1.0, 0.0, 0.0])),
                "node 0 places the splats",
            ),
            (
                edited(&good, |d, _| {
                    let a = attribute(d, "POSITION");
                    d.accessors[a].kind = "VEC4".into();
                }),
                "POSITION: accessor 0 is VEC4; expected VEC3",
            ),
            (edited(&good, |d, _| d.buffers[0].uri = Some("x.bin".into())), "external buffers"),
            (container(b"{\"asset\": 1}", &[]), "the JSON chunk is invalid"),
        ];
        for (bytes, want) in cases {
            let e = parse_t(&bytes).unwrap_err();
            assert!(
                e.starts_with("t.glb: glTF: ") && e.contains(want) && !e.contains('\n'),
                "{e:?} lacks {want:?}"
            );
        }
    }

    #[test]
    fn invalid_values_are_refused_or_dropped_through_read_with() {
        let mut g = random_scene(4, 0, 9);
        g.log_scales[2] = [0.0; 3];
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.glb");
        // A negative linear scale (spec: MUST NOT be negative) in Gaussian 2.
        let b = edited(&to_bytes(&g), |d, bin| {
            let at =
                d.buffer_views[attribute(d, "KHR_gaussian_splatting:SCALE")].byte_offset as usize + 2 * 12;
            bin[at..at + 4].copy_from_slice(&(-1.0f32).to_le_bytes());
        });
        std::fs::write(&path, b).unwrap();
        let e = crate::formats::read(&path).unwrap_err().to_string();
        assert!(e.contains("s.glb") && e.contains("Gaussian 2 has an invalid scale"), "{e}");
        let options = crate::formats::ReadOptions { drop_invalid: true, ..Default::default() };
        let (d, dropped) = crate::formats::read_with(&path, &options).unwrap();
        assert_eq!((d.len(), dropped), (3, 1));
    }
}
