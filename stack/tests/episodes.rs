//! Each layer of the stack does what it is there for, shown with a policy whose every choice
//! is known ([`Fixated`]: forward above all, then left).

use nalgebra::Point2;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use wheelleg_runtime::robot::{RobotGeometry, WHEELLEG};
use wheelleg_sim::env::{Env, EnvConfig, Status};
use wheelleg_sim::obstacle::{Obstacle, ObstacleKind, ObstacleYaw};
use wheelleg_sim::planner::{plan, PlanOutcome, PlannerConfig};
use wheelleg_sim::scenario::Scenario;
use wheelleg_sim::state::RobotState;
use wheelleg_stack::episodes::{run_episodes, FinishedEpisode};
use wheelleg_stack::lookahead::LookaheadConfig;
use wheelleg_stack::policy::Fixated;
use wheelleg_stack::{DecisionRule, Preset, StackConfig};

/// [`Fixated`] on `scenario` alone through `stack`.
fn fixated_on(scenario: &Scenario, stack: &StackConfig) -> Result<FinishedEpisode, String> {
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let mut episodes = run_episodes(
        &Fixated,
        std::slice::from_ref(scenario),
        stack,
        EnvConfig::default(),
        &mut rng,
        &mut |_| {},
    )?;
    episodes.pop().ok_or_else(|| "no episode".to_string())
}

fn policy_with(rule: DecisionRule) -> StackConfig {
    StackConfig {
        rule,
        ..Preset::Policy.config()
    }
}

fn start() -> RobotState {
    RobotState::new(
        Point2::new(0.0, 0.125),
        0,
        &wheelleg_runtime::action::ActionLattice::PAPER,
    )
}

#[test]
fn arrival_takes_the_one_step_the_policy_would_not() {
    // The target 6 cm to the robot's right: one step right arrives; the policy only ever
    // wants forward, then left.
    let scenario = Scenario {
        name: "target-beside".into(),
        start: start(),
        target: Point2::new(0.0, 0.065),
        obstacles: vec![],
    };
    let alone = fixated_on(&scenario, &Preset::Policy.config()).unwrap();
    assert_ne!(alone.env.status(), Status::Success);
    let arriving = StackConfig {
        arrival: true,
        ..Preset::Policy.config()
    };
    let arrived = fixated_on(&scenario, &arriving).unwrap();
    assert_eq!(arrived.env.status(), Status::Success);
    assert_eq!(arrived.env.steps(), 1);
    assert!(arrived.env.distance_to_target_m() <= 0.05);
    // The robot stack arrives the same way.
    let robot = fixated_on(&scenario, &Preset::Robot.config()).unwrap();
    assert_eq!(robot.env.status(), Status::Success);
    assert_eq!(robot.env.steps(), 1);
    // Not with a rule that does not remember what it took.
    let argmax = StackConfig {
        rule: DecisionRule::Argmax,
        ..arriving
    };
    assert!(fixated_on(&scenario, &argmax)
        .unwrap_err()
        .contains("untried"));
}

/// A block straight ahead of [`start`], the target beyond it.
fn block_ahead() -> Scenario {
    Scenario {
        name: "block-ahead".into(),
        start: start(),
        target: Point2::new(0.9, 0.125),
        obstacles: vec![Obstacle::new(
            ObstacleKind::Block,
            0.625,
            0.125,
            ObstacleYaw::Deg0,
        )],
    }
}

#[test]
fn the_default_rule_does_not_repeat_a_refused_action_and_argmax_does() {
    // A block straight ahead: "forward" is refused once the robot reaches it.
    let scenario = block_ahead();
    let run = |rule| fixated_on(&scenario, &policy_with(rule)).unwrap().env;
    let argmax = run(DecisionRule::Argmax);
    assert_eq!(argmax.status(), Status::StepLimit);
    assert!(
        argmax.collisions() > 80,
        "argmax pushes on: {}",
        argmax.collisions()
    );
    let untried = run(DecisionRule::Untried);
    // After each refusal it takes the next most probable action (forward and left, then
    // left), which slides it along the block's face until forward is free again; argmax
    // pushes into the block every step.
    assert!(untried.collisions() > 0, "it did meet the block");
    assert!(
        untried.collisions() * 4 < argmax.collisions(),
        "untried {}, argmax {}",
        untried.collisions(),
        argmax.collisions()
    );
    // The guard refuses the push before it is sent: no collision at all.
    let guarded = fixated_on(&scenario, &Preset::Robot.config()).unwrap().env;
    assert_eq!(guarded.collisions(), 0);
}

fn looking(candidates: usize, search_expansions: usize) -> StackConfig {
    StackConfig {
        lookahead: Some(LookaheadConfig {
            candidates,
            stuck_candidates: candidates,
            search_expansions,
            ..LookaheadConfig::default()
        }),
        ..Preset::Policy.config()
    }
}

#[test]
fn the_look_ahead_takes_a_later_choice_only_where_it_arrives_sooner() {
    // Ahead and to the left: the policy only ever drives forward and passes it by; its
    // second choice, forward and left, leads there diagonally.
    let ahead_left = Scenario {
        name: "ahead-left".into(),
        start: start(),
        target: Point2::new(0.5, 0.625),
        obstacles: vec![],
    };
    let alone = fixated_on(&ahead_left, &Preset::Policy.config()).unwrap();
    assert_ne!(alone.env.status(), Status::Success);
    assert_eq!(alone.lookahead.decisions, 0);
    let looked = fixated_on(&ahead_left, &looking(2, 0)).unwrap();
    assert_eq!(looked.env.status(), Status::Success, "{looked:?}");
    // 0.71 m at 0.0707 m a diagonal step, within the 0.05 m success radius.
    assert!(looked.env.steps() <= 10, "{looked:?}");
    assert!(looked.lookahead.overrides > 0, "{looked:?}");
    // Straight ahead the policy's own choice is already the shortest: never overridden.
    let ahead = Scenario {
        name: "ahead".into(),
        target: Point2::new(0.5, 0.125),
        ..ahead_left
    };
    let alone = fixated_on(&ahead, &Preset::Policy.config()).unwrap();
    let looked = fixated_on(&ahead, &looking(4, 0)).unwrap();
    assert_eq!(looked.env.status(), Status::Success);
    assert_eq!(looked.env.steps(), alone.env.steps());
    assert!(looked.lookahead.decisions > 0);
    assert_eq!(looked.lookahead.overrides, 0);
}

#[test]
fn the_search_finds_the_shortest_way_where_every_rollout_is_longer() {
    // Far ahead on open ground: the policy drives straight, one 5 cm step at a time; the
    // shortest way turns so that the longer diagonal steps carry it.
    let ahead = Scenario {
        name: "far-ahead".into(),
        start: start(),
        target: Point2::new(0.9, 0.125),
        obstacles: vec![],
    };
    let rollouts = fixated_on(&ahead, &looking(4, 0)).unwrap();
    let searched = fixated_on(&ahead, &looking(4, 2_000)).unwrap();
    assert_eq!(rollouts.env.status(), Status::Success, "{rollouts:?}");
    assert_eq!(searched.env.status(), Status::Success, "{searched:?}");
    let env = Env::new(&ahead, EnvConfig::default()).unwrap();
    let PlanOutcome::Solved { actions, .. } = plan(&env, &PlannerConfig::default()).outcome else {
        panic!("open ground is solvable");
    };
    let shortest = actions.len() as u32;
    assert!(rollouts.env.steps() > shortest, "{rollouts:?}");
    assert_eq!(searched.env.steps(), shortest, "{searched:?}");
    assert!(searched.lookahead.overrides > 0);
}

#[test]
fn the_guard_checks_the_robot_the_episodes_simulate() {
    // A robot whose body reaches 15 cm further forward than the shipped one's meets the block
    // ahead earlier: a guard that checked the shipped body would let it push in.
    let long = RobotGeometry {
        body_length_m: WHEELLEG.body_length_m + 0.3,
        ..WHEELLEG
    };
    let rules = EnvConfig {
        robot: wheelleg_sim::robot::SimulatedRobot::new(
            long,
            wheelleg_runtime::action::ActionLattice::PAPER,
        )
        .unwrap(),
        ..EnvConfig::default()
    };
    let scenario = block_ahead();
    let run = |stack: &StackConfig| {
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        run_episodes(
            &Fixated,
            std::slice::from_ref(&scenario),
            stack,
            rules,
            &mut rng,
            &mut |_| {},
        )
        .unwrap()
        .remove(0)
        .env
    };
    let unguarded = run(&Preset::Policy.config());
    assert!(unguarded.collisions() > 0, "the long body meets the block");
    let guarded = run(&Preset::Robot.config());
    assert_eq!(guarded.collisions(), 0);
}
