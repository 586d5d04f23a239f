//! `transsplat edit`: language-driven editing of a scene with any 2D editor.

use super::common::{
    load_cameras, load_scene, parse_rgb, show_steps, steps_bar, CheckpointArgs, SceneArgs, SpzWriteArgs,
};
use anyhow::{bail, Context, Result};
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::time::Duration;
use transsplat_builtin::SimulatedEditor;
use transsplat_edit::{EditConfig, Progress};
use transsplat_editors::phrase::target_phrase;
use transsplat_scene::formats::{self, SceneFormat};
use transsplat_scene::spz;
use transsplat_session as session;
use transsplat_session::edit::{EditRequest, EditorSpec, Features, OutputRequest, SegmenterSpec};
use transsplat_session::views::ViewChoice;

/// Which 2D editor produces the edits.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum EditorKind {
    /// Edited images made by any tool, in `--edits DIR` (see `transsplat views export`).
    Folder,
    /// Runs `--command CMD` on exported views (file protocol in the editors crate docs).
    Command,
    /// Ground-truth edits of a built-in scene, corrupted like a 2D editor's.
    Simulated,
    /// InstructPix2Pix from a local diffusers folder (`--ip2p-weights DIR`).
    Ip2p,
}

/// Arguments of `transsplat edit`.
#[derive(clap::Args, Debug)]
pub struct EditArgs {
    #[command(flatten)]
    pub scene: SceneArgs,
    /// Cameras: cameras.json, transforms.json or a COLMAP folder (default: beside the scene).
    #[arg(long, conflicts_with = "data")]
    pub cameras: Option<PathBuf>,
    /// A dataset folder (COLMAP, transforms.json or cameras.json layout) giving the cameras.
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// The instruction, e.g. "make the ball blue".
    #[arg(long)]
    pub prompt: String,
    #[arg(long, value_enum)]
    pub editor: EditorKind,
    /// Folder of edited images (`folder` editor).
    #[arg(long)]
    pub edits: Option<PathBuf>,
    /// Command line to run (`command` editor).
    #[arg(long)]
    pub command: Option<String>,
    /// Seconds the command editor may run before it is ended with its whole process
    /// group (0 = no limit). The default, 4 hours, is generous for hundreds of views on a
    /// GPU; a hung editor is ended instead of waited for forever.
    #[arg(long, default_value_t = 14_400)]
    pub editor_timeout: u64,
    /// InstructPix2Pix pipeline folder (`ip2p` editor), as written by
    /// `hf download timbrooks/instruct-pix2pix --local-dir DIR`.
    #[arg(long, value_name = "DIR")]
    pub ip2p_weights: Option<PathBuf>,
    /// Views the `ip2p` editor edits per pipeline call (the UNet then runs a batch of 3 ×
    /// this many; views keep their own noise and timesteps, so the edit does not depend
    /// on it). More views per call use more memory.
    #[arg(long, default_value_t = transsplat_models::ip2p::editor::DEFAULT_BATCH as u64,
          value_parser = clap::value_parser!(u64).range(1..=64))]
    pub ip2p_batch: u64,
    /// DINOv2 folder (`facebook/dinov2-small` or `-base`, Hugging Face layout): its
    /// features become the semantic features E of the source renders and of every edited
    /// view (the built-in fallback features otherwise).
    #[arg(long, value_name = "DIR")]
    pub dino_weights: Option<PathBuf>,
    /// Restrict each edited view to a CLIPSeg mask of what PHRASE names ("the ball"): its
    /// support becomes its attention inside the mask (replacing any mask the editor gave).
    /// Without PHRASE, the object the instruction edits ("make the ball blue": "the
    /// ball"; the rules are in docs/cli.md). Needs --segment-weights.
    #[arg(long, value_name = "PHRASE", num_args = 0..=1, default_missing_value = "", requires = "segment_weights")]
    pub segment: Option<String>,
    /// CLIPSeg folder for --segment, as written by
    /// `hf download CIDAS/clipseg-rd64-refined --local-dir DIR`.
    #[arg(long, value_name = "DIR", requires = "segment")]
    pub segment_weights: Option<PathBuf>,
    /// SAM folder (`SamModel` layout: `hf download Zigeng/SlimSAM-uniform-77 --local-dir
    /// DIR`, or `facebook/sam-vit-base`): each CLIPSeg mask of --segment is sharpened by
    /// SAM, prompted by the mask's box and most confident pixel.
    #[arg(long, value_name = "DIR", requires = "segment")]
    pub sam_weights: Option<PathBuf>,
    /// Restrict each edited view to a mask made elsewhere: DIR/<stem>.png, grey (inside
    /// where > 0.5), one per edited view at its size (replacing any mask the editor gave).
    #[arg(long, value_name = "DIR", conflicts_with = "segment")]
    pub masks: Option<PathBuf>,
    /// Which views the 2D editor edits: all (every camera but each 8th), K of them or
    /// 1/N, spread over the capture (the editor then runs K times; the transport, fusion
    /// and image loss work from those K views), or auto: a quarter of them as seeds,
    /// then rounds of the views that most lower the uncertainty of the target's edit
    /// until it is within 2/255 (a consistent editor stops early).
    #[arg(long, value_parser = ViewChoice::parse, default_value = "all")]
    pub views: ViewChoice,
    /// Simulated editor severity (0 = perfect edits).
    #[arg(long, value_parser = super::common::finite_f32, default_value_t = 1.0)]
    pub severity: f32,
    /// TOML file of edit settings.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Method: transsplat, paper, naive, masklift, no_leaksup, no_prototype, geometric.
    #[arg(long)]
    pub method: Option<String>,
    /// Optimisation steps (overrides the config).
    #[arg(long)]
    pub steps: Option<usize>,
    /// Override any setting, e.g. `--set transport.top_k=128 --set loss.leak=0.2`.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Background colour R,G,B in [0, 1].
    #[arg(long, value_parser = parse_rgb, default_value = "0,0,0")]
    pub background: [f32; 3],
    /// Output folder (replaced only if it holds an earlier edit's output).
    #[arg(long)]
    pub out: PathBuf,
    /// Also write the edited scene in these formats beside point_cloud.ply
    /// (compressed-ply, spz, glb, sog; comma-separated), for web viewers.
    #[arg(long, value_delimiter = ',', value_parser = SceneFormat::parse)]
    pub format: Vec<SceneFormat>,
    #[command(flatten)]
    pub spz: SpzWriteArgs,
    #[command(flatten)]
    pub checkpoints: CheckpointArgs,
}

/// The built-in scene a dataset folder written by `transsplat scene` came from.
fn builtin_scene(scene_arg: &Path) -> Result<transsplat_builtin::Scene> {
    let root = if scene_arg.is_dir() {
        scene_arg.to_path_buf()
    } else {
        scene_arg
            .parent()
            .and_then(Path::parent)
            .and_then(Path::parent)
            .map(Path::to_path_buf)
            .unwrap_or_default()
    };
    let path = root.join("labels.json");
    if !path.is_file() {
        bail!(
            "{}: the simulated editor needs a built-in scene folder written by `transsplat scene`",
            path.display()
        );
    }
    let labels = transsplat_builtin::Labels::read(&path)?;
    let (name, cfg) = (&labels.scene, labels.scene_config());
    Ok(transsplat_builtin::build(name, &cfg)?)
}

/// Runs `transsplat edit`: the arguments as an [`EditRequest`] for the session layer.
pub fn run(args: &EditArgs, cancel: &AtomicBool) -> Result<()> {
    if args.prompt.trim().is_empty() {
        bail!("--prompt is empty: give an instruction such as \"make the ball blue\"");
    }
    let base = match &args.config {
        Some(p) => EditConfig::from_toml_file(p).map_err(anyhow::Error::msg)?,
        None => EditConfig::default(),
    };
    let config = base.assemble(args.method.as_deref(), &args.set, args.steps).map_err(anyhow::Error::msg)?;
    let (g, scene_path) = load_scene(&args.scene)?;
    let (cams, cam_path) = load_cameras(args.cameras.as_deref().or(args.data.as_deref()), &args.scene.scene)?;
    let features = args.dino_weights.clone().map_or(Features::Builtin, Features::Dinov2);
    let segmenter = segmenter_spec(args)?;
    // A missing model or mask folder is refused before the editor is built.
    features.check()?;
    if let Some(s) = &segmenter {
        s.check()?;
    }
    let (editor, target) = editor_spec(args, &scene_path, &g, &config)?;
    let bar = steps_bar(config.schedule.steps as u64);
    let editor_name = editor.name();
    let request = EditRequest {
        gaussians: &g,
        cameras: &cams,
        prompt: &args.prompt,
        editor,
        segmenter,
        features,
        views: args.views,
        background: args.background,
        output: Some(output_request(args, scene_path, cam_path)),
        target,
        config,
    };
    let outcome = session::edit::run(request, Some(cancel), &mut |p| show_progress(&bar, &editor_name, p));
    bar.finish_and_clear();
    let outcome = outcome?;
    let timing = &outcome.result.timing;
    println!(
        "edited {} Gaussians in {:.1} s (transport {:.1} s); wrote {}",
        outcome.result.gaussians.len(),
        timing.total,
        timing.transport,
        outcome.out.unwrap_or_default().display()
    );
    Ok(())
}

/// Where the target masks come from: CLIPSeg on `--segment` with `--segment-weights`
/// (a bare `--segment`: the object the instruction edits), or the folder `--masks`;
/// `None` keeps the editor's own.
fn segmenter_spec(args: &EditArgs) -> Result<Option<SegmenterSpec<'static>>> {
    Ok(match (&args.segment, &args.segment_weights, &args.masks) {
        (Some(phrase), Some(weights), _) => {
            let phrase = match phrase.as_str() {
                "" => {
                    let derived = target_phrase(&args.prompt).with_context(|| {
                        format!(
                            "--segment: no object to segment found in the instruction {:?}; name it: --segment \"the ball\"",
                            args.prompt
                        )
                    })?;
                    tracing::info!("--segment: segmenting {derived:?}, the object the instruction edits");
                    derived
                }
                given => given.to_string(),
            };
            Some(SegmenterSpec::ClipSeg { weights: weights.clone(), phrase, sam: args.sam_weights.clone() })
        }
        (_, _, Some(dir)) => Some(SegmenterSpec::Folder(dir.clone())),
        _ => None,
    })
}

/// The output folder `--out`, with every input the flags name (as given and as
/// resolved) for the output rule, the formats written beside the PLY and checkpoints.
fn output_request(args: &EditArgs, scene_path: PathBuf, cam_path: PathBuf) -> OutputRequest {
    let mut inputs = vec![args.scene.scene.clone(), scene_path, cam_path];
    inputs.extend(
        [
            &args.edits,
            &args.config,
            &args.ip2p_weights,
            &args.dino_weights,
            &args.segment_weights,
            &args.sam_weights,
            &args.masks,
        ]
        .into_iter()
        .flatten()
        .cloned(),
    );
    OutputRequest {
        path: args.out.clone(),
        inputs,
        formats: args.format.clone(),
        write_options: formats::WriteOptions {
            spz: spz::Options { version: args.spz.spz_version, axes: args.scene.spz_axes },
        },
        checkpoints: Some(args.checkpoints.spec()),
    }
}

/// The editor `--editor` names, and the ground-truth target per Gaussian where it is
/// known (the simulated editor of a built-in scene).
fn editor_spec(
    args: &EditArgs,
    scene_path: &Path,
    g: &transsplat_scene::Gaussians,
    config: &EditConfig,
) -> Result<(EditorSpec<'static>, Option<Vec<bool>>)> {
    Ok(match args.editor {
        EditorKind::Folder => {
            (EditorSpec::Folder(args.edits.clone().context("--editor folder needs --edits DIR")?), None)
        }
        EditorKind::Command => {
            let command = args.command.clone().context("--editor command needs --command CMD")?;
            let timeout = (args.editor_timeout > 0).then(|| Duration::from_secs(args.editor_timeout));
            (EditorSpec::Command { command, timeout }, None)
        }
        EditorKind::Simulated => {
            let (sim, target) = simulated_editor(&args.scene.scene, scene_path, g, args, config)?;
            (EditorSpec::Custom(Box::new(sim)), Some(target))
        }
        EditorKind::Ip2p => {
            let weights = args.ip2p_weights.clone().with_context(|| {
                format!(
                    "--editor ip2p needs --ip2p-weights DIR; get it with `{}`",
                    transsplat_models::ip2p::download_hint(Path::new("DIR"))
                )
            })?;
            (EditorSpec::Ip2p { weights, batch: args.ip2p_batch as usize }, None)
        }
    })
}

/// The progress bar and log lines of an edit.
fn show_progress(bar: &indicatif::ProgressBar, editor: &str, p: Progress) {
    match p {
        Progress::Step { step, loss, .. } => {
            bar.set_position(step as u64);
            if step % 10 == 0 {
                bar.set_message(format!("loss {loss:.4}"));
            }
        }
        Progress::Round(r) => tracing::debug!(
            "transport round {}: objective {:.4}, mean gate {:.3}",
            r.round,
            r.objective,
            r.mean_gate
        ),
        Progress::Edited { views, seconds } => {
            tracing::info!("editor {editor} edited {views} views in {seconds:.1} s");
            show_steps(bar);
        }
    }
}

/// The simulated editor of the built-in scene `scene_arg` came from, told the
/// instruction, and the ground-truth target per Gaussian.
fn simulated_editor(
    scene_arg: &Path,
    scene_path: &Path,
    g: &transsplat_scene::Gaussians,
    args: &EditArgs,
    config: &EditConfig,
) -> Result<(SimulatedEditor, Vec<bool>)> {
    let scene = builtin_scene(scene_arg)?;
    if scene.gaussians.len() != g.len() {
        bail!("{}: the scene does not match its built-in source (labels.json)", scene_path.display());
    }
    let mut sim = SimulatedEditor::new(&scene, args.severity, config.seed);
    // the instruction's target labels (the Gaussians the ground truth changes)
    sim.instruct(&args.prompt)?;
    let target = scene.labels.iter().map(|l| sim.target_labels().contains(l)).collect();
    Ok((sim, target))
}
