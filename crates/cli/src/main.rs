//! The `transsplat` binary: argument parsing and logging only; the work is in the crates.

mod commands;

/// mimalloc keeps freed memory mapped and reuses it. With the system allocator every
/// large buffer (a render's binning arrays, the backward accumulators, a 1M-Gaussian
/// gradient, a transport kernel) is a fresh `mmap`: a page fault per 4 KiB on first
/// touch and TLB shootdowns on `munmap`, which cost more than the rasterizer's own work
/// at 1M Gaussians (`transsplat bench raster`).
///
/// It also gives freed memory back to the system (a purge) 10 ms to 100 ms after it is
/// freed, and the next allocation of it faults every page in again, zeroed by the
/// kernel. A neural model's forward pass frees and reallocates its large activations
/// every few tens of milliseconds, so a command that runs one turns purging off
/// ([`keep_freed_memory`]): the process keeps what it freed for reuse until it exits.
/// The others keep purging: without it training and the lift run a few percent faster
/// but need 8–13 % more peak memory (method.md M10).
#[global_allocator]
static ALLOC: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// Whether `command` runs a neural model: InstructPix2Pix, a segmenter, the model benchmarks.
fn runs_models(command: &Command) -> bool {
    match command {
        Command::Bench(BenchCommand::Models(_)) => true,
        Command::Bench(BenchCommand::Edit(args)) => args.editor == "ip2p",
        Command::Edit(args) => {
            matches!(args.editor, commands::edit::EditorKind::Ip2p) || args.segment.is_some()
        }
        _ => false,
    }
}

/// Turns mimalloc's purging off (`mi_option_purge_delay` = −1, mimalloc.h).
fn keep_freed_memory() {
    extern "C" {
        fn mi_option_set(option: std::ffi::c_int, value: std::ffi::c_long);
    }
    /// `mi_option_purge_delay` in mimalloc.h's `mi_option_e` (versions 2 and 3).
    const PURGE_DELAY: std::ffi::c_int = 15;
    // SAFETY: mimalloc is linked as the global allocator above; setting an option is
    // thread-safe and takes plain integers.
    unsafe { mi_option_set(PURGE_DELAY, -1) };
}

use clap::{Parser, Subcommand};

/// Language-driven editing of 3D Gaussian Splatting scenes by unbalanced semantic transport.
#[derive(Parser, Debug)]
#[command(name = "transsplat", version, about, long_about = None)]
struct Cli {
    /// More log output (-v debug, -vv trace).
    #[arg(short, long, action = clap::ArgAction::Count, global = true)]
    verbose: u8,
    #[command(subcommand)]
    command: Command,
}

// Parsed once per process: the size of the largest variant does not matter.
#[allow(clippy::large_enum_variant)]
#[derive(Subcommand, Debug)]
enum Command {
    /// The built-in benchmark: a built-in scene, the simulated editor, TransSplat and
    /// every baseline and ablation scored against ground truth (no weights, no inputs).
    Demo(commands::demo::DemoArgs),
    /// Edit a scene from an instruction with a 2D editor (folder, command or simulated).
    Edit(commands::edit::EditArgs),
    /// CLIP-sim and CLIP-dir of edited renders against source renders (any method).
    Eval(commands::eval::EvalArgs),
    /// Render every camera of a scene to PNG (and raw .npy).
    Render(commands::render::RenderArgs),
    /// Convert a scene between INRIA PLY, PlayCanvas compressed PLY and SPZ (and cameras to cameras.json).
    Convert(commands::convert::ConvertArgs),
    /// Write an interactive 3D viewer page (WebGL2, offline) for a scene, or a before/after pair.
    View(commands::view::ViewArgs),
    /// Print a summary of a scene: count, SH degree, bounding box, opacity and scale.
    Info(commands::info::InfoArgs),
    /// Solve one entropic unbalanced transport problem from .npy files.
    Uot(commands::uot::UotArgs),
    /// Write a built-in benchmark scene (tabletop, occluded, garden) as a dataset with labels and masks.
    Scene(commands::scene::BuiltinSceneArgs),
    /// Train a 3DGS scene from a COLMAP, transforms.json or INRIA-layout dataset.
    Train(commands::train::TrainArgs),
    /// Export the edit views (training cameras) as PNGs for editing with any 2D tool.
    #[command(subcommand)]
    Views(commands::views::ViewsCommand),
    /// Benchmarks.
    #[command(subcommand)]
    Bench(BenchCommand),
}

#[derive(Subcommand, Debug)]
enum BenchCommand {
    /// Unbalanced transport solver: dense and top-k, 1e5 and 1e6 sources.
    Transport(commands::uot::BenchArgs),
    /// Rasterizer: forward, backward and splat-back on a synthetic scene.
    Raster(commands::bench::RasterArgs),
    /// Models: CLIP, CLIPSeg, SAM, DINOv2 and InstructPix2Pix forward passes at the real sizes (random weights).
    Models(commands::bench::ModelsArgs),
    /// Training: time per step (render, loss, backward, Adam) against forward + backward.
    Train(commands::train::BenchArgs),
    /// A whole edit at a stated real size (simulated editor), timed by stage and scored.
    Edit(commands::bench::EditArgs),
    /// The ground-truth quality suite: scenes (built and trained) x edits x severities, every method.
    Quality(commands::bench::QualityArgs),
}

/// Set by SIGINT / Ctrl-C or SIGTERM; long commands stop at the next step, write nothing partial, and
/// `train` / `edit` write a checkpoint to resume from.
static CANCEL: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Held by whoever ends the process. The hard exit on a second signal takes it before it
/// ends the editors (which lets the main thread run on to its own exit) and never lets
/// go, so the process quits with 130 and not with the main thread's code; a main thread
/// that took it first was already quitting, and its code stands.
static EXITING: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// Ends the process with `code` unless a hard exit already holds [`EXITING`].
fn exit(code: i32) -> ! {
    let _held = EXITING.lock().unwrap_or_else(|e| e.into_inner());
    std::process::exit(code)
}

/// Parses the command line. A bad flag is one line, `error: ...` naming the flag, and
/// exit status 2, like every other bad input (clap's usage block and hint are left out);
/// `--help` and `--version` print as usual.
fn parse_args() -> Cli {
    use clap::error::ErrorKind;
    match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) if matches!(e.kind(), ErrorKind::DisplayHelp | ErrorKind::DisplayVersion) => e.exit(),
        Err(e) if e.kind() == ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand => e.exit(),
        Err(e) => {
            let text = e.render().to_string();
            let message: Vec<&str> = text
                .lines()
                .map(str::trim)
                .take_while(|l| !l.is_empty() && !l.starts_with("Usage:"))
                .collect();
            eprintln!("{}", message.join(" "));
            std::process::exit(2)
        }
    }
}

fn main() {
    let cli = parse_args();
    if runs_models(&cli.command) {
        keep_freed_memory();
    }
    // Commands that poll CANCEL stop cleanly at their next step; the others (short, and
    // writing each output atomically) keep the default: Ctrl-C ends them at once.
    let polls_cancel = matches!(
        cli.command,
        Command::Demo(_)
            | Command::Edit(_)
            | Command::Eval(_)
            | Command::Render(_)
            | Command::Train(_)
            | Command::Bench(BenchCommand::Edit(_))
            | Command::Bench(BenchCommand::Quality(_))
    );
    if !polls_cancel {
        // The short commands print and end: a reader that closes the pipe early
        // (`transsplat info SCENE | head`) ends them quietly, as it does any Unix tool,
        // instead of a panic on the failed write. Their files are written to a temporary
        // name and renamed, so nothing half-written is left.
        // SAFETY: called before any other thread starts; SIG_DFL is a valid disposition.
        #[cfg(unix)]
        unsafe {
            libc::signal(libc::SIGPIPE, libc::SIG_DFL);
        }
    }
    if polls_cancel {
        // SIGINT, SIGTERM (what `timeout`, docker and batch schedulers send) and SIGHUP.
        let _ = ctrlc::set_handler(|| {
            if CANCEL.swap(true, std::sync::atomic::Ordering::SeqCst) {
                // A second signal quits at once, still ending any editor process group
                // and removing the staging folders.
                let _held = EXITING.lock().unwrap_or_else(|e| e.into_inner());
                transsplat_editors::child::kill_all();
                transsplat_scene::atomic::remove_staged();
                std::process::exit(130);
            }
            eprintln!(
                "interrupt: stopping at the next step (train and edit save a checkpoint); a second signal quits at once"
            );
        });
    }
    let level = match cli.verbose {
        0 => "info",
        1 => "debug",
        _ => "trace",
    };
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(level));
    tracing_subscriber::fmt().with_env_filter(filter).with_writer(std::io::stderr).with_target(false).init();
    let result = match &cli.command {
        Command::Demo(a) => commands::demo::run(a, &CANCEL),
        Command::Edit(a) => commands::edit::run(a, &CANCEL),
        Command::Eval(a) => commands::eval::run(a, &CANCEL),
        Command::Render(a) => commands::render::run(a, &CANCEL),
        Command::Info(a) => commands::info::run(a),
        Command::Convert(a) => commands::convert::run(a),
        Command::View(a) => commands::view::run(a),
        Command::Uot(a) => commands::uot::run(a),
        Command::Scene(a) => commands::scene::run(a),
        Command::Views(c) => commands::views::run(c),
        Command::Bench(BenchCommand::Transport(a)) => commands::uot::bench(a),
        Command::Bench(BenchCommand::Raster(a)) => commands::bench::raster(a),
        Command::Bench(BenchCommand::Models(a)) => commands::bench::models(a),
        Command::Train(a) => commands::train::run(a, &CANCEL),
        Command::Bench(BenchCommand::Train(a)) => commands::train::bench(a),
        Command::Bench(BenchCommand::Edit(a)) => commands::bench::edit(a, &CANCEL),
        Command::Bench(BenchCommand::Quality(a)) => commands::bench::quality(a, &CANCEL),
    };
    if let Err(e) = result {
        eprintln!("error: {e:#}");
        exit(2);
    }
    exit(0)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn runs(args: &[&str]) -> bool {
        let cli = Cli::try_parse_from(std::iter::once("transsplat").chain(args.iter().copied())).unwrap();
        runs_models(&cli.command)
    }

    /// Purging stays on unless the command runs a neural model (the doc of `ALLOC`).
    #[test]
    fn only_commands_that_run_a_model_keep_freed_memory() {
        assert!(runs(&["bench", "models"]));
        assert!(runs(&["bench", "edit", "--editor", "ip2p"]));
        assert!(!runs(&["bench", "edit"]));
        let edit = |editor: &str, more: &[&str]| {
            let mut args =
                vec!["edit", "--scene", "s.ply", "--cameras", "c.json", "--prompt", "p", "--out", "o"];
            args.extend(["--editor", editor]);
            args.extend(more);
            runs(&args)
        };
        assert!(edit("ip2p", &[]));
        assert!(edit("simulated", &["--segment", "the ball", "--segment-weights", "clipseg"]));
        assert!(!edit("simulated", &[]));
        assert!(!runs(&["demo"]));
    }
}
