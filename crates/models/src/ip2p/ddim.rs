//! The DDIM sampler (diffusers `DDIMScheduler`, η = 0) as Instruct-NeRF2NeRF and
//! Instruct-GS2GS drive it: a start timestep T is drawn, the 1000-step noise schedule is
//! kept, and the `steps` inference timesteps are spread over [0, T) with "leading"
//! spacing (diffusers' `set_timesteps` after `num_train_timesteps` is replaced by T).
//!
//! The config is read from the pipeline's `scheduler/scheduler_config.json` with
//! `DDIMScheduler`'s own defaults for absent keys (what `DDIMScheduler.from_config`
//! does); without that file the Stable Diffusion 1.x values are used.

use candle_core::Tensor;
use serde::Deserialize;

use crate::check::{self, ModelConfig};

fn beta_start() -> f64 {
    0.0001
}
fn beta_end() -> f64 {
    0.02
}
fn linear() -> String {
    "linear".into()
}
fn thousand() -> usize {
    1000
}
fn f_true() -> bool {
    true
}
fn epsilon() -> String {
    "epsilon".into()
}
fn leading() -> String {
    "leading".into()
}
fn one() -> f64 {
    1.0
}

/// The `DDIMScheduler` settings read from a scheduler config (defaults are diffusers').
#[derive(Debug, Clone, Deserialize)]
pub struct DdimConfig {
    #[serde(default = "beta_start")]
    pub beta_start: f64,
    #[serde(default = "beta_end")]
    pub beta_end: f64,
    #[serde(default = "linear")]
    pub beta_schedule: String,
    #[serde(default = "thousand")]
    pub num_train_timesteps: usize,
    #[serde(default)]
    pub steps_offset: usize,
    #[serde(default = "f_true")]
    pub set_alpha_to_one: bool,
    #[serde(default = "f_true")]
    pub clip_sample: bool,
    #[serde(default = "one")]
    pub clip_sample_range: f64,
    #[serde(default = "epsilon")]
    pub prediction_type: String,
    #[serde(default = "leading")]
    pub timestep_spacing: String,
    #[serde(default)]
    pub thresholding: bool,
}

impl DdimConfig {
    /// The schedule of Stable Diffusion 1.x and `timbrooks/instruct-pix2pix`.
    pub fn instruct_pix2pix() -> Self {
        Self {
            beta_start: 0.00085,
            beta_end: 0.012,
            beta_schedule: "scaled_linear".into(),
            num_train_timesteps: 1000,
            steps_offset: 1,
            set_alpha_to_one: false,
            clip_sample: false,
            clip_sample_range: 1.0,
            prediction_type: "epsilon".into(),
            timestep_spacing: "leading".into(),
            thresholding: false,
        }
    }
}

/// What the model predicts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Prediction {
    Epsilon,
    V,
}

/// DDIM with η = 0 over a fixed training noise schedule.
#[derive(Debug, Clone)]
pub struct Ddim {
    pub config: DdimConfig,
    alphas_cumprod: Vec<f64>,
    final_alpha_cumprod: f64,
    prediction: Prediction,
}

/// Most training timesteps a scheduler config may declare (SD uses 1000).
const MAX_TIMESTEPS: usize = 100_000;

impl ModelConfig for DdimConfig {
    /// Errors naming the first field that cannot describe a schedule.
    fn check(&self) -> Result<(), String> {
        let n = self.num_train_timesteps;
        if !(2..=MAX_TIMESTEPS).contains(&n) {
            return Err(format!("num_train_timesteps is {n}: must be between 2 and {MAX_TIMESTEPS}"));
        }
        if self.steps_offset >= n {
            return Err(format!("steps_offset {} is not below num_train_timesteps {n}", self.steps_offset));
        }
        for (field, b) in [("beta_start", self.beta_start), ("beta_end", self.beta_end)] {
            if !(b > 0.0 && b < 1.0) {
                return Err(format!("{field} is {b}: must lie in (0, 1)"));
            }
        }
        check::positive("clip_sample_range", self.clip_sample_range)
    }
}

impl Ddim {
    /// The schedule of `config`; errors name unsupported settings.
    pub fn new(config: DdimConfig) -> Result<Self, String> {
        config.check()?;
        let n = config.num_train_timesteps;
        let betas: Vec<f64> = match config.beta_schedule.as_str() {
            "linear" => (0..n)
                .map(|i| {
                    config.beta_start + (config.beta_end - config.beta_start) * i as f64 / (n - 1) as f64
                })
                .collect(),
            "scaled_linear" => {
                let (a, b) = (config.beta_start.sqrt(), config.beta_end.sqrt());
                (0..n).map(|i| (a + (b - a) * i as f64 / (n - 1) as f64).powi(2)).collect()
            }
            other => return Err(format!("beta_schedule {other:?} is not supported")),
        };
        let prediction = match config.prediction_type.as_str() {
            "epsilon" => Prediction::Epsilon,
            "v_prediction" => Prediction::V,
            other => return Err(format!("prediction_type {other:?} is not supported")),
        };
        if config.timestep_spacing != "leading" {
            return Err(format!(
                "timestep_spacing {:?} is not supported (only \"leading\")",
                config.timestep_spacing
            ));
        }
        if config.thresholding {
            return Err("thresholding is not supported".into());
        }
        let mut alphas_cumprod = Vec::with_capacity(n);
        let mut acc = 1.0;
        for b in betas {
            acc *= 1.0 - b;
            alphas_cumprod.push(acc);
        }
        let final_alpha_cumprod = if config.set_alpha_to_one { 1.0 } else { alphas_cumprod[0] };
        Ok(Self { config, alphas_cumprod, final_alpha_cumprod, prediction })
    }

    /// Number of training timesteps (the largest valid start span).
    pub fn train_steps(&self) -> usize {
        self.alphas_cumprod.len()
    }

    /// Inference timesteps, descending: `steps` "leading" steps over a span of `span`
    /// training timesteps, `i · ⌊span/steps⌋ + steps_offset` for i = steps−1 … 0.
    pub fn timesteps(&self, span: usize, steps: usize) -> Result<Vec<usize>, String> {
        if steps == 0 || span < steps || span > self.train_steps() {
            return Err(format!(
                "DDIM: {steps} steps over a span of {span} timesteps (needs 1 <= steps <= span <= {})",
                self.train_steps()
            ));
        }
        let ratio = span / steps;
        let ts: Vec<usize> = (0..steps).rev().map(|i| i * ratio + self.config.steps_offset).collect();
        if ts[0] >= self.train_steps() {
            return Err(format!("DDIM: timestep {} is past the schedule", ts[0]));
        }
        Ok(ts)
    }

    /// ᾱ_t.
    pub fn alpha_bar(&self, t: usize) -> f64 {
        self.alphas_cumprod[t.min(self.alphas_cumprod.len() - 1)]
    }

    /// Forward diffusion: √ᾱ_t x + √(1 − ᾱ_t) ε.
    pub fn add_noise(&self, x: &Tensor, noise: &Tensor, t: usize) -> candle_core::Result<Tensor> {
        let a = self.alpha_bar(t);
        (x * a.sqrt())? + (noise * (1.0 - a).sqrt())?
    }

    /// One DDIM step (η = 0) from timestep `t` to `t − ratio` given the model output,
    /// where `ratio` = ⌊span/steps⌋ of the schedule from [`Ddim::timesteps`].
    pub fn step(
        &self,
        model_output: &Tensor,
        t: usize,
        ratio: usize,
        x: &Tensor,
    ) -> candle_core::Result<Tensor> {
        let a_t = self.alpha_bar(t);
        let a_prev = if t >= ratio { self.alpha_bar(t - ratio) } else { self.final_alpha_cumprod };
        let b_t = 1.0 - a_t;
        let (mut x0, eps) = match self.prediction {
            Prediction::Epsilon => {
                (((x - (model_output * b_t.sqrt())?)? / a_t.sqrt())?, model_output.clone())
            }
            Prediction::V => (
                ((x * a_t.sqrt())? - (model_output * b_t.sqrt())?)?,
                ((model_output * a_t.sqrt())? + (x * b_t.sqrt())?)?,
            ),
        };
        if self.config.clip_sample {
            // Only x0 is clipped: diffusers keeps the model's ε (use_clipped_model_output false).
            let r = self.config.clip_sample_range;
            x0 = x0.clamp(-r, r)?;
        }
        (x0 * a_prev.sqrt())? + (eps * (1.0 - a_prev).sqrt())?
    }
}
