//! `assist synth`: the built-in scene generator.

use std::path::PathBuf;

use clap::Args;

#[derive(Args, Debug)]
pub struct SynthArgs {
    #[arg(long)]
    pub out: PathBuf,
}

pub fn run(_a: SynthArgs) -> anyhow::Result<()> {
    anyhow::bail!("synth is being written")
}
