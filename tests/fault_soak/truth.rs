//! Where the robot really is against where the plan has it: its true pose, the planned
//! step's path, and when it came to rest.

use nalgebra::{Isometry2, Point2, Vector2};
use wheelleg_firmware_sim::rig::{Rig, TrueSample};
use wheelleg_runtime::can::node_map::{Axis, AxisKind};
use wheelleg_runtime::leg::LegConfig;
use wheelleg_runtime::robot::WHEELLEG;
use wheelleg_sim::collision::{ObstacleSet, RobotParts};
use wheelleg_sim::state::RobotState;

/// Where the robot really is: the scene's start pose moved by the rig's ground-truth odometry,
/// with the legs the joints really hold.
pub(crate) fn true_pose_collides(
    sample: &TrueSample,
    start: Isometry2<f32>,
    obstacles: &ObstacleSet,
) -> bool {
    let pose = start * sample.pose;
    let legs = sample.legs;
    // FK of real joint positions can leave the command limits by motor noise; the body is
    // where it is, so clamp only for the IK inside RobotParts.
    let [c0, c1] = WHEELLEG.clearance_range_m;
    let [t0, t1] = WHEELLEG.track_range_m;
    let legs = LegConfig {
        clearance_m: legs.clearance_m.clamp(c0, c1),
        track_m: legs.track_m.clamp(t0, t1),
    };
    let position = Point2::new(pose.translation.x, pose.translation.y);
    let parts = RobotParts::new(&WHEELLEG, position, pose.rotation.angle(), legs).unwrap();
    obstacles.collides(&parts)
}

/// One pose of the straight path from `from` to `to` at fraction `t`, as `Env::check_swept`
/// and the controller's step motion see it.
pub(crate) fn path_pose(from: &RobotState, to: &RobotState, t: f32) -> (Isometry2<f32>, LegConfig) {
    let yaw = from.yaw_rad() + t * from.yaw_turn_rad_to(to);
    let p = from.position + t * (to.position - from.position);
    let (l0, l1) = (from.leg_config(&WHEELLEG), to.leg_config(&WHEELLEG));
    let legs = LegConfig {
        clearance_m: l0.clearance_m + t * (l1.clearance_m - l0.clearance_m),
        track_m: l0.track_m + t * (l1.track_m - l0.track_m),
    };
    (Isometry2::new(Vector2::new(p.x, p.y), yaw), legs)
}

/// How far the true pose is from the nearest pose of the path (position, heading, legs at
/// the nearest position).
pub(crate) fn off_path(
    from: &RobotState,
    to: &RobotState,
    truth: Isometry2<f32>,
    legs: LegConfig,
) -> (f32, f32, f32) {
    (0..=100)
        .map(|i| {
            let (pose, path_legs) = path_pose(from, to, i as f32 / 100.0);
            let d = pose.inverse() * truth;
            (
                d.translation.vector.norm(),
                d.rotation.angle().abs(),
                (legs.clearance_m - path_legs.clearance_m)
                    .abs()
                    .max((legs.track_m - path_legs.track_m).abs()),
            )
        })
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .unwrap()
}

/// How long after `stop_us` the true pose last moved (more than 10 µm or 10 µrad, or the legs
/// more than 10 µm, between two control ticks).
pub(crate) fn rest_time_us(log: &[TrueSample], stop_us: u64) -> u64 {
    log.windows(2)
        .filter(|w| w[1].at_us > stop_us)
        .filter(|w| {
            let d = w[0].pose.inverse() * w[1].pose;
            d.translation.vector.norm() > 1e-5
                || d.rotation.angle().abs() > 1e-5
                || (w[0].legs.clearance_m - w[1].legs.clearance_m).abs() > 1e-5
                || (w[0].legs.track_m - w[1].legs.track_m).abs() > 1e-5
        })
        .map(|w| w[1].at_us - stop_us)
        .max()
        .unwrap_or(0)
}

pub(crate) fn joint_positions(rig: &Rig) -> Vec<f32> {
    Axis::ALL
        .into_iter()
        .filter(|a| a.kind() == AxisKind::Joint)
        .map(|a| rig.firmware().axis(a).unwrap().pos_turns())
        .collect()
}
