//! Checked views of numpy inputs and numpy outputs that own Rust buffers.
//!
//! Every check raises `ValueError` naming the argument: its shape against the expected
//! one, and the first non-finite value. Inputs are read in place (no copy) when they
//! are C-contiguous float32; the Python layer converts anything else first.

use numpy::{PyArray1, PyArrayMethods, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::exceptions::{PyFileNotFoundError, PyOSError, PyValueError};
use pyo3::prelude::*;

/// A `ValueError` with `msg`.
pub fn value_error(msg: impl Into<String>) -> PyErr {
    PyValueError::new_err(msg.into())
}

/// The library's file errors as Python's: a missing file is `FileNotFoundError`, any
/// other refusal of the operating system `OSError`, a bad file `ValueError`; the message
/// is the CLI's (it names the file).
pub fn scene_error(e: transsplat_scene::Error) -> PyErr {
    match &e {
        transsplat_scene::Error::Io { err, .. } if err.kind() == std::io::ErrorKind::NotFound => {
            PyFileNotFoundError::new_err(e.to_string())
        }
        transsplat_scene::Error::Io { .. } => PyOSError::new_err(e.to_string()),
        transsplat_scene::Error::Format { .. } => PyValueError::new_err(e.to_string()),
    }
}

/// The shape of `a` as text, e.g. `(5, 3)`.
fn shape_text(shape: &[usize]) -> String {
    match shape {
        [n] => format!("({n},)"),
        _ => format!("({})", shape.iter().map(|d| d.to_string()).collect::<Vec<_>>().join(", ")),
    }
}

/// The values of `a` as a slice, after checking its shape against `want` (`None` is
/// any size) and that every value is finite.
pub fn slice<'a>(
    name: &str,
    a: &'a PyReadonlyArrayDyn<'_, f32>,
    want: &[Option<usize>],
) -> PyResult<&'a [f32]> {
    let shape = a.shape();
    let ok = shape.len() == want.len() && shape.iter().zip(want).all(|(s, w)| w.is_none_or(|w| *s == w));
    if !ok {
        let want: Vec<String> = want.iter().map(|w| w.map_or("*".into(), |w| w.to_string())).collect();
        return Err(value_error(format!(
            "{name}: expected shape ({}), got {}",
            want.join(", "),
            shape_text(shape)
        )));
    }
    let s = a.as_slice().map_err(|_| value_error(format!("{name}: the array is not C-contiguous")))?;
    if !all_finite(s) {
        let i = s.iter().position(|v| !v.is_finite()).unwrap_or(0);
        let mut idx = Vec::with_capacity(shape.len());
        let mut rest = i;
        for d in shape.iter().rev() {
            idx.push(rest % d.max(&1));
            rest /= d.max(&1);
        }
        idx.reverse();
        return Err(value_error(format!("{name}: non-finite value {} at index {}", s[i], shape_text(&idx))));
    }
    Ok(s)
}

/// True when every value is finite: a branch-free test of the exponent bits over
/// chunks in parallel, so checking a million Gaussians' SH costs a few milliseconds.
pub fn all_finite(s: &[f32]) -> bool {
    use rayon::prelude::*;
    const EXP: u32 = 0x7f80_0000;
    s.par_chunks(1 << 16).all(|c| !c.iter().fold(false, |bad, v| bad | (v.to_bits() & EXP == EXP)))
}

/// `s` seen as rows of `N` values (no copy); the length must be a multiple of `N`.
pub fn rows<const N: usize>(s: &[f32]) -> &[[f32; N]] {
    let (rows, rest) = s.as_chunks::<N>();
    debug_assert!(rest.is_empty());
    rows
}

/// A numpy array of shape `shape` that takes over `data` (no copy).
pub fn to_numpy<'py, T: numpy::Element>(
    py: Python<'py>,
    data: Vec<T>,
    shape: &[usize],
) -> PyResult<Bound<'py, PyAny>> {
    debug_assert_eq!(data.len(), shape.iter().product::<usize>());
    Ok(PyArray1::from_vec(py, data).reshape(shape)?.into_any())
}
