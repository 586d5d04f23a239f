//! `transsplat demo`: the built-in benchmark with ground truth (no weights, no inputs).

use super::common::progress;
use anyhow::Result;
use std::path::PathBuf;
use std::sync::atomic::AtomicBool;
use transsplat_bench::demo::{self, DemoOptions};
use transsplat_edit::EditConfig;
use transsplat_edit::Method;
use transsplat_edit::Progress;

/// Arguments of `transsplat demo`.
#[derive(clap::Args, Debug)]
pub struct DemoArgs {
    /// Output folder (replaced if it holds an earlier demo's output).
    #[arg(long, default_value = "demo")]
    pub out: PathBuf,
    /// Small scene and few steps (about a minute).
    #[arg(long)]
    pub quick: bool,
    /// Built-in scene: tabletop, occluded or garden.
    #[arg(long, default_value = "tabletop")]
    pub scene: String,
    /// Instruction for the simulated editor.
    #[arg(long, default_value = "make the ball blue")]
    pub prompt: String,
    /// Severity of the simulated editor's failures (0 = perfect edits).
    #[arg(long, value_parser = super::common::finite_f32, default_value_t = 1.0)]
    pub severity: f32,
    /// Methods to run (comma-separated): transsplat, paper, naive, masklift, no_leaksup, no_prototype, geometric.
    #[arg(long, value_delimiter = ',')]
    pub methods: Option<Vec<String>>,
    /// TOML file of edit settings (see `EditConfig`).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Override any edit setting, e.g. `--set transport.top_k=128`.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Train the scene from its own renders for N steps first and edit the trained scene
    /// (what users bring: a scene trained from photos); scored against the same truth.
    #[arg(long, value_name = "N", default_value_t = 0)]
    pub trained: u64,
    /// With --trained: also train a scene the same way from the true edit's renders and
    /// report its target PSNR (what an edit of the trained scene could reach at best).
    #[arg(long, requires = "trained")]
    pub retrain_truth: bool,
    /// Which training views the simulated editor edits: all, auto, K or 1/N (as `edit
    /// --views`).
    #[arg(long, value_parser = transsplat_session::views::ViewChoice::parse, default_value = "all")]
    pub views: transsplat_session::views::ViewChoice,
    /// Hand the edits masks from the simulated segmenter at this severity (0: the true
    /// target mask; failure modes in crates/builtin/src/segmenter.rs).
    #[arg(long, value_parser = super::common::finite_f32)]
    pub segmenter: Option<f32>,
}

/// The methods named on the command line (all of them when none are).
pub fn parse_methods(names: Option<&[String]>) -> Result<Vec<Method>> {
    match names {
        None => Ok(Method::ALL.to_vec()),
        Some(v) => v
            .iter()
            .map(|s| {
                Method::parse(s.trim()).ok_or_else(|| {
                    let all: Vec<&str> = Method::ALL.iter().map(|m| m.name()).collect();
                    anyhow::anyhow!("unknown method {s:?}; methods are: {}", all.join(", "))
                })
            })
            .collect(),
    }
}

/// Runs `transsplat demo`.
pub fn run(args: &DemoArgs, cancel: &AtomicBool) -> Result<()> {
    let opts = demo_options(args)?;
    let mut bars = MethodBars::default();
    let outcome = demo::run(&opts, Some(cancel), &mut |name, p| bars.show(name, p));
    bars.finish();
    let demo::DemoOutcome { out, scores, .. } = outcome.map_err(|e| match e {
        demo::DemoError::Edit(transsplat_edit::EditError::Interrupted(s)) => {
            anyhow::anyhow!("interrupted at step {s}; nothing was written to {}", args.out.display())
        }
        e => e.into(),
    })?;
    print_scores(&scores);
    println!("wrote {}/metrics.json and {}/report.html", out.display(), out.display());
    Ok(())
}

/// The demo's settings from its flags: the edit settings (`--config`, the quick
/// schedule, then `--set`, so an explicit setting wins) and the case.
fn demo_options(args: &DemoArgs) -> Result<DemoOptions> {
    let mut config = match &args.config {
        Some(p) => EditConfig::from_toml_file(p).map_err(anyhow::Error::msg)?,
        None => EditConfig::default(),
    };
    if args.quick {
        transsplat_bench::demo::quick_schedule(&mut config);
    }
    let config = config.with_overrides(&args.set).map_err(anyhow::Error::msg)?;
    Ok(DemoOptions {
        out: args.out.clone(),
        scene: args.scene.clone(),
        prompt: args.prompt.clone(),
        severity: args.severity,
        quick: args.quick,
        methods: parse_methods(args.methods.as_deref())?,
        config,
        seed: args.seed,
        trained: args.trained,
        retrain_truth: args.retrain_truth,
        views: args.views,
        segmenter: args.segmenter,
    })
}

/// One progress bar per method, each replacing the last when its method starts.
#[derive(Default)]
struct MethodBars {
    current: Option<(String, indicatif::ProgressBar)>,
}

impl MethodBars {
    fn show(&mut self, name: &str, p: Progress) {
        let Progress::Step { step, steps, loss } = p else { return };
        if self.current.as_ref().is_none_or(|(n, _)| n != name) {
            self.finish();
            self.current = Some((name.to_string(), progress(steps as u64, name)));
        }
        if let Some((_, bar)) = &self.current {
            bar.set_position(step as u64);
            if step % 10 == 0 {
                bar.set_message(format!("{name} {loss:.4}"));
            }
        }
    }

    fn finish(&mut self) {
        if let Some((_, bar)) = self.current.take() {
            bar.finish_and_clear();
        }
    }
}

/// The scores table on stdout.
fn print_scores(scores: &[demo::MethodScore]) {
    println!(
        "{:<14} {:>12} {:>16} {:>8} {:>8} {:>11} {:>9}",
        "method", "target PSNR", "background PSNR", "PSNR", "SSIM", "gate AUROC", "seconds"
    );
    for s in scores {
        println!(
            "{:<14} {:>12.3} {:>16.3} {:>8.3} {:>8.4} {:>11} {:>9.1}",
            s.name,
            s.metrics.target_psnr,
            s.metrics.background_psnr,
            s.metrics.psnr,
            s.metrics.ssim,
            s.gate_auroc.map_or("-".into(), |a| format!("{a:.4}")),
            s.seconds
        );
    }
}
