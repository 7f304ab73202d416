//! Replaying a stored trajectory: its observations, its errors, its undone actions.

use super::*;

#[test]
fn a_planned_trajectory_replays_to_success_with_its_observations() {
    let config = EnvConfig::default();
    for t in sources() {
        let replay = t.replay(config).unwrap();
        assert!(replay.success(), "{}: {:?}", t.scenario.name, replay.status);
        assert!(replay.collision_free());
        assert_eq!(replay.steps as usize, t.actions.len());
        assert_eq!(replay.path.len(), t.actions.len() + 1);
        let returns = replay.returns(1.0);
        assert!((returns[0] - replay.total_reward()).abs() < 1e-4);

        // The re-rendered samples are what a live episode shows.
        let steps = t.replay_observations(config).unwrap();
        assert_eq!(steps.len(), t.actions.len());
        let mut env = Env::new(&t.scenario, config).unwrap();
        let mut observation = Observation::default();
        for (i, step) in steps.iter().enumerate() {
            env.observe(&mut observation);
            assert_eq!(step.observation, observation, "step {i}");
            assert_eq!(step.action, t.actions[i]);
            let outcome = env.step(step.action).unwrap();
            assert_eq!(step.reward, outcome.reward.total());
            assert_eq!(step.reward, replay.rewards[i]);
            assert_eq!(step.done, i + 1 == steps.len());
        }
        assert_eq!(env.status(), Status::Success);
    }
}

#[test]
fn replay_reports_actions_past_the_end_and_bad_scenes() {
    let t = sources()[0].clone();
    let mut longer = t.clone();
    longer.actions.push(Action::IDLE);
    let e = longer.replay(EnvConfig::default()).unwrap_err();
    assert!(e.to_string().contains("before action"), "{e}");

    let mut bad = t.clone();
    bad.scenario.obstacles.push(Obstacle::new(
        ObstacleKind::Block,
        bad.scenario.start.position.x,
        bad.scenario.start.position.y,
        ObstacleYaw::Deg0,
    ));
    let e = bad.replay(EnvConfig::default()).unwrap_err();
    assert!(e.to_string().contains("inside an obstacle"), "{e}");
}

#[test]
fn undone_actions_are_dropped_and_the_path_stays() {
    let config = EnvConfig::default();
    let t = sources()[1].clone();
    let bumped = with_a_collision(&t);
    let replay = bumped.replay(config).unwrap();
    assert!(replay.success());
    assert_eq!(replay.collisions, 1);
    let pruned = bumped.without_undone_actions(config).unwrap();
    assert_eq!(pruned.actions, t.actions);
    let mut path = replay.path.clone();
    path.dedup();
    let mut pruned_path = pruned.replay(config).unwrap().path;
    pruned_path.dedup();
    assert_eq!(path, pruned_path);

    // Randomizing the bumped source stores the clean actions.
    let randomize = RandomizeConfig {
        per_trajectory: 5,
        ..RandomizeConfig::default()
    };
    let record = randomize_source(&bumped, 0, &randomize).unwrap();
    assert!(record.rejected.is_empty(), "{}", record.rejected);
    let stored: Vec<usize> = record.actions.iter().map(|&a| a as usize).collect();
    let clean: Vec<usize> = t.actions.iter().map(Action::index).collect();
    assert_eq!(stored, clean);
}
