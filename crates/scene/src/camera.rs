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

    /// Checks sizes and intrinsics are positive and finite.
    pub fn validate(&self) -> Result<(), String> {
        if self.width == 0 || self.height == 0 {
            return Err(format!("camera {:?} has image size {}x{}", self.name, self.width, self.height));
        }
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
        Ok(())
    }
}
