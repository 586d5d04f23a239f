//! `transsplat._core`: the Python extension module, a thin front over the library like
//! the CLI (`crates/cli`). The public API, argument conversions and docstrings live in
//! the Python package (`python/transsplat`); this module takes C-contiguous float32
//! arrays, checks shapes and values, releases the GIL for the compute and returns numpy
//! arrays that own the library's buffers (no copy on the way out).
//!
//! - [`io`]: INRIA PLY scenes and cameras in every format the CLI reads.
//! - [`raster`]: gsplat-style rasterization and its backward.
//! - [`transport`]: POT-style unbalanced Sinkhorn (dense and top-k).
//! - [`edit`]: the TransSplat edit with a Python callable as the 2D editor.

/// The allocator of the command line tool (`crates/cli/src/main.rs` says why: large
/// per-call buffers are reused instead of page-faulted afresh), so a call from Python
/// costs what the same call costs in the binary. Arrays handed to numpy are freed by it
/// too: numpy releases them through the Rust `Vec` they came from.
#[global_allocator]
static ALLOC: mimalloc::MiMalloc = mimalloc::MiMalloc;

mod arrays;
mod edit;
mod io;
mod raster;
mod transport;

use pyo3::prelude::*;

/// The compiled core of the `transsplat` package (see `transsplat/__init__.py`).
#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_function(wrap_pyfunction!(io::load_ply, m)?)?;
    m.add_function(wrap_pyfunction!(io::save_ply, m)?)?;
    m.add_function(wrap_pyfunction!(io::load_cameras, m)?)?;
    m.add_function(wrap_pyfunction!(io::builtin_scene, m)?)?;
    m.add_function(wrap_pyfunction!(io::bench_scene, m)?)?;
    m.add_function(wrap_pyfunction!(io::check_output, m)?)?;
    m.add_function(wrap_pyfunction!(raster::rasterize, m)?)?;
    m.add_function(wrap_pyfunction!(raster::rasterize_backward, m)?)?;
    m.add_class::<raster::Frames>()?;
    m.add_function(wrap_pyfunction!(transport::sinkhorn_unbalanced, m)?)?;
    m.add_function(wrap_pyfunction!(edit::edit, m)?)?;
    m.add_function(wrap_pyfunction!(edit::check_config, m)?)?;
    m.add_function(wrap_pyfunction!(edit::is_test_view, m)?)?;
    Ok(())
}
