//! The in-memory 3DGS scene: a struct of arrays, one entry per Gaussian.

/// The degree-0 SH basis constant: a DC coefficient f shows as colour `SH_C0·f + ½`.
pub const SH_C0: f32 = 0.282_094_8;

/// Number of SH coefficients per colour channel for a degree (1, 4, 9, 16).
pub const fn sh_coeffs(degree: u32) -> usize {
    ((degree + 1) * (degree + 1)) as usize
}

/// A set of 3D Gaussians in the INRIA 3DGS parameterisation.
///
/// Every per-Gaussian array has the same length `len()`; [`Gaussians::validate`]
/// checks it. Parameters are stored unactivated, exactly as in the PLY file:
/// log-scales, opacity logits, unnormalised (w, x, y, z) quaternions.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Gaussians {
    /// Centres in world space.
    pub means: Vec<[f32; 3]>,
    /// Natural log of the per-axis standard deviations.
    pub log_scales: Vec<[f32; 3]>,
    /// Rotation quaternions (w, x, y, z), not necessarily normalised.
    pub rotations: Vec<[f32; 4]>,
    /// Opacity as a logit: opacity = sigmoid(logit).
    pub opacity_logits: Vec<f32>,
    /// SH degree, 0 to 3.
    pub sh_degree: u32,
    /// SH coefficients, `len() * sh_coeffs(sh_degree) * 3` values laid out
    /// `[gaussian][coefficient][channel]`; coefficient 0 is the DC term (`f_dc_*`).
    pub sh: Vec<f32>,
    /// Extra per-Gaussian properties carried through I/O (e.g. semantic latents `sem_0..`).
    pub extra: Extra,
}

/// Named extra per-Gaussian float properties, `values[i * names.len() + k]`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Extra {
    pub names: Vec<String>,
    pub values: Vec<f32>,
}

impl Extra {
    /// Number of extra properties per Gaussian.
    pub fn width(&self) -> usize {
        self.names.len()
    }

    /// The values of property `name`, one per Gaussian, if there is such a property.
    pub fn column(&self, name: &str) -> Option<Vec<f32>> {
        let w = self.width();
        let k = self.names.iter().position(|n| n == name)?;
        Some(self.values.chunks_exact(w).map(|row| row[k]).collect())
    }
}

impl Gaussians {
    /// Number of Gaussians.
    pub fn len(&self) -> usize {
        self.means.len()
    }

    /// True when there are no Gaussians.
    pub fn is_empty(&self) -> bool {
        self.means.is_empty()
    }

    /// SH coefficients per channel.
    pub fn sh_coeffs(&self) -> usize {
        sh_coeffs(self.sh_degree)
    }

    /// The SH coefficients of Gaussian `i`, `[coefficient][channel]` flattened.
    pub fn sh_of(&self, i: usize) -> &[f32] {
        let k = self.sh_coeffs() * 3;
        &self.sh[i * k..(i + 1) * k]
    }

    /// Checks that every array has the right length and the SH degree is 0..=3.
    pub fn validate(&self) -> Result<(), String> {
        let n = self.len();
        if self.sh_degree > 3 {
            return Err(format!("SH degree {} is not in 0..=3", self.sh_degree));
        }
        let checks = [
            ("log_scales", self.log_scales.len(), n),
            ("rotations", self.rotations.len(), n),
            ("opacity_logits", self.opacity_logits.len(), n),
            ("sh", self.sh.len(), n * self.sh_coeffs() * 3),
            ("extra", self.extra.values.len(), n * self.extra.width()),
        ];
        for (name, got, want) in checks {
            if got != want {
                return Err(format!("{name} has {got} values, expected {want} for {n} Gaussians"));
            }
        }
        Ok(())
    }

    /// Index of the first Gaussian with a NaN or infinite parameter, and which one.
    pub fn first_non_finite(&self) -> Option<(usize, &'static str)> {
        (0..self.len()).find_map(|i| self.non_finite_at(i).map(|what| (i, what)))
    }

    /// Which parameter group of Gaussian `i` is NaN or infinite (or an all-zero
    /// rotation), if any. Assumes [`Gaussians::validate`] passes.
    pub fn non_finite_at(&self, i: usize) -> Option<&'static str> {
        let k = self.sh_coeffs() * 3;
        let e = self.extra.width();
        let bad = |v: &[f32]| v.iter().any(|x| !x.is_finite());
        if bad(&self.means[i]) {
            Some("position")
        } else if bad(&self.log_scales[i]) {
            Some("scale")
        } else if bad(&self.rotations[i]) || self.rotations[i].iter().all(|&x| x == 0.0) {
            Some("rotation")
        } else if !self.opacity_logits[i].is_finite() {
            Some("opacity")
        } else if bad(&self.sh[i * k..(i + 1) * k]) {
            Some("SH colour")
        } else if bad(&self.extra.values[i * e..(i + 1) * e]) {
            Some("extra property")
        } else {
            None
        }
    }

    /// Keeps only the Gaussians for which `keep[i]` is true, in order.
    pub fn retain(&mut self, keep: &[bool]) {
        assert_eq!(keep.len(), self.len());
        fn filter<T: Copy>(v: &[T], keep: &[bool], stride: usize) -> Vec<T> {
            v.chunks_exact(stride.max(1))
                .zip(keep)
                .filter(|(_, &k)| k)
                .flat_map(|(c, _)| c.iter().copied())
                .collect()
        }
        let k = self.sh_coeffs() * 3;
        self.means = filter(&self.means, keep, 1);
        self.log_scales = filter(&self.log_scales, keep, 1);
        self.rotations = filter(&self.rotations, keep, 1);
        self.opacity_logits = filter(&self.opacity_logits, keep, 1);
        self.sh = filter(&self.sh, keep, k);
        if self.extra.width() > 0 {
            self.extra.values = filter(&self.extra.values, keep, self.extra.width());
        }
    }
}

impl Gaussians {
    /// The Gaussians at `order`, in that order (a permutation or a subset; indices may
    /// repeat). Panics on an index out of range.
    pub fn select(&self, order: &[u32]) -> Gaussians {
        fn pick<T: Copy>(v: &[T], order: &[u32], stride: usize) -> Vec<T> {
            let mut out = Vec::with_capacity(order.len() * stride);
            for &i in order {
                let i = i as usize * stride;
                out.extend_from_slice(&v[i..i + stride]);
            }
            out
        }
        let k = self.sh_coeffs() * 3;
        let e = self.extra.width();
        Gaussians {
            means: pick(&self.means, order, 1),
            log_scales: pick(&self.log_scales, order, 1),
            rotations: pick(&self.rotations, order, 1),
            opacity_logits: pick(&self.opacity_logits, order, 1),
            sh_degree: self.sh_degree,
            sh: pick(&self.sh, order, k),
            extra: Extra {
                names: self.extra.names.clone(),
                values: if e > 0 { pick(&self.extra.values, order, e) } else { Vec::new() },
            },
        }
    }

    /// Drops the SH coefficients above `degree` (no-op when the scene's degree is lower).
    pub fn truncate_sh(&mut self, degree: u32) {
        if degree >= self.sh_degree {
            return;
        }
        let (k_old, k_new) = (self.sh_coeffs() * 3, crate::sh_coeffs(degree) * 3);
        self.sh = self.sh.chunks_exact(k_old).flat_map(|c| c[..k_new].iter().copied()).collect();
        self.sh_degree = degree;
    }
}

/// Which of x, y, z each higher SH basis function (coefficients 1..=15, INRIA order) is
/// odd in: `y; z; x; xy; yz; 2z²−x²−y²; xz; x²−y²; y(3x²−y²); xyz; y(4z²−x²−y²);
/// z(2z²−3x²−3y²); x(4z²−x²−y²); z(x²−y²); x(x²−3y²)`.
const SH_ODD_IN: [[bool; 3]; 15] = {
    const X: [bool; 3] = [true, false, false];
    const Y: [bool; 3] = [false, true, false];
    const Z: [bool; 3] = [false, false, true];
    const E: [bool; 3] = [false, false, false];
    [
        Y,
        Z,
        X,
        [true, true, false],
        [false, true, true],
        E,
        [true, false, true],
        E,
        Y,
        [true; 3],
        Y,
        Z,
        X,
        Z,
        X,
    ]
};

impl Gaussians {
    /// Turns the centres and the view-dependent colour half a turn about coordinate
    /// axis `axis` (0 = x, 1 = y, 2 = z): the two other coordinates change sign, and so
    /// does each SH coefficient whose basis function is odd in exactly one of them.
    /// Its own inverse. The rotations are left to the caller: formats differ in which of
    /// the two equivalent quaternions they store.
    pub fn half_turn_means_and_sh(&mut self, axis: usize) {
        for m in &mut self.means {
            for (a, v) in m.iter_mut().enumerate() {
                if a != axis {
                    *v = -*v;
                }
            }
        }
        let sign: Vec<f32> = SH_ODD_IN
            .iter()
            .map(|odd| {
                let flips = (0..3).filter(|&a| a != axis && odd[a]).count();
                if flips % 2 == 1 {
                    -1.0
                } else {
                    1.0
                }
            })
            .collect();
        let k = self.sh_coeffs();
        for sh in self.sh.chunks_exact_mut(k * 3) {
            for j in 1..k {
                sh[j * 3..j * 3 + 3].iter_mut().for_each(|v| *v *= sign[j - 1]);
            }
        }
    }
}

impl Gaussians {
    /// Refuses (naming `path`) a scene that no format may store: inconsistent arrays,
    /// or a NaN or infinite parameter.
    pub fn check_writable(&self, path: &std::path::Path) -> crate::Result<()> {
        self.validate().map_err(|m| crate::Error::format(path, format!("cannot write scene: {m}")))?;
        match self.first_non_finite() {
            Some((i, what)) => Err(crate::Error::format(
                path,
                format!("cannot write scene: Gaussian {i} has an invalid {what}"),
            )),
            None => Ok(()),
        }
    }
}

/// The opacity logit of an 8-bit opacity (the compressed formats), kept finite: 0 and
/// 255 map a quarter step inside (0, 1), which encodes back to the same byte.
pub fn opacity_logit_of_byte(b: u8) -> f32 {
    let o = (b as f32 / 255.0).clamp(0.25 / 255.0, 1.0 - 0.25 / 255.0);
    (o / (1.0 - o)).ln()
}

/// A seeded random scene of SH degree `degree` for the format tests: centres in
/// [−1, 1)³, log-scales in [−6, −2), random rotations, logits in [−4, 4), SH in [−1, 1).
#[cfg(test)]
pub(crate) fn random_scene(n: usize, degree: u32, seed: u64) -> Gaussians {
    let mut r = crate::rng::SplitMix64::new(seed);
    let mut g = Gaussians { sh_degree: degree, ..Default::default() };
    for _ in 0..n {
        g.means.push([r.signed(), r.signed(), r.signed()]);
        g.log_scales.push([r.range(-6.0, -2.0), r.range(-6.0, -2.0), r.range(-6.0, -2.0)]);
        g.rotations.push([r.signed(), r.signed(), r.signed(), r.signed()]);
        g.opacity_logits.push(r.range(-4.0, 4.0));
        g.sh.extend((0..sh_coeffs(degree) * 3).map(|_| r.signed()));
    }
    g
}

/// Logistic sigmoid.
pub fn sigmoid(x: f32) -> f32 {
    1.0 / (1.0 + (-x).exp())
}
