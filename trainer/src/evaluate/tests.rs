use super::*;
use nalgebra::Point2;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use wheelleg_sim::obstacle::{Obstacle, ObstacleKind, ObstacleYaw};
use wheelleg_sim::state::RobotState;
use wheelleg_stack::lookahead::LookaheadConfig;
use wheelleg_stack::policy::Fixated;
use wheelleg_stack::Preset;

/// [`Fixated`] on `scenario` alone through `stack`, without the planner. What each layer
/// does is tested with the stack (`stack/tests/episodes.rs`); here, what the report says.
fn fixated_on(scenario: &Scenario, stack: StackConfig) -> Result<EvalReport, TrainError> {
    let options = EvalOptions {
        stack,
        planner_expansions: 0,
        ..EvalOptions::default()
    };
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    evaluate(&Fixated, std::slice::from_ref(scenario), &options, &mut rng)
}

#[test]
fn the_report_names_the_layers_and_splits_by_what_stands_beside_the_target() {
    // The target 6 cm to the robot's right: one step right arrives; the policy only ever
    // wants forward, then left.
    let scenario = Scenario {
        name: "target-beside".into(),
        start: RobotState::new(
            Point2::new(0.0, 0.125),
            0,
            &wheelleg_runtime::action::ActionLattice::PAPER,
        ),
        target: Point2::new(0.0, 0.065),
        obstacles: vec![],
    };
    let alone = fixated_on(&scenario, Preset::Policy.config()).unwrap();
    assert!(!alone.arrival && alone.guard_margin_m.is_none() && alone.lookahead.is_none());
    assert_ne!(alone.scenarios[0].status, "Success");
    let robot = fixated_on(&scenario, Preset::Robot.config()).unwrap();
    assert!(robot.arrival);
    assert_eq!(robot.guard_cell_m, Some(0.01));
    assert_eq!(robot.scenarios[0].status, "Success");
    assert_eq!(robot.scenarios[0].steps, 1);
    assert!(robot.scenarios[0].final_distance_m <= 0.05);
    assert_eq!(
        robot.by_target_beside,
        [TargetBeside {
            beside: "nothing".into(),
            scenarios: 1,
            successes: 1,
            collision_free: 1,
        }]
    );
    // A block 0.175 m short of the target.
    let block = Scenario {
        name: "block-ahead".into(),
        target: Point2::new(0.9, 0.125),
        obstacles: vec![Obstacle::new(
            ObstacleKind::Block,
            0.625,
            0.125,
            ObstacleYaw::Deg0,
        )],
        ..scenario
    };
    let argmax = StackConfig {
        rule: DecisionRule::Argmax,
        ..Preset::Policy.config()
    };
    let report = fixated_on(&block, argmax).unwrap();
    assert_eq!(report.decision, DecisionRule::Argmax);
    assert_eq!(report.scenarios[0].status, "StepLimit");
    assert_eq!(report.scenarios[0].target_beside.as_deref(), Some("block"));
    // The look-ahead's counts add up over the episodes.
    let ahead_left = Scenario {
        name: "ahead-left".into(),
        target: Point2::new(0.5, 0.625),
        obstacles: vec![],
        ..block
    };
    let looking = StackConfig {
        lookahead: Some(LookaheadConfig {
            candidates: 2,
            stuck_candidates: 2,
            ..LookaheadConfig::default()
        }),
        ..Preset::Policy.config()
    };
    let looked = fixated_on(&ahead_left, looking).unwrap();
    let report = looked.lookahead.unwrap();
    assert_eq!(report.candidates, 2);
    assert!(report.overrides > 0);
    assert_eq!(
        report.overrides,
        u64::from(looked.scenarios[0].lookahead.overrides)
    );
}
