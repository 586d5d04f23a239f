//! Pinhole cameras in the OpenCV convention (x right, y down, z forward).

/// A pinhole camera with world-to-camera extrinsics: `x_cam = R x_world + t`.
#[derive(Clone, Debug, PartialEq)]
pub struct Camera {
    /// Image name as given by the source (may include an extension, e.g. `00001.png`).
    pub name: String,
    pub width: u32,
    pub height: u32,
    pub fx: f32,
    pub fy: f32,
    pub cx: f32,
    pub cy: f32,
    /// World-to-camera rotation, row-major.
    pub rotation: [[f32; 3]; 3],
    /// World-to-camera translation.
    pub translation: [f32; 3],
}

impl Camera {
    /// The image name without directory or extension, used to name outputs.
    pub fn stem(&self) -> String {
        let base = self.name.rsplit(['/', '\\']).next().unwrap_or(&self.name);
        match base.rfind('.') {
            Some(i) if i > 0 => base[..i].to_string(),
            _ => base.to_string(),
        }
    }

    /// Camera centre in world coordinates: `-Rᵀ t`.
    pub fn centre(&self) -> [f32; 3] {
        let r = &self.rotation;
        let t = &self.translation;
        let mut c = [0.0f32; 3];
        for (j, cj) in c.iter_mut().enumerate() {
            *cj = -(r[0][j] * t[0] + r[1][j] * t[1] + r[2][j] * t[2]);
        }
        c
    }

    /// A camera at the world origin looking down +z (identity rotation, zero
    /// translation) with focal length `focal` in pixels and the principal point at the
    /// image centre; set `translation` on the result to move the world in front of it.
    pub fn pinhole(name: &str, width: u32, height: u32, focal: f32) -> Self {
        Camera {
            name: name.into(),
            width,
            height,
            fx: focal,
            fy: focal,
            cx: width as f32 / 2.0,
            cy: height as f32 / 2.0,
            rotation: [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            translation: [0.0; 3],
        }
    }

    /// Builds a camera from a camera-to-world rotation and the camera centre.
    #[allow(clippy::too_many_arguments)]
    pub fn from_c2w(
        name: String,
        width: u32,
        height: u32,
        fx: f32,
        fy: f32,
        cx: f32,
        cy: f32,
        c2w_rotation: [[f32; 3]; 3],
        centre: [f32; 3],
    ) -> Self {
        let mut rotation = [[0.0f32; 3]; 3];
        for (i, row) in rotation.iter_mut().enumerate() {
            for (j, v) in row.iter_mut().enumerate() {
                *v = c2w_rotation[j][i];
            }
        }
        let mut translation = [0.0f32; 3];
        for (i, t) in translation.iter_mut().enumerate() {
            *t = -(0..3).map(|j| rotation[i][j] * centre[j]).sum::<f32>();
        }
        Camera { name, width, height, fx, fy, cx, cy, rotation, translation }
    }

    /// Camera-to-world rotation (the transpose of `rotation`).
    pub fn c2w_rotation(&self) -> [[f32; 3]; 3] {
        let mut m = [[0.0f32; 3]; 3];
        for (i, row) in m.iter_mut().enumerate() {
            for (j, v) in row.iter_mut().enumerate() {
                *v = self.rotation[j][i];
            }
        }
        m
    }

    /// Checks the camera can be used: the image name is not empty (outputs are named
    /// after it), the image size is within [`check_image_size`], the focal lengths are
    /// positive and every parameter is finite, and `rotation` is a rotation: orthonormal
    /// within [`ROTATION_TOLERANCE`], determinant +1. The message names the camera.
    pub fn validate(&self) -> Result<(), String> {
        if self.name.trim().is_empty() {
            return Err("a camera has an empty image name (outputs are named after it)".into());
        }
        if self.stem().trim().is_empty() {
            return Err(format!(
                "camera {:?}: the image name has no file name to name outputs after",
                self.name
            ));
        }
        check_image_size(self.width.into(), self.height.into())
            .map_err(|m| format!("camera {:?}: {m}", self.name))?;
        for (k, v) in [("fx", self.fx), ("fy", self.fy)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("camera {:?} has focal length {k} = {v}", self.name));
            }
        }
        let finite = [self.cx, self.cy]
            .iter()
            .chain(self.translation.iter())
            .chain(self.rotation.iter().flatten())
            .all(|v| v.is_finite());
        if !finite {
            return Err(format!("camera {:?} has a NaN or infinite parameter", self.name));
        }
        check_rotation(&self.rotation).map_err(|m| format!("camera {:?}: {m}", self.name))
    }
}

/// Largest image side, in pixels, accepted for a camera and for an image file.
pub const MAX_IMAGE_SIDE: u64 = 1 << 15;

/// Largest pixel count (2^27 ≈ 134 million) accepted for a camera and for an image
/// file: 1.6 GB as float RGB, far above any capture used for 3DGS. It is the same cap
/// as the image reader's (`image.rs`, tested to agree), so a camera that passes can
/// have its image read, and no camera makes a renderer allocate more.
pub const MAX_IMAGE_PIXELS: u64 = 1 << 27;

/// Checks an image size against the one cap for images and cameras: both sides
/// non-zero, at most [`MAX_IMAGE_SIDE`] (32768) a side and [`MAX_IMAGE_PIXELS`] (2^27,
/// about 134 million) in all. Readers call it (through [`Camera::validate`]) before
/// anything is allocated for the image.
pub fn check_image_size(width: u64, height: u64) -> Result<(), String> {
    if width == 0 || height == 0 {
        return Err(format!("image size {width}x{height} has a zero side"));
    }
    if width > MAX_IMAGE_SIDE || height > MAX_IMAGE_SIDE {
        return Err(format!("image size {width}x{height} is larger than {MAX_IMAGE_SIDE} pixels a side"));
    }
    if width * height > MAX_IMAGE_PIXELS {
        return Err(format!(
            "image size {width}x{height} is more than {MAX_IMAGE_PIXELS} pixels ({} million)",
            MAX_IMAGE_PIXELS >> 20
        ));
    }
    Ok(())
}

/// Largest accepted deviation of `R Rᵀ` from the identity, entry by entry, for a
/// camera rotation (1%: rounding in any file format is far below it; a scaled, sheared
/// or zero matrix is far above it).
pub const ROTATION_TOLERANCE: f64 = 1e-2;

/// Checks that `r` is a rotation: orthonormal within [`ROTATION_TOLERANCE`] and not a
/// reflection. The one rotation check for every camera reader (a camera-to-world
/// matrix is a rotation exactly when its transpose is).
pub fn check_rotation(r: &[[f32; 3]; 3]) -> Result<(), String> {
    if !r.iter().flatten().all(|v| v.is_finite()) {
        return Err("rotation has a NaN or infinite entry".into());
    }
    let m = r.map(|row| row.map(f64::from));
    let mut worst = 0.0f64;
    for a in 0..3 {
        for b in 0..3 {
            let dot: f64 = (0..3).map(|k| m[a][k] * m[b][k]).sum();
            let want = if a == b { 1.0 } else { 0.0 };
            worst = worst.max((dot - want).abs());
        }
    }
    if worst > ROTATION_TOLERANCE {
        return Err(format!(
            "rotation is not orthonormal (R R^T is off the identity by {worst:.3}, more than \
             {ROTATION_TOLERANCE}): a zero, scaled or sheared matrix is not a rotation"
        ));
    }
    let det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
        - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
    if det < 0.0 {
        return Err(format!("rotation is a reflection (determinant {det:.3}), not a rotation"));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cam() -> Camera {
        Camera { translation: [0.0, 0.0, 3.0], ..Camera::pinhole("images/a.png", 40, 30, 50.0) }
    }

    #[test]
    fn image_size_cap_boundaries() {
        let side = MAX_IMAGE_SIDE;
        assert!(check_image_size(side, MAX_IMAGE_PIXELS / side).is_ok());
        assert!(check_image_size(1, side).is_ok());
        let e = check_image_size(side, MAX_IMAGE_PIXELS / side + 1).unwrap_err();
        assert!(e.contains("32768x4097") && e.contains("134217728 pixels (128 million)"), "{e}");
        let e = check_image_size(side + 1, 1).unwrap_err();
        assert!(e.contains("32769x1") && e.contains("32768 pixels a side"), "{e}");
        let e = check_image_size(100_000, 100_000).unwrap_err();
        assert!(e.contains("100000x100000"), "{e}");
        assert!(check_image_size(0, 5).unwrap_err().contains("image size 0x5 has a zero side"));
        // No overflow for sizes beyond u32 (COLMAP stores u64).
        assert!(check_image_size(u64::MAX, u64::MAX).is_err());
    }

    #[test]
    fn rotations_must_be_orthonormal_and_proper() {
        let id = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        assert!(check_rotation(&id).is_ok());
        let (s, c) = 0.3f32.sin_cos();
        assert!(check_rotation(&[[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]).is_ok());
        // Rounding well within the tolerance is fine (files store a few digits).
        assert!(check_rotation(&[[1.002, 0.0, 0.0], [0.0, 1.0, 0.001], [0.0, 0.0, 0.999]]).is_ok());
        let bad: [([[f32; 3]; 3], &str); 5] = [
            ([[0.0; 3]; 3], "not orthonormal"),
            ([[2.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], "not orthonormal"),
            ([[1.0, 0.5, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]], "not orthonormal"),
            ([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.95]], "by 0.098"),
            ([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, -1.0]], "reflection (determinant -1.000)"),
        ];
        for (r, want) in bad {
            let e = check_rotation(&r).unwrap_err();
            assert!(e.contains(want), "{r:?}: expected {want:?} in {e:?}");
        }
        assert!(check_rotation(&[[f32::NAN, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]).is_err());
    }

    #[test]
    fn validate_names_the_camera_and_the_problem() {
        assert!(cam().validate().is_ok());
        let with = |f: fn(&mut Camera)| {
            let mut c = cam();
            f(&mut c);
            c.validate().unwrap_err()
        };
        assert!(with(|c| c.name = String::new()).contains("empty image name"));
        assert!(with(|c| c.name = "  ".into()).contains("empty image name"));
        assert!(with(|c| c.name = "images/".into()).contains("no file name"));
        let e = with(|c| c.width = 100_000);
        assert!(e.starts_with("camera \"images/a.png\": image size 100000x30"), "{e}");
        let e = with(|c| c.rotation = [[0.0; 3]; 3]);
        assert!(e.starts_with("camera \"images/a.png\": rotation is not orthonormal"), "{e}");
        assert!(with(|c| c.fy = 0.0).contains("focal length fy = 0"));
        assert!(with(|c| c.translation[1] = f32::INFINITY).contains("NaN or infinite"));
    }
}
