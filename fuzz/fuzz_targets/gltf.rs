//! glTF binary scenes (KHR_gaussian_splatting): never panic, never allocate past what
//! the input's lengths allow; what reads with finite values survives write + read with
//! the centres and SH bit-exact.
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::path::Path;
use transsplat_scene::gltf;

fuzz_target!(|data: &[u8]| {
    let path = Path::new("fuzz.glb");
    let Ok(mut g) = gltf::parse(data, path) else { return };
    g.validate().expect("a parsed scene is consistent");
    let keep: Vec<bool> = (0..g.len()).map(|i| g.non_finite_at(i).is_none()).collect();
    g.retain(&keep);
    if g.is_empty() {
        return;
    }
    let back = gltf::parse(&gltf::to_bytes(&g), path).expect("a scene we wrote reads back");
    assert_eq!((back.len(), back.sh_degree), (g.len(), g.sh_degree));
    assert_eq!(back.means, g.means);
    assert_eq!(back.sh, g.sh);
});
