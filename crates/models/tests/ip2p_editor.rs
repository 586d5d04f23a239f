//! The InstructPix2Pix editor on the tiny fixture pipeline (tools/model_fixtures_ip2p.py):
//! prompt encoding against transformers, views of any size edited back at their size,
//! seeded reproducibility, empty prompts and missing weights.

use std::path::{Path, PathBuf};

use candle_core::Device;
use transsplat_editors::{Editor, Error as EditError, SourceView};
use transsplat_models::ip2p::{Ip2pEditor, Settings};
use transsplat_scene::Camera;

fn fixtures() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/ip2p")
}

fn editor(seed: u64) -> Ip2pEditor<'static> {
    let settings = Settings { steps: 3, ..Settings::default() };
    Ip2pEditor::load(&fixtures(), settings, seed, &Device::Cpu).unwrap().with_progress(false)
}

fn camera(name: &str, w: u32, h: u32) -> Camera {
    Camera { translation: [0.0, 0.0, 3.0], ..Camera::pinhole(name, w, h, w as f32) }
}

fn image(w: usize, h: usize, phase: f32) -> Vec<f32> {
    (0..w * h * 3).map(|i| 0.5 + 0.4 * ((i as f32) * 0.013 + phase).sin()).collect()
}

#[test]
fn prompt_embeddings_match_transformers() {
    let r = candle_core::safetensors::load(fixtures().join("reference.safetensors"), &Device::Cpu).unwrap();
    let e = editor(0).encode_prompt("turn the chair into bronze").unwrap();
    for (got, want) in [(&e.cond, &r["edit.prompt_embeds"]), (&e.uncond, &r["edit.uncond_embeds"])] {
        let d = (got - want).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f32>().unwrap();
        let s = want.abs().unwrap().max_all().unwrap().to_scalar::<f32>().unwrap();
        assert!(d <= 1e-4 * s, "text encoder: max error {d:e} vs scale {s:e}");
    }
}

#[test]
fn views_are_edited_at_their_size_reproducibly() {
    let cams = [camera("a.png", 36, 50), camera("b.png", 24, 16)];
    let imgs = [image(36, 50, 0.0), image(24, 16, 1.0)];
    let views: Vec<SourceView> = cams
        .iter()
        .zip(&imgs)
        .enumerate()
        .map(|(index, (camera, image))| SourceView { index, camera, image })
        .collect();
    let run = |seed| editor(seed).edit(&views, "turn the chair into bronze").unwrap();
    let a = run(7);
    assert_eq!(a.len(), 2);
    for (v, (cam, src)) in a.iter().zip(cams.iter().zip(&imgs)) {
        let v = v.as_ref().expect("every view is edited");
        let (w, h) = (cam.width as usize, cam.height as usize);
        assert_eq!((v.width, v.height, v.image.len(), v.attention.len()), (w, h, w * h * 3, w * h));
        assert!(v.image.iter().all(|x| (0.0..=1.0).contains(x)));
        assert!(v.attention.iter().all(|x| x.is_finite() && *x >= 0.0));
        assert!(v.attention.iter().any(|&x| x > 0.0), "text guidance leaves no trace");
        assert!(v.image.iter().zip(src).any(|(x, y)| (x - y).abs() > 1e-3), "image unchanged");
    }
    assert_eq!(a, run(7), "same seed, same edit");
    assert_ne!(a[0].as_ref().unwrap().image, run(8)[0].as_ref().unwrap().image, "seed unused");
}

#[test]
fn empty_prompt_is_refused() {
    let cam = camera("a.png", 16, 16);
    let img = image(16, 16, 0.0);
    let views = [SourceView { index: 0, camera: &cam, image: &img }];
    match editor(0).edit(&views, "  ") {
        Err(EditError::Instruction(m)) => assert!(m.contains("empty"), "{m}"),
        other => panic!("expected an instruction error, got {other:?}"),
    }
}

#[test]
fn wrong_image_size_is_an_error() {
    let cam = camera("a.png", 16, 16);
    let img = image(8, 8, 0.0);
    let views = [SourceView { index: 0, camera: &cam, image: &img }];
    assert!(matches!(editor(0).edit(&views, "make it red"), Err(EditError::Invalid(_))));
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let target = to.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &target);
        } else {
            std::fs::copy(e.path(), target).unwrap();
        }
    }
}

#[test]
fn missing_weights_name_folder_file_and_download_command() {
    let tmp = tempfile::tempdir().unwrap();
    let load =
        |p: &Path| Ip2pEditor::load(p, Settings::default(), 0, &Device::Cpu).err().unwrap().to_string();

    let missing = tmp.path().join("nowhere");
    let err = load(&missing);
    assert!(err.contains("nowhere") && err.contains("hf download timbrooks/instruct-pix2pix"), "{err}");

    let dir = tmp.path().join("ip2p");
    copy_dir(&fixtures(), &dir);
    std::fs::remove_file(dir.join("unet/diffusion_pytorch_model.fp16.safetensors")).unwrap();
    let err = load(&dir);
    assert!(
        err.contains("unet")
            && err.contains("diffusion_pytorch_model.safetensors")
            && err.contains(&format!("hf download timbrooks/instruct-pix2pix --local-dir {}", dir.display())),
        "{err}"
    );

    std::fs::remove_dir_all(dir.join("text_encoder")).unwrap();
    let err = load(&dir);
    assert!(err.contains("text_encoder") && err.contains("hf download"), "{err}");
}

#[test]
fn bad_settings_are_refused() {
    let bad = Settings { t_min: 0.9, t_max: 0.5, ..Settings::default() };
    let err = Ip2pEditor::load(&fixtures(), bad, 0, &Device::Cpu).err().unwrap().to_string();
    assert!(err.contains("t_min"), "{err}");
}

/// Views batched into one pipeline call come out as each view edited alone; a view of
/// another size goes to its own batch.
#[test]
fn batched_views_edit_as_one_view_per_call() {
    let cams =
        [camera("a.png", 24, 16), camera("b.png", 24, 16), camera("c.png", 16, 16), camera("d.png", 24, 16)];
    let imgs = [image(24, 16, 0.0), image(24, 16, 1.0), image(16, 16, 2.0), image(24, 16, 3.0)];
    let views: Vec<SourceView> = cams
        .iter()
        .zip(&imgs)
        .enumerate()
        .map(|(index, (camera, image))| SourceView { index, camera, image })
        .collect();
    let prompt = "turn the chair into bronze";
    let one = editor(5).edit(&views, prompt).unwrap();
    let batched = editor(5).with_batch(3).edit(&views, prompt).unwrap();
    assert_eq!(one.len(), 4);
    for (k, (a, b)) in one.iter().zip(&batched).enumerate() {
        let (a, b) = (a.as_ref().unwrap(), b.as_ref().unwrap());
        assert_eq!((a.width, a.height), (b.width, b.height), "view {k}");
        let err = a.image.iter().zip(&b.image).fold(0f32, |m, (x, y)| m.max((x - y).abs()));
        assert!(err < 1e-4, "view {k}: batched image differs by {err}");
        let scale = a.attention.iter().fold(0f32, |m, v| m.max(v.abs()));
        let err = a.attention.iter().zip(&b.attention).fold(0f32, |m, (x, y)| m.max((x - y).abs()));
        assert!(
            err <= 1e-4 * scale.max(1e-6),
            "view {k}: batched attention differs by {err} (scale {scale})"
        );
    }
}
