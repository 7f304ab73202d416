//! Leg kinematics: the symmetric (clearance, track) command to joint angles and back.
//!
//! Each leg has three joints, all rotating about axes parallel to the body x axis, so the leg lives
//! in its leg plane (see [`crate::robot`]): a point there is measured *outward* from the hip
//! (away from the body's centre line) and *down* from the hip.
//!
//! - hip: angle of the thigh below the outward horizontal;
//! - knee: angle of the shank relative to the thigh (0 = straight leg, positive bends the knee
//!   up and out, the sprawled posture that keeps the knees clear of anything under the body);
//! - wheel mount: turns the wheel back so its axle stays horizontal: `-(hip + knee)`.
//!
//! Two joints place the wheel mount, the third orients it, so a (clearance, track) pair maps to
//! one joint solution, or to none: such a pair is an *impossible action*. The wheel's centre sits
//! on the mount's axle, [`RobotGeometry::wheel_offset_m`] outward of the mount's joint: the axle
//! stays level, so the offset is a fixed outward shift in the leg plane.

use crate::robot::{LegId, RobotGeometry};
use nalgebra::Point3;

/// Slack on range checks so that values built from the discrete step lattice in `f32` (for
/// example `0.36 - 10 * 0.02`) are not refused for rounding noise.
const RANGE_EPS: f32 = 1e-5;

/// The command all four legs share: body clearance and wheel track.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LegConfig {
    /// Ground to body underside.
    pub clearance_m: f32,
    /// Wheel centre to wheel centre across the body.
    pub track_m: f32,
}

/// Joint angles of one leg (left-leg convention; right legs are mirrored, same numbers).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct JointAngles {
    /// Thigh angle below the outward horizontal.
    pub hip_rad: f32,
    /// Shank angle relative to the thigh, 0 = straight.
    pub knee_rad: f32,
    /// Wheel mount angle relative to the shank; keeps the axle horizontal.
    pub wheel_mount_rad: f32,
}

/// A point in a leg plane.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LegPlanePoint {
    /// Distance outward from the hip, away from the body's centre line.
    pub outward_m: f32,
    /// Distance below the hip.
    pub down_m: f32,
}

/// Positions of a leg's joints in its leg plane.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LegPlanePose {
    /// Knee joint.
    pub knee: LegPlanePoint,
    /// Wheel mount joint, where the shank ends.
    pub wheel_mount: LegPlanePoint,
    /// Wheel centre, on the mount's axle.
    pub wheel: LegPlanePoint,
}

/// Positions of one leg's joints in the body frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LegPoints {
    /// Hip joint.
    pub hip: Point3<f32>,
    /// Knee joint.
    pub knee: Point3<f32>,
    /// Wheel mount joint, where the shank ends.
    pub wheel_mount: Point3<f32>,
    /// Wheel centre, on the mount's axle.
    pub wheel: Point3<f32>,
}

/// Why a (clearance, track) pair has no leg solution.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum IkError {
    /// A value is NaN or infinite.
    NotFinite,
    /// Track outside the robot's track limits.
    TrackOutOfRange,
    /// Clearance outside the robot's clearance limits.
    ClearanceOutOfRange,
    /// The wheel mount would be farther from (or closer to) the hip than the leg can reach.
    OutOfReach,
    /// A solution exists but breaks a joint's range.
    JointLimit,
}

impl RobotGeometry {
    /// Where the wheel centre must be, in the leg plane, for a leg configuration.
    pub fn wheel_target(&self, config: LegConfig) -> LegPlanePoint {
        LegPlanePoint {
            outward_m: 0.5 * config.track_m - self.hip_y_m,
            down_m: self.body_centre_height_m(config.clearance_m) - self.wheel_radius_m,
        }
    }

    /// Inverse kinematics: joint angles that realise `config`, or why none do.
    pub fn leg_ik(&self, config: LegConfig) -> Result<JointAngles, IkError> {
        if !config.clearance_m.is_finite() || !config.track_m.is_finite() {
            return Err(IkError::NotFinite);
        }
        if !within(config.track_m, self.track_range_m) {
            return Err(IkError::TrackOutOfRange);
        }
        if !within(config.clearance_m, self.clearance_range_m) {
            return Err(IkError::ClearanceOutOfRange);
        }
        let wheel = self.wheel_target(config);
        // The chain of thigh and shank reaches the mount, inboard of the wheel's centre.
        let target = LegPlanePoint {
            outward_m: wheel.outward_m - self.wheel_offset_m,
            down_m: wheel.down_m,
        };
        let (l1, l2) = (self.thigh_m, self.shank_m);
        let r2 = target.outward_m * target.outward_m + target.down_m * target.down_m;
        // Law of cosines at the knee.
        let cos_knee = (r2 - l1 * l1 - l2 * l2) / (2.0 * l1 * l2);
        if !(-1.0 - RANGE_EPS..=1.0 + RANGE_EPS).contains(&cos_knee) {
            return Err(IkError::OutOfReach);
        }
        let knee_rad = crate::trig::acos(cos_knee.clamp(-1.0, 1.0));
        let hip_rad = libm::atan2f(target.down_m, target.outward_m)
            - libm::atan2f(
                l2 * crate::trig::sin(knee_rad),
                l1 + l2 * crate::trig::cos(knee_rad),
            );
        if !within(hip_rad, self.hip_range_rad) || !within(knee_rad, self.knee_range_rad) {
            return Err(IkError::JointLimit);
        }
        Ok(JointAngles {
            hip_rad,
            knee_rad,
            wheel_mount_rad: -(hip_rad + knee_rad),
        })
    }

    /// Whether the legs can realise `config`.
    pub fn is_reachable(&self, config: LegConfig) -> bool {
        self.leg_ik(config).is_ok()
    }

    /// Forward kinematics in the leg plane (the wheel mount turns the axle about the mount's
    /// joint; with the axle level, the wheel centre is the offset outward of it).
    pub fn leg_fk(&self, joints: JointAngles) -> LegPlanePose {
        let knee = LegPlanePoint {
            outward_m: self.thigh_m * crate::trig::cos(joints.hip_rad),
            down_m: self.thigh_m * crate::trig::sin(joints.hip_rad),
        };
        let shank_rad = joints.hip_rad + joints.knee_rad;
        let wheel_mount = LegPlanePoint {
            outward_m: knee.outward_m + self.shank_m * crate::trig::cos(shank_rad),
            down_m: knee.down_m + self.shank_m * crate::trig::sin(shank_rad),
        };
        let wheel = LegPlanePoint {
            outward_m: wheel_mount.outward_m + self.wheel_offset_m,
            down_m: wheel_mount.down_m,
        };
        LegPlanePose {
            knee,
            wheel_mount,
            wheel,
        }
    }

    /// The leg configuration that measured joint angles realise (forward kinematics).
    pub fn config_from_joints(&self, joints: JointAngles) -> LegConfig {
        let wheel = self.leg_fk(joints).wheel;
        LegConfig {
            track_m: 2.0 * (wheel.outward_m + self.hip_y_m),
            clearance_m: wheel.down_m + self.wheel_radius_m - 0.5 * self.body_thickness_m,
        }
    }

    /// Hip, knee, wheel mount and wheel centre of `leg` in the body frame.
    pub fn leg_points(&self, leg: LegId, joints: JointAngles) -> LegPoints {
        let pose = self.leg_fk(joints);
        let hip = self.hip_in_body(leg);
        let to_body = |p: LegPlanePoint| {
            Point3::new(
                hip.x,
                hip.y + leg.side_sign() * p.outward_m,
                hip.z - p.down_m,
            )
        };
        LegPoints {
            hip: Point3::from(hip),
            knee: to_body(pose.knee),
            wheel_mount: to_body(pose.wheel_mount),
            wheel: to_body(pose.wheel),
        }
    }
}

fn within(value: f32, range: [f32; 2]) -> bool {
    value >= range[0] - RANGE_EPS && value <= range[1] + RANGE_EPS
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::WHEELLEG;

    fn config(clearance_m: f32, track_m: f32) -> LegConfig {
        LegConfig {
            clearance_m,
            track_m,
        }
    }

    #[test]
    fn ik_then_fk_returns_the_commanded_configuration() {
        let g = WHEELLEG;
        let mut checked = 0;
        for t in 0..=20 {
            for c in 0..=10 {
                let want = config(0.04 + 0.02 * c as f32, 0.16 + 0.02 * t as f32);
                if let Ok(joints) = g.leg_ik(want) {
                    let got = g.config_from_joints(joints);
                    assert!(
                        (got.track_m - want.track_m).abs() < 1e-5,
                        "{want:?} -> {got:?}"
                    );
                    assert!((got.clearance_m - want.clearance_m).abs() < 1e-5);
                    // The wheel mount keeps the axle horizontal.
                    let axle = joints.hip_rad + joints.knee_rad + joints.wheel_mount_rad;
                    assert!(axle.abs() < 1e-6);
                    checked += 1;
                }
            }
        }
        assert!(checked > 100, "only {checked} reachable lattice points");
    }

    #[test]
    fn an_offset_wheel_keeps_the_track_between_wheel_centres() {
        // Wheels 3 cm outboard of their mounts: the commanded track is still centre to centre,
        // the chain reaches 3 cm less far out, and the wheel's centre is the mount's plus 3 cm.
        let g = RobotGeometry {
            wheel_offset_m: 0.03,
            ..WHEELLEG
        };
        assert_eq!(g.check(), Ok(()));
        let want = config(0.12, 0.36);
        let joints = g.leg_ik(want).unwrap();
        let got = g.config_from_joints(joints);
        assert!((got.track_m - want.track_m).abs() < 1e-5, "{got:?}");
        assert!((got.clearance_m - want.clearance_m).abs() < 1e-5, "{got:?}");
        let pose = g.leg_fk(joints);
        assert_eq!(pose.wheel.outward_m, pose.wheel_mount.outward_m + 0.03);
        assert_eq!(pose.wheel.down_m, pose.wheel_mount.down_m);
        // The chain is the shipped robot's at a track 6 cm narrower.
        let narrower = WHEELLEG.leg_ik(config(0.12, 0.30)).unwrap();
        assert!((joints.hip_rad - narrower.hip_rad).abs() < 1e-5);
        assert!((joints.knee_rad - narrower.knee_rad).abs() < 1e-5);
        let right = g.leg_points(LegId::FrontRight, joints);
        assert!((right.wheel.y - (-0.18)).abs() < 1e-5, "{right:?}");
        assert!((right.wheel_mount.y - (-0.15)).abs() < 1e-5, "{right:?}");
        // Beyond half the wheel's width and the link radius, the axle would stand clear.
        let too_far = RobotGeometry {
            wheel_offset_m: 0.033,
            ..WHEELLEG
        };
        assert_eq!(
            too_far.check(),
            Err(crate::robot::GeometryError::BadWheelOffset)
        );
    }

    #[test]
    fn required_poses_are_reachable() {
        let g = WHEELLEG;
        assert!(g.is_reachable(config(0.12, 0.36)), "default pose");
        assert!(g.is_reachable(config(0.06, 0.56)), "full track at 0.06 m");
        assert!(
            g.is_reachable(config(0.18, 0.36)),
            "default track at 0.18 m"
        );
    }

    #[test]
    fn unreachable_poses_are_refused_with_a_reason() {
        let g = WHEELLEG;
        assert_eq!(g.leg_ik(config(0.24, 0.56)), Err(IkError::OutOfReach));
        assert_eq!(g.leg_ik(config(0.12, 0.58)), Err(IkError::TrackOutOfRange));
        assert_eq!(
            g.leg_ik(config(0.02, 0.36)),
            Err(IkError::ClearanceOutOfRange)
        );
        assert_eq!(g.leg_ik(config(f32::NAN, 0.36)), Err(IkError::NotFinite));
    }

    #[test]
    fn right_legs_mirror_left_legs() {
        let g = WHEELLEG;
        let joints = g.leg_ik(config(0.12, 0.36)).unwrap();
        let left = g.leg_points(LegId::FrontLeft, joints);
        let right = g.leg_points(LegId::FrontRight, joints);
        assert!((left.wheel.y + right.wheel.y).abs() < 1e-6);
        assert!((left.wheel.y - 0.18).abs() < 1e-5);
        assert!(
            g.is_reachable(config(0.20, 0.36)),
            "highest default-track pose"
        );
        // Wheel axle one wheel radius above the ground.
        let ground_z = -g.body_centre_height_m(0.12);
        assert!((left.wheel.z - (ground_z + g.wheel_radius_m)).abs() < 1e-5);
        // Sprawled posture: the knee is outboard of the hip.
        assert!(left.knee.y > left.hip.y);
    }
}

#[cfg(test)]
mod reachable_set {
    use super::*;
    use crate::robot::WHEELLEG;

    /// Lowest and highest lattice clearance (0.04 + 0.02 k) the legs reach at `track_m`.
    fn clearance_span(track_m: f32) -> (f32, f32) {
        let reachable: [f32; 11] = core::array::from_fn(|k| 0.04 + 0.02 * k as f32);
        let mut span = (f32::INFINITY, f32::NEG_INFINITY);
        for clearance_m in reachable {
            if WHEELLEG.is_reachable(LegConfig {
                clearance_m,
                track_m,
            }) {
                span = (span.0.min(clearance_m), span.1.max(clearance_m));
            }
        }
        span
    }

    /// The figures docs/robot.md states about the reachable set.
    #[test]
    fn documented_clearance_spans_hold() {
        let close = |a: f32, b: f32| (a - b).abs() < 1e-4;
        let full = clearance_span(0.56);
        assert!(
            full.0 <= 0.06 + 1e-4 && close(full.1, 0.10),
            "full track {full:?}"
        );
        let default = clearance_span(0.36);
        assert!(close(default.1, 0.20), "default track {default:?}");
        let narrow = clearance_span(0.16);
        assert!(
            close(narrow.0, 0.10) && close(narrow.1, 0.24),
            "narrowest track {narrow:?}"
        );
    }
}
