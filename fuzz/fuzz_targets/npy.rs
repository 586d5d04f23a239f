//! numpy .npy: never panic or allocate past the input; a parsed array has as many
//! values as its shape says and survives a float32 write + read.
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::path::Path;
use transsplat_scene::npy;

fuzz_target!(|data: &[u8]| {
    let path = Path::new("fuzz.npy");
    if let Ok(a) = npy::parse(data, path) {
        assert_eq!(a.shape.iter().product::<usize>(), a.data.len());
        let back = npy::parse(&npy::to_bytes(&a.shape, &a.data), path).expect("an array we wrote reads back");
        assert_eq!(back.shape, a.shape);
        assert!(back.data.iter().zip(&a.data).all(|(x, y)| x.to_bits() == y.to_bits()));
    }
});
