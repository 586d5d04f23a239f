//! Dataset loading: layouts, image conversions, the size rules and bad input.

use std::path::Path;
use transsplat_scene::cameras::inria;
use transsplat_scene::{image, Camera};
use transsplat_train::dataset::Masks;
use transsplat_train::{dataset, LoadOptions};

fn camera(name: &str, w: u32, h: u32, z: f32) -> Camera {
    let r = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    Camera::from_c2w(name.into(), w, h, 40.0, 40.0, w as f32 / 2.0, h as f32 / 2.0, r, [0.0, 0.0, z])
}

fn png(path: &Path, w: u32, h: u32, ct: png::ColorType, depth: png::BitDepth, data: &[u8]) {
    let f = std::fs::File::create(path).unwrap();
    let mut enc = png::Encoder::new(f, w, h);
    enc.set_color(ct);
    enc.set_depth(depth);
    enc.write_header().unwrap().write_image_data(data).unwrap();
}

/// An INRIA-layout folder with three views: RGB, grey+alpha 8-bit, RGBA 16-bit.
fn inria_folder(dir: &Path) {
    std::fs::create_dir_all(dir.join("images")).unwrap();
    let cams: Vec<Camera> = (0..3).map(|k| camera(&format!("v{k}"), 8, 6, -(k as f32))).collect();
    inria::write(&dir.join("cameras.json"), &cams).unwrap();
    image::write_png(&dir.join("images/v0.png"), 8, 6, &[0.5; 8 * 6 * 3]).unwrap();
    png(
        &dir.join("images/v1.png"),
        8,
        6,
        png::ColorType::GrayscaleAlpha,
        png::BitDepth::Eight,
        &[255, 0].repeat(48),
    );
    let px16: Vec<u8> = [0xFF, 0xFF, 0, 0, 0, 0, 0x80, 0x00].repeat(48);
    png(&dir.join("images/v2.png"), 8, 6, png::ColorType::Rgba, png::BitDepth::Sixteen, &px16);
}

#[test]
fn inria_layout_with_grey_alpha_and_16_bit_images() {
    let d = tempfile::tempdir().unwrap();
    inria_folder(d.path());
    let bg = [0.0, 0.0, 1.0];
    let ds = dataset::load(d.path(), &LoadOptions { background: bg, ..Default::default() }).unwrap();
    assert_eq!(ds.kind, dataset::DatasetKind::Inria);
    assert_eq!((ds.train.len(), ds.test.len()), (2, 1));
    assert_eq!(ds.test[0].camera.name, "v0");
    assert!(ds.points.is_none(), "no input.ply: random initialisation");
    // Grey with alpha 0: entirely background.
    assert_eq!(&ds.train[0].image[..3], &bg);
    // 16-bit red at alpha 0.5 over blue.
    let p = &ds.train[1].image[..3];
    assert!((p[0] - 0.5).abs() < 1e-3 && p[1].abs() < 1e-6 && (p[2] - 0.5).abs() < 1e-3, "{p:?}");
}

#[test]
fn downscale_and_prescaled_images() {
    let d = tempfile::tempdir().unwrap();
    inria_folder(d.path());
    let ds = dataset::load(d.path(), &LoadOptions { resolution: 2, ..Default::default() }).unwrap();
    let c = &ds.train[0].camera;
    assert_eq!((c.width, c.height, c.fx, c.cx), (4, 3, 20.0, 2.0));
    assert_eq!(ds.train[0].image.len(), 4 * 3 * 3);
    assert_eq!(ds.cameras[0].width, 8, "output cameras keep the original resolution");
    // An image at half the camera's size (same aspect) is accepted with rescaled intrinsics.
    image::write_png(&d.path().join("images/v1.png"), 4, 3, &[0.25; 4 * 3 * 3]).unwrap();
    let ds = dataset::load(d.path(), &LoadOptions::default()).unwrap();
    let c = &ds.train[0].camera;
    assert_eq!((c.width, c.height, c.fx), (4, 3, 20.0));
}

#[test]
fn bad_images_are_errors_naming_the_file() {
    let d = tempfile::tempdir().unwrap();
    inria_folder(d.path());
    image::write_png(&d.path().join("images/v1.png"), 8, 8, &[0.25; 8 * 8 * 3]).unwrap();
    let e = dataset::load(d.path(), &LoadOptions::default()).unwrap_err().to_string();
    assert!(e.contains("v1.png") && e.contains("8x8") && e.contains("8x6"), "{e}");
    std::fs::write(d.path().join("images/v1.png"), b"not an image").unwrap();
    let e = dataset::load(d.path(), &LoadOptions::default()).unwrap_err().to_string();
    assert!(e.contains("v1.png") && e.contains("not a PNG or JPEG"), "{e}");
    std::fs::remove_file(d.path().join("images/v1.png")).unwrap();
    let e = dataset::load(d.path(), &LoadOptions::default()).unwrap_err().to_string();
    assert!(e.contains("v1") && e.contains("missing"), "{e}");
    let e = dataset::load(&d.path().join("images"), &LoadOptions::default()).unwrap_err().to_string();
    assert!(e.contains("no dataset found"), "{e}");
}

#[test]
fn transforms_with_point_cloud_and_masks() {
    let d = tempfile::tempdir().unwrap();
    let dir = d.path();
    std::fs::create_dir_all(dir.join("images")).unwrap();
    std::fs::create_dir_all(dir.join("masks")).unwrap();
    let mut frames = Vec::new();
    for k in 0..2 {
        image::write_png(&dir.join(format!("images/f{k}.png")), 4, 2, &[0.5; 24]).unwrap();
        frames.push(serde_json::json!({
            "file_path": format!("images/f{k}.png"),
            "transform_matrix": [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, k], [0, 0, 0, 1]],
        }));
    }
    png(
        &dir.join("masks/f1.png"),
        4,
        2,
        png::ColorType::Grayscale,
        png::BitDepth::Eight,
        &[0, 255, 255, 0, 0, 0, 0, 255],
    );
    let t = serde_json::json!({"fl_x": 5.0, "w": 4, "h": 2, "frames": frames, "ply_file_path": "points.ply"});
    std::fs::write(dir.join("transforms.json"), t.to_string()).unwrap();
    let ply =
        "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n\
property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n0 0 1 255 0 0\n1 1 2 0 0 255\n";
    std::fs::write(dir.join("points.ply"), ply).unwrap();
    let mask = Some(&[0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0][..]);
    // A masks/ folder alone is not used.
    let ds = dataset::load(dir, &LoadOptions::default()).unwrap();
    assert_eq!(ds.kind, dataset::DatasetKind::Transforms);
    assert_eq!(ds.points.as_ref().unwrap().len(), 2);
    assert!(ds.train[0].weights.is_none() && ds.test[0].weights.is_none());
    // Asked for: every view needs one (test view f0 has none).
    let folder = LoadOptions { masks: Masks::Folder(dir.join("masks")), ..Default::default() };
    let e = dataset::load(dir, &folder).unwrap_err().to_string();
    assert!(e.contains("masks") && e.contains("no mask for camera \"images/f0.png\""), "{e}");
    image::write_png(&dir.join("masks/f0.png"), 4, 2, &[1.0; 24]).unwrap();
    let ds = dataset::load(dir, &folder).unwrap();
    assert_eq!(ds.train[0].weights.as_deref(), mask);
    assert_eq!(ds.test[0].weights.as_deref(), Some(&[1.0; 8][..]));
    // Declared per frame (transforms.json mask_path): used by default, off with Masks::Off.
    let mut t2 = t.clone();
    t2["frames"][1]["mask_path"] = "masks/f1.png".into();
    std::fs::write(dir.join("transforms.json"), t2.to_string()).unwrap();
    let ds = dataset::load(dir, &LoadOptions::default()).unwrap();
    assert_eq!(ds.train[0].weights.as_deref(), mask);
    assert!(ds.test[0].weights.is_none());
    let ds = dataset::load(dir, &LoadOptions { masks: Masks::Off, ..Default::default() }).unwrap();
    assert!(ds.train[0].weights.is_none());
    t2["frames"][1]["mask_path"] = 3.into();
    std::fs::write(dir.join("transforms.json"), t2.to_string()).unwrap();
    let e = dataset::load(dir, &LoadOptions::default()).unwrap_err().to_string();
    assert!(e.contains("transforms.json") && e.contains("\"mask_path\" is not a file name"), "{e}");
    std::fs::write(dir.join("transforms.json"), t.to_string()).unwrap();
    // An empty point cloud falls back to random initialisation.
    std::fs::write(dir.join("points.ply"), "ply\nformat ascii 1.0\nelement vertex 0\nproperty float x\nproperty float y\nproperty float z\nend_header\n").unwrap();
    assert!(dataset::load(dir, &LoadOptions::default()).unwrap().points.is_none());
    std::fs::write(dir.join("points.ply"), "garbage").unwrap();
    let e = dataset::load(dir, &LoadOptions::default()).unwrap_err().to_string();
    assert!(e.contains("points.ply"), "{e}");
}
