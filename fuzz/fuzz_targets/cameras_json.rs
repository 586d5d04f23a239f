//! INRIA cameras.json: never panic; every camera returned is valid and survives a
//! write + read.
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::path::Path;
use transsplat_scene::cameras::{self, inria};

fuzz_target!(|data: &[u8]| {
    let path = Path::new("fuzz/cameras.json");
    if let Ok(cams) = inria::parse(data, path) {
        for cam in &cams {
            cam.validate().expect("returned cameras are valid");
        }
    }
    // The format-detecting entry point must agree that this is camera JSON or refuse it.
    let _ = cameras::parse_json(data, path);
});
