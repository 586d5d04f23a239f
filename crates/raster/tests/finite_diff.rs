//! Central finite differences of a random linear functional of the rendered images,
//! for every parameter group, on tiny scenes built so that no Gaussian–pixel pair
//! is near a hard decision (the 1/255 skip, the T ≤ 1e-4 stop, the 0.999 clamp,
//! the box edge): there the rendering is smooth and the gradient must match.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use transsplat_raster::{backward, render, ClampGrad, Grads, ImageGrads, RenderOptions, Splats};
use transsplat_scene::{Camera, Gaussians};

struct Case {
    g: Gaussians,
    feats: Vec<f32>,
    nf: usize,
    cam: Camera,
    opts: RenderOptions,
    v: [Vec<f32>; 4],
}

fn camera() -> Camera {
    let (w, h) = (12, 10);
    // Rotated slightly so the view direction → SH path is generic.
    let (a, b) = (0.1f32, -0.07f32);
    let ry = [[a.cos(), 0.0, a.sin()], [0.0, 1.0, 0.0], [-a.sin(), 0.0, a.cos()]];
    let rx = [[1.0, 0.0, 0.0], [0.0, b.cos(), -b.sin()], [0.0, b.sin(), b.cos()]];
    let r: [[f32; 3]; 3] =
        std::array::from_fn(|i| std::array::from_fn(|j| (0..3).map(|k| ry[i][k] * rx[k][j]).sum()));
    Camera {
        name: "fd".into(),
        width: w,
        height: h,
        fx: 9.0,
        fy: 10.0,
        cx: 6.2,
        cy: 4.9,
        rotation: r,
        translation: [0.05, -0.02, 0.1],
    }
}

fn case(seed: u64, n: usize, sh_degree: u32, nf: usize, background: [f32; 3]) -> Case {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let k = transsplat_scene::sh_coeffs(sh_degree);
    let mut g = Gaussians { sh_degree, ..Default::default() };
    for _ in 0..n {
        g.means.push([rng.gen_range(-0.3..0.3), rng.gen_range(-0.3..0.3), rng.gen_range(3.2..4.0)]);
        g.log_scales.push(std::array::from_fn(|_| rng.gen_range(1.4f32..1.9).ln()));
        g.rotations.push(std::array::from_fn(|_| rng.gen_range(-1.0..1.0)));
        g.opacity_logits.push(rng.gen_range(-1.5..0.0));
        for c in 0..k * 3 {
            g.sh.push(if c < 3 { rng.gen_range(0.0..1.0) } else { rng.gen_range(-0.2..0.2) });
        }
    }
    let feats = (0..n * nf).map(|_| rng.gen_range(-1.0..1.0)).collect();
    let cam = camera();
    let px = (cam.width * cam.height) as usize;
    let mut r = |m: usize| (0..m).map(|_| rng.gen_range(-1.0f32..1.0)).collect::<Vec<_>>();
    let v = [r(px * 3), r(px), r(px), r(px * nf)];
    Case { g, feats, nf, cam, opts: RenderOptions { background }, v }
}

fn loss(c: &Case, g: &Gaussians, feats: &[f32]) -> f64 {
    let s = Splats::new(g).with_features(feats, c.nf);
    let (img, _) = render(&s, &c.cam, &c.opts);
    let dot = |a: &[f32], b: &[f32]| a.iter().zip(b).map(|(x, y)| *x as f64 * *y as f64).sum::<f64>();
    dot(&img.rgb, &c.v[0]) + dot(&img.alpha, &c.v[1]) + dot(&img.depth, &c.v[2]) + dot(&img.features, &c.v[3])
}

/// Checks the scene is far from every hard decision of the compositor.
fn assert_smooth(c: &Case) {
    let s = Splats::new(&c.g);
    let stats = transsplat_raster::gaussian_stats(&s, &c.cam, None);
    let px = c.cam.width * c.cam.height;
    for (i, &n) in stats.pixel_count.iter().enumerate() {
        assert_eq!(n, px, "Gaussian {i} does not cover every pixel well above the 1/255 cutoff");
    }
    let (img, _) = render(&s, &c.cam, &c.opts);
    assert!(img.alpha.iter().all(|&a| a < 0.99), "transmittance too close to the stop rule");
}

fn analytic(c: &Case) -> Grads {
    let s = Splats::new(&c.g).with_features(&c.feats, c.nf);
    let (_, frame) = render(&s, &c.cam, &c.opts);
    let mut grads = Grads::zeros(c.g.len(), c.g.sh_degree, c.nf);
    let ig = ImageGrads {
        rgb: &c.v[0],
        alpha: &c.v[1],
        depth: &c.v[2],
        features: &c.v[3],
        clamp: ClampGrad::Exact, // the derivative of what is rendered
    };
    backward(&s, &c.cam, &frame, &ig, &mut grads);
    grads
}

fn check(name: &str, an: f32, fd: f64) {
    let tol = 3e-3 + 1.5e-2 * (an.abs() as f64).max(fd.abs());
    assert!((an as f64 - fd).abs() <= tol, "{name}: analytic {an} vs finite difference {fd}");
}

fn run(c: &Case) {
    assert_smooth(c);
    let an = analytic(c);
    let h = 1e-3f32;
    let fd = |edit: &dyn Fn(&mut Gaussians, &mut Vec<f32>, f32)| -> f64 {
        let (mut gp, mut fp) = (c.g.clone(), c.feats.clone());
        edit(&mut gp, &mut fp, h);
        let (mut gm, mut fm) = (c.g.clone(), c.feats.clone());
        edit(&mut gm, &mut fm, -h);
        (loss(c, &gp, &fp) - loss(c, &gm, &fm)) / (2.0 * h as f64)
    };
    let mut nonzero = 0;
    for i in 0..c.g.len() {
        for k in 0..3 {
            let d = fd(&|g, _, e| g.means[i][k] += e);
            check(&format!("mean[{i}][{k}]"), an.means[i][k], d);
            let d = fd(&|g, _, e| g.log_scales[i][k] += e);
            check(&format!("log_scale[{i}][{k}]"), an.log_scales[i][k], d);
            nonzero += (an.means[i][k].abs() > 1e-2) as usize;
        }
        for k in 0..4 {
            let d = fd(&|g, _, e| g.rotations[i][k] += e);
            check(&format!("rotation[{i}][{k}]"), an.rotations[i][k], d);
        }
        let d = fd(&|g, _, e| g.opacity_logits[i] += e);
        check(&format!("opacity[{i}]"), an.opacity_logits[i], d);
        let kc = c.g.sh_coeffs() * 3;
        for k in 0..kc {
            let d = fd(&|g, _, e| g.sh[i * kc + k] += e);
            check(&format!("sh[{i}][{k}]"), an.sh[i * kc + k], d);
        }
        for k in 0..c.nf {
            let d = fd(&|_, f, e| f[i * c.nf + k] += e);
            check(&format!("feature[{i}][{k}]"), an.features[i * c.nf + k], d);
        }
    }
    assert!(nonzero > 0, "all mean gradients vanish: the test would not detect anything");
}

#[test]
fn single_gaussian_degree_0() {
    run(&case(1, 1, 0, 0, [0.0; 3]));
}

#[test]
fn three_gaussians_degree_3_with_features_and_background() {
    run(&case(2, 3, 3, 3, [0.2, 0.5, 0.9]));
}

#[test]
fn four_gaussians_degree_1_and_2() {
    run(&case(3, 4, 1, 1, [1.0, 1.0, 1.0]));
    run(&case(4, 4, 2, 0, [0.0; 3]));
}

#[test]
fn gradients_and_statistics_are_bit_reproducible() {
    let g = transsplat_raster::synthetic::bench_scene(20_000, 3);
    let cam = transsplat_raster::synthetic::bench_camera(96, 80);
    let s = Splats::new(&g);
    let v: Vec<f32> = (0..96 * 80 * 3).map(|i| ((i * 31) % 7) as f32 - 3.0).collect();
    let run = || {
        let (_, frame) = render(&s, &cam, &RenderOptions::default());
        let mut grads = Grads::zeros(g.len(), g.sh_degree, 0);
        backward(&s, &cam, &frame, &ImageGrads { rgb: &v, ..Default::default() }, &mut grads);
        let st = transsplat_raster::gaussian_stats(&s, &cam, Some((&v, 3)));
        (grads, st)
    };
    let (g1, s1) = run();
    for _ in 0..3 {
        let (g2, s2) = run();
        assert!(g1 == g2 && s1 == s2, "results differ between identical runs");
    }
    assert!(g1.means.iter().flatten().any(|&x| x != 0.0));
}

/// The capped splat-back against its definition on one Gaussian, whose blend weight
/// is the rendered alpha (T = 1): the plain channel is Σ w G / Σ w, the capped one
/// Σ min(w, G) / Σ w.
#[test]
fn capped_splat_back_matches_its_definition() {
    let c = case(7, 1, 0, 0, [0.0; 3]);
    let s = Splats::new(&c.g);
    let (img, _) = render(&s, &c.cam, &c.opts);
    let px = img.alpha.len();
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let plane: Vec<f32> = (0..px * 2).map(|_| rng.gen_range(0.0f32..1.0)).collect();
    let st = transsplat_raster::gaussian_stats_capped(&s, &c.cam, Some((&plane, 2)), 1);
    let (mut sw, mut plain, mut capped) = (0.0f64, 0.0f64, 0.0f64);
    for (p, &w) in img.alpha.iter().enumerate() {
        let w = w as f64;
        sw += w;
        plain += w * plane[2 * p] as f64;
        capped += w.min(plane[2 * p + 1] as f64);
    }
    assert!(sw > 1.0 && (st.weight_sum[0] as f64 - sw).abs() < 1e-4 * sw);
    assert!((st.splat[0] as f64 - plain / sw).abs() < 1e-5, "{} vs {}", st.splat[0], plain / sw);
    assert!((st.splat[1] as f64 - capped / sw).abs() < 1e-5, "{} vs {}", st.splat[1], capped / sw);
    // The cap binds somewhere, so the test tells the two apart.
    assert!(img.alpha.iter().enumerate().any(|(p, &w)| w > plane[2 * p + 1] + 0.05));
}
