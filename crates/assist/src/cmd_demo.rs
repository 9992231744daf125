//! `assist demo`.
use clap::Args;

#[derive(Args, Debug)]
pub struct DemoArgs {}

pub fn run(_a: DemoArgs) -> anyhow::Result<()> {
    anyhow::bail!("demo is being written")
}
