//! `wheelleg robot check|import-urdf|urdf|dbc`: a robot description read, checked, converted.

use super::CliResult;
use std::path::{Path, PathBuf};
use wheelleg_robot::reach::reach;
use wheelleg_robot::urdf;
use wheelleg_robot::RobotDescription;
use wheelleg_sim::generate::{Behaviour, SceneRobot, FENCE_MARGIN_M};
use wheelleg_sim::robot::SimulatedRobot;

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

    /// The description and the robot as the simulator steps it (refused, naming the key, when
    /// the simulator cannot: [`SimulatedRobot::of`]).
    pub fn simulated(&self) -> Result<(RobotDescription, SimulatedRobot), String> {
        let description = self.description()?;
        let robot = SimulatedRobot::of(&description)?;
        Ok((description, robot))
    }
}

/// How one scene fence fits a robot: its passing pose in (clearance, track) steps, or why the
/// fence is left out.
type FenceFit = Result<(i32, i32), String>;

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
            // How the scene generators' fences fit it (for a robot the simulator can run).
            let fences: Vec<(&str, FenceFit)> = match SimulatedRobot::of(&description) {
                Ok(simulated) => {
                    let fit = SceneRobot::new(&simulated);
                    [
                        Behaviour::LiftOver,
                        Behaviour::SpreadOver,
                        Behaviour::Squeeze,
                    ]
                    .into_iter()
                    .map(|b| (b.name(), fit.has(b).map(|()| fit.passing_legs(b))))
                    .collect()
                }
                Err(why) => vec![("all", Err(why))],
            };
            if json {
                let mut value = serde_json::to_value(&report)?;
                value["fences"] = fences
                    .iter()
                    .map(|(name, fit)| {
                        let fit = match fit {
                            Ok((c, t)) => {
                                serde_json::json!({"clearance_steps": c, "track_steps": t})
                            }
                            Err(why) => serde_json::json!({"left_out": why}),
                        };
                        ((*name).to_owned(), fit)
                    })
                    .collect::<serde_json::Map<_, _>>()
                    .into();
                outln!("{}", serde_json::to_string(&value)?);
            } else {
                outln!("{}", report.to_text().trim_end());
                outln!(
                    "scene fences (the pose each is passed in; found with {:.0} mm to spare, \
                     the shipped robot's as designed):",
                    FENCE_MARGIN_M * 1000.0
                );
                let robot = &description.robot;
                for (name, fit) in &fences {
                    match fit {
                        Ok((c, t)) => outln!(
                            "  {name:<8} {c:+} clearance, {t:+} track steps (clearance {:.0} mm, track {:.0} mm)",
                            1000.0 * (robot.geometry.default_clearance_m + *c as f32 * robot.actions.clearance_step_m),
                            1000.0 * (robot.geometry.default_track_m + *t as f32 * robot.actions.track_step_m),
                        ),
                        Err(why) => outln!("  {name:<8} left out: {why}"),
                    }
                }
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
