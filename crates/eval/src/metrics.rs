//! Image and ranking metrics.

/// PSNR in dB of two `[0, 1]` RGB images (`H × W × 3`), over the pixels where
/// `mask` is true (all pixels when `None`). Returns `None` when no pixel counts.
pub fn psnr(a: &[f32], b: &[f32], mask: Option<&[bool]>) -> Option<f64> {
    let (se, n) = squared_error(a, b, mask);
    (n > 0).then(|| psnr_from_mse(se / n as f64))
}

/// Sum of squared errors and number of values over the masked pixels (clamped to [0, 1]).
pub fn squared_error(a: &[f32], b: &[f32], mask: Option<&[bool]>) -> (f64, usize) {
    assert_eq!(a.len(), b.len(), "images differ in size");
    let mut se = 0.0f64;
    let mut n = 0usize;
    for (p, (x, y)) in a.chunks_exact(3).zip(b.chunks_exact(3)).enumerate() {
        if mask.is_some_and(|m| !m[p]) {
            continue;
        }
        for k in 0..3 {
            let d = (x[k].clamp(0.0, 1.0) - y[k].clamp(0.0, 1.0)) as f64;
            se += d * d;
        }
        n += 3;
    }
    (se, n)
}

/// PSNR for a mean squared error of `[0, 1]` values (capped at 100 dB for identical images).
pub fn psnr_from_mse(mse: f64) -> f64 {
    if mse <= 1e-10 {
        100.0
    } else {
        -10.0 * mse.log10()
    }
}

/// SSIM of two RGB images (11×11 Gaussian window σ 1.5, as INRIA 3DGS).
pub fn ssim(a: &[f32], b: &[f32], width: usize, height: usize) -> f64 {
    transsplat_train::loss::ssim(a, b, width, height) as f64
}

/// Area under the ROC curve of `scores` for the binary `labels` (the probability that
/// a random positive scores above a random negative; ties count half). `None` when a
/// class is empty.
pub fn auroc(scores: &[f32], labels: &[bool]) -> Option<f64> {
    assert_eq!(scores.len(), labels.len());
    let mut idx: Vec<usize> = (0..scores.len()).collect();
    idx.sort_by(|&a, &b| scores[a].total_cmp(&scores[b]));
    let (pos, neg) =
        labels.iter().fold((0usize, 0usize), |(p, n), &l| if l { (p + 1, n) } else { (p, n + 1) });
    if pos == 0 || neg == 0 {
        return None;
    }
    // Mann–Whitney U with average ranks for ties.
    let mut rank_sum = 0.0f64;
    let mut i = 0;
    while i < idx.len() {
        let mut j = i;
        while j + 1 < idx.len() && scores[idx[j + 1]] == scores[idx[i]] {
            j += 1;
        }
        let avg = (i + j) as f64 / 2.0 + 1.0;
        for &k in &idx[i..=j] {
            if labels[k] {
                rank_sum += avg;
            }
        }
        i = j + 1;
    }
    let u = rank_sum - (pos * (pos + 1)) as f64 / 2.0;
    Some(u / (pos as f64 * neg as f64))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn psnr_by_hand() {
        let a = [0.0f32; 6];
        let b = [0.1f32, 0.1, 0.1, 0.5, 0.5, 0.5];
        // Only the first pixel: MSE 0.01 → 20 dB.
        assert!((psnr(&a, &b, Some(&[true, false])).unwrap() - 20.0).abs() < 1e-4);
        assert!(psnr(&a, &b, Some(&[false, false])).is_none());
        assert_eq!(psnr(&a, &a, None), Some(100.0));
    }

    #[test]
    fn auroc_by_hand() {
        assert_eq!(auroc(&[0.1, 0.2, 0.8, 0.9], &[false, false, true, true]), Some(1.0));
        assert_eq!(auroc(&[0.9, 0.8, 0.2, 0.1], &[false, false, true, true]), Some(0.0));
        // One inversion out of four pairs → 0.75; a tie counts half.
        assert_eq!(auroc(&[0.1, 0.6, 0.5, 0.9], &[false, false, true, true]), Some(0.75));
        assert_eq!(auroc(&[0.5, 0.5], &[false, true]), Some(0.5));
        assert_eq!(auroc(&[0.5, 0.5], &[true, true]), None);
    }
}
