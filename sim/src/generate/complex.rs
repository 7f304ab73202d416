//! Complex scenes: one to eight obstacles of any kind and yaw on the way to the target.

use super::{cell_index, layout, SceneRobot, StartYaw};
use crate::obstacle::{cell_centre_m, Obstacle, ObstacleKind, ObstacleYaw};
use crate::scenario::Scenario;
use rand::Rng;

pub(super) fn complex_scene(
    robot: &SceneRobot,
    rng: &mut impl Rng,
    name: String,
    start_yaw: StartYaw,
) -> Scenario {
    let lay = layout(robot, rng, 0.5, start_yaw);
    let count = rng.random_range(1..=8);
    let (x0, x1) = (
        cell_index(lay.start.position.x - 0.5),
        cell_index(lay.target.x + 0.5),
    );
    let y_mid = cell_index(lay.start.position.y);
    let mut obstacles = Vec::with_capacity(count);
    let start_obstacles_free = |obstacles: &[Obstacle]| {
        Scenario {
            name: String::new(),
            start: lay.start,
            target: lay.target,
            obstacles: obstacles.to_vec(),
        }
        .validate(robot.robot())
        .is_ok()
    };
    let mut attempts = 0;
    while obstacles.len() < count && attempts < 100 {
        attempts += 1;
        let candidate = random_obstacle(rng, x0..=x1, y_mid - 3..=y_mid + 3);
        if obstacles
            .iter()
            .any(|o: &Obstacle| o.centre == candidate.centre)
        {
            continue;
        }
        obstacles.push(candidate);
        if !start_obstacles_free(&obstacles) {
            obstacles.pop();
        }
    }
    Scenario {
        name,
        start: lay.start,
        target: lay.target,
        obstacles,
    }
}

/// An obstacle of random kind and yaw on a random cell of `cells_x` x `cells_y` (cell indices).
pub(super) fn random_obstacle(
    rng: &mut impl Rng,
    cells_x: std::ops::RangeInclusive<i32>,
    cells_y: std::ops::RangeInclusive<i32>,
) -> Obstacle {
    let kind = ObstacleKind::ALL[rng.random_range(0..ObstacleKind::ALL.len())];
    let yaw = if rng.random_bool(0.5) {
        ObstacleYaw::Deg0
    } else {
        ObstacleYaw::Deg90
    };
    let cell = (rng.random_range(cells_x), rng.random_range(cells_y));
    Obstacle::new(kind, cell_centre_m(cell.0), cell_centre_m(cell.1), yaw)
}
