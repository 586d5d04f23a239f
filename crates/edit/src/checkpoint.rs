//! Checkpoints of the edit loop: two files in the checkpoint folder.
//!
//! - `editor.ckpt`, written once: the 2D editor's outputs (edited images,
//!   attention, semantic and appearance features, masks), so a resumed edit never
//!   calls the editor again. Everything derived from them (PCA, prototypes) is
//!   recomputed deterministically.
//! - `edit.ckpt`, rewritten atomically every N steps: the trainer (model with
//!   semantic latents, Adam, statistics, RNG), the transport state (EMA targets z̄,
//!   gate γ, the cached view plans), the leakage reference, masklift's lifted mask,
//!   the view order and its RNG, round and loss records, timings, and the checksum
//!   of `editor.ckpt` it belongs with.
//!
//! Both carry the run's identity (settings as TOML, hash of the scene, cameras,
//! edit views, background, instruction and editor name).

use crate::engine::{EditError, EditJob, RoundStats, StepLosses};
use crate::view::ViewTransport;
use crate::EditConfig;
use rand_chacha::ChaCha8Rng;
use transsplat_editors::EditedView;
use transsplat_scene::archive::{Hasher, Writer};
use transsplat_train::checkpoint::{get_rng, get_trainer, put_rng, put_trainer};
use transsplat_train::{Checkpointer, RunId, TrainConfig, TrainError, Trainer};

/// The editor outputs' file in the checkpoint folder.
pub const EDITOR_FILE: &str = "editor.ckpt";
/// The loop state's file in the checkpoint folder.
pub const STATE_FILE: &str = "edit.ckpt";

/// The edit loop's state at the top of a step, besides the trainer.
#[derive(Clone, Debug)]
pub(crate) struct LoopState {
    /// Steps done.
    pub step: usize,
    pub sh0: Vec<f32>,
    pub gamma: Vec<f32>,
    pub zbar: Option<Vec<f32>>,
    pub cached: Vec<ViewTransport>,
    pub rounds: Vec<RoundStats>,
    pub losses: Vec<StepLosses>,
    pub order: Vec<usize>,
    pub rng: ChaCha8Rng,
    pub force_round: bool,
    pub lifted: Option<Vec<bool>>,
    pub gate_report: Option<Vec<f32>>,
    /// Seconds spent in the editor, in transport rounds, and in all (previous
    /// processes included).
    pub editor_s: f64,
    pub transport_s: f64,
    pub elapsed_s: f64,
}

fn err(e: TrainError) -> EditError {
    EditError::Checkpoint(e.to_string())
}

fn aerr(e: transsplat_scene::Error) -> EditError {
    EditError::Checkpoint(e.to_string())
}

/// The identity of an edit run.
pub(crate) fn run_id(job: &EditJob, cfg: &EditConfig, editor: &str) -> RunId {
    let g = job.gaussians;
    let mut h = Hasher::default();
    h.f32s(g.means.as_flattened())
        .f32s(g.log_scales.as_flattened())
        .f32s(g.rotations.as_flattened())
        .f32s(&g.opacity_logits)
        .u64(g.sh_degree as u64)
        .f32s(&g.sh)
        .str(&g.extra.names.join("\n"))
        .f32s(&g.extra.values)
        .str(&format!("{:?}\n{:?}\n{:?}", job.cameras, job.edit_views, job.background))
        .str(job.prompt);
    RunId { settings: format!("editor = {editor:?}\n{}", cfg.to_toml()), inputs: h.finish() }
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
    w.scalar("views", edited.len() as u64);
    for (k, e) in edited.iter().enumerate() {
        let Some(e) = e else { continue };
        w.u64(
            format!("{k}.dims"),
            vec![e.width as u64, e.height as u64, e.d_sem as u64, e.d_app as u64, e.mask.is_some() as u64],
        )
        .f32(format!("{k}.image"), &e.image[..])
        .f32(format!("{k}.attention"), &e.attention[..])
        .f32(format!("{k}.semantic"), &e.semantic[..])
        .f32(format!("{k}.appearance"), &e.appearance[..])
        .f32(format!("{k}.mask"), e.mask.as_deref().unwrap_or(&[]));
    }
    let prev = ck.last;
    let sum = ck.write(EDITOR_FILE, &w, step as u64).map_err(err)?;
    ck.last = prev;
    Ok(sum)
}

/// Reads the editor outputs (array sizes are checked by the engine against the cameras).
pub(crate) fn load_edited(ck: &Checkpointer) -> Result<(Vec<Option<EditedView>>, u64), EditError> {
    let a = ck.read(EDITOR_FILE).map_err(err)?;
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
        let &[w, h, d_sem, d_app, has_mask] = dims else {
            return Err(aerr(a.err(format!("view {k}: bad dimensions"))));
        };
        let get = |n: &str| a.f32(&format!("{k}.{n}")).map(<[f32]>::to_vec).map_err(aerr);
        let mask = get("mask")?;
        out.push(Some(EditedView {
            width: w as usize,
            height: h as usize,
            image: get("image")?,
            attention: get("attention")?,
            semantic: get("semantic")?,
            d_sem: d_sem as usize,
            appearance: get("appearance")?,
            d_app: d_app as usize,
            mask: (has_mask == 1).then_some(mask),
        }));
    }
    Ok((out, a.checksum()))
}

/// Writes the loop state.
pub(crate) fn save_state(
    ck: &mut Checkpointer,
    tr: &Trainer,
    st: &LoopState,
    editor_sum: u64,
) -> Result<(), EditError> {
    let id = ck.id.clone();
    let mut w = Writer::new();
    id.put(&mut w);
    w.scalar("editor_checksum", editor_sum).scalar("step", st.step as u64);
    put_trainer(&mut w, "tr", tr);
    w.f32("sh0", &st.sh0[..]).f32("gamma", &st.gamma[..]);
    if let Some(z) = &st.zbar {
        w.f32("zbar", &z[..]);
    }
    if let Some(l) = &st.lifted {
        w.u32("lifted", l.iter().map(|&b| b as u32).collect::<Vec<_>>());
    }
    if let Some(g) = &st.gate_report {
        w.f32("gate_report", &g[..]);
    }
    w.scalar("cached", st.cached.len() as u64);
    for (k, v) in st.cached.iter().enumerate() {
        w.scalar(format!("cached.{k}.view"), v.view as u64)
            .u32(format!("cached.{k}.idx"), &v.idx[..])
            .f32(format!("cached.{k}.a"), &v.a[..])
            .f32(format!("cached.{k}.w"), &v.w[..])
            .f32(format!("cached.{k}.y"), &v.y[..])
            .f32(format!("cached.{k}.plan_e"), &v.plan_e[..])
            .f64(format!("cached.{k}.stats"), vec![v.objective, v.dual, v.gap, v.transported_mass]);
    }
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
        .u64("order", st.order.iter().map(|&i| i as u64).collect::<Vec<_>>())
        .scalar("force_round", st.force_round as u64)
        .f64("timing", vec![st.editor_s, st.transport_s, st.elapsed_s]);
    put_rng(&mut w, "rng", &st.rng);
    ck.write(STATE_FILE, &w, st.step as u64).map_err(err)?;
    Ok(())
}

/// Reads the loop state; `editor_sum` is the checksum of the editor file read with it.
pub(crate) fn load_state(
    ck: &mut Checkpointer,
    config: TrainConfig,
    editor_sum: u64,
    views: usize,
) -> Result<(Trainer, LoopState), EditError> {
    let a = ck.read(STATE_FILE).map_err(err)?;
    let e = |m: String| aerr(a.err(m));
    if a.scalar("editor_checksum").map_err(aerr)? != editor_sum {
        return Err(e(format!("belongs with another {EDITOR_FILE} (checksums differ)")));
    }
    let tr = get_trainer(&a, "tr", config).map_err(err)?;
    let n = tr.model.len();
    let d = tr.model.num_features;
    let kc = tr.model.gaussians.sh_coeffs() * 3;
    let f = |name: &str, len: usize| a.f32_len(name, len).map(<[f32]>::to_vec).map_err(aerr);
    let opt = |name: &str, len: usize| if a.has(name) { f(name, len).map(Some) } else { Ok(None) };
    let lifted = if a.has("lifted") {
        let l = a.u32("lifted").map_err(aerr)?;
        if l.len() != n {
            return Err(e(format!("lifted mask has {} entries for {n} Gaussians", l.len())));
        }
        Some(l.iter().map(|&b| b != 0).collect())
    } else {
        None
    };
    let count = a.scalar("cached").map_err(aerr)? as usize;
    if count > views {
        return Err(e(format!("{count} cached view plans for {views} views")));
    }
    let mut cached = Vec::with_capacity(count);
    for k in 0..count {
        let p = |s: &str| format!("cached.{k}.{s}");
        let idx = a.u32(&p("idx")).map_err(aerr)?.to_vec();
        if idx.iter().any(|&i| i as usize >= n) {
            return Err(e(format!("cached view plan {k} refers to a Gaussian out of range")));
        }
        let m = idx.len();
        let stats = a.f64(&p("stats")).map_err(aerr)?;
        let &[objective, dual, gap, transported_mass] = stats else {
            return Err(e(format!("cached view plan {k}: bad statistics")));
        };
        cached.push(ViewTransport {
            view: a.scalar(&p("view")).map_err(aerr)? as usize,
            a: f(&p("a"), m)?,
            w: f(&p("w"), m)?,
            y: f(&p("y"), m * d)?,
            plan_e: f(&p("plan_e"), m * d)?,
            idx,
            objective,
            dual,
            gap,
            transported_mass,
        });
    }
    let rounds = a.f64("rounds").map_err(aerr)?;
    let losses = a.f64("losses").map_err(aerr)?;
    let timing = a.f64("timing").map_err(aerr)?;
    if rounds.len() % 9 != 0 || losses.len() % 5 != 0 || timing.len() != 3 {
        return Err(e("round, loss or timing records are malformed".into()));
    }
    let order: Vec<usize> = a.u64("order").map_err(aerr)?.iter().map(|&i| i as usize).collect();
    if order.iter().any(|&i| i >= views) {
        return Err(e("the saved view order refers to a view out of range".into()));
    }
    let step = a.scalar("step").map_err(aerr)? as usize;
    if step as u64 != tr.step {
        return Err(e(format!("loop step {step} and trainer step {} differ", tr.step)));
    }
    let st = LoopState {
        step,
        sh0: f("sh0", n * kc)?,
        gamma: f("gamma", n)?,
        zbar: opt("zbar", n * d)?,
        cached,
        rounds: rounds
            .chunks_exact(9)
            .map(|r| RoundStats {
                round: r[0] as usize,
                step: r[1] as usize,
                views: r[2] as usize,
                objective: r[3],
                dual: r[4],
                gap: r[5],
                transported_mass: r[6],
                mean_gate: r[7],
                seconds: r[8],
            })
            .collect(),
        losses: losses
            .chunks_exact(5)
            .map(|l| StepLosses { step: l[0] as usize, img: l[1], sem: l[2], uot: l[3], leak: l[4] })
            .collect(),
        order,
        rng: get_rng(&a, "rng").map_err(err)?,
        force_round: a.scalar("force_round").map_err(aerr)? != 0,
        lifted,
        gate_report: opt("gate_report", n)?,
        editor_s: timing[0],
        transport_s: timing[1],
        elapsed_s: timing[2],
    };
    ck.last = Some(step as u64);
    Ok((tr, st))
}
