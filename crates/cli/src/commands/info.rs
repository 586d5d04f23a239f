//! `transsplat info`: a summary of a scene file.

use super::common::{load_scene, SceneArgs};
use anyhow::Result;
use transsplat_scene::{sigmoid, Gaussians};

/// Arguments of `transsplat info`.
#[derive(clap::Args, Debug)]
pub struct InfoArgs {
    /// Scene: an INRIA 3DGS PLY, or an INRIA output folder.
    pub path: std::path::PathBuf,
    /// Drop Gaussians with NaN or infinite parameters instead of refusing the file.
    #[arg(long)]
    pub drop_invalid: bool,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
}

/// Order statistics of a sample.
fn summary(mut v: Vec<f32>) -> serde_json::Value {
    v.sort_by(|a, b| a.total_cmp(b));
    let q = |p: f64| v[((v.len() - 1) as f64 * p).round() as usize];
    let mean = v.iter().map(|&x| x as f64).sum::<f64>() / v.len() as f64;
    serde_json::json!({"min": q(0.0), "p01": q(0.01), "median": q(0.5), "p99": q(0.99), "max": q(1.0), "mean": mean})
}

/// The `info` report of a scene as JSON.
pub fn report(g: &Gaussians) -> serde_json::Value {
    let axis = |k: usize| summary(g.means.iter().map(|m| m[k]).collect());
    serde_json::json!({
        "gaussians": g.len(),
        "sh_degree": g.sh_degree,
        "extra_properties": g.extra.names,
        "position": {"x": axis(0), "y": axis(1), "z": axis(2)},
        "opacity": summary(g.opacity_logits.iter().map(|&o| sigmoid(o)).collect()),
        "scale": summary(g.log_scales.iter().flat_map(|s| s.map(f32::exp)).collect()),
        "max_scale": summary(g.log_scales.iter().map(|s| s.iter().fold(f32::MIN, |a, &b| a.max(b)).exp()).collect()),
    })
}

/// Runs `transsplat info`.
pub fn run(args: &InfoArgs) -> Result<()> {
    let (g, path) = load_scene(&SceneArgs { scene: args.path.clone(), drop_invalid: args.drop_invalid })?;
    let r = report(&g);
    if args.json {
        println!("{r}");
        return Ok(());
    }
    let f = |v: &serde_json::Value, k: &str| v[k].as_f64().unwrap_or(f64::NAN);
    println!("file         {}", path.display());
    println!("gaussians    {}", g.len());
    println!("sh degree    {}", g.sh_degree);
    if !g.extra.names.is_empty() {
        println!("extra        {}", g.extra.names.join(" "));
    }
    println!("bounding box (min .. max; 1st .. 99th percentile)");
    for k in ["x", "y", "z"] {
        let a = &r["position"][k];
        println!(
            "  {k}  {:>12.4} .. {:<12.4} ({:.4} .. {:.4})",
            f(a, "min"),
            f(a, "max"),
            f(a, "p01"),
            f(a, "p99")
        );
    }
    for (name, key) in [("opacity", "opacity"), ("scale", "scale"), ("max scale", "max_scale")] {
        let a = &r[key];
        println!(
            "{name:<12} min {:.4e}  median {:.4e}  mean {:.4e}  p99 {:.4e}  max {:.4e}",
            f(a, "min"),
            f(a, "median"),
            f(a, "mean"),
            f(a, "p99"),
            f(a, "max")
        );
    }
    Ok(())
}
