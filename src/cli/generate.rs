//! `wheelleg generate --kind K --count N --seed S --out FILE`.

use super::CliResult;
use rand::SeedableRng;
use std::path::PathBuf;
use wheelleg_sim::generate::{generate_many, SceneKind};

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
}

/// Runs `generate`.
pub fn run(args: Args) -> CliResult {
    let kind = parse_kind(&args.kind)?;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(args.seed);
    let scenarios = generate_many(kind, &mut rng, args.count);
    wheelleg_sim::scenario_file::save(&args.out, &scenarios)?;
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
