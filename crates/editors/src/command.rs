//! The command editor: runs a user command over a folder of renders and reads its
//! edits back — the way to plug in any editor (a diffusers script on a GPU machine,
//! an image tool, a remote call).
//!
//! # File protocol
//!
//! Before the command runs, transsplat writes into the work folder `WORK`:
//!
//! - `WORK/input/<stem>.png`: the current render of every edit view (8-bit RGB), named
//!   by the stem of the camera's image name (`00012.png` → `00012`).
//! - `WORK/request.json`:
//!   `{"prompt": "...", "views": [{"name": "00012", "file": "00012.png", "index": 12,
//!   "width": 256, "height": 192}, ...]}`.
//!
//! It then runs the command line with `sh -c` in `WORK`, stdin empty, with these
//! environment variables (absolute paths):
//!
//! | variable | value |
//! |---|---|
//! | `TRANSSPLAT_INPUT` | `WORK/input` |
//! | `TRANSSPLAT_OUTPUT` | `WORK/output` (exists and holds no stale results) |
//! | `TRANSSPLAT_PROMPT` | the instruction |
//! | `TRANSSPLAT_REQUEST` | `WORK/request.json` |
//!
//! The command writes, for each view it edited:
//!
//! - `WORK/output/<stem>.png` (or `.jpg`): the edited image, ideally at the view's
//!   size (other sizes are resized, with a warning);
//! - optionally `WORK/output/masks/<stem>.png`: the target mask (grey, > 0.5 inside);
//! - optionally `WORK/output/attention/<stem>.npy`: a float32 `H × W` attention map
//!   (≥ 0; e.g. the text-guidance magnitude of a diffusion editor), used instead of the
//!   mask or the change map.
//!
//! The command runs in a process group of its own. Its stdout and stderr stream to
//! `WORK/editor.stdout.log` and `WORK/editor.stderr.log`; a non-zero exit status is an
//! error that quotes the last lines of the stderr log (bounded). A time limit
//! ([`CommandEditor::with_timeout`]) ends a hung command and a cancel flag
//! ([`CommandEditor::with_cancel`]: Ctrl-C, SIGTERM) ends it early; either way its whole
//! process group is ended, so nothing is orphaned ([`crate::child`]). Views without an
//! output are skipped with a warning, no output at all is an error — exactly as for the
//! [`folder`](crate::folder) editor, which reads the outputs.
//!
//! Before each run the files this protocol names (inputs, outputs, masks and attention
//! maps of the current views, and `request.json`) are removed from `WORK`; nothing else
//! in it is touched.

use crate::child::{tail, Run};
use crate::folder::{read_edits, view_entries, ViewEntry};
use crate::{EditedView, Editor, Error, SourceView};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::AtomicBool;
use std::time::Duration;
use transsplat_scene::{atomic, image};

/// Runs a command line over exported views (see the module doc).
#[derive(Clone, Debug)]
pub struct CommandEditor<'c> {
    command: String,
    work_dir: PathBuf,
    timeout: Option<Duration>,
    cancel: Option<&'c AtomicBool>,
}

fn io_err(path: &Path, e: std::io::Error) -> Error {
    transsplat_scene::Error::io(path, e).into()
}

fn remove_if_present(path: &Path) -> Result<(), Error> {
    match std::fs::remove_file(path) {
        Ok(()) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(()),
        Err(e) => Err(io_err(path, e)),
    }
}

impl<'c> CommandEditor<'c> {
    /// `command_line` is run with `sh -c`; `work_dir` is created if needed.
    pub fn new(command_line: impl Into<String>, work_dir: impl Into<PathBuf>) -> Self {
        CommandEditor { command: command_line.into(), work_dir: work_dir.into(), timeout: None, cancel: None }
    }

    /// Ends the command (and its process group) when it runs longer than `limit`.
    pub fn with_timeout(mut self, limit: Duration) -> Self {
        self.timeout = Some(limit);
        self
    }

    /// Ends the command (and its process group) when `flag` becomes true.
    pub fn with_cancel(mut self, flag: &'c AtomicBool) -> Self {
        self.cancel = Some(flag);
        self
    }

    pub fn command_line(&self) -> &str {
        &self.command
    }

    pub fn work_dir(&self) -> &Path {
        &self.work_dir
    }

    /// Writes the request and inputs, clearing stale protocol files; returns the
    /// absolute input and output folders and the request path.
    fn prepare(&self, views: &[SourceView], prompt: &str) -> Result<(PathBuf, PathBuf, PathBuf), Error> {
        let entries = view_entries(views)?;
        let work = &self.work_dir;
        std::fs::create_dir_all(work).map_err(|e| io_err(work, e))?;
        let work = work.canonicalize().map_err(|e| io_err(work, e))?;
        let (input, output) = (work.join("input"), work.join("output"));
        for d in [&input, &output] {
            std::fs::create_dir_all(d).map_err(|e| io_err(d, e))?;
        }
        let request = work.join("request.json");
        remove_if_present(&request)?;
        for e in &entries {
            remove_if_present(&input.join(&e.file))?;
            for ext in image::EXTENSIONS {
                remove_if_present(&output.join(format!("{}.{ext}", e.name)))?;
            }
            remove_if_present(&output.join("masks").join(format!("{}.png", e.name)))?;
            remove_if_present(&output.join("attention").join(format!("{}.npy", e.name)))?;
        }
        for (v, e) in views.iter().zip(&entries) {
            image::write_png(&input.join(&e.file), e.width, e.height, v.image)?;
        }
        let text = serde_json::to_string_pretty(&Request { prompt, views: &entries })
            .expect("plain data serialises");
        atomic::write_bytes(&request, text.as_bytes())?;
        Ok((input, output, request))
    }
}

/// `request.json`, what the command reads beside the input images: the instruction and
/// one entry per view (name, file, index, width, height; the protocol in the module doc).
#[derive(Debug, serde::Serialize)]
struct Request<'a> {
    prompt: &'a str,
    views: &'a [ViewEntry],
}

impl Editor for CommandEditor<'_> {
    fn name(&self) -> &str {
        "command"
    }

    fn edit(&mut self, views: &[SourceView], prompt: &str) -> Result<Vec<Option<EditedView>>, Error> {
        if self.command.trim().is_empty() {
            return Err(Error::Command("the editor command is empty".into()));
        }
        let (input, output, request) = self.prepare(views, prompt)?;
        tracing::info!("running editor command: {}", self.command);
        let work = input.parent().unwrap_or(&input);
        let mut cmd = Command::new("sh");
        cmd.arg("-c")
            .arg(&self.command)
            .current_dir(work)
            .env("TRANSSPLAT_INPUT", &input)
            .env("TRANSSPLAT_OUTPUT", &output)
            .env("TRANSSPLAT_PROMPT", prompt)
            .env("TRANSSPLAT_REQUEST", &request);
        let run = Run { log_dir: work, timeout: self.timeout, cancel: self.cancel };
        let status = run.status(cmd, &format!("editor command `{}`", self.command))?;
        if !status.success() {
            let err = tail(&run.stderr_log());
            let err = if err.is_empty() { "no stderr output".to_string() } else { err };
            return Err(Error::Command(format!(
                "editor command `{}` failed ({status}): {err}",
                self.command
            )));
        }
        tracing::debug!("editor output: {}", run.log_dir.display());
        read_edits(&output, views, None, Some(&output.join("attention"))).map_err(|e| match e {
            Error::NoEdits(msg) => {
                Error::NoEdits(format!("editor command `{}` wrote nothing usable: {msg}", self.command))
            }
            other => other,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::folder::tests::camera;
    use transsplat_scene::{npy, Camera};

    fn setup() -> (Vec<Camera>, Vec<Vec<f32>>) {
        let cams = vec![camera("v0.png", 6, 4), camera("v1.png", 6, 4)];
        let imgs =
            (0..2).map(|k| (0..6 * 4 * 3).map(|i| ((i + k * 7) % 11) as f32 / 10.0).collect()).collect();
        (cams, imgs)
    }

    #[test]
    fn protocol_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let (cams, imgs) = setup();
        let views: Vec<SourceView> = cams
            .iter()
            .zip(&imgs)
            .enumerate()
            .map(|(i, (c, m))| SourceView { index: i, camera: c, image: m })
            .collect();
        // copy the inputs as outputs, record the prompt and request, and give v1 an attention map
        let cmd = r#"cp "$TRANSSPLAT_INPUT"/* "$TRANSSPLAT_OUTPUT"/ && printf '%s' "$TRANSSPLAT_PROMPT" > prompt.txt && cp "$TRANSSPLAT_REQUEST" seen.json && mkdir -p "$TRANSSPLAT_OUTPUT/attention" && cp attn.npy "$TRANSSPLAT_OUTPUT/attention/v1.npy""#;
        let attn: Vec<f32> = (0..24).map(|i| i as f32).collect();
        npy::write(&dir.path().join("attn.npy"), &[4, 6], &attn).unwrap();
        let mut ed = CommandEditor::new(cmd, dir.path());
        let out = ed.edit(&views, "make it \"blue\" $HOME").unwrap();
        assert_eq!(std::fs::read_to_string(dir.path().join("prompt.txt")).unwrap(), "make it \"blue\" $HOME");
        let req: serde_json::Value =
            serde_json::from_slice(&std::fs::read(dir.path().join("seen.json")).unwrap()).unwrap();
        assert_eq!(req["prompt"], "make it \"blue\" $HOME");
        assert_eq!(req["views"][1]["name"], "v1");
        assert_eq!(req["views"][0]["width"], 6);
        for (v, src) in out.iter().zip(&imgs) {
            let v = v.as_ref().unwrap();
            for (a, b) in v.image.iter().zip(src) {
                assert!((a - b).abs() <= 0.5 / 255.0 + 1e-6);
            }
        }
        // unchanged image: change attention ~0; v1 takes the attention file
        assert!(out[0].as_ref().unwrap().attention.iter().all(|&a| a < 1e-2));
        assert_eq!(out[1].as_ref().unwrap().attention, attn);

        // a second run does not see the first run's outputs
        let mut ed = CommandEditor::new("true", dir.path());
        let e = ed.edit(&views, "x").unwrap_err();
        assert!(matches!(e, Error::NoEdits(_)), "{e}");
        assert!(e.to_string().contains("wrote nothing usable"), "{e}");
        // but its own files and unrelated files are left alone
        assert!(dir.path().join("attn.npy").is_file() && dir.path().join("input/v0.png").is_file());
    }

    #[test]
    fn failing_command_reports_status_and_stderr() {
        let dir = tempfile::tempdir().unwrap();
        let (cams, imgs) = setup();
        let views = [SourceView { index: 0, camera: &cams[0], image: &imgs[0] }];
        let mut ed = CommandEditor::new("echo first >&2; echo 'out of memory' >&2; exit 3", dir.path());
        let e = ed.edit(&views, "p").unwrap_err();
        assert!(matches!(e, Error::Command(_)));
        let msg = e.to_string();
        assert!(msg.contains("exit status: 3") && msg.contains("first | out of memory"), "{msg}");
        let e = CommandEditor::new("  ", dir.path()).edit(&views, "p").unwrap_err().to_string();
        assert!(e.contains("empty"), "{e}");
    }

    #[test]
    fn attention_of_the_wrong_shape_is_an_error_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let (cams, imgs) = setup();
        let views = [SourceView { index: 0, camera: &cams[0], image: &imgs[0] }];
        npy::write(&dir.path().join("bad.npy"), &[3, 3], &[0.0; 9]).unwrap();
        let cmd = r#"cp "$TRANSSPLAT_INPUT"/v0.png "$TRANSSPLAT_OUTPUT"/ && mkdir -p "$TRANSSPLAT_OUTPUT/attention" && cp bad.npy "$TRANSSPLAT_OUTPUT/attention/v0.npy""#;
        let e = CommandEditor::new(cmd, dir.path()).edit(&views, "p").unwrap_err().to_string();
        assert!(e.contains("v0.npy") && e.contains("3x3"), "{e}");
    }
}
