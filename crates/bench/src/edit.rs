//! `transsplat bench edit`: a whole edit job timed at a stated real size on a built-in
//! scene, run by the session layer as `transsplat edit` runs it. With the simulated
//! editor (no weights) every run is reproducible and scored against the ground truth (a
//! speed-up must not cost quality); with InstructPix2Pix at random weights
//! ([`crate::ip2p::random_editor`]) the 2D editor does the real model's arithmetic, so
//! the whole language-driven edit is timed, the editor and the lift apart.
//!
//! The sizes ([`SIZES`]) are those of the performance issue: (a) ~700k Gaussians, 42
//! edit views at 256×256; (b) ~1M Gaussians, 40 edit views at 800×600; (c) the 48-view
//! scene at 512×512; plus `quick` for tests. Every 8th camera is a test view, so 48 and
//! 46 cameras.

use crate::demo::DemoError;
use std::path::Path;
use std::sync::atomic::AtomicBool;
use std::time::Instant;
use transsplat_builtin::SimulatedEditor;
use transsplat_builtin::{build, SceneConfig};
use transsplat_edit::{EditConfig, Progress, Timing};
use transsplat_editors::Editor;
use transsplat_eval::ground_truth::{GtMetrics, Reference};
use transsplat_session::edit::{EditRequest, EditorSpec, Features};
use transsplat_session::views::ViewChoice;
use transsplat_session::SessionError;

/// One benchmark size.
#[derive(Clone, Copy, Debug)]
pub struct BenchSize {
    pub name: &'static str,
    pub scene: &'static str,
    /// Gaussian density multiplier of the built-in scene.
    pub detail: f32,
    pub width: u32,
    pub height: u32,
    /// Cameras (every 8th held out).
    pub views: usize,
}

/// The sizes `bench edit` knows.
pub const SIZES: [BenchSize; 4] = [
    BenchSize { name: "a", scene: "tabletop", detail: 15.2, width: 256, height: 256, views: 48 },
    BenchSize { name: "b", scene: "tabletop", detail: 21.7, width: 800, height: 600, views: 46 },
    BenchSize { name: "c", scene: "tabletop", detail: 15.2, width: 512, height: 512, views: 48 },
    BenchSize { name: "quick", scene: "tabletop", detail: 0.12, width: 128, height: 96, views: 16 },
];

/// The size named `name`, or an error listing the names.
pub fn size(name: &str) -> Result<BenchSize, String> {
    SIZES.iter().copied().find(|s| s.name == name).ok_or_else(|| {
        let names: Vec<&str> = SIZES.iter().map(|s| s.name).collect();
        format!("unknown bench size {name:?}; sizes are: {}", names.join(", "))
    })
}

/// The 2D editor of a timed edit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum BenchEditor {
    /// The simulated editor at this severity (scored against the ground truth).
    Simulated { severity: f32 },
    /// InstructPix2Pix with random weights, this many views per UNet call.
    Ip2p { batch: usize },
}

impl BenchEditor {
    pub fn name(&self) -> &'static str {
        match self {
            BenchEditor::Simulated { .. } => "simulated",
            BenchEditor::Ip2p { .. } => "ip2p",
        }
    }
}

/// InstructPix2Pix at random weights with the simulated editor's attention and mask: the
/// model does the real arithmetic (timed), but its attention at random weights marks no
/// target the lift could use, so the simulated editor's (cheap) says where the ball is.
struct TargetOf<E: Editor> {
    editor: E,
    target: SimulatedEditor,
}

impl<E: Editor> Editor for TargetOf<E> {
    fn name(&self) -> &str {
        self.editor.name()
    }

    fn expect_views(&mut self, views: usize) {
        self.editor.expect_views(views)
    }

    fn edit(
        &mut self,
        views: &[transsplat_editors::SourceView],
        prompt: &str,
    ) -> Result<Vec<Option<transsplat_editors::EditedView>>, transsplat_editors::Error> {
        let mut edited = self.editor.edit(views, prompt)?;
        let target = self.target.edit(views, prompt)?;
        for (e, t) in edited.iter_mut().zip(target) {
            if let (Some(e), Some(t)) = (e.as_mut(), t) {
                e.attention = t.attention;
                e.mask = t.mask;
            }
        }
        Ok(edited)
    }
}

/// What one timed edit is.
#[derive(Clone, Debug)]
pub struct EditBenchOptions<'a> {
    pub size: BenchSize,
    pub config: EditConfig,
    pub prompt: &'a str,
    pub editor: BenchEditor,
    /// Which edit views the editor edits (`edit --views`).
    pub views: ViewChoice,
}

/// What one timed edit measured.
#[derive(Clone, Debug, serde::Serialize)]
pub struct EditBench {
    pub size: &'static str,
    pub editor: &'static str,
    pub gaussians: usize,
    /// The views the editor edited (of `candidate_views`).
    pub edit_views: usize,
    pub candidate_views: usize,
    pub width: u32,
    pub height: u32,
    pub steps: usize,
    /// Building the scene and its ground truth (not part of an edit).
    pub setup_s: f64,
    /// The edit, split by stage (editor, transport, optimisation and its stages).
    pub timing: Timing,
    /// Writing the edited scene as a PLY.
    pub write_s: f64,
    /// Optimisation seconds per step (`timing.optimise / steps`).
    pub per_step_s: f64,
    /// Ground-truth scores of the result on the test views (the simulated editor's truth:
    /// meaningless for InstructPix2Pix at random weights).
    pub metrics: GtMetrics,
}

/// Builds the size's scene and edits it as `opts` says, writing the result into `work` (a
/// scratch folder); `on_progress` sees the steps.
pub fn run(
    opts: &EditBenchOptions,
    work: &Path,
    cancel: Option<&AtomicBool>,
    on_progress: &mut dyn FnMut(Progress),
) -> Result<EditBench, DemoError> {
    let EditBenchOptions { size, config, prompt, editor: which, views } = opts;
    let clock = Instant::now();
    let cfg = SceneConfig {
        seed: config.seed,
        detail: size.detail,
        width: size.width,
        height: size.height,
        views: size.views,
        open: false,
    };
    let scene = build(size.scene, &cfg)?;
    let severity = match which {
        BenchEditor::Simulated { severity } => *severity,
        BenchEditor::Ip2p { .. } => 0.0,
    };
    let mut simulated = SimulatedEditor::new(&scene, severity, config.seed);
    simulated.instruct(prompt)?;
    let reference = Reference::new(&scene, simulated.ground_truth(), simulated.target_labels());
    let editor: Box<dyn Editor + Send + '_> = match which {
        BenchEditor::Simulated { .. } => Box::new(simulated),
        BenchEditor::Ip2p { batch } => {
            let device = transsplat_models::default_device();
            let mut e = crate::ip2p::random_editor(&device, config.seed)
                .map_err(|e| DemoError::Session(SessionError::Model(e)))?
                .with_batch(*batch);
            if let Some(flag) = cancel {
                e = e.with_cancel(flag);
            }
            Box::new(TargetOf { editor: e, target: simulated })
        }
    };
    let source = scene.gaussians_with_labels();
    let candidates = scene.train_views().len();
    let setup_s = clock.elapsed().as_secs_f64();
    tracing::info!(
        "bench edit {}: {} Gaussians, {candidates} edit views of {}x{}, {} editor, {} steps (setup {setup_s:.1} s)",
        size.name,
        source.len(),
        size.width,
        size.height,
        which.name(),
        config.schedule.steps
    );
    let request = EditRequest {
        gaussians: &source,
        cameras: &scene.cameras,
        prompt,
        editor: EditorSpec::Custom(editor),
        segmenter: None,
        features: Features::Builtin,
        views: *views,
        config: config.clone(),
        background: scene.background,
        output: None,
        target: None,
    };
    let outcome = transsplat_session::edit::run(request, cancel, on_progress)?;
    let res = outcome.result;
    let clock = Instant::now();
    let out = work.join("point_cloud.ply");
    transsplat_scene::ply::write(&out, &res.gaussians)?;
    let write_s = clock.elapsed().as_secs_f64();
    std::fs::remove_file(&out).map_err(|e| transsplat_scene::Error::io(&out, e))?;
    let steps = config.schedule.steps;
    Ok(EditBench {
        size: size.name,
        editor: which.name(),
        gaussians: source.len(),
        edit_views: outcome.edit_views.len(),
        candidate_views: candidates,
        width: size.width,
        height: size.height,
        steps,
        setup_s,
        per_step_s: res.timing.optimise / steps.max(1) as f64,
        timing: res.timing,
        write_s,
        metrics: reference.score(&scene.cameras, &res.gaussians),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quick_bench_times_every_stage_and_scores_the_edit() {
        let dir = tempfile::tempdir().unwrap();
        let mut config = EditConfig::default();
        config.schedule.steps = 12;
        config.schedule.transport_every = 6;
        let mut full = config.clone();
        full.schedule.delta_render = false;
        let bench = |c: &EditConfig| {
            let opts = EditBenchOptions {
                size: size("quick").unwrap(),
                config: c.clone(),
                prompt: "make the ball blue",
                editor: BenchEditor::Simulated { severity: 0.0 },
                views: ViewChoice::All,
            };
            run(&opts, dir.path(), None, &mut |_| {}).unwrap()
        };
        // Full renders bin every step; rendering the colour change alone builds blend
        // weights instead and never bins in a step.
        for (r, delta) in [(bench(&full), false), (bench(&config), true)] {
            assert_eq!((r.steps, r.edit_views), (12, 14));
            let st = &r.timing.stages;
            let (binning, weights) = if delta { (st.weights, st.binning) } else { (st.binning, st.weights) };
            assert!(weights < 1e-3 * r.timing.optimise, "delta {delta}: {weights}");
            for (name, v) in [
                ("binning or weights", binning),
                ("tiles", st.tiles),
                ("image_loss", st.image_loss),
                ("backward", st.backward),
                ("method_terms", st.method_terms),
                ("optimiser", st.optimiser),
            ] {
                assert!(v > 0.0 && v < r.timing.optimise, "{name}: {v} of {}", r.timing.optimise);
            }
            let staged = st.binning
                + st.weights
                + st.tiles
                + st.image_loss
                + st.backward
                + st.method_terms
                + st.optimiser;
            assert!(
                staged <= r.timing.optimise * 1.001,
                "stages {staged} exceed the optimisation {}",
                r.timing.optimise
            );
            assert!(r.timing.transport > 0.0 && r.write_s > 0.0);
            assert!(r.metrics.target_psnr.is_finite() && r.metrics.background_psnr.is_finite());
        }
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0, "the scratch PLY is removed");
        assert!(size("huge").unwrap_err().contains("a, b, c, quick"));
    }
}
