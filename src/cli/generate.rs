//! `wheelleg generate --kind K --count N --seed S --out FILE [--robot FILE]`.

use super::robot::RobotArg;
use super::CliResult;
use rand::SeedableRng;
use std::path::PathBuf;
use wheelleg_sim::generate::{generate_many, Behaviour, SceneKind, SceneRobot};

/// Arguments of `generate`.
#[derive(clap::Args)]
pub struct Args {
    /// Scene kind.
    #[arg(long, value_enum)]
    kind: KindArg,
    /// Number of scenes.
    #[arg(long, default_value_t = 10)]
    count: usize,
    /// Seed of every random choice.
    #[arg(long, default_value_t = wheelleg_sim::seeds::TRAINING)]
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
    let kind = args.kind.scene_kind();
    let (description, simulated) = args.robot.simulated()?;
    let robot = SceneRobot::new(&simulated);
    robot.has_kind(kind).map_err(|why| {
        format!(
            "no {} scenes for robot '{}': {why}",
            kind.name(),
            description.name
        )
    })?;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(args.seed);
    let scenarios = generate_many(&robot, kind, &mut rng, args.count);
    wheelleg_sim::scenario_file::save(&args.out, &scenarios, &simulated)?;
    outln!(
        "wrote {} {} scenes to {}",
        scenarios.len(),
        kind.name(),
        args.out.display()
    );
    Ok(())
}

/// A scene kind on the command line (`--kind`): the generators' [`SceneKind`] by its name.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum KindArg {
    /// Nothing in the way.
    Straight,
    /// One block, or two side by side, to drive around.
    Around,
    /// A fence of bars: lift the body over one.
    Lift,
    /// A fence with a slab: spread the legs over it.
    Spread,
    /// A fence of blocks with one narrow gap: squeeze through.
    Squeeze,
    /// One to eight obstacles of any kind.
    Complex,
    /// One or two fences amid clutter.
    Composed,
}

impl KindArg {
    /// The generators' scene kind.
    pub fn scene_kind(self) -> SceneKind {
        match self {
            KindArg::Straight => SceneKind::Behaviour(Behaviour::Straight),
            KindArg::Around => SceneKind::Behaviour(Behaviour::Around),
            KindArg::Lift => SceneKind::Behaviour(Behaviour::LiftOver),
            KindArg::Spread => SceneKind::Behaviour(Behaviour::SpreadOver),
            KindArg::Squeeze => SceneKind::Behaviour(Behaviour::Squeeze),
            KindArg::Complex => SceneKind::Complex,
            KindArg::Composed => SceneKind::Composed,
        }
    }
}
