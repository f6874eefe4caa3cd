//! `tessera report`: the pictures and summary of a headless flight.

use crate::flight_report::animation;
use crate::output;
use std::path::PathBuf;

/// `tessera report`'s arguments (its help text is on the `Command` it is a variant of).
#[derive(Debug, clap::Args)]
pub struct ReportArgs {
    /// The flight's stats.jsonl.
    stats: PathBuf,
    /// The frames directory (frame_NNNNN.png) for the contact sheet and the
    /// animation.
    #[arg(long)]
    frames: Option<PathBuf>,
    /// Where to write stats.png, contact_sheet.png and flight.png.
    #[arg(long, short, default_value = ".")]
    out: PathBuf,
    /// Frames per second the frames were flown at (the animation's pace).
    #[arg(long, default_value_t = 30, value_parser = clap::value_parser!(u32).range(1..=1000))]
    fps: u32,
}

/// Runs the command.
pub fn run(args: ReportArgs) -> anyhow::Result<()> {
    let ReportArgs {
        stats,
        frames,
        out,
        fps,
    } = args;
    let summary = crate::flight_report::flight::write_report(&stats, frames.as_deref(), &out)?;
    // A reader gone away (`| head -1`) stops the printing, not the report's files.
    let mut printed = output::print_line(&summary);
    if let Some(dir) = &frames {
        let file = out.join("flight.png");
        let opts = animation::AnimationOptions {
            fps,
            ..animation::AnimationOptions::default()
        };
        let a = animation::write_animation(&animation::frame_files(dir)?, &file, opts)?;
        if printed.is_ok() {
            printed = output::print_line(format_args!(
                "{}: {} frames of {}×{} (every {}), {:.1} MB",
                file.display(),
                a.frames,
                a.width,
                a.height,
                a.step,
                a.bytes as f64 / 1e6
            ));
        }
    }
    Ok(printed?)
}
