//! PNG and JPEG images: never panic or allocate past the input; an accepted image has
//! `width * height * 3` values, an alpha channel (if any) of `width * height`, all in
//! [0, 1], and compositing over a background in [0, 1] stays in [0, 1].
//!
//! No round trip: `image::write_png` only writes to a path (there is no bytes encoder),
//! and a fuzzer must not write files.
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::path::Path;
use transsplat_scene::image;

fn unit(v: &[f32]) -> bool {
    v.iter().all(|x| x.is_finite() && (0.0..=1.0).contains(x))
}

fuzz_target!(|data: &[u8]| {
    if let Ok(img) = image::decode(data, Path::new("fuzz.img")) {
        let n = img.width * img.height;
        assert!(n > 0);
        assert_eq!(img.data.len(), n * 3);
        assert!(unit(&img.data));
        if let Some(a) = &img.alpha {
            assert_eq!(a.len(), n);
            assert!(unit(a));
        }
        let c = img.composite([0.0, 0.5, 1.0]);
        assert!(c.alpha.is_none() && c.data.len() == n * 3 && unit(&c.data));
    }
});
