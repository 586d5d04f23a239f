//! End-to-end tests of `transsplat render` and `transsplat info` through the binary.

use std::path::Path;
use std::process::Command;
use transsplat_raster::synthetic as bench;
use transsplat_raster::{render, RenderOptions, Splats};
use transsplat_scene::{cameras, image, npy, ply, Camera};

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_transsplat"))
}

fn cams() -> Vec<Camera> {
    let mut a = bench::bench_camera(40, 30);
    a.name = "view_a.png".into();
    let mut b = bench::bench_camera(40, 30);
    b.name = "sub/view_b.jpg".into();
    b.translation = [0.3, -0.1, 0.5];
    vec![a, b]
}

fn write_inputs(dir: &Path) -> (std::path::PathBuf, std::path::PathBuf) {
    let g = bench::bench_scene(3000, 1);
    let scene = dir.join("in/scene.ply");
    std::fs::create_dir_all(scene.parent().unwrap()).unwrap();
    ply::write(&scene, &g).unwrap();
    let cam_path = dir.join("in/cameras.json");
    cameras::inria::write(&cam_path, &cams()).unwrap();
    (scene, cam_path)
}

#[test]
fn render_writes_png_and_npy_matching_the_library() {
    let dir = tempfile::tempdir().unwrap();
    let (scene, cam_path) = write_inputs(dir.path());
    let before = std::fs::read(&scene).unwrap();
    let out = dir.path().join("out");
    let st = bin()
        .args(["render", "--scene"])
        .arg(&scene)
        .arg("--cameras")
        .arg(&cam_path)
        .arg("--out")
        .arg(&out)
        .args(["--raw", "--background", "0.2,0.4,0.6"])
        .status()
        .unwrap();
    assert!(st.success());
    assert_eq!(std::fs::read(&scene).unwrap(), before, "input modified");
    let g = ply::read(&scene).unwrap();
    for cam in cameras::inria::read(&cam_path).unwrap() {
        let (img, _) = render(&Splats::new(&g), &cam, &RenderOptions { background: [0.2, 0.4, 0.6] });
        let raw = npy::read(&out.join(format!("{}.npy", cam.stem()))).unwrap();
        assert_eq!(raw.shape, vec![30, 40, 3]);
        assert_eq!(raw.data, img.rgb);
        let png = image::read(&out.join(format!("{}.png", cam.stem()))).unwrap();
        for (a, b) in png.data.iter().zip(&img.rgb) {
            assert!((a - b.clamp(0.0, 1.0)).abs() <= 0.5 / 255.0 + 1e-6);
        }
    }
    let names: Vec<_> = std::fs::read_dir(&out).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(names.len(), 5, "{names:?}");
    assert!(names.iter().any(|n| n == "render.json"), "{names:?}");
}

#[test]
fn info_reports_count_and_degree() {
    let dir = tempfile::tempdir().unwrap();
    let (scene, _) = write_inputs(dir.path());
    let o = bin().args(["info", "--json"]).arg(&scene).output().unwrap();
    assert!(o.status.success());
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(v["gaussians"], 3000);
    assert_eq!(v["sh_degree"], 3);
    let text = bin().arg("info").arg(&scene).output().unwrap();
    assert!(String::from_utf8_lossy(&text.stdout).contains("gaussians    3000"));
}

/// `transsplat info SCENE | head`: a reader that closes the pipe before the output ends
/// the command quietly (SIGPIPE, as any Unix tool), not with a panic.
#[test]
fn info_into_a_closed_pipe_ends_quietly() {
    use std::os::unix::process::ExitStatusExt;
    let dir = tempfile::tempdir().unwrap();
    let (scene, _) = write_inputs(dir.path());
    let mut child = bin()
        .arg("info")
        .arg(&scene)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take()); // the reader is gone before anything is printed
    let o = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert_eq!(o.status.signal(), Some(libc::SIGPIPE), "{:?}: {stderr}", o.status);
}

#[test]
fn bad_inputs_exit_2_with_a_message_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let (scene, cam_path) = write_inputs(dir.path());
    let bytes = std::fs::read(&scene).unwrap();
    let trunc = dir.path().join("in/trunc.ply");
    std::fs::write(&trunc, &bytes[..bytes.len() / 2]).unwrap();
    let out = dir.path().join("out");
    let o = bin()
        .args(["render", "--scene"])
        .arg(&trunc)
        .arg("--cameras")
        .arg(&cam_path)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("trunc.ply"), "{err}");
    // Output folder equal to the input folder is refused.
    let o = bin()
        .args(["render", "--scene"])
        .arg(&scene)
        .arg("--cameras")
        .arg(&cam_path)
        .arg("--out")
        .arg(dir.path().join("in"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert_eq!(std::fs::read(&scene).unwrap(), bytes);
    // Bad background.
    let o = bin()
        .args(["render", "--scene"])
        .arg(&scene)
        .arg("--out")
        .arg(&out)
        .args(["--background", "2,0"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
}
