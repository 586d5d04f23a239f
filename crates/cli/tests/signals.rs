//! SIGTERM (what `timeout`, docker and batch schedulers send) is handled like Ctrl-C:
//! an `edit` whose command editor hangs stops, ends the editor's whole process group,
//! removes its staging folder and exits 2, also when the editor ignores SIGTERM; a
//! second signal quits at once (130) and still leaves no staging folder and no editor
//! process behind.

#![cfg(unix)]

mod common;
use common::*;
use std::path::Path;
use std::time::{Duration, Instant};

/// Shell processes (the editor and the grandchild it starts) whose command line holds
/// `token`.
fn processes_with(token: &str) -> Vec<String> {
    let mut found = Vec::new();
    for e in std::fs::read_dir("/proc").unwrap().flatten() {
        if let Ok(cmd) = std::fs::read(e.path().join("cmdline")) {
            let cmd = String::from_utf8_lossy(&cmd);
            if cmd.starts_with("sh\0-c\0") && cmd.contains(token) {
                found.push(format!("{}: {cmd}", e.file_name().to_string_lossy()));
            }
        }
    }
    found
}

/// Starts an edit whose editor hangs, waits until the editor runs, sends `signals`
/// SIGTERMs and returns the exit code.
fn edit_with_hung_editor(dir: &Path, token: &str, signals: usize) -> Option<i32> {
    let ds = quick_scene(dir);
    let out = dir.join("out");
    // An editor that ignores SIGTERM (so ending it takes the grace period and then
    // SIGKILL, and a second signal arrives while it is being ended), a grandchild that
    // would outlive the editor's shell, then a hang.
    let script = format!("trap '' TERM; sh -c 'sleep 302; true # {token}' & sleep 301; echo {token}");
    let mut child = bin()
        .args(["edit", "--scene"])
        .arg(&ds)
        .args(["--prompt", "make the ball blue", "--editor", "command", "--steps", "5", "--command", &script])
        .arg("--out")
        .arg(&out)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // Signals are not queued: two SIGTERMs sent before the first is delivered merge into
    // one. So each further signal waits until transsplat has reported the one before.
    let (noticed, notices) = std::sync::mpsc::channel();
    let stderr = child.stderr.take().unwrap();
    std::thread::spawn(move || {
        use std::io::BufRead;
        for line in std::io::BufReader::new(stderr).lines().map_while(Result::ok) {
            if line.starts_with("interrupt:") && noticed.send(()).is_err() {
                break;
            }
        }
    });
    let start = Instant::now();
    while processes_with(token).len() < 2 {
        assert!(start.elapsed() < Duration::from_secs(120), "the editor never started");
        std::thread::sleep(Duration::from_millis(50));
    }
    for i in 0..signals {
        // SAFETY: sends a signal to the child we spawned.
        unsafe { libc::kill(child.id() as i32, libc::SIGTERM) };
        if i + 1 < signals {
            notices.recv_timeout(Duration::from_secs(60)).expect("the first signal was never reported");
        }
    }
    let status = child.wait().unwrap();
    std::thread::sleep(Duration::from_millis(300));
    let left = processes_with(token);
    assert!(left.is_empty(), "the editor outlived transsplat: {left:?}");
    assert!(!out.exists(), "no output folder after a signal");
    let left: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains("partial"))
        .collect();
    assert!(left.is_empty(), "staging folders left: {left:?}");
    status.code()
}

#[test]
fn sigterm_stops_an_edit_and_its_editor_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    assert_eq!(edit_with_hung_editor(dir.path(), "tok_sigterm_once_8f3a", 1), Some(2));
}

#[test]
fn a_second_sigterm_quits_at_once_without_leaving_anything() {
    let dir = tempfile::tempdir().unwrap();
    assert_eq!(edit_with_hung_editor(dir.path(), "tok_sigterm_twice_51c2", 2), Some(130));
}
