//! The INRIA 3DGS PLY scene file.
//!
//! Reading accepts `ascii`, `binary_little_endian` and `binary_big_endian`, every PLY
//! scalar type (converted to `f32`), properties in any order, comments and `obj_info`
//! lines, and other elements before or after `vertex` (skipped). Required vertex
//! properties: `x y z f_dc_0..2 opacity scale_0..2 rot_0..3`; `nx ny nz` are ignored;
//! the SH degree (0 to 3) follows from the number of `f_rest_*` properties (0, 9, 24,
//! 45), which the file stores channel-major (all R coefficients, then G, then B).
//! Every other scalar vertex property is carried in [`Gaussians::extra`].
//!
//! Writing produces `binary_little_endian` float32 in the INRIA order
//! (`x y z nx ny nz f_dc_0..2 f_rest_0..K opacity scale_0..2 rot_0..3`) followed by
//! the extra properties, which the INRIA viewer, SuperSplat and PlayCanvas ignore.
//! Read, write, read is bit-exact.
//!
//! Robustness: the reader never allocates more per-Gaussian storage than the bytes
//! after the header can hold, whatever the header's counts say, and never panics.

use crate::{atomic, Error, Gaussians, Result};

pub mod compressed;
use std::io::Write;
use std::path::Path;

/// Options for [`read_with`].
#[derive(Clone, Copy, Debug, Default)]
pub struct ReadOptions {
    /// Drop Gaussians with a NaN or infinite parameter (or an all-zero rotation)
    /// instead of failing; [`read_with`] returns how many were dropped.
    pub drop_invalid: bool,
}

/// Reads a PLY scene; a NaN or infinite parameter is an error naming the Gaussian.
pub fn read(path: &Path) -> Result<Gaussians> {
    read_with(path, &ReadOptions::default()).map(|(g, _)| g)
}

/// Reads a PLY scene with options; returns the scene and the number of dropped Gaussians.
pub fn read_with(path: &Path, options: &ReadOptions) -> Result<(Gaussians, usize)> {
    let bytes = atomic::read(path)?;
    parse_with(&bytes, path, options)
}

/// Parses PLY bytes (`path` is used in error messages only); NaN or infinite values
/// are an error naming the first bad Gaussian and property.
pub fn parse(bytes: &[u8], path: &Path) -> Result<Gaussians> {
    parse_with(bytes, path, &ReadOptions::default()).map(|(g, _)| g)
}

/// Parses PLY bytes with options; returns the scene and the number of dropped Gaussians.
pub fn parse_with(bytes: &[u8], path: &Path, options: &ReadOptions) -> Result<(Gaussians, usize)> {
    let err = |m: String| Error::format(path, m);
    let header = parse_header(bytes).map_err(err)?;
    let (mut g, plan) = if compressed::is_compressed(&header) {
        (compressed::decode(bytes, &header).map_err(err)?, None)
    } else {
        let plan = Plan::new(&header).map_err(err)?;
        (read_body(bytes, &header, &plan).map_err(err)?, Some(plan))
    };
    if g.validate().is_err() {
        // Cannot happen: every row pushes the same number of values.
        return Err(err("internal error: inconsistent Gaussian arrays".into()));
    }
    let mut dropped = 0;
    if options.drop_invalid {
        let keep: Vec<bool> = (0..g.len()).map(|i| g.non_finite_at(i).is_none()).collect();
        dropped = keep.iter().filter(|k| !**k).count();
        if dropped > 0 {
            g.retain(&keep);
        }
    } else if let Some((i, what)) = g.first_non_finite() {
        return Err(err(format!(
            "Gaussian {i} (vertex {i}) has an invalid {what}: {} (use --drop-invalid to skip such Gaussians)",
            plan.as_ref().map_or_else(
                || "(decoded from the compressed layout)".to_string(),
                |p| describe_bad(&g, p, i)
            )
        )));
    }
    Ok((g, dropped))
}

/// Serialises a scene as a binary little-endian float32 INRIA PLY.
///
/// Extra property names are made safe (whitespace replaced, clashes with standard
/// names prefixed `extra_`). Panics if `g.validate()` fails (a programming error);
/// [`write()`] checks first and returns an error instead.
pub fn to_bytes(g: &Gaussians) -> Vec<u8> {
    let row = 4 * (17 + g.sh_coeffs().saturating_sub(1) * 3 + g.extra.width());
    let mut out = Vec::with_capacity(1024 + g.len() * row);
    if let Err(e) = write_to(&mut out, g) {
        panic!("ply::to_bytes: {e}");
    }
    out
}

/// Writes a scene atomically as a binary little-endian float32 INRIA PLY.
/// Refuses (before creating anything) a scene with NaN or infinite parameters.
pub fn write(path: &Path, g: &Gaussians) -> Result<()> {
    g.check_writable(path)?;
    atomic::write_with(path, |w| write_to(w, g))
}

// ---------------------------------------------------------------------------------
// Writing

fn standard_names(sh_degree: u32) -> Vec<String> {
    let rest = (crate::sh_coeffs(sh_degree) - 1) * 3;
    let mut names: Vec<String> = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    names.extend((0..rest).map(|j| format!("f_rest_{j}")));
    names.extend(
        ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
            .iter()
            .map(|s| s.to_string()),
    );
    names
}

/// Property names for the extras that are valid PLY tokens and clash with nothing.
fn safe_extra_names(g: &Gaussians) -> Vec<String> {
    let mut taken: std::collections::HashSet<String> = standard_names(3).into_iter().collect();
    let mut out = Vec::with_capacity(g.extra.width());
    for (k, name) in g.extra.names.iter().enumerate() {
        let mut s: String =
            name.chars().map(|c| if c.is_ascii_graphic() { c } else { '_' }).collect::<String>();
        if s.is_empty() {
            s = format!("extra_{k}");
        }
        while taken.contains(&s) || is_reserved(&s) {
            s = format!("extra_{s}");
        }
        taken.insert(s.clone());
        out.push(s);
    }
    out
}

/// Names that a reader would map to a standard property.
fn is_reserved(name: &str) -> bool {
    name.strip_prefix("f_rest_").is_some_and(|r| r.parse::<usize>().is_ok())
}

fn write_to(w: &mut dyn Write, g: &Gaussians) -> std::io::Result<()> {
    if let Err(m) = g.validate() {
        return Err(std::io::Error::new(std::io::ErrorKind::InvalidInput, m));
    }
    let n = g.len();
    let ncoef = g.sh_coeffs();
    let extra_names = safe_extra_names(g);
    let mut header = String::new();
    header.push_str("ply\nformat binary_little_endian 1.0\n");
    header.push_str(&format!("element vertex {n}\n"));
    for name in standard_names(g.sh_degree).iter().chain(&extra_names) {
        header.push_str(&format!("property float {name}\n"));
    }
    header.push_str("end_header\n");
    w.write_all(header.as_bytes())?;

    let width = g.extra.width();
    let mut row: Vec<f32> = Vec::with_capacity(17 + (ncoef - 1) * 3 + width);
    let mut buf: Vec<u8> = Vec::with_capacity(row.capacity() * 4);
    for i in 0..n {
        row.clear();
        row.extend_from_slice(&g.means[i]);
        row.extend_from_slice(&[0.0; 3]);
        let sh = g.sh_of(i);
        row.extend((0..3).map(|c| sh[c]));
        for c in 0..3 {
            row.extend((1..ncoef).map(|k| sh[k * 3 + c]));
        }
        row.push(g.opacity_logits[i]);
        row.extend_from_slice(&g.log_scales[i]);
        row.extend_from_slice(&g.rotations[i]);
        row.extend_from_slice(&g.extra.values[i * width..(i + 1) * width]);
        buf.clear();
        for v in &row {
            buf.extend_from_slice(&v.to_le_bytes());
        }
        w.write_all(&buf)?;
    }
    Ok(())
}

// ---------------------------------------------------------------------------------
// Header

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Format {
    Ascii,
    LittleEndian,
    BigEndian,
}

/// A PLY scalar property type (shared with other PLY readers, e.g. plain point clouds).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl Scalar {
    /// The type of a header name (`float`, `uchar`, `float64`, ...).
    pub fn parse(s: &str) -> Option<Self> {
        Some(match s {
            "char" | "int8" => Scalar::I8,
            "uchar" | "uint8" => Scalar::U8,
            "short" | "int16" => Scalar::I16,
            "ushort" | "uint16" => Scalar::U16,
            "int" | "int32" => Scalar::I32,
            "uint" | "uint32" => Scalar::U32,
            "float" | "float32" => Scalar::F32,
            "double" | "float64" => Scalar::F64,
            _ => return None,
        })
    }

    /// Bytes per value in binary formats.
    pub fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    fn is_float(self) -> bool {
        matches!(self, Scalar::F32 | Scalar::F64)
    }

    /// One binary value (little or big endian) as f32; NaN if `b` is too short.
    pub fn decode(self, b: &[u8], big: bool) -> f32 {
        decode(self, b, big)
    }
}

#[derive(Clone, Copy, Debug)]
enum Kind {
    Scalar(Scalar),
    List { count: Scalar, item: Scalar },
}

#[derive(Clone, Debug)]
struct Property {
    name: String,
    kind: Kind,
}

#[derive(Clone, Debug)]
struct Element {
    name: String,
    count: u64,
    props: Vec<Property>,
}

impl Element {
    /// Bytes per row when every property is a scalar.
    fn fixed_size(&self) -> Option<usize> {
        self.props
            .iter()
            .map(|p| match p.kind {
                Kind::Scalar(s) => Some(s.size()),
                Kind::List { .. } => None,
            })
            .sum()
    }

    /// Fewest bytes a binary row can take (lists empty).
    fn min_size(&self) -> usize {
        self.props
            .iter()
            .map(|p| match p.kind {
                Kind::Scalar(s) => s.size(),
                Kind::List { count, .. } => count.size(),
            })
            .sum()
    }
}

#[derive(Debug)]
struct Header {
    format: Format,
    elements: Vec<Element>,
    body: usize,
}

fn parse_header(bytes: &[u8]) -> std::result::Result<Header, String> {
    let magic_len = if bytes.starts_with(b"ply\n") {
        4
    } else if bytes.starts_with(b"ply\r\n") {
        5
    } else {
        return Err("not a PLY file (it does not start with the 'ply' magic line)".into());
    };
    let mut pos = magic_len;
    let mut format = None;
    let mut elements: Vec<Element> = Vec::new();
    let mut line_no = 1usize;
    loop {
        line_no += 1;
        let rest = &bytes[pos..];
        let Some(nl) = rest.iter().position(|&b| b == b'\n') else {
            return Err("truncated PLY header: no 'end_header' line".into());
        };
        let raw = &rest[..nl];
        pos += nl + 1;
        let raw = raw.strip_suffix(b"\r").unwrap_or(raw);
        let line = std::str::from_utf8(raw)
            .map_err(|_| format!("malformed PLY header: line {line_no} is not text"))?;
        let mut tok = line.split_ascii_whitespace();
        let Some(keyword) = tok.next() else { continue };
        let bad = |what: &str| format!("malformed PLY header line {line_no} ({what}): {line:?}");
        match keyword {
            "end_header" => break,
            "comment" | "obj_info" => {}
            "format" => {
                if format.is_some() {
                    return Err(bad("second format line"));
                }
                let f = tok.next().ok_or_else(|| bad("format without a name"))?;
                format = Some(match f {
                    "ascii" => Format::Ascii,
                    "binary_little_endian" => Format::LittleEndian,
                    "binary_big_endian" => Format::BigEndian,
                    other => {
                        return Err(format!(
                            "unknown PLY format {other:?} (expected ascii, binary_little_endian or binary_big_endian)"
                        ))
                    }
                });
            }
            "element" => {
                let name = tok.next().ok_or_else(|| bad("element without a name"))?;
                let count = tok
                    .next()
                    .and_then(|c| c.parse::<u64>().ok())
                    .ok_or_else(|| bad("element count is not a non-negative integer"))?;
                elements.push(Element { name: name.to_string(), count, props: Vec::new() });
            }
            "property" => {
                let el = elements.last_mut().ok_or_else(|| bad("property before any element"))?;
                let t = tok.next().ok_or_else(|| bad("property without a type"))?;
                let kind = if t == "list" {
                    let c = tok.next().and_then(Scalar::parse).ok_or_else(|| bad("bad list count type"))?;
                    let i = tok.next().and_then(Scalar::parse).ok_or_else(|| bad("bad list item type"))?;
                    if c.is_float() {
                        return Err(bad("list count type must be an integer type"));
                    }
                    Kind::List { count: c, item: i }
                } else {
                    Kind::Scalar(Scalar::parse(t).ok_or_else(|| bad("unknown property type"))?)
                };
                let name = tok.next().ok_or_else(|| bad("property without a name"))?;
                if el.props.iter().any(|p| p.name == name) {
                    return Err(bad("duplicate property name"));
                }
                el.props.push(Property { name: name.to_string(), kind });
            }
            _ => return Err(bad("unknown keyword")),
        }
    }
    let format = format.ok_or("malformed PLY header: no 'format' line")?;
    Ok(Header { format, elements, body: pos })
}

// ---------------------------------------------------------------------------------
// Mapping vertex properties to the Gaussians

/// Where each vertex property goes: indices into a row of scalar values.
struct Plan {
    vertex: usize,
    mean: [usize; 3],
    rot: [usize; 4],
    scale: [usize; 3],
    opacity: usize,
    /// Row index of each SH value in our `[coefficient][channel]` order.
    sh: Vec<usize>,
    sh_degree: u32,
    extra: Vec<usize>,
    extra_names: Vec<String>,
    /// PLY property name of each row slot (for messages).
    names: Vec<String>,
}

impl Plan {
    fn new(h: &Header) -> std::result::Result<Plan, String> {
        let mut vertices = h.elements.iter().enumerate().filter(|(_, e)| e.name == "vertex");
        let (vertex, el) = vertices.next().ok_or("PLY has no 'vertex' element")?;
        if vertices.next().is_some() {
            return Err("PLY has more than one 'vertex' element".into());
        }
        let find = |name: &str| -> std::result::Result<usize, String> {
            match el.props.iter().position(|p| p.name == name) {
                Some(i) => match el.props[i].kind {
                    Kind::Scalar(_) => Ok(i),
                    Kind::List { .. } => {
                        Err(format!("vertex property '{name}' is a list, expected a number"))
                    }
                },
                None => Err(format!("missing required vertex property '{name}'")),
            }
        };
        let mean = [find("x")?, find("y")?, find("z")?];
        let dc = [find("f_dc_0")?, find("f_dc_1")?, find("f_dc_2")?];
        let opacity = find("opacity")?;
        let scale = [find("scale_0")?, find("scale_1")?, find("scale_2")?];
        let rot = [find("rot_0")?, find("rot_1")?, find("rot_2")?, find("rot_3")?];

        let mut rest: Vec<(usize, usize)> = Vec::new();
        for (i, p) in el.props.iter().enumerate() {
            if let Some(j) = p.name.strip_prefix("f_rest_").and_then(|r| r.parse::<usize>().ok()) {
                if matches!(p.kind, Kind::List { .. }) {
                    return Err(format!("vertex property '{}' is a list, expected a number", p.name));
                }
                rest.push((j, i));
            }
        }
        rest.sort_unstable();
        let sh_degree = match rest.len() {
            0 => 0,
            9 => 1,
            24 => 2,
            45 => 3,
            k => {
                return Err(format!(
                    "PLY has {k} f_rest_* properties; expected 0, 9, 24 or 45 (SH degree 0 to 3)"
                ))
            }
        };
        if let Some((pos, _)) = rest.iter().enumerate().find(|(pos, (j, _))| pos != j) {
            return Err(format!(
                "f_rest_* properties are not numbered 0..{}: f_rest_{pos} is missing",
                rest.len()
            ));
        }
        let ncoef = crate::sh_coeffs(sh_degree);
        let per = ncoef - 1;
        let mut sh = Vec::with_capacity(ncoef * 3);
        sh.extend_from_slice(&dc);
        for k in 1..ncoef {
            for c in 0..3 {
                sh.push(rest[c * per + k - 1].1);
            }
        }

        let mut used = vec![false; el.props.len()];
        for &i in mean.iter().chain(&dc).chain(&scale).chain(&rot).chain(&[opacity]) {
            used[i] = true;
        }
        for &(_, i) in &rest {
            used[i] = true;
        }
        let mut extra = Vec::new();
        let mut extra_names = Vec::new();
        for (i, p) in el.props.iter().enumerate() {
            let normal = matches!(p.name.as_str(), "nx" | "ny" | "nz");
            if !used[i] && !normal && matches!(p.kind, Kind::Scalar(_)) {
                extra.push(i);
                extra_names.push(p.name.clone());
            }
        }
        let names = el.props.iter().map(|p| p.name.clone()).collect();
        Ok(Plan { vertex, mean, rot, scale, opacity, sh, sh_degree, extra, extra_names, names })
    }

    fn push_row(&self, g: &mut Gaussians, row: &[f32]) {
        let at = |i: usize| row.get(i).copied().unwrap_or(f32::NAN);
        g.means.push(self.mean.map(at));
        g.log_scales.push(self.scale.map(at));
        g.rotations.push(self.rot.map(at));
        g.opacity_logits.push(at(self.opacity));
        g.sh.extend(self.sh.iter().map(|&i| at(i)));
        g.extra.values.extend(self.extra.iter().map(|&i| at(i)));
    }

    fn reserve(&self, g: &mut Gaussians, n: usize) {
        g.means.reserve_exact(n);
        g.log_scales.reserve_exact(n);
        g.rotations.reserve_exact(n);
        g.opacity_logits.reserve_exact(n);
        g.sh.reserve_exact(n.saturating_mul(self.sh.len()));
        g.extra.values.reserve_exact(n.saturating_mul(self.extra.len()));
    }
}

/// The offending property of Gaussian `i`, e.g. `f_rest_7 = NaN`.
fn describe_bad(g: &Gaussians, plan: &Plan, i: usize) -> String {
    let name = |slot: usize| plan.names.get(slot).cloned().unwrap_or_default();
    let mut pairs: Vec<(String, f32)> = Vec::new();
    for k in 0..3 {
        pairs.push((name(plan.mean[k]), g.means[i][k]));
    }
    for k in 0..3 {
        pairs.push((name(plan.scale[k]), g.log_scales[i][k]));
    }
    for k in 0..4 {
        pairs.push((name(plan.rot[k]), g.rotations[i][k]));
    }
    pairs.push((name(plan.opacity), g.opacity_logits[i]));
    for (slot, v) in plan.sh.iter().zip(g.sh_of(i)) {
        pairs.push((name(*slot), *v));
    }
    let w = g.extra.width();
    for (k, n) in g.extra.names.iter().enumerate() {
        pairs.push((n.clone(), g.extra.values[i * w + k]));
    }
    match pairs.iter().find(|(_, v)| !v.is_finite()) {
        Some((n, v)) => format!("property '{n}' = {v}"),
        None => "rotation rot_0..rot_3 is all zero".to_string(),
    }
}

// ---------------------------------------------------------------------------------
// Body

/// A source of row values: binary bytes or ASCII tokens.
trait Source {
    fn scalar(&mut self, t: Scalar) -> Option<f32>;
    fn count(&mut self, t: Scalar) -> Option<usize>;
    fn skip_items(&mut self, t: Scalar, n: usize) -> Option<()>;
    fn remaining(&self) -> usize;
    /// Binary only: the next `n` rows of `stride` bytes as one slice, and whether
    /// values are big-endian.
    fn fixed_rows(&mut self, _stride: usize, _n: usize) -> Option<(&[u8], bool)> {
        None
    }
}

/// One scalar from exactly `t.size()` bytes (shorter input gives NaN; callers pass
/// exact slices).
fn decode(t: Scalar, b: &[u8], big: bool) -> f32 {
    fn arr<const N: usize>(b: &[u8], big: bool) -> Option<[u8; N]> {
        let mut a: [u8; N] = b.get(..N)?.try_into().ok()?;
        if big {
            a.reverse();
        }
        Some(a)
    }
    let v = match t {
        Scalar::F32 => return arr(b, big).map_or(f32::NAN, f32::from_le_bytes),
        Scalar::I8 => arr(b, big).map(|a| i8::from_le_bytes(a) as f32),
        Scalar::U8 => arr(b, big).map(|a| u8::from_le_bytes(a) as f32),
        Scalar::I16 => arr(b, big).map(|a| i16::from_le_bytes(a) as f32),
        Scalar::U16 => arr(b, big).map(|a| u16::from_le_bytes(a) as f32),
        Scalar::I32 => arr(b, big).map(|a| i32::from_le_bytes(a) as f32),
        Scalar::U32 => arr(b, big).map(|a| u32::from_le_bytes(a) as f32),
        Scalar::F64 => arr(b, big).map(|a| f64::from_le_bytes(a) as f32),
    };
    v.unwrap_or(f32::NAN)
}

struct Binary<'a> {
    bytes: &'a [u8],
    pos: usize,
    big: bool,
}

impl Binary<'_> {
    fn take<const N: usize>(&mut self) -> Option<[u8; N]> {
        let end = self.pos.checked_add(N)?;
        let mut a: [u8; N] = self.bytes.get(self.pos..end)?.try_into().ok()?;
        if self.big {
            a.reverse();
        }
        self.pos = end;
        Some(a)
    }

    fn value(&mut self, t: Scalar) -> Option<f64> {
        Some(match t {
            Scalar::I8 => i8::from_le_bytes(self.take()?) as f64,
            Scalar::U8 => u8::from_le_bytes(self.take()?) as f64,
            Scalar::I16 => i16::from_le_bytes(self.take()?) as f64,
            Scalar::U16 => u16::from_le_bytes(self.take()?) as f64,
            Scalar::I32 => i32::from_le_bytes(self.take()?) as f64,
            Scalar::U32 => u32::from_le_bytes(self.take()?) as f64,
            Scalar::F32 => f32::from_le_bytes(self.take()?) as f64,
            Scalar::F64 => f64::from_le_bytes(self.take()?),
        })
    }

    fn skip(&mut self, n: usize) -> Option<()> {
        let end = self.pos.checked_add(n).filter(|&e| e <= self.bytes.len())?;
        self.pos = end;
        Some(())
    }
}

impl Source for Binary<'_> {
    fn scalar(&mut self, t: Scalar) -> Option<f32> {
        match t {
            // Direct, so float32 values (including NaN payloads) survive bit-exactly.
            Scalar::F32 => Some(f32::from_le_bytes(self.take()?)),
            _ => self.value(t).map(|v| v as f32),
        }
    }
    fn count(&mut self, t: Scalar) -> Option<usize> {
        let v = self.value(t)?;
        (v >= 0.0).then_some(v as usize)
    }
    fn skip_items(&mut self, t: Scalar, n: usize) -> Option<()> {
        self.skip(n.checked_mul(t.size())?)
    }
    fn remaining(&self) -> usize {
        self.bytes.len().saturating_sub(self.pos)
    }
    fn fixed_rows(&mut self, stride: usize, n: usize) -> Option<(&[u8], bool)> {
        let len = stride.checked_mul(n)?;
        let start = self.pos;
        self.skip(len)?;
        Some((&self.bytes[start..start + len], self.big))
    }
}

struct Ascii<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl<'a> Ascii<'a> {
    fn token(&mut self) -> Option<&'a str> {
        let b = self.bytes;
        while self.pos < b.len() && b[self.pos].is_ascii_whitespace() {
            self.pos += 1;
        }
        let start = self.pos;
        while self.pos < b.len() && !b[self.pos].is_ascii_whitespace() {
            self.pos += 1;
        }
        if start == self.pos {
            return None;
        }
        std::str::from_utf8(&b[start..self.pos]).ok()
    }
}

impl Source for Ascii<'_> {
    fn scalar(&mut self, t: Scalar) -> Option<f32> {
        let s = self.token()?;
        match t {
            Scalar::F32 => s.parse::<f32>().ok(),
            Scalar::F64 => s.parse::<f64>().ok().map(|v| v as f32),
            _ => s.parse::<i64>().ok().map(|v| v as f32).or_else(|| s.parse::<f64>().ok().map(|v| v as f32)),
        }
    }
    fn count(&mut self, _t: Scalar) -> Option<usize> {
        self.token()?.parse::<usize>().ok()
    }
    fn skip_items(&mut self, _t: Scalar, n: usize) -> Option<()> {
        for _ in 0..n {
            self.token()?;
        }
        Some(())
    }
    fn remaining(&self) -> usize {
        self.bytes.len().saturating_sub(self.pos)
    }
}

/// Where the vertex rows go: one `f32` per property (a list property's slot is left
/// as it was), in header order.
trait RowSink {
    fn reserve(&mut self, rows: usize);
    fn push(&mut self, row: &[f32]);
}

/// The Gaussians a [`Plan`] maps the rows into.
struct GaussianSink<'a> {
    plan: &'a Plan,
    gaussians: Gaussians,
}

impl RowSink for GaussianSink<'_> {
    fn reserve(&mut self, rows: usize) {
        self.plan.reserve(&mut self.gaussians, rows);
    }
    fn push(&mut self, row: &[f32]) {
        self.plan.push_row(&mut self.gaussians, row);
    }
}

/// Every vertex row as it is.
impl RowSink for Vec<f32> {
    fn reserve(&mut self, rows: usize) {
        Vec::reserve(self, rows);
    }
    fn push(&mut self, row: &[f32]) {
        self.extend_from_slice(row);
    }
}

/// Reads the rows of element `vertex` into `sink`, skipping the elements before it.
fn read_rows(
    bytes: &[u8],
    h: &Header,
    vertex: usize,
    sink: &mut dyn RowSink,
) -> std::result::Result<(), String> {
    let body = bytes.get(h.body..).unwrap_or(&[]);
    match h.format {
        Format::Ascii => read_elements(&mut Ascii { bytes: body, pos: 0 }, h, vertex, 2, sink),
        Format::LittleEndian | Format::BigEndian => {
            let mut src = Binary { bytes: body, pos: 0, big: h.format == Format::BigEndian };
            read_elements(&mut src, h, vertex, 1, sink)
        }
    }
}

fn read_body(bytes: &[u8], h: &Header, plan: &Plan) -> std::result::Result<Gaussians, String> {
    let gaussians = Gaussians {
        sh_degree: plan.sh_degree,
        extra: crate::Extra { names: plan.extra_names.clone(), values: Vec::new() },
        ..Default::default()
    };
    let mut sink = GaussianSink { plan, gaussians };
    read_rows(bytes, h, plan.vertex, &mut sink)?;
    Ok(sink.gaussians)
}

/// The `vertex` element of any PLY file as a table: one row of `f32` per vertex, one
/// column per property (a list property's column is 0), for readers of other vertex
/// layouts (plain point clouds). The same header parser and bounds as the scene reader:
/// allocation is bounded by the file size whatever the header claims.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct VertexTable {
    /// Each column's property name and scalar type (`None` for a list property).
    pub columns: Vec<(String, Option<Scalar>)>,
    /// `rows × columns.len()` values, row-major.
    pub values: Vec<f32>,
}

impl VertexTable {
    /// Parses the `vertex` element of PLY `bytes` (`path` is named in errors).
    pub fn parse(bytes: &[u8], path: &Path) -> Result<VertexTable> {
        let err = |m: String| Error::format(path, m);
        let header = parse_header(bytes).map_err(err)?;
        let vertex = header
            .elements
            .iter()
            .position(|e| e.name == "vertex")
            .ok_or_else(|| err("PLY has no 'vertex' element".into()))?;
        let columns = header.elements[vertex]
            .props
            .iter()
            .map(|p| {
                let scalar = match p.kind {
                    Kind::Scalar(t) => Some(t),
                    Kind::List { .. } => None,
                };
                (p.name.clone(), scalar)
            })
            .collect();
        let mut values = Vec::new();
        read_rows(bytes, &header, vertex, &mut values).map_err(err)?;
        Ok(VertexTable { columns, values })
    }

    /// Number of vertices.
    pub fn rows(&self) -> usize {
        self.values.len() / self.columns.len().max(1)
    }

    /// The column of the first of `names` present as a scalar, with its type.
    pub fn column(&self, names: &[&str]) -> Option<(usize, Scalar)> {
        names.iter().find_map(|n| {
            self.columns.iter().position(|c| c.0 == *n).and_then(|k| self.columns[k].1.map(|t| (k, t)))
        })
    }

    /// Row `i`.
    pub fn row(&self, i: usize) -> &[f32] {
        let w = self.columns.len();
        &self.values[i * w..(i + 1) * w]
    }
}

/// Reads the elements up to and including `vertex`. `unit` is the fewest bytes one
/// value can take in this encoding (1 in binary for u8, 2 in ASCII for "0 ").
fn read_elements<S: Source>(
    src: &mut S,
    h: &Header,
    vertex: usize,
    unit: usize,
    sink: &mut dyn RowSink,
) -> std::result::Result<(), String> {
    let binary = unit == 1;
    for el in &h.elements[..vertex] {
        skip_element(src, el, binary)?;
    }
    let el = &h.elements[vertex];
    let n_props = el.props.len().max(1);
    let min_row = if binary { el.min_size() } else { n_props * unit }.max(1);
    let remaining = src.remaining();
    // ASCII: the last value needs no separator after it.
    let fits = if binary { remaining / min_row } else { (remaining + 1) / min_row };
    if el.count > fits as u64 {
        let need = match el.fixed_size() {
            Some(s) if binary => format!("{} bytes", el.count.saturating_mul(s as u64)),
            _ => format!("at least {} bytes", el.count.saturating_mul(min_row as u64)),
        };
        return Err(format!(
            "vertex count {} needs {need} but only {remaining} bytes follow the header (truncated file or wrong count)",
            el.count
        ));
    }
    // Bounded by the file size above.
    let n = el.count as usize;
    sink.reserve(n);
    let mut row = vec![0.0f32; el.props.len()];
    if let Some(stride) = el.fixed_size().filter(|_| binary) {
        // Fast path: fixed-size binary rows, already checked to fit.
        let mut cols = Vec::with_capacity(el.props.len());
        let mut off = 0;
        for p in &el.props {
            if let Kind::Scalar(t) = p.kind {
                cols.push((off, t));
                off += t.size();
            }
        }
        if let Some((rows, big)) = src.fixed_rows(stride, n) {
            for chunk in rows.chunks_exact(stride.max(1)) {
                for (slot, &(off, t)) in cols.iter().enumerate() {
                    row[slot] = decode(t, &chunk[off..], big);
                }
                sink.push(&row);
            }
            return Ok(());
        }
    }
    for i in 0..n {
        for (slot, p) in el.props.iter().enumerate() {
            let ok = match p.kind {
                Kind::Scalar(t) => src.scalar(t).map(|v| row[slot] = v),
                Kind::List { count, item } => src.count(count).and_then(|k| src.skip_items(item, k)),
            };
            if ok.is_none() {
                let what = if src.remaining() == 0 { "the file ends" } else { "the value is malformed" };
                return Err(format!(
                    "cannot read vertex {i} of {n}, property '{}': {what} (truncated file or wrong count)",
                    p.name
                ));
            }
        }
        sink.push(&row);
    }
    Ok(())
}

fn skip_element<S: Source>(src: &mut S, el: &Element, binary: bool) -> std::result::Result<(), String> {
    let fail = || {
        format!(
            "cannot skip element '{}' ({} rows) before the vertices: the file ends (truncated file or wrong count)",
            el.name, el.count
        )
    };
    if el.props.is_empty() || el.count == 0 {
        return Ok(());
    }
    if binary {
        if let Some(size) = el.fixed_size() {
            let total = el.count.checked_mul(size as u64).ok_or_else(fail)?;
            if total > src.remaining() as u64 {
                return Err(fail());
            }
            return src.skip_items(Scalar::U8, total as usize).ok_or_else(fail);
        }
    }
    // Each row consumes at least one byte or token, so this loop ends with the data.
    for _ in 0..el.count {
        for p in &el.props {
            let ok = match p.kind {
                Kind::Scalar(t) => src.scalar(t).map(|_| ()),
                Kind::List { count, item } => src.count(count).and_then(|k| src.skip_items(item, k)),
            };
            ok.ok_or_else(fail)?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests;
