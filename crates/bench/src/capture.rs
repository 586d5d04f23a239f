//! Captures rendered from textured meshes by a real renderer (`tools/mesh_captures.py`)
//! as trained cases of the quality suite (`bench quality --captures DIR`).
//!
//! A capture folder holds a nerfstudio dataset (`transforms.json`, `images/`,
//! `points3d.ply`), the true edit of every view (`edited/<stem>.png`), the renderer's
//! object labels sampled `supersample` times finer than the images (`labels/<stem>.png`)
//! and `capture.json`: the target, the objects and their labels.
//!
//! A case trains the capture as `transsplat train --no-masks` does (every 8th view held
//! out, the suite's steps, the default settings), then edits the trained scene with the
//! simulated editor's corruption model ([`Corruption`], module doc of
//! `transsplat_builtin::simulated`) applied to each view's true edit: a label's weight in
//! a pixel is its share of the pixel's label samples ([`LabelRender::from_samples`]), the
//! edit colour c_e is the target's mean colour in the true edits of the training views,
//! the wrong-object candidates are the other objects, and the distractor is the object
//! whose mean colour in the training images is nearest the target's (as the simulated
//! editor picks it over Gaussians). The scores are the demo's for a trained scene: target
//! PSNR against the true edit, background PSNR against the trained scene's own render.

use crate::demo::{CaseRun, CaseScores, DemoError, DemoOptions, DemoOutcome, Fidelity};
use rayon::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use transsplat_builtin::{Corruption, LabelRender};
use transsplat_edit::Progress;
use transsplat_editors::{EditedView, Editor, SourceView};
use transsplat_eval::ground_truth::Reference;
use transsplat_scene::cameras::split_views;
use transsplat_scene::{image, Gaussians};
use transsplat_train::dataset::{self, Dataset, LoadOptions, Masks};

/// Largest label sampling factor read from `capture.json` (the tool writes 3).
const MAX_SUPERSAMPLE: usize = 8;
/// Largest object label (labels are 8-bit in `labels/`).
const MAX_LABEL: u32 = 255;

/// `capture.json`, as `tools/mesh_captures.py` writes it (fields this crate reads).
#[derive(Clone, Debug, serde::Deserialize)]
pub struct CaptureMeta {
    /// The edited object's name, one of `objects`.
    pub target: String,
    pub objects: Vec<CaptureObject>,
    /// Label samples per pixel along each axis in `labels/`.
    pub supersample: usize,
}

/// One object of a capture and its label in `labels/`.
#[derive(Clone, Debug, serde::Deserialize)]
pub struct CaptureObject {
    pub name: String,
    pub label: u32,
}

/// A capture loaded for editing.
#[derive(Clone, Debug)]
pub struct Capture {
    /// The folder's name, which names the suite's cases.
    pub name: String,
    pub dir: PathBuf,
    pub meta: CaptureMeta,
    /// Loaded as `train --no-masks` loads it (every 8th camera held out).
    pub dataset: Dataset,
    /// Per camera (the dataset's order): the true edit and its label samples.
    truths: Vec<(Vec<f32>, Vec<u8>)>,
    num_labels: usize,
}

impl Capture {
    /// Reads the capture in `dir`; every error names the file and the problem.
    pub fn load(dir: &Path) -> Result<Capture, DemoError> {
        let meta_path = dir.join("capture.json");
        let text = transsplat_scene::atomic::read(&meta_path)?;
        let bad = |why: String| DemoError::Io(transsplat_scene::Error::format(&meta_path, why));
        let meta: CaptureMeta =
            serde_json::from_slice(&text).map_err(|e| bad(format!("not a capture description: {e}")))?;
        if !(1..=MAX_SUPERSAMPLE).contains(&meta.supersample) {
            return Err(bad(format!("supersample {} is not in 1..={MAX_SUPERSAMPLE}", meta.supersample)));
        }
        if let Some(o) = meta.objects.iter().find(|o| o.label < 1 || o.label > MAX_LABEL) {
            return Err(bad(format!("object {:?} has label {}, not in 1..={MAX_LABEL}", o.name, o.label)));
        }
        if !meta.objects.iter().any(|o| o.name == meta.target) {
            return Err(bad(format!("the target {:?} is not one of the objects", meta.target)));
        }
        let opts = LoadOptions { masks: Masks::Off, ..Default::default() };
        let dataset = dataset::load(dir, &opts)?;
        let k = meta.supersample;
        let mut truths = Vec::with_capacity(dataset.cameras.len());
        for cam in &dataset.cameras {
            let (w, h) = (cam.width as usize, cam.height as usize);
            let stem = cam.stem();
            let edited_path = dir.join("edited").join(format!("{stem}.png"));
            let edited = image::read(&edited_path)?;
            if (edited.width, edited.height) != (w, h) {
                return Err(DemoError::Io(transsplat_scene::Error::format(
                    &edited_path,
                    format!("is {}x{}, the camera {w}x{h}", edited.width, edited.height),
                )));
            }
            let labels_path = dir.join("labels").join(format!("{stem}.png"));
            let labels = image::read(&labels_path)?;
            if (labels.width, labels.height) != (w * k, h * k) {
                return Err(DemoError::Io(transsplat_scene::Error::format(
                    &labels_path,
                    format!("is {}x{}, not {} times the camera's {w}x{h}", labels.width, labels.height, k),
                )));
            }
            // a grey PNG reads as three equal channels in [0, 1]
            let samples = labels.data.chunks_exact(3).map(|p| (p[0] * 255.0).round() as u8).collect();
            truths.push((edited.data, samples));
        }
        let num_labels = meta.objects.iter().map(|o| o.label as usize + 1).max().unwrap_or(2);
        let name = dir.file_name().map_or_else(|| "capture".into(), |n| n.to_string_lossy().into_owned());
        Ok(Capture { name, dir: dir.to_path_buf(), meta, dataset, truths, num_labels })
    }

    /// The true edit of camera `index` with its labels.
    pub fn truth(&self, index: usize) -> LabelRender {
        let cam = &self.dataset.cameras[index];
        let (rgb, samples) = &self.truths[index];
        let samples: Vec<u32> = samples.iter().map(|&l| l as u32).collect();
        let (w, h) = (cam.width as usize, cam.height as usize);
        LabelRender::from_samples(rgb.clone(), w, h, &samples, self.meta.supersample, self.num_labels)
    }

    fn label_of(&self, name: &str) -> u32 {
        self.meta.objects.iter().find(|o| o.name == name).map_or(0, |o| o.label)
    }

    /// The target's label.
    pub fn target(&self) -> u32 {
        self.label_of(&self.meta.target)
    }

    /// The instruction the cases pass on (the engine's prompt).
    pub fn prompt(&self) -> String {
        format!("recolour the {}", self.meta.target)
    }

    /// Mean colour per label over the pixels it labels in the training views, of the
    /// true edits (`edited`) or of the captured images.
    fn mean_colours(&self, edited: bool) -> Vec<[f32; 3]> {
        let (_, edit_views) = split_views(self.dataset.cameras.len());
        let mut sums = vec![[0.0f64; 4]; self.num_labels];
        for v in edit_views {
            let truth = self.truth(v);
            let captured;
            let rgb = if edited {
                &truth.rgb
            } else {
                captured = self.dataset_image(v);
                &captured
            };
            for (&l, px) in truth.labels.iter().zip(rgb.chunks_exact(3)) {
                let s = &mut sums[l as usize];
                for c in 0..3 {
                    s[c] += px[c] as f64;
                }
                s[3] += 1.0;
            }
        }
        sums.iter().map(|s| std::array::from_fn(|c| (s[c] / s[3].max(1.0)) as f32)).collect()
    }

    /// The captured image of camera `index`.
    fn dataset_image(&self, index: usize) -> Vec<f32> {
        let name = &self.dataset.cameras[index].name;
        self.dataset
            .train
            .iter()
            .chain(&self.dataset.test)
            .find(|v| &v.camera.name == name)
            .map(|v| v.image.clone())
            .expect("every camera has its view")
    }

    /// The corruption of this capture's edit at `severity`: see the module doc.
    pub fn corruption(&self, severity: f32, seed: u64) -> Corruption {
        let target = self.target();
        let others: Vec<u32> = self.meta.objects.iter().map(|o| o.label).filter(|&l| l != target).collect();
        let source = self.mean_colours(false);
        let dist = |a: [f32; 3], b: [f32; 3]| (0..3).map(|c| (a[c] - b[c]).powi(2)).sum::<f32>();
        let distractor = others.iter().copied().min_by(|&a, &b| {
            let (da, db) = (
                dist(source[a as usize], source[target as usize]),
                dist(source[b as usize], source[target as usize]),
            );
            da.total_cmp(&db)
        });
        Corruption {
            labels: vec![target],
            global: false,
            colour: self.mean_colours(true)[target as usize],
            distractor,
            others,
            severity: if severity.is_finite() { severity.max(0.0) } else { 0.0 },
            want_mask: false,
            seed,
        }
    }
}

/// The simulated editor of a capture: [`Corruption`] of each view's true edit.
#[derive(Clone)]
pub struct CaptureEditor<'a> {
    capture: &'a Capture,
    corruption: Corruption,
}

impl<'a> CaptureEditor<'a> {
    pub fn new(capture: &'a Capture, severity: f32, seed: u64) -> Self {
        CaptureEditor { capture, corruption: capture.corruption(severity, seed) }
    }
}

impl Editor for CaptureEditor<'_> {
    fn name(&self) -> &str {
        "simulated"
    }

    fn edit(
        &mut self,
        views: &[SourceView],
        _prompt: &str,
    ) -> Result<Vec<Option<EditedView>>, transsplat_editors::Error> {
        for v in views {
            v.check()?;
            if v.index >= self.capture.truths.len() {
                return Err(transsplat_editors::Error::Invalid(format!(
                    "view {} is not a camera of the capture {}",
                    v.index, self.capture.name
                )));
            }
        }
        Ok(views
            .par_iter()
            .map(|v| Some(self.corruption.edit_view(&self.capture.truth(v.index), v.image, v.index)))
            .collect())
    }
}

/// Trains `capture` for `steps` steps (see the module doc); returns the Gaussians and the
/// test PSNR.
pub fn train(
    capture: &Capture,
    steps: u64,
    seed: u64,
    cancel: Option<&AtomicBool>,
    on_step: &mut dyn FnMut(u64, u64),
) -> Result<(Gaussians, f32), DemoError> {
    let background = LoadOptions::default().background;
    let (g, psnr) =
        crate::trained::train_dataset(&capture.dataset, steps, seed, background, cancel, on_step)?;
    tracing::info!(
        "trained the capture {}: {steps} steps, {} Gaussians, test PSNR {psnr:.2} dB",
        capture.name,
        g.len()
    );
    Ok((g, psnr))
}

/// Runs every method on `capture`'s trained scene `trained` (its Gaussians and test
/// PSNR) at `opts.severity` into the folder `opts.out`, staged as the demo's.
pub fn run(
    capture: &Capture,
    trained: &(Gaussians, f32),
    opts: &DemoOptions,
    cancel: Option<&AtomicBool>,
    on_progress: &mut dyn FnMut(&str, Progress),
) -> Result<DemoOutcome, DemoError> {
    crate::demo::staged(&opts.out, |dir| run_into(dir, capture, trained, opts, cancel, on_progress))
}

fn run_into(
    dir: &Path,
    capture: &Capture,
    trained: &(Gaussians, f32),
    opts: &DemoOptions,
    cancel: Option<&AtomicBool>,
    on_progress: &mut dyn FnMut(&str, Progress),
) -> Result<CaseScores, DemoError> {
    let cameras = &capture.dataset.cameras;
    let (test, edit_views) =
        transsplat_session::views::split(cameras, opts.views).map_err(|e| DemoError::Views(e.to_string()))?;
    let background = LoadOptions::default().background;
    let target = [capture.target()];
    let truths: Vec<LabelRender> = test.iter().map(|&v| capture.truth(v)).collect();
    let captured: Vec<Vec<f32>> = test.iter().map(|&v| capture.dataset_image(v)).collect();
    let (source, psnr) = trained;
    let reference = Reference::from_images(test.clone(), captured, &truths, &target, background);
    let (target_psnr, background_psnr) = reference.fidelity(cameras, source);
    tracing::info!(
        "trained capture against its images: PSNR {target_psnr:.2} dB inside the target, {background_psnr:.2} dB \
         over the background"
    );
    let reference = reference.with_source(cameras, source);
    let fidelity = Fidelity { test_psnr: *psnr as f64, target_psnr, background_psnr, retrained: None };
    let editor = CaptureEditor::new(capture, opts.severity, opts.seed);
    let description =
        format!("{} of the capture {}, severity {}", capture.prompt(), capture.name, opts.severity);
    let truth_of = |v: usize| capture.truth(v);
    let case = CaseRun {
        scene: &capture.name,
        description: &description,
        cameras,
        source,
        edit_views,
        test,
        background,
        reference: &reference,
        target_labels: &target,
        // a trained scene's Gaussians carry no labels
        target_of: &|_: &Gaussians| Vec::new(),
        truth_of: &truth_of,
        trained: Some(fidelity),
    };
    let (scores, evidence) = crate::demo::run_case(dir, opts, &case, &editor, cancel, on_progress)?;
    Ok((scores, Some(fidelity), evidence))
}

#[cfg(test)]
mod tests {
    use super::*;
    use transsplat_builtin::{build, write_dataset, SceneConfig, WriteOptions};
    use transsplat_raster::{render, RenderOptions, Splats};

    /// A capture made from a built-in scene: its dataset (whose `masks/` hold each
    /// pixel's label: the label samples at one per pixel), the true recolour of the ball
    /// as `edited/`, and `capture.json`.
    fn capture_of_tabletop(dir: &Path) -> (transsplat_builtin::Scene, Gaussians) {
        let scene = build("tabletop", &SceneConfig::quick()).unwrap();
        write_dataset(&scene, dir, &WriteOptions::default(), &mut |_, _| {}).unwrap();
        let ball = scene.label_of("ball").unwrap();
        let truth = scene.recolor(ball, [0.1, 0.2, 0.9]).unwrap();
        std::fs::rename(dir.join("masks"), dir.join("labels")).unwrap();
        std::fs::create_dir(dir.join("edited")).unwrap();
        let splats = Splats::new(&truth);
        for cam in &scene.cameras {
            let img = render(&splats, cam, &RenderOptions { background: scene.background }).0.rgb;
            let path = dir.join("edited").join(format!("{}.png", cam.stem()));
            image::write_png(&path, cam.width as usize, cam.height as usize, &img).unwrap();
        }
        let objects: Vec<serde_json::Value> =
            scene.objects.iter().map(|o| serde_json::json!({"name": o.name, "label": o.label})).collect();
        let meta = serde_json::json!({"target": "ball", "objects": objects, "supersample": 1});
        std::fs::write(dir.join("capture.json"), meta.to_string()).unwrap();
        (scene, truth)
    }

    #[test]
    fn a_capture_is_corrupted_by_the_simulated_model_and_scored_against_its_images() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("tabletop");
        let (scene, truth) = capture_of_tabletop(&dir);
        let capture = Capture::load(&dir).unwrap();
        let ball = scene.label_of("ball").unwrap();
        assert_eq!(capture.target(), ball);
        let cameras = &capture.dataset.cameras;
        assert_eq!(cameras.len(), scene.cameras.len());
        let (test, edit) = split_views(cameras.len());
        let v = edit[0];
        let t = capture.truth(v);
        // one sample per pixel: the weights are the label's indicator
        assert_eq!(t.weight(ball), t.labels.iter().map(|&l| f32::from(l == ball)).collect::<Vec<_>>());
        assert!(t.labels.contains(&ball), "the ball is seen in view {v}");
        let source = capture.dataset_image(v);
        // severity 0 hands out the true edit exactly
        let exact = capture.corruption(0.0, 3).edit_view(&t, &source, v);
        assert_eq!(exact.image, t.rgb);
        // severity 2: the ball's colour changes, the distractor is another object
        let c = capture.corruption(2.0, 3);
        assert!(c.distractor.is_some_and(|d| d != ball) && !c.others.contains(&ball));
        assert!(c.colour[2] > c.colour[0] + 0.3, "the edit's mean colour is blue: {:?}", c.colour);
        let changed = c.edit_view(&t, &source, v);
        assert_ne!(changed.image, t.rgb);
        // the same view edited twice is the same (seeded by the view)
        assert_eq!(changed.image, c.edit_view(&t, &source, v).image);

        // scores: the true edit's Gaussians reproduce the edited images inside the target,
        // the unedited source leaves nothing changed outside it
        let truths: Vec<LabelRender> = test.iter().map(|&v| capture.truth(v)).collect();
        let captured = test.iter().map(|&v| capture.dataset_image(v)).collect();
        let reference = Reference::from_images(test.clone(), captured, &truths, &[ball], scene.background);
        let on_truth = reference.score(cameras, &truth);
        let on_source = reference.score(cameras, &scene.gaussians);
        assert!(on_truth.target_psnr > 40.0, "{on_truth:?}");
        assert!(on_source.target_psnr < 25.0, "{on_source:?}");
        assert!(on_source.background_psnr > 40.0, "{on_source:?}");
    }

    #[test]
    fn bad_captures_are_errors_naming_the_file() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("tabletop");
        capture_of_tabletop(&dir);
        let meta = dir.join("capture.json");
        let good = std::fs::read_to_string(&meta).unwrap();
        let err = |text: &str| {
            std::fs::write(&meta, text).unwrap();
            Capture::load(&dir).unwrap_err().to_string()
        };
        let e = err(&good.replace("\"target\":\"ball\"", "\"target\":\"kite\""));
        assert!(e.contains("capture.json") && e.contains("kite"), "{e}");
        let e = err(&good.replace("\"supersample\":1", "\"supersample\":0"));
        assert!(e.contains("capture.json") && e.contains("supersample"), "{e}");
        let e = err("[1, 2]");
        assert!(e.contains("capture.json"), "{e}");
        std::fs::write(&meta, good.replace("\"supersample\":1", "\"supersample\":2")).unwrap();
        let e = Capture::load(&dir).unwrap_err().to_string();
        assert!(e.contains("labels") && e.contains("2 times"), "{e}");
    }

    #[test]
    fn the_suite_never_writes_inside_a_capture() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("tabletop");
        capture_of_tabletop(&dir);
        let capture = Capture::load(&dir).unwrap();
        let before: Vec<_> = std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().file_name()).collect();
        for out in [dir.join("suite"), dir.clone()] {
            let opts = crate::quality::SuiteOptions {
                out: out.clone(),
                cases: Vec::new(),
                quick: true,
                methods: vec![transsplat_edit::Method::Transsplat],
                config: Default::default(),
                seed: 0,
                views: transsplat_session::views::ViewChoice::All,
                captures: vec![capture.clone()],
                segmenter: None,
            };
            let err = crate::quality::run(&opts, None, &mut |_, _, _| {}).unwrap_err().to_string();
            assert!(err.contains(&dir.display().to_string()), "{err}");
        }
        let after: Vec<_> = std::fs::read_dir(&dir).unwrap().map(|e| e.unwrap().file_name()).collect();
        assert_eq!(before, after, "nothing written into the capture");
    }
}
