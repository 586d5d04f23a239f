//! Content fingerprints: a scene's and a view's identity by what they hold, not by
//! file names, so results made for one scene and camera are never taken for another's
//! (docs/method.md#e6-sharded-views-and-content-names).
//!
//! - [`scene`]: SHA-256 over everything that changes a render (SH degree, counts,
//!   centres, log-scales, rotations, opacity logits, SH coefficients as little-endian
//!   `f32`); extra properties (e.g. semantic latents) are left out.
//! - [`view`]: 16 hex digits of SHA-256 over a scene fingerprint and one camera (name,
//!   size, intrinsics, pose): the content name of that view's files.

use crate::{Camera, Gaussians};
use sha2::{Digest, Sha256};

fn floats<'a>(h: &mut Sha256, values: impl IntoIterator<Item = &'a f32>) {
    for v in values {
        h.update(v.to_le_bytes());
    }
}

/// The scene's fingerprint: 64 hex digits.
pub fn scene(g: &Gaussians) -> String {
    let mut h = Sha256::new();
    h.update(b"transsplat-scene-v1\0");
    h.update(g.sh_degree.to_le_bytes());
    h.update((g.len() as u64).to_le_bytes());
    floats(&mut h, g.means.iter().flatten());
    floats(&mut h, g.log_scales.iter().flatten());
    floats(&mut h, g.rotations.iter().flatten());
    floats(&mut h, &g.opacity_logits);
    floats(&mut h, &g.sh);
    hex(&h.finalize())
}

/// The content name of one view of the scene with fingerprint `scene`: 16 hex digits.
pub fn view(scene: &str, cam: &Camera) -> String {
    let mut h = Sha256::new();
    h.update(b"transsplat-view-v1\0");
    h.update(scene.as_bytes());
    h.update(b"\0");
    h.update(cam.name.as_bytes());
    h.update(b"\0");
    h.update(cam.width.to_le_bytes());
    h.update(cam.height.to_le_bytes());
    floats(&mut h, &[cam.fx, cam.fy, cam.cx, cam.cy]);
    floats(&mut h, cam.rotation.iter().flatten());
    floats(&mut h, &cam.translation);
    hex(&h.finalize()[..8])
}

/// True when `s` looks like a [`view`] fingerprint (16 lowercase hex digits).
pub fn is_view_key(s: &str) -> bool {
    s.len() == 16 && s.bytes().all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b))
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam() -> Camera {
        Camera {
            name: "0001.png".into(),
            width: 4,
            height: 3,
            fx: 2.0,
            fy: 2.0,
            cx: 2.0,
            cy: 1.5,
            rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            translation: [0.0, 0.0, 1.0],
        }
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
    fn known_digest_and_sensitivity() {
        // SHA-256 itself, against the FIPS 180-2 "abc" vector: the hex encoding is right
        assert_eq!(
            hex(&Sha256::digest(b"abc")),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
        let a = scene(&scene_of(0.0));
        assert_eq!(a.len(), 64);
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
        assert_ne!(k, view(&scene(&scene_of(1.0)), &cam()));
        assert!(!is_view_key("0123456789abcdeg") && !is_view_key("0123"));
    }
}
