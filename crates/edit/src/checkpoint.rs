//! Checkpoints of the edit loop: two files in the checkpoint folder.
//!
//! - `editor.ckpt`, written once: the 2D editor's outputs (edited images, attention,
//!   masks), so a resumed edit never calls the editor again. Everything derived from
//!   them (features, PCA, prototypes) is recomputed deterministically.
//! - `edit.ckpt`, rewritten atomically every N steps: the trainer (model with
//!   semantic latents, Adam, statistics, RNG), the loop state
//!   ([`crate::optimise::LoopState`]: view order and its RNG, round and loss records,
//!   timings), the method's own state ([`crate::methods::EditMethod::save`]) and the
//!   checksum of `editor.ckpt` it belongs with.
//!
//! Both carry the run's identity (settings as TOML, hash of the scene, cameras,
//! edit views, background, instruction and editor name) and the format version; a
//! checkpoint of an earlier format is refused with a message saying so.

use crate::error::EditError;
use crate::methods::EditMethod;
use crate::optimise::{LoopState, StepLosses, ViewOrder};
use crate::round::RoundStats;
use crate::EditConfig;
use transsplat_editors::EditedView;
use transsplat_scene::archive::{Archive, Hasher, Writer};
use transsplat_scene::{Camera, Gaussians};
use transsplat_train::checkpoint::{get_rng, get_trainer, put_rng, put_trainer};
use transsplat_train::{Checkpointer, RunId, TrainConfig, TrainError, Trainer};

/// The editor outputs' file in the checkpoint folder.
pub const EDITOR_FILE: &str = "editor.ckpt";
/// The loop state's file in the checkpoint folder.
pub const STATE_FILE: &str = "edit.ckpt";
/// The format of both files: 2 since editors return no features (earlier files held
/// E_v and Φ_v) and methods store their own state; 3 since TransSplat steps the
/// semantic latents itself (their Adam moments moved from the trainer's state to the
/// method's).
const FORMAT: u64 = 3;

fn err(e: TrainError) -> EditError {
    EditError::Checkpoint(e.to_string())
}

fn aerr(e: transsplat_scene::Error) -> EditError {
    EditError::Checkpoint(e.to_string())
}

/// The identity of an edit run.
pub(crate) fn run_id(
    g: &Gaussians,
    cameras: &[Camera],
    edit_views: &[usize],
    background: [f32; 3],
    prompt: &str,
    cfg: &EditConfig,
    editor: &str,
) -> RunId {
    let mut h = Hasher::default();
    transsplat_scene::fingerprint::add_scene(&mut h, g)
        .str(&g.extra.names.join("\n"))
        .f32s(&g.extra.values)
        .str(&format!("{cameras:?}\n{edit_views:?}\n{background:?}"))
        .str(prompt);
    RunId { settings: format!("editor = {editor:?}\n{}", cfg.to_toml()), inputs: h.finish() }
}

/// Reads `name`, refusing a file of an earlier format or of another run.
fn read(ck: &Checkpointer, name: &str) -> Result<Archive, EditError> {
    let path = ck.file(name);
    if !path.is_file() {
        return ck.read(name).map_err(err);
    }
    let a = Archive::read(&path).map_err(aerr)?;
    if !a.has("format") || a.scalar("format").map_err(aerr)? != FORMAT {
        return Err(EditError::Checkpoint(format!(
            "{}: written by an earlier build of transsplat in another checkpoint format; it cannot be \
             resumed: remove {} and run the edit again",
            path.display(),
            ck.dir.display()
        )));
    }
    ck.id.check(&a).map_err(err)?;
    Ok(a)
}

/// Writes the editor outputs (once per run); returns the file's checksum.
pub(crate) fn save_edited(
    ck: &mut Checkpointer,
    edited: &[Option<EditedView>],
    step: usize,
) -> Result<u64, EditError> {
    let id = ck.id.clone();
    let mut w = Writer::new();
    id.put(&mut w);
    w.scalar("format", FORMAT).scalar("views", edited.len() as u64);
    for (k, e) in edited.iter().enumerate() {
        let Some(e) = e else { continue };
        w.u64(format!("{k}.dims"), vec![e.width as u64, e.height as u64, e.mask.is_some() as u64])
            .f32(format!("{k}.image"), &e.image[..])
            .f32(format!("{k}.attention"), &e.attention[..])
            .f32(format!("{k}.mask"), e.mask.as_deref().unwrap_or(&[]));
    }
    let prev = ck.last;
    let sum = ck.write(EDITOR_FILE, &w, step as u64).map_err(err)?;
    ck.last = prev;
    Ok(sum)
}

/// Reads the editor outputs (array sizes are checked by the engine against the cameras).
pub(crate) fn load_edited(ck: &Checkpointer) -> Result<(Vec<Option<EditedView>>, u64), EditError> {
    let a = read(ck, EDITOR_FILE)?;
    let count = a.scalar("views").map_err(aerr)? as usize;
    if count > 1 << 20 {
        return Err(aerr(a.err("implausible number of views")));
    }
    let mut out = Vec::with_capacity(count);
    for k in 0..count {
        if !a.has(&format!("{k}.dims")) {
            out.push(None);
            continue;
        }
        let dims = a.u64(&format!("{k}.dims")).map_err(aerr)?;
        let &[w, h, has_mask] = dims else {
            return Err(aerr(a.err(format!("view {k}: bad dimensions"))));
        };
        let get = |n: &str| a.f32(&format!("{k}.{n}")).map(<[f32]>::to_vec).map_err(aerr);
        let mask = get("mask")?;
        out.push(Some(EditedView {
            width: w as usize,
            height: h as usize,
            image: get("image")?,
            attention: get("attention")?,
            mask: (has_mask == 1).then_some(mask),
        }));
    }
    Ok((out, a.checksum()))
}

/// Writes the loop state with the trainer and the method's state.
pub(crate) fn save_state(
    ck: &mut Checkpointer,
    trainer: &Trainer,
    st: &LoopState,
    method: &dyn EditMethod,
    editor_sum: u64,
) -> Result<(), EditError> {
    let id = ck.id.clone();
    let mut w = Writer::new();
    id.put(&mut w);
    w.scalar("format", FORMAT).scalar("editor_checksum", editor_sum).scalar("step", st.step as u64);
    put_trainer(&mut w, "tr", trainer);
    let rounds: Vec<f64> = st
        .rounds
        .iter()
        .flat_map(|r| {
            [
                r.round as f64,
                r.step as f64,
                r.views as f64,
                r.objective,
                r.dual,
                r.gap,
                r.transported_mass,
                r.mean_gate,
                r.seconds,
            ]
        })
        .collect();
    let losses: Vec<f64> =
        st.losses.iter().flat_map(|l| [l.step as f64, l.img, l.sem, l.uot, l.leak]).collect();
    w.f64("rounds", rounds)
        .f64("losses", losses)
        .u64("order", st.order.left.iter().map(|&i| i as u64).collect::<Vec<_>>())
        .f64("timing", vec![st.editor_s, st.elapsed_s]);
    put_rng(&mut w, "rng", &st.order.rng);
    method.save(&mut w);
    ck.write(STATE_FILE, &w, st.step as u64).map_err(err)?;
    Ok(())
}

/// Reads the loop state, the trainer and the method's state; `editor_sum` is the
/// checksum of the editor file read with it, `views` the number of usable views.
pub(crate) fn load_state(
    ck: &mut Checkpointer,
    config: TrainConfig,
    method: &mut dyn EditMethod,
    editor_sum: u64,
    views: usize,
) -> Result<(Trainer, LoopState), EditError> {
    let a = read(ck, STATE_FILE)?;
    let e = |m: &str| aerr(a.err(m));
    if a.scalar("editor_checksum").map_err(aerr)? != editor_sum {
        return Err(e(&format!("belongs with another {EDITOR_FILE} (checksums differ)")));
    }
    let trainer = get_trainer(&a, "tr", config).map_err(err)?;
    method.load(&a, trainer.model.len(), trainer.model.num_features, views)?;
    let rounds = a.f64("rounds").map_err(aerr)?;
    let losses = a.f64("losses").map_err(aerr)?;
    let timing = a.f64("timing").map_err(aerr)?;
    if rounds.len() % 9 != 0 || losses.len() % 5 != 0 || timing.len() != 2 {
        return Err(e("round, loss or timing records are malformed"));
    }
    let left: Vec<usize> = a.u64("order").map_err(aerr)?.iter().map(|&i| i as usize).collect();
    if left.iter().any(|&i| i >= views) {
        return Err(e("the saved view order refers to a view out of range"));
    }
    let step = a.scalar("step").map_err(aerr)? as usize;
    if step as u64 != trainer.step {
        return Err(e(&format!("loop step {step} and trainer step {} differ", trainer.step)));
    }
    let st = LoopState {
        step,
        order: ViewOrder { left, rng: get_rng(&a, "rng").map_err(err)? },
        rounds: rounds.chunks_exact(9).map(round_record).collect(),
        losses: losses
            .chunks_exact(5)
            .map(|l| StepLosses { step: l[0] as usize, img: l[1], sem: l[2], uot: l[3], leak: l[4] })
            .collect(),
        editor_s: timing[0],
        elapsed_s: timing[1],
        stages: Default::default(),
    };
    ck.last = Some(step as u64);
    Ok((trainer, st))
}

/// A round record from its nine stored numbers.
fn round_record(r: &[f64]) -> RoundStats {
    RoundStats {
        round: r[0] as usize,
        step: r[1] as usize,
        views: r[2] as usize,
        objective: r[3],
        dual: r[4],
        gap: r[5],
        transported_mass: r[6],
        mean_gate: r[7],
        seconds: r[8],
    }
}
