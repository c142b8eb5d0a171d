//! `prism info <scene_dir>`.

use prism_domain::scene::Scene;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// Scene directory (scene.yaml + .npy arrays), or an R²-Gaussian case folder (meta_data.json).
    scene: PathBuf,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let scene = Scene::open(&args.scene)?;
    print!("{}", scene.summary());
    Ok(())
}
