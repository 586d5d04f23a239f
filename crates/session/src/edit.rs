//! An edit job: a scene, its cameras and an instruction, a 2D editor, the edit engine
//! (`transsplat_edit`) and, when an output folder is asked for, that folder
//! ([`crate::edit_folder`]) committed only when complete.
//!
//! The order is fixed so every front keeps the same guarantees: the output rule and
//! staging come before anything slow (a model load, the editor); the view split is
//! [`crate::views::split`] (every 8th camera held out); a stop or a
//! failure leaves the output as it was and says where the checkpoint is.

use crate::checkpoints::{self, Checkpoints};
use crate::edit_folder::{self, EditOutput, MARKER};
use crate::output::Output;
use crate::views::ViewChoice;
use crate::SessionError;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::time::Duration;
use transsplat_edit::checkpoint::STATE_FILE;
use transsplat_edit::{semantic, EditConfig, EditError, EditJob, EditResult, Progress};
use transsplat_editors::{CommandEditor, Editor, FolderEditor, MaskFolder, Segmented, Segmenter};
use transsplat_scene::formats::{self, SceneFormat};
use transsplat_scene::{Camera, Gaussians};

/// DINOv2 features are reduced to this many channels (a fixed random projection) before
/// the engine's PCA to `semantic_dim`: 384 or 768 channels per pixel of every view would
/// not fit in memory for a real capture.
const DINO_CHANNELS: usize = 64;

/// Edit checkpoints are written every this many steps unless asked otherwise.
const CHECKPOINT_EVERY: u64 = 100;

/// Which 2D editor makes the edits.
pub enum EditorSpec<'a> {
    /// Edited images made by any tool, in a folder (`transsplat views export` layout).
    Folder(PathBuf),
    /// A command run on exported views (file protocol in the editors crate docs),
    /// ended with its process group after `timeout`. Needs an output folder: it works
    /// inside the staged output.
    Command { command: String, timeout: Option<Duration> },
    /// InstructPix2Pix from a local diffusers folder, `batch` views per pipeline call.
    Ip2p { weights: PathBuf, batch: usize },
    /// Any other editor: a Python callable, the benchmark's simulated editor.
    Custom(Box<dyn Editor + Send + 'a>),
}

impl EditorSpec<'_> {
    /// The editor's name in logs and outputs.
    pub fn name(&self) -> String {
        match self {
            EditorSpec::Folder(_) => "folder".into(),
            EditorSpec::Command { .. } => "command".into(),
            EditorSpec::Ip2p { .. } => "ip2p".into(),
            EditorSpec::Custom(e) => e.name().into(),
        }
    }
}

/// Where the target masks M_sam of the edited views come from
/// (`transsplat_editors::segment`). The edit's editor is wrapped so every edited view's
/// mask is the segmenter's, whichever way it is made, replacing any mask the editor gave.
pub enum SegmenterSpec<'a> {
    /// CLIPSeg from a local Hugging Face folder (`CIDAS/clipseg-rd64-refined`), segmenting
    /// what `phrase` names ("the ball"), given by the user; with `sam`, a SAM folder
    /// (`SamModel` layout), each CLIPSeg mask sharpened by SAM prompted by its box and
    /// most confident pixel (`transsplat_models::sam::SamSharpened`).
    ClipSeg { weights: PathBuf, phrase: String, sam: Option<PathBuf> },
    /// Masks made elsewhere: `DIR/<stem>.png` (or the view's content name), grey, one per
    /// edited view at the view's size.
    Folder(PathBuf),
    /// Any other segmenter (a Python callable) and the phrase it is given.
    Custom(Box<dyn Segmenter + Send + 'a>, String),
}

impl SegmenterSpec<'_> {
    /// Checks what can be checked without loading anything (the weights folder and its
    /// files, the mask folder, a non-empty phrase), so a front can refuse a bad request
    /// before it builds anything slow of its own; [`run`] loads the model.
    pub fn check(&self) -> Result<(), SessionError> {
        match self {
            SegmenterSpec::ClipSeg { weights, phrase, sam } => {
                if phrase.trim().is_empty() {
                    return Err(SessionError::Input(
                        "segment: the phrase is empty; name the target, e.g. \"the ball\"".into(),
                    ));
                }
                check_model_folder(weights, "CLIPSeg", &clipseg_hint(weights))?;
                if let Some(sam) = sam {
                    check_model_folder(sam, "SAM", &transsplat_models::sam::download_hint(sam))?;
                }
                Ok(())
            }
            SegmenterSpec::Folder(dir) => {
                MaskFolder::new(dir).check().map_err(|e| SessionError::Input(e.to_string()))
            }
            SegmenterSpec::Custom(..) => Ok(()),
        }
    }

    /// The folders the segmenter reads (inputs of the output rule).
    fn inputs(&self) -> Vec<PathBuf> {
        match self {
            SegmenterSpec::ClipSeg { weights, sam, .. } => {
                std::iter::once(weights.clone()).chain(sam.clone()).collect()
            }
            SegmenterSpec::Folder(dir) => vec![dir.clone()],
            SegmenterSpec::Custom(..) => Vec::new(),
        }
    }
}

/// `dir` is a model folder with `config.json` and `model.safetensors` (its error names
/// the folder or file and `hint`, the download command).
fn check_model_folder(dir: &Path, what: &str, hint: &str) -> Result<(), SessionError> {
    let model = |e: transsplat_models::Error| SessionError::Model(e.to_string());
    let dir = transsplat_models::ModelDir::open(dir, what, hint).map_err(model)?;
    dir.file("config.json").map_err(model)?;
    dir.safetensors("model").map(|_| ()).map_err(model)
}

/// The download command of CLIPSeg into `dir`.
fn clipseg_hint(dir: &Path) -> String {
    transsplat_models::clipseg::download_hint(dir)
}

/// The segmenter a [`SegmenterSpec`] describes, loaded and ready, and its phrase.
fn build_segmenter<'a>(
    spec: SegmenterSpec<'a>,
    gaussians: &Gaussians,
) -> Result<(Box<dyn Segmenter + 'a>, String), SessionError> {
    Ok(match spec {
        SegmenterSpec::ClipSeg { weights, phrase, sam } => {
            use transsplat_models::clipseg::ClipSegSegmenter;
            use transsplat_models::sam::{Sam, SamSharpened};
            let model = |e: transsplat_models::Error| SessionError::Model(e.to_string());
            let device = transsplat_models::default_device();
            let mut s = ClipSegSegmenter::load(&weights, &device).map_err(model)?;
            // A phrase the model cannot take is refused before the editor runs.
            s.prepare(&phrase).map_err(|e| {
                SessionError::Model(format!("{}: CLIPSeg cannot take {phrase:?}: {e}", weights.display()))
            })?;
            match sam {
                Some(sam) => {
                    (Box::new(SamSharpened::new(s, Sam::load(&sam, &device).map_err(model)?)), phrase)
                }
                None => (Box::new(s), phrase),
            }
        }
        SegmenterSpec::Folder(dir) => {
            let folder = MaskFolder::new(dir).for_scene(transsplat_scene::fingerprint::scene(gaussians));
            (Box::new(folder), String::new())
        }
        SegmenterSpec::Custom(s, phrase) => (s, phrase),
    })
}

/// Where the semantic features E of the renders and edited views come from.
#[derive(Clone, Debug, Default)]
pub enum Features {
    /// The built-in features (`transsplat_edit::semantic::builtin`).
    #[default]
    Builtin,
    /// DINOv2 from a local Hugging Face folder (`facebook/dinov2-small` or `-base`).
    Dinov2(PathBuf),
}

impl Features {
    /// Checks that the feature model's folder is there with its files (cheap: nothing
    /// is loaded), so a front can refuse a missing folder before it builds anything
    /// slow of its own; [`run`] loads the model.
    pub fn check(&self) -> Result<(), SessionError> {
        match self {
            Features::Builtin => Ok(()),
            Features::Dinov2(dir) => transsplat_models::ModelDir::open(dir, "DINOv2", &dinov2_hint(dir))
                .map(|_| ())
                .map_err(|e| SessionError::Model(e.to_string())),
        }
    }
}

/// The download command of DINOv2 into `dir`.
fn dinov2_hint(dir: &Path) -> String {
    format!("hf download facebook/dinov2-small --local-dir {}", dir.display())
}

/// The output folder of an edit.
#[derive(Clone, Debug)]
pub struct OutputRequest {
    /// The folder (replaced only if it holds an earlier edit's output).
    pub path: PathBuf,
    /// Every input path (as given and as resolved), for the output rule.
    pub inputs: Vec<PathBuf>,
    /// Formats written beside `point_cloud.ply`.
    pub formats: Vec<SceneFormat>,
    /// How they are written (SPZ's version and axes).
    pub write_options: formats::WriteOptions,
    /// Checkpoints beside the output (`None`: none).
    pub checkpoints: Option<Checkpoints>,
}

/// An edit job.
pub struct EditRequest<'a> {
    pub gaussians: &'a Gaussians,
    pub cameras: &'a [Camera],
    pub prompt: &'a str,
    pub editor: EditorSpec<'a>,
    /// Where the target masks come from; `None` keeps the editor's own (if any).
    pub segmenter: Option<SegmenterSpec<'a>>,
    pub features: Features,
    /// Which edit views the editor edits ([`crate::views`]).
    pub views: ViewChoice,
    pub config: EditConfig,
    pub background: [f32; 3],
    /// The output folder; `None` returns the result only (the Python API's default).
    pub output: Option<OutputRequest>,
    /// Ground truth: which Gaussians are the edit's target, for the report's viewer.
    pub target: Option<Vec<bool>>,
}

/// What an edit produced.
pub struct EditOutcome {
    pub result: EditResult,
    /// The committed output folder, if one was asked for.
    pub out: Option<PathBuf>,
    /// The held-out test views and the edited views (camera indices).
    pub test_views: Vec<usize>,
    pub edit_views: Vec<usize>,
}

/// Runs an edit job; `cancel` stops it between steps, `progress` hears every step,
/// transport round and editor call.
pub fn run(
    request: EditRequest,
    cancel: Option<&AtomicBool>,
    progress: &mut dyn FnMut(Progress),
) -> Result<EditOutcome, SessionError> {
    let EditRequest {
        gaussians,
        cameras,
        prompt,
        editor,
        segmenter,
        features,
        views,
        config,
        background,
        output,
        target,
    } = request;
    if gaussians.is_empty() {
        return Err(SessionError::Input("scene: the scene has no Gaussians".into()));
    }
    if background.iter().any(|v| !v.is_finite()) {
        return Err(SessionError::Input(format!("background: non-finite value in {background:?}")));
    }
    let (test_views, edit_views) = crate::views::split(cameras, views)?;
    if !matches!(views, ViewChoice::All | ViewChoice::Auto) {
        tracing::info!("the editor edits {} views: {:?}", edit_views.len(), edit_views);
    }
    if let Some(s) = &segmenter {
        s.check()?;
    }
    let staged = match &output {
        Some(o) => {
            let segmenter_inputs = segmenter.as_ref().map(SegmenterSpec::inputs).unwrap_or_default();
            let inputs: Vec<&Path> = o.inputs.iter().chain(&segmenter_inputs).map(PathBuf::as_path).collect();
            Some(Output::begin(&o.path, &inputs, MARKER)?)
        }
        None => None,
    };
    let mut control = match output.as_ref().and_then(|o| o.checkpoints.as_ref().map(|c| (o, c))) {
        Some((o, checkpoints)) => checkpoints.control(&o.path, CHECKPOINT_EVERY, STATE_FILE, cancel)?,
        None => transsplat_train::Control { cancel, ..Default::default() },
    };
    let dino = match &features {
        Features::Dinov2(dir) => {
            use transsplat_models::{dinov2::Dinov2, ModelDir};
            let model = ModelDir::open(dir, "DINOv2", &dinov2_hint(dir))
                .and_then(|d| Dinov2::load(&d, &transsplat_models::default_device()))
                .map_err(|e| SessionError::Model(e.to_string()))?;
            Some(model)
        }
        Features::Builtin => None,
    };
    let segmenter = segmenter.map(|s| build_segmenter(s, gaussians)).transpose()?;
    let segmenter_name = segmenter.as_ref().map(|(s, phrase)| (s.name().to_string(), phrase.clone()));
    let editor_name = editor.name();
    // Views per call of the editor while its finished views are kept (InstructPix2Pix
    // edits its batch at a time; other editors take the whole shard at once), and what
    // the kept views' key knows of the editor.
    let group = match &editor {
        EditorSpec::Ip2p { batch, .. } => *batch,
        _ => usize::MAX,
    };
    let editor_settings = match &editor {
        EditorSpec::Folder(dir) => format!("folder {}", dir.display()),
        EditorSpec::Command { command, .. } => format!("command {command}"),
        EditorSpec::Ip2p { weights, .. } => format!("ip2p {}", weights.display()),
        EditorSpec::Custom(e) => e.name().to_string(),
    };
    let editor = build_editor(editor, gaussians, staged.as_ref(), &config, cancel)?;
    let mut editor: Box<dyn Editor + '_> = match segmenter {
        Some((segmenter, phrase)) => Box::new(Segmented::new(editor, segmenter, phrase)),
        None => editor,
    };
    let mut job_key = 0;
    if let Some(checkpoint) = &control.checkpoint {
        let segmenter = segmenter_name.as_ref().map(|(n, p)| format!("{n} {p}")).unwrap_or_default();
        job_key = crate::editor_views::job_key(
            &transsplat_scene::fingerprint::scene(gaussians),
            prompt,
            &format!("{editor_settings} {segmenter}"),
            config.seed,
        );
        let kept = checkpoint.dir.join(crate::editor_views::VIEWS_DIR);
        let mut kept_views =
            crate::editor_views::KeptViews::new(editor, kept, job_key, group, control.resume);
        if let Some(flag) = cancel {
            kept_views = kept_views.with_cancel(flag);
        }
        let stop_after =
            output.as_ref().and_then(|o| o.checkpoints.as_ref()).and_then(|c| c.stop_after_views);
        if let (Some(flag), Some(after)) = (cancel, stop_after) {
            kept_views = kept_views.with_stop_after(flag, after);
        }
        editor = Box::new(kept_views);
    }
    // A stop during the 2D edits: the views finished so far are kept for a resume; a
    // failure says where they are.
    let kept_at =
        control.checkpoint.as_ref().zip(output.as_ref()).map(|(c, o)| (c.dir.clone(), o.path.clone()));
    let editing_error = |e: SessionError| -> SessionError {
        let stopped = cancel.is_some_and(|c| c.load(std::sync::atomic::Ordering::SeqCst));
        match &kept_at {
            Some(_) if matches!(e, SessionError::Interrupted { .. }) => e,
            Some((dir, out)) if stopped => crate::editor_views::stopped(dir, out),
            Some((dir, _)) => crate::editor_views::failed_with_kept(e, dir),
            None => e,
        }
    };
    // `auto` edits its seeds and the views the target needs now; the engine then takes
    // those outputs as the edits of the chosen views (their time is the editor's).
    let auto_clock = std::time::Instant::now();
    let kept_choice = control
        .checkpoint
        .as_ref()
        .filter(|c| control.resume && c.dir.join(crate::views::AUTO_FILE).is_file())
        .map(|c| c.dir.clone());
    let edit_views = match (views, kept_choice) {
        // A resumed `auto` edit takes the views it chose; their edits come from the
        // checkpoint or the kept views.
        (ViewChoice::Auto, Some(dir)) => crate::views::read_auto_choice(&dir, &edit_views, job_key)?,
        (ViewChoice::Auto, None) => {
            let scene = crate::views::AutoScene {
                gaussians,
                cameras,
                edit_views: &edit_views,
                background,
                prompt,
                prototypes: &config.for_method(config.method).prototypes,
            };
            let choice = crate::views::auto(&scene, editor.as_mut()).map_err(&editing_error)?;
            if let Some(checkpoint) = &control.checkpoint {
                crate::views::write_auto_choice(&checkpoint.dir, &choice.views, job_key)?;
            }
            editor = Box::new(crate::views::Prepared::new(editor.name(), &choice.views, choice.edited));
            choice.views
        }
        _ => edit_views,
    };
    let auto_s = if views == ViewChoice::Auto { auto_clock.elapsed().as_secs_f64() } else { 0.0 };
    // The one semantic model of the job, for source renders and edited images alike.
    let semantic = move |img: &[f32], w: usize, h: usize| match &dino {
        Some(m) => m.features_projected(img, w, h, DINO_CHANNELS).map_err(|e| format!("DINOv2: {e}")),
        None => semantic::builtin(img, w, h),
    };
    let job = EditJob {
        gaussians,
        cameras,
        edit_views: edit_views.clone(),
        background,
        prompt,
        semantic: &semantic,
    };
    let result = transsplat_edit::run_with(&job, editor.as_mut(), &config, &mut control, progress);
    let mut result = match (result, &output) {
        (Ok(r), _) => r,
        (Err(EditError::Interrupted(step)), Some(o)) => {
            return Err(checkpoints::interrupted(step as u64, &control, &o.path))
        }
        (Err(e @ EditError::Train(_)), Some(o)) => return Err(checkpoints::failed(e, &control, &o.path)),
        (Err(e), _) => return Err(editing_error(e.into())),
    };
    result.timing.editor += auto_s;
    result.timing.total += auto_s;
    // A stop asked for during the last step (after the loop's last check) still stops:
    // nothing is written.
    if cancel.is_some_and(|c| c.load(std::sync::atomic::Ordering::SeqCst)) {
        let step = config.schedule.steps as u64;
        return Err(match &output {
            Some(o) => checkpoints::interrupted(step, &control, &o.path),
            None => EditError::Interrupted(step as usize).into(),
        });
    }
    let out = match (staged, &output) {
        (Some(staged), Some(o)) => {
            let folder = EditOutput {
                source: gaussians,
                result: &result,
                cameras,
                test_views: &test_views,
                edit_views: &edit_views,
                background,
                prompt,
                editor: &editor_name,
                segmenter: segmenter_name.as_ref().map(|(n, p)| (n.as_str(), p.as_str())),
                config: &config,
                target: target.as_deref(),
                formats: &o.formats,
                write_options: o.write_options,
            };
            staged.write(|dir| edit_folder::write(dir, &folder))?;
            let out = staged.commit()?;
            if let Some(ck) = &control.checkpoint {
                ck.remove();
            }
            Some(out)
        }
        _ => None,
    };
    Ok(EditOutcome { result, out, test_views, edit_views })
}

/// The editor an [`EditorSpec`] describes.
fn build_editor<'a>(
    spec: EditorSpec<'a>,
    gaussians: &Gaussians,
    staged: Option<&Output>,
    config: &EditConfig,
    cancel: Option<&'a AtomicBool>,
) -> Result<Box<dyn Editor + 'a>, SessionError> {
    Ok(match spec {
        EditorSpec::Folder(dir) => {
            Box::new(FolderEditor::new(dir).for_scene(transsplat_scene::fingerprint::scene(gaussians)))
        }
        EditorSpec::Command { command, timeout } => {
            let staged = staged.ok_or_else(|| {
                SessionError::Input("the command editor needs an output folder to work in".into())
            })?;
            let mut e = CommandEditor::new(command, staged.dir().join("editor"));
            if let Some(flag) = cancel {
                e = e.with_cancel(flag);
            }
            if let Some(limit) = timeout {
                e = e.with_timeout(limit);
            }
            Box::new(e)
        }
        EditorSpec::Ip2p { weights, batch } => {
            use transsplat_models::ip2p::{Ip2pEditor, Settings};
            let device = transsplat_models::default_device();
            let mut e = Ip2pEditor::load(&weights, Settings::default(), config.seed, &device)
                .map_err(|e| SessionError::Model(e.to_string()))?
                .with_batch(batch);
            if let Some(flag) = cancel {
                e = e.with_cancel(flag);
            }
            Box::new(e)
        }
        EditorSpec::Custom(editor) => editor as Box<dyn Editor + 'a>,
    })
}
