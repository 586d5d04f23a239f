//! nerfstudio / Blender transforms.json: never panic; every camera returned is valid.
//! Frames without "w"/"h" look for their image beside the JSON (a folder that does
//! not exist here), so that path is exercised as a missing-image error.
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::path::Path;
use transsplat_scene::cameras::transforms;

fuzz_target!(|data: &[u8]| {
    let path = Path::new("/nonexistent-transsplat-fuzz/transforms.json");
    if let Ok(t) = transforms::parse(data, path) {
        for cam in &t.cameras {
            cam.validate().expect("returned cameras are valid");
        }
    }
});
