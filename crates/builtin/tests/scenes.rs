//! Scene generation, masks, ground-truth edits and the dataset writer.

#![allow(clippy::needless_range_loop)]

use transsplat_builtin::dataset::PLY_PATH;
use transsplat_builtin::{
    build, is_test, labels_from_extra, one_hot, write_dataset, Error, Material, Scene, SceneConfig,
    WriteOptions, SCENE_NAMES,
};
use transsplat_raster::{gaussian_stats, Splats};
use transsplat_scene::{cameras, image, ply, scene_paths, Gaussians};

fn quick(name: &str) -> Scene {
    build(name, &SceneConfig::quick()).unwrap()
}

#[test]
fn same_seed_gives_byte_identical_ply_and_another_seed_does_not() {
    for name in SCENE_NAMES {
        let a = ply::to_bytes(&quick(name).gaussians_with_labels());
        let b = ply::to_bytes(&quick(name).gaussians_with_labels());
        assert!(a == b, "{name}: not deterministic");
        let c = build(name, &SceneConfig { seed: 7, ..SceneConfig::quick() }).unwrap();
        assert!(ply::to_bytes(&c.gaussians_with_labels()) != a, "{name}: seed ignored");
    }
}

#[test]
fn sizes_and_label_counts() {
    for (name, objects) in [("tabletop", 4), ("occluded", 3), ("garden", 4)] {
        let s = build(name, &SceneConfig::default()).unwrap();
        let n = s.gaussians.len();
        eprintln!(
            "{name}: {n} Gaussians, {:?} per label; quick {:?}",
            s.label_counts(),
            quick(name).label_counts()
        );
        assert!((30_000..=80_000).contains(&n), "{name}: {n} Gaussians");
        assert_eq!(s.objects.len(), objects);
        assert_eq!(s.labels.len(), n);
        assert!(s.gaussians.validate().is_ok());
        assert!(s.gaussians.first_non_finite().is_none());
        assert_eq!(s.gaussians.sh_degree, 1);
        let counts = s.label_counts();
        assert_eq!(counts.len(), objects + 1);
        assert_eq!(counts.iter().sum::<usize>(), n);
        assert!(counts[0] > n / 2, "{name}: background {counts:?}");
        for o in &s.objects {
            assert!(counts[o.label as usize] >= 400, "{name}/{}: {counts:?}", o.name);
            assert_eq!(s.object(&o.name).unwrap().label, o.label);
        }
        assert_eq!(s.label_names()[0], "background");
        assert!(s.object(&s.target).is_some());
        assert_eq!(s.cameras.len(), 32);
        assert_eq!(s.test_views(), vec![0, 8, 16, 24]);
        assert_eq!(s.train_views().len(), 28);

        let q = quick(name);
        assert!((2_500..=8_000).contains(&q.gaussians.len()), "{name} quick: {}", q.gaussians.len());
        assert!(q.label_counts().iter().all(|&c| c > 50), "{name} quick: {:?}", q.label_counts());
    }
}

#[test]
fn unknown_scene_and_bad_config_are_errors() {
    let e = build("kitchen", &SceneConfig::quick()).unwrap_err().to_string();
    assert!(
        e.contains("kitchen") && e.contains("tabletop") && e.contains("occluded") && e.contains("garden"),
        "{e}"
    );
    for cfg in [
        SceneConfig { detail: 0.0, ..SceneConfig::quick() },
        SceneConfig { detail: f32::NAN, ..SceneConfig::quick() },
        SceneConfig { width: 0, ..SceneConfig::quick() },
        SceneConfig { views: 0, ..SceneConfig::quick() },
    ] {
        assert!(matches!(build("tabletop", &cfg), Err(Error::Invalid(_))), "{cfg:?}");
    }
    let s = quick("tabletop");
    let e = s.label_of("teapot").unwrap_err().to_string();
    assert!(e.contains("teapot") && e.contains("ball") && e.contains("vase"), "{e}");
    assert!(s.recolor(0, [0.0, 0.0, 1.0]).is_err(), "background is not an object");
    assert!(s.recolor(9, [0.0, 0.0, 1.0]).is_err());
    assert!(s.recolor(1, [0.0, 2.0, 1.0]).is_err());
    assert!(transsplat_builtin::recolor(&s.gaussians, &s.labels[1..], 1, [0.0; 3]).is_err());
}

#[test]
fn every_object_is_visible_in_most_views() {
    for name in SCENE_NAMES {
        let s = quick(name);
        let mut seen = vec![0usize; s.objects.len()];
        for v in 0..s.cameras.len() {
            let r = s.render_view(v).unwrap();
            for (k, o) in s.objects.iter().enumerate() {
                if r.area(o.label) > 0 {
                    seen[k] += 1;
                }
            }
            // the backdrop covers the frame: almost no empty pixels
            let empty = r.alpha.iter().filter(|&&a| a < 0.5).count();
            assert!(empty * 50 < r.alpha.len(), "{name} view {v}: {empty} empty pixels");
        }
        for (k, o) in s.objects.iter().enumerate() {
            assert!(seen[k] * 4 >= s.cameras.len() * 3, "{name}/{}: visible in {} views", o.name, seen[k]);
        }
    }
}

#[test]
fn ball_in_occluded_is_partly_hidden() {
    // the ball's rendered area is smaller than with the crate removed, in most views
    let s = quick("occluded");
    let crate_label = s.label_of("crate").unwrap();
    let ball = s.label_of("ball").unwrap();
    let keep: Vec<bool> = s.labels.iter().map(|&l| l != crate_label).collect();
    let mut g = s.gaussians.clone();
    g.retain(&keep);
    let labels: Vec<u32> = s.labels.iter().copied().filter(|&l| l != crate_label).collect();
    let mut hidden = 0;
    for (v, cam) in s.cameras.iter().enumerate() {
        let with = s.render_view(v).unwrap().area(ball);
        let without =
            transsplat_builtin::render_labels(&g, &labels, s.num_labels(), cam, s.background).area(ball);
        if (with as f32) < 0.85 * without as f32 {
            hidden += 1;
        }
    }
    assert!(hidden * 2 >= s.cameras.len(), "ball occluded in only {hidden} views");
}

/// Mean diffuse colour of each label's Gaussians.
fn mean_colours(s: &Scene) -> Vec<[f32; 3]> {
    let mut sum = vec![[0.0f64; 3]; s.num_labels()];
    let mut n = vec![0usize; s.num_labels()];
    for (i, &l) in s.labels.iter().enumerate() {
        let c = transsplat_builtin::edit::dc_colour(&s.gaussians, i);
        for k in 0..3 {
            sum[l as usize][k] += c[k] as f64;
        }
        n[l as usize] += 1;
    }
    sum.iter().zip(&n).map(|(c, &n)| c.map(|v| (v / n.max(1) as f64) as f32)).collect()
}

#[test]
fn garden_has_a_look_alike_a_large_background_and_thin_structures() {
    let g = quick("garden");
    let t = quick("tabletop");
    assert_eq!(g.target, "apple");
    // the tomato is the object closest in colour to the apple, and close
    let means = mean_colours(&g);
    let apple = g.label_of("apple").unwrap();
    let dist = |l: u32| {
        (0..3).map(|k| (means[l as usize][k] - means[apple as usize][k]).powi(2)).sum::<f32>().sqrt()
    };
    let nearest =
        g.objects.iter().filter(|o| o.label != apple).min_by(|a, b| dist(a.label).total_cmp(&dist(b.label)));
    assert_eq!(nearest.unwrap().name, "tomato");
    assert!(dist(g.label_of("tomato").unwrap()) < 0.25, "{means:?}");
    // the background takes a larger share of the pixels than on the tabletop
    let share = |s: &Scene, l: u32| {
        let (mut hit, mut all) = (0usize, 0usize);
        for v in 0..s.cameras.len() {
            let r = s.render_view(v).unwrap();
            hit += r.area(l);
            all += r.labels.len();
        }
        hit as f64 / all as f64
    };
    // (tabletop: 0.905 background, 0.026 ball; garden: 0.934 background, 0.011 apple)
    let (bg_g, bg_t) = (share(&g, 0), share(&t, 0));
    assert!(bg_g > 0.92 && bg_g > bg_t + 0.02, "background share: garden {bg_g}, tabletop {bg_t}");
    let (ta_g, ta_t) = (share(&g, apple), share(&t, t.label_of("ball").unwrap()));
    assert!(ta_g < 0.6 * ta_t, "target share: garden {ta_g}, tabletop {ta_t}");
    // the lamp and the fence are thin: the median length of their runs of pixels along
    // a row (lamp: a vertical pole) or a column (fence: horizontal rails) is at most 4
    // pixels, while the apple's is more than 6
    let median_run = |l: u32, by_row: bool| {
        let mut runs = Vec::new();
        for v in 0..g.cameras.len() {
            let r = g.render_view(v).unwrap();
            let (lines, len) = if by_row { (r.height, r.width) } else { (r.width, r.height) };
            for a in 0..lines {
                let at = |b: usize| if by_row { a * r.width + b } else { b * r.width + a };
                let mut run = 0;
                for b in 0..=len {
                    if b < len && r.labels[at(b)] == l {
                        run += 1;
                    } else if run > 0 {
                        runs.push(run);
                        run = 0;
                    }
                }
            }
        }
        runs.sort_unstable();
        runs.get(runs.len() / 2).copied().unwrap_or(0)
    };
    let lamp = median_run(g.label_of("lamp").unwrap(), true);
    let fence = median_run(g.label_of("fence").unwrap(), false);
    eprintln!("lamp {lamp} px, fence {fence} px, apple {} px", median_run(apple, true));
    assert!((1..=4).contains(&lamp) && (1..=4).contains(&fence), "lamp {lamp} px, fence {fence} px");
    assert!(median_run(apple, true) > 6, "apple {} px", median_run(apple, true));
    // the cameras orbit wider and farther than the tabletop's
    let reach = |s: &Scene| s.cameras.iter().map(|c| c.centre()[0].abs()).fold(0f32, f32::max);
    assert!(reach(&g) > 1.5 * reach(&t), "{} vs {}", reach(&g), reach(&t));
}

#[test]
fn masks_splat_back_onto_the_labels() {
    for name in SCENE_NAMES {
        let s = quick(name);
        let nl = s.num_labels();
        let (mut agree, mut total) = (0usize, 0usize);
        for v in (0..s.cameras.len()).step_by(3) {
            let r = s.render_view(v).unwrap();
            let mask_onehot = one_hot(&r.labels, nl);
            let st = gaussian_stats(&Splats::new(&s.gaussians), &s.cameras[v], Some((&mask_onehot, nl)));
            for i in 0..s.gaussians.len() {
                if st.weight_sum[i] < 1.0 {
                    continue;
                }
                let w = &st.splat[i * nl..(i + 1) * nl];
                let best = (0..nl).fold(0, |b, k| if w[k] > w[b] { k } else { b });
                total += 1;
                agree += (best as u32 == s.labels[i]) as usize;
            }
        }
        assert!(total > 1000, "{name}: {total}");
        let frac = agree as f64 / total as f64;
        assert!(frac > 0.95, "{name}: mask/label agreement {frac}");
    }
}

fn assert_same_except(a: &Gaussians, b: &Gaussians, labels: &[u32], target: u32) {
    assert_eq!(a.means, b.means);
    assert_eq!(a.log_scales, b.log_scales);
    assert_eq!(a.rotations, b.rotations);
    assert_eq!(a.opacity_logits, b.opacity_logits);
    let k = a.sh_coeffs() * 3;
    let mut changed = 0;
    for i in 0..a.len() {
        let (x, y) = (&a.sh[i * k..(i + 1) * k], &b.sh[i * k..(i + 1) * k]);
        let same = x.iter().zip(y).all(|(p, q)| p.to_bits() == q.to_bits());
        if labels[i] == target {
            changed += !same as usize;
        } else {
            assert!(same, "Gaussian {i} (label {}) changed", labels[i]);
        }
    }
    let n = labels.iter().filter(|&&l| l == target).count();
    assert!(changed * 10 >= n * 9, "only {changed} of {n} target Gaussians changed");
}

#[test]
fn recolor_changes_only_the_target_and_moves_its_pixels_to_the_colour() {
    let s = quick("tabletop");
    let ball = s.label_of("ball").unwrap();
    let blue = [0.1, 0.2, 0.9];
    let before = s.gaussians.clone();
    let edited = s.recolor(ball, blue).unwrap();
    assert_eq!(s.gaussians, before, "input modified");
    assert_same_except(&s.gaussians, &edited, &s.labels, ball);
    let (mut d_before, mut d_after, mut inside, mut untouched) = (0.0f64, 0.0f64, 0usize, 0usize);
    for v in [0, 5, 11] {
        let src = s.render_view(v).unwrap();
        let out = s.render_edited(&edited, v).unwrap();
        let wt = src.weight(ball);
        for p in 0..src.labels.len() {
            let (a, b) = (&src.rgb[p * 3..p * 3 + 3], &out.rgb[p * 3..p * 3 + 3]);
            if wt[p] == 0.0 {
                assert!(
                    a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits()),
                    "view {v} pixel {p} changed"
                );
                untouched += 1;
            } else if src.labels[p] == ball {
                let dist = |c: &[f32]| (0..3).map(|k| (c[k] - blue[k]).powi(2)).sum::<f32>().sqrt() as f64;
                d_before += dist(a);
                d_after += dist(b);
                inside += 1;
            }
        }
    }
    assert!(inside > 100 && untouched > inside);
    assert!(
        d_after < 0.35 * d_before,
        "mean distance to blue {} -> {}",
        d_before / inside as f64,
        d_after / inside as f64
    );
}

#[test]
fn recolor_keeps_texture_as_luminance_variation() {
    let s = quick("tabletop");
    let crate_label = s.label_of("crate").unwrap();
    let g = s.recolor(crate_label, [0.5, 0.5, 0.5]).unwrap();
    let greys: Vec<f32> = (0..g.len())
        .filter(|&i| s.labels[i] == crate_label)
        .map(|i| transsplat_builtin::edit::dc_colour(&g, i)[0])
        .collect();
    let (lo, hi) = greys.iter().fold((1f32, 0f32), |(l, h), &v| (l.min(v), h.max(v)));
    assert!(hi - lo > 0.1, "texture lost: {lo}..{hi}");
    let mean = greys.iter().sum::<f32>() / greys.len() as f32;
    assert!((mean - 0.5).abs() < 0.05, "{mean}");
    // higher SH of the target are zeroed
    let k = g.sh_coeffs() * 3;
    let i = s.labels.iter().position(|&l| l == crate_label).unwrap();
    assert!(g.sh[i * k + 3..(i + 1) * k].iter().all(|&v| v == 0.0));
}

#[test]
fn retexture_changes_only_the_target_and_materials_differ() {
    let s = quick("occluded");
    let ball = s.label_of("ball").unwrap();
    let mut means = Vec::new();
    for m in Material::ALL {
        assert_eq!(Material::from_name(m.name()), Some(m));
        let g = s.retexture(ball, m).unwrap();
        assert_same_except(&s.gaussians, &g, &s.labels, ball);
        assert!(g.first_non_finite().is_none());
        let cols: Vec<[f32; 3]> = (0..g.len())
            .filter(|&i| s.labels[i] == ball)
            .map(|i| transsplat_builtin::edit::dc_colour(&g, i))
            .collect();
        assert!(cols.iter().flatten().all(|c| (-1e-5..=1.0 + 1e-5).contains(c)));
        let mean: [f32; 3] =
            std::array::from_fn(|k| cols.iter().map(|c| c[k]).sum::<f32>() / cols.len() as f32);
        let var = cols.iter().map(|c| (0..3).map(|k| (c[k] - mean[k]).powi(2)).sum::<f32>()).sum::<f32>()
            / cols.len() as f32;
        if m != Material::Gold {
            assert!(var > 1e-3, "{}: no texture (variance {var})", m.name());
        }
        means.push(mean);
    }
    for a in 0..means.len() {
        for b in a + 1..means.len() {
            let d: f32 = (0..3).map(|k| (means[a][k] - means[b][k]).abs()).sum();
            assert!(d > 0.05, "materials {a} and {b} look alike");
        }
    }
    assert_eq!(Material::from_name(" Golden "), Some(Material::Gold));
    assert_eq!(Material::from_name("plastic"), None);
}

#[test]
fn dataset_round_trips_through_the_scene_readers() {
    let s = quick("tabletop");
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("data");
    let mut calls = 0;
    let sum = write_dataset(&s, &dir, &WriteOptions::default(), &mut |_, _| calls += 1).unwrap();
    assert_eq!(calls, s.cameras.len());
    assert_eq!(sum.views, 16);
    assert_eq!(sum.test_views, 2);
    // nothing but the dataset beside it (no temporary folder left)
    let siblings: Vec<_> = std::fs::read_dir(tmp.path()).unwrap().collect();
    assert_eq!(siblings.len(), 1);

    assert_eq!(scene_paths::resolve_scene(&dir).unwrap(), dir.join(PLY_PATH));
    let g = ply::read(&dir.join(PLY_PATH)).unwrap();
    assert_eq!(labels_from_extra(&g).unwrap(), s.labels);
    let mut plain = g.clone();
    plain.extra = Default::default();
    assert_eq!(plain, s.gaussians);

    let cams = cameras::load(&dir).unwrap();
    assert_eq!(cams.len(), s.cameras.len());
    for (a, b) in cams.iter().zip(&s.cameras) {
        assert_eq!(a.stem(), b.stem());
        assert_eq!((a.width, a.height), (b.width, b.height));
        assert!((a.fx - b.fx).abs() < 1e-3 && (a.cx - b.cx).abs() < 1e-3);
        for (x, y) in a.centre().iter().zip(b.centre()) {
            assert!((x - y).abs() < 1e-4);
        }
    }
    let colmap = cameras::colmap::read_sparse(&dir.join("sparse/0")).unwrap();
    assert_eq!(colmap.cameras.len(), s.cameras.len());
    assert!(colmap.points.len() > 1000);
    for (a, b) in colmap.cameras.iter().zip(&s.cameras) {
        assert_eq!(a.stem(), b.stem());
        for i in 0..3 {
            assert!((a.translation[i] - b.translation[i]).abs() < 1e-4);
            for j in 0..3 {
                assert!((a.rotation[i][j] - b.rotation[i][j]).abs() < 1e-4);
            }
        }
    }

    let meta: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("labels.json")).unwrap()).unwrap();
    assert_eq!(meta["scene"], "tabletop");
    assert_eq!(meta["test_views"], serde_json::json!(["view_000", "view_008"]));
    assert_eq!(meta["objects"].as_array().unwrap().len(), 4);
    assert_eq!(meta["objects"][0]["name"], "ball");
    assert_eq!(meta["objects"][0]["label"], 1);
    // The typed reader rebuilds the scene bit for bit from what the writer recorded.
    let labels = transsplat_builtin::Labels::read(&dir.join("labels.json")).unwrap();
    assert_eq!(labels.views.len(), s.cameras.len());
    let rebuilt = build(&labels.scene, &labels.scene_config()).unwrap();
    assert_eq!(rebuilt.gaussians, s.gaussians);
    let keys = |v: &serde_json::Value| v.as_object().unwrap().keys().cloned().collect::<Vec<_>>();
    assert_eq!(keys(&serde_json::to_value(&labels).unwrap()), keys(&meta), "the reader keeps every field");
    for (i, cam) in s.cameras.iter().enumerate() {
        let view = &meta["views"][i];
        assert_eq!(view["test"], is_test(i));
        let img = image::read(&dir.join(view["image"].as_str().unwrap())).unwrap();
        assert_eq!((img.width, img.height), (cam.width as usize, cam.height as usize));
        let mask = image::read(&dir.join(view["mask"].as_str().unwrap())).unwrap();
        let r = s.render_view(i).unwrap();
        for (p, &l) in r.labels.iter().enumerate() {
            assert_eq!((mask.data[p * 3] * 255.0).round() as u32, l);
        }
        for o in &s.objects {
            assert_eq!(view["object_pixels"][&o.name], r.area(o.label));
        }
    }

    // an earlier dataset is replaced as a whole; a foreign non-empty folder is refused
    // unless forced, and forcing rewrites the files and deletes nothing
    std::fs::write(dir.join("stale.txt"), b"old").unwrap();
    write_dataset(&s, &dir, &WriteOptions::default(), &mut |_, _| {}).unwrap();
    assert!(!dir.join("stale.txt").exists() && dir.join("labels.json").is_file());
    let foreign = tmp.path().join("foreign");
    std::fs::create_dir(&foreign).unwrap();
    std::fs::write(foreign.join("mine.txt"), b"mine").unwrap();
    let e = write_dataset(&s, &foreign, &WriteOptions::default(), &mut |_, _| {}).unwrap_err().to_string();
    assert!(e.contains("not empty"), "{e}");
    assert_eq!(std::fs::read_dir(&foreign).unwrap().count(), 1);
    std::fs::write(dir.join("keep.txt"), b"mine").unwrap();
    std::fs::remove_file(dir.join("images/view_003.png")).unwrap();
    write_dataset(&s, &dir, &WriteOptions { force: true, ..Default::default() }, &mut |_, _| {}).unwrap();
    assert!(dir.join("images/view_003.png").is_file());
    assert_eq!(std::fs::read(dir.join("keep.txt")).unwrap(), b"mine");
    // an existing empty folder is fine
    let empty = tmp.path().join("empty");
    std::fs::create_dir(&empty).unwrap();
    write_dataset(&s, &empty, &WriteOptions::default(), &mut |_, _| {}).unwrap();
    assert!(empty.join("labels.json").is_file());
    // a file in the way is an error
    let file = tmp.path().join("file");
    std::fs::write(&file, b"x").unwrap();
    assert!(write_dataset(&s, &file, &WriteOptions { force: true, ..Default::default() }, &mut |_, _| {})
        .is_err());
}
