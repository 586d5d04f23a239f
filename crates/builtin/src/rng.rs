//! The scenes' generator: `transsplat_scene::rng::SplitMix64` with a fixed seed
//! offset (the scenes depend on no RNG crate, so their bytes never change with a
//! dependency update).

pub(crate) use transsplat_scene::rng::mix;
use transsplat_scene::rng::SplitMix64;

pub(crate) type Rng = SplitMix64;

/// The generator of a scene seed.
pub(crate) fn seeded(seed: u64) -> Rng {
    SplitMix64::new(seed ^ 0x7261_6E73_5370_6C74)
}
