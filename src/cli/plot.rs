//! `wheelleg plot runs/A runs/B ... --out curves.png`; several seeds of one method as one curve
//! (mean and min-max band): `wheelleg plot baseline=runs/b-s0,runs/b-s1 primary=... --out x.png`.

use super::CliResult;
use std::path::PathBuf;

/// Arguments of `plot`.
#[derive(clap::Args)]
pub struct Args {
    /// Curves: a run folder (with a metrics.jsonl), or LABEL=DIR,DIR,... to draw several
    /// seeds as their mean with a min-max band.
    #[arg(required = true)]
    runs: Vec<String>,
    /// Output PNG.
    #[arg(long)]
    out: PathBuf,
    /// TTF font for the labels (default: a common system font; without one, no labels).
    #[arg(long)]
    font: Option<PathBuf>,
    /// Trailing moving average over this many iterations per run (1: as logged).
    #[arg(long, default_value_t = 1)]
    smooth: usize,
}

/// Runs `plot`.
pub fn run(args: Args) -> CliResult {
    let groups = args
        .runs
        .iter()
        .map(|r| wheelleg_trainer::plot::RunGroup::parse(r))
        .collect::<Result<Vec<_>, _>>()?;
    wheelleg_trainer::plot::plot_runs(
        &groups,
        &args.out,
        args.font.as_deref(),
        (1400, 1000),
        args.smooth,
    )?;
    outln!("wrote {}", args.out.display());
    Ok(())
}
