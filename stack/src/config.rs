//! Which layers of the stack run, and the three named stacks.

use crate::lookahead::LookaheadConfig;
use serde::Serialize;
use wheelleg_runtime::guard::DEFAULT_MARGIN_M;
use wheelleg_sim::height_map::MapGrid;
use wheelleg_sim::local_plan::LastMetresConfig;

/// How the policy's five heads become one action.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum DecisionRule {
    /// The most probable joint action not yet taken at the same observation (deterministic;
    /// what the robot runs).
    #[default]
    Untried,
    /// Each head's most probable choice, even if that action was just refused.
    Argmax,
    /// A draw from each head's distribution (the training rule).
    Sample,
}

/// The collision guard's settings (`wheelleg_runtime::guard`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GuardLayer {
    /// Growth of every map column on each side (negative shrinks them).
    pub margin_m: f32,
    /// The map the guard reads: none, the policy's own 5 cm map; a layout, a map of it
    /// rendered from the scene at every step (a robot that keeps a finer elevation map than
    /// the policy's input, docs/results.md "A finer map for the guard").
    pub grid: Option<MapGrid>,
}

impl Default for GuardLayer {
    /// 5 mm per side on the 1 cm map: what the controller firmware runs.
    fn default() -> Self {
        GuardLayer {
            margin_m: DEFAULT_MARGIN_M,
            grid: Some(MapGrid::GUARD_FINE),
        }
    }
}

/// The layers that run between the policy's logits and the action sent.
#[derive(Clone, Copy, Debug)]
pub struct StackConfig {
    /// How actions are chosen from the logits.
    pub rule: DecisionRule,
    /// Check each action against a height map before taking it; none: unchecked.
    pub guard: Option<GuardLayer>,
    /// Take the policy's most probable action that reaches the target whenever one does
    /// (`wheelleg_runtime::arrival`, at the episode's success radius).
    pub arrival: bool,
    /// Weigh the rule's first candidates by rollouts of the policy on the robot's own map
    /// ([`crate::lookahead`]); none: the rule's own action.
    pub lookahead: Option<LookaheadConfig>,
    /// Search the robot's own map for the last metres when the policy lingers near the target
    /// (`wheelleg_sim::local_plan`); none: the policy alone there.
    pub last_metres: Option<LastMetresConfig>,
}

impl Default for StackConfig {
    /// The `robot` stack.
    fn default() -> Self {
        Preset::Robot.config()
    }
}

impl StackConfig {
    /// Whether the layers can run together: the guard, the arrival rule and the host's layers
    /// build on the untried rule's memory of what it took, which the other rules lack.
    pub fn check(&self) -> Result<(), String> {
        if self.rule == DecisionRule::Untried {
            return Ok(());
        }
        let layers = [
            ("the collision guard", self.guard.is_some()),
            ("the arrival rule", self.arrival),
            ("the look-ahead", self.lookahead.is_some()),
            ("the search for the last metres", self.last_metres.is_some()),
        ];
        match layers.iter().find(|(_, on)| *on) {
            Some((layer, _)) => Err(format!(
                "{layer} needs the untried decision rule, not {:?}",
                self.rule
            )),
            None => Ok(()),
        }
    }
}

/// The named stacks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Preset {
    /// The decision rule alone: the policy as trained, every action unchecked.
    Policy,
    /// What the controller firmware runs: the rule, the guard on the 1 cm map, arrival.
    Robot,
    /// `robot` plus what a companion computer adds: the look-ahead with its search for a
    /// shorter way, and the search for the last metres.
    Full,
}

impl Preset {
    /// Every preset, in order of the layers they add.
    pub const ALL: [Preset; 3] = [Preset::Policy, Preset::Robot, Preset::Full];

    /// The name users give it.
    pub fn name(self) -> &'static str {
        match self {
            Preset::Policy => "policy",
            Preset::Robot => "robot",
            Preset::Full => "full",
        }
    }

    /// The preset of that name.
    pub fn from_name(name: &str) -> Result<Preset, String> {
        Preset::ALL
            .into_iter()
            .find(|p| p.name() == name)
            .ok_or_else(|| format!("no stack named {name:?}: policy, robot or full"))
    }

    /// Its layers. `full`'s look-ahead: 8 candidates (8 where none arrives), 40-step
    /// rollouts, a search for a shorter way within 500 expansions; its last metres: searched
    /// within 1,000 expansions (docs/results.md, "Current figures").
    pub fn config(self) -> StackConfig {
        let policy = StackConfig {
            rule: DecisionRule::Untried,
            guard: None,
            arrival: false,
            lookahead: None,
            last_metres: None,
        };
        match self {
            Preset::Policy => policy,
            Preset::Robot => StackConfig {
                guard: Some(GuardLayer::default()),
                arrival: true,
                ..policy
            },
            Preset::Full => StackConfig {
                lookahead: Some(LookaheadConfig {
                    search_expansions: 500,
                    ..LookaheadConfig::default()
                }),
                last_metres: Some(LastMetresConfig::default()),
                ..Preset::Robot.config()
            },
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn each_preset_adds_layers_to_the_one_before() {
        let [policy, robot, full] = Preset::ALL.map(Preset::config);
        assert!(policy.guard.is_none() && !policy.arrival && policy.lookahead.is_none());
        assert_eq!(robot.guard, Some(GuardLayer::default()));
        assert_eq!(robot.guard.and_then(|g| g.grid), Some(MapGrid::GUARD_FINE));
        assert!(robot.arrival && robot.lookahead.is_none() && robot.last_metres.is_none());
        assert_eq!(full.guard, robot.guard);
        assert!(full.arrival);
        assert_eq!(full.lookahead.map(|l| l.search_expansions), Some(500));
        assert_eq!(
            full.last_metres.map(|l| l.planner.max_expansions),
            Some(1_000)
        );
        let default = StackConfig::default();
        assert_eq!(
            (default.guard, default.arrival),
            (robot.guard, robot.arrival)
        );
        assert!(default.lookahead.is_none() && default.last_metres.is_none());
        for preset in Preset::ALL {
            assert_eq!(Preset::from_name(preset.name()), Ok(preset));
            assert!(preset.config().check().is_ok());
        }
        assert!(Preset::from_name("fast")
            .unwrap_err()
            .contains("policy, robot or full"));
    }

    #[test]
    fn only_the_untried_rule_carries_the_layers() {
        let argmax = StackConfig {
            rule: DecisionRule::Argmax,
            ..Preset::Policy.config()
        };
        assert!(argmax.check().is_ok());
        let guarded = StackConfig {
            rule: DecisionRule::Sample,
            ..Preset::Robot.config()
        };
        assert!(guarded.check().unwrap_err().contains("collision guard"));
    }
}
