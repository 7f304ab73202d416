//! `wheelleg`: simulate, plan, render, train, evaluate and run the wheel-legged robot's policy.
//!
//! Each subcommand lives in its own module under `cli/` with its arguments and a `run`
//! function; this file only dispatches. Every failure is reported as one line naming what is
//! wrong, with a non-zero exit status.

#[macro_use]
mod cli;

use clap::{Parser, Subcommand};
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "wheelleg",
    version,
    about = "Wheel-legged robot navigation by deep RL"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Generate scenes of a behaviour or complex scenes into a scenario file.
    Generate(cli::generate::Args),
    /// Print what a weights file holds, checked as the robot's runtime checks it.
    Inspect(cli::inspect::Args),
    /// Prove scenarios solvable and find their shortest step counts.
    Plan(cli::plan::Args),
    /// Draw each scenario's top view (with the planner's path) and the robot's height map.
    Render(cli::render::Args),
    /// Train a policy with PPO (checkpoints, metrics, --resume).
    Train(cli::train::Args),
    /// Evaluate a policy: success, collision-free success, path length vs the planner.
    Eval(cli::eval::Args),
    /// Quantize a checkpoint to the robot's int8 weights file (with a model card).
    Export(cli::export::Args),
    /// Plot learning curves of runs into a PNG.
    Plot(cli::plot::Args),
    /// Relevance of each obstacle to a policy's trajectory (remove it, re-roll, compare) as a PNG.
    Relevance(cli::relevance::Args),
    /// Robot descriptions: check one, import a URDF, write one as URDF.
    Robot(cli::robot::Args),
    /// Run the closed loop on one scene: world -> policy (or planner) -> CAN -> simulated
    /// motors -> measured motion -> world; writes path.png and bus.log (candump -L).
    Demo(cli::demo::Args),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Generate(args) => cli::generate::run(args),
        Command::Inspect(args) => cli::inspect::run(args),
        Command::Plan(args) => cli::plan::run(args),
        Command::Render(args) => cli::render::run(args),
        Command::Train(args) => cli::train::run(args),
        Command::Eval(args) => cli::eval::run(args),
        Command::Export(args) => cli::export::run(args),
        Command::Plot(args) => cli::plot::run(args),
        Command::Relevance(args) => cli::relevance::run(args),
        Command::Demo(args) => cli::demo::run(args),
        Command::Robot(args) => cli::robot::run(args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("wheelleg: {error}");
            ExitCode::FAILURE
        }
    }
}
