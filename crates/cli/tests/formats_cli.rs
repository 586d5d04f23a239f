//! `convert`, `view` and `edit --format` through the binary: every format round-trips
//! the scene within its quantisation (renders compared), the viewer page is
//! self-contained, and edit writes the web formats beside its PLY.

mod common;
use common::{bin, ok, quick_scene};
use transsplat_raster::{render, RenderOptions, Splats};
use transsplat_scene::{cameras, formats, Camera, Gaussians};

fn psnr(a: &[f32], b: &[f32]) -> f64 {
    let mse =
        a.iter().zip(b).map(|(x, y)| ((x.clamp(0.0, 1.0) - y.clamp(0.0, 1.0)) as f64).powi(2)).sum::<f64>()
            / a.len() as f64;
    10.0 * (1.0 / mse.max(1e-12)).log10()
}

/// Mean render PSNR of `b` against `a` over the cameras.
fn render_psnr(a: &Gaussians, b: &Gaussians, cams: &[Camera]) -> f64 {
    let o = RenderOptions { background: [0.0; 3] };
    let (sa, sb) = (Splats::new(a), Splats::new(b));
    cams.iter().map(|c| psnr(&render(&sa, c, &o).0.rgb, &render(&sb, c, &o).0.rgb)).sum::<f64>()
        / cams.len() as f64
}

#[test]
fn convert_round_trips_every_format_within_its_quantisation() {
    let d = tempfile::tempdir().unwrap();
    let ds = quick_scene(d.path());
    let src = ds.join("point_cloud/iteration_0/point_cloud.ply");
    let g = formats::read(&src).unwrap();
    let cams = cameras::load(&ds.join("cameras.json")).unwrap();
    // PSNR floors: float32 PLY is exact; the 8-bit colour of the compressed formats
    // bounds them (measured 52 dB compressed PLY, 48.7 dB SPZ on the default tabletop);
    // glTF holds float32 (only scale and opacity pass through exp / sigmoid and back);
    // SOG's 16-bit centres and codebooks (measured 61.6 dB on the default tabletop).
    for (name, floor) in
        [("a.ply", 119.0), ("a.compressed.ply", 45.0), ("a.spz", 42.0), ("a.glb", 100.0), ("a.sog", 38.0)]
    {
        let out = d.path().join(name);
        ok(&bin().arg("convert").arg(&src).arg(&out).output().unwrap());
        let back = formats::read(&out).unwrap();
        assert_eq!(back.len(), g.len(), "{name}");
        let p = render_psnr(&g, &back, &cams);
        assert!(p >= floor, "{name}: {p:.1} dB < {floor}");
        // And back to a plain PLY from the compressed file.
        let again = d.path().join(format!("{name}.back.ply"));
        ok(&bin().arg("convert").arg(&out).arg(&again).output().unwrap());
        assert_eq!(formats::read(&again).unwrap().len(), g.len());
    }
    // Cameras to INRIA JSON.
    let cj = d.path().join("cams.json");
    let o = bin()
        .args(["convert"])
        .arg(&src)
        .arg(d.path().join("b.spz"))
        .arg("--cameras")
        .arg(ds.join("sparse/0"))
        .arg("--cameras-out")
        .arg(&cj)
        .output()
        .unwrap();
    ok(&o);
    assert_eq!(cameras::load(&cj).unwrap().len(), cams.len());
}

#[test]
fn view_writes_a_self_contained_page_with_the_cameras() {
    let d = tempfile::tempdir().unwrap();
    let ds = quick_scene(d.path());
    let page = d.path().join("page.html");
    ok(&bin().arg("view").arg(&ds).arg("--out").arg(&page).args(["--layer", "label"]).output().unwrap());
    let html = std::fs::read_to_string(&page).unwrap();
    assert!(html.contains("class=\"ts-viewer\"") && html.contains("ts-blob"));
    // Offline: no external script, style or fetch.
    for bad in ["<script src", "<link", "http://", "https://"] {
        assert!(!html.contains(bad), "page contains {bad:?}");
    }
    let cams = cameras::load(&ds.join("cameras.json")).unwrap();
    assert_eq!(html.matches("\"role\":\"train\"").count(), cams.len());
    assert!(html.contains("\"kind\":\"label\""));
    // A scene without cameras gets an overview camera.
    let lone = d.path().join("lone.spz");
    ok(&bin().arg("convert").arg(&ds).arg(&lone).output().unwrap());
    let page2 = d.path().join("lone.html");
    ok(&bin().arg("view").arg(&lone).arg("--out").arg(&page2).output().unwrap());
    assert!(std::fs::read_to_string(&page2).unwrap().contains("\"name\":\"overview\""));
}

#[test]
fn edit_writes_the_requested_formats_and_a_report_with_the_viewer() {
    let d = tempfile::tempdir().unwrap();
    let ds = quick_scene(d.path());
    let out = d.path().join("out");
    let o = bin()
        .args(["edit", "--editor", "simulated", "--prompt", "make the ball blue", "--steps", "20"])
        .args(["--format", "spz,compressed-ply", "--scene"])
        .arg(&ds)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    ok(&o);
    let pc = out.join("point_cloud/iteration_20");
    let ply = formats::read(&pc.join("point_cloud.ply")).unwrap();
    for f in ["point_cloud.spz", "point_cloud.compressed.ply"] {
        assert_eq!(formats::read(&pc.join(f)).unwrap().len(), ply.len(), "{f}");
    }
    let report = std::fs::read_to_string(out.join("report.html")).unwrap();
    for want in ["ts-viewer", "gate γ", "transported support", "target (ground truth)", "\"role\":\"test\""]
    {
        assert!(report.contains(want), "report lacks {want:?}");
    }
}
