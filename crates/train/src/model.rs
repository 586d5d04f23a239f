//! The trainable model, and the rearrangement that keeps every per-Gaussian array
//! aligned when Gaussians are added or removed.
//!
//! A [`Model`] owns a [`Gaussians`] (the INRIA parameters plus carried `extra`
//! properties such as an object `label`) and learnable per-Gaussian `features`
//! (the semantic latents of the edit stage). Densification and pruning describe what
//! they did as a [`Reindex`] — new row `j` is a copy of old row `src[j]` — and each
//! holder of per-Gaussian state applies it with its own `reindex` method
//! ([`Model::reindex`], [`Adam::reindex`](crate::Adam::reindex),
//! [`DensifyStats::reindex`](crate::DensifyStats::reindex)), which destructures
//! its struct exhaustively, so adding a field without handling it there is a compile
//! error; [`crate::trainer::apply_reindex`] applies it to all three together. Callers
//! holding their own per-Gaussian arrays apply the returned [`Reindex`] to them with
//! [`Reindex::apply`].

use transsplat_raster::Splats;
use transsplat_scene::{Extra, Gaussians};

/// Gaussians plus learnable feature channels.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Model {
    /// Standard parameters and carried extra properties.
    pub gaussians: Gaussians,
    /// `[gaussian][channel]`, `num_features` learnable channels.
    pub features: Vec<f32>,
    pub num_features: usize,
}

impl Model {
    /// A model with `num_features` zero-initialised feature channels.
    pub fn new(gaussians: Gaussians, num_features: usize) -> Self {
        let features = vec![0.0; gaussians.len() * num_features];
        Model { gaussians, features, num_features }
    }

    /// A model with the given features (`features.len() == len * num_features`).
    pub fn with_features(
        gaussians: Gaussians,
        features: Vec<f32>,
        num_features: usize,
    ) -> Result<Self, String> {
        let m = Model { gaussians, features, num_features };
        m.validate()?;
        Ok(m)
    }

    /// Number of Gaussians.
    pub fn len(&self) -> usize {
        self.gaussians.len()
    }

    /// True when there are no Gaussians.
    pub fn is_empty(&self) -> bool {
        self.gaussians.is_empty()
    }

    /// Checks every array length.
    pub fn validate(&self) -> Result<(), String> {
        self.gaussians.validate()?;
        let want = self.len() * self.num_features;
        if self.features.len() != want {
            return Err(format!(
                "features has {} values, expected {want} for {} Gaussians x {} channels",
                self.features.len(),
                self.len(),
                self.num_features
            ));
        }
        Ok(())
    }

    /// The rasterizer's view of the model, rendering SH up to `active_sh_degree`:
    /// colour only. The features act through per-Gaussian terms (the edit's L_sem,
    /// L_uot), never through a render, so rendering their channels (and backpropagating
    /// zeros through them) every step would be work for nothing.
    pub fn splats(&self, active_sh_degree: u32) -> Splats<'_> {
        let mut s = Splats::new(&self.gaussians);
        s.active_sh_degree = active_sh_degree.min(self.gaussians.sh_degree);
        s
    }

    /// The features of Gaussian `i`.
    pub fn features_of(&self, i: usize) -> &[f32] {
        &self.features[i * self.num_features..(i + 1) * self.num_features]
    }

    /// Applies `r` to every per-Gaussian array: parameters, extras and features.
    pub fn reindex(&mut self, r: &Reindex) {
        assert_eq!(
            self.len(),
            r.old_len,
            "rearrangement made for {} Gaussians, model has {}",
            r.old_len,
            self.len()
        );
        // Exhaustive destructuring: a new field must be handled here.
        let Model {
            gaussians: Gaussians { means, log_scales, rotations, opacity_logits, sh_degree, sh, extra },
            features,
            num_features,
        } = self;
        let Extra { names, values } = extra;
        let kc = transsplat_scene::sh_coeffs(*sh_degree) * 3;
        *means = unflat(r.gather(flat3(means), 3));
        *log_scales = unflat(r.gather(flat3(log_scales), 3));
        *rotations = unflat(r.gather(rotations.as_flattened(), 4));
        *opacity_logits = r.gather(opacity_logits, 1);
        *sh = r.gather(sh, kc);
        if !names.is_empty() {
            *values = r.gather(values, names.len());
        }
        if *num_features > 0 {
            *features = r.gather(features, *num_features);
        }
    }
}

/// A rearrangement of the Gaussians: new row `j` is a copy of old row `src[j]`.
/// Rows `j >= fresh_from` are new Gaussians (clones, split samples): their Adam
/// moments and densification statistics start at zero, as INRIA's
/// `densification_postfix` does. Pruning is a `Reindex` with no fresh rows.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Reindex {
    /// For each new row, the old row it copies.
    pub src: Vec<u32>,
    /// First new (fresh) row; `src.len()` when there are none.
    pub fresh_from: usize,
    /// Number of rows before.
    pub old_len: usize,
}

impl Reindex {
    /// The identity on `n` rows.
    pub fn identity(n: usize) -> Self {
        Reindex { src: (0..n as u32).collect(), fresh_from: n, old_len: n }
    }

    /// Keeps the rows where `keep[i]` is true, in order.
    pub fn keep(keep: &[bool]) -> Self {
        let src: Vec<u32> = keep.iter().enumerate().filter(|(_, &k)| k).map(|(i, _)| i as u32).collect();
        let n = src.len();
        Reindex { src, fresh_from: n, old_len: keep.len() }
    }

    /// Number of rows after.
    pub fn len(&self) -> usize {
        self.src.len()
    }

    /// True when no rows remain.
    pub fn is_empty(&self) -> bool {
        self.src.is_empty()
    }

    /// True when nothing moves.
    pub fn is_identity(&self) -> bool {
        self.old_len == self.src.len() && self.src.iter().enumerate().all(|(j, &s)| s as usize == j)
    }

    /// Whether new row `j` is a new Gaussian.
    pub fn is_fresh(&self, j: usize) -> bool {
        j >= self.fresh_from
    }

    /// Gathers rows of `stride` values: `out[j] = v[src[j]]`.
    pub fn gather<T: Copy>(&self, v: &[T], stride: usize) -> Vec<T> {
        assert_eq!(v.len(), self.old_len * stride, "array does not have {} rows of {stride}", self.old_len);
        let mut out = Vec::with_capacity(self.src.len() * stride);
        for &s in &self.src {
            let s = s as usize;
            out.extend_from_slice(&v[s * stride..(s + 1) * stride]);
        }
        out
    }

    /// Like [`Reindex::gather`], with fresh rows set to `zero`.
    pub fn gather_fresh_zero<T: Copy>(&self, v: &[T], stride: usize, zero: T) -> Vec<T> {
        let mut out = self.gather(v, stride);
        out[self.fresh_from.min(self.src.len()) * stride..].fill(zero);
        out
    }

    /// Applies the rearrangement in place to an array of rows of `stride` values
    /// (for per-Gaussian data kept outside the model).
    pub fn apply<T: Copy>(&self, v: &mut Vec<T>, stride: usize) {
        *v = self.gather(v, stride);
    }

    /// `self` followed by `next` (`next.old_len == self.len()`). Fresh rows must stay
    /// at the end (true when `next` only removes rows or appends fresh ones).
    pub fn then(&self, next: &Reindex) -> Reindex {
        assert_eq!(next.old_len, self.len(), "composed rearrangements do not fit");
        let src: Vec<u32> = next.src.iter().map(|&j| self.src[j as usize]).collect();
        let fresh_from = next
            .src
            .iter()
            .enumerate()
            .position(|(k, &j)| k >= next.fresh_from || self.is_fresh(j as usize))
            .unwrap_or(src.len());
        Reindex { src, fresh_from, old_len: self.old_len }
    }
}

fn flat3(v: &[[f32; 3]]) -> &[f32] {
    v.as_flattened()
}

fn unflat<const N: usize>(v: Vec<f32>) -> Vec<[f32; N]> {
    v.chunks_exact(N).map(|c| std::array::from_fn(|k| c[k])).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reindex_gather_and_compose() {
        let r = Reindex { src: vec![0, 2, 2, 1], fresh_from: 3, old_len: 3 };
        assert_eq!(r.gather(&[10, 11, 20, 21, 30, 31], 2), vec![10, 11, 30, 31, 30, 31, 20, 21]);
        assert_eq!(r.gather_fresh_zero(&[1, 2, 3], 1, 0), vec![1, 3, 3, 0]);
        let p = Reindex::keep(&[true, false, true, true]);
        let c = r.then(&p);
        assert_eq!(c.src, vec![0, 2, 1]);
        assert_eq!(c.fresh_from, 2);
        assert!(Reindex::identity(4).is_identity());
        assert!(!p.is_identity());
    }
}
