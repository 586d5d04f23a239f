//! Camera rigs: views on an arc of rings in front of the backdrop, all looking at the
//! table centre, in the OpenCV convention (x right, y down, z forward; world-to-camera
//! extrinsics). World frame: z up, the backdrop wall at +y, cameras on the −y side.

use crate::build::{cross, normalize, sub};
use transsplat_scene::cameras::is_held_out;
use transsplat_scene::Camera;

pub use transsplat_scene::cameras::LLFF_HOLD;

/// True for the held-out test views (llffhold = 8: indices 0, 8, 16, ...).
pub fn is_test(index: usize) -> bool {
    is_held_out(index, LLFF_HOLD)
}

/// Where the cameras are and what they look at.
#[derive(Clone, Debug, PartialEq)]
pub struct Rig {
    /// Point every camera looks at.
    pub target: [f32; 3],
    /// Distance from the target.
    pub distance: f32,
    /// Elevations of the rings in degrees; camera `i` is on ring `i % rings.len()`.
    pub elevations_deg: Vec<f32>,
    /// Azimuth span in degrees, centred on the −y direction (facing the backdrop).
    pub azimuth_span_deg: f32,
    /// Horizontal field of view in degrees.
    pub fov_x_deg: f32,
}

/// A camera at `centre` looking at `target` with world up +z (OpenCV axes).
pub fn look_at(name: String, width: u32, height: u32, fx: f32, centre: [f32; 3], target: [f32; 3]) -> Camera {
    let f = normalize(sub(target, centre));
    let mut r = cross(f, [0.0, 0.0, 1.0]);
    if r.iter().map(|v| v * v).sum::<f32>() < 1e-12 {
        r = [1.0, 0.0, 0.0];
    }
    let r = normalize(r);
    let d = cross(f, r);
    // camera-to-world: columns are the camera axes (right, down, forward) in world space
    let c2w = [[r[0], d[0], f[0]], [r[1], d[1], f[1]], [r[2], d[2], f[2]]];
    Camera::from_c2w(name, width, height, fx, fx, width as f32 / 2.0, height as f32 / 2.0, c2w, centre)
}

impl Rig {
    /// `views` cameras of `width × height`, named `view_000`, `view_001`, ...;
    /// azimuth sweeps the arc in index order while the ring cycles.
    pub fn cameras(&self, views: usize, width: u32, height: u32) -> Vec<Camera> {
        let fx = 0.5 * width as f32 / (0.5 * self.fov_x_deg.to_radians()).tan();
        let rings = self.elevations_deg.len().max(1);
        (0..views)
            .map(|i| {
                let az = (-0.5 + (i as f32 + 0.5) / views as f32) * self.azimuth_span_deg.to_radians();
                let el = self.elevations_deg.get(i % rings).copied().unwrap_or(30.0).to_radians();
                let dir = [az.sin() * el.cos(), -az.cos() * el.cos(), el.sin()];
                let centre = [
                    self.target[0] + self.distance * dir[0],
                    self.target[1] + self.distance * dir[1],
                    self.target[2] + self.distance * dir[2],
                ];
                look_at(format!("view_{i:03}"), width, height, fx, centre, self.target)
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cameras_look_at_the_target() {
        let rig = Rig {
            target: [0.1, 0.2, 0.3],
            distance: 2.0,
            elevations_deg: vec![20.0, 40.0],
            azimuth_span_deg: 120.0,
            fov_x_deg: 50.0,
        };
        let cams = rig.cameras(10, 64, 48);
        assert_eq!(cams.len(), 10);
        for c in &cams {
            assert!(c.validate().is_ok());
            // target projects to the principal point, in front of the camera
            let t = rig.target;
            let x: Vec<f32> = (0..3)
                .map(|i| (0..3).map(|j| c.rotation[i][j] * t[j]).sum::<f32>() + c.translation[i])
                .collect();
            assert!((x[2] - 2.0).abs() < 1e-4);
            assert!((x[0] / x[2]).abs() < 1e-5 && (x[1] / x[2]).abs() < 1e-5);
            // image "up" (−y camera axis) points to world +z
            let up_world: f32 = -(c.rotation[1][2]);
            assert!(up_world > 0.0);
            assert!(c.centre()[1] < t[1]);
        }
        assert!(is_test(0) && is_test(8) && !is_test(7) && !is_test(9));
    }
}
