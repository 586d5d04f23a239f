//! Every hyperparameter of an edit in one struct, with the paper's defaults
//! (appendix B: M = 32 prototypes, d = 16 semantic channels, 30 Sinkhorn
//! iterations) except top-k, which is dense by default (measured: see
//! `TransportConfig::top_k`), overridable from a TOML file and command-line flags.

use crate::prototypes::PrototypeConfig;
use crate::view::TransportConfig;
use serde::{Deserialize, Serialize};
use std::path::Path;
use transsplat_raster::ClampGrad;

/// Which method runs in the edit loop: the full method or a baseline / ablation.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Method {
    /// The full TransSplat method (this tool's default formulation: evidence-mass
    /// balancing, visibility agreement, the colour gate).
    Transsplat,
    /// TransSplat as the paper writes it: Σ b = 1, the residual ω-weighted over the
    /// supported views, L_leak as the only suppression (docs/method.md#m6-residual-and-gate).
    Paper,
    /// Image loss only, every Gaussian free (Instruct-GS2GS / IN2N style).
    Naive,
    /// GaussianEditor style: the 2D mask lifted by splat-back and a threshold;
    /// gradients masked outside; no transport.
    Masklift,
    /// TransSplat without leakage suppression (λ_leak = 0, no gated densification).
    NoLeaksup,
    /// Pixel-level transport on a subsample of the support pixels (no prototypes).
    NoPrototype,
    /// Geometric cost only (λ_sem = λ_app = 0).
    Geometric,
}

impl Method {
    /// All methods, in report order.
    pub const ALL: [Method; 7] = [
        Method::Transsplat,
        Method::Paper,
        Method::Naive,
        Method::Masklift,
        Method::NoLeaksup,
        Method::NoPrototype,
        Method::Geometric,
    ];

    /// The name used in files and flags.
    pub fn name(self) -> &'static str {
        match self {
            Method::Transsplat => "transsplat",
            Method::Paper => "paper",
            Method::Naive => "naive",
            Method::Masklift => "masklift",
            Method::NoLeaksup => "no_leaksup",
            Method::NoPrototype => "no_prototype",
            Method::Geometric => "geometric",
        }
    }

    /// Parses a method name.
    pub fn parse(s: &str) -> Option<Method> {
        Method::ALL.into_iter().find(|m| m.name() == s)
    }
    /// The settings this method implies (an ablation zeroes some weights).
    pub fn implied(self, cfg: &mut EditConfig) {
        match self {
            Method::NoLeaksup => {
                cfg.loss.leak = 0.0;
                cfg.loss.colour_gate = 0.0;
            }
            Method::Paper => {
                cfg.transport.evidence_mass = false;
                cfg.fusion.agreement = crate::gate::Agreement::Transport;
                cfg.fusion.coverage = false;
                cfg.fusion.view_weight = crate::gate::ViewWeight::Mass;
                cfg.loss.colour_gate = 0.0;
                cfg.semantic_init = SemanticInit::Source;
                cfg.prototypes.close_radius = 0.0;
                cfg.prototypes.outside_mask = 0.0;
                cfg.prototypes.normalise = crate::prototypes::Normalise::View;
                // The colour lift is an initialisation of the optimisation, not part of
                // the formulation: `paper` keeps it, so the row compares formulations
                // (docs/method.md M9).
            }
            Method::Geometric => {
                cfg.transport.lambda_sem = 0.0;
                cfg.transport.lambda_app = 0.0;
            }
            _ => {}
        }
    }
}

/// What the semantic latents s_i start from (docs/method.md#m8-semantic-space): the
/// semantic features of the edit views, projected and lifted onto the Gaussians.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SemanticInit {
    /// The edited images' features (the source render's where the editor gave
    /// nothing): the space the prototypes' e_m are taken from.
    #[default]
    Edited,
    /// The source renders' features (the paper leaves this open; `paper` keeps it).
    Source,
}

/// Canonical fusion settings (Theorem 1 and the EMA across rounds).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct FusionConfig {
    /// ρ: anchor to the current latent.
    pub rho: f32,
    /// μ: EMA factor across transport rounds.
    pub ema: f32,
    /// A view supports Gaussian i when w_i > min_support · a_i.
    pub min_support: f32,
    /// τ_r: gate temperature on the relative residual.
    pub tau_r: f32,
    /// How per-view residuals are combined across views ([`crate::gate::Agreement`]).
    pub agreement: crate::gate::Agreement,
    /// A view's support of a Gaussian is bounded by how much of its footprint lies in
    /// the view's evidence: min(σ, ω) ([`crate::view::ViewTransport::view_support`]); off:
    /// the plan's relative support σ alone.
    pub coverage: bool,
    /// How much say each view has in the visibility agreement
    /// ([`crate::gate::ViewWeight`]).
    pub view_weight: crate::gate::ViewWeight,
}

impl Default for FusionConfig {
    fn default() -> Self {
        FusionConfig {
            rho: 0.1,
            ema: 0.5,
            min_support: 1e-3,
            tau_r: 0.25,
            agreement: Default::default(),
            coverage: true,
            view_weight: Default::default(),
        }
    }
}

/// Loss weights.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LossConfig {
    /// λ_img on the photometric loss.
    pub img: f32,
    /// Weight of D-SSIM inside L_img (0 = pure L1).
    pub dssim: f32,
    /// λ_sem.
    pub sem: f32,
    /// λ_uot.
    pub uot: f32,
    /// λ_leak.
    pub leak: f32,
    /// The image loss's colour gradients are kept only where the aggregated support
    /// 1 − r_i is at least this (the gated region, TransSplat's colour mask; 0.5: a
    /// majority of the views that see the Gaussian, by `fusion.view_weight`), and L_leak acts
    /// only outside it ([`EditConfig::colour_gate_gamma`]); 0 = off (the paper).
    pub colour_gate: f32,
}

impl Default for LossConfig {
    fn default() -> Self {
        LossConfig { img: 1.0, dssim: 0.0, sem: 1.0, uot: 0.1, leak: 0.1, colour_gate: 0.5 }
    }
}

/// The edit loop's schedule (EditSplat / Instruct-GS2GS style;
/// docs/method.md#m9-the-edit-loop): the views are edited once.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ScheduleConfig {
    /// Optimisation steps (one view per step).
    pub steps: usize,
    /// A transport round every this many steps.
    pub transport_every: usize,
    /// Densify (within the gated region) every this many steps (0 = never).
    pub densify_every: usize,
    /// Gaussians with γ ≥ this may be densified.
    pub densify_gate: f32,
    /// With frozen geometry and a colour mask, a step renders only the colour change
    /// of the Gaussians that can change (`delta`): the same edit up to float
    /// rounding, in a fraction of the time. Off: every step renders in full.
    pub delta_render: bool,
    /// Before the first step, move the colour of every Gaussian the method lets
    /// change by the blend-weighted mean of the edited views' residuals over the
    /// pixels it blends (docs/method.md#m9-the-edit-loop); every method has it.
    pub colour_lift: bool,
}

impl Default for ScheduleConfig {
    fn default() -> Self {
        ScheduleConfig {
            steps: 600,
            transport_every: 150,
            densify_every: 0,
            densify_gate: 0.5,
            delta_render: true,
            colour_lift: true,
        }
    }
}

/// Learning rates of the edit stage (mostly colour).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LearningRates {
    pub position: f32,
    pub sh_dc: f32,
    pub sh_rest: f32,
    pub opacity: f32,
    pub scale: f32,
    pub rotation: f32,
    pub semantic: f32,
}

impl Default for LearningRates {
    fn default() -> Self {
        LearningRates {
            position: 0.0,
            sh_dc: 0.025,
            sh_rest: 0.0005,
            opacity: 0.0,
            scale: 0.0,
            rotation: 0.0,
            semantic: 0.01,
        }
    }
}

/// Every setting of an edit.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct EditConfig {
    pub method: Method,
    /// Semantic latent size d.
    pub semantic_dim: usize,
    /// What the semantic latents start from (docs/method.md#m8-semantic-space).
    pub semantic_init: SemanticInit,
    pub prototypes: PrototypeConfig,
    pub transport: TransportConfig,
    pub fusion: FusionConfig,
    pub loss: LossConfig,
    pub schedule: ScheduleConfig,
    pub lr: LearningRates,
    /// Pixels sampled per view by the `no_prototype` ablation.
    pub pixel_samples: usize,
    /// masklift: splat-back mask threshold.
    pub masklift_threshold: f32,
    /// How the colour clamp at 0 passes the image loss's gradients to the SH
    /// coefficients (docs/method.md#m11-colour-clamp): `revive` (default) lets a
    /// channel below 0 rise, so a dark colour of a scene trained elsewhere can be
    /// edited; `exact` is the clamp's derivative.
    pub clamp_grad: ClampGrad,
    pub seed: u64,
}

impl Default for EditConfig {
    fn default() -> Self {
        EditConfig {
            method: Method::Transsplat,
            semantic_dim: 16,
            semantic_init: SemanticInit::default(),
            prototypes: PrototypeConfig::default(),
            transport: TransportConfig::default(),
            fusion: FusionConfig::default(),
            loss: LossConfig::default(),
            schedule: ScheduleConfig::default(),
            lr: LearningRates::default(),
            pixel_samples: 256,
            masklift_threshold: 0.5,
            clamp_grad: ClampGrad::Revive,
            seed: 0,
        }
    }
}

impl EditConfig {
    /// The gate value at which the colour gate opens: support 1 − r ≥ `loss.colour_gate`
    /// is γ = exp(−r / τ_r) ≥ exp(−(1 − colour_gate) / τ_r); `None` when the colour
    /// gate is off.
    pub fn colour_gate_gamma(&self) -> Option<f32> {
        let c = self.loss.colour_gate;
        (c > 0.0).then(|| (-(1.0 - c) / self.fusion.tau_r).exp())
    }

    /// Reads a TOML file of overrides (unknown keys are errors naming the file).
    pub fn from_toml_file(path: &Path) -> Result<Self, String> {
        let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
        Self::from_toml(&text).map_err(|e| format!("{}: {e}", path.display()))
    }

    /// Parses TOML overrides on top of the defaults and validates them.
    pub fn from_toml(text: &str) -> Result<Self, String> {
        let c: EditConfig = toml::from_str(text).map_err(|e| one_line(&e, text))?;
        c.validate()?;
        Ok(c)
    }

    /// Applies `key.path=value` overrides (command-line `--set`), e.g.
    /// `transport.top_k=128` or `loss.leak=0.2`; values are TOML (`true`, `1.5`,
    /// `"transsplat"`), bare words are taken as strings. Unknown keys are errors.
    pub fn with_overrides(&self, sets: &[String]) -> Result<Self, String> {
        let mut root: toml::Value = toml::Value::try_from(self).map_err(|e| e.to_string())?;
        for set in sets {
            let (key, value) = set
                .split_once('=')
                .ok_or_else(|| format!("--set {set:?}: expected KEY=VALUE, e.g. loss.leak=0.2"))?;
            let value: toml::Value = toml::from_str::<toml::Table>(&format!("v = {}", value.trim()))
                .ok()
                .and_then(|mut t| t.remove("v"))
                .unwrap_or_else(|| toml::Value::String(value.trim().to_string()));
            let mut node = &mut root;
            let parts: Vec<&str> = key.trim().split('.').collect();
            for (k, part) in parts.iter().enumerate() {
                let table =
                    node.as_table_mut().ok_or_else(|| format!("--set {set:?}: {part:?} is not a section"))?;
                if !table.contains_key(*part) {
                    return Err(format!("--set {set:?}: unknown setting {key:?}"));
                }
                if k + 1 == parts.len() {
                    table.insert(part.to_string(), value.clone());
                    break;
                }
                node = table.get_mut(*part).expect("checked above");
            }
        }
        let c: EditConfig = root.try_into().map_err(|e: toml::de::Error| one_line(&e, ""))?;
        c.validate()?;
        Ok(c)
    }

    /// The settings as TOML (for reports and for `--config` round trips).
    pub fn to_toml(&self) -> String {
        toml::to_string_pretty(self).expect("config serialises")
    }

    /// The settings of one edit as every front assembles them: `self` (defaults or a
    /// file), then the method by name (its implied settings), the `key=value` overrides
    /// and the step count, checked.
    pub fn assemble(
        &self,
        method: Option<&str>,
        sets: &[String],
        steps: Option<usize>,
    ) -> Result<Self, String> {
        let mut c = match method {
            Some(m) => self.for_method(Method::parse(m).ok_or_else(|| {
                let names: Vec<&str> = Method::ALL.iter().map(|m| m.name()).collect();
                format!("unknown method {m:?}; expected one of {}", names.join(", "))
            })?),
            None => self.clone(),
        };
        c = c.with_overrides(sets)?;
        if let Some(s) = steps {
            c.schedule.steps = s;
        }
        c.validate()?;
        Ok(c)
    }

    /// Applies this config's method to the settings it implies (ablations).
    pub fn for_method(&self, method: Method) -> Self {
        let mut c = self.clone();
        c.method = method;
        method.implied(&mut c);
        c
    }

    /// Checks ranges; the message names the offending key.
    pub fn validate(&self) -> Result<(), String> {
        let t = &self.transport;
        let checks: [(&str, bool); 15] = [
            ("semantic_dim", self.semantic_dim > 0 && self.semantic_dim <= 256),
            ("prototypes.count", self.prototypes.count > 0),
            ("prototypes.threshold", (0.0..=1.0).contains(&self.prototypes.threshold)),
            ("prototypes.close_radius", (0.0..=0.1).contains(&self.prototypes.close_radius)),
            ("prototypes.outside_mask", (0.0..=1.0).contains(&self.prototypes.outside_mask)),
            ("transport.eps", t.eps.is_finite() && t.eps > 0.0),
            ("transport.tau_s", t.tau_s > 0.0),
            ("transport.tau_t", t.tau_t > 0.0),
            ("transport.iters", t.iters > 0),
            ("fusion.rho", self.fusion.rho >= 0.0),
            ("fusion.ema", (0.0..1.0).contains(&self.fusion.ema)),
            ("fusion.tau_r", self.fusion.tau_r > 0.0),
            ("loss.colour_gate", (0.0..=1.0).contains(&self.loss.colour_gate)),
            ("schedule.steps", self.schedule.steps > 0),
            ("schedule.transport_every", self.schedule.transport_every > 0),
        ];
        for (k, ok) in checks {
            if !ok {
                return Err(format!("config value {k} is out of range"));
            }
        }
        let (l, lr) = (&self.loss, &self.lr);
        let non_negative = [
            ("transport.lambda_geo", t.lambda_geo),
            ("transport.lambda_sem", t.lambda_sem),
            ("transport.lambda_app", t.lambda_app),
            ("transport.delta", t.delta),
            ("prototypes.min_area_fraction", self.prototypes.min_area_fraction),
            ("fusion.min_support", self.fusion.min_support),
            ("loss.img", l.img),
            ("loss.dssim", l.dssim),
            ("loss.sem", l.sem),
            ("loss.uot", l.uot),
            ("loss.leak", l.leak),
            ("schedule.densify_gate", self.schedule.densify_gate),
            ("lr.position", lr.position),
            ("lr.sh_dc", lr.sh_dc),
            ("lr.sh_rest", lr.sh_rest),
            ("lr.opacity", lr.opacity),
            ("lr.scale", lr.scale),
            ("lr.rotation", lr.rotation),
            ("lr.semantic", lr.semantic),
            ("masklift_threshold", self.masklift_threshold),
        ];
        for (k, v) in non_negative {
            if !(v.is_finite() && v >= 0.0) {
                return Err(format!("config value {k} must be finite and >= 0, got {v}"));
            }
        }
        Ok(())
    }
}

/// A TOML error as one line, `line L, column C: message` (the TOML crate's own text
/// spans several lines with a source excerpt, which does not fit a CLI error line).
fn one_line(e: &toml::de::Error, text: &str) -> String {
    let msg = e.message().split_whitespace().collect::<Vec<_>>().join(" ");
    match e.span().filter(|s| s.start <= text.len() && text.is_char_boundary(s.start)) {
        Some(span) if !text.is_empty() => {
            let before = &text[..span.start];
            let line = before.matches('\n').count() + 1;
            let column = before.rsplit('\n').next().map_or(0, |l| l.chars().count()) + 1;
            format!("TOML error at line {line}, column {column}: {msg}")
        }
        _ => format!("TOML error: {msg}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paper_defaults_and_toml_overrides() {
        let c = EditConfig::default();
        assert_eq!(
            (c.prototypes.count, c.semantic_dim, c.transport.iters, c.transport.top_k),
            (32, 16, 30, 0)
        );
        let c = EditConfig::from_toml("[transport]\ntop_k = 128\neps = 0.1\n[loss]\nleak = 2.0\n").unwrap();
        assert_eq!(c.transport.top_k, 128);
        assert_eq!(c.loss.leak, 2.0);
        assert_eq!(c.prototypes.count, 32);
        let back = EditConfig::from_toml(&c.to_toml()).unwrap();
        assert_eq!(back, c);
        assert!(EditConfig::from_toml("[transport]\nepsilon = 1\n").unwrap_err().contains("epsilon"));
        assert!(EditConfig::from_toml("[transport]\neps = -1.0\n").unwrap_err().contains("transport.eps"));
        assert_eq!(Method::parse("no_prototype"), Some(Method::NoPrototype));
        assert_eq!(c.for_method(Method::Geometric).transport.lambda_sem, 0.0);
        let o = c
            .with_overrides(&["transport.top_k=64".into(), "loss.leak = 0.5".into(), "method=naive".into()])
            .unwrap();
        assert_eq!((o.transport.top_k, o.loss.leak, o.method), (64, 0.5, Method::Naive));
        assert!(c.with_overrides(&["transport.nope=1".into()]).unwrap_err().contains("unknown setting"));
        assert!(c.with_overrides(&["fusion.tau_r=-1".into()]).unwrap_err().contains("fusion.tau_r"));
        assert!(c.with_overrides(&["leak".into()]).unwrap_err().contains("KEY=VALUE"));
        // The attention's normalisation: each view's own peak above the floor unless asked,
        // the paper's own peak always in `paper`.
        use crate::prototypes::Normalise;
        assert_eq!(c.prototypes.normalise, Normalise::Floor);
        assert_eq!(c.for_method(Method::Paper).prototypes.normalise, Normalise::View);
        let job = c.with_overrides(&["prototypes.normalise=job".into()]).unwrap();
        assert_eq!(job.prototypes.normalise, Normalise::Job);
        assert_eq!(job.for_method(Method::Paper).prototypes.normalise, Normalise::View);
        let view = c.with_overrides(&["prototypes.normalise=view".into()]).unwrap();
        assert_eq!(view.prototypes.normalise, Normalise::View);
        let floor = view.with_overrides(&["prototypes.normalise=floor".into()]).unwrap();
        assert_eq!(floor.prototypes.normalise, Normalise::Floor);
        assert!(c.with_overrides(&["prototypes.normalise=scene".into()]).is_err());
    }

    /// TOML errors are one line with the position (the CLI prints one error line).
    #[test]
    fn toml_errors_are_one_line_with_the_position() {
        for (text, want) in [
            ("[transport]\nepsilon = 1\n", "line 2, column 1: unknown field `epsilon`"),
            ("[transport\neps = 1\n", "line 1, column 11: invalid table header"),
            ("seed = -1\n", "line 1, column 8:"),
        ] {
            let e = EditConfig::from_toml(text).unwrap_err();
            assert!(!e.contains('\n') && e.contains(want), "{text:?}: {e}");
        }
        let e = EditConfig::default().with_overrides(&["seed=\"x\"".into()]).unwrap_err();
        assert!(!e.contains('\n') && e.contains("TOML error"), "{e}");
    }

    /// NaN, infinite or negative weights were accepted (and a NaN config did not
    /// survive a TOML round trip, found by the `edit_config` fuzz target's invariant).
    #[test]
    fn non_finite_and_negative_weights_are_refused_by_name() {
        for (toml, key) in [
            ("[loss]\nleak = nan\n", "loss.leak"),
            ("[lr]\nsh_dc = inf\n", "lr.sh_dc"),
            ("[loss]\nimg = -1.0\n", "loss.img"),
            ("masklift_threshold = nan\n", "masklift_threshold"),
            ("[transport]\ndelta = -inf\n", "transport.delta"),
            ("[fusion]\nmin_support = nan\n", "fusion.min_support"),
        ] {
            let e = EditConfig::from_toml(toml).unwrap_err();
            assert!(e.contains(key), "{toml:?}: {e}");
        }
        // tau = inf (a hard marginal) stays allowed and round-trips.
        let c = EditConfig::from_toml("[transport]\ntau_s = inf\n").unwrap();
        assert_eq!(EditConfig::from_toml(&c.to_toml()).unwrap(), c);
    }
}
