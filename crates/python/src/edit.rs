//! The TransSplat edit with a Python callable as the 2D editor (docs/method.md#e1-the-editor-contract).
//!
//! The edit runs with the GIL released; the editor and the progress callback take it
//! back when they are called. Ctrl-C (KeyboardInterrupt) is noticed at every step and
//! stops the loop before the next one; the Python exception is raised as it was.

use crate::arrays::{scene_error, slice, to_numpy, value_error};
use crate::io::{cameras_from_lists, gaussians_from_arrays, gaussians_to_dict, intrinsics, viewmat};
use numpy::{PyArrayMethods, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::exceptions::{PyKeyboardInterrupt, PyRuntimeError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList, PyTuple};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use transsplat_edit::{EditConfig, EditError, Progress};
use transsplat_editors::{change_attention, EditedView, Editor, Segmenter, SourceView};
use transsplat_scene::Camera;
use transsplat_session as session;
use transsplat_session::edit::{EditRequest, EditorSpec, Features, OutputRequest, SegmenterSpec};
use transsplat_session::views::ViewChoice;
use transsplat_session::SessionError;

/// Name of the Python editor in logs and outputs.
const EDITOR_NAME: &str = "python";

/// Name of the Python segmenter in logs and outputs.
const SEGMENTER_NAME: &str = "python";

/// True for the held-out test views (every 8th camera, the llffhold split): the edit
/// uses the others.
#[pyfunction]
pub fn is_test_view(index: usize) -> bool {
    transsplat_scene::cameras::is_held_out(index, transsplat_scene::cameras::LLFF_HOLD)
}

/// An editor that calls `adapter(views, prompt)`; the adapter (Python,
/// `transsplat._edit.call_editor`) calls the user's editor and returns per view `None`
/// or `(image, attention or None, mask or None)` as float32 arrays.
struct PyEditor {
    adapter: Py<PyAny>,
    /// The Python exception that stopped the editor, raised again by [`edit`].
    raised: Arc<Mutex<Option<PyErr>>>,
}

/// The views as the adapters (editor and segmenter) receive them: `(index, name, image
/// (H, W, 3), viewmat, K, width, height)`.
fn py_views<'py>(py: Python<'py>, views: &[SourceView]) -> PyResult<Bound<'py, PyList>> {
    let list = PyList::empty(py);
    for v in views {
        let (w, h) = v.size();
        let c = v.camera;
        let image = to_numpy(py, v.image.to_vec(), &[h, w, 3])?;
        let vm = to_numpy(py, viewmat(c).to_vec(), &[4, 4])?;
        let k = to_numpy(py, intrinsics(c).to_vec(), &[3, 3])?;
        let item = (v.index, c.name.clone(), image, vm, k, w, h);
        list.append(item)?;
    }
    Ok(list)
}

/// Calls `adapter(views, text)`; an exception is kept in `raised` (raised again by
/// [`edit`]) and becomes an editor error quoting it.
fn call_adapter(
    py: Python<'_>,
    adapter: &Py<PyAny>,
    raised: &Mutex<Option<PyErr>>,
    who: &str,
    views: &[SourceView],
    text: &str,
) -> Result<Py<PyAny>, transsplat_editors::Error> {
    match py_views(py, views).and_then(|list| adapter.call1(py, (list, text))) {
        Ok(out) => Ok(out),
        Err(e) => {
            let msg = e.to_string();
            *raised.lock().unwrap_or_else(|p| p.into_inner()) = Some(e);
            Err(transsplat_editors::Error::Command(format!("the {who} raised {msg}")))
        }
    }
}

/// A segmenter that calls `adapter(views, phrase)`; the adapter (Python,
/// `transsplat._edit.call_segmenter`) calls the user's segmenter and returns per view
/// `None` or an `H × W` float32 mask (values are checked by the wrapper,
/// `transsplat_editors::segment`).
struct PySegmenter {
    adapter: Py<PyAny>,
    /// The Python exception that stopped the segmenter, raised again by [`edit`].
    raised: Arc<Mutex<Option<PyErr>>>,
}

impl Segmenter for PySegmenter {
    fn name(&self) -> &str {
        SEGMENTER_NAME
    }

    fn segment(
        &mut self,
        views: &[SourceView],
        phrase: &str,
    ) -> Result<Vec<Option<Vec<f32>>>, transsplat_editors::Error> {
        Python::with_gil(|py| {
            let out = call_adapter(py, &self.adapter, &self.raised, "segmenter", views, phrase)?;
            let bad = |m: String| transsplat_editors::Error::Invalid(m);
            let list = out
                .bind(py)
                .downcast::<PyList>()
                .map_err(|_| bad("the segmenter adapter returned no list".into()))?;
            if list.len() != views.len() {
                return Err(bad(format!(
                    "the segmenter returned {} masks for {} views",
                    list.len(),
                    views.len()
                )));
            }
            views
                .iter()
                .zip(list.iter())
                .map(|(v, item)| {
                    if item.is_none() {
                        return Ok(None);
                    }
                    let (w, h) = v.size();
                    let what = format!("view {} ({}): mask", v.index, v.camera.name);
                    let arr = item
                        .downcast::<numpy::PyArrayDyn<f32>>()
                        .map_err(|_| bad(format!("{what} is not a float32 array")))?
                        .readonly();
                    if arr.shape() != [h, w] {
                        return Err(bad(format!(
                            "{what} has shape {:?}, the view is {h}x{w} (H x W)",
                            arr.shape()
                        )));
                    }
                    slice(&what, &arr, &[Some(h), Some(w)])
                        .map(|s| Some(s.to_vec()))
                        .map_err(|e| bad(Python::with_gil(|py| e.value(py).to_string())))
                })
                .collect()
        })
    }
}

impl PyEditor {
    /// One view's output from the adapter's `(image, attention, mask)`.
    fn output(v: &SourceView, item: &Bound<'_, PyAny>) -> Result<Option<EditedView>, String> {
        if item.is_none() {
            return Ok(None);
        }
        let name = &v.camera.name;
        let (w, h) = v.size();
        let t = item
            .downcast::<PyTuple>()
            .map_err(|_| format!("view '{name}': the adapter returned no tuple"))?;
        let plane = |k: usize, what: &str, ch: Option<usize>| -> Result<Option<Vec<f32>>, String> {
            let obj = t.get_item(k).map_err(|e| e.to_string())?;
            if obj.is_none() {
                return Ok(None);
            }
            let arr = obj
                .downcast::<numpy::PyArrayDyn<f32>>()
                .map_err(|_| format!("view '{name}': {what} is not a float32 array"))?
                .readonly();
            let want: Vec<Option<usize>> = match ch {
                Some(c) => vec![Some(h), Some(w), Some(c)],
                None => vec![Some(h), Some(w)],
            };
            if arr.shape().len() != want.len() {
                let s = arr.shape();
                return Err(format!("view '{name}': {what} has shape {s:?}, the view is {h}x{w} (H x W)"));
            }
            slice(&format!("view '{name}': {what}"), &arr, &want)
                .map(|s| Some(s.to_vec()))
                .map_err(|e| Python::with_gil(|py| e.value(py).to_string()))
        };
        let image =
            plane(0, "edited image", Some(3))?.ok_or_else(|| format!("view '{name}': no edited image"))?;
        let attention = plane(1, "attention", None)?;
        let mask = plane(2, "mask", None)?;
        // The folder editor's rule: the given attention, else the mask, else the change map.
        let attention = match (attention, &mask) {
            (Some(a), _) => a,
            (None, Some(m)) => m.clone(),
            (None, None) => change_attention(v.image, &image, w, h),
        };
        Ok(Some(EditedView::new(image, w, h, attention, mask)))
    }
}

impl Editor for PyEditor {
    fn name(&self) -> &str {
        EDITOR_NAME
    }

    fn edit(
        &mut self,
        views: &[SourceView],
        prompt: &str,
    ) -> Result<Vec<Option<EditedView>>, transsplat_editors::Error> {
        Python::with_gil(|py| {
            let out = call_adapter(py, &self.adapter, &self.raised, "editor", views, prompt)?;
            let bad = |m: String| transsplat_editors::Error::Invalid(m);
            let list =
                out.bind(py).downcast::<PyList>().map_err(|_| bad("the adapter returned no list".into()))?;
            if list.len() != views.len() {
                return Err(bad(format!(
                    "the editor returned {} views for {} inputs",
                    list.len(),
                    views.len()
                )));
            }
            views.iter().zip(list.iter()).map(|(v, item)| Self::output(v, &item).map_err(bad)).collect()
        })
    }
}

/// Settings from TOML text, `key=value` overrides, a method and a step count, checked.
fn config(
    toml: Option<&str>,
    overrides: &[String],
    method: Option<&str>,
    steps: Option<usize>,
) -> PyResult<EditConfig> {
    let base = match toml {
        Some(t) => EditConfig::from_toml(t).map_err(value_error)?,
        None => EditConfig::default(),
    };
    base.assemble(method, overrides, steps).map_err(value_error)
}

/// Runs the edit (see `transsplat.edit`). Returns a dict with the edited Gaussians, the
/// gate, the per-round statistics, the per-step losses and the timing, and writes the
/// CLI's output folder when `out` is given.
#[pyfunction]
#[pyo3(signature = (
    means, quats, log_scales, opacity_logits, sh, extra_names, extra,
    viewmats, ks, widths, heights, names,
    prompt, adapter, config_toml, overrides, method, steps, background, out, inputs, progress, views,
    segmenter=None, segment=None
))]
#[allow(clippy::too_many_arguments)]
pub fn edit<'py>(
    py: Python<'py>,
    means: PyReadonlyArrayDyn<'py, f32>,
    quats: PyReadonlyArrayDyn<'py, f32>,
    log_scales: PyReadonlyArrayDyn<'py, f32>,
    opacity_logits: PyReadonlyArrayDyn<'py, f32>,
    sh: PyReadonlyArrayDyn<'py, f32>,
    extra_names: Vec<String>,
    extra: Option<PyReadonlyArrayDyn<'py, f32>>,
    viewmats: PyReadonlyArrayDyn<'py, f32>,
    ks: PyReadonlyArrayDyn<'py, f32>,
    widths: Vec<u32>,
    heights: Vec<u32>,
    names: Vec<String>,
    prompt: String,
    adapter: Py<PyAny>,
    config_toml: Option<String>,
    overrides: Vec<String>,
    method: Option<String>,
    steps: Option<usize>,
    background: [f32; 3],
    out: Option<PathBuf>,
    inputs: Vec<PathBuf>,
    progress: Option<Py<PyAny>>,
    views: String,
    segmenter: Option<Py<PyAny>>,
    segment: Option<String>,
) -> PyResult<Bound<'py, PyDict>> {
    let views = ViewChoice::parse(&views).map_err(|e| value_error(format!("views: {e}")))?;
    let g = gaussians_from_arrays(
        &means,
        &quats,
        &log_scales,
        &opacity_logits,
        &sh,
        extra_names,
        extra.as_ref(),
    )?;
    let cams: Vec<Camera> = cameras_from_lists(&viewmats, &ks, widths, heights, names)?;
    let cfg = config(config_toml.as_deref(), &overrides, method.as_deref(), steps)?;
    let output = out.map(|path| OutputRequest {
        path,
        inputs,
        formats: Vec::new(),
        write_options: Default::default(),
        checkpoints: None,
    });
    let raised = Arc::new(Mutex::new(None));
    // The segmenter is given the phrase, else the whole instruction.
    let segmenter = segmenter.map(|adapter| {
        let phrase = segment.unwrap_or_else(|| prompt.clone());
        SegmenterSpec::Custom(Box::new(PySegmenter { adapter, raised: raised.clone() }), phrase)
    });
    let request = EditRequest {
        gaussians: &g,
        cameras: &cams,
        prompt: &prompt,
        editor: EditorSpec::Custom(Box::new(PyEditor { adapter, raised: raised.clone() })),
        segmenter,
        features: Features::Builtin,
        views,
        config: cfg,
        background,
        output,
        target: None,
    };
    run_session(py, request, progress.as_ref(), &raised)
}

/// Runs the edit job without the GIL, reporting to `progress`; the error is the
/// exception a Python callable raised (kept in `raised`), the stop's own, or the job's.
fn run_session<'py>(
    py: Python<'py>,
    request: EditRequest,
    progress: Option<&Py<PyAny>>,
    raised: &Mutex<Option<PyErr>>,
) -> PyResult<Bound<'py, PyDict>> {
    let cancel = AtomicBool::new(false);
    let interrupt: Mutex<Option<PyErr>> = Mutex::new(None);
    let outcome = py.allow_threads(|| {
        let mut report = |p: Progress| report_progress(p, progress, &cancel, &interrupt);
        session::edit::run(request, Some(&cancel), &mut report)
    });
    // The exception that asked for the stop; one raised in the last step's report
    // comes after the loop's last check, so it is looked at on success too.
    let stop = interrupt.into_inner().unwrap_or_else(|p| p.into_inner());
    match (outcome, stop) {
        (Ok(outcome), None) => result_dict(py, outcome),
        (Ok(_), Some(stop)) => Err(stop),
        (Err(e), stop) => match raised.lock().unwrap_or_else(|p| p.into_inner()).take() {
            Some(raised) => Err(raised),
            None => Err(session_error(e, stop)),
        },
    }
}

/// Hands one step, round or editor call to the Python callback `progress` (with the
/// GIL); Ctrl-C in Python, or an exception in the callback, is kept in `interrupt` and
/// asks the loop to stop.
fn report_progress(
    p: Progress,
    progress: Option<&Py<PyAny>>,
    cancel: &AtomicBool,
    interrupt: &Mutex<Option<PyErr>>,
) {
    Python::with_gil(|py| {
        if let Err(e) = py.check_signals() {
            *interrupt.lock().unwrap_or_else(|p| p.into_inner()) = Some(e);
            cancel.store(true, Ordering::SeqCst);
            return;
        }
        let Some(cb) = progress else { return };
        let call = match p {
            Progress::Step { step, steps, loss } => cb.call1(py, ("step", step, steps, loss)),
            Progress::Edited { views, seconds } => cb.call1(py, ("edited", views, 0usize, seconds)),
            Progress::Round(r) => cb.call1(py, ("round", r.round, r.step, r.mean_gate)),
        };
        if let Err(e) = call {
            *interrupt.lock().unwrap_or_else(|p| p.into_inner()) = Some(e);
            cancel.store(true, Ordering::SeqCst);
        }
    })
}

/// The Python exception for a failed edit job: the stop's own exception (Ctrl-C, the
/// callback's) for an interruption, `ValueError` for a bad input, the scene error for a
/// file, `RuntimeError` otherwise.
fn session_error(e: SessionError, stop: Option<PyErr>) -> PyErr {
    match e {
        SessionError::Edit(EditError::Interrupted(step)) => {
            stop.unwrap_or_else(|| PyKeyboardInterrupt::new_err(format!("edit interrupted at step {step}")))
        }
        SessionError::Interrupted { message, .. } => {
            stop.unwrap_or_else(|| PyKeyboardInterrupt::new_err(message))
        }
        SessionError::Edit(EditError::Input(m)) | SessionError::Input(m) => value_error(m),
        SessionError::Edit(e @ EditError::NoEvidence) => value_error(e.to_string()),
        SessionError::Edit(EditError::Editor(transsplat_editors::Error::Invalid(m))) => value_error(m),
        SessionError::Io(e) => scene_error(e),
        e => PyRuntimeError::new_err(e.to_string()),
    }
}

/// What `edit` returns to Python: the edited scene, the gate, per-round and per-step
/// statistics (as JSON text), the edited views and the output folder.
fn result_dict(py: Python<'_>, outcome: session::edit::EditOutcome) -> PyResult<Bound<'_, PyDict>> {
    let session::edit::EditOutcome { result, out: written, edit_views, .. } = outcome;
    let d = PyDict::new(py);
    let json = |e: serde_json::Result<String>| e.expect("edit statistics serialise");
    d.set_item("rounds_json", json(serde_json::to_string(&result.rounds)))?;
    d.set_item("losses_json", json(serde_json::to_string(&result.losses)))?;
    d.set_item("timing_json", json(serde_json::to_string(&result.timing)))?;
    d.set_item("prototypes", result.prototypes.clone())?;
    d.set_item("edit_views", edit_views)?;
    match &result.gate {
        Some(gate) => d.set_item("gate", to_numpy(py, gate.clone(), &[gate.len()])?)?,
        None => d.set_item("gate", py.None())?,
    }
    d.set_item("out", written)?;
    d.set_item("gaussians", gaussians_to_dict(py, result.gaussians)?)?;
    Ok(d)
}

/// Checks edit settings as [`edit`] would (TOML text, `key=value` overrides, a method, a
/// step count) without running anything: for manifests checked before a run starts.
#[pyfunction]
#[pyo3(signature = (config_toml, overrides, method, steps))]
pub fn check_config(
    config_toml: Option<String>,
    overrides: Vec<String>,
    method: Option<String>,
    steps: Option<usize>,
) -> PyResult<()> {
    config(config_toml.as_deref(), &overrides, method.as_deref(), steps).map(|_| ())
}
