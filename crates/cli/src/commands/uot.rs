//! `transsplat uot` and `transsplat bench transport` (owned by the transport work).

/// Arguments of `transsplat uot`.
#[derive(clap::Args, Debug)]
pub struct UotArgs {}

/// Runs `transsplat uot`.
pub fn run(_args: &UotArgs) -> anyhow::Result<()> {
    anyhow::bail!("not implemented yet")
}

/// Arguments of `transsplat bench transport`.
#[derive(clap::Args, Debug)]
pub struct BenchArgs {}

/// Runs `transsplat bench transport`.
pub fn bench(_args: &BenchArgs) -> anyhow::Result<()> {
    anyhow::bail!("not implemented yet")
}
