//! numpy `.npy` (format versions 1.0 to 3.0): read any little- or big-endian
//! float or integer array as `f32`, write `float32` C-order arrays.

use crate::{atomic, Error, Result};
use std::path::Path;

/// A dense array: `data.len() == shape.iter().product()`, C order.
#[derive(Clone, Debug, PartialEq)]
pub struct Array {
    pub shape: Vec<usize>,
    pub data: Vec<f32>,
}

impl Array {
    /// A new array; panics if `data` does not fit `shape`.
    pub fn new(shape: Vec<usize>, data: Vec<f32>) -> Self {
        assert_eq!(shape.iter().product::<usize>(), data.len(), "npy shape does not fit data");
        Array { shape, data }
    }
}

const MAGIC: &[u8] = b"\x93NUMPY";

/// Parses `.npy` bytes; `path` is only used in error messages.
pub fn parse(bytes: &[u8], path: &Path) -> Result<Array> {
    let err = |m: String| Error::format(path, m);
    if bytes.len() < 10 || &bytes[..6] != MAGIC {
        return Err(err("not a .npy file (bad magic)".into()));
    }
    let major = bytes[6];
    let (hlen, start): (usize, usize) = match major {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 => {
            if bytes.len() < 12 {
                return Err(err("truncated .npy header".into()));
            }
            (u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize, 12)
        }
        v => return Err(err(format!("unsupported .npy format version {v}"))),
    };
    let end = start.checked_add(hlen).filter(|&e| e <= bytes.len());
    let end = end.ok_or_else(|| err("truncated .npy header".into()))?;
    let header = std::str::from_utf8(&bytes[start..end]).map_err(|_| err("non-UTF-8 .npy header".into()))?;
    let descr = dict_value(header, "descr").ok_or_else(|| err("header has no 'descr'".into()))?;
    let descr = descr.trim_matches(|c| c == '\'' || c == '"');
    let fortran =
        dict_value(header, "fortran_order").ok_or_else(|| err("header has no 'fortran_order'".into()))?;
    let shape_s = dict_value(header, "shape").ok_or_else(|| err("header has no 'shape'".into()))?;
    let shape: Vec<usize> = shape_s
        .trim_matches(|c| c == '(' || c == ')')
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| s.parse::<usize>().map_err(|_| err(format!("bad shape {shape_s}"))))
        .collect::<Result<_>>()?;
    let count = shape
        .iter()
        .try_fold(1usize, |a, &d| a.checked_mul(d))
        .ok_or_else(|| err(format!("shape {shape_s} overflows")))?;
    let (endian, kind, size) = parse_descr(descr).ok_or_else(|| err(format!("unsupported dtype {descr}")))?;
    let payload = &bytes[end..];
    let need = count.checked_mul(size).ok_or_else(|| err("array too large".into()))?;
    if payload.len() < need {
        return Err(err(format!(
            "data truncated: shape {shape:?} needs {need} bytes, file has {}",
            payload.len()
        )));
    }
    let mut data: Vec<f32> = payload[..need]
        .chunks_exact(size)
        .map(|c| {
            let mut b = [0u8; 8];
            b[..size].copy_from_slice(c);
            if endian == '>' {
                b[..size].reverse();
            }
            match (kind, size) {
                ('f', 4) => f32::from_le_bytes([b[0], b[1], b[2], b[3]]),
                ('f', 8) => f64::from_le_bytes(b) as f32,
                ('f', 2) => half_to_f32(u16::from_le_bytes([b[0], b[1]])),
                ('i', 1) => b[0] as i8 as f32,
                ('i', 2) => i16::from_le_bytes([b[0], b[1]]) as f32,
                ('i', 4) => i32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f32,
                ('i', 8) => i64::from_le_bytes(b) as f32,
                ('u', 1) | ('b', 1) => b[0] as f32,
                ('u', 2) => u16::from_le_bytes([b[0], b[1]]) as f32,
                ('u', 4) => u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as f32,
                ('u', 8) => u64::from_le_bytes(b) as f32,
                _ => unreachable!(),
            }
        })
        .collect();
    if fortran.trim() == "True" && shape.len() > 1 {
        data = fortran_to_c(&data, &shape);
    }
    Ok(Array { shape, data })
}

/// Reads a `.npy` file.
pub fn read(path: &Path) -> Result<Array> {
    parse(&atomic::read(path)?, path)
}

/// Serialises a float32 C-order `.npy` (format 1.0).
pub fn to_bytes(shape: &[usize], data: &[f32]) -> Vec<u8> {
    assert_eq!(shape.iter().product::<usize>(), data.len());
    let shape_s = match shape.len() {
        1 => format!("({},)", shape[0]),
        _ => format!("({})", shape.iter().map(|d| d.to_string()).collect::<Vec<_>>().join(", ")),
    };
    let mut header = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': {shape_s}, }}");
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut out = Vec::with_capacity(10 + header.len() + data.len() * 4);
    out.extend_from_slice(MAGIC);
    out.extend_from_slice(&[1, 0]);
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    for v in data {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

/// Writes a float32 `.npy` atomically.
pub fn write(path: &Path, shape: &[usize], data: &[f32]) -> Result<()> {
    atomic::write_bytes(path, &to_bytes(shape, data))
}

fn dict_value<'a>(header: &'a str, key: &str) -> Option<&'a str> {
    let k1 = format!("'{key}'");
    let k2 = format!("\"{key}\"");
    let pos = header.find(&k1).map(|p| p + k1.len()).or_else(|| header.find(&k2).map(|p| p + k2.len()))?;
    let rest = header[pos..].trim_start().strip_prefix(':')?.trim_start();
    let end = if rest.starts_with('(') { rest.find(')')? + 1 } else { rest.find([',', '}'])? };
    Some(rest[..end].trim())
}

fn parse_descr(d: &str) -> Option<(char, char, usize)> {
    let mut chars = d.chars();
    let first = chars.next()?;
    let (endian, rest) =
        if matches!(first, '<' | '>' | '|' | '=') { (first, chars.as_str()) } else { ('<', d) };
    let endian = if endian == '>' { '>' } else { '<' };
    let kind = rest.chars().next()?;
    let size: usize = rest[kind.len_utf8()..].parse().ok()?;
    let ok = matches!((kind, size), ('f', 2 | 4 | 8) | ('i' | 'u', 1 | 2 | 4 | 8) | ('b', 1));
    ok.then_some((endian, kind, size))
}

fn fortran_to_c(data: &[f32], shape: &[usize]) -> Vec<f32> {
    let n = data.len();
    let mut out = vec![0.0; n];
    let mut idx = vec![0usize; shape.len()];
    // `data` is in Fortran order: the first index runs fastest.
    for &v in data {
        let mut c_i = 0;
        for (d, &s) in shape.iter().enumerate() {
            c_i = c_i * s + idx[d];
        }
        out[c_i] = v;
        for (d, &s) in shape.iter().enumerate() {
            idx[d] += 1;
            if idx[d] < s {
                break;
            }
            idx[d] = 0;
        }
    }
    out
}

fn half_to_f32(h: u16) -> f32 {
    let s = ((h >> 15) & 1) as u32;
    let e = ((h >> 10) & 0x1f) as i32;
    let m = (h & 0x3ff) as u32;
    let v = if e == 0 {
        (m as f32) * 2f32.powi(-24)
    } else if e == 31 {
        if m == 0 {
            f32::INFINITY
        } else {
            f32::NAN
        }
    } else {
        (1.0 + m as f32 / 1024.0) * 2f32.powi(e - 15)
    };
    if s == 1 {
        -v
    } else {
        v
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trip_and_header_alignment() {
        let data: Vec<f32> = (0..24).map(|i| i as f32 * 0.5 - 3.0).collect();
        let bytes = to_bytes(&[2, 3, 4], &data);
        let hlen = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
        assert_eq!((10 + hlen) % 64, 0);
        let a = parse(&bytes, Path::new("x.npy")).unwrap();
        assert_eq!(a.shape, vec![2, 3, 4]);
        assert_eq!(a.data, data);
    }

    #[test]
    fn fortran_order_is_transposed_to_c() {
        // numpy: np.asfortranarray(np.arange(6, dtype='<f8').reshape(2, 3))
        let mut bytes = Vec::new();
        let header = "{'descr': '<f8', 'fortran_order': True, 'shape': (2, 3), }";
        bytes.extend_from_slice(MAGIC);
        bytes.extend_from_slice(&[1, 0]);
        bytes.extend_from_slice(&(header.len() as u16).to_le_bytes());
        bytes.extend_from_slice(header.as_bytes());
        for v in [0.0f64, 3.0, 1.0, 4.0, 2.0, 5.0] {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
        let a = parse(&bytes, Path::new("f.npy")).unwrap();
        assert_eq!(a.data, vec![0.0, 1.0, 2.0, 3.0, 4.0, 5.0]);
    }

    #[test]
    fn truncated_and_garbage_are_errors_naming_the_file() {
        let bytes = to_bytes(&[4], &[1.0, 2.0, 3.0, 4.0]);
        let e = parse(&bytes[..bytes.len() - 2], Path::new("t.npy")).unwrap_err();
        assert!(e.to_string().starts_with("t.npy: data truncated"), "{e}");
        let e = parse(b"hello world", Path::new("g.npy")).unwrap_err();
        assert!(e.to_string().contains("g.npy"));
        let e = parse(&bytes[..12], Path::new("h.npy")).unwrap_err();
        assert!(e.to_string().contains("truncated"), "{e}");
    }

    /// Found by the `npy` fuzz target: a dtype starting with a multi-byte character
    /// panicked (a string slice inside a character).
    #[test]
    fn non_ascii_dtype_is_an_error_not_a_panic() {
        for descr in ["\u{64a}u2", "<\u{e9}4", "\u{1f600}"] {
            let header = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': (3,), }}");
            let mut bytes = MAGIC.to_vec();
            bytes.extend_from_slice(&[1, 0]);
            bytes.extend_from_slice(&(header.len() as u16).to_le_bytes());
            bytes.extend_from_slice(header.as_bytes());
            bytes.extend_from_slice(&[0; 24]);
            let e = parse(&bytes, Path::new("d.npy")).unwrap_err().to_string();
            assert!(e.starts_with("d.npy: unsupported dtype"), "{e}");
        }
    }

    #[test]
    fn huge_declared_shape_does_not_allocate() {
        let header = "{'descr': '<f4', 'fortran_order': False, 'shape': (100000000000, 100000), }";
        let mut bytes = MAGIC.to_vec();
        bytes.extend_from_slice(&[1, 0]);
        bytes.extend_from_slice(&(header.len() as u16).to_le_bytes());
        bytes.extend_from_slice(header.as_bytes());
        assert!(parse(&bytes, Path::new("big.npy")).is_err());
    }
}
