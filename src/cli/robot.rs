//! `wheelleg robot check|import-urdf|urdf|dbc`: a robot description read, checked, converted.

use super::CliResult;
use std::path::{Path, PathBuf};
use wheelleg_robot::reach::reach;
use wheelleg_robot::urdf;
use wheelleg_robot::RobotDescription;

/// Arguments of `robot`.
#[derive(clap::Args)]
pub struct Args {
    #[command(subcommand)]
    command: Command,
}

#[derive(clap::Subcommand)]
enum Command {
    /// Check a description and print what its geometry allows: the poses on the action
    /// lattice, the tallest bar, the widest slab, the narrowest gap, the behaviours.
    Check {
        /// The description (robots/NAME.toml).
        file: PathBuf,
        /// One JSON object instead of the text report.
        #[arg(long)]
        json: bool,
    },
    /// Read a URDF of a robot of the paper's kind into a description (the CAN map and the
    /// pose ranges get documented defaults to edit, unless the URDF was written by `robot urdf`).
    ImportUrdf {
        /// The URDF.
        file: PathBuf,
        /// Where to write the description (robots/NAME.toml); an existing file is refused.
        #[arg(long)]
        out: PathBuf,
    },
    /// Write a description as URDF (to stdout, or --out) for RViz, MuJoCo or Isaac Lab.
    Urdf {
        /// The description.
        file: PathBuf,
        /// Where to write the URDF.
        #[arg(long)]
        out: Option<PathBuf>,
    },
}

/// Runs `robot`.
pub fn run(args: Args) -> CliResult {
    match args.command {
        Command::Check { file, json } => {
            let description = RobotDescription::load(&file)?;
            let report = reach(&description);
            if json {
                outln!("{}", serde_json::to_string(&report)?);
            } else {
                outln!("{}", report.to_text().trim_end());
            }
            Ok(())
        }
        Command::ImportUrdf { file, out } => {
            let text = std::fs::read_to_string(&file)
                .map_err(|e| format!("cannot read {}: {e}", file.display()))?;
            let description =
                urdf::import(&text).map_err(|e| format!("URDF {}: {e}", file.display()))?;
            if out.exists() {
                return Err(format!(
                    "{} exists; choose another --out (nothing was written)",
                    out.display()
                )
                .into());
            }
            write(&out, &description.to_toml())?;
            outln!(
                "wrote {} (robot '{}'); check it with `wheelleg robot check {}`",
                out.display(),
                description.name,
                out.display()
            );
            Ok(())
        }
        Command::Urdf { file, out } => {
            let description = RobotDescription::load(&file)?;
            let text = urdf::export(&description);
            match out {
                Some(out) => {
                    write(&out, &text)?;
                    outln!("wrote {}", out.display());
                }
                None => outln!("{}", text.trim_end()),
            }
            Ok(())
        }
    }
}

fn write(path: &Path, text: &str) -> CliResult {
    wheelleg_sim::atomic_write(path, text.as_bytes())
        .map_err(|e| format!("cannot write {}: {e}", path.display()).into())
}
