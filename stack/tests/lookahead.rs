//! The look-ahead asks the robot's guard about a searched way's first step, and only about it:
//! shown with a policy whose every choice is known ([`Fixated`]: forward above all, then left).

use nalgebra::Point2;
use wheelleg_runtime::action::Action;
use wheelleg_runtime::decision::{Decider, ObservationKey};
use wheelleg_sim::env::{Env, EnvConfig, Observation};
use wheelleg_sim::planner::{plan, PlanOutcome, PlannerConfig};
use wheelleg_sim::scenario::Scenario;
use wheelleg_sim::state::RobotState;
use wheelleg_stack::lookahead::{steps_still_needed, Lookahead, LookaheadConfig, Weighed};
use wheelleg_stack::policy::{BatchPolicy, Fixated, LOG_PROBS};
use wheelleg_stack::rule::{candidates, RobotRule};

/// The first decision on `scenario`, weighed by a fresh look-ahead with the search on, the
/// guard answering `allowed`; returns what it chose, the rule's own action and the actions
/// the guard was asked about.
fn first_decision(scenario: &Scenario, allowed: bool) -> (Weighed, Action, Vec<(usize, Action)>) {
    let env = Env::new(scenario, EnvConfig::default()).unwrap();
    let mut obs = Observation::default();
    env.observe(&mut obs);
    let key = ObservationKey::of_metres(&obs.height_map, &obs.state);
    let log_probs = Fixated.log_probs(&obs.height_map, &obs.state, 1).unwrap();
    let logits: &[f32; LOG_PROBS] = log_probs.as_slice().try_into().unwrap();
    let decider = Decider::new();
    let mut lookahead = Lookahead::new(LookaheadConfig {
        candidates: 4,
        stuck_candidates: 4,
        search_expansions: 2_000,
        ..LookaheadConfig::default()
    });
    let rule = RobotRule::untried();
    let found = candidates(&decider, lookahead.candidates_wanted(), |d| {
        rule.choose(d, key, logits)
    });
    let own = found[0];
    lookahead.push(7, &env, &decider, key, found);
    let mut asked = Vec::new();
    let weighed = lookahead
        .weigh(
            &Fixated,
            false,
            EnvConfig::default().success_radius_m,
            &mut |slot, a| {
                asked.push((slot, a));
                allowed
            },
        )
        .unwrap();
    assert_eq!(weighed.len(), 1);
    (weighed[0], own, asked)
}

fn far_ahead() -> Scenario {
    Scenario {
        name: "far-ahead".into(),
        start: RobotState::new(
            Point2::new(0.0, 0.125),
            0,
            &wheelleg_runtime::action::ActionLattice::PAPER,
        ),
        target: Point2::new(0.9, 0.125),
        obstacles: vec![],
    }
}

#[test]
fn the_steps_a_rollout_still_needs_bound_the_shortest_way() {
    // A rollout is stopped once these steps cannot beat another's arrival: a bound that
    // overshot would stop one that could have won.
    for target in [
        Point2::new(0.9, 0.125),
        Point2::new(0.5, 0.625),
        Point2::new(0.1, 0.125),
    ] {
        let scenario = Scenario {
            target,
            ..far_ahead()
        };
        let env = Env::new(&scenario, EnvConfig::default()).unwrap();
        let PlanOutcome::Solved { actions, .. } = plan(&env, &PlannerConfig::default()).outcome
        else {
            panic!("open ground is solvable");
        };
        let needed = steps_still_needed(&env);
        assert!(
            needed >= 1 && needed as usize <= actions.len(),
            "{target}: {needed} vs {}",
            actions.len()
        );
    }
}

#[test]
fn a_searched_way_is_taken_only_where_the_guard_allows_its_first_step() {
    // Far ahead on open ground: every rollout drives straight, the search finds the shorter
    // way of diagonal steps.
    let far_ahead = far_ahead();
    let (searched, own, asked) = first_decision(&far_ahead, true);
    assert_eq!(searched.slot, 7);
    assert!(searched.overridden, "{searched:?}");
    assert_ne!(searched.action, own);
    // Asked about the searched way's first step alone, for the decision's own slot.
    assert_eq!(asked, vec![(7, searched.action)]);

    let (refused, own, asked) = first_decision(&far_ahead, false);
    assert_eq!(refused.action, own, "{refused:?}");
    assert!(!refused.overridden);
    assert!(refused.arrives);
    assert_eq!(asked, vec![(7, searched.action)]);
}
