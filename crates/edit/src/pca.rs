//! The semantic space (docs/method.md#m8-semantic-space): a PCA basis of size d fitted once per job on
//! the semantic features of the source and edited views together, applied to both.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use transsplat_train::linalg::symmetric_eigen;

/// A fitted projection `y = (x − mean) · basis`, `basis` is `d_in × d` (columns are
/// the leading principal directions, padded with zeros when `d > d_in`).
#[derive(Clone, Debug, PartialEq)]
pub struct Pca {
    pub d_in: usize,
    pub d: usize,
    pub mean: Vec<f32>,
    pub basis: Vec<f32>,
    /// Variance along each kept direction.
    pub variance: Vec<f32>,
}

impl Pca {
    /// Fits on feature planes (`pixels × d_in` each), using up to `samples` pixels
    /// drawn uniformly (seeded) from all planes together.
    pub fn fit(planes: &[&[f32]], d_in: usize, d: usize, samples: usize, seed: u64) -> Pca {
        let total: usize = planes.iter().map(|p| p.len() / d_in.max(1)).sum();
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let take = samples.min(total);
        let mut rows: Vec<&[f32]> = Vec::with_capacity(take);
        for _ in 0..take {
            let mut k = rng.gen_range(0..total);
            for p in planes {
                let n = p.len() / d_in;
                if k < n {
                    rows.push(&p[k * d_in..(k + 1) * d_in]);
                    break;
                }
                k -= n;
            }
        }
        let m = rows.len().max(1) as f64;
        let mut mean = vec![0.0f64; d_in];
        for r in &rows {
            for (a, &x) in mean.iter_mut().zip(r.iter()) {
                *a += x as f64 / m;
            }
        }
        let mut cov = vec![0.0f64; d_in * d_in];
        for r in &rows {
            for i in 0..d_in {
                let xi = r[i] as f64 - mean[i];
                for j in i..d_in {
                    cov[i * d_in + j] += xi * (r[j] as f64 - mean[j]) / m;
                }
            }
        }
        for i in 0..d_in {
            for j in 0..i {
                cov[i * d_in + j] = cov[j * d_in + i];
            }
        }
        let (vals, vecs) = symmetric_eigen(&cov, d_in);
        let mut order: Vec<usize> = (0..d_in).collect();
        order.sort_by(|&a, &b| vals[b].total_cmp(&vals[a]));
        let mut basis = vec![0.0f32; d_in * d];
        let mut variance = vec![0.0f32; d];
        for (c, &k) in order.iter().take(d).enumerate() {
            // Sign convention: the largest-magnitude entry of each direction is positive.
            let col: Vec<f64> = (0..d_in).map(|i| vecs[i * d_in + k]).collect();
            let big = col.iter().fold(0.0f64, |m, &x| if x.abs() > m.abs() { x } else { m });
            let sign = if big < 0.0 { -1.0 } else { 1.0 };
            for i in 0..d_in {
                basis[i * d + c] = (sign * col[i]) as f32;
            }
            variance[c] = vals[k].max(0.0) as f32;
        }
        Pca { d_in, d, mean: mean.into_iter().map(|x| x as f32).collect(), basis, variance }
    }

    /// Projects a `pixels × d_in` plane to `pixels × d`.
    pub fn project(&self, plane: &[f32]) -> Vec<f32> {
        use rayon::prelude::*;
        let (di, d) = (self.d_in, self.d);
        let mut out = vec![0.0f32; plane.len() / di * d];
        out.par_chunks_mut(d).zip(plane.par_chunks(di)).with_min_len(1024).for_each(|(o, x)| {
            for (i, (&xv, &m)) in x.iter().zip(&self.mean).enumerate() {
                let xi = xv - m;
                if xi != 0.0 {
                    let row = &self.basis[i * d..(i + 1) * d];
                    for (oj, bj) in o.iter_mut().zip(row) {
                        *oj += xi * bj;
                    }
                }
            }
        });
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pca_finds_the_dominant_direction() {
        // Points along (3, 4)/5 with small noise in 3D.
        let mut plane = Vec::new();
        for i in 0..200 {
            let t = (i as f32 - 100.0) / 10.0;
            let n = ((i * 37 % 11) as f32 - 5.0) * 0.01;
            plane.extend_from_slice(&[1.0 + 0.6 * t, 2.0 + 0.8 * t + n, -1.0 + n]);
        }
        let p = Pca::fit(&[&plane], 3, 2, 10_000, 1);
        assert!((p.basis[0] - 0.6).abs() < 0.01 && (p.basis[2] - 0.8).abs() < 0.01, "{:?}", p.basis);
        assert!(p.variance[0] > 100.0 * p.variance[1]);
        let y = p.project(&plane[..3]);
        assert!((y[0] - (-10.0)).abs() < 0.1, "{y:?}");
    }
}
