//! Content fingerprints: a scene's and a view's identity by what they hold, not by
//! file names, so results made for one scene and camera are never taken for another's
//! (docs/method.md#e6-sharded-views-and-content-names). Built on the project's one
//! input hash, [`archive::Hasher`] (not cryptographic: it guards against mix-ups, not
//! against forgery).
//!
//! - [`add_scene`] / [`scene`]: everything that changes a render (centres, log-scales,
//!   rotations, opacity logits, SH degree and coefficients); extra properties (e.g.
//!   semantic latents) are left out.
//! - [`view`]: 16 hex digits over a scene fingerprint and one camera (name, size,
//!   intrinsics, pose): the content name of that view's files.

use crate::archive::Hasher;
use crate::{Camera, Gaussians};

/// Feeds the render-relevant parameters of `g` to `h` (the edit checkpoint's run
/// identity adds the extras after them).
pub fn add_scene<'h>(h: &'h mut Hasher, g: &Gaussians) -> &'h mut Hasher {
    h.f32s(g.means.as_flattened())
        .f32s(g.log_scales.as_flattened())
        .f32s(g.rotations.as_flattened())
        .f32s(&g.opacity_logits)
        .u64(g.sh_degree as u64)
        .f32s(&g.sh)
}

/// The scene's fingerprint: 16 hex digits.
pub fn scene(g: &Gaussians) -> String {
    format!("{:016x}", add_scene(&mut Hasher::default(), g).finish())
}

/// The content name of one view of the scene with fingerprint `scene`: 16 hex digits.
pub fn view(scene: &str, cam: &Camera) -> String {
    let mut h = Hasher::default();
    h.str(scene).str(&cam.name).u64(cam.width as u64).u64(cam.height as u64);
    h.f32s(&[cam.fx, cam.fy, cam.cx, cam.cy]).f32s(cam.rotation.as_flattened()).f32s(&cam.translation);
    format!("{:016x}", h.finish())
}

/// True when `s` looks like a [`view`] fingerprint (16 lowercase hex digits).
pub fn is_view_key(s: &str) -> bool {
    s.len() == 16 && s.bytes().all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam() -> Camera {
        Camera { translation: [0.0, 0.0, 1.0], ..Camera::pinhole("0001.png", 4, 3, 2.0) }
    }

    fn scene_of(x: f32) -> Gaussians {
        Gaussians {
            means: vec![[x, 0.0, 0.0]],
            log_scales: vec![[0.0; 3]],
            rotations: vec![[1.0, 0.0, 0.0, 0.0]],
            opacity_logits: vec![0.0],
            sh_degree: 0,
            sh: vec![0.5; 3],
            extra: Default::default(),
        }
    }

    #[test]
    fn fingerprints_follow_content_only() {
        let a = scene(&scene_of(0.0));
        assert_eq!(a.len(), 16);
        assert_eq!(a, scene(&scene_of(0.0)), "deterministic");
        assert_ne!(a, scene(&scene_of(1e-7)), "any change of a centre changes it");
        let mut with_extra = scene_of(0.0);
        with_extra.extra.names.push("sem_0".into());
        with_extra.extra.values.push(3.0);
        assert_eq!(a, scene(&with_extra), "extra properties do not change a render");
        let k = view(&a, &cam());
        assert!(is_view_key(&k), "{k}");
        let mut moved = cam();
        moved.translation[2] = 1.5;
        assert_ne!(k, view(&a, &moved));
        let mut renamed = cam();
        renamed.name = "0002.png".into();
        assert_ne!(k, view(&a, &renamed));
        assert_ne!(k, view(&scene(&scene_of(1.0)), &cam()));
        assert!(!is_view_key("0123456789abcdeg") && !is_view_key("0123"));
    }
}
