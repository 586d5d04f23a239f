//! PLY scenes (ASCII, binary little- and big-endian): never panic, never allocate past
//! the input; anything read is finite (unless refused) and survives write + read.
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::path::Path;
use transsplat_scene::ply::{self, ReadOptions};

fuzz_target!(|data: &[u8]| {
    let path = Path::new("fuzz.ply");
    let strict = ply::parse_with(data, path, &ReadOptions { drop_invalid: false });
    let lenient = ply::parse_with(data, path, &ReadOptions { drop_invalid: true });
    match (&strict, &lenient) {
        (Ok((g, 0)), Ok((h, 0))) => assert_eq!(g.len(), h.len()),
        (Ok(_), _) => panic!("strict read dropped Gaussians or lenient read failed"),
        _ => {}
    }
    if let Ok((g, _)) = lenient {
        assert!(g.first_non_finite().is_none(), "drop_invalid kept a non-finite Gaussian");
        let bytes = ply::to_bytes(&g);
        let back = ply::parse(&bytes, path).expect("a scene we wrote reads back");
        assert_eq!(back.len(), g.len());
        assert_eq!(back.sh_degree, g.sh_degree);
        assert_eq!(back.means, g.means);
        assert_eq!(back.sh, g.sh);
    }
});
