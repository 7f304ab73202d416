//! The paper's relevance test ("Attend task-relevant components of the observation"): roll the
//! greedy policy in a scene, then again with each obstacle removed in turn; an obstacle whose
//! removal moves the trajectory far is one the policy attends to.
//!
//! The distance between two trajectories is the symmetric mean closest-point distance between
//! their paths of body centres (polylines): the mean, over the points of each path, of the
//! distance to the other path, averaged over both directions. It is 0 for the same path, does
//! not depend on how many steps either took to trace the same curve, and grows with how far
//! apart the paths run.

use crate::network_f32::NetworkF32;
use nalgebra::{Point2, Vector2};
use wheelleg_runtime::action::{Action, CHOICES, DIMS};
use wheelleg_runtime::decision::{Decider, ObservationKey};
use wheelleg_sim::env::{Env, EnvConfig, Observation, Status};
use wheelleg_sim::scenario::{Scenario, ScenarioError};
use wheelleg_sim::state::RobotState;

mod figure;

pub use figure::render;

/// One episode of a policy.
#[derive(Clone, Debug, PartialEq)]
pub struct PolicyRun {
    /// States from the start to the end, one per step.
    pub path: Vec<RobotState>,
    /// How it ended.
    pub status: Status,
    /// Collisions (undone actions).
    pub collisions: u32,
}

impl PolicyRun {
    /// The body centres along the path.
    pub fn centres(&self) -> Vec<Point2<f32>> {
        self.path.iter().map(|s| s.position).collect()
    }
}

/// The relevance of one obstacle.
#[derive(Clone, Debug, PartialEq)]
pub struct ObstacleRelevance {
    /// Index of the removed obstacle in the scenario.
    pub index: usize,
    /// Distance between the trajectory without it and the one with all obstacles, m.
    pub relevance_m: f32,
    /// The episode without it.
    pub run: PolicyRun,
}

/// The relevance of every obstacle of a scene.
#[derive(Clone, Debug, PartialEq)]
pub struct RelevanceReport {
    /// The episode with every obstacle.
    pub baseline: PolicyRun,
    /// Per obstacle, in scenario order.
    pub obstacles: Vec<ObstacleRelevance>,
}

/// A float policy acting by the robot's rule (`wheelleg_runtime::decision::Decider`): the most
/// probable joint action not yet taken at the current observation.
pub struct DecidingPolicy<'a> {
    network: &'a NetworkF32,
    decider: Decider,
}

impl<'a> DecidingPolicy<'a> {
    /// `network` with nothing taken yet.
    pub fn new(network: &'a NetworkF32) -> DecidingPolicy<'a> {
        DecidingPolicy {
            network,
            decider: Decider::new(),
        }
    }

    /// The action for `observation`.
    pub fn act(&mut self, observation: &Observation) -> Action {
        let (logits, _) = self
            .network
            .forward(&observation.height_map, &observation.state);
        let mut head_logits = [0.0f32; DIMS * CHOICES];
        for (out, &l) in head_logits.iter_mut().zip(&logits) {
            *out = l;
        }
        let key = ObservationKey::of_metres(&observation.height_map, &observation.state);
        self.decider.choose(key, &head_logits)
    }
}

/// Runs `policy` in `scenario` until the episode ends.
pub fn roll(
    scenario: &Scenario,
    config: EnvConfig,
    policy: &mut dyn FnMut(&Observation) -> Action,
) -> Result<PolicyRun, ScenarioError> {
    let mut env = Env::new(scenario, config)?;
    let mut observation = Observation::default();
    let mut path = vec![*env.state()];
    while !env.status().is_done() {
        env.observe(&mut observation);
        let action = policy(&observation);
        if env.step(action).is_err() {
            break;
        }
        path.push(*env.state());
    }
    Ok(PolicyRun {
        path,
        status: env.status(),
        collisions: env.collisions(),
    })
}

/// Distance from `p` to the segment `a`-`b`.
fn point_segment_m(p: Point2<f32>, a: Point2<f32>, b: Point2<f32>) -> f32 {
    let ab: Vector2<f32> = b - a;
    let len2 = ab.norm_squared();
    let t = if len2 > 0.0 {
        ((p - a).dot(&ab) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p - (a + t * ab)).norm()
}

/// Mean over the points of `a` of the distance to the polyline `b`.
fn directed_mean_m(a: &[Point2<f32>], b: &[Point2<f32>]) -> f32 {
    if a.is_empty() || b.is_empty() {
        return 0.0;
    }
    let nearest = |p: Point2<f32>| {
        if b.len() == 1 {
            return (p - b[0]).norm();
        }
        b.windows(2)
            .map(|w| point_segment_m(p, w[0], w[1]))
            .fold(f32::INFINITY, f32::min)
    };
    a.iter().map(|&p| nearest(p)).sum::<f32>() / a.len() as f32
}

/// The symmetric mean closest-point distance between two paths (see the module comment), m.
pub fn trajectory_distance_m(a: &[Point2<f32>], b: &[Point2<f32>]) -> f32 {
    0.5 * (directed_mean_m(a, b) + directed_mean_m(b, a))
}

/// Rolls `policy` with all obstacles and with each removed in turn.
pub fn relevance(
    scenario: &Scenario,
    config: EnvConfig,
    policy: &mut dyn FnMut(&Observation) -> Action,
) -> Result<RelevanceReport, ScenarioError> {
    let baseline = roll(scenario, config, policy)?;
    let centres = baseline.centres();
    let mut obstacles = Vec::with_capacity(scenario.obstacles.len());
    for index in 0..scenario.obstacles.len() {
        let mut without = scenario.clone();
        without.obstacles.remove(index);
        let run = roll(&without, config, policy)?;
        obstacles.push(ObstacleRelevance {
            index,
            relevance_m: trajectory_distance_m(&centres, &run.centres()),
            run,
        });
    }
    Ok(RelevanceReport {
        baseline,
        obstacles,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distance_is_zero_for_the_same_path_and_grows_with_offset() {
        let a: Vec<Point2<f32>> = (0..10).map(|i| Point2::new(0.05 * i as f32, 0.0)).collect();
        assert_eq!(trajectory_distance_m(&a, &a), 0.0);
        // The same line traced with other steps is the same path.
        let b: Vec<Point2<f32>> = (0..5)
            .map(|i| Point2::new(0.1125 * i as f32, 0.0))
            .collect();
        assert!(trajectory_distance_m(&a, &b) < 1e-6);
        let c: Vec<Point2<f32>> = a.iter().map(|p| p + Vector2::new(0.0, 0.2)).collect();
        assert!((trajectory_distance_m(&a, &c) - 0.2).abs() < 1e-5);
    }
}
