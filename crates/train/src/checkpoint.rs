//! Checkpoints of long runs (training in [`fit`](mod@crate::fit), the edit loop in the
//! edit crate): everything needed to continue bit-identically, in a
//! [`transsplat_scene::archive`] file written atomically into a checkpoint folder.
//!
//! A checkpoint holds the model (every array, extras and feature channels), the
//! Adam moments and step counters per group, the densification statistics, the step,
//! the active SH degree, the scene extent, the random generator states, and a
//! [`RunId`]: the run's settings as text and a hash of its inputs. Resuming with
//! other settings or inputs is refused with a message naming the first difference.
//! The learning-rate schedule is a function of the step, so it resumes with it.
//!
//! [`Control`] is how a caller steers a long loop: a cancel flag (Ctrl-C), a
//! [`Checkpointer`] (folder and interval), a deterministic stop after k steps (for
//! tests of resuming) and whether to resume.

use crate::adam::{Adam, Group, GroupState};
use crate::densify::DensifyStats;
use crate::model::Model;
use crate::trainer::{TrainConfig, TrainError, Trainer};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use transsplat_scene::archive::{Archive, Writer};
use transsplat_scene::{sh_coeffs, Extra, Gaussians};

/// What identifies a run: its settings as text (compared line by line when
/// resuming) and a hash of its inputs.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct RunId {
    pub settings: String,
    pub inputs: u64,
}

impl RunId {
    /// Stores the identity in a checkpoint.
    pub fn put<'a>(&'a self, w: &mut Writer<'a>) {
        w.text("run.settings", self.settings.as_str()).scalar("run.inputs", self.inputs);
    }

    /// Refuses a checkpoint made by a run with other settings or inputs.
    pub fn check(&self, a: &Archive) -> Result<(), TrainError> {
        let theirs = a.text("run.settings")?;
        if theirs != self.settings {
            let (old, new) = theirs
                .lines()
                .map(str::trim)
                .zip(self.settings.lines().map(str::trim))
                .find(|(a, b)| a != b)
                .unwrap_or(("(more settings)", "(fewer settings)"));
            return Err(TrainError::Resume(format!(
                "{}: the checkpoint was made with other settings ({old} in the checkpoint, {new} now); \
                 resume with the settings of the interrupted run",
                a.path().display()
            )));
        }
        if a.scalar("run.inputs")? != self.inputs {
            return Err(TrainError::Resume(format!(
                "{}: the checkpoint was made from other inputs (scene, cameras, images or instruction \
                 differ); resume with the inputs of the interrupted run",
                a.path().display()
            )));
        }
        Ok(())
    }
}

/// Where and how often checkpoints are written, and the last one made.
#[derive(Clone, Debug)]
pub struct Checkpointer {
    /// The checkpoint folder (created when the first checkpoint is written).
    pub dir: PathBuf,
    /// A checkpoint every this many steps (0 = only when stopped).
    pub every: u64,
    /// The run's identity, stored in and checked against every checkpoint.
    pub id: RunId,
    /// Step of the newest checkpoint written or resumed from.
    pub last: Option<u64>,
}

impl Checkpointer {
    pub fn new(dir: impl Into<PathBuf>, every: u64) -> Self {
        Checkpointer { dir: dir.into(), every, id: RunId::default(), last: None }
    }

    /// A file in the checkpoint folder.
    pub fn file(&self, name: &str) -> PathBuf {
        self.dir.join(name)
    }

    /// Whether a periodic checkpoint is due at the top of step `step` of a run (or
    /// resumed run) that began at `start`.
    pub fn due(&self, step: u64, start: u64) -> bool {
        self.every > 0 && step > start && step.is_multiple_of(self.every) && self.last != Some(step)
    }

    /// Writes `w` as `name` in the folder (atomically: the previous checkpoint stays
    /// valid until the new one is complete) and records `step`; returns the checksum.
    pub fn write(&mut self, name: &str, w: &Writer, step: u64) -> Result<u64, TrainError> {
        let t = std::time::Instant::now();
        std::fs::create_dir_all(&self.dir).map_err(|e| transsplat_scene::Error::io(&self.dir, e))?;
        let path = self.file(name);
        let sum = w.write(&path)?;
        self.last = Some(step);
        let mb = std::fs::metadata(&path).map_or(0.0, |m| m.len() as f64 / 1e6);
        tracing::debug!(
            "checkpoint at step {step}: {} ({mb:.1} MB in {:.2} s)",
            path.display(),
            t.elapsed().as_secs_f64()
        );
        Ok(sum)
    }

    /// Reads `name` from the folder and checks it belongs to this run.
    pub fn read(&self, name: &str) -> Result<Archive, TrainError> {
        let path = self.file(name);
        if !path.is_file() {
            return Err(TrainError::Resume(format!("{}: no checkpoint to resume from", path.display())));
        }
        let a = Archive::read(&path)?;
        self.id.check(&a)?;
        Ok(a)
    }

    /// A sentence about the last good checkpoint, for messages after a failure.
    pub fn note(&self) -> String {
        match self.last {
            Some(s) => format!("the last good checkpoint (step {s}) remains in {}", self.dir.display()),
            None => "no checkpoint had been written yet".into(),
        }
    }

    /// Removes the checkpoint folder (after the run's output is complete).
    pub fn remove(&self) {
        if self.dir.is_dir() {
            if let Err(e) = std::fs::remove_dir_all(&self.dir) {
                tracing::warn!("{}: cannot remove the checkpoint folder: {e}", self.dir.display());
            }
        }
    }
}

/// How a caller steers a long loop.
#[derive(Debug, Default)]
pub struct Control<'a> {
    /// Set by Ctrl-C: the loop writes a checkpoint (when enabled) and stops.
    pub cancel: Option<&'a AtomicBool>,
    /// Checkpointing; `None` = no checkpoints.
    pub checkpoint: Option<Checkpointer>,
    /// Stop as if interrupted once this many steps are done (deterministic tests of
    /// resuming).
    pub stop_after: Option<u64>,
    /// Continue from the checkpoint in `checkpoint.dir` (used by the edit loop;
    /// training restores with [`Checkpointer::load_train`]).
    pub resume: bool,
}

impl Control<'_> {
    /// Whether the loop must stop at the top of step `step` (steps done so far).
    pub fn should_stop(&self, step: u64) -> bool {
        self.cancel.is_some_and(|c| c.load(Ordering::Relaxed)) || self.stop_after.is_some_and(|k| step >= k)
    }

    /// The sentence about checkpoints for a message after a failure.
    pub fn note(&self) -> String {
        self.checkpoint.as_ref().map_or("checkpoints were off".into(), Checkpointer::note)
    }
}

/// Stores a random generator's full state (seed, stream, position).
pub fn put_rng(w: &mut Writer, name: &str, rng: &ChaCha8Rng) {
    let seed = rng.get_seed();
    let mut v: Vec<u64> =
        seed.chunks_exact(8).map(|c| u64::from_le_bytes(c.try_into().expect("8"))).collect();
    let pos = rng.get_word_pos();
    v.extend([rng.get_stream(), pos as u64, (pos >> 64) as u64]);
    w.u64(name.to_string(), v);
}

/// Restores a random generator stored by [`put_rng`].
pub fn get_rng(a: &Archive, name: &str) -> Result<ChaCha8Rng, TrainError> {
    let v = a.u64(name)?;
    if v.len() != 7 {
        return Err(a.err(format!("entry {name:?} is not a random generator state")).into());
    }
    let mut seed = [0u8; 32];
    for (k, w) in v[..4].iter().enumerate() {
        seed[k * 8..(k + 1) * 8].copy_from_slice(&w.to_le_bytes());
    }
    let mut rng = ChaCha8Rng::from_seed(seed);
    rng.set_stream(v[4]);
    rng.set_word_pos(v[5] as u128 | (v[6] as u128) << 64);
    Ok(rng)
}

/// Stores a trainer's state under `p.` (the config is the run's and not stored).
pub fn put_trainer<'a>(w: &mut Writer<'a>, p: &str, t: &'a Trainer) {
    let g = &t.model.gaussians;
    w.f32(format!("{p}.means"), g.means.as_flattened())
        .f32(format!("{p}.log_scales"), g.log_scales.as_flattened())
        .f32(format!("{p}.rotations"), g.rotations.as_flattened())
        .f32(format!("{p}.opacity_logits"), &g.opacity_logits[..])
        .scalar(format!("{p}.sh_degree"), g.sh_degree as u64)
        .f32(format!("{p}.sh"), &g.sh[..])
        .text(format!("{p}.extra_names"), g.extra.names.join("\n"))
        .f32(format!("{p}.extra_values"), &g.extra.values[..])
        .scalar(format!("{p}.num_features"), t.model.num_features as u64)
        .f32(format!("{p}.features"), &t.model.features[..]);
    for (k, st) in t.adam.groups.iter().enumerate() {
        w.f32(format!("{p}.adam.{k}.m"), &st.m[..]).f32(format!("{p}.adam.{k}.v"), &st.v[..]);
    }
    w.u64(format!("{p}.adam.steps"), t.adam.groups.iter().map(|s| s.step).collect::<Vec<_>>())
        .f32(format!("{p}.adam.hyper"), vec![t.adam.betas.0, t.adam.betas.1, t.adam.eps])
        .f32(format!("{p}.stats.grad_accum"), &t.stats.grad_accum[..])
        .u32(format!("{p}.stats.denom"), &t.stats.denom[..])
        .f32(format!("{p}.stats.max_radii"), &t.stats.max_radii[..])
        .f32(format!("{p}.extent"), vec![t.extent])
        .scalar(format!("{p}.step"), t.step)
        .scalar(format!("{p}.active_sh_degree"), t.active_sh_degree as u64);
    if let Some(c) = t.centre {
        w.f32(format!("{p}.centre"), c.to_vec());
    }
    if !t.cameras.is_empty() {
        w.f32(format!("{p}.cameras"), t.cameras.as_flattened());
    }
    put_rng(w, &format!("{p}.rng"), &t.rng);
}

/// The first parameter group of `model` holding a NaN or infinite value.
pub fn non_finite_parameters(model: &Model) -> Option<&'static str> {
    let g = &model.gaussians;
    let bad = |v: &[f32]| v.par_iter().with_min_len(1 << 14).any(|x| !x.is_finite());
    [
        (Group::Position, g.means.as_flattened()),
        (Group::Scaling, g.log_scales.as_flattened()),
        (Group::Rotation, g.rotations.as_flattened()),
        (Group::Opacity, &g.opacity_logits[..]),
        (Group::ShDc, &g.sh[..]),
        (Group::Features, &model.features[..]),
    ]
    .into_iter()
    .find(|(_, v)| bad(v))
    .map(|(grp, _)| grp.name())
}

/// Restores a trainer stored by [`put_trainer`], checking every length and value.
pub fn get_trainer(a: &Archive, p: &str, config: TrainConfig) -> Result<Trainer, TrainError> {
    let k = |s: &str| format!("{p}.{s}");
    let means = a.f32(&k("means"))?;
    if means.len() % 3 != 0 {
        return Err(a.err("means are not triples").into());
    }
    let n = means.len() / 3;
    let sh_degree = a.scalar(&k("sh_degree"))?;
    if sh_degree > 3 {
        return Err(a.err(format!("SH degree {sh_degree} is not 0 to 3")).into());
    }
    let sh_degree = sh_degree as u32;
    let names_text = a.text(&k("extra_names"))?;
    let names: Vec<String> =
        if names_text.is_empty() { Vec::new() } else { names_text.split('\n').map(str::to_string).collect() };
    let num_features = a.scalar(&k("num_features"))? as usize;
    let len = |name: &str, w: usize| -> Result<Vec<f32>, TrainError> {
        let want = n.checked_mul(w).ok_or_else(|| a.err("sizes overflow"))?;
        Ok(a.f32_len(&k(name), want)?.to_vec())
    };
    let gaussians = Gaussians {
        means: means.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
        log_scales: len("log_scales", 3)?.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
        rotations: len("rotations", 4)?.chunks_exact(4).map(|c| [c[0], c[1], c[2], c[3]]).collect(),
        opacity_logits: len("opacity_logits", 1)?,
        sh_degree,
        sh: len("sh", sh_coeffs(sh_degree) * 3)?,
        extra: Extra { values: len("extra_values", names.len())?, names },
    };
    let model = Model { gaussians, features: len("features", num_features)?, num_features };
    if let Some(group) = non_finite_parameters(&model) {
        return Err(a.err(format!("the checkpoint holds NaN or infinite {group}")).into());
    }
    let mut adam = Adam::new(&model);
    let steps = a.u64(&k("adam.steps"))?;
    let hyper = a.f32_len(&k("adam.hyper"), 3)?;
    if steps.len() != 7 {
        return Err(a.err("Adam state does not have 7 groups").into());
    }
    adam.betas = (hyper[0], hyper[1]);
    adam.eps = hyper[2];
    for (g, st) in adam.groups.iter_mut().enumerate() {
        let (m, v) = (a.f32(&k(&format!("adam.{g}.m")))?, a.f32(&k(&format!("adam.{g}.v")))?);
        let want = n * st.width;
        if m.len() != v.len() || !(m.is_empty() || m.len() == want) {
            return Err(a.err(format!("Adam moments of group {g} do not match {n} Gaussians")).into());
        }
        *st = GroupState { width: st.width, m: m.to_vec(), v: v.to_vec(), step: steps[g], live: Vec::new() };
    }
    let stats = DensifyStats {
        grad_accum: len("stats.grad_accum", 1)?,
        denom: a.u32(&k("stats.denom"))?.to_vec(),
        max_radii: len("stats.max_radii", 1)?,
    };
    if stats.denom.len() != n {
        return Err(a.err("densification statistics do not match the Gaussians").into());
    }
    let extent = a.f32_len(&k("extent"), 1)?[0];
    let mut t = Trainer::new(model, extent, config)?;
    // Absent in checkpoints of trainers made without cameras (and before it was saved).
    if a.has(&k("centre")) {
        let c = a.f32_len(&k("centre"), 3)?;
        t.centre = Some([c[0], c[1], c[2]]);
    }
    if a.has(&k("cameras")) {
        let c = a.f32(&k("cameras"))?;
        if c.len() % 3 != 0 {
            return Err(a.err("camera centres are not triples").into());
        }
        t.cameras = c.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
    }
    t.adam = adam;
    t.stats = stats;
    t.step = a.scalar(&k("step"))?;
    t.active_sh_degree = (a.scalar(&k("active_sh_degree"))? as u32).min(sh_degree);
    t.rng = get_rng(a, &k("rng"))?;
    Ok(t)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::Rng;
    use std::path::Path;

    #[test]
    fn rng_state_round_trips_mid_block() {
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        rng.set_stream(3);
        for draws in [0usize, 1, 15, 16, 33] {
            let mut r = rng.clone();
            for _ in 0..draws {
                let _: u32 = r.gen();
            }
            let _: u64 = r.gen();
            let mut w = Writer::new();
            put_rng(&mut w, "r", &r);
            let a = Archive::parse(&w.to_bytes(), Path::new("r.ckpt")).unwrap();
            let mut back = get_rng(&a, "r").unwrap();
            let want: Vec<u64> = (0..40).map(|_| r.gen()).collect();
            let got: Vec<u64> = (0..40).map(|_| back.gen()).collect();
            assert_eq!(want, got, "after {draws} draws");
        }
    }
}
