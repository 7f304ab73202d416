//! `wheelleg eval --policy CKPT|WEIGHTS (--scenarios FILE | --generated N --kind K) --seed S [--json]
//! [--stack policy|robot|full] [--rule untried|argmax|sample] [layer options, shared with demo]
//! [--max-expansions N | --planner-results PLAN.json]`.

use super::robot::RobotArg;
use super::stack_args::StackArgs;
use super::CliResult;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use std::path::{Path, PathBuf};
use wheelleg_robot::RobotDescription;
use wheelleg_runtime::model::format::MAGIC;
use wheelleg_sim::env::EnvConfig;
use wheelleg_sim::generate::{generate_many, SceneRobot};
use wheelleg_stack::policy::BatchPolicy;
use wheelleg_stack::policy::Int8Policy;
use wheelleg_stack::{DecisionRule, Preset};
use wheelleg_trainer::batch_policy::FloatPolicy;
use wheelleg_trainer::evaluate::{evaluate, EvalOptions};
use wheelleg_trainer::network::BackendKind;
use wheelleg_trainer::TrainError;

/// Arguments of `eval`.
#[derive(clap::Args)]
pub struct Args {
    /// Policy: a run's checkpoint.ckpt (float, as trained) or a `.wlw` weights file (int8, run
    /// by the robot's runtime crate).
    #[arg(long)]
    policy: PathBuf,
    /// Scenario file (JSON) to evaluate on.
    #[arg(long, conflicts_with_all = ["generated", "kind"])]
    scenarios: Option<PathBuf>,
    /// Evaluate on this many generated scenes (needs --kind).
    #[arg(long, requires = "kind")]
    generated: Option<usize>,
    /// Kind of generated scenes.
    #[arg(long, value_enum)]
    kind: Option<super::generate::KindArg>,
    /// Seed of scene generation and stochastic actions (use seeds not used in training).
    #[arg(long, default_value_t = wheelleg_sim::seeds::HELD_OUT)]
    seed: u64,
    /// Print JSON instead of a table.
    #[arg(long)]
    json: bool,
    /// How the policy's heads become one action: `untried` (the most probable action not yet
    /// taken at this observation, what the robot runs; the default), `argmax` (each head's most
    /// probable choice, even when that action was just refused) or `sample` (a draw from each
    /// head, the training rule). argmax and sample only with `--stack policy` (docs/results.md,
    /// "Decision rule").
    #[arg(long, value_name = "RULE", value_enum, default_value_t = RuleArg::Untried)]
    rule: RuleArg,
    /// Planner budget per scenario (expanded states) for the shortest-path ratio; 0 skips it.
    #[arg(long, alias = "planner-expansions", default_value_t = 20_000)]
    max_expansions: usize,
    /// Shortest paths already found by `wheelleg plan --json` on the same scenarios (a file);
    /// the planner is then not run, so one planner pass serves every policy.
    #[arg(long, conflicts_with = "max_expansions")]
    planner_results: Option<PathBuf>,
    /// The decision stack.
    #[command(flatten)]
    stack: StackArgs,
    /// The robot simulated; the policy must be trained for it.
    #[command(flatten)]
    robot: RobotArg,
}

/// Runs `f` with the policy in file `path`: a `.wlw` weights file (int8, run by the robot's
/// runtime crate) or a run's checkpoint (float, as trained); refused when it was made for
/// another robot than `robot`.
pub fn with_policy<T>(
    path: &Path,
    robot: &RobotDescription,
    f: impl FnOnce(&dyn BatchPolicy) -> Result<T, TrainError>,
) -> Result<T, Box<dyn std::error::Error>> {
    let label = path.display().to_string();
    let bytes = std::fs::read(path).map_err(|e| format!("cannot read {label}: {e}"))?;
    if bytes.starts_with(&MAGIC) {
        let policy = Int8Policy::from_bytes(&bytes).map_err(|e| format!("{label}: {e}"))?;
        robot.accepts(&policy.model().trained_for, &label)?;
        Ok(f(&policy)?)
    } else {
        let (checkpoint, extras) =
            wheelleg_trainer::checkpoint::Checkpoint::from_bytes_with_extras(&bytes)
                .map_err(|e| format!("{label}: {e}"))?;
        extras.check_robot(robot, &label)?;
        let net = checkpoint
            .network
            .to_network()
            .map_err(|e| format!("{label}: {e}"))?;
        let policy = FloatPolicy::new(&net, &BackendKind::Flex.device()?)?;
        Ok(f(&policy)?)
    }
}

/// How the policy's heads become one action (`--rule`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum RuleArg {
    /// The most probable action not yet taken at this observation: what the robot runs.
    Untried,
    /// Each head's most probable choice, even when that action was just refused.
    Argmax,
    /// A draw from each head: the training rule.
    Sample,
}

/// Runs `eval`.
pub fn run(args: Args) -> CliResult {
    let (robot, simulated) = args.robot.simulated()?;
    let scenarios = match (&args.scenarios, args.generated, &args.kind) {
        (Some(file), _, _) => wheelleg_sim::scenario_file::load(file, &simulated)?,
        (None, Some(n), Some(kind)) => {
            let kind = kind.scene_kind();
            let scene_robot = SceneRobot::of(&simulated);
            scene_robot.has_kind(kind).map_err(|why| {
                format!(
                    "no {} scenes for robot '{}': {why}",
                    kind.name(),
                    robot.name
                )
            })?;
            generate_many(
                scene_robot,
                kind,
                &mut ChaCha8Rng::seed_from_u64(args.seed),
                n,
            )
        }
        _ => return Err("give --scenarios FILE or --generated N --kind K".into()),
    };
    if scenarios.is_empty() {
        return Err("no scenarios to evaluate".into());
    }
    let known_shortest = match &args.planner_results {
        Some(path) => {
            let text = std::fs::read_to_string(path)
                .map_err(|e| format!("cannot read {}: {e}", path.display()))?;
            Some(
                wheelleg_trainer::evaluate::read_plan_results(&text)
                    .map_err(|e| format!("{}: {e}", path.display()))?,
            )
        }
        None => None,
    };
    let mut stack = args.stack.config()?;
    stack.rule = match args.rule {
        RuleArg::Argmax => DecisionRule::Argmax,
        RuleArg::Sample => DecisionRule::Sample,
        RuleArg::Untried => DecisionRule::Untried,
    };
    if stack.rule != DecisionRule::Untried && args.stack.preset() != Preset::Policy {
        return Err(format!(
            "--rule {}: only with --stack policy (the guard, arrival and the look-ahead build on \
             the untried rule's memory of what it took)",
            clap::ValueEnum::to_possible_value(&args.rule)
                .map_or_else(String::new, |v| v.get_name().to_owned())
        )
        .into());
    }
    stack.check()?;
    let options = EvalOptions {
        stack,
        planner_expansions: args.max_expansions,
        known_shortest,
        env_config: EnvConfig {
            robot: simulated,
            ..EvalOptions::default().env_config
        },
    };
    let mut rng = ChaCha8Rng::seed_from_u64(args.seed);
    rng.set_stream(1);
    let report = with_policy(&args.policy, &robot, |policy| {
        evaluate(policy, &scenarios, &options, &mut rng)
    })?;
    if args.json {
        outln!("{}", serde_json::to_string_pretty(&report)?);
        return Ok(());
    }
    outln!(
        "{:<28} {:>8} {:>9} {:>6} {:>10} {:>8} {:>7} {:>8}",
        "scenario",
        "success",
        "coll-free",
        "steps",
        "collisions",
        "planner",
        "end m",
        "beside"
    );
    for r in &report.scenarios {
        outln!(
            "{:<28} {:>8} {:>9} {:>6} {:>10} {:>8} {:>7.3} {:>8}",
            r.name,
            if r.success { "yes" } else { "no" },
            if r.collision_free { "yes" } else { "no" },
            r.steps,
            r.collisions,
            r.planner_steps.map_or("-".to_string(), |s| s.to_string()),
            r.final_distance_m,
            r.target_beside.as_deref().unwrap_or("-")
        );
    }
    let opt =
        |v: Option<f32>, digits: usize| v.map_or("-".to_string(), |v| format!("{v:.digits$}"));
    outln!();
    outln!("scenarios            {}", report.scenarios.len());
    outln!(
        "decision rule        {}",
        match report.decision {
            DecisionRule::Untried =>
                "untried (most probable action not yet taken at this observation)",
            DecisionRule::Argmax => "argmax (each head's most probable choice)",
            DecisionRule::Sample => "sampled",
        }
    );
    outln!(
        "collision guard      {}",
        report
            .guard_margin_m
            .map_or("off (the policy alone)".to_string(), |m| format!(
                "on, map columns grown by {m} m, {} m cells",
                report.guard_cell_m.unwrap_or(f32::NAN)
            ))
    );
    outln!(
        "arrival rule         {}",
        if report.arrival {
            "on (an action that reaches the target goes first)"
        } else {
            "off"
        }
    );
    outln!(
        "last metres          {}",
        report.last_metres.map_or("off".to_string(), |l| format!(
            "searched on the robot's map in {} episodes: {} searches, {} plans",
            l.episodes_searched, l.searches, l.plans
        ))
    );
    outln!(
        "look-ahead           {}",
        report.lookahead.map_or("off".to_string(), |l| format!(
            "{} candidates ({} where none arrives), {}-step rollouts: another action than the rule's at {} of {} decisions",
            l.candidates, l.stuck_candidates, l.horizon_steps, l.overrides, l.decisions
        ))
    );
    outln!("success rate         {:.1}%", 100.0 * report.success_rate);
    outln!(
        "collision-free rate  {:.1}%",
        100.0 * report.collision_free_rate
    );
    outln!("mean steps (success) {}", opt(report.mean_steps, 1));
    outln!(
        "steps vs shortest    {} ({} successes without a planner result, excluded)",
        opt(report.steps_vs_shortest, 3),
        report.planner_budget_exceeded
    );
    outln!(
        "median vs shortest   {} (per scenario: the typical detour)",
        opt(report.median_steps_vs_shortest, 3)
    );
    outln!();
    outln!(
        "beside the target    scenarios  success  coll-free   (an obstacle within {} m of it)",
        wheelleg_trainer::evaluate::BESIDE_TARGET_M
    );
    for b in &report.by_target_beside {
        let pct = |n: usize| 100.0 * n as f32 / b.scenarios.max(1) as f32;
        outln!(
            "  {:<18} {:>9} {:>7.1}% {:>9.1}%",
            b.beside,
            b.scenarios,
            pct(b.successes),
            pct(b.collision_free)
        );
    }
    // One family is the whole evaluation again: the split shows from two on.
    for (title, groups, shown_from) in [
        ("scene family", &report.by_family, 2),
        ("composed variant", &report.by_composed_variant, 1),
    ] {
        if groups.len() < shown_from {
            continue;
        }
        outln!();
        outln!("{title:<20} scenarios  success  coll-free");
        for g in groups {
            let pct = |n: usize| 100.0 * n as f32 / g.scenarios.max(1) as f32;
            outln!(
                "  {:<18} {:>9} {:>7.1}% {:>9.1}%",
                g.name,
                g.scenarios,
                pct(g.successes),
                pct(g.collision_free)
            );
        }
    }
    Ok(())
}
