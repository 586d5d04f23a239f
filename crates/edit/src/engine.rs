//! The edit loop (paper Sec. 3.5; docs/method.md#m9-the-edit-loop), read top to
//! bottom as the pipeline: edit the views once → semantic space → each view's
//! evidence handed to the method → optimiser → per step: the method's round (a
//! transport round for TransSplat: view statistics, prototypes' transport, fusion,
//! gate), at the first step the colour lift inside the method's colour mask, L_img
//! plus the method's terms, Adam, densification → the edited scene.
//!
//! The method is one pluggable part ([`crate::methods`]); [`run_with`] adds
//! checkpoints, resuming ([`crate::checkpoint`]) and Ctrl-C.

use crate::checkpoint as ckpt;
use crate::config::EditConfig;
use crate::edits;
use crate::error::EditError;
use crate::job::{EditJob, EditResult, Progress, Timing};
use crate::methods::{Context, EditMethod};
use crate::optimise::{self, LoopState, Renderer, StepLosses};
use crate::semantic::{set_semantic_extras, SemanticSpace};
use std::sync::atomic::AtomicBool;
use std::time::Instant;
use transsplat_editors::{EditedView, Editor};
use transsplat_scene::Camera;
use transsplat_train::{Control, Trainer};

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
/// called) and the run continues to the result an uninterrupted run would give. A
/// folder without the editor outputs (a run stopped during the 2D edits) starts the
/// loop afresh, the editor called again (a caller's editor may keep finished views).
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
    check_job(job, cfg)?;
    let clock = Instant::now();
    if let Some(checkpoint) = control.checkpoint.as_mut() {
        let j = job;
        checkpoint.id =
            ckpt::run_id(j.gaussians, j.cameras, &j.edit_views, j.background, j.prompt, cfg, editor.name());
    }
    let cams: Vec<&Camera> = job.edit_views.iter().map(|&v| &job.cameras[v]).collect();

    // 1. Render the edit views and edit them once (or read the edits back).
    let sources = edits::render_sources(job.gaussians, &cams, job.background);
    let (edited, mut editor_sum) = edited_views(job, editor, &sources, control)?;
    let editor_s = clock.elapsed().as_secs_f64();
    progress(Progress::Edited { views: edited.iter().flatten().count(), seconds: editor_s });

    // 2. The semantic space of the source and edited views, and the initial latents
    //    (before step 3 takes the edited features).
    let mut lap = Instant::now();
    let mut space = SemanticSpace::fit(job.semantic, &cams, &sources, &edited, cfg.semantic_dim, cfg.seed)?;
    tracing::debug!("semantic space: {:.2} s", optimise::lap(&mut lap));
    let latents = space.initial_latents(job.gaussians, &cams, cfg.semantic_init);
    tracing::debug!("initial latents: {:.2} s", optimise::lap(&mut lap));

    // 3. Each usable view's evidence, taken in by the method.
    let mut method = crate::methods::part(cfg);
    let (views, prototypes) =
        edits::gather(&job.edit_views, &edited, &cfg.prototypes, &mut space, |cam, ev| {
            method.add_view(cam, ev)
        });
    let ctx = Context { cameras: job.cameras, views: &views };
    method.start(job.gaussians, &ctx)?;
    let view_cams: Vec<&Camera> = views.iter().map(|v| &job.cameras[v.cam]).collect();
    let mut renderer = Renderer::new(cfg.schedule.delta_render && optimise::geometry_frozen(cfg), || {
        let mut sources: Vec<Option<Vec<f32>>> = sources.into_iter().map(Some).collect();
        let at = |cam| job.edit_views.iter().position(|&c| c == cam).expect("a usable view is an edit view");
        views.iter().map(|v| sources[at(v.cam)].take().expect("one usable view per edit view")).collect()
    });
    tracing::debug!("evidence, prototypes and the method's start: {:.2} s", optimise::lap(&mut lap));

    // 4. The optimiser, from the source scene with its initial semantic latents.
    let mut trainer = optimise::trainer(job.gaussians, latents, cfg, job.cameras, job.background)?;
    tracing::debug!("trainer: {:.2} s", optimise::lap(&mut lap));
    let mut loop_state = LoopState::new(cfg.seed, editor_s);
    if let (true, Some(checkpoint), Some(sum)) = (control.resume, control.checkpoint.as_mut(), editor_sum) {
        (trainer, loop_state) =
            ckpt::load_state(checkpoint, trainer.config.clone(), method.as_mut(), sum, views.len())?;
    }

    // 5. The steps.
    let (start, before) = (loop_state.step, loop_state.elapsed_s);
    for step in start..cfg.schedule.steps {
        loop_state.step = step;
        loop_state.elapsed_s = before + clock.elapsed().as_secs_f64();
        let io = Instant::now();
        checkpoint_or_stop(
            control,
            start,
            &edited,
            &mut editor_sum,
            &mut trainer,
            &mut loop_state,
            method.as_mut(),
        )?;
        loop_state.stages.checkpoint += io.elapsed().as_secs_f64();
        if let Some(mut r) = method.before_step(step, &mut trainer, &mut loop_state.losses, &ctx)? {
            r.round = loop_state.rounds.len();
            progress(Progress::Round(&r));
            loop_state.rounds.push(r);
        }
        let t = Instant::now();
        renderer.follow(method.colour_mask(), &trainer, job.gaussians, &view_cams);
        loop_state.stages.weights += t.elapsed().as_secs_f64();
        if step == 0 && cfg.schedule.colour_lift {
            let t = Instant::now();
            optimise::colour_lift(&mut trainer, &renderer, job.cameras, &views, method.colour_mask());
            loop_state.stages.lift += t.elapsed().as_secs_f64();
        }
        let k = loop_state.order.next(views.len());
        optimise_step(&mut trainer, method.as_mut(), &mut renderer, k, &ctx, cfg, &mut loop_state)?;
        let rec = loop_state.losses.last().expect("the step's record");
        progress(Progress::Step {
            step: step + 1,
            steps: cfg.schedule.steps,
            loss: rec.img + rec.sem + rec.leak,
        });
    }

    // 6. The edited scene and the run's records.
    method.sync(&mut trainer, &mut loop_state.losses)?;
    loop_state.elapsed_s = before + clock.elapsed().as_secs_f64();
    Ok(finish(trainer, method, loop_state, edited, prototypes))
}

/// Refuses settings out of range, an empty instruction and a job without edit views.
fn check_job(job: &EditJob, cfg: &EditConfig) -> Result<(), EditError> {
    cfg.validate().map_err(EditError::Input)?;
    if job.prompt.trim().is_empty() {
        return Err(EditError::Input("the instruction (--prompt) is empty".into()));
    }
    if job.edit_views.is_empty() {
        return Err(EditError::Input("no edit views".into()));
    }
    Ok(())
}

/// The editor's outputs for the source renders: from the editor, or when resuming
/// from the checkpoint (with its checksum); checked against the cameras either way.
fn edited_views(
    job: &EditJob,
    editor: &mut dyn Editor,
    sources: &[Vec<f32>],
    control: &Control,
) -> Result<(Vec<Option<EditedView>>, Option<u64>), EditError> {
    // A run stopped during the 2D edits resumes by editing again (the session's editor
    // then hands back the views it kept).
    let edits_saved = control.checkpoint.as_ref().is_some_and(|c| c.dir.join(ckpt::EDITOR_FILE).is_file());
    if let Some(c) = control.checkpoint.as_ref().filter(|_| control.resume && !edits_saved) {
        if c.dir.join(ckpt::STATE_FILE).is_file() {
            return Err(EditError::Checkpoint(format!(
                "{}: holds the loop state ({}) without the editor's outputs ({}): a damaged checkpoint",
                c.dir.display(),
                ckpt::STATE_FILE,
                ckpt::EDITOR_FILE
            )));
        }
    }
    if !control.resume || !edits_saved {
        let edited = edits::edit_views(editor, job.cameras, &job.edit_views, sources, job.prompt)?;
        return Ok((edited, None));
    }
    let checkpoint = control
        .checkpoint
        .as_ref()
        .ok_or_else(|| EditError::Input("resume without a checkpoint folder".into()))?;
    let (edited, sum) = ckpt::load_edited(checkpoint)?;
    edits::check_outputs(editor.name(), &edited, job.cameras, &job.edit_views)?;
    Ok((edited, Some(sum)))
}

/// Writes a checkpoint when one is due or the run must stop (the editor outputs
/// once, then the loop state), and stops with [`EditError::Interrupted`] on a stop.
fn checkpoint_or_stop(
    control: &mut Control,
    start: usize,
    edited: &[Option<EditedView>],
    editor_sum: &mut Option<u64>,
    trainer: &mut Trainer,
    loop_state: &mut LoopState,
    method: &mut dyn EditMethod,
) -> Result<(), EditError> {
    let step = loop_state.step;
    let stop = control.should_stop(step as u64);
    if let Some(checkpoint) = control.checkpoint.as_mut() {
        if checkpoint.due(step as u64, start as u64) || (stop && checkpoint.last != Some(step as u64)) {
            method.sync(trainer, &mut loop_state.losses)?;
            let sum = match *editor_sum {
                Some(s) => s,
                None => *editor_sum.insert(ckpt::save_edited(checkpoint, edited, step)?),
            };
            ckpt::save_state(checkpoint, trainer, loop_state, method, sum)?;
        }
    }
    if stop {
        return Err(EditError::Interrupted(step));
    }
    Ok(())
}

/// One optimisation step on usable view `k`: L_img (colour gradients inside the
/// method's colour mask) and the method's terms, the NaN checks, Adam and
/// densification (only where the method allows); the step's record is pushed onto
/// `loop_state.losses` and its stage times added to `loop_state.stages`.
fn optimise_step(
    trainer: &mut Trainer,
    method: &mut dyn EditMethod,
    renderer: &mut Renderer,
    k: usize,
    ctx: &Context,
    cfg: &EditConfig,
    loop_state: &mut LoopState,
) -> Result<(), EditError> {
    let (step, losses, times) = (loop_state.step, &mut loop_state.losses, &mut loop_state.stages);
    trainer.begin_step();
    let view = &ctx.views[k];
    let cam = &ctx.cameras[view.cam];
    let (frame, mut grads, img) =
        renderer.image_gradients(trainer, k, cam, &view.target, method.colour_mask(), cfg, times);
    let mut rec = StepLosses { step, img, ..Default::default() };
    let mut clock = Instant::now();
    method.add_gradients(trainer, view, &mut grads, &mut rec);
    optimise::check_losses(&rec, trainer.step)?;
    losses.push(rec);
    // The mask is read only at densification steps: built only then, after the
    // method's deferred updates are in (the model is about to be rearranged).
    let densifies = trainer.config.densify.densifies(trainer.step);
    if densifies {
        method.sync(trainer, losses)?;
    }
    times.method_terms += optimise::lap(&mut clock);
    let mask = if densifies { method.densify_mask() } else { None };
    let report = trainer
        .finish_step(&grads, renderer.grad_rows(), frame.as_ref(), mask.as_deref())
        .map_err(|e| EditError::Train(e.to_string()))?;
    renderer.recycle(grads);
    times.optimiser += optimise::lap(&mut clock);
    if let Some(r) = &report.reindex {
        method.reindex(r);
    }
    Ok(())
}

/// The result: the edited scene with its semantic latents, the method's gate, the
/// records and the time split.
fn finish(
    trainer: Trainer,
    method: Box<dyn EditMethod>,
    loop_state: LoopState,
    edited: Vec<Option<EditedView>>,
    prototypes: Vec<usize>,
) -> EditResult {
    let mut gaussians = trainer.model.gaussians;
    set_semantic_extras(&mut gaussians, &trainer.model.features, trainer.model.num_features);
    let transport = loop_state.rounds.iter().fold(0.0, |t, r| t + r.seconds);
    let timing = Timing {
        total: loop_state.elapsed_s,
        editor: loop_state.editor_s,
        transport,
        optimise: loop_state.elapsed_s - loop_state.editor_s - transport,
        stages: loop_state.stages,
    };
    let support = method.support();
    EditResult {
        gaussians,
        support,
        gate: method.gate(),
        rounds: loop_state.rounds,
        losses: loop_state.losses,
        timing,
        edited,
        prototypes,
    }
}
