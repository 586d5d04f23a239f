use super::*;
use crate::{build, SceneConfig};
use std::sync::OnceLock;

fn scene() -> &'static Scene {
    static S: OnceLock<Scene> = OnceLock::new();
    S.get_or_init(|| build("tabletop", &SceneConfig::quick()).expect("tabletop builds"))
}

/// Source renders of the scene's training views.
fn sources() -> &'static Vec<(usize, Vec<f32>)> {
    static R: OnceLock<Vec<(usize, Vec<f32>)>> = OnceLock::new();
    R.get_or_init(|| {
        let s = scene();
        s.train_views().into_iter().map(|i| (i, s.render_view(i).expect("view").rgb)).collect()
    })
}

fn views() -> Vec<SourceView<'static>> {
    let s = scene();
    sources().iter().map(|(i, img)| SourceView { index: *i, camera: &s.cameras[*i], image: img }).collect()
}

fn run(severity: f32, seed: u64, prompt: &str) -> (SimulatedEditor, Vec<EditedView>) {
    let mut ed = SimulatedEditor::new(scene(), severity, seed);
    let out = ed.edit(&views(), prompt).expect("edit succeeds");
    (ed, out.into_iter().map(|v| v.expect("every view edited")).collect())
}

#[test]
fn instruction_parsing_table() {
    let s = scene();
    let ok = [
        ("make the ball blue", "recolor ball to blue (0.10, 0.20, 0.90)"),
        ("Make the BALL Blue!", "recolor ball to blue (0.10, 0.20, 0.90)"),
        ("paint the vase red", "recolor vase to red (0.85, 0.10, 0.10)"),
        ("turn the crate into marble", "retexture crate with marble"),
        ("make the ball look like gold", "retexture ball with gold"),
        ("make the balls golden", "retexture ball with gold"),
        ("turn the red ball purple", "recolor ball to purple (0.50, 0.15, 0.70)"),
        ("give the cone a wooden look", "retexture cone with wood"),
        ("a grey vase", "recolor vase to grey (0.50, 0.50, 0.50)"),
        ("make the ball and the crate blue", "recolor ball and crate to blue (0.10, 0.20, 0.90)"),
        ("make the cones, the ball and the vase golden", "retexture ball, vase and cone with gold"),
        ("turn the red ball and the cone white", "recolor ball and cone to white (0.95, 0.95, 0.95)"),
        ("make it autumn", "restyle the whole scene as autumn"),
        ("give the scene a winter look", "restyle the whole scene as winter"),
        ("Make everything SEPIA.", "restyle the whole scene as sepia"),
    ];
    for (prompt, want) in ok {
        let ins = parse_instruction(s, prompt).unwrap_or_else(|e| panic!("{prompt:?}: {e}"));
        assert_eq!(ins.describe(), want, "{prompt:?}");
        let labels: Vec<u32> = ins.objects.iter().map(|o| s.label_of(o).unwrap()).collect();
        if ins.is_global() {
            assert!(ins.objects.is_empty());
            assert_eq!(ins.labels, vec![0, 1, 2, 3, 4], "{prompt:?}: every label, the background included");
        } else {
            assert_eq!(ins.labels, labels, "{prompt:?}");
        }
    }
    let bad = [
        ("", &["empty instruction"][..]),
        ("   ", &["empty instruction"]),
        ("make the dragon blue", &["names none of the scene's objects", "ball, crate, vase, cone", "autumn"]),
        ("make the baller blue", &["names none"]),
        ("make it blue", &["names none of the scene's objects", "no style of the whole scene"]),
        ("make it nice", &["names none", "autumn, winter, sepia"]),
        ("make the ball pretty", &["names the ball but no colour or material", "blue", "marble", "stripes"]),
        ("make the ball and the cone pretty", &["names the ball and cone but no colour or material"]),
        ("make the ball blue and red", &["several changes", "blue, red"]),
        ("make the ball blue marble", &["several changes"]),
        ("make it autumn and winter", &["several changes", "autumn, winter"]),
        ("make the ball autumn", &["the autumn style, which changes the whole scene", "objects (ball)"]),
    ];
    for (prompt, wants) in bad {
        let e = parse_instruction(s, prompt).expect_err(prompt);
        assert!(matches!(e, Error::Instruction(_)), "{prompt:?}: {e:?}");
        let msg = e.to_string();
        for w in wants {
            assert!(msg.contains(w), "{prompt:?}: {msg:?} lacks {w:?}");
        }
    }
    // an empty prompt is refused by the editor itself, with the exact message
    let mut ed = SimulatedEditor::new(s, 1.0, 0);
    assert_eq!(ed.edit(&views(), "").unwrap_err().to_string(), "empty instruction");
    assert!(ed.target_labels().is_empty());
}

#[test]
fn severity_zero_is_the_ground_truth_render() {
    let s = scene();
    let (ed, out) = run(0.0, 3, "make the ball blue");
    let ball = s.label_of("ball").unwrap();
    assert_eq!(ed.target_labels(), [ball]);
    assert_eq!(ed.describe(), "recolor ball to blue (0.10, 0.20, 0.90)");
    assert_eq!(ed.ground_truth(), &s.recolor(ball, [0.1, 0.2, 0.9]).unwrap());
    let mut changed = 0usize;
    for ((i, src), v) in sources().iter().zip(&out) {
        let want = s.render_edited(ed.ground_truth(), *i).unwrap();
        assert_eq!(v.image, want.rgb, "view {i}");
        assert_eq!(v.attention, want.weight(ball).iter().map(|w| w.clamp(0.0, 1.0)).collect::<Vec<_>>());
        assert!(v.mask.is_none());
        assert_eq!(v.image.len(), v.width * v.height * 3);
        changed += v.image.iter().zip(src).filter(|(a, b)| (*a - *b).abs() > 0.05).count();
    }
    assert!(changed > 100, "the edit changes the images ({changed} values)");
}

struct Errors {
    /// Mean absolute error against the ground truth outside the target (dilated by 1 px).
    outside: f64,
    /// Standard deviation across views of the mean colour inside the target.
    spread: f64,
    /// Mean attention inside the target / outside it.
    ratio: f64,
}

fn errors(severity: f32, seed: u64) -> Errors {
    let s = scene();
    let (ed, out) = run(severity, seed, "make the ball blue");
    let labels = ed.target_labels().to_vec();
    let (mut err, mut cnt) = (0.0f64, 0usize);
    let mut means = Vec::new();
    let (mut a_in, mut n_in, mut a_out, mut n_out) = (0.0f64, 0usize, 0.0f64, 0usize);
    for ((i, _), v) in sources().iter().zip(&out) {
        let gt = s.render_edited(ed.ground_truth(), *i).unwrap();
        let target = gt.mask_of(&labels);
        let near =
            distance_to(&target, v.width, v.height).unwrap_or_else(|| vec![f32::INFINITY; target.len()]);
        let mut sum = [0.0f64; 3];
        let mut k = 0usize;
        for p in 0..target.len() {
            if target[p] {
                for (acc, &x) in sum.iter_mut().zip(&v.image[p * 3..p * 3 + 3]) {
                    *acc += x as f64;
                }
                k += 1;
                a_in += v.attention[p] as f64;
                n_in += 1;
            } else if near[p] > 1.5 {
                for c in 0..3 {
                    err += (v.image[p * 3 + c] - gt.rgb[p * 3 + c]).abs() as f64;
                }
                cnt += 3;
                a_out += v.attention[p] as f64;
                n_out += 1;
            }
        }
        if k > 20 {
            means.push(sum.map(|x| x / k as f64));
        }
    }
    assert!(means.len() >= 5, "the ball is visible in most views");
    let centre: [f64; 3] =
        std::array::from_fn(|c| means.iter().map(|m| m[c]).sum::<f64>() / means.len() as f64);
    let spread = (means.iter().map(|m| (0..3).map(|c| (m[c] - centre[c]).powi(2)).sum::<f64>()).sum::<f64>()
        / means.len() as f64)
        .sqrt();
    eprintln!(
        "severity {severity}: outside error {:.5}, spread {:.5}, attention ratio {:.2}",
        err / cnt as f64,
        spread,
        (a_in / n_in.max(1) as f64) / (a_out / n_out.max(1) as f64).max(1e-12)
    );
    Errors {
        outside: err / cnt as f64,
        spread,
        ratio: (a_in / n_in.max(1) as f64) / (a_out / n_out.max(1) as f64).max(1e-12),
    }
}

#[test]
fn severity_increases_spill_and_inconsistency_and_attention_concentrates() {
    let e0 = errors(0.0, 7);
    let e1 = errors(0.5, 7);
    let e2 = errors(1.0, 7);
    let e3 = errors(2.0, 7);
    assert_eq!(e0.outside, 0.0);
    assert!(
        e0.outside < e1.outside && e1.outside < e2.outside && e2.outside < e3.outside,
        "error outside the target: {} {} {} {}",
        e0.outside,
        e1.outside,
        e2.outside,
        e3.outside
    );
    assert!(
        e0.spread < e1.spread && e1.spread < e2.spread && e2.spread < e3.spread,
        "cross-view colour spread: {} {} {} {}",
        e0.spread,
        e1.spread,
        e2.spread,
        e3.spread
    );
    assert!(e2.ratio > 5.0, "attention inside / outside at severity 1: {}", e2.ratio);
}

#[test]
fn deterministic_by_seed_and_independent_of_the_view_set() {
    let (_, a) = run(1.0, 11, "turn the crate into marble");
    let (_, b) = run(1.0, 11, "turn the crate into marble");
    assert_eq!(a, b);
    let (_, c) = run(1.0, 12, "turn the crate into marble");
    assert_ne!(a, c);
    // one view alone gets the same result as within the full set
    let s = scene();
    let (i, img) = &sources()[3];
    let mut ed = SimulatedEditor::new(s, 1.0, 11);
    let one = ed
        .edit(&[SourceView { index: *i, camera: &s.cameras[*i], image: img }], "turn the crate into marble");
    assert_eq!(one.unwrap()[0].as_ref(), Some(&a[3]));
}

#[test]
fn mask_is_the_dilated_target_and_attention_is_non_negative() {
    let s = scene();
    let mut ed = SimulatedEditor::new(s, 1.0, 5).with_mask(true);
    let out = ed.edit(&views(), "paint the vase red").unwrap();
    let labels = ed.target_labels().to_vec();
    for ((i, _), v) in sources().iter().zip(&out) {
        let v = v.as_ref().unwrap();
        assert!(v.attention.iter().all(|a| a.is_finite() && *a >= 0.0));
        let mask = v.mask.as_ref().expect("mask requested");
        let target = s.render_edited(ed.ground_truth(), *i).unwrap().mask_of(&labels);
        let inside = target.iter().zip(mask).filter(|(t, _)| **t).all(|(_, m)| *m == 1.0);
        assert!(inside, "view {i}: the mask covers the target");
        let (t, m) = (target.iter().filter(|t| **t).count(), mask.iter().filter(|m| **m > 0.5).count());
        assert!(m >= t && (m == 0 || m <= 3 * t + 200), "view {i}: mask {m} px for a {t} px target");
    }
}

#[test]
fn a_view_that_misses_the_target_still_gets_an_edit() {
    let s = scene();
    let mut cam = s.cameras[1].clone();
    // turn the camera around its own y axis: same centre, looking away from the table
    for k in [0, 2] {
        cam.rotation[k] = cam.rotation[k].map(|v| -v);
        cam.translation[k] = -cam.translation[k];
    }
    let img = vec![0.0f32; cam.width as usize * cam.height as usize * 3];
    let view = SourceView { index: 1, camera: &cam, image: &img };
    let mut ed = SimulatedEditor::new(s, 0.0, 1);
    let out = ed.edit(&[view], "make the ball blue").unwrap();
    let v = out[0].as_ref().expect("an edited view");
    assert!(v.attention.iter().all(|&a| a == 0.0));
    let mut ed = SimulatedEditor::new(s, 1.0, 1);
    assert!(ed.edit(&[view], "make the ball blue").unwrap()[0].is_some());
    // a view whose image does not match its camera is refused, not a panic
    let short = SourceView { index: 1, camera: &cam, image: &img[..9] };
    assert!(matches!(ed.edit(&[short], "make the ball blue"), Err(Error::Invalid(_))));
}

#[test]
fn distance_transform_by_hand() {
    let mut m = vec![false; 5 * 3];
    m[5 + 1] = true; // (1, 1)
    let d = distance_to(&m, 5, 3).unwrap();
    assert_eq!(d[5 + 1], 0.0);
    assert_eq!(d[5 + 4], 3.0);
    assert!((d[4] - 10f32.sqrt()).abs() < 1e-6);
    assert!((d[0] - 2f32.sqrt()).abs() < 1e-6);
    assert!(distance_to(&[false; 4], 2, 2).is_none());
}

#[test]
fn hue_rotation_by_hand() {
    let close = |a: [f32; 3], b: [f32; 3]| a.iter().zip(&b).all(|(x, y)| (x - y).abs() < 1e-6);
    // +120° about the grey axis turns red to green, green to blue
    let r = hue_rotation(120f32.to_radians());
    assert!(close(mat_vec(&r, [1.0, 0.0, 0.0]), [0.0, 1.0, 0.0]), "{r:?}");
    assert!(close(mat_vec(&r, [0.0, 1.0, 0.0]), [0.0, 0.0, 1.0]));
    // 0° is the identity; a grey stays itself at any angle
    assert!(close(mat_vec(&hue_rotation(0.0), [0.3, 0.6, 0.9]), [0.3, 0.6, 0.9]));
    assert!(close(mat_vec(&hue_rotation(0.7), [0.4; 3]), [0.4; 3]));
    // a rotation keeps the mean and the distance from the grey axis
    let p = [0.8, 0.2, 0.1];
    let q = mat_vec(&hue_rotation(0.5), p);
    let mean = |c: [f32; 3]| (c[0] + c[1] + c[2]) / 3.0;
    let chroma = |c: [f32; 3]| c.iter().map(|v| (v - mean(c)).powi(2)).sum::<f32>().sqrt();
    assert!((mean(q) - mean(p)).abs() < 1e-6 && (chroma(q) - chroma(p)).abs() < 1e-6, "{q:?}");
    assert!(!close(q, p));
    // R(θ)·R(−θ) = I
    assert!(close(mat_vec(&hue_rotation(-0.5), q), p));
}

#[test]
fn failure_probabilities_and_strengths_follow_severity() {
    // rates of the distractor (min(1, 0.25 s)), the wrong-object view (min(0.4, 0.1 s)),
    // half of which edit another object, over 4000 views
    for (s, p_d, p_w) in [(1.0f32, 0.25f64, 0.1f64), (2.0, 0.5, 0.2), (4.0, 1.0, 0.4), (10.0, 1.0, 0.4)] {
        let (mut fired, mut wrong, mut other) = (0usize, 0usize, 0usize);
        let n = 4000;
        for v in 0..n {
            let d = draw(&mut view_rng(9, v), s, 3);
            if let Some(a) = d.distractor {
                fired += 1;
                assert!(a >= (0.2 * s).min(0.8) - 1e-6 && a <= (0.4 * s).min(0.8), "s {s}: strength {a}");
            }
            match d.wrong {
                Some(Wrong::Other(k)) => {
                    assert!(k < 3);
                    wrong += 1;
                    other += 1;
                }
                Some(Wrong::Nothing) => wrong += 1,
                None => {}
            }
            assert!(d.cast.iter().all(|k| *k >= 0.0) && d.gain.iter().all(|g| *g >= 0.0));
        }
        let rate = |k: usize| k as f64 / n as f64;
        assert!((rate(fired) - p_d).abs() < 0.03, "s {s}: distractor rate {}", rate(fired));
        assert!((rate(wrong) - p_w).abs() < 0.025, "s {s}: wrong-object rate {}", rate(wrong));
        assert!((other as f64 / wrong as f64 - 0.5).abs() < 0.1, "s {s}: {other} of {wrong} edit another");
    }
    // without another object, a wrong view returns the source
    for v in 0..200 {
        assert!(!matches!(draw(&mut view_rng(9, v), 4.0, 0).wrong, Some(Wrong::Other(_))));
    }
}

/// The ground-truth render, source and setting of view `i` of the tabletop for `prompt`.
fn setting_for(prompt: &str) -> (SimulatedEditor, Prepared) {
    let mut ed = SimulatedEditor::new(scene(), 4.0, 0);
    ed.instruct(prompt).unwrap();
    let p = ed.current.clone().unwrap();
    (ed, p)
}

#[test]
fn wrong_object_views_edit_another_object_or_return_the_source_under_the_cast() {
    let s = scene();
    let (_, p) = setting_for("make the ball blue");
    let set = Corruption {
        labels: p.ins.labels.clone(),
        global: false,
        colour: p.colour,
        distractor: p.distractor,
        others: p.others.clone(),
        severity: 4.0,
        want_mask: false,
        seed: 0,
    };
    let (i, src) = &sources()[2];
    let r = s.render_edited(&p.truth, *i).unwrap();
    let ball = s.label_of("ball").unwrap();
    let on = |a: &[f32], l: u32| {
        let (sum, n) =
            r.labels.iter().zip(a).filter(|(&x, _)| x == l).fold((0.0, 0), |(s, n), (_, &v)| (s + v, n + 1));
        sum / n.max(1) as f32
    };
    let (mut nothing, mut other) = (false, false);
    for seed in 0..400u64 {
        let rng = view_rng(seed, *i);
        let d = draw(&mut rng.clone(), 4.0, p.others.len());
        let c = corrupt(&r, src, &set, &mut rng.clone());
        match d.wrong {
            Some(Wrong::Nothing) if !nothing => {
                nothing = true;
                // the source render under the cast, exactly; attention near zero
                let want: Vec<f32> = src.chunks_exact(3).flat_map(|px| cast(&d, rgb(px))).collect();
                assert_eq!(c.image, want, "seed {seed}");
                assert!(on(&c.attention, ball) < 0.15, "attention on the ball {}", on(&c.attention, ball));
            }
            Some(Wrong::Other(k)) if !other => {
                other = true;
                let o = p.others[k];
                // the target is left as in the source (under the cast), the other object edited
                for (q, &l) in r.labels.iter().enumerate() {
                    if l == ball && r.weight(o)[q] == 0.0 {
                        let want = cast(&d, rgb(&src[q * 3..q * 3 + 3]));
                        assert_eq!(rgb(&c.image[q * 3..q * 3 + 3]), want, "seed {seed} pixel {q}");
                    }
                }
                assert!(on(&c.attention, o) > 0.5, "attention on the edited object {}", on(&c.attention, o));
                assert!(on(&c.attention, ball) < 0.15, "attention on the ball {}", on(&c.attention, ball));
            }
            _ => {}
        }
        if nothing && other {
            return;
        }
    }
    panic!("no wrong-object view in 400 seeds (nothing {nothing}, other {other})");
}

#[test]
fn the_distractor_is_the_look_alike_and_draws_attention() {
    let s = scene();
    let (ed, _) = setting_for("make the ball blue");
    assert_eq!(ed.distractor(), Some(s.label_of("crate").unwrap()), "the crate is the nearest colour to red");
    // mean attention per label over the views at severity 2 (distractor in half the views)
    let attention_on = |severity: f32| {
        let (ed, out) = run(severity, 21, "make the ball blue");
        let mut sum = vec![0.0f64; s.num_labels()];
        let mut n = vec![0usize; s.num_labels()];
        for ((i, _), v) in sources().iter().zip(&out) {
            let r = s.render_edited(ed.ground_truth(), *i).unwrap();
            for (l, a) in r.labels.iter().zip(&v.attention) {
                sum[*l as usize] += *a as f64;
                n[*l as usize] += 1;
            }
        }
        sum.iter().zip(&n).map(|(s, &n)| s / n.max(1) as f64).collect::<Vec<_>>()
    };
    let [crate_, vase, cone] = ["crate", "vase", "cone"].map(|o| s.label_of(o).unwrap() as usize);
    let a0 = attention_on(0.0);
    assert!(a0[crate_] < 0.01, "attention per label at severity 0: {a0:?}");
    let a2 = attention_on(2.0);
    eprintln!("attention per label: severity 0 {a0:?}, severity 2 {a2:?}");
    assert!(a2[crate_] > a2[vase].max(a2[cone]) + 0.1, "attention per label at severity 2: {a2:?}");
    // a global edit and an edit of every object have no distractor
    assert_eq!(setting_for("make it sepia").0.distractor(), None);
    assert_eq!(setting_for("make the ball, crate, vase and cone red").0.distractor(), None);
}

#[test]
fn two_objects_are_both_edited() {
    let s = scene();
    let (ed, out) = run(0.0, 4, "make the ball and the cone blue");
    let (ball, cone) = (s.label_of("ball").unwrap(), s.label_of("cone").unwrap());
    assert_eq!(ed.target_labels(), [ball, cone]);
    let blue = [0.1, 0.2, 0.9];
    let want = crate::recolor(&s.recolor(ball, blue).unwrap(), &s.labels, cone, blue).unwrap();
    assert_eq!(ed.ground_truth(), &want);
    for ((i, _), v) in sources().iter().zip(&out) {
        let r = s.render_edited(&want, *i).unwrap();
        assert_eq!(v.image, r.rgb);
        assert_eq!(v.attention, r.weight_of(&[ball, cone]), "view {i}");
    }
}

#[test]
fn a_global_edit_gets_only_the_cast_and_the_hue_and_attention_one() {
    let s = scene();
    let (ed, out) = run(0.0, 4, "make it autumn");
    assert_eq!(ed.ground_truth(), &s.restyle(crate::Style::Autumn).unwrap());
    assert_eq!(ed.target_labels(), [0, 1, 2, 3, 4]);
    for ((i, _), v) in sources().iter().zip(&out) {
        assert_eq!(v.image, s.render_edited(ed.ground_truth(), *i).unwrap().rgb);
        assert!(v.attention.iter().all(|&a| a == 1.0));
    }
    // at severity 1 each view is clamp(k ⊙ clamp(R p)) of the ground truth, exactly
    let (ed, out) = run(1.0, 4, "make it autumn");
    let mut differ = 0;
    for ((i, _), v) in sources().iter().zip(&out) {
        let gt = s.render_edited(ed.ground_truth(), *i).unwrap().rgb;
        let d = draw(&mut view_rng(4, *i), 1.0, 0);
        let want: Vec<f32> =
            gt.chunks_exact(3).flat_map(|p| cast(&d, clamp01(mat_vec(&d.hue, rgb(p))))).collect();
        assert_eq!(v.image, want, "view {i}");
        assert!(v.attention.iter().all(|&a| a == 1.0));
        differ += (v.image != gt) as usize;
    }
    assert_eq!(differ, out.len(), "every view is corrupted");
}
