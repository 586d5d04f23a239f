use super::*;
use crate::Extra;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::path::PathBuf;

fn random_scene(n: usize, degree: u32, extras: usize, seed: u64) -> Gaussians {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut v = |s: f32| rng.gen_range(-s..s);
    let k = crate::sh_coeffs(degree) * 3;
    let mut g = Gaussians {
        sh_degree: degree,
        extra: Extra { names: (0..extras).map(|i| format!("sem_{i}")).collect(), values: vec![] },
        ..Default::default()
    };
    for _ in 0..n {
        g.means.push([v(10.0), v(10.0), v(10.0)]);
        g.log_scales.push([v(5.0), v(5.0), v(5.0)]);
        g.rotations.push([v(1.0) + 2.0, v(1.0), v(1.0), v(1.0)]);
        g.opacity_logits.push(v(8.0));
        for _ in 0..k {
            g.sh.push(v(3.0));
        }
        for _ in 0..extras {
            g.extra.values.push(v(1.0));
        }
    }
    g
}

fn bits(g: &Gaussians) -> Vec<u32> {
    let mut out = Vec::new();
    out.extend(g.means.iter().flatten().map(|v| v.to_bits()));
    out.extend(g.log_scales.iter().flatten().map(|v| v.to_bits()));
    out.extend(g.rotations.iter().flatten().map(|v| v.to_bits()));
    out.extend(g.opacity_logits.iter().map(|v| v.to_bits()));
    out.extend(g.sh.iter().map(|v| v.to_bits()));
    out.extend(g.extra.values.iter().map(|v| v.to_bits()));
    out
}

fn p() -> PathBuf {
    PathBuf::from("/data/scene.ply")
}

#[test]
fn round_trip_is_bit_exact_for_every_degree() {
    for degree in 0..=3 {
        let g = random_scene(57, degree, if degree == 2 { 0 } else { 16 }, degree as u64);
        let bytes = to_bytes(&g);
        let back = parse(&bytes, &p()).expect("parse");
        assert_eq!(back.sh_degree, degree);
        assert_eq!(back.extra.names, g.extra.names);
        assert_eq!(bits(&back), bits(&g));
        assert_eq!(to_bytes(&back), bytes);
    }
}

#[test]
fn write_and_read_files_atomically() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("out.ply");
    let g = random_scene(10, 3, 4, 7);
    write(&path, &g).unwrap();
    let back = read(&path).unwrap();
    assert_eq!(bits(&back), bits(&g));
    let names: Vec<_> = std::fs::read_dir(dir.path()).unwrap().map(|e| e.unwrap().file_name()).collect();
    assert_eq!(names.len(), 1, "temporary file left behind: {names:?}");
    let mut bad = g.clone();
    bad.log_scales[9][2] = f32::NAN;
    let e = write(&dir.path().join("bad.ply"), &bad).unwrap_err().to_string();
    assert!(e.contains("bad.ply: cannot write scene: Gaussian 9 has an invalid scale"), "{e}");
    assert!(!dir.path().join("bad.ply").exists());
    assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
}

#[test]
#[ignore = "timing; run with --ignored --nocapture"]
fn timing_one_million() {
    let g = random_scene(1_000_000, 3, 0, 1);
    let t = std::time::Instant::now();
    let bytes = to_bytes(&g);
    let w = t.elapsed();
    let t = std::time::Instant::now();
    let back = parse(&bytes, &p()).unwrap();
    eprintln!("1M degree-3: to_bytes {w:?}, parse {:?} ({} MB)", t.elapsed(), bytes.len() >> 20);
    assert_eq!(back.len(), g.len());
}

#[test]
fn header_has_inria_order() {
    let g = random_scene(1, 1, 2, 1);
    let bytes = to_bytes(&g);
    let text = String::from_utf8_lossy(&bytes[..bytes.windows(10).position(|w| w == b"end_header").unwrap()]);
    let props: Vec<&str> = text.lines().filter_map(|l| l.strip_prefix("property float ")).collect();
    let mut want = vec!["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"];
    let rest: Vec<String> = (0..9).map(|j| format!("f_rest_{j}")).collect();
    want.extend(rest.iter().map(|s| s.as_str()));
    want.extend([
        "opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3", "sem_0", "sem_1",
    ]);
    assert_eq!(props, want);
    assert!(text.starts_with("ply\nformat binary_little_endian 1.0\nelement vertex 1\n"));
}

#[test]
fn f_rest_is_channel_major_in_the_file() {
    // Degree 1: 3 rest coefficients per channel; f_rest_j = j.
    let mut g = random_scene(1, 1, 0, 3);
    for k in 1..4 {
        for c in 0..3 {
            g.sh[k * 3 + c] = (c * 3 + k - 1) as f32;
        }
    }
    let bytes = to_bytes(&g);
    let body = &bytes[bytes.len() - 4 * (17 + 9)..];
    let vals: Vec<f32> = body.chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect();
    assert_eq!(&vals[9..18], &[0., 1., 2., 3., 4., 5., 6., 7., 8.]);
}

const ASCII: &str = "ply\r
format ascii 1.0\r
comment made by hand\r
obj_info nothing\r
element vertex 2\r
property float rot_1\r
property float y\r
property float x\r
property float z\r
property double nx\r
property float f_dc_2\r
property float f_dc_0\r
property float f_dc_1\r
property float opacity\r
property float scale_2\r
property float scale_1\r
property float scale_0\r
property float rot_0\r
property float rot_2\r
property float rot_3\r
property uchar label\r
element face 1\r
property list uchar int vertex_indices\r
end_header\r
0.5 2 1 3 9 0.3 0.1 0.2 -1.5 -3 -2 -1 1 0 0 7\r
0 -2 -1 -3 0 0 0 0 2.5 0 0 0 1 0 0.25 255\r
3 0 1 0\r
";

#[test]
fn ascii_in_any_order_with_trailing_faces() {
    let g = parse(ASCII.as_bytes(), &p()).unwrap();
    assert_eq!(g.len(), 2);
    assert_eq!(g.sh_degree, 0);
    assert_eq!(g.means, vec![[1.0, 2.0, 3.0], [-1.0, -2.0, -3.0]]);
    assert_eq!(g.sh, vec![0.1, 0.2, 0.3, 0.0, 0.0, 0.0]);
    assert_eq!(g.opacity_logits, vec![-1.5, 2.5]);
    assert_eq!(g.log_scales[0], [-1.0, -2.0, -3.0]);
    assert_eq!(g.rotations, vec![[1.0, 0.5, 0.0, 0.0], [1.0, 0.0, 0.0, 0.25]]);
    assert_eq!(g.extra.names, vec!["label"]);
    assert_eq!(g.extra.values, vec![7.0, 255.0]);
}

/// Big-endian, float64 positions, a list element before the vertices.
fn big_endian_file(count_in_header: usize, rows: usize) -> Vec<u8> {
    let mut h = String::from("ply\nformat binary_big_endian 1.0\n");
    h.push_str("element face 2\nproperty list uchar int vertex_indices\nproperty ushort flags\n");
    h.push_str(&format!("element vertex {count_in_header}\n"));
    for n in ["x", "y", "z"] {
        h.push_str(&format!("property double {n}\n"));
    }
    for n in ["f_dc_0", "f_dc_1", "f_dc_2", "opacity", "scale_0", "scale_1", "scale_2"] {
        h.push_str(&format!("property float {n}\n"));
    }
    for n in ["rot_0", "rot_1", "rot_2", "rot_3"] {
        h.push_str(&format!("property float {n}\n"));
    }
    h.push_str("property short sem_0\nend_header\n");
    let mut b = h.into_bytes();
    // faces: [3: 0 1 2] flags 9, [0:] flags 1
    b.push(3);
    for i in [0i32, 1, 2] {
        b.extend_from_slice(&i.to_be_bytes());
    }
    b.extend_from_slice(&9u16.to_be_bytes());
    b.push(0);
    b.extend_from_slice(&1u16.to_be_bytes());
    for r in 0..rows {
        let r = r as f64;
        for v in [r + 0.125, -r, 1e-3] {
            b.extend_from_slice(&v.to_be_bytes());
        }
        for v in [0.5f32, 0.25, -0.5, 1.0, -2.0, -3.0, -4.0, 1.0, 0.0, 0.0, 0.0] {
            b.extend_from_slice(&v.to_be_bytes());
        }
        b.extend_from_slice(&(-(r as i16) - 7).to_be_bytes());
    }
    b
}

#[test]
fn big_endian_float64_with_leading_list_element() {
    let g = parse(&big_endian_file(3, 3), &p()).unwrap();
    assert_eq!(g.len(), 3);
    assert_eq!(g.means[2], [2.125, -2.0, 1e-3f64 as f32]);
    assert_eq!(g.sh_of(1), &[0.5, 0.25, -0.5]);
    assert_eq!(g.opacity_logits[0], 1.0);
    assert_eq!(g.log_scales[0], [-2.0, -3.0, -4.0]);
    assert_eq!(g.extra.values, vec![-7.0, -8.0, -9.0]);
    // And it survives our own write/read.
    let back = parse(&to_bytes(&g), &p()).unwrap();
    assert_eq!(bits(&back), bits(&g));
}

#[test]
fn float64_little_endian_degree_one() {
    let mut h = String::from("ply\nformat binary_little_endian 1.0\nelement vertex 1\n");
    let mut names: Vec<String> = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2"].map(String::from).to_vec();
    names.extend((0..9).map(|j| format!("f_rest_{j}")));
    names.extend(
        ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"].map(String::from),
    );
    for n in &names {
        h.push_str(&format!("property double {n}\n"));
    }
    h.push_str("end_header\n");
    let mut b = h.into_bytes();
    for i in 0..names.len() {
        b.extend_from_slice(&(i as f64 + 0.5).to_le_bytes());
    }
    let g = parse(&b, &p()).unwrap();
    assert_eq!(g.sh_degree, 1);
    assert_eq!(g.means[0], [0.5, 1.5, 2.5]);
    // coefficient 1 channel G is f_rest_3 (property index 6 + 3 = 9)
    assert_eq!(g.sh[3 + 1], 9.5);
    assert_eq!(g.sh[2 * 3 + 2], 6.0 + 7.0 + 0.5); // coef 2, B -> f_rest_7
    assert_eq!(g.opacity_logits[0], 15.5);
    assert_eq!(g.rotations[0], [19.5, 20.5, 21.5, 22.5]);
}

#[test]
fn zero_gaussians_is_an_empty_scene() {
    let g = Gaussians { sh_degree: 2, ..Default::default() };
    let back = parse(&to_bytes(&g), &p()).unwrap();
    assert!(back.is_empty());
    assert_eq!(back.sh_degree, 2);
}

#[test]
fn drop_invalid_removes_and_counts() {
    let mut g = random_scene(20, 1, 3, 11);
    g.means[3][1] = f32::NAN;
    g.sh[7 * 12 + 5] = f32::INFINITY;
    g.extra.values[12 * 3 + 2] = f32::NEG_INFINITY;
    g.rotations[15] = [0.0; 4];
    let bytes = to_bytes(&g);
    let e = parse(&bytes, &p()).unwrap_err().to_string();
    assert!(e.contains("Gaussian 3") && e.contains("'y'") && e.contains("NaN"), "{e}");
    let (kept, dropped) = parse_with(&bytes, &p(), &ReadOptions { drop_invalid: true }).unwrap();
    assert_eq!(dropped, 4);
    assert_eq!(kept.len(), 16);
    assert!(kept.first_non_finite().is_none());
    assert_eq!(kept.means[3], g.means[4]);
}

#[test]
fn extra_names_that_clash_are_renamed() {
    let mut g = random_scene(2, 0, 3, 5);
    g.extra.names = vec!["x".into(), "f_rest_0".into(), "my prop".into()];
    let back = parse(&to_bytes(&g), &p()).unwrap();
    assert_eq!(back.sh_degree, 0);
    assert_eq!(back.extra.names, vec!["extra_x", "extra_f_rest_0", "my_prop"]);
    assert_eq!(back.extra.values, g.extra.values);
}

fn replace(bytes: &[u8], from: &str, to: &str) -> Vec<u8> {
    let i = bytes.windows(from.len()).position(|w| w == from.as_bytes()).expect("pattern");
    let mut out = bytes[..i].to_vec();
    out.extend_from_slice(to.as_bytes());
    out.extend_from_slice(&bytes[i + from.len()..]);
    out
}

#[test]
fn bad_inputs_give_errors_naming_file_and_problem() {
    let good = to_bytes(&random_scene(4, 1, 2, 9));
    let mut nan = random_scene(4, 1, 2, 9);
    nan.sh[2 * 12 + 4] = f32::NAN; // Gaussian 2, coefficient 1, channel G -> f_rest_3
    let mut inf = random_scene(4, 0, 0, 9);
    inf.opacity_logits[1] = f32::INFINITY;
    let cases: Vec<(&str, Vec<u8>, &str)> = vec![
        ("empty", vec![], "not a PLY file"),
        ("bad magic", b"plx\nformat ascii 1.0\nend_header\n".to_vec(), "not a PLY file"),
        ("no end_header", good[..60].to_vec(), "no 'end_header'"),
        ("unknown format", replace(&good, "binary_little_endian", "binary_middle_endian"), "unknown PLY format"),
        ("no format", replace(&good, "format binary_little_endian 1.0\n", ""), "no 'format'"),
        ("bad count", replace(&good, "element vertex 4", "element vertex -4"), "element count"),
        ("unknown type", replace(&good, "property float x", "property quad x"), "unknown property type"),
        ("truncated", good[..good.len() - 1].to_vec(), "vertex count 4 needs"),
        (
            "lying count",
            replace(&good, "element vertex 4", "element vertex 999999999999999"),
            "vertex count 999999999999999",
        ),
        ("missing property", replace(&good, "property float opacity", "property float opacityx"), "'opacity'"),
        ("missing position", replace(&good, "property float z\n", "property float w\n"), "'z'"),
        ("bad f_rest count", replace(&good, "property float f_rest_8\n", "property float g_rest_8\n"), "8 f_rest_*"),
        ("no vertex element", replace(&good, "element vertex", "element vertox"), "no 'vertex' element"),
        ("nan", to_bytes(&nan), "Gaussian 2 (vertex 2) has an invalid SH colour: property 'f_rest_3' = NaN"),
        ("inf", to_bytes(&inf), "Gaussian 1 (vertex 1) has an invalid opacity: property 'opacity' = inf"),
        ("ascii truncated", ASCII.replace("3 0 1 0\r\n", "").replace(" 0.25 255", "").into_bytes(), "vertex 1"),
        (
            "ascii lying count",
            ASCII.replace("element vertex 2", "element vertex 4000000000").into_bytes(),
            "vertex count 4000000000",
        ),
        ("ascii garbage", ASCII.replace("0.5 2 1", "0.5 two 1").into_bytes(), "malformed"),
        (
            "lying list element",
            replace(&big_endian_file(3, 3), "element face 2", "element face 2000000"),
            "cannot skip element 'face'",
        ),
        (
            "huge fixed element before vertex",
            replace(&good, "ply\nformat binary_little_endian 1.0\n", "ply\nformat binary_little_endian 1.0\nelement junk 18446744073709551615\nproperty double a\n"),
            "cannot skip element 'junk'",
        ),
    ];
    for (what, bytes, want) in cases {
        match parse(&bytes, &p()) {
            Ok(_) => panic!("{what}: parsed without error"),
            Err(e) => {
                let msg = e.to_string();
                assert!(msg.starts_with("/data/scene.ply: "), "{what}: {msg}");
                assert!(msg.contains(want), "{what}: expected {want:?} in {msg:?}");
                assert!(!msg.contains('\n'), "{what}: multi-line message {msg:?}");
            }
        }
    }
}

#[test]
fn every_truncation_errors_without_panicking() {
    let good = to_bytes(&random_scene(3, 2, 1, 4));
    for len in 0..good.len() {
        assert!(parse(&good[..len], &p()).is_err(), "prefix of {len} bytes parsed");
    }
    let ascii = ASCII.as_bytes();
    // The face element after the vertices is not needed; everything shorter than the
    // vertex data must fail.
    let vert_end = ASCII.find("3 0 1 0").unwrap() - 2;
    for len in 0..vert_end - 4 {
        assert!(parse(&ascii[..len], &p()).is_err(), "ascii prefix of {len} bytes parsed");
    }
}

#[test]
fn missing_file_names_the_file() {
    let e = read(Path::new("/nonexistent/dir/scene.ply")).unwrap_err().to_string();
    assert!(e.contains("/nonexistent/dir/scene.ply"), "{e}");
}

/// Random byte mutations of valid files never panic (a cheap stand-in until the
/// fuzz targets exist).
#[test]
fn mutated_files_never_panic() {
    let mut rng = ChaCha8Rng::seed_from_u64(99);
    let seeds = [to_bytes(&random_scene(3, 1, 2, 1)), ASCII.as_bytes().to_vec(), big_endian_file(2, 2)];
    for seed in &seeds {
        for _ in 0..3000 {
            let mut b = seed.clone();
            for _ in 0..rng.gen_range(1..6) {
                let i = rng.gen_range(0..b.len());
                match rng.gen_range(0..3) {
                    0 => b[i] = rng.gen(),
                    1 => b[i] = b"0123456789 \n-e.x"[rng.gen_range(0..16)],
                    _ => b.truncate(i),
                }
                if b.is_empty() {
                    break;
                }
            }
            let _ = parse_with(&b, &p(), &ReadOptions { drop_invalid: rng.gen() });
        }
    }
}
