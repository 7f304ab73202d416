//! The decision stack's options, shared by `eval` and `demo` so that both spell them the same.

use wheelleg_sim::local_plan::{LastMetresConfig, LocalPlannerConfig};
use wheelleg_stack::{Preset, StackConfig};

/// The map the collision guard reads (`--guard-map`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum GuardMapArg {
    /// The policy's own 5 cm map.
    Policy,
    /// A 1 cm map of the robot's surroundings, as a robot's elevation mapping keeps
    /// (`MapGrid::GUARD_FINE`; docs/results.md, "A finer map for the guard").
    Fine,
}

/// The stack presets by name (`--stack`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum StackArg {
    /// The decision rule alone.
    Policy,
    /// What the controller firmware runs: the rule, the guard, arrival.
    #[default]
    Robot,
    /// `robot` plus the look-ahead and the searches of a companion computer.
    Full,
}

impl StackArg {
    /// The preset it names.
    pub fn preset(self) -> Preset {
        match self {
            StackArg::Policy => Preset::Policy,
            StackArg::Robot => Preset::Robot,
            StackArg::Full => Preset::Full,
        }
    }
}

/// Which stack decides, and its layers' settings.
#[derive(clap::Args, Clone, Debug, Default)]
pub struct StackArgs {
    /// The layers between the policy's logits and the action sent: `policy` (the decision
    /// rule alone: the most probable action not yet taken at this observation), `robot` (what
    /// the controller firmware runs: the rule, the collision guard on a 1 cm map, the arrival
    /// rule) or `full` (`robot` plus what a companion computer adds: rollouts of the policy
    /// on the robot's map with a search for a shorter way, and a search for the last metres).
    /// Default: robot. docs/results.md, "Current figures".
    #[arg(long, value_enum, value_name = "NAME")]
    pub stack: Option<StackArg>,
    /// The guard grows every map column by MARGIN_M metres on each side (default 0.005;
    /// negative shrinks them).
    #[arg(long, value_name = "MARGIN_M", allow_negative_numbers = true)]
    pub guard_margin: Option<f32>,
    /// The map the guard reads: `fine` (a 1 cm map of the robot's surroundings, as a robot's
    /// elevation mapping keeps; the default) or `policy` (the policy's own 5 cm map).
    #[arg(long, value_name = "MAP")]
    pub guard_map: Option<GuardMapArg>,
    /// Leave out the collision guard: actions are sent unchecked.
    #[arg(long)]
    pub no_guard: bool,
    /// Leave out the arrival rule (which takes the policy's most probable action that ends
    /// within the success radius of the target whenever one does).
    #[arg(long)]
    pub no_arrival: bool,
    /// The look-ahead (`full`) weighs the rule's own action and the next ones it would fall
    /// back to, CANDIDATES in all (default 8), by rollouts of the policy on the robot's map.
    #[arg(long, value_name = "CANDIDATES",
          value_parser = clap::value_parser!(u16).range(2..=243))]
    pub lookahead_candidates: Option<u16>,
    /// Steps a look-ahead rollout may take before it counts as not arriving (default 40).
    #[arg(long, value_name = "STEPS", value_parser = clap::value_parser!(u32).range(1..))]
    pub lookahead_horizon: Option<u32>,
    /// Where none of the look-ahead's candidates arrives, weigh this many in all (default 8).
    #[arg(long, value_name = "CANDIDATES",
          value_parser = clap::value_parser!(u16).range(1..=243))]
    pub lookahead_stuck: Option<u16>,
    /// The look-ahead's search for a way shorter than the best rollout's, at most EXPANSIONS
    /// (default 500; 0 leaves the search out).
    #[arg(long, value_name = "EXPANSIONS")]
    pub lookahead_search: Option<usize>,
    /// The search for the last metres (`full`), at most EXPANSIONS (default 1000; 0 leaves it
    /// out).
    #[arg(long, value_name = "EXPANSIONS")]
    pub last_metres: Option<usize>,
}

impl StackArgs {
    /// The preset named by `--stack` (robot when none is).
    pub fn preset(&self) -> Preset {
        self.stack.unwrap_or_default().preset()
    }

    /// Whether nothing but the default `robot` stack was asked for.
    pub fn is_robot_default(&self) -> bool {
        let Self {
            stack,
            guard_margin,
            guard_map,
            no_guard,
            no_arrival,
            lookahead_candidates,
            lookahead_horizon,
            lookahead_stuck,
            lookahead_search,
            last_metres,
        } = self;
        stack.is_none_or(|s| s == StackArg::Robot)
            && guard_margin.is_none()
            && guard_map.is_none()
            && !no_guard
            && !no_arrival
            && lookahead_candidates.is_none()
            && lookahead_horizon.is_none()
            && lookahead_stuck.is_none()
            && lookahead_search.is_none()
            && last_metres.is_none()
    }

    /// The stack's layers: the preset's, with the options applied. An option for a layer the
    /// stack does not have is an error naming it, never silently ignored.
    pub fn config(&self) -> Result<StackConfig, String> {
        let preset = self.preset();
        let mut config = preset.config();
        let name = preset.name();
        if self.no_guard {
            config.guard = None;
        }
        if self.no_arrival {
            config.arrival = false;
        }
        for (given, option) in [
            (self.guard_margin.is_some(), "--guard-margin"),
            (self.guard_map.is_some(), "--guard-map"),
        ] {
            if given && config.guard.is_none() {
                return Err(format!(
                    "{option}: the {name} stack{} has no collision guard",
                    if self.no_guard {
                        " with --no-guard"
                    } else {
                        ""
                    }
                ));
            }
        }
        if let Some(guard) = &mut config.guard {
            if let Some(margin_m) = self.guard_margin {
                guard.margin_m = margin_m;
            }
            if let Some(map) = self.guard_map {
                guard.grid = match map {
                    GuardMapArg::Policy => None,
                    GuardMapArg::Fine => Some(wheelleg_sim::height_map::MapGrid::GUARD_FINE),
                };
            }
        }
        let lookahead_options = [
            (
                self.lookahead_candidates.is_some(),
                "--lookahead-candidates",
            ),
            (self.lookahead_horizon.is_some(), "--lookahead-horizon"),
            (self.lookahead_stuck.is_some(), "--lookahead-stuck"),
            (self.lookahead_search.is_some(), "--lookahead-search"),
            (self.last_metres.is_some(), "--last-metres"),
        ];
        if let Some((_, option)) = lookahead_options.iter().find(|(given, _)| *given) {
            if preset != Preset::Full {
                return Err(format!(
                    "{option}: the {name} stack has no look-ahead or searches (--stack full has)"
                ));
            }
        }
        if let Some(lookahead) = &mut config.lookahead {
            if let Some(n) = self.lookahead_candidates {
                lookahead.candidates = usize::from(n);
            }
            if let Some(steps) = self.lookahead_horizon {
                lookahead.horizon_steps = steps;
            }
            if let Some(n) = self.lookahead_stuck {
                lookahead.stuck_candidates = usize::from(n);
            }
            if let Some(expansions) = self.lookahead_search {
                lookahead.search_expansions = expansions;
            }
        }
        match self.last_metres {
            Some(0) => config.last_metres = None,
            Some(max_expansions) => {
                config.last_metres = Some(LastMetresConfig {
                    planner: LocalPlannerConfig {
                        max_expansions,
                        ..LocalPlannerConfig::default()
                    },
                    ..LastMetresConfig::default()
                })
            }
            None => {}
        }
        Ok(config)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Cli {
        #[command(flatten)]
        stack: StackArgs,
    }

    fn config(args: &[&str]) -> Result<StackConfig, String> {
        let cli = Cli::try_parse_from(std::iter::once("wheelleg").chain(args.iter().copied()))
            .map_err(|e| e.to_string())?;
        cli.stack.config()
    }

    #[test]
    fn the_options_change_the_named_stacks_layers_and_refuse_missing_ones() {
        let robot = config(&[]).unwrap();
        assert!(robot.guard.is_some() && robot.arrival && robot.lookahead.is_none());
        let unguarded = config(&["--no-guard", "--no-arrival"]).unwrap();
        assert!(unguarded.guard.is_none() && !unguarded.arrival);
        let coarse = config(&["--guard-map", "policy", "--guard-margin", "-0.01"]).unwrap();
        let guard = coarse.guard.unwrap();
        assert_eq!((guard.grid, guard.margin_m), (None, -0.01));
        let full = config(&[
            "--stack",
            "full",
            "--lookahead-search",
            "0",
            "--last-metres",
            "0",
        ])
        .unwrap();
        assert_eq!(full.lookahead.map(|l| l.search_expansions), Some(0));
        assert!(full.last_metres.is_none() && full.guard.is_some());
        assert!(config(&["--stack", "policy", "--guard-margin", "0.01"])
            .unwrap_err()
            .contains("no collision guard"));
        assert!(config(&["--lookahead-candidates", "4"])
            .unwrap_err()
            .contains("--stack full"));
        assert!(config(&["--stack", "fast"]).is_err());
    }
}
