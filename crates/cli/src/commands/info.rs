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

/// Keys of a summary, in the order of [`stats`].
const KEYS: [&str; 6] = ["min", "p01", "median", "p99", "max", "mean"];

/// Order statistics (min, 1st percentile, median, 99th percentile, max) of a sample,
/// in f64, then `mean(sorted sample)`.
fn stats(mut v: Vec<f32>, mean: fn(&[f32]) -> f64) -> [f64; 6] {
    v.sort_by(|a, b| a.total_cmp(b));
    let q = |p: f64| v[((v.len() - 1) as f64 * p).round() as usize] as f64;
    [q(0.0), q(0.01), q(0.5), q(0.99), q(1.0), mean(&v)]
}

/// The arithmetic mean, summed in f64 (no f32 sum can overflow it).
fn mean(v: &[f32]) -> f64 {
    v.iter().map(|&x| x as f64).sum::<f64>() / v.len() as f64
}

/// `ln(mean(exp(v)))` without overflow: the largest value is factored out, so every
/// term is at most 1 and the result is finite for finite `v`.
fn log_mean_exp(v: &[f32]) -> f64 {
    let m = v.iter().fold(f64::NEG_INFINITY, |a, &x| a.max(x as f64));
    let s: f64 = v.iter().map(|&x| (x as f64 - m).exp()).sum();
    m + (s / v.len() as f64).ln()
}

fn to_json(s: [f64; 6]) -> serde_json::Value {
    KEYS.iter().zip(s).map(|(k, v)| (k.to_string(), serde_json::json!(v))).collect()
}

/// Statistics of the scales `exp(log_scale)` in the log domain: each entry is the
/// natural log of the statistic of the scales (exp is increasing, so the order
/// statistics are those of the log-scales; the mean is [`log_mean_exp`]). Over every
/// axis, or over each Gaussian's largest axis.
fn ln_scale_stats(g: &Gaussians, largest_axis: bool) -> [f64; 6] {
    let v = if largest_axis {
        g.log_scales.iter().map(|s| s.iter().fold(f32::MIN, |a, &b| a.max(b))).collect()
    } else {
        g.log_scales.iter().flatten().copied().collect()
    };
    stats(v, log_mean_exp)
}

/// The `info` report of a scene as JSON. Statistics are computed in f64, those of the
/// scales in the log domain, so finite parameters give finite statistics: `scale` and
/// `max_scale` are null only where the value itself is beyond f64 (a log-scale over
/// 709.78); `log_scale` and `max_log_scale` (the stored log-scales, mean of the logs)
/// are always finite.
pub fn report(g: &Gaussians) -> serde_json::Value {
    let axis = |k: usize| to_json(stats(g.means.iter().map(|m| m[k]).collect(), mean));
    let largest = |s: &[f32; 3]| s.iter().fold(f32::MIN, |a, &b| a.max(b));
    serde_json::json!({
        "gaussians": g.len(),
        "sh_degree": g.sh_degree,
        "extra_properties": g.extra.names,
        "position": {"x": axis(0), "y": axis(1), "z": axis(2)},
        "opacity": to_json(stats(g.opacity_logits.iter().map(|&o| sigmoid(o)).collect(), mean)),
        "scale": to_json(ln_scale_stats(g, false).map(f64::exp)),
        "max_scale": to_json(ln_scale_stats(g, true).map(f64::exp)),
        "log_scale": to_json(stats(g.log_scales.iter().flatten().copied().collect(), mean)),
        "max_log_scale": to_json(stats(g.log_scales.iter().map(largest).collect(), mean)),
    })
}

/// `exp(ln)` written as `{:.4e}` would write it, also where it is beyond f64 (or
/// below its normal range): then from the decimal logarithm, e.g. `1.9700e434`.
fn fmt_exp(ln: f64) -> String {
    let v = ln.exp();
    if v.is_normal() || !ln.is_finite() {
        return format!("{v:.4e}");
    }
    let l10 = ln / std::f64::consts::LN_10;
    let mut e = l10.floor();
    let mut m = 10f64.powf(l10 - e);
    if format!("{m:.4}").starts_with("10") {
        m /= 10.0;
        e += 1.0;
    }
    format!("{m:.4}e{}", e as i128)
}

/// Runs `transsplat info`.
pub fn run(args: &InfoArgs) -> Result<()> {
    let (g, path) = load_scene(&SceneArgs {
        scene: args.path.clone(),
        drop_invalid: args.drop_invalid,
        spz_axes: Default::default(),
    })?;
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
    let rows = [
        ("opacity", KEYS.map(|k| format!("{:.4e}", f(&r["opacity"], k)))),
        ("scale", ln_scale_stats(&g, false).map(fmt_exp)),
        ("max scale", ln_scale_stats(&g, true).map(fmt_exp)),
    ];
    for (name, [min, _, median, p99, max, mean]) in rows {
        println!("{name:<12} min {min}  median {median}  mean {mean}  p99 {p99}  max {max}");
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scene(log_scales: Vec<[f32; 3]>) -> Gaussians {
        let n = log_scales.len();
        Gaussians {
            sh_degree: 0,
            means: (0..n).map(|i| [i as f32, f32::MAX, -f32::MAX]).collect(),
            log_scales,
            rotations: vec![[1.0, 0.0, 0.0, 0.0]; n],
            opacity_logits: vec![0.0; n],
            sh: vec![0.5; n * 3],
            ..Default::default()
        }
    }

    /// Every number in the report.
    fn numbers(v: &serde_json::Value, out: &mut Vec<(String, Option<f64>)>, at: &str) {
        match v {
            serde_json::Value::Object(m) => m.iter().for_each(|(k, v)| numbers(v, out, &format!("{at}.{k}"))),
            serde_json::Value::Number(n) => out.push((at.to_string(), n.as_f64())),
            serde_json::Value::Null => out.push((at.to_string(), None)),
            _ => {}
        }
    }

    #[test]
    fn large_finite_log_scales_give_finite_statistics() {
        // exp(100) overflows f32 (the report used to say NaN); exp(700) is near the top
        // of f64.
        for ls in [80.0f32, 100.0, 700.0] {
            let g = scene(vec![[ls, ls, ls], [ls, 0.0, -3.0], [0.0; 3]]);
            let r = report(&g);
            let mut all = Vec::new();
            numbers(&r, &mut all, "");
            for (k, v) in &all {
                assert!(v.is_some_and(f64::is_finite), "log-scale {ls}: {k} = {v:?}");
            }
            let mean = r["scale"]["mean"].as_f64().unwrap();
            let want = (4.0 * (ls as f64).exp() + 4.0 + (-3.0f64).exp()) / 9.0;
            assert!((mean / want - 1.0).abs() < 1e-12, "{ls}: {mean} vs {want}");
            assert_eq!(r["max_scale"]["max"].as_f64().unwrap(), (ls as f64).exp());
            assert_eq!(r["max_log_scale"]["min"].as_f64().unwrap(), 0.0);
            // Positions at ±f32::MAX average without overflow.
            assert_eq!(r["position"]["y"]["mean"].as_f64().unwrap(), f32::MAX as f64);
        }
    }

    #[test]
    fn log_scales_beyond_f64_are_written_from_the_log() {
        let g = scene(vec![[1000.0, 1000.0, 1000.0], [-1000.0; 3]]);
        let r = report(&g);
        assert!(r["scale"]["max"].is_null(), "beyond f64 is null in JSON");
        assert_eq!(r["log_scale"]["max"].as_f64(), Some(1000.0));
        assert_eq!(r["log_scale"]["mean"].as_f64(), Some(0.0));
        // e^1000 = 1.9701e434; the mean of six values, three of them e^1000, is half that.
        assert_eq!(fmt_exp(1000.0), "1.9701e434");
        assert_eq!(fmt_exp(log_mean_exp(&[1000.0, 1000.0, 1000.0, -1000.0, -1000.0, -1000.0])), "9.8504e433");
        assert_eq!(fmt_exp(-1000.0), "5.0760e-435");
        // The largest finite log-scale still prints a number (its mantissa is rounding).
        let top = fmt_exp(f32::MAX as f64);
        assert!(top.contains("e14778274") && !top.contains("inf") && !top.contains("NaN"), "{top}");
        // Where f64 holds the value the text is {:.4e}'s.
        for ln in [0.0, 1.0, -2.5, 80.0, 700.0, 709.0] {
            assert_eq!(fmt_exp(ln), format!("{:.4e}", ln.exp()));
        }
        assert_eq!(fmt_exp(f64::NEG_INFINITY), "0.0000e0");
    }
}
