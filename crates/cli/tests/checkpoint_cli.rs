//! Interruptible long runs through the binary: `train` and `edit` stopped after k
//! steps (the hidden `--stop-after`) print the exact command that continues them,
//! and running that command gives byte-identical output to an uninterrupted run;
//! Ctrl-C (SIGINT to a child process) writes a checkpoint that resumes; NaN stops a
//! run naming the step and parameter group and writes no scene.

mod common;
use common::*;
use std::io::{BufRead, BufReader, Read};
use std::path::Path;
use std::process::{Command, Stdio};

/// Runs `args` with `--stop-after k` (expecting the stop message), then the printed
/// command line; returns the stderr of the stop.
fn stop_and_resume(dir: &Path, args: &[&str], k: u64) -> String {
    let o = bin().current_dir(dir).args(args).args(["--stop-after", &k.to_string()]).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(err.contains(&format!("interrupted after step {k}; nothing was written")), "{err}");
    let cmd = err.split("continue with: ").nth(1).expect("the message gives the command").trim();
    assert!(
        cmd.ends_with(".checkpoint") && cmd.contains(" --resume ") && !cmd.contains("--stop-after"),
        "{cmd}"
    );
    ok(&Command::new("sh").current_dir(dir).args(["-c", cmd]).output().unwrap());
    err
}

#[test]
fn stopped_train_resumed_with_the_printed_command_matches_an_uninterrupted_run() {
    let dir = tempfile::tempdir().unwrap();
    quick_scene_in(dir.path(), "data");
    let run = |out: &str| -> Vec<String> {
        [
            "train",
            "--data",
            "data",
            "--iters",
            "40",
            "--resolution",
            "4",
            "--checkpoint-every",
            "10",
            "--out",
            out,
        ]
        .map(String::from)
        .to_vec()
    };
    let a = run("a");
    ok(&bin().current_dir(dir.path()).args(&a).output().unwrap());
    let b = run("b");
    let b: Vec<&str> = b.iter().map(String::as_str).collect();
    stop_and_resume(dir.path(), &b, 23);
    let ply = "point_cloud/iteration_40/point_cloud.ply";
    let (pa, pb) = (
        std::fs::read(dir.path().join("a").join(ply)).unwrap(),
        std::fs::read(dir.path().join("b").join(ply)).unwrap(),
    );
    assert!(pa == pb, "resumed training differs from the uninterrupted run");
    assert!(!dir.path().join("b.checkpoint").exists(), "the checkpoint folder is removed after success");

    // A fresh run over a leftover checkpoint is refused; so is resuming with other settings.
    let o = bin().current_dir(dir.path()).args(&b).args(["--stop-after", "5"]).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    let o = bin().current_dir(dir.path()).args(&b).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("holds a checkpoint of an earlier run") && err.contains("--resume"), "{err}");
    let o = bin()
        .current_dir(dir.path())
        .args(&b)
        .args(["--seed", "4", "--resume", "b.checkpoint"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("other settings") && err.contains("seed: 4"), "{err}");
}

#[test]
fn stopped_edit_resumed_with_the_printed_command_matches_an_uninterrupted_edit() {
    let dir = tempfile::tempdir().unwrap();
    quick_scene_in(dir.path(), "data");
    let run = |out: &'static str| {
        [
            "edit",
            "--scene",
            "data",
            "--prompt",
            "make the ball blue",
            "--editor",
            "simulated",
            "--steps",
            "30",
            "--set",
            "schedule.transport_every=10",
            "--checkpoint-every",
            "10",
            "--out",
            out,
        ]
    };
    ok(&bin().current_dir(dir.path()).args(run("a")).output().unwrap());
    let err = stop_and_resume(dir.path(), &run("b"), 13);
    assert!(err.contains("'make the ball blue'"), "the prompt is quoted for the shell: {err}");
    let ply = "point_cloud/iteration_30/point_cloud.ply";
    let (pa, pb) = (
        std::fs::read(dir.path().join("a").join(ply)).unwrap(),
        std::fs::read(dir.path().join("b").join(ply)).unwrap(),
    );
    assert!(pa == pb, "resumed edit differs from the uninterrupted edit");
    assert!(!dir.path().join("b.checkpoint").exists());
}

#[test]
fn sigint_writes_a_checkpoint_that_resumes() {
    let dir = tempfile::tempdir().unwrap();
    quick_scene_in(dir.path(), "data");
    let args = ["train", "--data", "data", "--iters", "1000000", "--resolution", "8", "--out", "out"];
    let mut child = bin().current_dir(dir.path()).args(args).stderr(Stdio::piped()).spawn().unwrap();
    let mut err = BufReader::new(child.stderr.take().unwrap());
    let mut log = String::new();
    while !log.contains("initialised") {
        assert!(err.read_line(&mut log).unwrap() > 0, "the child ended early: {log}");
    }
    ok(&Command::new("kill").args(["-INT", &child.id().to_string()]).output().unwrap());
    err.read_to_string(&mut log).unwrap();
    let status = child.wait().unwrap();
    assert_eq!(status.code(), Some(2), "{log}");
    let step: u64 = log
        .split("interrupted after step ")
        .nth(1)
        .and_then(|s| s.split(';').next())
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no step in {log}"));
    assert!(log.contains("--resume") && dir.path().join("out.checkpoint/train.ckpt").is_file(), "{log}");
    assert!(!dir.path().join("out/point_cloud").exists());
    // The checkpoint resumes at that step: continue 3 more steps and stop again.
    let o = bin()
        .current_dir(dir.path())
        .args(args)
        .args(["--resume", "out.checkpoint", "--stop-after", &(step + 3).to_string()])
        .output()
        .unwrap();
    let e = String::from_utf8_lossy(&o.stderr);
    assert!(
        e.contains(&format!("resuming at step {step}"))
            && e.contains(&format!("interrupted after step {}", step + 3)),
        "{e}"
    );
}

#[test]
fn nan_stops_train_and_edit_naming_step_and_group_and_writes_no_scene() {
    let dir = tempfile::tempdir().unwrap();
    quick_scene_in(dir.path(), "data");
    let o = bin()
        .current_dir(dir.path())
        .args([
            "train",
            "--data",
            "data",
            "--iters",
            "20",
            "--resolution",
            "8",
            "--opacity-lr",
            "3e38",
            "--out",
            "t",
        ])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("step 1: the opacities became NaN or infinite") && err.contains("no scene was written"),
        "{err}"
    );
    assert!(!dir.path().join("t").exists());
    let o = bin()
        .current_dir(dir.path())
        .args(["edit", "--scene", "data", "--prompt", "make the ball blue", "--editor", "simulated"])
        .args(["--steps", "20", "--set", "lr.sh_dc=1e38", "--out", "e"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("step 1: the sh became NaN or infinite") && err.contains("no scene was written"),
        "{err}"
    );
    assert!(!dir.path().join("e").exists());
}

/// The `--views auto` edit of the quick scene (20 steps, a checkpoint every 10) into `out`.
fn auto_edit(out: &str) -> Vec<&str> {
    let args = "edit --scene data --prompt make_the_ball_blue --editor simulated --views auto --steps 20";
    let mut a: Vec<&str> = args.split(' ').collect();
    a[4] = "make the ball blue";
    a.extend(["--checkpoint-every", "10", "--out", out]);
    a
}

/// Runs the command a stop printed (after "continue with: ") in `dir`, checks it ends
/// well and that its edit equals the uninterrupted one in `a` (20 steps); returns its log.
fn continue_and_compare(dir: &Path, stop_log: &str, out: &str) -> String {
    let cmd = stop_log.split("continue with: ").nth(1).expect("the message gives the command").trim();
    let resumed = Command::new("sh").current_dir(dir).args(["-c", cmd]).output().unwrap();
    ok(&resumed);
    let ply = "point_cloud/iteration_20/point_cloud.ply";
    let read = |o: &str| std::fs::read(dir.join(o).join(ply)).unwrap();
    assert!(read("a") == read(out), "the resumed auto edit differs from the uninterrupted one");
    String::from_utf8_lossy(&resumed.stderr).into_owned()
}

/// `--views auto` stopped during the steps and resumed: the resumed edit takes the chosen
/// views and their edits from the checkpoint (the editor is not called again) and ends as
/// the uninterrupted edit does. Stopped during auto's own edits (after the seeds, before
/// the first round): the seeds are kept, and the printed command chooses again from them.
#[test]
fn stopped_auto_edits_resume_to_the_uninterrupted_result() {
    let dir = tempfile::tempdir().unwrap();
    quick_scene_in(dir.path(), "data");
    ok(&bin().current_dir(dir.path()).args(auto_edit("a")).output().unwrap());

    let o = bin().current_dir(dir.path()).args(auto_edit("b")).args(["--stop-after", "13"]).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert!(err.contains("--views auto:") && o.status.code() == Some(2), "{err}");
    let log = continue_and_compare(dir.path(), &err, "b");
    assert!(!log.contains("--views auto:"), "the resumed edit chose its views again: {log}");

    let o = bin()
        .current_dir(dir.path())
        .args(auto_edit("c"))
        .args(["--stop-after-views", "1"])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("interrupted during the 2D edits") && err.contains("4 edited views kept"), "{err}");
    let log = continue_and_compare(dir.path(), &err, "c");
    assert!(log.contains("4 of 4 views kept by the stopped run"), "{log}");
}
