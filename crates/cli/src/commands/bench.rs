//! `transsplat bench raster`: forward, backward and splat-back timings on the
//! reproducible synthetic scene of `transsplat_raster::bench`.

use transsplat_raster::bench;

/// Arguments of `transsplat bench raster`.
#[derive(clap::Args, Debug)]
pub struct RasterArgs {
    /// Gaussian counts to run (comma-separated).
    #[arg(long, value_delimiter = ',', default_value = "100000,1000000")]
    pub gaussians: Vec<usize>,
    /// Image size (square).
    #[arg(long, default_value_t = 512)]
    pub size: u32,
    /// Repetitions per measurement (the best is reported).
    #[arg(long, default_value_t = 3)]
    pub reps: usize,
}

/// Runs `transsplat bench raster` and prints a table and one JSON line per configuration.
pub fn raster(args: &RasterArgs) -> anyhow::Result<()> {
    anyhow::ensure!(args.size > 0, "--size must be positive");
    println!(
        "{:>10} {:>9} {:>10} {:>10} {:>10} {:>10} {:>12} {:>10} {:>9}",
        "gaussians",
        "size",
        "forward s",
        "(binning)",
        "backward s",
        "splat s",
        "Mpairs/s fwd",
        "saturated",
        "traversed"
    );
    for &n in &args.gaussians {
        let r = bench::run(n, args.size, args.size, args.reps);
        println!(
            "{:>10} {:>9} {:>10.4} {:>10.4} {:>10.4} {:>10.4} {:>12.1} {:>9.1}% {:>9}",
            n,
            format!("{}x{}", r.width, r.height),
            r.forward,
            r.binning,
            r.backward,
            r.splat_back,
            r.blended_pairs as f64 / r.forward / 1e6,
            100.0 * r.saturated_fraction,
            r.median_traversed
        );
        println!(
            "{}",
            serde_json::json!({
                "gaussians": n, "width": r.width, "height": r.height,
                "forward_s": r.forward, "binning_s": r.binning, "backward_s": r.backward, "splat_back_s": r.splat_back,
                "blended_pairs": r.blended_pairs, "intersections": r.intersections,
                "saturated_fraction": r.saturated_fraction, "median_traversed": r.median_traversed,
                "backward_over_forward": r.backward / r.forward,
                "threads": rayon::current_num_threads(),
            })
        );
    }
    Ok(())
}

/// Arguments of `transsplat bench models`.
#[derive(clap::Args, Debug)]
pub struct ModelsArgs {
    /// Only the cases whose name contains this text.
    #[arg(long)]
    pub only: Option<String>,
}

/// `transsplat bench models`: one forward pass per model case (real architecture sizes,
/// random weights), after one warm-up.
pub fn models(args: &ModelsArgs) -> anyhow::Result<()> {
    let device = transsplat_models::default_device();
    println!("{:<28} {:>10}", "case", "seconds");
    for case in transsplat_models::bench::cases() {
        if args.only.as_deref().is_some_and(|o| !case.name.contains(o)) {
            continue;
        }
        let s = (case.run)(&device)?;
        println!("{:<28} {:>10.3}", case.name, s);
    }
    Ok(())
}
