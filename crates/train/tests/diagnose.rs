//! The low-view diagnosis (`train::diagnose`): a splat right in front of a held-out
//! camera, which the training cameras beside it cannot see, is floaters; the same
//! scene without it is extrapolation.

use transsplat_scene::{Camera, Gaussians};
use transsplat_train::diagnose::{diagnose, Cause};
use transsplat_train::{Model, TrainConfig, Trainer};

/// A wall of opaque splats 5 in front of the origin, 4 × 3 wide, and optionally one
/// wide grey splat 0.4 in front of the origin.
fn scene(floater: bool) -> Trainer {
    let mut g = Gaussians { sh_degree: 0, ..Default::default() };
    let mut add = |m: [f32; 3], s: f32| {
        g.means.push(m);
        g.log_scales.push([s.ln(), s.ln(), (0.2 * s).ln()]);
        g.rotations.push([1.0, 0.0, 0.0, 0.0]);
        g.opacity_logits.push(4.0);
        g.sh.extend([0.5, -0.5, 0.2]);
    };
    for i in 0..40 {
        for j in 0..30 {
            add([-2.0 + 0.1 * i as f32, -1.5 + 0.1 * j as f32, 5.0], 0.06);
        }
    }
    if floater {
        add([0.0, 0.0, 0.4], 0.08);
    }
    Trainer::new(Model::new(g, 0), 3.0, TrainConfig::default()).unwrap()
}

/// A camera at (x, 0, 0) looking down +z.
fn camera(name: &str, x: f32) -> Camera {
    Camera { translation: [-x, 0.0, 0.0], ..Camera::pinhole(name, 64, 48, 60.0) }
}

#[test]
fn a_splat_only_the_held_out_camera_sees_near_it_is_floaters() {
    let test = camera("test", 0.0);
    let train = [camera("a", -1.5), camera("b", 1.5), camera("c", -1.0), camera("d", 1.0)];
    let hazy = diagnose(&scene(true), &test, &train);
    assert_eq!(hazy.cause, Cause::Floaters, "{hazy:?}");
    assert!(hazy.near_share > 0.2, "{hazy:?}");
    let clean = diagnose(&scene(false), &test, &train);
    assert_eq!(clean.cause, Cause::Extrapolation, "{clean:?}");
    assert_eq!(clean.near_share, 0.0);
    // A training camera at the test camera's place sees the splat where the test view
    // does: not a floater to it, so not near content.
    let seen = diagnose(&scene(true), &test, &[camera("same", 0.0)]);
    assert_eq!(seen.cause, Cause::Extrapolation, "{seen:?}");
}
