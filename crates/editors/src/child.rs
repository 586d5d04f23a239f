//! Running an external editor process without trusting it: it gets a process group of
//! its own, its stdout and stderr stream to log files (never into memory), a failure
//! quotes a bounded tail of its stderr, a time limit ends a hung editor, a cancel flag
//! (Ctrl-C, SIGTERM) ends it early, and ending it always ends its whole group so no
//! grandchild is orphaned. [`kill_all`] ends every running editor at once, for a hard
//! exit on a second signal.

use crate::Error;
use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// Lines of stderr quoted in an error.
const TAIL_LINES: usize = 12;
/// Bytes read from the end of the stderr log for the quote, and characters kept of
/// one quoted line: the message stays one bounded line whatever the editor printed.
const TAIL_BYTES: u64 = 16 * 1024;
const LINE_CHARS: usize = 300;
/// How long an ended group gets between SIGTERM and SIGKILL.
const GRACE: Duration = Duration::from_secs(2);
/// How often the run is polled for its end, the time limit and the cancel flag.
const POLL: Duration = Duration::from_millis(20);

/// Process group ids of the editors running now.
static RUNNING: Mutex<Vec<i32>> = Mutex::new(Vec::new());

/// Where a run's output goes and what may end it early.
pub struct Run<'a> {
    /// Folder for `editor.stdout.log` and `editor.stderr.log` (created if needed).
    pub log_dir: &'a Path,
    /// End the editor after this long (`None`: no limit).
    pub timeout: Option<Duration>,
    /// End the editor when this becomes true.
    pub cancel: Option<&'a AtomicBool>,
}

impl Run<'_> {
    /// The stderr log's path.
    pub fn stderr_log(&self) -> PathBuf {
        self.log_dir.join("editor.stderr.log")
    }

    /// Runs `cmd` to its end in a new process group; returns its exit status, or an
    /// error when it cannot start, runs past the time limit or is cancelled (its group
    /// is ended first).
    pub fn status(&self, mut cmd: Command, what: &str) -> Result<ExitStatus, Error> {
        let io = |p: &Path, e| Error::from(transsplat_scene::Error::io(p, e));
        std::fs::create_dir_all(self.log_dir).map_err(|e| io(self.log_dir, e))?;
        let out = self.log_dir.join("editor.stdout.log");
        let stdout = std::fs::File::create(&out).map_err(|e| io(&out, e))?;
        let err = self.stderr_log();
        let stderr = std::fs::File::create(&err).map_err(|e| io(&err, e))?;
        cmd.stdout(Stdio::from(stdout)).stderr(Stdio::from(stderr)).stdin(Stdio::null());
        new_group(&mut cmd);
        let mut child = cmd.spawn().map_err(|e| Error::Command(format!("cannot run {what}: {e}")))?;
        let pid = child.id() as i32;
        RUNNING.lock().unwrap_or_else(|e| e.into_inner()).push(pid);
        let result = self.wait(&mut child, what);
        // Whatever happened, nothing of the group outlives the run.
        end_group(pid, &mut child);
        RUNNING.lock().unwrap_or_else(|e| e.into_inner()).retain(|&p| p != pid);
        result
    }

    fn wait(&self, child: &mut Child, what: &str) -> Result<ExitStatus, Error> {
        let start = Instant::now();
        loop {
            if let Some(status) =
                child.try_wait().map_err(|e| Error::Command(format!("waiting for {what}: {e}")))?
            {
                return Ok(status);
            }
            if self.cancel.is_some_and(|c| c.load(Ordering::SeqCst)) {
                return Err(Error::Command(format!("{what} was interrupted (its process group was ended)")));
            }
            if let Some(limit) = self.timeout.filter(|&t| start.elapsed() > t) {
                return Err(Error::Command(format!(
                    "{what} ran past the time limit of {} s (--editor-timeout) and was ended; its output is in {}",
                    limit.as_secs(),
                    self.log_dir.display()
                )));
            }
            std::thread::sleep(POLL);
        }
    }
}

/// The last non-empty lines of a log file, joined with " | ": at most [`TAIL_LINES`]
/// lines from its last [`TAIL_BYTES`] bytes, each cut to [`LINE_CHARS`] characters.
pub fn tail(path: &Path) -> String {
    let Ok(mut f) = std::fs::File::open(path) else { return String::new() };
    let len = f.metadata().map_or(0, |m| m.len());
    let from = len.saturating_sub(TAIL_BYTES);
    let mut bytes = Vec::new();
    if f.seek(SeekFrom::Start(from)).is_err() || f.take(TAIL_BYTES).read_to_end(&mut bytes).is_err() {
        return String::new();
    }
    let text = String::from_utf8_lossy(&bytes);
    let lines: Vec<String> = text
        .lines()
        .skip(usize::from(from > 0)) // the first line may be cut
        .map(str::trim_end)
        .filter(|l| !l.trim().is_empty())
        .map(|l| {
            let mut s: String = l.chars().take(LINE_CHARS).collect();
            if s.len() < l.len() {
                s.push('…');
            }
            s
        })
        .collect();
    lines[lines.len().saturating_sub(TAIL_LINES)..].join(" | ")
}

/// Ends the process group of every editor running now (for a hard exit).
pub fn kill_all() {
    let groups = RUNNING.lock().unwrap_or_else(|e| e.into_inner()).clone();
    for pid in groups {
        signal_group(pid, true);
    }
}

#[cfg(unix)]
fn new_group(cmd: &mut Command) {
    use std::os::unix::process::CommandExt;
    cmd.process_group(0);
}

#[cfg(not(unix))]
fn new_group(_cmd: &mut Command) {}

/// Sends SIGTERM (or SIGKILL) to the process group `pid`.
#[cfg(unix)]
fn signal_group(pid: i32, kill: bool) {
    // SAFETY: kill(2) with a negative pid signals a process group; no memory is touched.
    unsafe {
        libc::kill(-pid, if kill { libc::SIGKILL } else { libc::SIGTERM });
    }
}

#[cfg(not(unix))]
fn signal_group(_pid: i32, _kill: bool) {}

/// Ends the group led by `child`: SIGTERM, then SIGKILL after [`GRACE`] if the
/// leader still runs; reaps the leader. Stragglers of a leader that already ended get
/// SIGTERM too.
fn end_group(pid: i32, child: &mut Child) {
    signal_group(pid, false);
    let start = Instant::now();
    while start.elapsed() < GRACE {
        if let Ok(Some(_)) = child.try_wait() {
            return;
        }
        std::thread::sleep(POLL);
    }
    signal_group(pid, true);
    let _ = child.kill();
    let _ = child.wait();
}

#[cfg(all(test, unix))]
mod tests {
    use super::*;

    fn sh(script: &str) -> Command {
        let mut c = Command::new("sh");
        c.arg("-c").arg(script);
        c
    }

    #[test]
    fn output_goes_to_logs_and_the_tail_is_bounded() {
        let dir = tempfile::tempdir().unwrap();
        let run = Run { log_dir: dir.path(), timeout: None, cancel: None };
        // 3 MB on stdout, one 50 kB stderr line, then a short last line.
        let script =
            "head -c 3000000 /dev/zero | tr '\\0' x; printf '%050000d\\n' 0 >&2; echo bye >&2; exit 4";
        let status = run.status(sh(script), "the test editor").unwrap();
        assert_eq!(status.code(), Some(4));
        assert_eq!(std::fs::metadata(dir.path().join("editor.stdout.log")).unwrap().len(), 3_000_000);
        let t = tail(&run.stderr_log());
        assert!(
            t.ends_with("bye") && t.len() < 2 * LINE_CHARS,
            "{} chars: {}",
            t.len(),
            &t[..80.min(t.len())]
        );
    }

    #[test]
    fn a_hung_editor_is_ended_with_its_whole_group() {
        let dir = tempfile::tempdir().unwrap();
        let pidfile = dir.path().join("grandchild.pid");
        // A grandchild that would outlive the shell, then a hang.
        let script = format!("sleep 300 & echo $! > {}; sleep 300", pidfile.display());
        let run = Run { log_dir: dir.path(), timeout: Some(Duration::from_millis(300)), cancel: None };
        let t = Instant::now();
        let e = run.status(sh(&script), "the test editor").unwrap_err().to_string();
        assert!(e.contains("time limit") && e.contains("--editor-timeout"), "{e}");
        assert!(t.elapsed() < Duration::from_secs(10));
        let pid: i32 = std::fs::read_to_string(&pidfile).unwrap().trim().parse().unwrap();
        std::thread::sleep(Duration::from_millis(200));
        // SAFETY: signal 0 only checks whether the process exists.
        let alive = unsafe { libc::kill(pid, 0) } == 0;
        assert!(!alive || is_zombie(pid), "grandchild {pid} outlived the editor");
    }

    fn is_zombie(pid: i32) -> bool {
        std::fs::read_to_string(format!("/proc/{pid}/stat")).is_ok_and(|s| s.contains(") Z"))
    }

    #[test]
    fn cancelling_ends_the_editor() {
        let dir = tempfile::tempdir().unwrap();
        let flag = AtomicBool::new(false);
        std::thread::scope(|s| {
            s.spawn(|| {
                std::thread::sleep(Duration::from_millis(200));
                flag.store(true, Ordering::SeqCst);
            });
            let run = Run { log_dir: dir.path(), timeout: None, cancel: Some(&flag) };
            let e = run.status(sh("sleep 300"), "the test editor").unwrap_err().to_string();
            assert!(e.contains("interrupted"), "{e}");
        });
    }
}
