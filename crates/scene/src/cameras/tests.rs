use super::colmap::{read_sparse, ColmapModel, Point3D};
use super::*;
use std::path::Path;

// ---------------------------------------------------------------- helpers

type Cam = (u32, i32, &'static str, u64, u64, Vec<f64>);
type Img = (u32, [f64; 4], [f64; 3], u32, &'static str);
type Pts = Vec<([f64; 3], [u8; 3])>;

fn write_bin(dir: &Path, cams: &[Cam], imgs: &[Img], pts: &[([f64; 3], [u8; 3])]) {
    let mut b = Vec::new();
    b.extend_from_slice(&(cams.len() as u64).to_le_bytes());
    for (id, model, _, w, h, params) in cams {
        b.extend_from_slice(&id.to_le_bytes());
        b.extend_from_slice(&model.to_le_bytes());
        b.extend_from_slice(&w.to_le_bytes());
        b.extend_from_slice(&h.to_le_bytes());
        for p in params {
            b.extend_from_slice(&p.to_le_bytes());
        }
    }
    std::fs::write(dir.join("cameras.bin"), b).unwrap();
    let mut b = Vec::new();
    b.extend_from_slice(&(imgs.len() as u64).to_le_bytes());
    for (k, (id, q, t, cam, name)) in imgs.iter().enumerate() {
        b.extend_from_slice(&id.to_le_bytes());
        for v in q.iter().chain(t) {
            b.extend_from_slice(&v.to_le_bytes());
        }
        b.extend_from_slice(&cam.to_le_bytes());
        b.extend_from_slice(name.as_bytes());
        b.push(0);
        b.extend_from_slice(&(k as u64).to_le_bytes()); // k 2D points
        for j in 0..k {
            b.extend_from_slice(&(j as f64).to_le_bytes());
            b.extend_from_slice(&1.5f64.to_le_bytes());
            b.extend_from_slice(&(-1i64).to_le_bytes());
        }
    }
    std::fs::write(dir.join("images.bin"), b).unwrap();
    let mut b = Vec::new();
    b.extend_from_slice(&(pts.len() as u64).to_le_bytes());
    for (i, (xyz, rgb)) in pts.iter().enumerate() {
        b.extend_from_slice(&(i as u64 + 1).to_le_bytes());
        for v in xyz {
            b.extend_from_slice(&v.to_le_bytes());
        }
        b.extend_from_slice(rgb);
        b.extend_from_slice(&0.5f64.to_le_bytes());
        b.extend_from_slice(&2u64.to_le_bytes());
        for v in [1i32, 0, 2, 5] {
            b.extend_from_slice(&v.to_le_bytes());
        }
    }
    std::fs::write(dir.join("points3D.bin"), b).unwrap();
}

fn write_txt(dir: &Path, cams: &[Cam], imgs: &[Img], pts: &[([f64; 3], [u8; 3])]) {
    let mut s = String::from(
        "# Camera list with one line of data per camera:\n#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n",
    );
    for (id, _, model, w, h, params) in cams {
        let p: Vec<String> = params.iter().map(|v| format!("{v:?}")).collect();
        s.push_str(&format!("{id} {model} {w} {h} {}\n", p.join(" ")));
    }
    std::fs::write(dir.join("cameras.txt"), s).unwrap();
    let mut s = String::from("# Image list with two lines of data per image:\n\n");
    for (k, (id, q, t, cam, name)) in imgs.iter().enumerate() {
        s.push_str(&format!(
            "{id} {:?} {:?} {:?} {:?} {:?} {:?} {:?} {cam} {name}\n",
            q[0], q[1], q[2], q[3], t[0], t[1], t[2]
        ));
        // An empty 2D-point line for the first image, as COLMAP writes it.
        let pts: Vec<String> = (0..k).map(|j| format!("{j}.0 1.5 -1")).collect();
        s.push_str(&format!("{}\n", pts.join(" ")));
    }
    std::fs::write(dir.join("images.txt"), s).unwrap();
    let mut s = String::from("# 3D point list\n");
    for (i, (xyz, rgb)) in pts.iter().enumerate() {
        s.push_str(&format!(
            "{} {:?} {:?} {:?} {} {} {} 0.5 1 0 2 5\n",
            i + 1,
            xyz[0],
            xyz[1],
            xyz[2],
            rgb[0],
            rgb[1],
            rgb[2]
        ));
    }
    std::fs::write(dir.join("points3D.txt"), s).unwrap();
}

const S: f64 = std::f64::consts::FRAC_1_SQRT_2;

fn model() -> (Vec<Cam>, Vec<Img>, Pts) {
    let cams = vec![
        (1, 1, "PINHOLE", 640, 480, vec![500.0, 510.0, 320.5, 240.25]),
        (7, 2, "SIMPLE_RADIAL", 100, 50, vec![80.0, 50.0, 25.0, 0.0]),
        (3, 4, "OPENCV", 64, 48, vec![60.0, 61.0, 32.0, 24.0, 0.0, 0.0, 0.0, 0.0]),
    ];
    let imgs = vec![
        // 90 degrees about z: R = [[0,-1,0],[1,0,0],[0,0,1]]; centre = -R^T t = (-2, 1, -3).
        (5, [S, 0.0, 0.0, S], [1.0, 2.0, 3.0], 1, "c.jpg"),
        (2, [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, 4.0], 7, "a.jpg"),
        (9, [2.0, 0.0, 0.0, 0.0], [1.0, 1.0, 1.0], 3, "b.jpg"),
    ];
    let pts = vec![([0.5, -1.0, 2.0], [255, 0, 7]), ([3.0, 2.0, 1.0], [1, 2, 3])];
    (cams, imgs, pts)
}

fn close(a: &[f32], b: &[f32], tol: f32) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| (x - y).abs() <= tol)
}

fn err_of<T: std::fmt::Debug>(r: crate::Result<T>) -> String {
    r.expect_err("expected an error").to_string()
}

// ---------------------------------------------------------------- COLMAP

#[test]
fn colmap_bin_and_txt_agree_with_hand_computed_values() {
    let (cams, imgs, pts) = model();
    let bin = tempfile::tempdir().unwrap();
    let txt = tempfile::tempdir().unwrap();
    write_bin(bin.path(), &cams, &imgs, &pts);
    write_txt(txt.path(), &cams, &imgs, &pts);
    let a = read_sparse(bin.path()).unwrap();
    let b = read_sparse(txt.path()).unwrap();
    assert_eq!(a, b);
    let names: Vec<_> = a.cameras.iter().map(|c| c.name.as_str()).collect();
    assert_eq!(names, ["a.jpg", "b.jpg", "c.jpg"]);
    let c = &a.cameras[2];
    assert!(close(&c.centre(), &[-2.0, 1.0, -3.0], 1e-6), "{:?}", c.centre());
    assert!(close(&c.rotation.concat(), &[0., -1., 0., 1., 0., 0., 0., 0., 1.], 1e-7));
    assert_eq!((c.width, c.height, c.fx, c.fy, c.cx, c.cy), (640, 480, 500.0, 510.0, 320.5, 240.25));
    let simple = &a.cameras[0];
    assert_eq!((simple.fx, simple.fy, simple.cx, simple.cy), (80.0, 80.0, 50.0, 25.0));
    assert!(close(&simple.centre(), &[0.0, 0.0, -4.0], 0.0));
    // Unnormalised quaternion (2,0,0,0) is the identity.
    assert_eq!(a.cameras[1].rotation, [[1., 0., 0.], [0., 1., 0.], [0., 0., 1.]]);
    assert_eq!(
        a.points,
        vec![
            Point3D { xyz: [0.5, -1.0, 2.0], rgb: [255, 0, 7] },
            Point3D { xyz: [3.0, 2.0, 1.0], rgb: [1, 2, 3] }
        ]
    );
    // The same model through load(): a dataset folder with sparse/0.
    let ds = tempfile::tempdir().unwrap();
    let sparse = ds.path().join("sparse").join("0");
    std::fs::create_dir_all(&sparse).unwrap();
    write_bin(&sparse, &cams, &imgs, &pts);
    assert_eq!(load(ds.path()).unwrap(), a.cameras);
    assert_eq!(load(&sparse).unwrap(), a.cameras);
}

#[test]
fn colmap_without_points_is_allowed() {
    let (cams, imgs, pts) = model();
    let d = tempfile::tempdir().unwrap();
    write_txt(d.path(), &cams, &imgs, &pts);
    std::fs::remove_file(d.path().join("points3D.txt")).unwrap();
    let m: ColmapModel = read_sparse(d.path()).unwrap();
    assert!(m.points.is_empty());
    assert_eq!(m.cameras.len(), 3);
}

/// Points with NaN or infinite coordinates are dropped (bin and txt), the rest kept;
/// the bytes entry point gives the same model as reading the folder.
#[test]
fn colmap_non_finite_points_are_dropped_and_bytes_match_files() {
    let (cams, imgs, mut pts) = model();
    pts.insert(0, ([f64::NAN, 0.0, 0.0], [9, 9, 9]));
    pts.push(([0.0, f64::INFINITY, 0.0], [8, 8, 8]));
    for (write, ext) in
        [(write_bin as fn(&Path, &[Cam], &[Img], &[([f64; 3], [u8; 3])]), "bin"), (write_txt, "txt")]
    {
        let d = tempfile::tempdir().unwrap();
        write(d.path(), &cams, &imgs, &pts);
        let m = read_sparse(d.path()).unwrap();
        let rgb: Vec<[u8; 3]> = m.points.iter().map(|p| p.rgb).collect();
        assert_eq!(rgb, [[255, 0, 7], [1, 2, 3]], "{ext}");
        let file = |stem: &str| {
            (
                d.path().join(format!("{stem}.{ext}")),
                std::fs::read(d.path().join(format!("{stem}.{ext}"))).unwrap(),
            )
        };
        let (c, i, p) = (file("cameras"), file("images"), file("points3D"));
        let from_bytes =
            colmap::parse_model((&c.0, &c.1), (&i.0, &i.1), Some((p.0.as_path(), p.1.as_slice()))).unwrap();
        assert_eq!(from_bytes, m, "{ext}");
    }
}

#[test]
fn colmap_bad_inputs() {
    let (cams, imgs, pts) = model();
    type Edit = Box<dyn Fn(&mut Vec<Cam>, &mut Vec<Img>)>;
    let cases: Vec<(&str, Edit, &str, &str)> = vec![
        (
            "distortion",
            Box::new(|c: &mut Vec<Cam>, _: &mut Vec<Img>| c[2].5[4] = 0.1),
            "cameras.",
            "model OPENCV has non-zero distortion",
        ),
        (
            "fisheye",
            Box::new(|c: &mut Vec<Cam>, _: &mut Vec<Img>| {
                c[2].1 = 5;
                c[2].2 = "OPENCV_FISHEYE"
            }),
            "cameras.",
            "OPENCV_FISHEYE is a fisheye model",
        ),
        (
            "unknown camera id",
            Box::new(|_: &mut Vec<Cam>, i: &mut Vec<Img>| i[1].3 = 42),
            "images.",
            "refers to camera id 42",
        ),
        (
            "zero focal",
            Box::new(|c: &mut Vec<Cam>, _: &mut Vec<Img>| c[0].5[1] = 0.0),
            "images.",
            "focal length fy = 0",
        ),
        (
            "zero width",
            Box::new(|c: &mut Vec<Cam>, _: &mut Vec<Img>| c[1].3 = 0),
            "cameras.",
            "camera 7: image size 0x50",
        ),
        (
            "duplicate camera",
            Box::new(|c: &mut Vec<Cam>, _: &mut Vec<Img>| c[1].0 = 1),
            "cameras.",
            "camera id 1 appears twice",
        ),
        (
            "zero quaternion",
            Box::new(|_: &mut Vec<Cam>, i: &mut Vec<Img>| i[0].1 = [0.0; 4]),
            "images.",
            "invalid quaternion",
        ),
    ];
    for (what, edit, file, want) in cases {
        for ext in ["bin", "txt"] {
            let (mut c, mut i) = (cams.clone(), imgs.clone());
            edit(&mut c, &mut i);
            let d = tempfile::tempdir().unwrap();
            if ext == "bin" {
                write_bin(d.path(), &c, &i, &pts)
            } else {
                write_txt(d.path(), &c, &i, &pts)
            }
            let e = err_of(read_sparse(d.path()));
            let file = format!("{}{ext}: ", d.path().join(file).display());
            assert!(e.starts_with(&file), "{what}/{ext}: {e}");
            assert!(e.contains(want), "{what}/{ext}: expected {want:?} in {e:?}");
        }
    }
}

#[test]
fn colmap_truncated_and_lying_binaries() {
    let (cams, imgs, pts) = model();
    let d = tempfile::tempdir().unwrap();
    write_bin(d.path(), &cams, &imgs, &pts);
    for name in ["cameras.bin", "images.bin", "points3D.bin"] {
        let p = d.path().join(name);
        let good = std::fs::read(&p).unwrap();
        for len in 0..good.len() {
            std::fs::write(&p, &good[..len]).unwrap();
            let e = err_of(read_sparse(d.path()));
            assert!(e.starts_with(&format!("{}: ", p.display())), "{name}[..{len}]: {e}");
        }
        // A count of 2^60 records must fail quickly without allocating for them.
        let mut lying = good.clone();
        lying[..8].copy_from_slice(&(1u64 << 60).to_le_bytes());
        std::fs::write(&p, &lying).unwrap();
        let e = err_of(read_sparse(d.path()));
        assert!(e.contains("truncated"), "{name}: {e}");
        std::fs::write(&p, &good).unwrap();
    }
    std::fs::write(d.path().join("cameras.bin"), b"").unwrap();
    assert!(err_of(read_sparse(d.path())).contains("no camera count"));
}

#[test]
fn colmap_text_errors_name_the_line() {
    let (cams, imgs, pts) = model();
    let d = tempfile::tempdir().unwrap();
    write_txt(d.path(), &cams, &imgs, &pts);
    // Extra spaces between fields and a name with a space.
    let images = "# c\n1  1 0 0 0   0 0 1 1   my photo 01.jpg\n\n";
    std::fs::write(d.path().join("images.txt"), images).unwrap();
    let m = read_sparse(d.path()).unwrap();
    assert_eq!(m.cameras[0].name, "my photo 01.jpg");
    assert_eq!(m.cameras[0].translation, [0.0, 0.0, 1.0]);
    std::fs::write(d.path().join("cameras.txt"), "1 PINHOLE 10 10 5 5 five 5\n").unwrap();
    let e = err_of(read_sparse(d.path()));
    assert!(e.contains("cameras.txt: line 1: parameter \"five\""), "{e}");
    std::fs::write(d.path().join("cameras.txt"), "1 WEIRD 10 10 5 5 5 5\n").unwrap();
    assert!(err_of(read_sparse(d.path())).contains("unknown camera model \"WEIRD\""));
    std::fs::write(d.path().join("cameras.txt"), "1 PINHOLE 10 10 5 5 5\n").unwrap();
    assert!(err_of(read_sparse(d.path())).contains("PINHOLE needs 4 parameters, got 3"));
}

// ---------------------------------------------------------------- transforms.json

fn project(c: &Camera, p: [f32; 3]) -> [f32; 3] {
    let x: Vec<f32> =
        (0..3).map(|i| (0..3).map(|j| c.rotation[i][j] * p[j]).sum::<f32>() + c.translation[i]).collect();
    [c.fx * x[0] / x[2] + c.cx, c.fy * x[1] / x[2] + c.cy, x[2]]
}

#[test]
fn transforms_opengl_camera_looking_at_origin() {
    let d = tempfile::tempdir().unwrap();
    let json = r#"{
        "camera_model": "OPENCV", "fl_x": 100, "fl_y": 110, "w": 64, "h": 48,
        "k1": 0, "k2": 0.0, "p1": 0, "p2": 0,
        "ply_file_path": "sparse_pc.ply",
        "frames": [
            {"file_path": "images/frame_00001.png",
             "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,5],[0,0,0,1]]},
            {"file_path": "images/frame_00002.png", "cx": 30.5,
             "transform_matrix": [[0,0,1,5],[1,0,0,0],[0,1,0,0],[0,0,0,1]]}
        ]}"#;
    let p = d.path().join("transforms.json");
    std::fs::write(&p, json).unwrap();
    let t = transforms::read(&p).unwrap();
    assert_eq!(t.ply_file_path, Some(d.path().join("sparse_pc.ply")));
    let c = &t.cameras[0];
    assert_eq!(c.name, "images/frame_00001.png");
    assert_eq!((c.width, c.height, c.fx, c.fy, c.cx, c.cy), (64, 48, 100.0, 110.0, 32.0, 24.0));
    assert!(close(&c.centre(), &[0.0, 0.0, 5.0], 0.0));
    // The origin is straight ahead at depth 5, at the image centre.
    assert!(close(&project(c, [0.0, 0.0, 0.0]), &[32.0, 24.0, 5.0], 1e-5));
    // World +x is image right; world +y (OpenGL up) is image up, i.e. smaller v.
    let right = project(c, [1.0, 0.0, 0.0]);
    assert!(close(&right, &[32.0 + 20.0, 24.0, 5.0], 1e-4), "{right:?}");
    let up = project(c, [0.0, 1.0, 0.0]);
    assert!(close(&up, &[32.0, 24.0 - 22.0, 5.0], 1e-4), "{up:?}");
    // Second camera: at (5,0,0), its OpenGL -z axis is world -x, its up (y) is world +z.
    let c = &t.cameras[1];
    assert_eq!(c.cx, 30.5);
    assert!(close(&project(c, [0.0, 0.0, 0.0]), &[30.5, 24.0, 5.0], 1e-5));
    let up = project(c, [0.0, 0.0, 1.0]);
    assert!(up[1] < 24.0 && (up[0] - 30.5).abs() < 1e-4, "{up:?}");
    // load() picks the same up from the file and from its folder.
    assert_eq!(load(&p).unwrap(), t.cameras);
    assert_eq!(load(d.path()).unwrap(), t.cameras);
}

fn png_header(w: u32, h: u32) -> Vec<u8> {
    let mut b = b"\x89PNG\r\n\x1a\n\0\0\0\x0dIHDR".to_vec();
    b.extend_from_slice(&w.to_be_bytes());
    b.extend_from_slice(&h.to_be_bytes());
    b.extend_from_slice(&[8, 2, 0, 0, 0, 0, 0, 0, 0]);
    b
}

fn jpeg_header(w: u16, h: u16) -> Vec<u8> {
    let mut b = vec![0xFF, 0xD8, 0xFF, 0xE0, 0x00, 0x10];
    b.extend_from_slice(b"JFIF\0\x01\x01\0\0\x01\0\x01\0\0");
    b.extend_from_slice(&[0xFF, 0xFF, 0xC2, 0x00, 0x11, 0x08]);
    b.extend_from_slice(&h.to_be_bytes());
    b.extend_from_slice(&w.to_be_bytes());
    b.extend_from_slice(&[3, 1, 0x22, 0, 2, 0x11, 1, 3, 0x11, 1]);
    b
}

#[test]
fn image_headers() {
    assert_eq!(image_size::from_bytes(&png_header(800, 600)), Ok((800, 600)));
    assert_eq!(image_size::from_bytes(&jpeg_header(1297, 840)), Ok((1297, 840)));
    assert_eq!(image_size::from_bytes(b"GIF89a"), Err(image_size::Problem::NotAnImage));
    let j = jpeg_header(10, 10);
    for len in 0..j.len() - 10 {
        assert!(image_size::from_bytes(&j[..len]).is_err(), "{len}");
    }
}

#[test]
fn blender_camera_angle_x_with_size_from_the_image() {
    let d = tempfile::tempdir().unwrap();
    std::fs::create_dir(d.path().join("train")).unwrap();
    std::fs::write(d.path().join("train/r_0.png"), png_header(40, 30)).unwrap();
    std::fs::write(d.path().join("train/r_1.jpg"), jpeg_header(40, 30)).unwrap();
    let a = 0.6911112070083618f64;
    let json = format!(
        r#"{{"camera_angle_x": {a}, "frames": [
            {{"file_path": "./train/r_0", "rotation": 0.01, "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,4],[0,0,0,1]]}},
            {{"file_path": "./train/r_1", "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,4],[0,0,0,1]]}}
        ]}}"#
    );
    let p = d.path().join("transforms_train.json");
    std::fs::write(&p, json).unwrap();
    let t = transforms::read(&p).unwrap();
    let f = (0.5 * 40.0 / (0.5 * a).tan()) as f32;
    for c in &t.cameras {
        assert_eq!((c.width, c.height, c.cx, c.cy), (40, 30, 20.0, 15.0));
        assert_eq!((c.fx, c.fy), (f, f));
    }
    assert_eq!(t.cameras[0].name, "./train/r_0");
    assert_eq!(t.ply_file_path, None);
}

#[test]
fn transforms_bad_inputs() {
    let frame = r#"{"file_path": "a.png", "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,5],[0,0,0,1]]}"#;
    let cases: Vec<(String, &str)> = vec![
        (format!(r#"{{"fl_x": 10, "w": 8, "h": 8, "k1": 0.02, "frames": [{frame}]}}"#), "distortion k1 = 0.02"),
        (
            format!(r#"{{"fl_x": 10, "w": 8, "h": 8, "camera_model": "OPENCV_FISHEYE", "frames": [{frame}]}}"#),
            "camera_model \"OPENCV_FISHEYE\" is not supported",
        ),
        (format!(r#"{{"fl_x": 0, "w": 8, "h": 8, "frames": [{frame}]}}"#), "focal length fx = 0"),
        (format!(r#"{{"fl_x": 10, "w": 0, "h": 8, "frames": [{frame}]}}"#), "image size 0x8"),
        (format!(r#"{{"fl_x": 10, "w": -3, "h": 8, "frames": [{frame}]}}"#), "\"w\" is not a non-negative integer"),
        (format!(r#"{{"w": 8, "h": 8, "frames": [{frame}]}}"#), "no focal length"),
        (format!(r#"{{"fl_x": 10, "frames": [{frame}]}}"#), "not found to read its size"),
        (r#"{"fl_x": 10, "w": 8, "h": 8, "frames": [{"file_path": "a.png"}]}"#.into(), "transform_matrix"),
        (
            r#"{"fl_x": 10, "w": 8, "h": 8, "frames": [{"file_path": "a", "transform_matrix": [[2,0,0,0],[0,1,0,0],[0,0,1,0]]}]}"#
                .into(),
            "not orthonormal",
        ),
        (r#"{"fl_x": 10, "frames": 3}"#.into(), "missing \"frames\""),
        (r#"{"frames": [ 1, 2"#.into(), "not valid JSON"),
    ];
    refused_transforms(&cases);
}

// ---------------------------------------------------------------- INRIA cameras.json

#[test]
fn inria_hand_written_and_round_trip() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("cameras.json");
    // Camera-to-world rotation: 90 degrees about z; centre (1, 2, 3).
    std::fs::write(
        &p,
        r#"[{"id": 0, "img_name": "00001", "width": 200, "height": 100,
             "position": [1.0, 2.0, 3.0], "rotation": [[0,-1,0],[1,0,0],[0,0,1]], "fy": 90.5, "fx": 91.5}]"#,
    )
    .unwrap();
    let cams = inria::read(&p).unwrap();
    let c = &cams[0];
    assert_eq!(
        (c.name.as_str(), c.width, c.height, c.fx, c.fy, c.cx, c.cy),
        ("00001", 200, 100, 91.5, 90.5, 100.0, 50.0)
    );
    assert_eq!(c.centre(), [1.0, 2.0, 3.0]);
    // World-to-camera is the transpose: the camera's x axis is world +y.
    assert_eq!(c.rotation, [[0., 1., 0.], [-1., 0., 0.], [0., 0., 1.]]);

    let (cams, imgs, pts) = model();
    let m = tempfile::tempdir().unwrap();
    write_bin(m.path(), &cams, &imgs, &pts);
    let mut orig = read_sparse(m.path()).unwrap().cameras;
    for c in &mut orig {
        c.cx = c.width as f32 / 2.0;
        c.cy = c.height as f32 / 2.0;
    }
    let out = d.path().join("out_cameras.json");
    inria::write(&out, &orig).unwrap();
    let back = inria::read(&out).unwrap();
    assert_eq!(back.len(), orig.len());
    for (a, b) in orig.iter().zip(&back) {
        assert_eq!(
            (&a.name, a.width, a.height, a.fx, a.fy, a.cx, a.cy),
            (&b.name, b.width, b.height, b.fx, b.fy, b.cx, b.cy)
        );
        assert!(close(&a.rotation.concat(), &b.rotation.concat(), 1e-6));
        assert!(close(&a.translation, &b.translation, 1e-5));
    }
    // load() on a file and on an INRIA output folder.
    assert_eq!(load(&out).unwrap(), back);
}

#[test]
fn inria_bad_inputs() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("cameras.json");
    let ok = r#"{"id": 0, "img_name": "x", "width": 4, "height": 4, "position": [0,0,0], "rotation": [[1,0,0],[0,1,0],[0,0,1]], "fy": 2, "fx": 2}"#;
    let cases = [
        (ok.replace("\"fx\": 2", "\"fx\": 0"), "focal length fx = 0"),
        (ok.replace("\"fx\": 2", "\"fx\": -1"), "focal length fx = -1"),
        (ok.replace("\"height\": 4", "\"height\": 0"), "image size 4x0"),
        (ok.replace(", \"fy\": 2", ""), "camera 1: missing \"fy\""),
        (ok.replace("[0,0,0]", "[0,0]"), "\"position\" is not 3 numbers"),
        (ok.replace("[[1,0,0],", "[[1,0,\"a\"],"), "\"rotation\" is not a 3x3"),
        (ok.replace("\"width\": 4", "\"width\": 4.5"), "\"width\" is not a non-negative integer"),
    ];
    for (cam, want) in cases {
        std::fs::write(&p, format!("[{ok}, {cam}]")).unwrap();
        let e = err_of(inria::read(&p));
        assert!(e.starts_with(&format!("{}: ", p.display())), "{e}");
        assert!(e.contains(want), "expected {want:?} in {e:?}");
        // Through load() the message is the same.
        assert_eq!(err_of(load(&p)), e);
    }
    std::fs::write(&p, "{\"a\": 1}").unwrap();
    assert!(err_of(load(&p)).contains("unrecognised camera JSON"));
}

/// One rotation check (`Camera::validate`) for every format: a zero or scaled matrix in
/// cameras.json is refused as transforms.json refuses it.
#[test]
fn inria_rotation_name_and_size_checks() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("cameras.json");
    let cam = |name: &str, rot: &str, w: u32| {
        format!(
            r#"{{"id": 0, "img_name": "{name}", "width": {w}, "height": 4, "position": [0,0,0], "rotation": {rot}, "fy": 2, "fx": 2}}"#
        )
    };
    let id = "[[1,0,0],[0,1,0],[0,0,1]]";
    let cases = [
        (vec![cam("a", "[[0,0,0],[0,0,0],[0,0,0]]", 4)], "camera \"a\": rotation is not orthonormal"),
        (
            vec![cam("a", "[[1,0,0],[0,1,0],[0,0,3]]", 4)],
            "not orthonormal (R R^T is off the identity by 8.000",
        ),
        (vec![cam("a", "[[1,0.5,0],[0,1,0],[0,0,1]]", 4)], "not orthonormal"),
        (vec![cam("a", "[[1,0,0],[0,1,0],[0,0,-1]]", 4)], "reflection"),
        (vec![cam("a", id, 4), cam("", id, 4)], "camera 1: a camera has an empty image name"),
        (vec![cam("a", id, 4), cam("b", id, 4), cam("a", id, 4)], "two cameras share the image name \"a\";"),
        (
            vec![cam("x/a.png", id, 4), cam("y/a.jpg", id, 4)],
            "two cameras share the image name \"a\" (\"x/a.png\" and \"y/a.jpg\")",
        ),
        (vec![cam("a", id, 100_000)], "image size 100000x4 is larger than 32768 pixels a side"),
    ];
    for (list, want) in cases {
        std::fs::write(&p, format!("[{}]", list.join(", "))).unwrap();
        let e = err_of(inria::read(&p));
        assert!(e.starts_with(&format!("{}: ", p.display())), "{e}");
        assert!(e.contains(want), "expected {want:?} in {e:?}");
        assert_eq!(err_of(load(&p)), e);
    }
    // A rotation with a few digits of rounding is still a rotation.
    std::fs::write(&p, format!("[{}]", cam("a", "[[0.7071,-0.7071,0],[0.7071,0.7071,0],[0,0,1]]", 4)))
        .unwrap();
    assert_eq!(inria::read(&p).unwrap().len(), 1);
}

#[test]
fn transforms_field_of_view_names_and_rotation() {
    let m = "[[1,0,0,0],[0,1,0,0],[0,0,1,5],[0,0,0,1]]";
    let frame = |name: &str| format!(r#"{{"file_path": "{name}", "transform_matrix": {m}}}"#);
    let cases: Vec<(String, &str)> = vec![
        (
            format!(r#"{{"camera_angle_x": 7, "w": 8, "h": 8, "frames": [{}]}}"#, frame("a.png")),
            "frame 0 (\"a.png\"): \"camera_angle_x\" = 7 is not a field of view in radians between 0 and pi",
        ),
        (format!(r#"{{"camera_angle_x": 0, "w": 8, "h": 8, "frames": [{}]}}"#, frame("a.png")), "= 0 is not"),
        (format!(r#"{{"camera_angle_x": -0.5, "w": 8, "h": 8, "frames": [{}]}}"#, frame("a.png")), "= -0.5 is not"),
        (
            format!(r#"{{"camera_angle_x": 0.7, "camera_angle_y": 3.2, "w": 8, "h": 8, "frames": [{}]}}"#, frame("a")),
            "\"camera_angle_y\" = 3.2 is not",
        ),
        (
            format!(r#"{{"fl_x": 10, "w": 8, "h": 8, "frames": [{}, {}]}}"#, frame("a.png"), frame("")),
            "camera 1: a camera has an empty image name",
        ),
        (
            format!(r#"{{"fl_x": 10, "w": 8, "h": 8, "frames": [{}, {}]}}"#, frame("i/a.png"), frame("i/a.png")),
            "two cameras share the image name \"a\"",
        ),
        (
            format!(r#"{{"fl_x": 10, "w": 100000, "h": 100000, "frames": [{}]}}"#, frame("a.png")),
            "image size 100000x100000",
        ),
        (
            r#"{"fl_x": 10, "w": 8, "h": 8, "frames": [{"file_path": "a", "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,-1,0]]}]}"#
                .into(),
            "camera \"a\": rotation is a reflection",
        ),
        (
            r#"{"fl_x": 10, "w": 8, "h": 8, "frames": [{"file_path": "a", "transform_matrix": [[0,0,0,0],[0,0,0,0],[0,0,0,0]]}]}"#
                .into(),
            "camera \"a\": rotation is not orthonormal",
        ),
    ];
    refused_transforms(&cases);
    // Angles just inside (0, pi) are accepted.
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("transforms.json");
    std::fs::write(&p, format!(r#"{{"camera_angle_x": 3.1, "w": 8, "h": 8, "frames": [{}]}}"#, frame("a")))
        .unwrap();
    assert!(transforms::read(&p).unwrap().cameras[0].fx > 0.0);
}

#[test]
fn colmap_size_cap_names_and_quaternions() {
    let (cams, imgs, pts) = model();
    for ext in ["bin", "txt"] {
        let write = |d: &Path, c: &[Cam], i: &[Img]| {
            if ext == "bin" {
                write_bin(d, c, i, &pts)
            } else {
                write_txt(d, c, i, &pts)
            }
        };
        let d = tempfile::tempdir().unwrap();
        // 100000x100000 is refused in the cameras file, before any image is read.
        let mut c = cams.clone();
        (c[0].3, c[0].4) = (100_000, 100_000);
        write(d.path(), &c, &imgs);
        let e = err_of(read_sparse(d.path()));
        let file = format!("{}: ", d.path().join(format!("cameras.{ext}")).display());
        assert!(e.starts_with(&file), "{ext}: {e}");
        assert!(e.contains("camera 1: image size 100000x100000 is larger than 32768 pixels a side"), "{e}");
        // Beyond u32 too.
        c[0].3 = 1 << 40;
        write(d.path(), &c, &imgs);
        assert!(err_of(read_sparse(d.path())).contains("is larger than"), "{ext}");
        // Image names: duplicates (by output name) and empty (binary; text needs a name).
        let mut i = imgs.clone();
        i[2].4 = "sub/c.png";
        write(d.path(), &cams, &i);
        let e = err_of(read_sparse(d.path()));
        assert!(e.starts_with(&format!("{}: ", d.path().join(format!("images.{ext}")).display())), "{e}");
        assert!(e.contains("two cameras share the image name \"c\" (\"c.jpg\" and \"sub/c.png\")"), "{e}");
        if ext == "bin" {
            i[2].4 = "";
            write(d.path(), &cams, &i);
            assert!(err_of(read_sparse(d.path())).contains("camera 2: a camera has an empty image name"));
        }
        // A quaternion of any finite non-zero scale is a rotation; zero or NaN is not.
        let mut i = imgs.clone();
        i[1].1 = [1e200, 0.0, 0.0, 0.0];
        i[0].1 = [0.0, 0.0, 0.0, 1e-200];
        write(d.path(), &cams, &i);
        let m = read_sparse(d.path()).unwrap();
        assert_eq!(m.cameras[0].rotation, [[1., 0., 0.], [0., 1., 0.], [0., 0., 1.]]);
        assert_eq!(m.cameras[2].rotation, [[-1., 0., 0.], [0., -1., 0.], [0., 0., 1.]]);
        for q in [[0.0; 4], [f64::NAN, 1.0, 0.0, 0.0], [f64::INFINITY, 0.0, 0.0, 0.0]] {
            i[1].1 = q;
            write(d.path(), &cams, &i);
            let e = err_of(read_sparse(d.path()));
            assert!(e.contains("image \"a.jpg\" has an invalid quaternion"), "{ext} {q:?}: {e}");
            assert_eq!(e.contains("line 5: image"), ext == "txt", "{e}");
        }
    }
}

/// An images.txt with a line missing used to read the next image as the points of the
/// one before and drop it; now the line is named.
#[test]
fn colmap_images_txt_missing_a_line_names_it() {
    let (cams, imgs, pts) = model();
    let d = tempfile::tempdir().unwrap();
    write_txt(d.path(), &cams, &imgs, &pts);
    let p = d.path().join("images.txt");
    let good = std::fs::read_to_string(&p).unwrap();
    let lines: Vec<&str> = good.lines().collect();
    // Header (2 lines), then two lines per image; image 2's points are on line 6.
    assert!(lines[5].starts_with("0.0 1.5 -1"), "{lines:?}");
    for drop in [3, 5] {
        let mut l = lines.clone();
        l.remove(drop);
        std::fs::write(&p, l.join("\n") + "\n").unwrap();
        let e = err_of(read_sparse(d.path()));
        assert!(e.starts_with(&format!("{}: line ", p.display())), "{e}");
        assert!(e.contains("expected the 2D points of image") && e.contains("is a line missing?"), "{e}");
    }
    // Dropping the last image's points line loses nothing: accepted.
    std::fs::write(&p, lines[..lines.len() - 1].join("\n") + "\n").unwrap();
    assert_eq!(read_sparse(d.path()).unwrap().cameras.len(), 3);
    // Points written as floats (some tools do) are still points; an image line is not.
    std::fs::write(&p, "1 1 0 0 0 0 0 1 1 a.jpg\n1.5 2.5 -1.0 3 4 7\n").unwrap();
    assert_eq!(read_sparse(d.path()).unwrap().cameras.len(), 1);
    std::fs::write(&p, "1 1 0 0 0 0 0 1 1 a.jpg\n2 1 0 0 0 0 0 1 1 b.jpg\n\n").unwrap();
    let e = err_of(read_sparse(d.path()));
    assert!(e.contains("line 2: expected the 2D points of image 1 (line 1)"), "{e}");
    // Duplicate image ids in text name the line.
    std::fs::write(&p, "1 1 0 0 0 0 0 1 1 a.jpg\n\n1 1 0 0 0 0 0 1 1 b.jpg\n\n").unwrap();
    assert!(err_of(read_sparse(d.path())).contains("images.txt: line 3: image id 1 appears twice"));
}

#[test]
fn load_reports_the_path_when_nothing_is_found() {
    let d = tempfile::tempdir().unwrap();
    let e = err_of(load(d.path()));
    assert!(e.starts_with(&format!("{}: no cameras found", d.path().display())), "{e}");
    let missing = d.path().join("nope");
    assert!(err_of(load(&missing)).starts_with(&missing.display().to_string()));
}

#[test]
fn mutated_colmap_and_images_never_panic() {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    let (cams, imgs, pts) = model();
    let d = tempfile::tempdir().unwrap();
    write_bin(d.path(), &cams, &imgs, &pts);
    write_txt(d.path(), &cams, &imgs, &pts);
    let files: Vec<(String, Vec<u8>)> =
        ["cameras.bin", "images.bin", "points3D.bin", "cameras.txt", "images.txt", "points3D.txt"]
            .iter()
            .map(|n| (n.to_string(), std::fs::read(d.path().join(n)).unwrap()))
            .collect();
    let imgs_bytes = [png_header(8, 8), jpeg_header(8, 8)];
    for _ in 0..2000 {
        for (name, good) in
            files.iter().map(|(n, b)| (n.as_str(), b)).chain(imgs_bytes.iter().map(|b| ("img", b)))
        {
            let mut b = good.clone();
            for _ in 0..rng.gen_range(1..4) {
                if b.is_empty() {
                    break;
                }
                let i = rng.gen_range(0..b.len());
                if rng.gen_bool(0.2) {
                    b.truncate(i)
                } else {
                    b[i] = rng.gen()
                }
            }
            match name {
                "cameras.bin" => drop(colmap::parse_cameras_bin(&b)),
                "images.bin" => drop(colmap::parse_images_bin(&b)),
                "points3D.bin" => drop(colmap::parse_points_bin(&b)),
                "cameras.txt" => drop(colmap::parse_cameras_txt(&b)),
                "images.txt" => drop(colmap::parse_images_txt(&b)),
                "points3D.txt" => drop(colmap::parse_points_txt(&b)),
                _ => drop(image_size::from_bytes(&b)),
            }
        }
    }
}

/// Each `(transforms.json text, expected words)` is refused with an error that starts
/// with the file's path and holds the words.
fn refused_transforms(cases: &[(String, &str)]) {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("transforms.json");
    for (json, want) in cases {
        std::fs::write(&p, json).unwrap();
        let e = err_of(transforms::read(&p));
        assert!(e.starts_with(&format!("{}: ", p.display())), "{json}: {e}");
        assert!(e.contains(want), "expected {want:?} in {e:?}");
    }
}
