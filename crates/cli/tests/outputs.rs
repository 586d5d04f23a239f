//! One rule for every command's output: an output that is an input, contains an input,
//! or lies inside an input dataset's folders is refused before anything is written
//! (exit 2, one line naming both paths), and the inputs are left byte for byte.

mod common;
use common::*;
use std::collections::BTreeMap;
use std::path::Path;

/// Every file below `dir` with its bytes.
fn snapshot(dir: &Path) -> BTreeMap<String, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap().flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
            } else {
                out.insert(p.display().to_string(), std::fs::read(&p).unwrap());
            }
        }
    }
    out
}

#[test]
fn outputs_over_inputs_are_refused_by_every_command() {
    let dir = tempfile::tempdir().unwrap();
    let ds = quick_scene(dir.path());
    let d = |p: &str| dir.path().join(p).display().to_string();
    let ply = d("ds/point_cloud/iteration_0/point_cloud.ply");
    let cams = d("ds/cameras.json");
    for name in ["c.npy", "a.npy", "b.npy"] {
        let (shape, data): (Vec<usize>, Vec<f32>) =
            if name == "c.npy" { (vec![3, 2], vec![1.0; 6]) } else { (vec![3], vec![1.0 / 3.0; 3]) };
        let shape = if name == "b.npy" { vec![2] } else { shape };
        let data = if name == "b.npy" { vec![0.5; 2] } else { data };
        transsplat_scene::npy::write(&dir.path().join(name), &shape, &data).unwrap();
    }
    std::fs::create_dir(dir.path().join("weights")).unwrap();
    std::fs::write(dir.path().join("weights/config.json"), b"{}").unwrap();
    std::fs::create_dir(dir.path().join("masks")).unwrap();
    std::fs::write(dir.path().join("masks/view_001.png"), b"not read").unwrap();
    let before = snapshot(dir.path());
    let cases: Vec<(Vec<String>, &str, &str)> = vec![
        (vec!["render".into(), "--scene".into(), d("ds"), "--out".into(), d("ds/images")], "ds/images", "ds"),
        (
            vec![
                "render".into(),
                "--scene".into(),
                ply.clone(),
                "--cameras".into(),
                cams.clone(),
                "--out".into(),
                d("ds/images/x"),
            ],
            "ds/images/x",
            "cameras.json",
        ),
        (
            vec![
                "render".into(),
                "--scene".into(),
                d("ds"),
                "--out".into(),
                dir.path().display().to_string(),
            ],
            "",
            "contains",
        ),
        (
            vec!["views".into(), "export".into(), "--scene".into(), d("ds"), "--out".into(), d("ds/views")],
            "ds/views",
            "ds",
        ),
        (vec!["train".into(), "--data".into(), d("ds"), "--out".into(), d("ds/trained")], "ds/trained", "ds"),
        (
            vec![
                "edit".into(),
                "--scene".into(),
                d("ds"),
                "--prompt".into(),
                "make the ball blue".into(),
                "--editor".into(),
                "simulated".into(),
                "--out".into(),
                d("ds/edit"),
            ],
            "ds/edit",
            "ds",
        ),
        (
            [
                "edit",
                "--scene",
                "ds",
                "--prompt",
                "make the ball blue",
                "--editor",
                "simulated",
                "--dino-weights",
                "weights",
                "--out",
                "weights/edit",
            ]
            .map(|a| if a == "ds" || a.starts_with("weights") { d(a) } else { a.to_string() })
            .to_vec(),
            "weights/edit",
            "weights",
        ),
        (
            [
                "edit",
                "--scene",
                "ds",
                "--prompt",
                "make the ball blue",
                "--editor",
                "simulated",
                "--masks",
                "masks",
                "--out",
                "masks/edit",
            ]
            .map(|a| if a == "ds" || a.starts_with("masks") { d(a) } else { a.to_string() })
            .to_vec(),
            "masks/edit",
            "masks",
        ),
        (
            [
                "uot", "--cost", "c.npy", "--source", "a.npy", "--target", "b.npy", "--eps", "0.1",
                "--tau-s", "1", "--tau-t", "1", "--out", "c.npy",
            ]
            .map(|a| if a.ends_with(".npy") { d(a) } else { a.to_string() })
            .to_vec(),
            "c.npy",
            "is the input",
        ),
    ];
    for (args, out, needle) in cases {
        let o = bin().args(&args).output().unwrap();
        let msg = String::from_utf8_lossy(&o.stderr);
        let err = msg.lines().filter(|l| l.starts_with("error:")).collect::<Vec<_>>();
        assert_eq!(o.status.code(), Some(2), "{args:?}: {}", text(&o));
        assert!(err.len() == 1 && err[0].contains(out) && err[0].contains(needle), "{args:?}: {msg}");
        assert_eq!(snapshot(dir.path()), before, "{args:?} changed the inputs");
    }
    assert!(ds.join("images").is_dir());
}
