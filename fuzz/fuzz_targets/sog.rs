//! SOG bundles: never panic, never allocate past what the file's size allows; what
//! reads with finite values survives write + read with the same count. The first
//! byte picks a mode: 0 parses the rest as a `.sog` file; 1 builds a scene from the
//! rest (little-endian floats) and parses our own bundle of it; 2 does the same, then
//! overwrites a byte range of the bundle (position, length and value from the input)
//! before parsing, so the zip, meta.json and WebP checks are reached without seeds.
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::path::Path;
use transsplat_scene::{sh_coeffs, sog, Gaussians};

/// Up to 64 Gaussians from the floats of `b`: centre, log-scale, rotation, opacity,
/// then the SH coefficients of degree `degree`, the floats reused cyclically.
fn scene(b: &[u8], degree: u32) -> Gaussians {
    let floats: Vec<f32> = b.chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect();
    let per = 11 + sh_coeffs(degree) * 3;
    let mut g = Gaussians { sh_degree: degree, ..Default::default() };
    for r in floats.chunks_exact(per).take(64) {
        g.means.push([r[0], r[1], r[2]]);
        g.log_scales.push([r[3], r[4], r[5]]);
        g.rotations.push([r[6], r[7], r[8], r[9]]);
        g.opacity_logits.push(r[10]);
        g.sh.extend_from_slice(&r[11..]);
    }
    let keep: Vec<bool> = (0..g.len()).map(|i| g.non_finite_at(i).is_none()).collect();
    g.retain(&keep);
    g
}

fuzz_target!(|data: &[u8]| {
    let path = Path::new("fuzz.sog");
    let Some((&mode, rest)) = data.split_first() else { return };
    let bytes = if mode % 3 == 0 {
        rest.to_vec()
    } else {
        let (head, body) = rest.split_at(rest.len().min(8));
        let g = scene(body, (mode as u32 / 3) % 4);
        if g.is_empty() {
            return;
        }
        let mut b = sog::to_bytes(&g);
        if mode % 3 == 2 && head.len() == 8 {
            let at = u32::from_le_bytes(head[..4].try_into().unwrap()) as usize % b.len();
            let len = (head[4] as usize).min(b.len() - at);
            b[at..at + len].fill(head[5]);
        }
        b
    };
    let Ok(mut g) = sog::parse(&bytes, path) else { return };
    g.validate().expect("a parsed scene is consistent");
    let keep: Vec<bool> = (0..g.len()).map(|i| g.non_finite_at(i).is_none()).collect();
    g.retain(&keep);
    if g.is_empty() {
        return;
    }
    let back = sog::parse(&sog::to_bytes(&g), path).expect("a scene we wrote reads back");
    assert_eq!((back.len(), back.sh_degree), (g.len(), g.sh_degree));
});
