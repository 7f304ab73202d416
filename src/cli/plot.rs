//! `wheelleg plot runs/A runs/B ... --out curves.png`.

use super::CliResult;
use std::path::PathBuf;

/// Arguments of `plot`.
#[derive(clap::Args)]
pub struct Args {
    /// Run folders (each with a metrics.jsonl).
    #[arg(required = true)]
    runs: Vec<PathBuf>,
    /// Output PNG.
    #[arg(long)]
    out: PathBuf,
    /// TTF font for the labels (default: a common system font; without one, no labels).
    #[arg(long)]
    font: Option<PathBuf>,
}

/// Runs `plot`.
pub fn run(args: Args) -> CliResult {
    wheelleg_trainer::plot::plot_runs(&args.runs, &args.out, args.font.as_deref(), (1400, 1000))?;
    println!("wrote {}", args.out.display());
    Ok(())
}
