//! `wheelleg generate --kind K --count N --seed S --out FILE [--robot FILE]`.

use super::robot::RobotArg;
use super::CliResult;
use rand::SeedableRng;
use std::path::PathBuf;
use wheelleg_sim::generate::{generate_many, Behaviour, SceneKind, SceneRobot};

/// Arguments of `generate`.
#[derive(clap::Args)]
pub struct Args {
    /// Scene kind: straight, around, lift, spread, squeeze, complex or composed.
    #[arg(long)]
    kind: String,
    /// Number of scenes.
    #[arg(long, default_value_t = 10)]
    count: usize,
    /// Seed of every random choice.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Scenario file to write.
    #[arg(long)]
    out: PathBuf,
    /// The robot the scenes are built for.
    #[command(flatten)]
    robot: RobotArg,
}

/// Runs `generate`.
pub fn run(args: Args) -> CliResult {
    let kind = parse_kind(&args.kind)?;
    let (description, geometry) = args.robot.simulated()?;
    let robot = SceneRobot::new(&geometry);
    scene_kind_for(&robot, kind, &description.name)?;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(args.seed);
    let scenarios = generate_many(&robot, kind, &mut rng, args.count);
    wheelleg_sim::scenario_file::save(&args.out, &scenarios, &geometry)?;
    outln!(
        "wrote {} {} scenes to {}",
        scenarios.len(),
        kind.name(),
        args.out.display()
    );
    Ok(())
}

/// Parses a scene kind name, listing the valid ones when it is not one.
pub fn parse_kind(name: &str) -> Result<SceneKind, String> {
    SceneKind::from_name(name).ok_or_else(|| {
        let names: Vec<&str> = SceneKind::ALL.iter().map(|k| k.name()).collect();
        format!(
            "unknown scene kind {name:?}; expected one of {}",
            names.join(", ")
        )
    })
}

/// Refuses a scene kind whose fence asks a behaviour `robot` lacks (composed scenes: when it has
/// no fence at all), saying why.
pub fn scene_kind_for(robot: &SceneRobot, kind: SceneKind, name: &str) -> Result<(), String> {
    let why = match kind {
        SceneKind::Behaviour(b) => robot.has(b).err(),
        SceneKind::Composed => {
            let fences = [
                Behaviour::LiftOver,
                Behaviour::SpreadOver,
                Behaviour::Squeeze,
            ];
            (!fences.iter().any(|&b| robot.has(b).is_ok()))
                .then(|| "it has none of the lift, spread and squeeze fences".to_string())
        }
        SceneKind::Complex => None,
    };
    match why {
        Some(why) => Err(format!(
            "no {} scenes for robot '{name}': {why}",
            kind.name()
        )),
        None => Ok(()),
    }
}
