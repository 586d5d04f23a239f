//! Adam per parameter group with the INRIA 3DGS learning rates.
//!
//! The update is PyTorch's `torch.optim.Adam` (which INRIA uses, with eps 1e-15):
//! `m ← β₁m + (1−β₁)g`, `v ← β₂v + (1−β₂)g²`,
//! `p ← p − lr/(1−β₁ᵗ) · m / (√v/√(1−β₂ᵗ) + eps)`, with one step counter per group.
//! Two update rules ([`Update`]):
//! - **dense** (INRIA): every Gaussian is updated every step; a Gaussian unseen this
//!   step still moves by its decaying momentum.
//! - **selective** (the "visible Adam" of gsplat's `SelectiveAdam` and of Taming 3DGS):
//!   a Gaussian's row of a group is updated only in steps where its gradient is
//!   non-zero; otherwise its parameters *and moments* stay as they are, so momentum
//!   does not carry a Gaussian the view cannot see, and its moments decay in "steps
//!   it was seen" rather than in wall steps. The bias correction still uses the group's
//!   step counter. The cost of a step is then proportional to the Gaussians the view
//!   reached, not to the model (docs/method.md M10).
//!
//! A group whose learning rate is 0 is skipped entirely — parameters, moments and step
//! counter stay as they are — so the edit stage can freeze geometry.
//!
//! The position learning rate follows INRIA's `get_expon_lr_func` (without the
//! delay, which INRIA's defaults disable): log-linear from `1.6e-4 · extent` to
//! `1.6e-6 · extent` over `max_steps`, constant after.

use crate::model::{Model, Reindex};
use rayon::prelude::*;
use transsplat_raster::Grads;
use transsplat_scene::cpu::prefetch_bytes;

/// The parameter groups, one learning rate and one Adam state each.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Group {
    Position,
    ShDc,
    ShRest,
    Opacity,
    Scaling,
    Rotation,
    Features,
}

impl Group {
    /// Every group, in state order.
    pub const ALL: [Group; 7] = [
        Group::Position,
        Group::ShDc,
        Group::ShRest,
        Group::Opacity,
        Group::Scaling,
        Group::Rotation,
        Group::Features,
    ];

    /// Index into [`Adam::groups`].
    pub fn index(self) -> usize {
        self as usize
    }

    /// The parameters' name in messages (means, scales, rotations, opacities, sh,
    /// features).
    pub fn name(self) -> &'static str {
        match self {
            Group::Position => "means",
            Group::ShDc => "sh",
            Group::ShRest => "sh (higher degrees)",
            Group::Opacity => "opacities",
            Group::Scaling => "scales",
            Group::Rotation => "rotations",
            Group::Features => "features",
        }
    }

    /// Values per Gaussian in this group for a model.
    pub fn width(self, model: &Model) -> usize {
        match self {
            Group::Position | Group::Scaling | Group::ShDc => 3,
            Group::ShRest => model.gaussians.sh_coeffs().saturating_sub(1) * 3,
            Group::Opacity => 1,
            Group::Rotation => 4,
            Group::Features => model.num_features,
        }
    }
}

/// Learning rates (INRIA 3DGS defaults). The position rates are multiplied by the
/// scene extent.
#[derive(Clone, Debug, PartialEq)]
pub struct LearningRates {
    /// Position learning rate at step 0, in units of the scene extent.
    pub position_init: f32,
    /// Position learning rate at `position_max_steps`, in units of the scene extent.
    pub position_final: f32,
    /// Length of the exponential decay; `None` = the length of the run.
    pub position_max_steps: Option<u64>,
    pub sh_dc: f32,
    pub sh_rest: f32,
    pub opacity: f32,
    pub scaling: f32,
    pub rotation: f32,
    pub features: f32,
}

impl Default for LearningRates {
    fn default() -> Self {
        LearningRates {
            position_init: 1.6e-4,
            position_final: 1.6e-6,
            position_max_steps: None,
            sh_dc: 2.5e-3,
            sh_rest: 2.5e-3 / 20.0,
            opacity: 0.025,
            scaling: 5e-3,
            rotation: 1e-3,
            features: 2.5e-3,
        }
    }
}

impl LearningRates {
    /// Every learning rate zero except colour (SH) and features: the edit stage's
    /// "appearance only" setting.
    pub fn colour_only(&self) -> Self {
        LearningRates {
            position_init: 0.0,
            position_final: 0.0,
            opacity: 0.0,
            scaling: 0.0,
            rotation: 0.0,
            ..self.clone()
        }
    }

    /// The learning rate of each group at `step` (1-based, as INRIA's iteration) for a
    /// run of `total_steps` and a scene of size `extent`, indexed by [`Group::index`].
    pub fn at(&self, step: u64, total_steps: u64, extent: f32) -> [f32; 7] {
        let max_steps = self.position_max_steps.unwrap_or(total_steps).max(1);
        let pos = expon_lr(step, self.position_init * extent, self.position_final * extent, max_steps);
        [pos, self.sh_dc, self.sh_rest, self.opacity, self.scaling, self.rotation, self.features]
    }
}

/// INRIA's `get_expon_lr_func` without delay: `exp(lerp(ln init, ln final, t))`,
/// `t = clamp(step / max_steps, 0, 1)`; 0 when both rates are 0.
pub fn expon_lr(step: u64, init: f32, final_: f32, max_steps: u64) -> f32 {
    if init == 0.0 && final_ == 0.0 {
        return 0.0;
    }
    let t = (step as f64 / max_steps.max(1) as f64).clamp(0.0, 1.0);
    let (a, b) = ((init as f64).max(1e-30).ln(), (final_ as f64).max(1e-30).ln());
    (a * (1.0 - t) + b * t).exp() as f32
}

/// Adam state of one group: moments with `width` values per Gaussian (allocated at
/// the group's first step) and the step counter.
#[derive(Clone, Debug, Default)]
pub struct GroupState {
    pub width: usize,
    pub m: Vec<f32>,
    pub v: Vec<f32>,
    pub step: u64,
    /// `live[i]`: row i of `m` or `v` holds a non-zero value. A cache of the moments
    /// (not part of equality, not saved): empty means unknown, rebuilt at the next step.
    pub live: Vec<bool>,
}

impl PartialEq for GroupState {
    fn eq(&self, o: &Self) -> bool {
        (self.width, &self.m, &self.v, self.step) == (o.width, &o.m, &o.v, o.step)
    }
}

impl GroupState {
    /// Begins this group's step over `n` Gaussians (moments allocated at the first, the
    /// live flags rebuilt if they were dropped, the step counter advanced): its share
    /// `block` of the parameter rows, its constants at learning rate `lr`, its moments.
    fn begin_step(
        &mut self,
        group: Group,
        n: usize,
        block: Block,
        lr: f32,
        betas: (f32, f32),
        eps: f32,
    ) -> Part<'_> {
        if self.m.len() != n * self.width {
            assert!(self.m.is_empty(), "Adam moments of {} are out of step with the model", group.name());
            self.m = vec![0.0; n * self.width];
            self.v = vec![0.0; n * self.width];
        }
        if self.live.len() != n {
            self.rebuild_live(n);
        }
        self.step += 1;
        let h = Hyper::at(lr, betas, eps, self.step);
        Part { b: block, h, mo: Moments { m: &mut self.m, v: &mut self.v, live: &mut self.live } }
    }

    /// Recomputes [`GroupState::live`] from the moments.
    fn rebuild_live(&mut self, n: usize) {
        let w = self.width.max(1);
        self.live = if self.m.is_empty() {
            vec![false; n]
        } else {
            self.m
                .par_chunks(w)
                .zip(self.v.par_chunks(w))
                .map(|(m, v)| m.iter().chain(v).any(|&x| x != 0.0))
                .collect()
        };
    }
}

/// Which rows an [`Adam::step`] moves (module doc).
#[derive(Clone, Copy, Debug)]
pub enum Update<'a> {
    /// Every row, as INRIA (rows with zero gradient and zero moments are skipped, an
    /// exact shortcut). `Some(rows)` lists, ascending, every row whose gradient may be
    /// non-zero, so the step touches only those and the rows with live moments instead
    /// of reading every row's gradient; `None` reads them. Both give the same result.
    Dense(Option<&'a [u32]>),
    /// Only rows with a non-zero gradient. `Some(rows)` lists, ascending, every row
    /// whose gradient may be non-zero (what [`transsplat_raster::backward`] returns), so
    /// the step visits only those; `None` scans every row's gradient. Both give the
    /// same result.
    Selective(Option<&'a [u32]>),
}

/// Which update rule a training run uses ([`Update`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum AdamRule {
    /// INRIA's dense Adam.
    #[default]
    Dense,
    /// Selective ("visible") Adam: only the rows the step's view reached.
    Selective,
}

impl AdamRule {
    /// Every rule.
    pub const ALL: [AdamRule; 2] = [AdamRule::Dense, AdamRule::Selective];

    /// The rule's name in options and summaries (`dense`, `selective`).
    pub fn name(self) -> &'static str {
        match self {
            AdamRule::Dense => "dense",
            AdamRule::Selective => "selective",
        }
    }

    /// The rule named `name` ([`AdamRule::name`]).
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|r| r.name() == name)
    }
}

/// Adam over the seven groups.
#[derive(Clone, Debug, PartialEq)]
pub struct Adam {
    /// Indexed by [`Group::index`].
    pub groups: [GroupState; 7],
    pub betas: (f32, f32),
    pub eps: f32,
}

impl Adam {
    /// Fresh state for `model` (β = (0.9, 0.999), eps = 1e-15 as INRIA).
    pub fn new(model: &Model) -> Self {
        Adam {
            groups: Group::ALL.map(|g| GroupState { width: g.width(model), ..Default::default() }),
            betas: (0.9, 0.999),
            eps: 1e-15,
        }
    }

    /// Applies `r` to every moment; fresh rows start at zero, as INRIA's
    /// `densification_postfix` does. A group never stepped stays lazily empty.
    pub fn reindex(&mut self, r: &Reindex) {
        // Exhaustive destructuring: a new field must be handled here.
        let Adam { groups, betas: _, eps: _ } = self;
        for g in groups.iter_mut() {
            if g.m.is_empty() && g.v.is_empty() {
                continue; // never stepped (e.g. frozen group)
            }
            let w = g.width;
            g.m = r.gather_fresh_zero(&g.m, w, 0.0);
            g.v = r.gather_fresh_zero(&g.v, w, 0.0);
            g.live.clear();
        }
    }

    /// Zeroes the moments of `group` for the Gaussians where `which` is true (all
    /// when `None`), as INRIA's `replace_tensor_to_optimizer` after an opacity reset.
    pub fn zero_moments(&mut self, group: Group, which: Option<&[bool]>) {
        let g = &mut self.groups[group.index()];
        let w = g.width;
        g.live.clear();
        match which {
            None => {
                g.m.fill(0.0);
                g.v.fill(0.0);
            }
            Some(sel) if !g.m.is_empty() => {
                for (i, _) in sel.iter().enumerate().filter(|(_, &s)| s) {
                    g.m[i * w..(i + 1) * w].fill(0.0);
                    g.v[i * w..(i + 1) * w].fill(0.0);
                }
            }
            Some(_) => {}
        }
    }

    /// One Adam step of every group with a non-zero learning rate. `lr` is indexed by
    /// [`Group::index`]; `update` chooses dense or selective Adam (module doc). Panics if
    /// `grads` does not match the model (a programming error).
    ///
    /// In the dense rule a row whose gradient is zero and whose moments are zero is
    /// skipped: updating it would leave it exactly as it is (m and v stay 0, the update
    /// is lr · 0 / eps = 0), so the result is bit-identical to updating every row, and a
    /// step in which few Gaussians can change (an edit with frozen geometry) touches
    /// only those.
    ///
    /// Numerical health is checked in the same pass as the update, so it costs no extra
    /// pass over the gradients or the parameters: a NaN or infinite gradient makes its
    /// parameter NaN (m turns NaN or infinite, and with it p), so only a row whose updated
    /// parameters are not all finite has its gradient looked at. Returns the first group
    /// with a NaN or infinite gradient ([`NonFinite::Gradient`]), else the first in
    /// which an updated parameter is NaN or infinite ([`NonFinite::Parameter`]); the
    /// update is applied in full either way (the caller stops). Rows the step does not
    /// visit (selective, or dense with zero gradient and moments) have a zero gradient,
    /// so every row where a gradient can be non-finite is checked.
    #[must_use]
    pub fn step(
        &mut self,
        model: &mut Model,
        grads: &Grads,
        lr: &[f32; 7],
        update: Update,
    ) -> Option<NonFinite> {
        let n = model.len();
        let kc = model.gaussians.sh_coeffs() * 3;
        let f = model.num_features;
        assert!(
            grads.means.len() == n
                && grads.log_scales.len() == n
                && grads.rotations.len() == n
                && grads.opacity_logits.len() == n
                && grads.sh.len() == n * kc
                && grads.features.len() == n * f,
            "gradients do not match the model ({n} Gaussians, {kc} SH values, {f} features each)"
        );
        let (b1, b2, eps) = (self.betas.0, self.betas.1, self.eps);
        // Dense with the rows known: every other row's gradient is zero, so a row neither
        // listed nor live is left as it is without reading it (the update would not change
        // it). Built when a group uses it (below).
        let mut listed: Option<Vec<bool>> = None;
        let (mut bad_grad, mut bad_param) = (None, None);
        // One pass per parameter array: the SH DC and rest groups share the SH rows, so
        // they are updated together and the rows are streamed once.
        let [pos, dc, rest, op, sc, rot, ft] = &mut self.groups;
        let gs = &mut model.gaussians;
        let arrays: [SharedRows; 6] = [
            (gs.means.as_flattened_mut(), grads.means.as_flattened(), 3, vec![(Group::Position, pos, 0)]),
            (&mut gs.sh, &grads.sh, kc, vec![(Group::ShDc, dc, 0), (Group::ShRest, rest, 3)]),
            (&mut gs.opacity_logits, &grads.opacity_logits, 1, vec![(Group::Opacity, op, 0)]),
            (
                gs.log_scales.as_flattened_mut(),
                grads.log_scales.as_flattened(),
                3,
                vec![(Group::Scaling, sc, 0)],
            ),
            (
                gs.rotations.as_flattened_mut(),
                grads.rotations.as_flattened(),
                4,
                vec![(Group::Rotation, rot, 0)],
            ),
            (&mut model.features, &grads.features, f, vec![(Group::Features, ft, 0)]),
        ];
        for (params, grad, row, groups) in arrays {
            let (names, parts): (Vec<Group>, Vec<Part>) = groups
                .into_iter()
                .filter_map(|(group, st, off)| {
                    let rate = lr[group.index()];
                    let block = Block { row, off, w: st.width };
                    (rate != 0.0 && st.width > 0 && n > 0)
                        .then(|| (group, st.begin_step(group, n, block, rate, (b1, b2), eps)))
                })
                .unzip();
            let verdicts = match update {
                Update::Dense(None) => update_block(params, grad, parts, Rule::Dense(None)),
                Update::Dense(Some(rows)) => {
                    let flags = dense_flags(rows, &parts, n, &mut listed);
                    update_block(params, grad, parts, Rule::Dense(flags))
                }
                Update::Selective(None) => update_block(params, grad, parts, Rule::Selective),
                Update::Selective(Some(rows)) => {
                    parts.into_iter().map(|part| update_rows(params, grad, part, rows)).collect()
                }
            };
            for (group, bad) in names.into_iter().zip(verdicts) {
                if bad & BAD_GRAD != 0 {
                    bad_grad = bad_grad.or(Some(group));
                }
                if bad & BAD_PARAM != 0 {
                    bad_param = bad_param.or(Some(group));
                }
            }
        }
        bad_grad.map(NonFinite::Gradient).or(bad_param.map(NonFinite::Parameter))
    }
}

/// The flags of a dense step's listed `rows` (built once a step, into `listed`) where
/// they pay, else `None` (every row read in order). They pay where few rows can move (an
/// edit: listed plus live rows, estimated from every 64th live flag, at most half the
/// rows); where most rows are live (training past its first views) reading every row in
/// order measured faster (in-step Adam at 1M Gaussians, 256²: 51–52 against 56–62 ms).
/// The same bits either way: the choice is speed only.
fn dense_flags<'a>(
    rows: &[u32],
    parts: &[Part],
    n: usize,
    listed: &'a mut Option<Vec<bool>>,
) -> Option<&'a [bool]> {
    let live = parts.iter().map(|p| p.mo.live.iter().step_by(64).filter(|&&l| l).count() * 64).max();
    if rows.len() + live.unwrap_or(0) > n / 2 {
        return None;
    }
    Some(listed.get_or_insert_with(|| {
        let mut flags = vec![false; n];
        rows.iter().for_each(|&r| flags[r as usize] = true);
        flags
    }))
}

/// A parameter array, its gradients, its row width and the groups that share its rows
/// (with their first column).
type SharedRows<'a> = (&'a mut [f32], &'a [f32], usize, Vec<(Group, &'a mut GroupState, usize)>);

/// Adam's constants at one step: β₁, β₂, eps and the bias corrections folded into
/// `step_size = lr / (1 − β₁ᵗ)` and `sqrt_bc2 = √(1 − β₂ᵗ)`.
#[derive(Clone, Copy, Debug)]
pub struct Hyper {
    b1: f32,
    b2: f32,
    eps: f32,
    step_size: f32,
    sqrt_bc2: f32,
}

impl Hyper {
    /// The constants of Adam step `t` (1-based) at learning rate `lr`.
    pub fn at(lr: f32, (b1, b2): (f32, f32), eps: f32, t: u64) -> Self {
        let t = t as i32;
        Hyper { b1, b2, eps, step_size: lr / (1.0 - b1.powi(t)), sqrt_bc2: (1.0 - b2.powi(t)).sqrt() }
    }

    /// One element's update (the module doc's formulas): moves `p`, `m`, `v` for
    /// gradient `g`. The one place the arithmetic lives, so every caller gets the
    /// same bits.
    #[inline(always)]
    pub fn update(&self, p: &mut f32, m: &mut f32, v: &mut f32, g: f32) {
        self.update_at(self.step_size, self.sqrt_bc2, p, m, v, g);
    }

    /// [`Hyper::update`] with the step size and bias correction given (another group's:
    /// β and eps are Adam's, the same in every group; [`update_shared_rows`]).
    #[inline(always)]
    fn update_at(&self, step_size: f32, sqrt_bc2: f32, p: &mut f32, m: &mut f32, v: &mut f32, g: f32) {
        *m = self.b1 * *m + (1.0 - self.b1) * g;
        *v = self.b2 * *v + (1.0 - self.b2) * g * g;
        *p -= step_size * *m / (v.sqrt() / sqrt_bc2 + self.eps);
    }
}

/// What [`Adam::step`] found NaN or infinite, and in which group.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NonFinite {
    /// A gradient (which turned its parameters NaN: the step stops there).
    Gradient(Group),
    /// A parameter after its update.
    Parameter(Group),
}

/// [`update_row`]'s verdict bits: an updated parameter is not finite.
const BAD_PARAM: u8 = 1;
/// [`update_row`]'s verdict bits: the gradient is not finite.
const BAD_GRAD: u8 = 2;

/// One group's moments and their live rows.
struct Moments<'a> {
    m: &'a mut [f32],
    v: &'a mut [f32],
    live: &'a mut [bool],
}

/// Columns `off..off + w` of a row-major array with rows of `row` values: one group's
/// share of a parameter array.
#[derive(Clone, Copy)]
struct Block {
    row: usize,
    off: usize,
    w: usize,
}

/// One group's share of a parameter array: its columns, its constants this step and
/// its moments.
struct Part<'a> {
    b: Block,
    h: Hyper,
    mo: Moments<'a>,
}

/// Updates one row (`p`, `g`: the Gaussian's whole parameter and gradient rows; `mo`:
/// its moments, one live flag) unless its gradient is zero and either the rule is
/// selective or its moments are zero ([`Adam::step`]). Returns 0 when every updated
/// value is finite, else [`BAD_GRAD`] when the gradient has a NaN or infinite value
/// (which always makes an updated value NaN), else [`BAD_PARAM`].
#[inline(always)]
fn update_row(p: &mut [f32], g: &[f32], mo: Moments, b: Block, selective: bool, h: &Hyper) -> u8 {
    let Moments { m, v, live: [live] } = mo else { unreachable!("one row has one live flag") };
    let g = &g[b.off..b.off + b.w];
    if (selective || !*live) && g.iter().all(|&x| x == 0.0) {
        return 0;
    }
    let (mut bad, mut nonzero) = (false, false);
    for k in 0..b.w {
        let pk = &mut p[b.off + k];
        h.update(pk, &mut m[k], &mut v[k], g[k]);
        bad |= !pk.is_finite();
        nonzero |= (m[k] != 0.0) | (v[k] != 0.0);
    }
    *live = nonzero;
    if bad {
        non_finite_kind(g)
    } else {
        0
    }
}

/// The verdict on a row whose updated values are not all finite: [`BAD_GRAD`] when its
/// gradient `g` has a NaN or infinite value (which always makes an updated value NaN),
/// else [`BAD_PARAM`].
fn non_finite_kind(g: &[f32]) -> u8 {
    if g.iter().any(|x| !x.is_finite()) {
        BAD_GRAD
    } else {
        BAD_PARAM
    }
}

/// Whether a row's moments hold a non-zero value ([`GroupState::live`]).
fn any_nonzero(m: &[f32], v: &[f32]) -> bool {
    m.iter().chain(v).any(|&x| x != 0.0)
}

/// Which rows [`update_block`] moves: dense ([`Update::Dense`], with the rows whose
/// gradient may be non-zero flagged when known) or selective.
#[derive(Clone, Copy)]
enum Rule<'a> {
    Dense(Option<&'a [bool]>),
    Selective,
}

/// [`update_row`] over every row of every part (groups sharing the array's rows: each
/// row is updated for all of them while it is in cache), in parallel; each part's
/// verdict, the union over its rows. Under [`Rule::Dense`] with flagged rows, a row
/// neither flagged nor live (in that part) is not touched, and a run of such rows is
/// skipped after a scan of the flags: a step in which few Gaussians can change (an edit
/// with frozen geometry) costs little more than that scan.
fn update_block(p: &mut [f32], g: &[f32], parts: Vec<Part>, rule: Rule) -> Vec<u8> {
    const ROWS: usize = 2048;
    let Some(row) = parts.first().map(|part| part.b.row) else { return Vec::new() };
    let (selective, listed) = match rule {
        Rule::Dense(listed) => (false, listed),
        Rule::Selective => (true, None),
    };
    let chunks = (p.len() / row).div_ceil(ROWS);
    let heads: Vec<(Block, Hyper)> = parts.iter().map(|part| (part.b, part.h)).collect();
    // Each chunk's moments, part by part.
    let mut moments: Vec<ChunkMoments> = (0..chunks).map(|_| Vec::with_capacity(parts.len())).collect();
    for Part { b, mo, .. } in parts {
        let pieces =
            mo.m.chunks_mut(b.w * ROWS).zip(mo.v.chunks_mut(b.w * ROWS)).zip(mo.live.chunks_mut(ROWS));
        for (c, ((m, v), live)) in pieces.enumerate() {
            moments[c].push((m, v, live));
        }
    }
    let verdicts = p
        .par_chunks_mut(row * ROWS)
        .zip(g.par_chunks(row * ROWS))
        .zip(moments.into_par_iter())
        .enumerate()
        .map(|(c, ((p, g), mut mos))| {
            let rows = p.len() / row;
            let listed = listed.map(|l| &l[c * ROWS..c * ROWS + rows]);
            let idle = |l: &[bool]| !l.iter().fold(false, |a, &x| a | x);
            if listed.is_some_and(|l| idle(l) && mos.iter().all(|(_, _, live)| idle(live))) {
                return 0;
            }
            if !selective {
                if let Some(bad) = update_all_live(p, g, &mut mos, &heads) {
                    return bad;
                }
            }
            let mut bad = 0u32;
            for r in 0..rows {
                let (pr, gr) = (&mut p[r * row..(r + 1) * row], &g[r * row..(r + 1) * row]);
                let flagged = listed.is_none_or(|l| l[r]);
                for (k, ((m, v, live), (b, h))) in mos.iter_mut().zip(&heads).enumerate() {
                    let lv = &mut live[r];
                    if !flagged && !*lv {
                        continue; // gradient and moments zero: the update would change nothing
                    }
                    let w = b.w;
                    let mo = Moments {
                        m: &mut m[r * w..(r + 1) * w],
                        v: &mut v[r * w..(r + 1) * w],
                        live: std::slice::from_mut(lv),
                    };
                    bad |= u32::from(update_row(pr, gr, mo, *b, selective, h)) << (2 * k);
                }
            }
            bad
        })
        .reduce(|| 0, |a, b| a | b);
    (0..heads.len()).map(|k| (verdicts >> (2 * k)) as u8 & (BAD_GRAD | BAD_PARAM)).collect()
}

/// One part's moments (`m`, `v`, live flags) over a chunk of rows.
type PartMoments<'a> = (&'a mut [f32], &'a mut [f32], &'a mut [bool]);

/// Each part's moments over one chunk of rows.
type ChunkMoments<'a> = Vec<PartMoments<'a>>;

/// A dense chunk's update when every row of every part is live, so every row is updated:
/// in full vector lanes ([`update_whole_rows`] for a group that owns its array,
/// [`update_shared_rows`] for the SH DC and rest), compiled for AVX2 where the CPU has it
/// (the same bits: no fused operations are formed); `None` where neither applies.
/// Verdicts two bits a part, as in [`update_block`].
fn update_all_live(
    p: &mut [f32],
    g: &[f32],
    mos: &mut ChunkMoments,
    heads: &[(Block, Hyper)],
) -> Option<u32> {
    if !mos.iter().all(|(_, _, live)| live.iter().all(|&l| l)) {
        return None;
    }
    #[cfg(target_arch = "x86_64")]
    if transsplat_scene::cpu::has_avx2() {
        // SAFETY: the CPU has AVX2 and FMA (checked above).
        return unsafe { update_all_live_avx2(p, g, mos, heads) };
    }
    update_all_live_any(p, g, mos, heads)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn update_all_live_avx2(
    p: &mut [f32],
    g: &[f32],
    mos: &mut ChunkMoments,
    heads: &[(Block, Hyper)],
) -> Option<u32> {
    update_all_live_any(p, g, mos, heads)
}

#[inline(always)]
fn update_all_live_any(
    p: &mut [f32],
    g: &[f32],
    mos: &mut ChunkMoments,
    heads: &[(Block, Hyper)],
) -> Option<u32> {
    match (heads, &mut mos[..]) {
        ([(b, h)], [(m, v, live)]) if b.w == b.row => {
            Some(u32::from(update_whole_rows(p, g, m, v, live, b.w, h)))
        }
        ([(b0, h0), (b1, h1)], [dc, rest])
            if b0.off == 0 && b1.off == b0.w && b0.w + b1.w == b0.row && b0.row <= SHARED_MAX =>
        {
            Some(update_shared_rows(p, g, [dc, rest], [(*b0, h0), (*b1, h1)]))
        }
        _ => None,
    }
}

/// [`update_row`] over a chunk of whole rows of `w` values (a group that owns its
/// parameter array) when every row is updated: one elementwise pass over the chunk, so
/// the arithmetic fills the vector lanes whatever the row width (rows of 1, 3 or 4 values
/// otherwise leave most lanes idle, and Adam waited on its square roots and divisions:
/// at 1M Gaussians, 256², Adam alone took 51 ms, 33–34 with this), then the rows' live
/// flags and, only if a value went non-finite, the rows' verdicts. The same arithmetic
/// per value as [`update_row`], so the same bits.
#[inline(always)]
fn update_whole_rows(
    p: &mut [f32],
    g: &[f32],
    m: &mut [f32],
    v: &mut [f32],
    live: &mut [bool],
    w: usize,
    h: &Hyper,
) -> u8 {
    let len = live.len() * w;
    let (p, g, m, v) = (&mut p[..len], &g[..len], &mut m[..len], &mut v[..len]);
    let mut finite = true;
    for i in 0..len {
        h.update(&mut p[i], &mut m[i], &mut v[i], g[i]);
        finite &= p[i].is_finite();
    }
    for (l, (mr, vr)) in live.iter_mut().zip(m.chunks(w).zip(v.chunks(w))) {
        *l = any_nonzero(mr, vr);
    }
    if finite {
        return 0;
    }
    let bad_rows = p.chunks(w).zip(g.chunks(w)).filter(|(pr, _)| pr.iter().any(|x| !x.is_finite()));
    bad_rows.fold(0, |bad, (_, gr)| bad | non_finite_kind(gr))
}

/// The widest row [`update_shared_rows`] takes (SH degree 3: 48 values).
const SHARED_MAX: usize = 48;

/// [`update_row`] over every row of a chunk for two groups sharing its rows (the SH DC
/// and rest: columns `0..w₀` and `w₀..row`) when every row of both is updated: each row's
/// moments of both groups are put side by side, so the row is one elementwise pass in
/// full vector lanes with each column's own step size and bias correction (the DC's three
/// values and the rest's last few otherwise each take a scalar square root and division;
/// β and eps are Adam's, the same for every group). The same arithmetic per value as
/// [`update_row`], so the same bits. Verdicts two bits a group, as in [`update_block`].
#[inline(always)]
fn update_shared_rows(
    p: &mut [f32],
    g: &[f32],
    mos: [&mut PartMoments; 2],
    heads: [(Block, &Hyper); 2],
) -> u32 {
    let [(b0, h0), (b1, h1)] = heads;
    let (w0, row) = (b0.w, b0.w + b1.w);
    let [(m0, v0, l0), (m1, v1, l1)] = mos.map(|(m, v, l)| (&mut **m, &mut **v, &mut **l));
    let mut step = [0.0f32; SHARED_MAX];
    let mut bc = [0.0f32; SHARED_MAX];
    for k in 0..row {
        let h = if k < w0 { h0 } else { h1 };
        (step[k], bc[k]) = (h.step_size, h.sqrt_bc2);
    }
    let mut bad = 0u32;
    for r in 0..l0.len() {
        let (pr, gr) = (&mut p[r * row..(r + 1) * row], &g[r * row..(r + 1) * row]);
        let (m0r, v0r) = (&mut m0[r * w0..(r + 1) * w0], &mut v0[r * w0..(r + 1) * w0]);
        let (m1r, v1r) = (&mut m1[r * b1.w..(r + 1) * b1.w], &mut v1[r * b1.w..(r + 1) * b1.w]);
        let mut m = [0.0f32; SHARED_MAX];
        let mut v = [0.0f32; SHARED_MAX];
        m[..w0].copy_from_slice(m0r);
        m[w0..row].copy_from_slice(m1r);
        v[..w0].copy_from_slice(v0r);
        v[w0..row].copy_from_slice(v1r);
        let mut finite = true;
        for k in 0..row {
            h0.update_at(step[k], bc[k], &mut pr[k], &mut m[k], &mut v[k], gr[k]);
            finite &= pr[k].is_finite();
        }
        m0r.copy_from_slice(&m[..w0]);
        m1r.copy_from_slice(&m[w0..row]);
        v0r.copy_from_slice(&v[..w0]);
        v1r.copy_from_slice(&v[w0..row]);
        l0[r] = any_nonzero(&m[..w0], &v[..w0]);
        l1[r] = any_nonzero(&m[w0..row], &v[w0..row]);
        if !finite {
            for (k, cols) in [(0, 0..w0), (1, w0..row)] {
                if pr[cols.clone()].iter().any(|x| !x.is_finite()) {
                    bad |= u32::from(non_finite_kind(&gr[cols])) << (2 * k);
                }
            }
        }
    }
    bad
}

/// Selective [`update_row`] over the listed rows only (ascending), in
/// parallel: the arrays are cut at row boundaries into one piece per run of listed rows.
fn update_rows(p: &mut [f32], g: &[f32], part: Part, rows: &[u32]) -> u8 {
    let Part { b, h, mo } = part;
    let h = &h;
    const ROWS: usize = 2048;
    let n = mo.live.len();
    let runs: Vec<&[u32]> = rows.chunks(ROWS).collect();
    // Piece k holds Gaussians [starts[k], starts[k + 1]) and run k lies inside it.
    let mut starts: Vec<usize> = runs.iter().map(|r| r[0] as usize).collect();
    if let Some(s) = starts.first_mut() {
        *s = 0;
    }
    starts.push(n);
    assert!(
        rows.windows(2).all(|r| r[0] < r[1]) && rows.last().is_none_or(|&r| (r as usize) < n),
        "rows must be ascending and in range"
    );
    let pieces =
        (cut(p, b.row, &starts), cut(mo.m, b.w, &starts), cut(mo.v, b.w, &starts), cut(mo.live, 1, &starts));
    pieces
        .into_par_iter()
        .zip(runs.into_par_iter().zip(starts.par_iter()))
        .map(|((p, m, v, live), (run, &start))| {
            let mut bad = 0;
            // The rows are scattered: fetch each a few rows ahead (raster::backward does too).
            const AHEAD: usize = 8;
            let addr = |s: &[f32], row: usize, i: usize| s.as_ptr() as usize + i * row * 4;
            for (r, &i) in run.iter().enumerate() {
                if let Some(&a) = run.get(r + AHEAD) {
                    let (a, k) = (a as usize, a as usize - start);
                    prefetch_bytes(addr(p, b.row, k), b.row * 4);
                    prefetch_bytes(addr(g, b.row, a), b.row * 4);
                    prefetch_bytes(addr(m, b.w, k), b.w * 4);
                    prefetch_bytes(addr(v, b.w, k), b.w * 4);
                }
                let (i, k) = (i as usize, i as usize - start);
                let (pr, gr) = (&mut p[k * b.row..(k + 1) * b.row], &g[i * b.row..(i + 1) * b.row]);
                let mo = Moments {
                    m: &mut m[k * b.w..(k + 1) * b.w],
                    v: &mut v[k * b.w..(k + 1) * b.w],
                    live: &mut live[k..k + 1],
                };
                bad |= update_row(pr, gr, mo, b, true, h);
            }
            bad
        })
        .reduce(|| 0, |a, b| a | b)
}

/// Cuts a row-major array (`width` values a row) into the pieces of rows
/// `[starts[k], starts[k + 1])`.
fn cut<'a, T>(mut data: &'a mut [T], width: usize, starts: &[usize]) -> Vec<&'a mut [T]> {
    let mut out = Vec::with_capacity(starts.len().saturating_sub(1));
    for s in starts.windows(2) {
        let (piece, rest) = data.split_at_mut((s[1] - s[0]) * width);
        out.push(piece);
        data = rest;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use transsplat_scene::Gaussians;

    fn one_gaussian() -> Model {
        let g = Gaussians {
            means: vec![[1.0, 2.0, 3.0]],
            log_scales: vec![[0.0; 3]],
            rotations: vec![[1.0, 0.0, 0.0, 0.0]],
            opacity_logits: vec![0.5],
            sh_degree: 1,
            sh: vec![0.1; 12],
            ..Default::default()
        };
        Model::new(g, 2)
    }

    #[test]
    fn adam_matches_hand_computed_steps() {
        let mut model = one_gaussian();
        let mut adam = Adam::new(&model);
        let mut grads = Grads::zeros(1, 1, 2);
        grads.means[0] = [0.5, -2.0, 0.0];
        grads.opacity_logits[0] = 0.25;
        grads.sh[0] = 1.0; // DC red
        grads.sh[3] = -1.0; // first rest coefficient, red
        grads.features[1] = 3.0;
        let lr = [0.1, 0.01, 0.001, 0.05, 0.0, 0.0, 0.2];
        assert!(adam.step(&mut model, &grads, &lr, Update::Dense(None)).is_none());
        // Step 1: m = 0.1 g, v = 0.001 g², m̂ = g, v̂ = g² -> p -= lr · sign(g) (eps negligible).
        let g = &model.gaussians;
        assert!((g.means[0][0] - (1.0 - 0.1)).abs() < 1e-6);
        assert!((g.means[0][1] - (2.0 + 0.1)).abs() < 1e-6);
        assert_eq!(g.means[0][2], 3.0, "zero gradient: no move at step 1");
        assert!((g.opacity_logits[0] - (0.5 - 0.05)).abs() < 1e-6);
        assert!((g.sh[0] - (0.1 - 0.01)).abs() < 1e-6);
        assert!((g.sh[3] - (0.1 + 0.001)).abs() < 1e-6);
        assert!((model.features[1] - (-0.2)).abs() < 1e-6);
        assert_eq!(g.log_scales[0], [0.0; 3], "lr 0 freezes the group");
        assert!(adam.groups[Group::Scaling.index()].m.is_empty());
        // Step 2 with gradient g2 = -1 on x: hand computation.
        grads.means[0] = [-1.0, 0.0, 0.0];
        assert!(adam.step(&mut model, &grads, &lr, Update::Dense(None)).is_none());
        let (b1, b2) = (0.9f64, 0.999f64);
        let m = b1 * (0.1 * 0.5) - 0.1;
        let v = b2 * (0.001 * 0.25) + 0.001 * 1.0;
        let upd = 0.1 / (1.0 - b1 * b1) * m / (v.sqrt() / (1.0 - b2 * b2).sqrt() + 1e-15);
        let want = 0.9 - upd;
        assert!(
            (model.gaussians.means[0][0] as f64 - want).abs() < 1e-6,
            "{} vs {want}",
            model.gaussians.means[0][0]
        );
        // y had gradient -2 then 0: moves on by momentum.
        let m = b1 * (0.1 * -2.0);
        let v = b2 * (0.001 * 4.0);
        let want = 2.1 - 0.1 / (1.0 - b1 * b1) * m / (v.sqrt() / (1.0 - b2 * b2).sqrt());
        assert!((model.gaussians.means[0][1] as f64 - want).abs() < 1e-6);
        assert_eq!(adam.groups[Group::Position.index()].step, 2);
    }

    #[test]
    fn non_finite_gradients_and_parameters_are_named_by_group_in_every_rule() {
        let lr = [0.1, 0.01, 0.001, 0.05, 0.1, 0.1, 0.2];
        for update in [Update::Dense(None), Update::Dense(Some(&[0])), Update::Selective(None)] {
            // An infinite opacity gradient; then also a NaN on a higher SH band, which
            // comes first in state order.
            for (sh_nan, want) in
                [(false, NonFinite::Gradient(Group::Opacity)), (true, NonFinite::Gradient(Group::ShRest))]
            {
                let mut model = one_gaussian();
                let mut grads = Grads::zeros(1, 1, 2);
                grads.means[0] = [1.0, 0.0, 0.0];
                grads.opacity_logits[0] = f32::INFINITY;
                if sh_nan {
                    grads.sh[7] = f32::NAN;
                }
                assert_eq!(Adam::new(&model).step(&mut model, &grads, &lr, update), Some(want));
            }
            // A finite gradient whose step overflows: the parameter is named.
            let mut model = one_gaussian();
            let mut grads = Grads::zeros(1, 1, 2);
            grads.log_scales[0] = [1.0, 0.0, 0.0];
            let mut huge = lr;
            huge[Group::Scaling.index()] = f32::MAX;
            model.gaussians.log_scales[0] = [-f32::MAX, 0.0, 0.0];
            let got = Adam::new(&model).step(&mut model, &grads, &huge, update);
            assert_eq!(got, Some(NonFinite::Parameter(Group::Scaling)));
            // Finite everywhere: nothing.
            let mut model = one_gaussian();
            assert_eq!(Adam::new(&model).step(&mut model, &grads, &lr, update), None);
        }
    }

    #[test]
    fn skipping_rows_without_gradient_or_moments_is_bit_identical_to_dense_adam() {
        // Eight Gaussians; the features group (width 2). Row 1 gets a gradient at step 1
        // only (it must keep moving by momentum), row 5 from step 2 on, row 3 never.
        let g = Gaussians {
            means: vec![[0.0; 3]; 8],
            log_scales: vec![[0.0; 3]; 8],
            rotations: vec![[1.0, 0.0, 0.0, 0.0]; 8],
            opacity_logits: vec![0.0; 8],
            sh_degree: 0,
            sh: vec![0.0; 24],
            ..Default::default()
        };
        let feats: Vec<f32> = (0..16).map(|k| (k as f32 * 0.37).sin()).collect();
        let mut model = Model::with_features(g, feats.clone(), 2).unwrap();
        let mut adam = Adam::new(&model);
        let lr = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.05];
        // Dense reference in f32 with the same expressions.
        let (mut p, mut m, mut v) = (feats, vec![0.0f32; 16], vec![0.0f32; 16]);
        for step in 1..=4 {
            let mut grads = Grads::zeros(8, 0, 2);
            let rows: &[usize] = if step == 1 { &[1, 6] } else { &[5, 6] };
            for &r in rows {
                grads.features[r * 2] = 0.3 * step as f32 - 0.5;
                grads.features[r * 2 + 1] = -0.2;
            }
            assert!(adam.step(&mut model, &grads, &lr, Update::Dense(None)).is_none());
            let (b1, b2) = (0.9f32, 0.999f32);
            let step_size = 0.05 / (1.0 - b1.powi(step));
            let bc2 = (1.0 - b2.powi(step)).sqrt();
            for k in 0..16 {
                let gk = grads.features[k];
                m[k] = b1 * m[k] + (1.0 - b1) * gk;
                v[k] = b2 * v[k] + (1.0 - b2) * gk * gk;
                p[k] -= step_size * m[k] / (v[k].sqrt() / bc2 + 1e-15);
            }
            let bits = |x: &[f32]| x.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
            assert_eq!(bits(&model.features), bits(&p), "step {step}");
            let st = &adam.groups[Group::Features.index()];
            assert_eq!((bits(&st.m), bits(&st.v)), (bits(&m), bits(&v)), "step {step}");
        }
        let live = &adam.groups[Group::Features.index()].live;
        assert_eq!(live, &[false, true, false, false, false, true, true, false]);
    }

    /// A model of `n` Gaussians (SH degree 1, two features) with varied parameters.
    fn varied_model(n: usize) -> Model {
        let wave = |k: usize, a: f32| (k as f32 * a).sin();
        let g = Gaussians {
            means: (0..n).map(|i| [wave(i, 0.3), wave(i, 0.7), wave(i, 1.1)]).collect(),
            log_scales: (0..n).map(|i| [wave(i, 0.2), wave(i, 0.5), wave(i, 0.9)]).collect(),
            rotations: (0..n).map(|i| [1.0, wave(i, 0.4), wave(i, 0.8), wave(i, 1.3)]).collect(),
            opacity_logits: (0..n).map(|i| wave(i, 0.6)).collect(),
            sh_degree: 1,
            sh: (0..n * 12).map(|k| wave(k, 0.17)).collect(),
            ..Default::default()
        };
        Model::with_features(g, (0..n * 2).map(|k| wave(k, 0.23)).collect(), 2).unwrap()
    }

    /// Gradients that are non-zero on `rows` only, different per step.
    fn grads_on(n: usize, rows: &[u32], step: u64) -> Grads {
        let mut g = Grads::zeros(n, 1, 2);
        for &r in rows {
            let (r, s) = (r as usize, step as f32);
            let x = |k: usize| ((r * 31 + k) as f32 * 0.13 + s).sin();
            g.means[r] = [x(0), x(1), x(2)];
            g.log_scales[r] = [x(3), x(4), x(5)];
            g.rotations[r] = [x(6), x(7), x(8), x(9)];
            g.opacity_logits[r] = x(10);
            g.sh[r * 12..(r + 1) * 12].iter_mut().enumerate().for_each(|(k, v)| *v = x(11 + k));
            g.features[r * 2..(r + 1) * 2].iter_mut().enumerate().for_each(|(k, v)| *v = x(23 + k));
        }
        g
    }

    #[test]
    fn dense_steps_over_live_rows_have_the_bits_of_the_formula_per_value() {
        // 3000 Gaussians (a chunk of 2048 rows and a partial one), every row reached at
        // every step but the second (rows ≡ 2 mod 5 get no gradient then, yet stay live):
        // from step 2 on each chunk takes the elementwise paths (whole rows; the SH DC and
        // rest side by side). Oracle: the update formula applied value by value.
        let n = 3000;
        let lr = [1e-3, 2e-3, 1e-4, 0.05, 5e-3, 1e-3, 2e-3];
        let mut model = varied_model(n);
        let mut adam = Adam::new(&model);
        // (group, flattened array, row width, first column) of a model's parameters or
        // of gradients: the arrays in Group order.
        type Arrays<'a> = (&'a [[f32; 3]], &'a [f32], &'a [f32], &'a [[f32; 3]], &'a [[f32; 4]], &'a [f32]);
        let flat = |(means, sh, op, ls, rot, ft): Arrays| -> Vec<(Group, Vec<f32>, usize, usize)> {
            vec![
                (Group::Position, means.as_flattened().to_vec(), 3, 0),
                (Group::ShDc, sh.to_vec(), 12, 0),
                (Group::ShRest, sh.to_vec(), 12, 3),
                (Group::Opacity, op.to_vec(), 1, 0),
                (Group::Scaling, ls.as_flattened().to_vec(), 3, 0),
                (Group::Rotation, rot.as_flattened().to_vec(), 4, 0),
                (Group::Features, ft.to_vec(), 2, 0),
            ]
        };
        let of_model = |m: &Model| {
            let g = &m.gaussians;
            flat((&g.means, &g.sh, &g.opacity_logits, &g.log_scales, &g.rotations, &m.features))
        };
        let mut want = of_model(&model);
        let mut moments: Vec<(Vec<f32>, Vec<f32>)> = want
            .iter()
            .map(|(gr, ..)| (vec![0.0; n * gr.width(&model)], vec![0.0; n * gr.width(&model)]))
            .collect();
        let all: Vec<u32> = (0..n as u32).collect();
        let some: Vec<u32> = (0..n as u32).filter(|i| i % 5 != 2).collect();
        for t in 1..=4u64 {
            let grads = grads_on(n, if t == 2 { &some } else { &all }, t);
            assert!(adam.step(&mut model, &grads, &lr, Update::Dense(None)).is_none());
            let g = &grads;
            let gflat = flat((&g.means, &g.sh, &g.opacity_logits, &g.log_scales, &g.rotations, &g.features));
            for ((group, p, row, off), ((m, v), (_, g, ..))) in
                want.iter_mut().zip(moments.iter_mut().zip(&gflat))
            {
                let w = group.width(&model);
                let h = Hyper::at(lr[group.index()], (0.9, 0.999), 1e-15, t);
                for i in 0..n {
                    for c in 0..w {
                        let (pi, mi) = (i * *row + *off + c, i * w + c);
                        h.update(&mut p[pi], &mut m[mi], &mut v[mi], g[pi]);
                    }
                }
            }
            let bits = |x: &[f32]| x.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
            for ((group, p, row, off), ((m, v), (_, got, ..))) in
                want.iter().zip(moments.iter().zip(of_model(&model)))
            {
                let w = group.width(&model);
                let cols = |x: &[f32]| -> Vec<f32> {
                    x.chunks(*row).flat_map(|r| r[*off..*off + w].to_vec()).collect()
                };
                assert_eq!(bits(&cols(&got)), bits(&cols(p)), "{group:?} parameters, step {t}");
                let st = &adam.groups[group.index()];
                assert_eq!((bits(&st.m), bits(&st.v)), (bits(m), bits(v)), "{group:?} moments, step {t}");
            }
        }
        // A non-finite gradient on live rows is named as in the per-row path.
        let mut grads = grads_on(n, &all, 5);
        grads.opacity_logits[2500] = f32::INFINITY;
        let got = adam.step(&mut model, &grads, &lr, Update::Dense(None));
        assert_eq!(got, Some(NonFinite::Gradient(Group::Opacity)));
        grads.sh[100 * 12 + 7] = f32::NAN;
        let got = adam.step(&mut model, &grads, &lr, Update::Dense(None));
        assert_eq!(got, Some(NonFinite::Gradient(Group::ShRest)), "the SH rest comes first in state order");
    }

    #[test]
    fn selective_adam_moves_only_reached_rows_and_agrees_with_dense_on_them() {
        // Every row is reached at step 1 (all moments live); from step 2 on, only some.
        let n = 5000;
        let lr = [1e-3, 2e-3, 1e-4, 0.05, 5e-3, 1e-3, 2e-3];
        let all: Vec<u32> = (0..n as u32).collect();
        let some: Vec<u32> = (0..n as u32).filter(|i| i % 3 != 1).collect();
        let (mut dense, mut sel, mut listed) = (varied_model(n), varied_model(n), varied_model(n));
        let (mut ad, mut asel, mut alisted) = (Adam::new(&dense), Adam::new(&sel), Adam::new(&listed));
        let mut dense_listed = varied_model(n);
        let mut adl = Adam::new(&dense_listed);
        for step in 1..=3u64 {
            let rows = if step == 1 { &all } else { &some };
            let g = grads_on(n, rows, step);
            let (before, abefore) = (sel.clone(), asel.clone());
            assert!(ad.step(&mut dense, &g, &lr, Update::Dense(None)).is_none());
            assert!(adl.step(&mut dense_listed, &g, &lr, Update::Dense(Some(rows))).is_none());
            assert!(asel.step(&mut sel, &g, &lr, Update::Selective(None)).is_none());
            assert!(alisted.step(&mut listed, &g, &lr, Update::Selective(Some(rows))).is_none());
            // Listing the rows is only a shortcut: bit-identical to scanning them.
            assert_eq!((&sel, &asel), (&listed, &alisted), "step {step}");
            assert_eq!((&dense, &ad), (&dense_listed, &adl), "step {step}");
            for i in 0..n {
                let reached = rows.binary_search(&(i as u32)).is_ok();
                let moved = sel.gaussians.means[i] != before.gaussians.means[i];
                assert_eq!(moved, reached, "step {step}, row {i}");
                if step == 2 && !reached {
                    // Dense Adam carries an unreached row on by its momentum; selective does not.
                    assert_ne!(dense.gaussians.means[i], before.gaussians.means[i]);
                    for (now, was) in asel.groups.iter().zip(&abefore.groups) {
                        let w = now.width;
                        assert_eq!(now.m[i * w..(i + 1) * w], was.m[i * w..(i + 1) * w]);
                        assert_eq!(now.v[i * w..(i + 1) * w], was.v[i * w..(i + 1) * w]);
                    }
                }
            }
            if step <= 2 {
                // Until a row is skipped once, both rules agree exactly on the rows reached.
                for &i in &some {
                    let i = i as usize;
                    assert_eq!(
                        dense.gaussians.sh[i * 12..(i + 1) * 12],
                        sel.gaussians.sh[i * 12..(i + 1) * 12]
                    );
                    assert_eq!(dense.features[i * 2..(i + 1) * 2], sel.features[i * 2..(i + 1) * 2]);
                }
            }
        }
    }

    #[test]
    fn dense_adam_skips_untouched_runs_of_rows_exactly() {
        // Runs of 2048 rows with nothing listed and nothing live are skipped whole: rows
        // reached first only in the first run, then only in the last, then nowhere.
        let n = 3 * 2048 + 5;
        let lr = [1e-3, 2e-3, 1e-4, 0.05, 5e-3, 1e-3, 2e-3];
        let (mut scanned, mut listed) = (varied_model(n), varied_model(n));
        let (mut a_scanned, mut a_listed) = (Adam::new(&scanned), Adam::new(&listed));
        let first: Vec<u32> = (0..2048).step_by(7).collect();
        let last: Vec<u32> = (3 * 2048..n as u32).collect();
        for (step, rows) in [&first, &last, &vec![]].into_iter().enumerate() {
            let g = grads_on(n, rows, step as u64 + 1);
            let before = listed.clone();
            assert!(a_scanned.step(&mut scanned, &g, &lr, Update::Dense(None)).is_none());
            assert!(a_listed.step(&mut listed, &g, &lr, Update::Dense(Some(rows))).is_none());
            assert_eq!((&scanned, &a_scanned), (&listed, &a_listed), "step {step}");
            // The middle runs were never reached: untouched; the first keeps moving.
            assert_eq!(
                listed.gaussians.sh[2048 * 12..2 * 2048 * 12],
                before.gaussians.sh[2048 * 12..2 * 2048 * 12]
            );
            if step > 0 {
                assert_ne!(listed.gaussians.means[0], before.gaussians.means[0], "step {step}");
            }
        }
    }

    #[test]
    fn exponential_position_schedule() {
        assert!((expon_lr(0, 1.6e-4, 1.6e-6, 100) - 1.6e-4).abs() < 1e-10);
        assert!((expon_lr(100, 1.6e-4, 1.6e-6, 100) - 1.6e-6).abs() < 1e-12);
        assert!((expon_lr(50, 1.6e-4, 1.6e-6, 100) - 1.6e-5).abs() < 1e-10);
        assert!((expon_lr(500, 1.6e-4, 1.6e-6, 100) - 1.6e-6).abs() < 1e-12);
        assert_eq!(expon_lr(5, 0.0, 0.0, 100), 0.0);
        let lr = LearningRates::default().at(0, 100, 2.0);
        assert!((lr[0] - 3.2e-4).abs() < 1e-9);
        assert!((lr[Group::ShRest.index()] - 1.25e-4).abs() < 1e-10);
    }
}
