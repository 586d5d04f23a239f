//! The optimisation side of the edit loop (docs/method.md#m9-the-edit-loop): the
//! trainer built from the edit settings, the view order (one view per step, shuffled
//! per epoch), the image term L_img of one step, and the loop's records.

use crate::config::EditConfig;
use crate::delta::Delta;
use crate::edits::ViewData;
use crate::error::EditError;
use crate::lift;
use crate::round::RoundStats;
use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use std::borrow::Cow;
use std::time::Instant;
use transsplat_raster::{Frame, Grads, ImageGrads};
use transsplat_scene::{Camera, Gaussians};
use transsplat_train::{DensifyConfig, LearningRates, Model, TrainConfig, Trainer};

/// Loss values of one step.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct StepLosses {
    pub step: usize,
    pub img: f64,
    pub sem: f64,
    pub uot: f64,
    pub leak: f64,
}

/// The trainer of an edit: the source scene with semantic latents `s` (`N × d`, which
/// it carries but does not step: the method does), the edit's learning rates
/// (position decaying to 1 %), and densification every
/// `schedule.densify_every` steps without opacity resets (or none).
pub fn trainer(
    g: &Gaussians,
    s: Vec<f32>,
    cfg: &EditConfig,
    cameras: &[Camera],
    background: [f32; 3],
) -> Result<Trainer, EditError> {
    let lr = &cfg.lr;
    let mut densify = DensifyConfig { sh_degree_interval: 0, ..DensifyConfig::disabled() };
    if cfg.schedule.densify_every > 0 {
        densify.from_step = 0;
        densify.until_step = cfg.schedule.steps as u64 + 1;
        densify.interval = cfg.schedule.densify_every as u64;
        densify.opacity_reset_interval = 0;
        // An edit adds detail where the edit asks for it and prunes only by opacity.
        densify.camera_reach = None;
    }
    let config = TrainConfig {
        iterations: cfg.schedule.steps as u64,
        lr: LearningRates {
            position_init: lr.position,
            position_final: lr.position * 0.01,
            position_max_steps: None,
            sh_dc: lr.sh_dc,
            sh_rest: lr.sh_rest,
            opacity: lr.opacity,
            scaling: lr.scale,
            rotation: lr.rotation,
            // The semantic latents are the method's: it steps them (crate::latents).
            features: 0.0,
        },
        densify,
        background,
        seed: cfg.seed,
        clamp_grad: cfg.clamp_grad,
        // A trainer's 3D filter is baked into the scene's scales and opacities; the
        // edit refines it as a plain 3DGS scene, whatever the training default.
        filter_3d: 0.0,
        ..TrainConfig::default()
    };
    let model = Model::with_features(g.clone(), s, cfg.semantic_dim).map_err(EditError::Train)?;
    Trainer::for_cameras(model, cameras, config).map_err(|e| EditError::Train(e.to_string()))
}

/// True when geometry and opacity cannot change during the edit (their learning rates
/// are zero and nothing is densified), so per-view statistics can be computed once.
pub fn geometry_frozen(cfg: &EditConfig) -> bool {
    let lr = &cfg.lr;
    lr.position == 0.0
        && lr.scale == 0.0
        && lr.rotation == 0.0
        && lr.opacity == 0.0
        && cfg.schedule.densify_every == 0
}

/// Seconds per stage of the optimisation steps, summed over the steps.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct StageTimes {
    /// Projection, depth sort and tile binning of the step's view.
    pub binning: f64,
    /// The forward tile pass (render minus binning).
    pub tiles: f64,
    /// L_img and its image gradient (L1 + D-SSIM).
    pub image_loss: f64,
    /// The rasterizer's backward (tile pass and projection backward).
    pub backward: f64,
    /// The method's own terms (L_sem, L_uot, L_leak and their gradients).
    pub method_terms: f64,
    /// Adam over every parameter group, plus densification at its steps.
    pub optimiser: f64,
    /// Checkpoint writes.
    pub checkpoint: f64,
    /// The colour lift before the first step.
    pub lift: f64,
    /// Building the blend weights of the Gaussians that can change colour (frozen
    /// geometry with a colour mask, [`crate::delta`]).
    pub weights: f64,
}

/// The colour lift (docs/method.md#m9-the-edit-loop): before the first step, each
/// Gaussian inside the colour mask `mask` (every Gaussian without one) takes the
/// blend-weighted mean of the usable views' residuals over the pixels it blends,
/// Δc_i = Σ_v Σ_p w_i^v(p) (E_v(p) − I_v(p)) / Σ_v Σ_p w_i^v(p), with E_v the edited
/// view and I_v the current render, added to its DC colour ([`lift::shift_dc`]).
/// With [`Renderer::Delta`] the views' blend weights of the covered Gaussians give it
/// ([`Delta::lift`]); otherwise a splat-back of each view's residual.
pub fn colour_lift(
    trainer: &mut Trainer,
    renderer: &Renderer,
    cameras: &[Camera],
    views: &[ViewData],
    mask: Option<&[bool]>,
) {
    let cams: Vec<&Camera> = views.iter().map(|v| &cameras[v.cam]).collect();
    let delta = match renderer {
        Renderer::Delta(d, _) => {
            let targets: Vec<&[f32]> = views.iter().map(|v| v.target.as_slice()).collect();
            d.lift(&trainer.splats(), &cams, &targets)
        }
        _ => lift::lift_each(&trainer.model.gaussians, &cams, 3, |v| {
            let (img, _) = trainer.render(cams[v]);
            Cow::Owned(views[v].target.iter().zip(&img.rgb).map(|(e, i)| e - i).collect())
        }),
    };
    let k = trainer.model.gaussians.sh_coeffs() * 3;
    lift::shift_dc(&mut trainer.model.gaussians.sh, k, &delta, mask);
}

/// Seconds since `t`, restarting it.
pub fn lap(t: &mut Instant) -> f64 {
    let now = Instant::now();
    let s = (now - *t).as_secs_f64();
    *t = now;
    s
}

/// How the steps render and take L_img's colour gradients (docs/method.md#m10-speed).
pub enum Renderer {
    /// Every Gaussian of the view: the rasterizer's forward and backward.
    Full,
    /// Geometry is frozen and the method's colour mask is not known yet: the usable
    /// views' source renders, kept for [`Delta`].
    Pending(Vec<Vec<f32>>),
    /// The colour change of the covered Gaussians alone, with the gradient buffer
    /// reused from step to step (zero outside the covered rows between steps).
    Delta(Delta, Box<Grads>),
}

impl Renderer {
    /// [`Renderer::Pending`] when `frozen` (the source renders `bases` of the usable
    /// views), else [`Renderer::Full`].
    pub fn new(frozen: bool, bases: impl FnOnce() -> Vec<Vec<f32>>) -> Self {
        if frozen {
            Renderer::Pending(bases())
        } else {
            Renderer::Full
        }
    }

    /// Follows the method's colour mask `mask` at the top of a step: starts or extends
    /// the covered set, or settles on full renders when there is no mask or it is
    /// too large ([`crate::delta::MAX_SHARE`]). `source` is the source scene and
    /// `cams` the usable views' cameras.
    pub fn follow(&mut self, mask: Option<&[bool]>, trainer: &Trainer, source: &Gaussians, cams: &[&Camera]) {
        let Some(mask) = mask else {
            *self = Renderer::Full;
            return;
        };
        match self {
            Renderer::Full => {}
            Renderer::Pending(bases) => {
                let bases = std::mem::take(bases);
                *self = match Delta::new(source, &trainer.model.gaussians.sh, mask, cams, bases) {
                    Some(d) => Renderer::Delta(d, Box::new(trainer.zero_grads())),
                    None => Renderer::Full,
                };
            }
            Renderer::Delta(d, _) => {
                if !d.cover(source, mask, cams) {
                    *self = Renderer::Full;
                }
            }
        }
    }

    /// Renders usable view `k` (camera `cam`) with the current model and
    /// backpropagates λ_img L_img against `target`, keeping the colour gradients only
    /// inside `mask`: returns the frame (of a full render), the gradients and
    /// λ_img L_img; adds the stages' times.
    #[allow(clippy::too_many_arguments)]
    pub fn image_gradients(
        &mut self,
        trainer: &Trainer,
        k: usize,
        cam: &Camera,
        target: &[f32],
        mask: Option<&[bool]>,
        cfg: &EditConfig,
        times: &mut StageTimes,
    ) -> (Option<Frame>, Grads, f64) {
        let mut clock = Instant::now();
        if let Renderer::Delta(d, buf) = self {
            let splats = trainer.splats();
            let rgb = d.render(k, &splats, cam);
            times.tiles += lap(&mut clock);
            let (grad_rgb, loss) = image_term(&rgb, target, cam, cfg);
            times.image_loss += lap(&mut clock);
            let mut grads = std::mem::take(buf.as_mut());
            let mask = mask.expect("a delta render follows a colour mask");
            d.backward(k, &splats, cam, &grad_rgb, mask, &mut grads.sh, trainer.config.clamp_grad);
            times.backward += lap(&mut clock);
            return (None, grads, loss);
        }
        let (img, frame) = trainer.render(cam);
        times.binning += frame.binning_s;
        times.tiles += lap(&mut clock) - frame.binning_s;
        let (grad_rgb, loss) = image_term(&img.rgb, target, cam, cfg);
        times.image_loss += lap(&mut clock);
        let mut grads = trainer.zero_grads();
        trainer.backward(cam, &frame, &ImageGrads { rgb: &grad_rgb, ..Default::default() }, &mut grads);
        if let Some(m) = mask {
            mask_colour_gradients(&mut grads.sh, m, trainer.model.gaussians.sh_coeffs() * 3);
        }
        times.backward += lap(&mut clock);
        (Some(frame), grads, loss)
    }

    /// The rows a step's gradients can be non-zero in, ascending (the covered
    /// Gaussians with [`Renderer::Delta`]); `None`: any row.
    pub fn grad_rows(&self) -> Option<&[u32]> {
        match self {
            Renderer::Delta(d, _) => Some(d.rows()),
            _ => None,
        }
    }

    /// Takes back the step's gradients: with [`Renderer::Delta`] they are zeroed where
    /// a step can write them (the covered rows' colours, the features) and kept for
    /// the next step.
    pub fn recycle(&mut self, mut grads: Grads) {
        if let Renderer::Delta(d, buf) = self {
            d.zero_rows(&mut grads.sh);
            grads.features.par_iter_mut().for_each(|g| *g = 0.0);
            **buf = grads;
        }
    }
}

/// λ_img L_img of a render `rgb` of `cam` against `target`: its image gradient and value.
fn image_term(rgb: &[f32], target: &[f32], cam: &Camera, cfg: &EditConfig) -> (Vec<f32>, f64) {
    let (w, h) = (cam.width as usize, cam.height as usize);
    let mut il = transsplat_train::loss::image_loss(rgb, target, w, h, None, cfg.loss.dssim);
    if cfg.loss.img != 1.0 {
        il.grad.iter_mut().for_each(|g| *g *= cfg.loss.img);
    }
    (il.grad, (il.loss * cfg.loss.img) as f64)
}

/// Zeroes the colour (SH) gradients outside `mask` (`k` values per Gaussian): the
/// colour mask of the method (TransSplat's colour gate, masklift's lifted mask).
pub fn mask_colour_gradients(grad_sh: &mut [f32], mask: &[bool], k: usize) {
    grad_sh.par_chunks_mut(k.max(1)).zip(mask).for_each(|(g, &keep)| {
        if !keep && g.iter().any(|&v| v != 0.0) {
            g.fill(0.0);
        }
    });
}

/// Stops the run when a loss of the step is NaN or infinite, naming the loss.
pub fn check_losses(rec: &StepLosses, step: u64) -> Result<(), EditError> {
    for (name, v) in
        [("image", rec.img), ("semantic", rec.sem), ("transport", rec.uot), ("leakage", rec.leak)]
    {
        if !v.is_finite() {
            return Err(EditError::Train(format!(
                "step {step}: the {name} loss became NaN or infinite; lower the learning rates or check the inputs"
            )));
        }
    }
    Ok(())
}

/// One view per step, every view once per epoch in a seeded shuffled order.
#[derive(Clone, Debug)]
pub struct ViewOrder {
    /// Views left in this epoch (taken from the back).
    pub left: Vec<usize>,
    pub rng: ChaCha8Rng,
}

impl ViewOrder {
    pub fn new(seed: u64) -> Self {
        ViewOrder { left: Vec::new(), rng: ChaCha8Rng::seed_from_u64(seed ^ 0xED17) }
    }

    /// The next view of `views`.
    pub fn next(&mut self, views: usize) -> usize {
        if self.left.is_empty() {
            self.left = (0..views).collect();
            self.left.shuffle(&mut self.rng);
        }
        self.left.pop().expect("at least one view")
    }
}

/// The loop's own state at the top of a step, besides the trainer and the method.
#[derive(Clone, Debug)]
pub struct LoopState {
    /// Steps done.
    pub step: usize,
    pub order: ViewOrder,
    pub rounds: Vec<RoundStats>,
    pub losses: Vec<StepLosses>,
    /// Seconds in the editor, and in all (earlier processes of a resumed run included).
    pub editor_s: f64,
    pub elapsed_s: f64,
    /// This process's steps by stage.
    pub stages: StageTimes,
}

impl LoopState {
    pub fn new(seed: u64, editor_s: f64) -> Self {
        LoopState {
            step: 0,
            order: ViewOrder::new(seed),
            rounds: Vec::new(),
            losses: Vec::new(),
            editor_s,
            elapsed_s: 0.0,
            stages: StageTimes::default(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Edited views that are the renders plus a constant d: every blended Gaussian
    /// lifts Δ = d, so each pixel moves by Σ_i w_i d = α(p) d, with α the renderer's
    /// own opacity (an independent oracle); a masked-out Gaussian keeps its colour.
    #[test]
    fn the_colour_lift_moves_each_pixel_by_its_opacity_times_a_uniform_residual() {
        use transsplat_builtin::{build, SceneConfig};
        let scene =
            build("tabletop", &SceneConfig { width: 40, height: 32, views: 3, ..SceneConfig::quick() })
                .unwrap();
        let (g, cams) = (&scene.gaussians, &scene.cameras);
        let cfg = EditConfig::default();
        let latents = vec![0.0; g.len() * cfg.semantic_dim];
        let mut edit_trainer = trainer(g, latents.clone(), &cfg, cams, [0.0; 3]).unwrap();
        let d = [0.1f32, -0.05, 0.2];
        let before: Vec<_> = cams.iter().map(|c| edit_trainer.render(c).0).collect();
        let views: Vec<ViewData> = (0..cams.len())
            .map(|v| ViewData {
                cam: v,
                target: before[v].rgb.iter().enumerate().map(|(j, x)| x + d[j % 3]).collect(),
                appearance: Vec::new(),
                d_app: 0,
            })
            .collect();
        colour_lift(&mut edit_trainer, &Renderer::Full, cams, &views, None);
        let mut worst = 0.0f32;
        for (c, b) in cams.iter().zip(&before) {
            let after = edit_trainer.render(c).0;
            for (j, (x, y)) in after.rgb.iter().zip(&b.rgb).enumerate() {
                worst = worst.max((x - y - b.alpha[j / 3] * d[j % 3]).abs());
            }
        }
        assert!(worst < 1e-4, "largest error {worst}");
        let mut edit_trainer = trainer(g, latents, &cfg, cams, [0.0; 3]).unwrap();
        let mask: Vec<bool> = (0..g.len()).map(|i| i % 2 == 0).collect();
        colour_lift(&mut edit_trainer, &Renderer::Full, cams, &views, Some(&mask));
        let k = g.sh_coeffs() * 3;
        let moved = |i: usize| edit_trainer.model.gaussians.sh[i * k..i * k + 3] != g.sh[i * k..i * k + 3];
        assert!((0..g.len()).filter(|&i| i % 2 == 1).all(|i| !moved(i)));
        assert!((0..g.len()).filter(|&i| i % 2 == 0).filter(|&i| moved(i)).count() > g.len() / 4);

        // With frozen geometry and a small mask the loop's Delta renderer gives the
        // lift from its blend weights: the same colours as the splat-back path.
        let mask: Vec<bool> = (0..g.len()).map(|i| i % 5 == 0).collect();
        let cam_refs: Vec<&Camera> = cams.iter().collect();
        let bases = before.iter().map(|b| b.rgb.clone()).collect();
        let mut renderer = Renderer::new(true, || bases);
        let mut by_delta = trainer(g, vec![0.0; g.len() * cfg.semantic_dim], &cfg, cams, [0.0; 3]).unwrap();
        renderer.follow(Some(&mask), &by_delta, g, &cam_refs);
        assert!(matches!(renderer, Renderer::Delta(..)));
        colour_lift(&mut by_delta, &renderer, cams, &views, Some(&mask));
        let mut by_splat = trainer(g, vec![0.0; g.len() * cfg.semantic_dim], &cfg, cams, [0.0; 3]).unwrap();
        colour_lift(&mut by_splat, &Renderer::Full, cams, &views, Some(&mask));
        let (a, b) = (&by_delta.model.gaussians.sh, &by_splat.model.gaussians.sh);
        let diff = a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0f32, f32::max);
        assert!(diff < 1e-4 && a != &g.sh, "largest difference {diff}");
    }

    #[test]
    fn every_view_once_per_epoch() {
        let mut o = ViewOrder::new(3);
        for _ in 0..3 {
            let mut epoch: Vec<usize> = (0..5).map(|_| o.next(5)).collect();
            epoch.sort();
            assert_eq!(epoch, vec![0, 1, 2, 3, 4]);
        }
    }

    #[test]
    fn colour_gradients_are_kept_inside_the_mask() {
        let mut g = vec![1.0f32, 2.0, 3.0, 4.0, 5.0, 6.0];
        mask_colour_gradients(&mut g, &[false, true, false], 2);
        assert_eq!(g, vec![0.0, 0.0, 3.0, 4.0, 0.0, 0.0]);
    }

    #[test]
    fn a_non_finite_loss_is_named() {
        let rec = StepLosses { leak: f64::NAN, ..Default::default() };
        let e = check_losses(&rec, 7).unwrap_err().to_string();
        assert!(e.contains("step 7: the leakage loss"), "{e}");
        assert!(check_losses(&StepLosses::default(), 7).is_ok());
    }
}
