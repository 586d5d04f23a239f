//! Checkpoints and numerical health of the edit loop, through the library: an edit
//! stopped at step k and resumed from its checkpoint gives bit-identical Gaussians,
//! gate, losses and transport rounds to an uninterrupted edit, without calling the
//! 2D editor again (with transport rounds, densification inside the gate and a
//! stop between rounds, and with frozen geometry, where steps render only the colour
//! change); with frozen geometry that render gives the edit of full renders; a
//! changed setting or instruction is refused; a poisoned learning rate stops naming
//! the step and the parameter group.

use transsplat_builtin::SimulatedEditor;
use transsplat_builtin::{build, Scene, SceneConfig};
use transsplat_edit::checkpoint::{EDITOR_FILE, STATE_FILE};
use transsplat_edit::gate::ViewWeight;
use transsplat_edit::{run_with, semantic, EditConfig, EditError, EditJob, EditResult, Method};
use transsplat_editors::{EditedView, Editor, SourceView};
use transsplat_train::{Checkpointer, Control};

const PROMPT: &str = "make the ball blue";

fn scene() -> Scene {
    build("tabletop", &SceneConfig { width: 48, height: 36, views: 10, ..SceneConfig::quick() }).unwrap()
}

fn config(method: Method) -> EditConfig {
    let mut c = EditConfig::default().for_method(method);
    c.schedule.steps = 40;
    c.schedule.transport_every = 10;
    c.schedule.densify_every = 12;
    c.lr.position = 1e-4;
    c.lr.scale = 1e-3;
    c
}

/// Counts calls to the wrapped editor.
struct Counting<'a> {
    inner: SimulatedEditor,
    calls: &'a std::cell::Cell<usize>,
}

impl Editor for Counting<'_> {
    fn name(&self) -> &str {
        self.inner.name()
    }
    fn edit(
        &mut self,
        views: &[SourceView],
        prompt: &str,
    ) -> Result<Vec<Option<EditedView>>, transsplat_editors::Error> {
        self.calls.set(self.calls.get() + 1);
        self.inner.edit(views, prompt)
    }
}

fn edit(
    scene: &Scene,
    cfg: &EditConfig,
    prompt: &str,
    control: &mut Control,
    calls: &std::cell::Cell<usize>,
) -> Result<EditResult, EditError> {
    let g = scene.gaussians_with_labels();
    let job = EditJob {
        gaussians: &g,
        cameras: &scene.cameras,
        edit_views: scene.train_views(),
        background: scene.background,
        prompt,
        semantic: &semantic::builtin,
    };
    let mut editor = Counting { inner: SimulatedEditor::new(scene, 1.0, 3), calls };
    run_with(&job, &mut editor, cfg, control, &mut |_| {})
}

fn bits(v: &[f32]) -> Vec<u32> {
    v.iter().map(|x| x.to_bits()).collect()
}

fn assert_same(a: &EditResult, b: &EditResult) {
    let (x, y) = (&a.gaussians, &b.gaussians);
    assert_eq!(x.len(), y.len());
    assert_eq!(bits(x.means.as_flattened()), bits(y.means.as_flattened()));
    assert_eq!(bits(x.log_scales.as_flattened()), bits(y.log_scales.as_flattened()));
    assert_eq!(bits(&x.opacity_logits), bits(&y.opacity_logits));
    assert_eq!(bits(&x.sh), bits(&y.sh));
    assert_eq!(x.extra.names, y.extra.names);
    assert_eq!(bits(&x.extra.values), bits(&y.extra.values), "semantic latents and labels");
    assert_eq!(a.gate.as_deref().map(bits), b.gate.as_deref().map(bits));
    assert_eq!(a.support.as_deref().map(bits), b.support.as_deref().map(bits), "transported support");
    assert_eq!(a.losses, b.losses);
    assert_eq!(a.rounds.len(), b.rounds.len());
    for (r, s) in a.rounds.iter().zip(&b.rounds) {
        assert_eq!((r.step, r.views, r.objective, r.mean_gate), (s.step, s.views, s.objective, s.mean_gate));
    }
    assert_eq!(a.prototypes, b.prototypes);
}

#[test]
fn stopped_and_resumed_edits_are_bit_identical_without_calling_the_editor_again() {
    let scene = scene();
    let dir = tempfile::tempdir().unwrap();
    for (method, stop) in [(Method::Transsplat, 17), (Method::Masklift, 25)] {
        let cfg = config(method);
        let calls = std::cell::Cell::new(0);
        let whole = edit(&scene, &cfg, PROMPT, &mut Control::default(), &calls).unwrap();
        assert!(
            whole.gaussians.len() != scene.gaussians.len(),
            "{method:?}: densification must change the count"
        );

        let ckdir = dir.path().join(method.name());
        let mut control = Control {
            checkpoint: Some(Checkpointer::new(&ckdir, 10)),
            stop_after: Some(stop),
            ..Default::default()
        };
        let e = edit(&scene, &cfg, PROMPT, &mut control, &calls).unwrap_err();
        assert!(matches!(e, EditError::Interrupted(s) if s as u64 == stop), "{e}");
        assert!(ckdir.join(EDITOR_FILE).is_file() && ckdir.join(STATE_FILE).is_file());
        assert_eq!(calls.get(), 2);

        let mut control =
            Control { checkpoint: Some(Checkpointer::new(&ckdir, 10)), resume: true, ..Default::default() };
        let resumed = edit(&scene, &cfg, PROMPT, &mut control, &calls).unwrap();
        assert_eq!(calls.get(), 2, "{method:?}: resuming must not call the editor");
        assert_eq!(control.checkpoint.unwrap().last, Some(30), "periodic checkpoints continue");
        assert_same(&whole, &resumed);
    }
}

/// The edit's default settings (frozen geometry) at the test's size.
fn frozen(method: Method) -> EditConfig {
    let mut c = EditConfig::default().for_method(method);
    c.schedule.steps = 40;
    c.schedule.transport_every = 10;
    c
}

#[test]
fn with_frozen_geometry_rendering_the_colour_change_alone_gives_the_full_render_edit() {
    let scene = scene();
    let calls = std::cell::Cell::new(0);
    for method in [Method::Transsplat, Method::Masklift] {
        let cfg = frozen(method);
        let mut full_cfg = cfg.clone();
        full_cfg.schedule.delta_render = false;
        let delta = edit(&scene, &cfg, PROMPT, &mut Control::default(), &calls).unwrap();
        let full = edit(&scene, &full_cfg, PROMPT, &mut Control::default(), &calls).unwrap();
        // The delta path rendered every step (no step binned), the full one did not.
        let (bd, bf) = (delta.timing.stages.binning, full.timing.stages.binning);
        assert!(bd == 0.0 && bf > 0.0, "{method:?}: binning {bd} s with the delta render, {bf} s without");
        let (a, b) = (&delta.gaussians.sh, &full.gaussians.sh);
        let src = &scene.gaussians.sh;
        let moved = b.iter().zip(src).filter(|(x, y)| (*x - *y).abs() > 1e-3).count();
        assert!(moved > 20, "{method:?}: the edit changes colours ({moved})");
        let worst = a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0f32, f32::max);
        assert!(worst < 1e-3, "{method:?}: largest SH difference {worst}");
        for (x, y) in delta.losses.iter().zip(&full.losses) {
            assert!((x.img - y.img).abs() <= 1e-4 * y.img.abs().max(1e-3), "{method:?} step {}", x.step);
        }
        assert_eq!(delta.rounds.len(), full.rounds.len());
    }
}

#[test]
fn a_resumed_edit_with_frozen_geometry_is_bit_identical() {
    let scene = scene();
    let dir = tempfile::tempdir().unwrap();
    // Each view's say by source mass and by blend weight (the default). Stopped at 35,
    // after the last transport round (rounds every 10 of 40 steps), the reported support
    // comes from the checkpointed plans, so they must carry their blend weights.
    for (view_weight, stop) in [(ViewWeight::Mass, 23), (ViewWeight::Blend, 35)] {
        let mut cfg = frozen(Method::Transsplat);
        cfg.fusion.view_weight = view_weight;
        let calls = std::cell::Cell::new(0);
        let whole = edit(&scene, &cfg, PROMPT, &mut Control::default(), &calls).unwrap();
        let ckdir = dir.path().join(format!("frozen-{view_weight:?}"));
        let mut control = Control {
            checkpoint: Some(Checkpointer::new(&ckdir, 10)),
            stop_after: Some(stop),
            ..Default::default()
        };
        edit(&scene, &cfg, PROMPT, &mut control, &calls).unwrap_err();
        let mut control =
            Control { checkpoint: Some(Checkpointer::new(&ckdir, 10)), resume: true, ..Default::default() };
        let resumed = edit(&scene, &cfg, PROMPT, &mut control, &calls).unwrap();
        assert_same(&whole, &resumed);
    }
}

#[test]
fn resuming_with_other_settings_or_instruction_is_refused() {
    let scene = scene();
    let dir = tempfile::tempdir().unwrap();
    let cfg = config(Method::Transsplat);
    let calls = std::cell::Cell::new(0);
    let mut control = Control {
        checkpoint: Some(Checkpointer::new(dir.path(), 10)),
        stop_after: Some(4),
        ..Default::default()
    };
    let e = edit(&scene, &cfg, PROMPT, &mut control, &calls).unwrap_err();
    assert!(matches!(e, EditError::Interrupted(4)), "{e}");
    let mut other = cfg.clone();
    other.loss.leak = 0.3;
    let mut control =
        Control { checkpoint: Some(Checkpointer::new(dir.path(), 10)), resume: true, ..Default::default() };
    let e = edit(&scene, &other, PROMPT, &mut control, &calls).unwrap_err().to_string();
    assert!(e.contains("other settings") && e.contains("leak = 0.3") && e.contains(EDITOR_FILE), "{e}");
    let mut control =
        Control { checkpoint: Some(Checkpointer::new(dir.path(), 10)), resume: true, ..Default::default() };
    let e = edit(&scene, &cfg, "make the crate blue", &mut control, &calls).unwrap_err().to_string();
    assert!(e.contains("other inputs"), "{e}");
    // A truncated state file is an error naming it.
    let state = dir.path().join(STATE_FILE);
    let bytes = std::fs::read(&state).unwrap();
    std::fs::write(&state, &bytes[..bytes.len() - 9]).unwrap();
    let mut control =
        Control { checkpoint: Some(Checkpointer::new(dir.path(), 10)), resume: true, ..Default::default() };
    let e = edit(&scene, &cfg, PROMPT, &mut control, &calls).unwrap_err().to_string();
    assert!(e.contains(&state.display().to_string()) && e.contains("truncated"), "{e}");
    assert_eq!(calls.get(), 1);
}

#[test]
fn a_poisoned_learning_rate_stops_the_edit_naming_the_step_and_group() {
    let scene = scene();
    let calls = std::cell::Cell::new(0);
    let mut cfg = config(Method::Transsplat);
    // The settings refuse NaN learning rates, so poison with finite but absurd ones.
    cfg.lr.sh_dc = 3e38;
    let e = edit(&scene, &cfg, PROMPT, &mut Control::default(), &calls).unwrap_err().to_string();
    assert!(e.contains("step 1: the sh became NaN or infinite"), "{e}");
    let mut cfg = config(Method::Transsplat);
    cfg.lr.semantic = 3e38;
    let e = edit(&scene, &cfg, PROMPT, &mut Control::default(), &calls).unwrap_err().to_string();
    assert!(e.contains("features") && e.contains("NaN or infinite") && e.contains("step "), "{e}");
}

#[test]
fn a_checkpoint_of_an_earlier_format_is_refused_saying_so() {
    let scene = scene();
    let dir = tempfile::tempdir().unwrap();
    // Files of the first format carried no format entry.
    let mut w = transsplat_scene::archive::Writer::new();
    w.scalar("views", 1);
    w.write(&dir.path().join(EDITOR_FILE)).unwrap();
    let calls = std::cell::Cell::new(0);
    let mut control =
        Control { checkpoint: Some(Checkpointer::new(dir.path(), 10)), resume: true, ..Default::default() };
    let e = edit(&scene, &config(Method::Transsplat), PROMPT, &mut control, &calls).unwrap_err().to_string();
    assert!(e.contains(EDITOR_FILE) && e.contains("earlier build") && e.contains("cannot be resumed"), "{e}");
    assert_eq!(calls.get(), 0);
}
