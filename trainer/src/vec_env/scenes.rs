//! How the batch draws its scenes: the run's kind, mixed with composed and exit scenes.

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use wheelleg_sim::generate::{
    exit_scene, generate_staged, Behaviour, SceneKind, SceneRobot, StartYaw,
};
use wheelleg_sim::robot::SimulatedRobot;
use wheelleg_sim::scenario::Scenario;

/// How new scenes are drawn.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Scenes {
    /// The kind of scene.
    pub kind: SceneKind,
    /// How the start yaw is drawn.
    pub start_yaw: StartYaw,
    /// Start stage (`wheelleg_sim::generate::generate_staged`; 1 is the task as specified).
    pub stage: f32,
    /// Share of episodes on composed scenes instead of `kind` (`run.composed_share`).
    pub composed_share: f64,
    /// Share of episodes on exit scenes of `exit_behaviour`'s fence (`run.exit_share`).
    pub exit_share: f64,
    /// The fence of the exit scenes.
    pub exit_behaviour: Behaviour,
}

pub(super) fn new_scene(
    robot: &SimulatedRobot,
    scenes: Scenes,
    rng: &mut ChaCha8Rng,
    env: usize,
    episode: u64,
) -> Scenario {
    let robot = SceneRobot::of(robot);
    // Without exit or composed scenes nothing extra is drawn, so such a run sees exactly the
    // scenes it saw before the mixes existed.
    if scenes.exit_share > 0.0 && rng.random_bool(scenes.exit_share.min(1.0)) {
        let name = format!("{}-exit-e{env}-{episode}", scenes.exit_behaviour.name());
        return exit_scene(robot, scenes.exit_behaviour, scenes.start_yaw, rng, name);
    }
    // Of the episodes left, so many that `composed_share` of all are composed.
    let composed = if scenes.exit_share > 0.0 {
        scenes.composed_share / (1.0 - scenes.exit_share)
    } else {
        scenes.composed_share
    };
    let kind = if composed > 0.0 && rng.random_bool(composed.min(1.0)) {
        SceneKind::Composed
    } else {
        scenes.kind
    };
    // At stage 1 this is `generate_with_start`, draw for draw.
    generate_staged(
        robot,
        kind,
        scenes.start_yaw,
        scenes.stage,
        rng,
        format!("{}-e{env}-{episode}", kind.name()),
    )
}
