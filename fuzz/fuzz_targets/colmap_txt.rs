//! COLMAP sparse models in .txt: cameras, images and points3D from one input
//! (see split.rs); never panic, and every camera returned is valid.
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::path::Path;
use transsplat_scene::cameras::colmap;

mod split;

fuzz_target!(|data: &[u8]| {
    let Some((cams, images, points)) = split::split3(data) else { return };
    let (c, i, p) = (Path::new("cameras.txt"), Path::new("images.txt"), Path::new("points3D.txt"));
    for pts in [Some((p, points)), None] {
        if let Ok(model) = colmap::parse_model((c, cams), (i, images), pts) {
            for cam in &model.cameras {
                cam.validate().expect("returned cameras are valid");
            }
        }
    }
});
