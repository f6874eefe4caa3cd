//! `tessera inspect`: a local pyramid file's size, levels and height range.

use anyhow::Context;
use std::path::PathBuf;
use tessera_shared::Pyramid;

/// `tessera inspect`'s arguments (its help text is on the `Command` it is a variant of).
#[derive(Debug, clap::Args)]
pub struct InspectArgs {
    /// A `.tess` pyramid file.
    file: PathBuf,
}

/// Runs the command.
pub fn run(args: InspectArgs) -> anyhow::Result<()> {
    let InspectArgs { file } = args;
    let p = Pyramid::open_file(&file).with_context(|| file.display().to_string())?;
    let m = p.metadata();
    println!(
        "{}: {}×{} samples, {} levels of {}-cell tiles, heights {:.2}..{:.2} m",
        file.display(),
        m.width,
        m.height,
        m.levels,
        m.tile_size,
        m.min_height,
        m.max_height
    );
    Ok(())
}
