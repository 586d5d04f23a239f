//! The built-in benchmark (`transsplat demo`): builds a built-in scene, edits its
//! training views with the simulated editor on a stated instruction, runs TransSplat
//! and every baseline and ablation in the same loop, scores each edited scene
//! against the ground truth on the test views, and writes `metrics.json`, the
//! edited scenes and `report.html`.

use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use transsplat_builtin::SimulatedSegmenter;
use transsplat_builtin::{build, labels_from_extra, LabelRender, Scene, SceneConfig, SimulatedEditor};
use transsplat_edit::{semantic, EditConfig, EditError, EditJob, EditResult, Method, Progress};
use transsplat_editors::segment::Segmented;
use transsplat_editors::{Editor, SourceView};
use transsplat_eval::ground_truth::{GtMetrics, Reference, PSNR_CAP};
use transsplat_eval::metrics::{auroc, psnr_from_mse, squared_error};
use transsplat_raster::{render, RenderOptions, Splats};
use transsplat_scene::{image, Camera, Gaussians};
use transsplat_session::edit::{EditRequest, EditorSpec, Features, OutputRequest};
use transsplat_session::edit_folder::{self, EditOutput};
use transsplat_session::report::Page;
use transsplat_session::views::ViewChoice;
use transsplat_session::{Output, SessionError};

/// Settings of a demo run.
#[derive(Clone, Debug)]
pub struct DemoOptions {
    pub out: PathBuf,
    pub scene: String,
    pub prompt: String,
    pub severity: f32,
    pub quick: bool,
    pub methods: Vec<Method>,
    pub config: EditConfig,
    pub seed: u64,
    /// Train the scene from its own renders for this many steps and edit the trained
    /// scene (0: edit the built-in Gaussians). Scenes trained from photos are what users
    /// bring; see [`crate::trained`].
    pub trained: u64,
    /// With `trained`, also train a scene the same way from the renders of the true
    /// edit and score it against the truth inside the target ([`Fidelity::retrained`]):
    /// what the trainer reaches when the images themselves show the edit.
    pub retrain_truth: bool,
    /// Which training views the simulated editor edits (`--views`).
    pub views: ViewChoice,
    /// Masks from the simulated segmenter at this severity with every edit
    /// (`transsplat_builtin::segmenter`); `None`: the editor's own (none).
    pub segmenter: Option<f32>,
}

impl Default for DemoOptions {
    fn default() -> Self {
        DemoOptions {
            out: PathBuf::from("demo"),
            scene: "tabletop".into(),
            prompt: "make the ball blue".into(),
            severity: 1.0,
            quick: false,
            methods: Method::ALL.to_vec(),
            config: EditConfig::default(),
            seed: 0,
            trained: 0,
            retrain_truth: false,
            views: ViewChoice::All,
            segmenter: None,
        }
    }
}

/// One method's scores.
#[derive(Clone, Debug, serde::Serialize)]
pub struct MethodScore {
    pub name: String,
    #[serde(flatten)]
    pub metrics: GtMetrics,
    pub gate_auroc: Option<f64>,
    pub seconds: f64,
    pub transport_seconds: f64,
}

/// How well a scene trained from the built-in scene's renders reproduces the unedited
/// truth on the test views (dB): over whole images, inside the target and over the
/// background. The target value is the bar of an edit's target PSNR on that scene.
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct Fidelity {
    pub test_psnr: f64,
    pub target_psnr: f64,
    pub background_psnr: f64,
    /// With [`DemoOptions::retrain_truth`]: target PSNR, against the true edit, of a
    /// scene trained the same way from the true edit's renders. The source's
    /// `target_psnr` ignores that an edit changes the contrast at the object's
    /// silhouette (a blue ball on a brown table shows the trained geometry's error more
    /// than the red one did); this one does not.
    pub retrained: Option<f64>,
}

/// What a demo run produced.
#[derive(Clone, Debug)]
pub struct DemoOutcome {
    /// The output folder.
    pub out: PathBuf,
    /// Per method, in the order run.
    pub scores: Vec<MethodScore>,
    /// The trained source's fidelity, for a scene trained from its renders.
    pub trained: Option<Fidelity>,
    /// The 2D evidence's own PSNR inside the target (dB; see [`CaseRun`]).
    pub evidence_psnr: f64,
}

/// The demo's errors.
#[derive(Debug, thiserror::Error)]
pub enum DemoError {
    #[error(transparent)]
    Scene(#[from] transsplat_builtin::Error),
    #[error(transparent)]
    Editor(#[from] transsplat_editors::Error),
    #[error(transparent)]
    Edit(#[from] EditError),
    #[error(transparent)]
    Io(#[from] transsplat_scene::Error),
    #[error(transparent)]
    Trained(#[from] crate::trained::TrainedError),
    /// A `--views` choice the scene cannot give.
    #[error("{0}")]
    Views(String),
    /// A capture case whose capture was not loaded.
    #[error("{0}")]
    Capture(String),
    /// A method's edit job (the session layer) refused or failed.
    #[error(transparent)]
    Session(SessionError),
}

impl From<SessionError> for DemoError {
    /// The session's errors as the demo's own where it has one, so a stop is still
    /// [`EditError::Interrupted`] and a failed write is still [`DemoError::Io`] (whose path
    /// [`staged`] gives back as the user's).
    fn from(e: SessionError) -> Self {
        match e {
            SessionError::Io(e) => DemoError::Io(e),
            SessionError::Edit(e) => DemoError::Edit(e),
            SessionError::Interrupted { step, .. } => DemoError::Edit(EditError::Interrupted(step as usize)),
            e => DemoError::Session(e),
        }
    }
}

/// `metrics.json`, the marker of a finished demo folder: the case and each method's
/// scores against the ground truth on the test views.
#[derive(Debug, serde::Serialize)]
pub struct DemoMetrics<'a> {
    pub scene: &'a str,
    pub prompt: &'a str,
    /// The simulated editor's description of the edit.
    pub edit: &'a str,
    pub severity: f32,
    pub quick: bool,
    /// Gaussians of the edited source (built or trained).
    pub gaussians: usize,
    pub test_views: &'a [usize],
    pub trained_steps: u64,
    pub trained: Option<Fidelity>,
    /// The editor's images of the edit views against the true edit, inside the target
    /// (dB): the evidence every method lifts.
    pub evidence_psnr: f64,
    pub methods: std::collections::BTreeMap<&'a str, MethodMetrics<'a>>,
}

/// One method's entry of [`DemoMetrics`].
#[derive(Debug, serde::Serialize)]
pub struct MethodMetrics<'a> {
    #[serde(flatten)]
    pub metrics: &'a GtMetrics,
    pub gate_auroc: Option<f64>,
    pub seconds: f64,
    pub transport_seconds: f64,
}

/// Marker file of a finished demo folder.
pub const MARKER: &str = "metrics.json";

/// The edit of a built-in scene's training views (its `source` Gaussians, built or
/// trained) with the built-in semantic features: the job of the demo and the benches.
pub fn scene_job<'a>(scene: &'a Scene, source: &'a Gaussians, prompt: &'a str) -> EditJob<'a> {
    EditJob {
        gaussians: source,
        cameras: &scene.cameras,
        edit_views: scene.train_views(),
        background: scene.background,
        prompt,
        semantic: &semantic::builtin,
    }
}

/// The `--quick` schedule: at most 150 steps, a transport round at least every 50.
/// Fronts apply it before the user's own settings, so an explicit setting wins.
pub fn quick_schedule(config: &mut EditConfig) {
    config.schedule.steps = config.schedule.steps.min(150);
    config.schedule.transport_every = config.schedule.transport_every.min(50);
}

/// Runs the demo; `on_method(name, progress)` reports progress. `opts.quick` picks the
/// small scene; the edit schedule is `opts.config` as given (see [`quick_schedule`]).
pub fn run(
    opts: &DemoOptions,
    cancel: Option<&AtomicBool>,
    on_progress: &mut dyn FnMut(&str, Progress),
) -> Result<DemoOutcome, DemoError> {
    staged(&opts.out, |dir| run_into(dir, opts, cancel, on_progress))
}

/// What a case writes into its staged folder returns: the scores, the trained source's
/// fidelity and the 2D evidence's target PSNR.
pub(crate) type CaseScores = (Vec<MethodScore>, Option<Fidelity>, f64);

/// Runs `write` into a staged folder for `out` and commits it; a failed write names the
/// output the user gave, not the staging folder.
pub(crate) fn staged(
    out: &Path,
    write: impl FnOnce(&Path) -> Result<CaseScores, DemoError>,
) -> Result<DemoOutcome, DemoError> {
    let staged = Output::begin(out, &[], MARKER)?;
    let (scores, trained, evidence_psnr) = match write(staged.dir()) {
        Ok(done) => done,
        Err(DemoError::Io(e)) => return Err(DemoError::Io(staged.user_error(e))),
        Err(e) => return Err(e),
    };
    let out = staged.commit()?;
    Ok(DemoOutcome { out, scores, trained, evidence_psnr })
}

/// The demo written into `dir` (the staged output folder).
fn run_into(
    dir: &Path,
    opts: &DemoOptions,
    cancel: Option<&AtomicBool>,
    on_progress: &mut dyn FnMut(&str, Progress),
) -> Result<CaseScores, DemoError> {
    let dir = dir.to_path_buf();
    let scfg = if opts.quick { SceneConfig::quick() } else { SceneConfig::default() };
    let scene = build(&opts.scene, &SceneConfig { seed: opts.seed, ..scfg })?;
    let mut sim = SimulatedEditor::new(&scene, opts.severity, opts.seed);
    let description = sim.instruct(&opts.prompt)?.describe();
    let target_labels = sim.target_labels().to_vec();
    let truth = sim.ground_truth().clone();
    tracing::info!("demo: scene {} ({} Gaussians), {description}", scene.name, scene.gaussians.len());
    let mut reference = Reference::new(&scene, &truth, &target_labels);
    // Trains a scene like `scene` from its renders, the run's steps and seed.
    let mut train = |from: &Scene| {
        crate::trained::train_from_renders(from, opts.trained, opts.seed, &dir, cancel, &mut |s, n| {
            on_progress("train", Progress::Step { step: s as usize, steps: n as usize, loss: 0.0 })
        })
    };
    let (source, trained) = if opts.trained > 0 {
        let (g, psnr) = train(&scene)?;
        let (target, background) = reference.fidelity(&scene.cameras, &g);
        tracing::info!(
            "trained scene against the unedited truth: PSNR {target:.2} dB inside the target, {background:.2} dB \
             over the background (the target value bounds an edit's target PSNR)"
        );
        // Background PSNR then measures what the edit changed outside the target, not
        // the trained scene's own error.
        reference = reference.with_source(&scene.cameras, &g);
        let retrained = if opts.retrain_truth {
            let (t, _) = train(&Scene { gaussians: truth.clone(), ..scene.clone() })?;
            let r = reference.score(&scene.cameras, &t).target_psnr;
            tracing::info!(
                "scene trained from the true edit's renders: target PSNR {r:.2} dB against the truth"
            );
            Some(r)
        } else {
            None
        };
        (
            g,
            Some(Fidelity {
                test_psnr: psnr as f64,
                target_psnr: target,
                background_psnr: background,
                retrained,
            }),
        )
    } else {
        (scene.gaussians_with_labels(), None)
    };
    let (test, edit_views) = transsplat_session::views::split(&scene.cameras, opts.views)
        .map_err(|e| DemoError::Views(e.to_string()))?;
    // Gaussian labels exist for the built-in Gaussians only (not for a trained scene).
    let built_labels = (opts.trained == 0).then(|| scene.labels.clone());
    let target_of = |g: &Gaussians| {
        let labels = labels_from_extra(g)
            .or_else(|| built_labels.clone())
            .filter(|l| l.len() == g.len())
            .unwrap_or_default();
        labels.iter().map(|l| target_labels.contains(l)).collect()
    };
    let truth_of = |v: usize| scene.render_edited(&truth, v).expect("an edit view exists");
    let case = CaseRun {
        scene: &scene.name,
        description: &description,
        cameras: &scene.cameras,
        source: &source,
        edit_views,
        test,
        background: scene.background,
        reference: &reference,
        target_labels: &target_labels,
        target_of: &target_of,
        truth_of: &truth_of,
        trained,
    };
    let (scores, evidence) = match opts.segmenter {
        None => run_case(&dir, opts, &case, &sim, cancel, on_progress)?,
        Some(severity) => {
            let segmenter =
                SimulatedSegmenter::new(&scene, &target_labels, sim.distractor(), severity, opts.seed);
            let editor = Segmented::new(sim.clone(), segmenter, opts.prompt.clone());
            run_case(&dir, opts, &case, &editor, cancel, on_progress)?
        }
    };
    Ok((scores, trained, evidence))
}

/// What a case hands to [`run_case`]: the scene, its source, the edit's truth and how to
/// score against it. The built-in demo and a capture case (`crate::capture`) fill it.
pub(crate) struct CaseRun<'a> {
    pub scene: &'a str,
    /// The edit in words (the simulated editor's description).
    pub description: &'a str,
    pub cameras: &'a [Camera],
    /// The edited source (built or trained).
    pub source: &'a Gaussians,
    pub edit_views: Vec<usize>,
    pub test: Vec<usize>,
    pub background: [f32; 3],
    pub reference: &'a Reference,
    /// The target's labels in [`CaseRun::truth_of`]'s label renders.
    pub target_labels: &'a [u32],
    /// Which Gaussians of an edited scene are the target (empty when unknown).
    pub target_of: &'a dyn Fn(&Gaussians) -> Vec<bool>,
    /// The true edit of a camera with its labels.
    pub truth_of: &'a (dyn Fn(usize) -> LabelRender + Sync),
    pub trained: Option<Fidelity>,
}

/// The 2D evidence's own PSNR inside the target: the editor's images of the edit views
/// (from the source's renders) against the true edit, squared errors pooled over the
/// target's pixels of every view (dB, capped). A corruption whose mean is off (a
/// saturation below 1, a hue shift) leaves every method short of the truth by about what
/// this shows; a method above it has averaged the views' independent errors away.
fn evidence_psnr<E: Editor + Clone>(case: &CaseRun, editor: &E, prompt: &str) -> Result<f64, DemoError> {
    let splats = Splats::new(case.source);
    let opts = RenderOptions { background: case.background };
    let images: Vec<Vec<f32>> =
        case.edit_views.iter().map(|&v| render(&splats, &case.cameras[v], &opts).0.rgb).collect();
    let views: Vec<SourceView> = case
        .edit_views
        .iter()
        .zip(&images)
        .map(|(&v, image)| SourceView { index: v, camera: &case.cameras[v], image })
        .collect();
    let edited = editor.clone().edit(&views, prompt)?;
    let (mut se, mut n) = (0.0, 0);
    for (view, out) in views.iter().zip(&edited) {
        let truth = (case.truth_of)(view.index);
        let inside = truth.mask_of(case.target_labels);
        // a view the editor returned nothing for is its source render
        let image = out.as_ref().map_or(view.image, |e| &e.image[..]);
        let (a, b) = squared_error(image, &truth.rgb, Some(&inside));
        (se, n) = (se + a, n + b);
    }
    Ok(if n == 0 { f64::NAN } else { psnr_from_mse(se / n as f64).min(PSNR_CAP) })
}

/// Runs every method of `opts` on `case` with (a fresh copy of) `editor`, scores each
/// against the case's reference and writes the method folders, `metrics.json` and
/// `report.html` into `dir`; returns the scores and the 2D evidence's own target PSNR.
pub(crate) fn run_case<E: Editor + Clone + Send>(
    dir: &Path,
    opts: &DemoOptions,
    case: &CaseRun,
    editor: &E,
    cancel: Option<&AtomicBool>,
    on_progress: &mut dyn FnMut(&str, Progress),
) -> Result<(Vec<MethodScore>, f64), DemoError> {
    let reference = case.reference;
    let test = &case.test;
    let stems: Vec<String> = test.iter().map(|&v| case.cameras[v].stem()).collect();

    // Reference images for the report.
    std::fs::create_dir_all(dir.join("reference")).map_err(|e| transsplat_scene::Error::io(dir, e))?;
    for (k, stem) in stems.iter().enumerate() {
        let cam = &case.cameras[test[k]];
        let (w, h) = (cam.width as usize, cam.height as usize);
        image::write_png(&dir.join(format!("reference/source_{stem}.png")), w, h, &reference.source[k])?;
        image::write_png(&dir.join(format!("reference/truth_{stem}.png")), w, h, &reference.truth[k])?;
    }
    let evidence = evidence_psnr(case, editor, &opts.prompt)?;
    tracing::info!("the editor's images against the true edit inside the target: {evidence:.2} dB");

    let config = opts.config.clone();
    let mut scores = Vec::new();
    let mut results: Vec<(Method, EditResult)> = Vec::new();
    // The top report's 3D viewer: the first method's edit.
    let mut viewer: Option<(String, String)> = None;
    let target = (case.target_of)(case.source);
    for &m in &opts.methods {
        let name = m.name();
        let cfg = config.for_method(m);
        // Each method is one edit job of the session layer, as `transsplat edit` runs it,
        // written into its own folder of the demo's staged output.
        let request = EditRequest {
            gaussians: case.source,
            cameras: case.cameras,
            prompt: &opts.prompt,
            editor: EditorSpec::Custom(Box::new(editor.clone())),
            segmenter: None,
            features: Features::Builtin,
            views: opts.views,
            config: cfg.clone(),
            background: case.background,
            output: Some(OutputRequest {
                path: dir.join(name),
                inputs: Vec::new(),
                formats: Vec::new(),
                write_options: Default::default(),
                checkpoints: None,
            }),
            target: Some(target.clone()),
        };
        let outcome = transsplat_session::edit::run(request, cancel, &mut |p| on_progress(name, p))?;
        debug_assert_eq!(&outcome.test_views, test, "one view split");
        debug_assert!(
            opts.views == ViewChoice::Auto || outcome.edit_views == case.edit_views,
            "one view choice"
        );
        let res = outcome.result;
        let metrics = reference.score(case.cameras, &res.gaussians);
        let is_target = (case.target_of)(&res.gaussians);
        let gate_auroc =
            res.gate.as_ref().filter(|_| !is_target.is_empty()).and_then(|g| auroc(g, &is_target));
        if let Some(g) = res.gate.as_ref().filter(|_| !is_target.is_empty()) {
            let mean = |want: bool| {
                let v: Vec<f32> =
                    g.iter().zip(&is_target).filter(|(_, &t)| t == want).map(|(&x, _)| x).collect();
                v.iter().sum::<f32>() / v.len().max(1) as f32
            };
            tracing::info!("{name}: mean gate on the target {:.3}, elsewhere {:.3}", mean(true), mean(false));
        }
        if viewer.is_none() {
            let output = EditOutput {
                source: case.source,
                result: &res,
                cameras: case.cameras,
                test_views: test,
                edit_views: &outcome.edit_views,
                background: case.background,
                prompt: &opts.prompt,
                editor: editor.name(),
                segmenter: None,
                config: &cfg,
                target: Some(&target),
                formats: &[],
                write_options: Default::default(),
            };
            viewer = Some((name.to_string(), edit_folder::viewer_section(&output)?));
        }
        tracing::info!(
            "{name}: target PSNR {:.2}, background PSNR {:.2}, PSNR {:.2}, SSIM {:.4}, gate AUROC {}, {:.1} s (transport {:.1} s)",
            metrics.target_psnr,
            metrics.background_psnr,
            metrics.psnr,
            metrics.ssim,
            gate_auroc.map_or("-".into(), |a| format!("{a:.4}")),
            res.timing.total,
            res.timing.transport
        );
        scores.push(MethodScore {
            name: name.into(),
            metrics,
            gate_auroc,
            seconds: res.timing.total,
            transport_seconds: res.timing.transport,
        });
        results.push((m, res));
    }

    let metrics = DemoMetrics {
        scene: case.scene,
        prompt: &opts.prompt,
        edit: case.description,
        severity: opts.severity,
        quick: opts.quick,
        gaussians: case.source.len(),
        test_views: test,
        trained_steps: opts.trained,
        trained: case.trained,
        evidence_psnr: evidence,
        methods: scores
            .iter()
            .map(|s| {
                let entry = MethodMetrics {
                    metrics: &s.metrics,
                    gate_auroc: s.gate_auroc,
                    seconds: s.seconds,
                    transport_seconds: s.transport_seconds,
                };
                (s.name.as_str(), entry)
            })
            .collect(),
    };
    let report =
        Report { prompt: &opts.prompt, description: case.description, scene: case.scene, stems: &stems };
    write_report(dir, &report, &scores, &results, &config, viewer)?;
    transsplat_scene::atomic::write_bytes(
        &dir.join(MARKER),
        serde_json::to_string_pretty(&metrics).expect("json").as_bytes(),
    )?;
    Ok((scores, evidence))
}

/// What the report says about the case.
struct Report<'a> {
    prompt: &'a str,
    description: &'a str,
    scene: &'a str,
    stems: &'a [String],
}

fn write_report(
    dir: &Path,
    case: &Report,
    scores: &[MethodScore],
    results: &[(Method, EditResult)],
    config: &EditConfig,
    viewer: Option<(String, String)>,
) -> Result<(), DemoError> {
    let (prompt, scene, stems) = (case.prompt, case.scene, case.stems);
    let mut p = Page::new(&format!("transsplat demo: \"{prompt}\" on {scene}"));
    p.paragraph(&format!("Simulated editor: {}. Test views: every 8th camera.", case.description));
    p.heading("Metrics (test views)");
    let f = |v: f64| format!("{v:.3}");
    let rows: Vec<Vec<String>> = scores
        .iter()
        .map(|s| {
            vec![
                s.name.clone(),
                f(s.metrics.target_psnr),
                f(s.metrics.background_psnr),
                f(s.metrics.background_psnr_worst),
                f(s.metrics.silhouette_psnr),
                f(s.metrics.psnr),
                format!("{:.4}", s.metrics.ssim),
                s.gate_auroc.map_or("-".into(), |a| format!("{a:.4}")),
                format!("{:.1}", s.seconds),
                format!("{:.1}%", 100.0 * s.transport_seconds / s.seconds.max(1e-9)),
            ]
        })
        .collect();
    p.table(
        &[
            "method",
            "target PSNR",
            "background PSNR",
            "background, worst view",
            "silhouette PSNR",
            "PSNR",
            "SSIM",
            "gate AUROC",
            "seconds",
            "transport share",
        ],
        &rows,
    );
    if let Some((method, html)) = viewer {
        p.heading(&format!("The {method} edit in 3D (each method's own report has its viewer)"));
        p.raw(&html);
    }
    p.heading("Renders of the test views");
    let mut grid = Vec::new();
    for stem in stems {
        let mut cells = vec![
            ("source".to_string(), format!("reference/source_{stem}.png")),
            ("ground truth".to_string(), format!("reference/truth_{stem}.png")),
        ];
        for s in scores {
            cells.push((s.name.clone(), format!("{}/renders/after_{stem}.png", s.name)));
        }
        grid.push((stem.clone(), cells));
    }
    p.image_grid(&grid);
    p.heading("Gate γ (or lifted mask) per Gaussian");
    let mut grid = Vec::new();
    for stem in stems {
        let cells = results
            .iter()
            .filter(|(_, r)| r.gate.is_some())
            .map(|(m, _)| (m.name().to_string(), format!("{}/renders/gate_{stem}.png", m.name())))
            .collect();
        grid.push((stem.clone(), cells));
    }
    p.image_grid(&grid);
    p.heading("Losses and transport statistics");
    let series = |get: &dyn Fn(&EditResult) -> Vec<(f64, f64)>| -> Vec<(String, Vec<(f64, f64)>)> {
        results.iter().map(|(m, r)| (m.name().to_string(), get(r))).filter(|(_, v)| !v.is_empty()).collect()
    };
    p.plot("image loss per step", &series(&|r| r.losses.iter().map(|l| (l.step as f64, l.img)).collect()));
    p.plot("leak loss per step", &series(&|r| r.losses.iter().map(|l| (l.step as f64, l.leak)).collect()));
    p.plot(
        "transport objective per round",
        &series(&|r| r.rounds.iter().map(|x| (x.round as f64, x.objective)).collect()),
    );
    p.plot(
        "transported mass per round",
        &series(&|r| r.rounds.iter().map(|x| (x.round as f64, x.transported_mass)).collect()),
    );
    p.plot(
        "mean gate per round",
        &series(&|r| r.rounds.iter().map(|x| (x.round as f64, x.mean_gate)).collect()),
    );
    p.heading("Settings");
    p.preformatted(&config.to_toml());
    transsplat_scene::atomic::write_bytes(&dir.join("report.html"), p.finish().as_bytes())?;
    Ok(())
}
