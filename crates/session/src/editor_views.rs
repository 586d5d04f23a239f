//! The 2D editor's finished views kept in the checkpoint folder as they are made
//! (`OUT.checkpoint/editor-views/view_NNNNN.edit`), so a job stopped during the edits
//! (Ctrl-C, a crash, a full disk) continues with `--resume` without editing a finished
//! view again. On a CPU the editor is the long stage: InstructPix2Pix takes minutes a
//! view.
//!
//! [`KeptViews`] wraps the job's editor: it hands the editor the views in groups of
//! `group` (InstructPix2Pix: its batch; editors that take a whole shard at once: all of
//! them), writes each finished view before the next group, and on a resume takes the
//! views already kept. A kept view belongs to its job and its view: its file holds a key
//! made from the job's (the scene's fingerprint, the instruction, the editor and its
//! settings, the seed) and the view's render the editor was given (which the camera and
//! the background make), and a file with another key is edited again.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

use crate::SessionError;
use transsplat_editors::{EditedView, Editor, Error as EditorError, SourceView};
use transsplat_scene::archive::{Archive, Hasher, Writer};

use crate::checkpoints::kept_view_files;
/// The folder of kept views inside the checkpoint folder.
pub use crate::checkpoints::EDITOR_VIEWS_DIR as VIEWS_DIR;

/// The job's key for its kept views (module doc); `editor` names the editor and its
/// settings.
pub fn job_key(scene_fingerprint: &str, prompt: &str, editor: &str, seed: u64) -> u64 {
    Hasher::default().str("editor-views 2").str(scene_fingerprint).str(prompt).str(editor).u64(seed).finish()
}

/// The key of one view of the job: the job's and the render the editor is given.
fn view_key(job: u64, view: &SourceView) -> u64 {
    let (w, h) = view.size();
    Hasher::default().u64(job).u64(view.index as u64).u64(w as u64).u64(h as u64).f32s(view.image).finish()
}

/// An editor whose finished views are kept in `dir` as they are made (module doc).
pub struct KeptViews<'a> {
    inner: Box<dyn Editor + 'a>,
    dir: PathBuf,
    key: u64,
    group: usize,
    /// Take the views kept by an earlier run of the job (a `--resume`).
    reuse: bool,
    /// Raise this stop (as Ctrl-C does) once `stop_after` views are kept (tests).
    stop: Option<(&'a AtomicBool, usize)>,
    /// Ctrl-C, checked between groups.
    cancel: Option<&'a AtomicBool>,
    kept: usize,
}

impl<'a> KeptViews<'a> {
    pub fn new(inner: Box<dyn Editor + 'a>, dir: PathBuf, key: u64, group: usize, reuse: bool) -> Self {
        KeptViews { inner, dir, key, group: group.max(1), reuse, stop: None, cancel: None, kept: 0 }
    }

    /// Stops between groups once `flag` is raised (Ctrl-C).
    pub fn with_cancel(mut self, flag: &'a AtomicBool) -> Self {
        self.cancel = Some(flag);
        self
    }

    /// Stops as Ctrl-C would, raising `flag`, once `views` views are kept (tests).
    pub fn with_stop_after(mut self, flag: &'a AtomicBool, views: usize) -> Self {
        self.stop = Some((flag, views));
        self
    }

    fn path(&self, index: usize) -> PathBuf {
        self.dir.join(format!("view_{index:05}.edit"))
    }

    /// The kept output of `view`, if this job kept one that fits its camera.
    fn load(&self, view: &SourceView) -> Option<Option<EditedView>> {
        let path = self.path(view.index);
        if !path.is_file() {
            return None;
        }
        let a = Archive::read(&path).ok()?;
        if a.scalar("key").ok()? != view_key(self.key, view) {
            tracing::info!("{}: kept by another job; the view is edited again", path.display());
            return None;
        }
        if a.scalar("edited").ok()? == 0 {
            return Some(None);
        }
        let (w, h) = view.size();
        let n = w * h;
        let has_mask = a.scalar("has_mask").ok()? == 1;
        let image = a.f32_len("image", n * 3).ok()?.to_vec();
        let attention = a.f32_len("attention", n).ok()?.to_vec();
        let mask = if has_mask { Some(a.f32_len("mask", n).ok()?.to_vec()) } else { None };
        Some(Some(EditedView { width: w, height: h, image, attention, mask }))
    }

    /// Keeps `out` as the output of `view` (written atomically).
    fn keep(&self, view: &SourceView, out: &Option<EditedView>) -> Result<(), EditorError> {
        let mut w = Writer::new();
        w.scalar("key", view_key(self.key, view)).scalar("edited", out.is_some() as u64);
        if let Some(e) = out {
            w.scalar("has_mask", e.mask.is_some() as u64)
                .f32("image", &e.image[..])
                .f32("attention", &e.attention[..])
                .f32("mask", e.mask.as_deref().unwrap_or(&[]));
        }
        std::fs::create_dir_all(&self.dir)
            .map_err(|e| EditorError::Invalid(format!("{}: {e}", self.dir.display())))?;
        let path = self.path(view.index);
        w.write(&path).map(|_| ()).map_err(|e| EditorError::Invalid(format!("keeping the edited view: {e}")))
    }
}

impl Editor for KeptViews<'_> {
    fn name(&self) -> &str {
        self.inner.name()
    }

    fn edit(&mut self, views: &[SourceView], prompt: &str) -> Result<Vec<Option<EditedView>>, EditorError> {
        let mut out: Vec<Option<EditedView>> = vec![None; views.len()];
        let mut todo = Vec::new();
        for (k, v) in views.iter().enumerate() {
            match self.reuse.then(|| self.load(v)).flatten() {
                Some(kept) => out[k] = kept,
                None => todo.push(k),
            }
        }
        if todo.len() < views.len() {
            tracing::info!(
                "editor {}: {} of {} views kept by the stopped run; {} to edit",
                self.inner.name(),
                views.len() - todo.len(),
                views.len(),
                todo.len()
            );
        }
        if !todo.is_empty() {
            self.inner.expect_views(todo.len());
        }
        for group in todo.chunks(self.group) {
            if let Some((flag, _)) = self.stop.filter(|&(_, after)| self.kept >= after) {
                flag.store(true, Ordering::SeqCst);
            }
            if self.cancel.is_some_and(|c| c.load(Ordering::SeqCst)) {
                return Err(EditorError::Invalid(format!("interrupted after {} edited views", self.kept)));
            }
            let part: Vec<SourceView> = group.iter().map(|&k| views[k]).collect();
            let edited = self.inner.edit(&part, prompt)?;
            if edited.len() != part.len() {
                return Err(EditorError::Invalid(format!(
                    "editor {} returned {} views for {} inputs",
                    self.inner.name(),
                    edited.len(),
                    part.len()
                )));
            }
            for (&k, e) in group.iter().zip(edited) {
                self.keep(&views[k], &e)?;
                self.kept += 1;
                out[k] = e;
            }
        }
        Ok(out)
    }
}

/// The error after a stop during the 2D edits: nothing was written to `out`, how many
/// views are kept and the command that continues (the same command again when none is).
pub fn stopped(dir: &Path, out: &Path) -> SessionError {
    let kept = kept_view_files(dir);
    let message = if kept == 0 {
        let _ = std::fs::remove_dir(dir.join(VIEWS_DIR));
        let _ = std::fs::remove_dir(dir);
        format!(
            "interrupted during the 2D edits; nothing was written to {}; no view was finished",
            out.display()
        )
    } else {
        format!(
            "interrupted during the 2D edits; nothing was written to {}; {kept} edited views kept in {}; \
             continue with: {}",
            out.display(),
            dir.display(),
            crate::checkpoints::resume_command(dir)
        )
    };
    SessionError::Interrupted { step: 0, message }
}

/// A failure after some views were kept: `error` with where they are and how to use them.
pub fn failed_with_kept(error: SessionError, dir: &Path) -> SessionError {
    match kept_view_files(dir) {
        0 => error,
        kept => SessionError::Failed(format!(
            "{error}; {kept} edited views kept in {}: continue with --resume {} (kept views are used where the \
             scene, instruction and editor are the same), or delete the folder to start over",
            dir.display(),
            dir.display()
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use transsplat_scene::Camera;

    /// Records the views it is asked to edit; view 3 gets a mask, view 5 is skipped.
    struct Counting {
        asked: std::sync::Arc<std::sync::Mutex<Vec<usize>>>,
    }

    fn counting() -> (Counting, std::sync::Arc<std::sync::Mutex<Vec<usize>>>) {
        let asked = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
        (Counting { asked: asked.clone() }, asked)
    }

    impl Editor for Counting {
        fn name(&self) -> &str {
            "counting"
        }
        fn edit(&mut self, views: &[SourceView], _: &str) -> Result<Vec<Option<EditedView>>, EditorError> {
            self.asked.lock().unwrap().extend(views.iter().map(|v| v.index));
            Ok(views
                .iter()
                .map(|v| {
                    let (w, h) = v.size();
                    let mask = (v.index == 3).then(|| vec![1.0; w * h]);
                    (v.index != 5).then(|| {
                        EditedView::new(vec![v.index as f32 / 10.0; w * h * 3], w, h, vec![0.5; w * h], mask)
                    })
                })
                .collect())
        }
    }

    #[test]
    fn kept_views_are_taken_back_and_only_the_rest_edited() {
        let dir = tempfile::tempdir().unwrap();
        let cams = [Camera::pinhole("c", 3, 2, 2.0)];
        let image = vec![0.0; 18];
        let views: Vec<SourceView> = [1usize, 3, 5, 7]
            .iter()
            .map(|&index| SourceView { index, camera: &cams[0], image: &image })
            .collect();
        let kept = dir.path().join(VIEWS_DIR);
        // A first run keeps every view (in groups of two); one file is then lost.
        let mut first = KeptViews::new(Box::new(counting().0), kept.clone(), 7, 2, false);
        let full = first.edit(&views, "p").unwrap();
        assert_eq!(std::fs::read_dir(&kept).unwrap().count(), 4, "every view kept, the skipped one too");
        std::fs::remove_file(kept.join("view_00007.edit")).unwrap();
        // A resume edits only view 7 and gives back what the first run made.
        let (editor, asked) = counting();
        let again = KeptViews::new(Box::new(editor), kept.clone(), 7, 2, true).edit(&views, "p").unwrap();
        assert_eq!(*asked.lock().unwrap(), vec![7]);
        assert_eq!(again, full);
        assert!(again[1].as_ref().unwrap().mask.is_some() && again[2].is_none());
        // Another job's key: every view is edited again.
        let (editor, asked) = counting();
        KeptViews::new(Box::new(editor), kept, 8, 4, true).edit(&views, "p").unwrap();
        assert_eq!(*asked.lock().unwrap(), vec![1, 3, 5, 7]);
    }
}
