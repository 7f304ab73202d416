//! Relevance: which obstacle changes the policy's way.

use super::*;

/// Drives at the target, never around anything: enough to see what an obstacle changes.
fn toward_target(observation: &Observation) -> Action {
    let (x, y) = (observation.state[2], observation.state[3]);
    let step = |v: f32| {
        if v > 0.025 {
            Step::Plus
        } else if v < -0.025 {
            Step::Minus
        } else {
            Step::Zero
        }
    };
    Action {
        move_x: step(x),
        move_y: step(y),
        ..Action::IDLE
    }
}

#[test]
fn relevance_finds_the_obstacle_in_the_way() {
    let scenario = Scenario {
        name: "relevance".into(),
        start: RobotState::new(
            Point2::new(0.025, 0.125),
            0,
            &wheelleg_runtime::action::ActionLattice::PAPER,
        ),
        target: Point2::new(1.025, 0.125),
        obstacles: vec![
            // Far to the side: irrelevant.
            Obstacle::new(ObstacleKind::Block, 0.375, -0.625, ObstacleYaw::Deg0),
            // On the straight line: the policy above gets stuck on it.
            Obstacle::new(ObstacleKind::Block, 0.625, 0.125, ObstacleYaw::Deg0),
        ],
    };
    let config = EnvConfig::default();
    let report = relevance(&scenario, config, &mut toward_target).unwrap();
    assert_ne!(report.baseline.status, Status::Success);
    assert_eq!(report.obstacles.len(), 2);
    assert_eq!(report.obstacles[0].relevance_m, 0.0);
    assert!(
        report.obstacles[1].relevance_m > 0.05,
        "{}",
        report.obstacles[1].relevance_m
    );
    assert_eq!(report.obstacles[1].run.status, Status::Success);
    let same = trajectory_distance_m(&report.baseline.centres(), &report.baseline.centres());
    assert_eq!(same, 0.0);

    let canvas = render(
        &scenario,
        &report,
        &wheelleg_runtime::robot::WHEELLEG,
        &config,
    )
    .unwrap();
    let red = (0..canvas.height())
        .flat_map(|y| (0..canvas.width()).map(move |x| (x, y)))
        .filter(|&(x, y)| canvas.pixel(x, y) == Some([255, 0, 0]))
        .count();
    assert!(
        red > 500,
        "the relevant block is drawn fully red ({red} px)"
    );
}

#[test]
fn behaviours_keep_their_file_codes() {
    // A behaviour's index in Behaviour::ALL, as in every batch file written so far; 5 and 6
    // (retired experiments) read as no behaviour, and a batch holding them is refused.
    for (code, b) in Behaviour::ALL.iter().enumerate() {
        assert_eq!(behaviour_code(*b) as usize, code);
        assert_eq!(behaviour_of_code(code as u8), Some(*b));
    }
    for retired in [5, 6, 7] {
        assert_eq!(behaviour_of_code(retired), None);
    }
}
