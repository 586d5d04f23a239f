use super::*;
use rand::{Rng, SeedableRng};
use transsplat_scene::ply::compressed;

fn scene(n: usize, seed: u64) -> Gaussians {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let mut g = Gaussians { sh_degree: 2, ..Default::default() };
    for _ in 0..n {
        g.means.push([rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0), rng.gen_range(-1.0..1.0)]);
        g.log_scales.push([rng.gen_range(-5.0..-2.0); 3]);
        g.rotations.push([1.0, 0.0, 0.0, 0.0]);
        g.opacity_logits.push(rng.gen_range(-3.0..3.0));
        g.sh.extend((0..27).map(|_| rng.gen_range(-0.5..0.5)));
    }
    g
}

fn base64_decode(s: &str) -> Vec<u8> {
    let val = |c: u8| match c {
        b'A'..=b'Z' => c - b'A',
        b'a'..=b'z' => c - b'a' + 26,
        b'0'..=b'9' => c - b'0' + 52,
        b'+' => 62,
        _ => 63,
    };
    let s = s.trim_end_matches('=').as_bytes();
    let mut out = Vec::new();
    for c in s.chunks(4) {
        let n = c.iter().enumerate().fold(0u32, |n, (k, &b)| n | (val(b) as u32) << (18 - 6 * k));
        out.extend_from_slice(&n.to_be_bytes()[1..c.len()]);
    }
    out
}

/// The base64 text of blob `k` in a section.
fn blob(html: &str, k: usize) -> Vec<u8> {
    let tag = format!("data-blob=\"{k}\">");
    let start = html.find(&tag).expect("blob present") + tag.len();
    let end = start + html[start..].find("</script>").expect("closed");
    base64_decode(&html[start..end])
}

fn meta(html: &str) -> serde_json::Value {
    let tag = "class=\"ts-meta\">";
    let start = html.find(tag).expect("meta") + tag.len();
    let end = start + html[start..].find("</script>").expect("closed");
    serde_json::from_str(&html[start..end].replace("<\\/", "</")).expect("json")
}

#[test]
fn base64_matches_rfc_4648_vectors() {
    for (plain, coded) in [
        ("", ""),
        ("f", "Zg=="),
        ("fo", "Zm8="),
        ("foo", "Zm9v"),
        ("foob", "Zm9vYg=="),
        ("foobar", "Zm9vYmFy"),
    ] {
        let mut s = String::new();
        base64_into(plain.as_bytes(), &mut s);
        assert_eq!(s, coded);
        assert_eq!(base64_decode(&s), plain.as_bytes());
    }
}

#[test]
fn the_script_cannot_close_its_own_tag() {
    assert!(!VIEWER_JS.to_ascii_lowercase().contains("</script"));
    assert!(!VIEWER_CSS.to_ascii_lowercase().contains("</style"));
}

#[test]
fn embeds_scenes_and_maps_in_the_same_order() {
    let before = scene(700, 1);
    let mut after = before.clone();
    for v in after.sh.iter_mut().step_by(27) {
        *v += 1.0;
    }
    // A map that encodes each Gaussian's x, so the embedded order can be checked.
    let x: Vec<f32> = before.means.iter().map(|m| (m[0] + 1.0) / 2.0).collect();
    let mut v = Viewer::new("t", [0.0; 3], vec![("before".into(), &before), ("after".into(), &after)]);
    v.layers.push(Layer { name: "x".into(), scene: 1, kind: LayerKind::Scalar, values: x });
    let html = section(&v).unwrap();
    let m = meta(&html);
    assert_eq!(m["shared_geometry"], true);
    assert_eq!(m["scenes"][1]["count"], 700);
    let b = compressed::parse(&blob(&html, 0)).unwrap();
    let a = compressed::parse(&blob(&html, 1)).unwrap();
    let layer = blob(&html, 2);
    assert_eq!((b.len(), a.len(), layer.len(), b.sh_degree), (700, 700, 700, 1));
    for (i, &l) in layer.iter().enumerate() {
        assert_eq!(a.means[i], b.means[i]);
        let want = ((b.means[i][0] + 1.0) / 2.0 * 255.0).round();
        assert!((l as f32 - want).abs() <= 2.0, "{i}: {l} vs {want}");
        // The edited red DC differs by 1 (up to the chunk's 8-bit colour step).
        assert!((a.sh[i * 12] - b.sh[i * 12] - 1.0).abs() < 0.05);
    }
}

#[test]
fn drops_the_least_important_gaussians_to_fit_the_budget_and_says_so() {
    let g = scene(40_000, 2);
    let mut v = Viewer::new("t", [0.0; 3], vec![("scene".into(), &g)]);
    let full = section(&v).unwrap();
    v.max_bytes = full.len() / 2;
    let half = section(&v).unwrap();
    assert!(half.len() <= v.max_bytes, "{} > {}", half.len(), v.max_bytes);
    let m = meta(&half);
    let count = m["scenes"][0]["count"].as_u64().unwrap() as usize;
    assert_eq!(m["scenes"][0]["dropped"].as_u64().unwrap() as usize, 40_000 - count);
    assert!(count > 15_000 && count < 20_000, "{count}");
    assert!(m["notes"][0].as_str().unwrap().contains("are not shown"));
    // The kept ones are the most opaque × largest: the smallest kept importance is at
    // least the largest dropped one.
    let imp = |i: usize| sigmoid(g.opacity_logits[i]) * (g.log_scales[i].iter().sum::<f32>()).exp();
    let kept = compressed::parse(&blob(&half, 0)).unwrap();
    assert_eq!(kept.len(), count);
    let mut all: Vec<f32> = (0..g.len()).map(imp).collect();
    all.sort_by(|a, b| b.total_cmp(a));
    let threshold = all[count - 1];
    let kept_min = (0..kept.len())
        .map(|i| sigmoid(kept.opacity_logits[i]) * (kept.log_scales[i].iter().sum::<f32>()).exp())
        .fold(f32::INFINITY, f32::min);
    assert!(kept_min >= threshold * 0.9, "{kept_min} < {threshold}");
}

#[test]
fn refuses_empty_and_non_finite_scenes_and_bad_maps() {
    let empty = Gaussians::default();
    let e = section(&Viewer::new("t", [0.0; 3], vec![("empty".into(), &empty)])).unwrap_err();
    assert!(e.to_string().contains("no Gaussians"), "{e}");
    let mut bad = scene(10, 3);
    bad.means[4][1] = f32::NAN;
    let e = section(&Viewer::new("t", [0.0; 3], vec![("bad".into(), &bad)])).unwrap_err();
    assert!(e.to_string().contains("Gaussian 4 has an invalid position"), "{e}");
    let g = scene(10, 4);
    let mut v = Viewer::new("t", [0.0; 3], vec![("s".into(), &g)]);
    v.layers.push(Layer { name: "gate".into(), scene: 0, kind: LayerKind::Scalar, values: vec![0.0; 9] });
    let e = section(&v).unwrap_err();
    assert!(e.to_string().contains("9 values for 10 Gaussians"), "{e}");
}
