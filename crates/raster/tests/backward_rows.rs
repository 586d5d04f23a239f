//! The rows `backward` reports are exactly the rows it wrote, and clearing them
//! returns the gradient buffer to zero (the trainer's reuse of one buffer rests on it).

use transsplat_raster::synthetic::{bench_camera, bench_scene};
use transsplat_raster::{backward, render, Grads, ImageGrads, RenderOptions, Splats};

/// Row `i` of every gradient array, flattened.
fn row(g: &Grads, i: usize) -> Vec<f32> {
    let n = g.means.len();
    let kc = g.sh.len() / n;
    let mut r = Vec::new();
    r.extend(g.means[i]);
    r.extend(g.log_scales[i]);
    r.extend(g.rotations[i]);
    r.push(g.opacity_logits[i]);
    r.extend(&g.sh[i * kc..(i + 1) * kc]);
    r.extend(g.means2d[i]);
    r
}

#[test]
fn reported_rows_are_the_written_rows_and_clearing_them_zeroes_the_buffer() {
    // Dense enough that most pixels saturate: many Gaussians are never reached.
    let g = bench_scene(20_000, 3);
    let cam = bench_camera(64, 48);
    let s = Splats::new(&g);
    let (img, frame) = render(&s, &cam, &RenderOptions::default());
    let v: Vec<f32> = (0..img.rgb.len()).map(|i| ((i * 7919) % 13) as f32 / 13.0 - 0.5).collect();
    let mut grads = Grads::zeros(g.len(), g.sh_degree, 0);
    let rows = backward(&s, &cam, &frame, &ImageGrads { rgb: &v, ..Default::default() }, &mut grads);
    let nonzero: Vec<u32> =
        (0..g.len()).filter(|&i| row(&grads, i).iter().any(|&x| x != 0.0)).map(|i| i as u32).collect();
    assert!(rows.windows(2).all(|w| w[0] < w[1]), "rows are not ascending");
    // Every written row is reported; a reported row may hold exact zeros only if its
    // splat gradients cancelled, which a random image gradient does not do.
    assert_eq!(rows, nonzero);
    assert!(!rows.is_empty() && rows.len() < g.len() * 9 / 10, "{} of {} rows reached", rows.len(), g.len());
    grads.clear_rows(&rows);
    assert_eq!(grads, Grads::zeros(g.len(), g.sh_degree, 0));
}
