//! Branch-free `f32` exp / ln and the two row kernels of the scaling iteration
//! (dot product and axpy), written so that LLVM vectorises them. The solver calls them
//! from functions compiled with AVX2 + FMA when the CPU has them (runtime dispatch in
//! [`crate::engine`]), and from plain code otherwise.
//!
//! Accuracy (checked in the unit tests): `exp` relative error < 2e-7 on [-87, 88],
//! exactly 0 below [`EXP_MIN`]; `ln` absolute error < 2e-7 on normal positive inputs.

/// Arguments below this give exactly 0 from [`exp`]: results stay normal `f32`
/// (e^-87 ≈ 1.6e-38 > f32::MIN_POSITIVE), so no denormals reach the hot loops.
pub const EXP_MIN: f32 = -87.0;
/// Arguments are clamped to this from above (e^88 ≈ 1.65e38 < f32::MAX).
pub const EXP_MAX: f32 = 88.0;

const LOG2E: f32 = std::f32::consts::LOG2_E;
const LN2_HI: f32 = 0.693_359_4;
const LN2_LO: f32 = -2.121_944_4e-4;
/// 1.5 * 2^23: adding it rounds to an integer held in the low mantissa bits.
const ROUND_MAGIC: f32 = 12_582_912.0;

/// e^x in `f32`, vectorisable (no branches, no table): range reduction x = n ln2 + r,
/// |r| <= ln2/2, degree-7 Taylor polynomial (truncation error < 6e-9), scaling by 2^n
/// through the exponent bits. Returns 0 for x < [`EXP_MIN`] and NaN-free output for
/// any non-NaN input.
#[inline(always)]
pub fn exp(x: f32) -> f32 {
    let xc = x.clamp(EXP_MIN, EXP_MAX);
    let t = xc * LOG2E + ROUND_MAGIC;
    let n_bits = t.to_bits().wrapping_sub(ROUND_MAGIC.to_bits()) as i32;
    let n = t - ROUND_MAGIC;
    let r = xc - n * LN2_HI - n * LN2_LO;
    let p = 1.0
        + r * (1.0
            + r * (0.5
                + r * (1.0 / 6.0
                    + r * (1.0 / 24.0 + r * (1.0 / 120.0 + r * (1.0 / 720.0 + r * (1.0 / 5040.0)))))));
    let scale = f32::from_bits(((n_bits + 127) as u32) << 23);
    let v = p * scale;
    if x < EXP_MIN {
        0.0
    } else {
        v
    }
}

/// ln x in `f32` for normal positive x (callers guarantee x > 1e-30), vectorisable:
/// x = 2^e m with m in [sqrt(1/2), sqrt(2)), ln m = 2 atanh((m-1)/(m+1)) by its odd
/// series to the 9th power (error < 1e-9 on that interval).
#[inline(always)]
pub fn ln(x: f32) -> f32 {
    let bits = x.to_bits();
    let mut e = ((bits >> 23) & 0xff) as i32 - 127;
    let mut m = f32::from_bits((bits & 0x007f_ffff) | 0x3f80_0000);
    let big = m > std::f32::consts::SQRT_2;
    m = if big { m * 0.5 } else { m };
    e += big as i32;
    let f = (m - 1.0) / (m + 1.0);
    let f2 = f * f;
    let s = f * (2.0 + f2 * (2.0 / 3.0 + f2 * (2.0 / 5.0 + f2 * (2.0 / 7.0 + f2 * (2.0 / 9.0)))));
    e as f32 * std::f32::consts::LN_2 + s
}

/// `sum_j k[j] * v[j]` with eight independent partial sums (vectorises to one
/// multiply-add per eight entries). No `mul_add`: without hardware FMA it would be a
/// libm call.
#[inline(always)]
pub fn dot(k: &[f32], v: &[f32]) -> f32 {
    let n = k.len().min(v.len());
    let (k, v) = (&k[..n], &v[..n]);
    let mut acc = [0.0f32; 8];
    let kc = k.chunks_exact(8);
    let vc = v.chunks_exact(8);
    let (kr, vr) = (kc.remainder(), vc.remainder());
    for (a, b) in kc.zip(vc) {
        for l in 0..8 {
            acc[l] += a[l] * b[l];
        }
    }
    let mut s = ((acc[0] + acc[4]) + (acc[1] + acc[5])) + ((acc[2] + acc[6]) + (acc[3] + acc[7]));
    for (a, b) in kr.iter().zip(vr) {
        s += a * b;
    }
    s
}

/// `acc[j] += w * k[j]`.
#[inline(always)]
pub fn axpy(w: f32, k: &[f32], acc: &mut [f32]) {
    for (a, x) in acc.iter_mut().zip(k) {
        *a += x * w;
    }
}

/// In-place `x[i] = exp(x[i])` over a buffer.
#[inline(always)]
pub fn exp_slice(x: &mut [f32]) {
    for v in x.iter_mut() {
        *v = exp(*v);
    }
}

/// In-place `x[i] = ln(x[i])` over a buffer (inputs <= 1e-30 give garbage; callers
/// test the input first).
#[inline(always)]
pub fn ln_slice(x: &mut [f32]) {
    for v in x.iter_mut() {
        *v = ln(*v);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exp_accuracy() {
        let mut worst = 0.0f64;
        let mut x = -87.0f32;
        while x < 88.0 {
            let e = exp(x) as f64;
            let r = (x as f64).exp();
            worst = worst.max(((e - r) / r).abs());
            x += 0.000_37;
        }
        assert!(worst < 2e-7, "exp worst relative error {worst}");
        assert_eq!(exp(-87.5), 0.0);
        assert_eq!(exp(f32::NEG_INFINITY), 0.0);
        assert!(exp(1000.0).is_finite());
        assert_eq!(exp(0.0), 1.0);
    }

    #[test]
    fn ln_accuracy() {
        let mut worst = 0.0f64;
        let mut x = 1e-30f32;
        while x < 1e30 {
            let l = ln(x) as f64;
            let r = (x as f64).ln();
            worst = worst.max((l - r).abs() / r.abs().max(1.0));
            x *= 1.000_93;
        }
        assert!(worst < 2e-7, "ln worst error {worst}");
        assert_eq!(ln(1.0), 0.0);
    }

    #[test]
    fn dot_axpy() {
        let k: Vec<f32> = (0..37).map(|i| i as f32 * 0.5).collect();
        let v: Vec<f32> = (0..37).map(|i| 1.0 / (1.0 + i as f32)).collect();
        let want: f64 = k.iter().zip(&v).map(|(a, b)| *a as f64 * *b as f64).sum();
        assert!((dot(&k, &v) as f64 - want).abs() < 1e-5 * want);
        let mut acc = vec![1.0f32; 37];
        axpy(2.0, &k, &mut acc);
        assert_eq!(acc[3], 4.0);
    }
}
