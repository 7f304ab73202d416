//! `wheelleg robot check|import-urdf|urdf|dbc`: a robot description read, checked, converted.

use super::CliResult;
use std::path::{Path, PathBuf};
use wheelleg_robot::reach::reach;
use wheelleg_robot::urdf;
use wheelleg_robot::RobotDescription;
use wheelleg_runtime::robot::RobotGeometry;

/// `--robot FILE`, the robot a command simulates, plans for or drives: the shipped robot
/// (`robots/wheelleg.toml`, compiled in) when not given.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct RobotArg {
    /// Robot description (robots/NAME.toml); the shipped robot when not given.
    #[arg(long, value_name = "FILE")]
    pub robot: Option<PathBuf>,
}

impl RobotArg {
    /// The description, read and checked.
    pub fn description(&self) -> Result<RobotDescription, String> {
        match &self.robot {
            Some(path) => RobotDescription::load(path),
            None => Ok(RobotDescription::shipped()),
        }
    }

    /// The description and the geometry the simulator runs it with (refused when the
    /// simulator cannot: [`RobotDescription::simulated_geometry`]).
    pub fn simulated(&self) -> Result<(RobotDescription, RobotGeometry), String> {
        let description = self.description()?;
        let geometry = description.simulated_geometry()?;
        Ok((description, geometry))
    }
}

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
        /// Also draw the front and side views at the default and the extreme poses (PNG, in
        /// metres), to hold against the robot.
        #[arg(long)]
        picture: Option<PathBuf>,
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
        Command::Check {
            file,
            json,
            picture,
        } => {
            let description = RobotDescription::load(&file)?;
            let report = reach(&description);
            if let Some(path) = &picture {
                let pose = |label: &str, p: wheelleg_robot::reach::Pose| {
                    let legs = wheelleg_runtime::leg::LegConfig {
                        clearance_m: p.clearance_m,
                        track_m: p.track_m,
                    };
                    (label.to_string(), legs)
                };
                let poses = [
                    pose("default", report.default_pose),
                    pose("lift", report.lift.pose),
                    pose("spread", report.spread.pose),
                    pose("squeeze", report.squeeze.pose),
                ];
                let canvas = wheelleg_sim::render::robot_views(
                    &description.name,
                    &description.robot.geometry,
                    &poses,
                )?;
                canvas
                    .save_png(path)
                    .map_err(|e| format!("cannot write {}: {e}", path.display()))?;
                eprintln!("wrote {}", path.display());
            }
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
