//! Lane-wise arithmetic, so one source of the per-Gaussian backward serves one Gaussian
//! (`f32`) or eight at once ([`F8`]).
//!
//! Every [`F8`] operation is the `f32` operation applied to each lane, in the same order
//! the scalar code applies it (no fused multiply-adds are formed, no reassociation), so
//! a Gaussian's gradients have the same bits whichever path computed them; a branch of
//! the scalar code is a [`Real::select`] here, which takes the same value per lane. The
//! compiler turns the eight-lane loops into vector instructions (AVX2 where the caller
//! is compiled for it): the backward's per-Gaussian pass is arithmetic-bound, and this
//! is what it gains.

use std::ops::{Add, AddAssign, Div, Mul, Neg, Sub};

/// A number type whose operations act lane by lane: `f32` (one lane) or [`F8`].
pub trait Real:
    Copy
    + Default
    + From<f32>
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
    + AddAssign
{
    /// One boolean per lane.
    type Mask: Copy;
    /// `f32::sqrt` per lane.
    fn sqrt(self) -> Self;
    /// `f32::exp` per lane.
    fn exp(self) -> Self;
    /// `f32::ln` per lane.
    fn ln(self) -> Self;
    /// `f32::min` per lane.
    fn min(self, o: Self) -> Self;
    /// `f32::max` per lane.
    fn max(self, o: Self) -> Self;
    /// `f32::ceil` per lane.
    fn ceil(self) -> Self;
    /// `f32::clamp` per lane.
    fn clamp(self, lo: Self, hi: Self) -> Self;
    /// `self < o` per lane.
    fn lt(self, o: Self) -> Self::Mask;
    /// `self != o` per lane.
    fn ne(self, o: Self) -> Self::Mask;
    /// Per lane, `a` where `m` holds, else `b`.
    fn select(m: Self::Mask, a: Self, b: Self) -> Self;
}

impl Real for f32 {
    type Mask = bool;
    #[inline(always)]
    fn sqrt(self) -> Self {
        f32::sqrt(self)
    }
    #[inline(always)]
    fn exp(self) -> Self {
        f32::exp(self)
    }
    #[inline(always)]
    fn ln(self) -> Self {
        f32::ln(self)
    }
    #[inline(always)]
    fn min(self, o: Self) -> Self {
        f32::min(self, o)
    }
    #[inline(always)]
    fn max(self, o: Self) -> Self {
        f32::max(self, o)
    }
    #[inline(always)]
    fn ceil(self) -> Self {
        f32::ceil(self)
    }
    #[inline(always)]
    fn clamp(self, lo: Self, hi: Self) -> Self {
        f32::clamp(self, lo, hi)
    }
    #[inline(always)]
    fn lt(self, o: Self) -> bool {
        self < o
    }
    #[inline(always)]
    fn ne(self, o: Self) -> bool {
        self != o
    }
    #[inline(always)]
    fn select(m: bool, a: Self, b: Self) -> Self {
        if m {
            a
        } else {
            b
        }
    }
}

/// Eight `f32` lanes.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[repr(C, align(32))]
pub struct F8(pub [f32; 8]);

impl F8 {
    /// Lane `l` is `f(l)`.
    #[inline(always)]
    pub fn from_fn(f: impl Fn(usize) -> f32) -> Self {
        F8(std::array::from_fn(f))
    }

    /// `f` of each lane.
    #[inline(always)]
    fn map(self, f: impl Fn(f32) -> f32) -> Self {
        F8(std::array::from_fn(|l| f(self.0[l])))
    }

    /// `f` of each pair of lanes.
    #[inline(always)]
    fn zip(self, o: Self, f: impl Fn(f32, f32) -> f32) -> Self {
        F8(std::array::from_fn(|l| f(self.0[l], o.0[l])))
    }
}

impl From<f32> for F8 {
    #[inline(always)]
    fn from(x: f32) -> Self {
        F8([x; 8])
    }
}

macro_rules! lane_op {
    ($tr:ident, $f:ident, $op:tt) => {
        impl $tr for F8 {
            type Output = F8;
            #[inline(always)]
            fn $f(self, o: F8) -> F8 {
                self.zip(o, |a, b| a $op b)
            }
        }
    };
}
lane_op!(Add, add, +);
lane_op!(Sub, sub, -);
lane_op!(Mul, mul, *);
lane_op!(Div, div, /);

impl Neg for F8 {
    type Output = F8;
    #[inline(always)]
    fn neg(self) -> F8 {
        self.map(|a| -a)
    }
}

impl AddAssign for F8 {
    #[inline(always)]
    fn add_assign(&mut self, o: F8) {
        *self = *self + o;
    }
}

impl Real for F8 {
    type Mask = [bool; 8];
    #[inline(always)]
    fn sqrt(self) -> Self {
        self.map(f32::sqrt)
    }
    #[inline(always)]
    fn exp(self) -> Self {
        self.map(f32::exp)
    }
    #[inline(always)]
    fn ln(self) -> Self {
        self.map(f32::ln)
    }
    #[inline(always)]
    fn min(self, o: Self) -> Self {
        self.zip(o, f32::min)
    }
    #[inline(always)]
    fn max(self, o: Self) -> Self {
        self.zip(o, f32::max)
    }
    #[inline(always)]
    fn ceil(self) -> Self {
        self.map(f32::ceil)
    }
    #[inline(always)]
    fn clamp(self, lo: Self, hi: Self) -> Self {
        F8(std::array::from_fn(|l| self.0[l].clamp(lo.0[l], hi.0[l])))
    }
    #[inline(always)]
    fn lt(self, o: Self) -> [bool; 8] {
        std::array::from_fn(|l| self.0[l] < o.0[l])
    }
    #[inline(always)]
    fn ne(self, o: Self) -> [bool; 8] {
        std::array::from_fn(|l| self.0[l] != o.0[l])
    }
    #[inline(always)]
    fn select(m: [bool; 8], a: Self, b: Self) -> Self {
        F8(std::array::from_fn(|l| if m[l] { a.0[l] } else { b.0[l] }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_operation_acts_lane_by_lane_as_f32() {
        use std::hint::black_box;
        let a = black_box(F8([1.5, -0.0, 0.0, f32::NAN, f32::INFINITY, -3.25, 1e-30, 7.0]));
        let b = black_box(F8([2.0, 0.0, -0.0, 1.0, f32::INFINITY, 0.5, -1e30, f32::NAN]));
        // The same bits, or both NaN (a NaN's sign and payload are not a result).
        let same = |v: F8, l: usize, want: f32| {
            let got = v.0[l];
            assert!(
                got.to_bits() == want.to_bits() || (got.is_nan() && want.is_nan()),
                "lane {l}: {got} vs {want}"
            );
        };
        for l in 0..8 {
            let (x, y) = (black_box(a.0[l]), black_box(b.0[l]));
            same(a + b, l, x + y);
            same(a - b, l, x - y);
            same(a * b, l, x * y);
            same(a / b, l, x / y);
            same(-a, l, -x);
            same(Real::sqrt(a), l, x.sqrt());
            same(Real::exp(a), l, x.exp());
            same(Real::ln(a), l, x.ln());
            same(Real::min(a, b), l, x.min(y));
            same(Real::max(a, b), l, x.max(y));
            same(Real::ceil(a), l, x.ceil());
            same(a.clamp(F8::from(-1.0), F8::from(2.0)), l, x.clamp(-1.0, 2.0));
            assert_eq!(a.lt(b)[l], x < y);
            assert_eq!(a.ne(b)[l], x != y);
            same(F8::select(a.lt(b), a, b), l, if x < y { x } else { y });
        }
    }
}
