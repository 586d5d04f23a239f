//! POT-style entropic unbalanced transport (`ot.unbalanced.sinkhorn_unbalanced`,
//! `reg_type="kl"`) over the library's solver, dense or top-k.

use crate::arrays::{slice, to_numpy, value_error};
use numpy::PyReadonlyArrayDyn;
use pyo3::prelude::*;
use pyo3::types::PyDict;
use transsplat_transport::{solve, Params, Problem};

/// Solves one problem; returns the dense plan `(n, m)` and a log dict with POT's keys
/// (`logu`, `logv`, `cost`, `err`) and the solver's statistics.
#[pyfunction]
#[pyo3(signature = (a, b, m, reg, reg_m_s, reg_m_t, num_iter_max, stop_thr, top_k))]
#[allow(clippy::too_many_arguments)]
pub fn sinkhorn_unbalanced<'py>(
    py: Python<'py>,
    a: PyReadonlyArrayDyn<'py, f32>,
    b: PyReadonlyArrayDyn<'py, f32>,
    m: PyReadonlyArrayDyn<'py, f32>,
    reg: f64,
    reg_m_s: f64,
    reg_m_t: f64,
    num_iter_max: usize,
    stop_thr: Option<f64>,
    top_k: usize,
) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyDict>)> {
    let a = slice("a", &a, &[None])?;
    let b = slice("b", &b, &[None])?;
    let (n, mm) = (a.len(), b.len());
    // +inf costs exclude an entry (the CLI's convention); NaN is refused by the solver.
    let cost = m.as_slice().map_err(|_| value_error("M: the array is not C-contiguous"))?;
    {
        use numpy::PyUntypedArrayMethods;
        if m.shape() != [n, mm] {
            return Err(value_error(format!(
                "M: expected shape ({n}, {mm}) for a and b, got {:?}",
                m.shape()
            )));
        }
    }
    if !(reg.is_finite() && reg > 0.0) {
        return Err(value_error(format!("reg: must be a positive number, got {reg}")));
    }
    let mut params = Params::new(reg, reg_m_s, reg_m_t);
    params.max_iters = num_iter_max;
    params.tol = stop_thr;
    let solved = py.allow_threads(|| -> transsplat_transport::Result<_> {
        let p = Problem::top_k(a, b, cost, top_k)?;
        let s = solve(&p, &params)?;
        let plan = s.dense_plan(&p);
        Ok((plan, s))
    });
    let (plan, s) = solved.map_err(|e| value_error(e.to_string()))?;
    let log = PyDict::new(py);
    let logu: Vec<f64> = s.potentials.f.iter().map(|f| f / reg).collect();
    let logv: Vec<f64> = s.potentials.g.iter().map(|g| g / reg).collect();
    log.set_item("logu", to_numpy(py, logu, &[n])?)?;
    log.set_item("logv", to_numpy(py, logv, &[mm])?)?;
    log.set_item("cost", s.stats.transport_cost)?;
    log.set_item("err", s.stats.last_change)?;
    log.set_item("objective", s.stats.objective)?;
    log.set_item("dual", s.stats.dual)?;
    log.set_item("transported_mass", s.stats.transported_mass)?;
    log.set_item("iterations", s.stats.iterations)?;
    log.set_item("converged", s.stats.converged)?;
    log.set_item("row_mass", to_numpy(py, s.row_mass, &[n])?)?;
    log.set_item("col_mass", to_numpy(py, s.col_mass, &[mm])?)?;
    Ok((to_numpy(py, plan, &[n, mm])?, log))
}
