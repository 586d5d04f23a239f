//! The edit loop (SPEC Method 9; paper Sec. 3.5): edit the views once, then
//! optimise the Gaussians one view per step with L_img + L_sem + L_uot + L_leak,
//! running a transport round (prototypes → view-wise UOT → fusion → gate) every R
//! steps. Baselines and ablations run in the same loop ([`Method`]). [`run_with`]
//! adds checkpoints, resuming ([`crate::checkpoint`]) and Ctrl-C.

use crate::checkpoint::{self as ckpt, LoopState};
use crate::config::{EditConfig, Method};
use crate::prototypes::{self, Prototypes, ViewEvidence};
use crate::view::{self, ViewTransport};
use crate::{fusion, gate, losses, pca::Pca};
use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use std::sync::atomic::AtomicBool;
use std::time::Instant;
use transsplat_editors::{EditedView, Editor, SourceView};
use transsplat_raster::{backward, gaussian_stats, render, ImageGrads, RenderOptions, Splats};
use transsplat_scene::{sigmoid, Camera, Gaussians};
use transsplat_train::{Control, DensifyConfig, Model, TrainConfig, Trainer};

/// Errors of an edit; messages are one line meant for the user.
#[derive(Debug, thiserror::Error)]
pub enum EditError {
    #[error("{0}")]
    Input(String),
    #[error(transparent)]
    Editor(#[from] transsplat_editors::Error),
    #[error("the editor found nothing to edit: no view has attention above the support threshold")]
    NoEvidence,
    /// The solver's message is part of this one (not a separate source), so an error
    /// chain prints it once.
    #[error("transport failed: {0}")]
    Transport(transsplat_transport::Error),
    #[error("optimisation failed: {0}")]
    Train(String),
    #[error("interrupted at step {0}")]
    Interrupted(usize),
    /// A checkpoint cannot be written, read or used (the message names the file).
    #[error("{0}")]
    Checkpoint(String),
}

impl From<transsplat_transport::Error> for EditError {
    fn from(e: transsplat_transport::Error) -> Self {
        EditError::Transport(e)
    }
}

/// Semantic features of an image: `(image, w, h)` → `(H × W × d, d)`.
pub type SemanticFn = dyn Fn(&[f32], usize, usize) -> (Vec<f32>, usize) + Sync;

/// What the edit works on.
pub struct EditJob<'a> {
    /// The source scene.
    pub gaussians: &'a Gaussians,
    /// All cameras of the scene.
    pub cameras: &'a [Camera],
    /// Indices of the cameras used for editing (the training views).
    pub edit_views: Vec<usize>,
    pub background: [f32; 3],
    pub prompt: &'a str,
    /// Semantic features of a source render (`image, w, h` → `(H×W×d, d)`); must be
    /// the same feature extractor as the editor's E_v.
    pub source_semantic: &'a SemanticFn,
}

/// Statistics of one transport round.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct RoundStats {
    pub round: usize,
    pub step: usize,
    pub views: usize,
    pub objective: f64,
    pub dual: f64,
    pub gap: f64,
    pub transported_mass: f64,
    pub mean_gate: f64,
    pub seconds: f64,
}

/// Loss values of one step.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct StepLosses {
    pub step: usize,
    pub img: f64,
    pub sem: f64,
    pub uot: f64,
    pub leak: f64,
}

/// Wall-clock split of an edit.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct Timing {
    pub total: f64,
    pub editor: f64,
    /// Transport rounds: statistics, prototypes, costs, UOT, fusion, gate.
    pub transport: f64,
    pub optimise: f64,
}

/// The outcome of an edit.
#[derive(Clone, Debug, Default)]
pub struct EditResult {
    /// The edited scene; semantic latents as extra properties `sem_0..`.
    pub gaussians: Gaussians,
    /// Per-Gaussian gate γ (transport methods), the lifted mask (masklift), or
    /// `None` (naive).
    pub gate: Option<Vec<f32>>,
    pub rounds: Vec<RoundStats>,
    pub losses: Vec<StepLosses>,
    pub timing: Timing,
    /// The editor's outputs, aligned with `EditJob::edit_views`.
    pub edited: Vec<Option<EditedView>>,
    /// Number of prototypes per edit view (0 = no evidence).
    pub prototypes: Vec<usize>,
}

/// Progress reports from the loop.
#[derive(Clone, Debug)]
pub enum Progress<'a> {
    Edited { views: usize, seconds: f64 },
    Step { step: usize, steps: usize, loss: f64 },
    Round(&'a RoundStats),
}

/// Per-edit-view evidence prepared once: edited image, projected semantics,
/// appearance plane and prototypes.
struct ViewData {
    cam: usize,
    target: Vec<f32>,
    app: Vec<f32>,
    d_app: usize,
    protos: Prototypes,
    /// masklift: the view's 2D mask.
    mask: Vec<f32>,
}

/// The source side of one view's transport: visible Gaussians, masses a_i^v,
/// projected means and normalised appearance descriptors φ_i^v.
#[derive(Default)]
struct ViewSources {
    idx: Vec<u32>,
    a: Vec<f32>,
    m2d: Vec<[f32; 2]>,
    phi: Vec<f32>,
}

/// Pixel-level prototypes for the `no_prototype` ablation: a seeded subsample of the
/// support pixels, each its own prototype with mass ∝ Ā.
fn pixel_prototypes(ev: &ViewEvidence, cfg: &EditConfig, seed: u64) -> Prototypes {
    let p = &cfg.prototypes;
    let min_area = ((p.min_area_fraction * (ev.width * ev.height) as f32).ceil() as usize).max(1);
    let (omega, abar) = prototypes::support(ev, p.threshold, min_area);
    let mut idx: Vec<usize> = (0..omega.len()).filter(|&i| omega[i]).collect();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    idx.shuffle(&mut rng);
    idx.truncate(cfg.pixel_samples);
    let (d, da) = (ev.d, ev.d_app);
    let mut out = Prototypes { d, d_app: da, ..Default::default() };
    let total: f32 = idx.iter().map(|&i| abar[i]).sum();
    for &i in &idx {
        out.u.push([(i % ev.width) as f32 + 0.5, (i / ev.width) as f32 + 0.5]);
        let mut e = ev.semantic[i * d..(i + 1) * d].to_vec();
        crate::normalize(&mut e, 1e-8);
        out.e.extend(e);
        let mut a = ev.appearance[i * da..(i + 1) * da].to_vec();
        crate::normalize(&mut a, 1e-8);
        out.psi.extend(a);
        out.b.push(abar[i] / total);
    }
    out
}

/// The 2D target mask of a view for `masklift`: the editor's mask, else the support Ω.
fn view_mask(ev: &ViewEvidence, cfg: &EditConfig) -> Vec<f32> {
    if let Some(m) = ev.mask {
        return m.iter().map(|&v| if v > 0.5 { 1.0 } else { 0.0 }).collect();
    }
    let p = &cfg.prototypes;
    let min_area = ((p.min_area_fraction * (ev.width * ev.height) as f32).ceil() as usize).max(1);
    prototypes::support(ev, p.threshold, min_area).0.iter().map(|&o| if o { 1.0 } else { 0.0 }).collect()
}

/// Splat-back of per-view planes averaged over views, weighted by blend weight:
/// Σ_v W_i^v x̄_i^v / Σ_v W_i^v (`channels` per Gaussian).
fn lift(g: &Gaussians, cams: &[&Camera], planes: &[&[f32]], channels: usize) -> Vec<f32> {
    let n = g.len();
    let mut num = vec![0.0f64; n * channels];
    let mut den = vec![0.0f64; n];
    let s = Splats::new(g);
    for (cam, plane) in cams.iter().zip(planes) {
        let st = gaussian_stats(&s, cam, Some((plane, channels)));
        for i in 0..n {
            let w = st.weight_sum[i] as f64;
            if w > 0.0 {
                den[i] += w;
                for k in 0..channels {
                    num[i * channels + k] += w * st.splat[i * channels + k] as f64;
                }
            }
        }
    }
    (0..n * channels)
        .map(|j| if den[j / channels] > 0.0 { (num[j] / den[j / channels]) as f32 } else { 0.0 })
        .collect()
}

/// Runs one edit: the editor, then the optimisation with the configured method.
pub fn run(
    job: &EditJob,
    editor: &mut dyn Editor,
    cfg: &EditConfig,
    cancel: Option<&AtomicBool>,
    progress: &mut dyn FnMut(Progress),
) -> Result<EditResult, EditError> {
    run_with(job, editor, cfg, &mut Control { cancel, ..Default::default() }, progress)
}

/// [`run`] steered by `control`: checkpoints every `every` steps and on a stop
/// (Ctrl-C or `stop_after`, then [`EditError::Interrupted`]); with `resume`, the
/// editor outputs and loop state come from the checkpoint folder (the editor is not
/// called) and the run continues to the result an uninterrupted run would give.
/// A NaN or infinite loss, gradient or parameter stops with [`EditError::Train`]
/// naming the step and the parameter group.
pub fn run_with(
    job: &EditJob,
    editor: &mut dyn Editor,
    cfg: &EditConfig,
    control: &mut Control,
    progress: &mut dyn FnMut(Progress),
) -> Result<EditResult, EditError> {
    // The method's implied settings (ablations zero some weights), however the
    // config was assembled.
    let cfg = &cfg.for_method(cfg.method);
    cfg.validate().map_err(EditError::Input)?;
    if job.prompt.trim().is_empty() {
        return Err(EditError::Input("the instruction (--prompt) is empty".into()));
    }
    if job.edit_views.is_empty() {
        return Err(EditError::Input("no edit views".into()));
    }
    let t_total = Instant::now();
    if let Some(ck) = control.checkpoint.as_mut() {
        ck.id = ckpt::run_id(job, cfg, editor.name());
    }
    // Resuming: the editor outputs and the loop state from the checkpoint.
    let mut resumed: Option<(Vec<Option<EditedView>>, u64)> = None;
    if control.resume {
        let ck = control
            .checkpoint
            .as_ref()
            .ok_or_else(|| EditError::Input("resume without a checkpoint folder".into()))?;
        resumed = Some(ckpt::load_edited(ck)?);
    }
    let g0 = job.gaussians;
    let n = g0.len();
    let d = cfg.semantic_dim;
    let opts = RenderOptions { background: job.background };

    // 1. Render the source views and edit them.
    let t_edit = Instant::now();
    let s0 = Splats::new(g0);
    let sources: Vec<Vec<f32>> =
        job.edit_views.iter().map(|&v| render(&s0, &job.cameras[v], &opts).0.rgb).collect();
    let src_views: Vec<SourceView> = job
        .edit_views
        .iter()
        .zip(&sources)
        .map(|(&v, img)| SourceView { index: v, camera: &job.cameras[v], image: img })
        .collect();
    let (edited, mut editor_sum) = match resumed {
        Some((e, sum)) => (e, Some(sum)),
        None => (editor.edit(&src_views, job.prompt)?, None),
    };
    if edited.len() != src_views.len() {
        return Err(EditError::Input(format!(
            "editor {} returned {} views for {} inputs",
            editor.name(),
            edited.len(),
            src_views.len()
        )));
    }
    for (e, &v) in edited.iter().zip(&job.edit_views) {
        let Some(e) = e else { continue };
        let c = &job.cameras[v];
        let px = c.width as usize * c.height as usize;
        let ok = e.width == c.width as usize
            && e.height == c.height as usize
            && e.image.len() == px * 3
            && e.attention.len() == px
            && e.d_sem > 0
            && e.semantic.len() == px * e.d_sem
            && e.d_app > 0
            && e.appearance.len() == px * e.d_app
            && e.mask.as_ref().is_none_or(|m| m.len() == px);
        if !ok {
            return Err(EditError::Input(format!(
                "editor {} returned an output for view {:?} whose planes do not match the view size {}x{}",
                editor.name(),
                c.name,
                c.width,
                c.height
            )));
        }
    }
    let editor_s = t_edit.elapsed().as_secs_f64();
    let usable = edited.iter().filter(|e| e.is_some()).count();
    if usable == 0 {
        return Err(EditError::Input(format!("editor {} produced no edited view", editor.name())));
    }
    progress(Progress::Edited { views: usable, seconds: editor_s });

    // 2. Semantic space: PCA on source and edited semantic features together.
    let src_sem: Vec<(Vec<f32>, usize)> = job
        .edit_views
        .par_iter()
        .zip(&sources)
        .map(|(&v, img)| {
            let c = &job.cameras[v];
            (job.source_semantic)(img, c.width as usize, c.height as usize)
        })
        .collect();
    let d_in = src_sem[0].1;
    if d_in == 0 || src_sem.iter().any(|(p, d)| *d != d_in || p.len() % d_in != 0) {
        return Err(EditError::Input("the source semantic features are empty or inconsistent".into()));
    }
    for e in edited.iter().flatten() {
        if e.d_sem != d_in {
            return Err(EditError::Input(format!(
                "editor semantic features have {} channels but the source features have {d_in}",
                e.d_sem
            )));
        }
    }
    let mut planes: Vec<&[f32]> = src_sem.iter().map(|(p, _)| p.as_slice()).collect();
    planes.extend(edited.iter().flatten().map(|e| e.semantic.as_slice()));
    let pca = Pca::fit(&planes, d_in, d, 20_000, cfg.seed);

    // 3. Per-view evidence and prototypes.
    let mut views: Vec<ViewData> = Vec::new();
    let mut proto_counts = vec![0usize; job.edit_views.len()];
    for (k, (e, &v)) in edited.iter().zip(&job.edit_views).enumerate() {
        let Some(e) = e else { continue };
        let sem = pca.project(&e.semantic);
        let ev = ViewEvidence {
            width: e.width,
            height: e.height,
            attention: &e.attention,
            mask: e.mask.as_deref(),
            semantic: &sem,
            d,
            appearance: &e.appearance,
            d_app: e.d_app,
        };
        let seed = cfg.seed.wrapping_mul(1_000_003).wrapping_add(v as u64);
        let protos = match cfg.method {
            Method::NoPrototype => pixel_prototypes(&ev, cfg, seed),
            _ => prototypes::extract(&ev, &cfg.prototypes, seed),
        };
        proto_counts[k] = protos.len();
        let mask = if cfg.method == Method::Masklift { view_mask(&ev, cfg) } else { Vec::new() };
        views.push(ViewData {
            cam: v,
            target: e.image.clone(),
            app: e.appearance.clone(),
            d_app: e.d_app,
            protos,
            mask,
        });
    }
    let has_evidence = match cfg.method {
        Method::Naive => true,
        Method::Masklift => views.iter().any(|v| v.mask.iter().any(|&m| m > 0.0)),
        _ => views.iter().any(|v| !v.protos.is_empty()),
    };
    if !has_evidence {
        return Err(EditError::NoEvidence);
    }

    // 4. Initial semantic latents: splat-back of the projected source features.
    let cams: Vec<&Camera> = job.edit_views.iter().map(|&v| &job.cameras[v]).collect();
    let proj_src: Vec<Vec<f32>> = src_sem.iter().map(|(p, _)| pca.project(p)).collect();
    let proj_refs: Vec<&[f32]> = proj_src.iter().map(|p| p.as_slice()).collect();
    let s_init = lift(g0, &cams, &proj_refs, d);

    // masklift: the 2D masks lifted onto the Gaussians, thresholded.
    let mut lifted: Option<Vec<bool>> = None;
    let mut gate_report: Option<Vec<f32>> = None;
    if cfg.method == Method::Masklift {
        let mcams: Vec<&Camera> = views.iter().map(|v| &job.cameras[v.cam]).collect();
        let mplanes: Vec<&[f32]> = views.iter().map(|v| v.mask.as_slice()).collect();
        let m = lift(g0, &mcams, &mplanes, 1);
        lifted = Some(m.iter().map(|&x| x >= cfg.masklift_threshold).collect());
        gate_report = Some(m);
    }

    // 5. The optimiser.
    let lr = &cfg.lr;
    let mut densify = DensifyConfig { sh_degree_interval: 0, ..DensifyConfig::disabled() };
    if cfg.schedule.densify_every > 0 {
        densify.from_step = 0;
        densify.until_step = cfg.schedule.steps as u64 + 1;
        densify.interval = cfg.schedule.densify_every as u64;
        densify.opacity_reset_interval = 0;
    }
    let tcfg = TrainConfig {
        iterations: cfg.schedule.steps as u64,
        lr: transsplat_train::LearningRates {
            position_init: lr.position,
            position_final: lr.position * 0.01,
            position_max_steps: None,
            sh_dc: lr.sh_dc,
            sh_rest: lr.sh_rest,
            opacity: lr.opacity,
            scaling: lr.scale,
            rotation: lr.rotation,
            features: lr.semantic,
        },
        densify,
        background: job.background,
        seed: cfg.seed,
        ..TrainConfig::default()
    };
    let extent = transsplat_train::trainer::scene_extent(job.cameras);
    let model = Model::with_features(g0.clone(), s_init, d).map_err(EditError::Train)?;
    let mut tr = Trainer::new(model, extent, tcfg).map_err(|e| EditError::Train(e.to_string()))?;
    let kc = g0.sh_coeffs() * 3;
    let mut ls = LoopState {
        step: 0,
        sh0: g0.sh.clone(),
        gamma: vec![1.0; n],
        zbar: None,
        cached: Vec::new(),
        rounds: Vec::new(),
        losses: Vec::new(),
        order: Vec::new(),
        rng: ChaCha8Rng::seed_from_u64(cfg.seed ^ 0xED17),
        force_round: false,
        lifted,
        gate_report,
        editor_s,
        transport_s: 0.0,
        elapsed_s: 0.0,
    };
    if let (true, Some(ck), Some(sum)) = (control.resume, control.checkpoint.as_mut(), editor_sum) {
        (tr, ls) = ckpt::load_state(ck, tr.config.clone(), sum, views.len())?;
    }
    let start = ls.step;
    let elapsed0 = ls.elapsed_s;
    // Geometry and opacity stay fixed when their learning rates are zero and nothing
    // is densified; then the per-view source statistics are computed once.
    let geometry_frozen = lr.position == 0.0
        && lr.scale == 0.0
        && lr.rotation == 0.0
        && lr.opacity == 0.0
        && cfg.schedule.densify_every == 0;
    let mut sources: Vec<ViewSources> = Vec::new();
    let diag = |c: &Camera| ((c.width as f32).powi(2) + (c.height as f32).powi(2)).sqrt();

    for step in start..cfg.schedule.steps {
        ls.step = step;
        let stop = control.should_stop(step as u64);
        if let Some(ck) = control.checkpoint.as_mut() {
            if ck.due(step as u64, start as u64) || (stop && ck.last != Some(step as u64)) {
                let sum = match editor_sum {
                    Some(s) => s,
                    None => *editor_sum.insert(ckpt::save_edited(ck, &edited, step)?),
                };
                ls.elapsed_s = elapsed0 + t_total.elapsed().as_secs_f64();
                ckpt::save_state(ck, &tr, &ls, sum)?;
            }
        }
        if stop {
            return Err(EditError::Interrupted(step));
        }
        // Transport round.
        if cfg.method.uses_transport() && (step % cfg.schedule.transport_every == 0 || ls.force_round) {
            ls.force_round = false;
            let t = Instant::now();
            let g = &tr.model.gaussians;
            let s = &tr.model.features;
            let opacity: Vec<f32> = g.opacity_logits.iter().map(|&o| sigmoid(o)).collect();
            let splats = Splats::new(g);
            // Visibility, projected means and appearance descriptors depend only on
            // geometry and opacity: recomputed only when those can have changed.
            if !geometry_frozen || sources.len() != views.len() {
                sources = views
                    .par_iter()
                    .map(|v| {
                        if v.protos.is_empty() {
                            return ViewSources::default();
                        }
                        let st = gaussian_stats(&splats, &job.cameras[v.cam], Some((&v.app, v.d_app)));
                        let (idx, a) = view::source_masses(&st.visibility, &opacity);
                        let m2d: Vec<[f32; 2]> = idx.iter().map(|&i| st.means2d[i as usize]).collect();
                        let mut phi: Vec<f32> = Vec::with_capacity(idx.len() * v.d_app);
                        for &i in &idx {
                            let mut p = st.splat[i as usize * v.d_app..(i as usize + 1) * v.d_app].to_vec();
                            crate::normalize(&mut p, 1e-8);
                            phi.extend(p);
                        }
                        ViewSources { idx, a, m2d, phi }
                    })
                    .collect();
            }
            let results: Vec<Result<ViewTransport, EditError>> = views
                .par_iter()
                .zip(&sources)
                .filter(|(v, _)| !v.protos.is_empty())
                .map(|(v, src)| {
                    let cam = &job.cameras[v.cam];
                    let sv: Vec<f32> = src
                        .idx
                        .iter()
                        .flat_map(|&i| s[i as usize * d..(i as usize + 1) * d].iter().copied())
                        .collect();
                    let mut t = view::transport(
                        src.idx.clone(),
                        src.a.clone(),
                        &src.m2d,
                        &sv,
                        &src.phi,
                        &v.protos,
                        diag(cam),
                        &cfg.transport,
                    )?;
                    t.view = v.cam;
                    Ok(t)
                })
                .collect();
            ls.cached = results.into_iter().collect::<Result<_, _>>()?;
            let acc = fusion::accumulate(tr.model.len(), d, &ls.cached, cfg.fusion.min_support);
            let z = fusion::canonical_targets(&acc, &tr.model.features, cfg.fusion.rho);
            ls.zbar = Some(fusion::ema(ls.zbar.as_deref(), &z, cfg.fusion.ema));
            let r = gate::residuals(tr.model.len(), &ls.cached, cfg.fusion.min_support);
            ls.gamma = gate::gate(&r, cfg.fusion.tau_r);
            let secs = t.elapsed().as_secs_f64();
            ls.transport_s += secs;
            let rs = RoundStats {
                round: ls.rounds.len(),
                step,
                views: ls.cached.len(),
                objective: ls.cached.iter().map(|v| v.objective).sum(),
                dual: ls.cached.iter().map(|v| v.dual).sum(),
                gap: ls.cached.iter().map(|v| v.gap).sum(),
                transported_mass: ls.cached.iter().map(|v| v.transported_mass).sum(),
                mean_gate: ls.gamma.iter().map(|&x| x as f64).sum::<f64>() / ls.gamma.len().max(1) as f64,
                seconds: secs,
            };
            progress(Progress::Round(&rs));
            ls.rounds.push(rs);
        }

        // One view per step, shuffled per epoch.
        if ls.order.is_empty() {
            ls.order = (0..views.len()).collect();
            ls.order.shuffle(&mut ls.rng);
        }
        let vd = &views[ls.order.pop().expect("non-empty")];
        let cam = &job.cameras[vd.cam];
        tr.begin_step();
        let (w, h) = (cam.width as usize, cam.height as usize);
        let mut sp = Splats::new(&tr.model.gaussians);
        sp.active_sh_degree = tr.active_sh_degree;
        let (img, frame) = render(&sp, cam, &opts);
        let mut il = transsplat_train::loss::image_loss(&img.rgb, &vd.target, w, h, None, cfg.loss.dssim);
        if cfg.loss.img != 1.0 {
            il.grad.iter_mut().for_each(|g| *g *= cfg.loss.img);
        }
        let mut grads = tr.zero_grads();
        backward(&sp, cam, &frame, &ImageGrads { rgb: &il.grad, ..Default::default() }, &mut grads);
        let mut rec = StepLosses { step, img: (il.loss * cfg.loss.img) as f64, ..Default::default() };
        match cfg.method {
            Method::Naive => {}
            Method::Masklift => {
                let m = ls.lifted.as_ref().expect("masklift mask");
                for (i, &keep) in m.iter().enumerate() {
                    if !keep {
                        grads.sh[i * kc..(i + 1) * kc].iter_mut().for_each(|g| *g = 0.0);
                    }
                }
            }
            _ => {
                if let Some(z) = &ls.zbar {
                    rec.sem = losses::semantic(
                        &tr.model.features,
                        z,
                        &ls.gamma,
                        d,
                        cfg.loss.sem,
                        &mut grads.features,
                    );
                }
                // L_uot = Σ_v 𝒯_v: one view per step, like L_img (an unbiased estimate of
                // the mean over views).
                if let Some(v) = ls.cached.iter().find(|t| t.view == vd.cam) {
                    losses::transport_semantic(
                        &tr.model.features,
                        &v.idx,
                        &v.plan_e,
                        d,
                        cfg.transport.lambda_sem,
                        cfg.loss.uot,
                        &mut grads.features,
                    );
                    rec.uot = cfg.loss.uot as f64 * v.objective;
                }
                if cfg.loss.leak > 0.0 {
                    rec.leak = losses::leakage(
                        &tr.model.gaussians.sh,
                        &ls.sh0,
                        &ls.gamma,
                        kc,
                        cfg.loss.leak,
                        &mut grads.sh,
                    );
                }
            }
        }
        for (name, v) in
            [("image", rec.img), ("semantic", rec.sem), ("transport", rec.uot), ("leakage", rec.leak)]
        {
            if !v.is_finite() {
                return Err(EditError::Train(format!(
                    "step {}: the {name} loss became NaN or infinite; lower the learning rates or check the inputs",
                    tr.step
                )));
            }
        }
        // Densification only among gated Gaussians (lifted mask for masklift; no
        // restriction for the ablation without leakage suppression, or for naive).
        let mask: Option<Vec<bool>> = match (cfg.schedule.densify_every > 0, cfg.method, &ls.lifted) {
            (false, _, _) | (true, Method::NoLeaksup | Method::Naive, _) => None,
            (true, _, Some(m)) => Some(m.clone()),
            (true, _, None) => Some(ls.gamma.iter().map(|&g| g >= cfg.schedule.densify_gate).collect()),
        };
        let report =
            tr.finish_step(&grads, &frame, mask.as_deref()).map_err(|e| EditError::Train(e.to_string()))?;
        if let Some(r) = &report.reindex {
            ls.gamma = r.gather(&ls.gamma, 1);
            ls.sh0 = r.gather(&ls.sh0, kc);
            ls.zbar = ls.zbar.map(|z| r.gather(&z, d));
            if let Some(m) = ls.lifted.as_mut() {
                *m = r.gather(m, 1);
            }
            if let Some(gr) = ls.gate_report.as_mut() {
                *gr = r.gather(gr, 1);
            }
            ls.cached.clear();
            sources.clear();
            ls.force_round = cfg.method.uses_transport();
        }
        progress(Progress::Step {
            step: step + 1,
            steps: cfg.schedule.steps,
            loss: rec.img + rec.sem + rec.leak,
        });
        ls.losses.push(rec);
    }

    let mut out = tr.model.gaussians.clone();
    set_semantic_extras(&mut out, &tr.model.features, d);
    let gate = match cfg.method {
        Method::Naive => None,
        Method::Masklift => ls.gate_report,
        _ => Some(ls.gamma),
    };
    let total = elapsed0 + t_total.elapsed().as_secs_f64();
    Ok(EditResult {
        gaussians: out,
        gate,
        rounds: ls.rounds,
        losses: ls.losses,
        timing: Timing {
            total,
            editor: ls.editor_s,
            transport: ls.transport_s,
            optimise: total - ls.editor_s - ls.transport_s,
        },
        edited,
        prototypes: proto_counts,
    })
}

/// Writes the semantic latents as extra properties `sem_0..sem_{d-1}`, replacing
/// any earlier `sem_*` properties and keeping the other extras.
pub fn set_semantic_extras(g: &mut Gaussians, s: &[f32], d: usize) {
    let n = g.len();
    let old = std::mem::take(&mut g.extra);
    let keep: Vec<usize> = (0..old.names.len()).filter(|&k| !old.names[k].starts_with("sem_")).collect();
    let mut names: Vec<String> = keep.iter().map(|&k| old.names[k].clone()).collect();
    names.extend((0..d).map(|k| format!("sem_{k}")));
    let w_old = old.names.len();
    let mut values = Vec::with_capacity(n * names.len());
    for i in 0..n {
        values.extend(keep.iter().map(|&k| old.values[i * w_old + k]));
        values.extend_from_slice(&s[i * d..(i + 1) * d]);
    }
    g.extra = transsplat_scene::Extra { names, values };
}

#[cfg(test)]
mod error_tests {
    #[test]
    fn transport_errors_carry_the_message_once() {
        use std::error::Error as _;
        let inner = transsplat_transport::Error::Shape { what: "source masses", got: 1, expected: 2 };
        let e: super::EditError = inner.into();
        // An error chain printer (anyhow's `{:#}`) appends every source; the solver's
        // message is already in this one, so there must be no source.
        assert!(e.source().is_none());
        assert_eq!(e.to_string().matches("source masses has 1 entries").count(), 1, "{e}");
    }
}
