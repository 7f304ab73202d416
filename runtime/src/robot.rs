//! Dimensions of the robot: body, legs, wheels. All lengths in metres, angles in radians.
//!
//! Frames: the **body frame** has its origin at the body's geometric centre, x forward, y left,
//! z up. The **leg plane** of a leg is the body's y-z plane through that leg's hip: every joint of a
//! leg rotates about an axis parallel to the body x axis, so a leg moves only sideways and up/down.
//! That is what makes height and track one coupled pair: all four legs act symmetrically.

use crate::action::ActionLattice;
use crate::can::NodeMap;
use nalgebra::Vector3;

/// A robot as the runtime drives it: its shape, its action lattice and its CAN wiring.
///
/// Host tools read it from a robot description (`robots/NAME.toml`, crate `wheelleg-robot`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Robot {
    /// Body, legs, wheels and the pose ranges.
    pub geometry: RobotGeometry,
    /// How far one step of each action dimension moves.
    pub actions: ActionLattice,
    /// Node id and calibration of each of the 16 axes.
    pub can: NodeMap,
}

impl Robot {
    /// The robot this project ships (`robots/wheelleg.toml`).
    pub const WHEELLEG: Robot = Robot {
        geometry: WHEELLEG,
        actions: ActionLattice::PAPER,
        can: NodeMap::NOMINAL,
    };
}

/// Which of the four legs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum LegId {
    /// Front left.
    FrontLeft,
    /// Front right.
    FrontRight,
    /// Rear left.
    RearLeft,
    /// Rear right.
    RearRight,
}

impl LegId {
    /// All legs in node order (the order of CAN node ids and of every per-leg array).
    pub const ALL: [LegId; 4] = [
        LegId::FrontLeft,
        LegId::FrontRight,
        LegId::RearLeft,
        LegId::RearRight,
    ];

    /// Index of the leg in [`LegId::ALL`].
    pub const fn index(self) -> usize {
        match self {
            LegId::FrontLeft => 0,
            LegId::FrontRight => 1,
            LegId::RearLeft => 2,
            LegId::RearRight => 3,
        }
    }

    /// +1 for a front leg, -1 for a rear leg (sign of the hip's body x).
    pub const fn fore_sign(self) -> f32 {
        match self {
            LegId::FrontLeft | LegId::FrontRight => 1.0,
            LegId::RearLeft | LegId::RearRight => -1.0,
        }
    }

    /// +1 for a left leg, -1 for a right leg (sign of the hip's body y). Right legs are the
    /// mirror image of left legs.
    pub const fn side_sign(self) -> f32 {
        match self {
            LegId::FrontLeft | LegId::RearLeft => 1.0,
            LegId::FrontRight | LegId::RearRight => -1.0,
        }
    }
}

/// Everything about the robot's shape that kinematics and collision need.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RobotGeometry {
    /// Body length along body x.
    pub body_length_m: f32,
    /// Body width along body y.
    pub body_width_m: f32,
    /// Body thickness along body z.
    pub body_thickness_m: f32,
    /// Body x of the front hips (rear hips at minus this).
    pub hip_x_m: f32,
    /// Body y of the left hips (right hips at minus this): the hip actuators sit inside the body,
    /// inboard of its sides, so that the legs can fold under it to squeeze.
    pub hip_y_m: f32,
    /// Thigh length, hip joint to knee joint.
    pub thigh_m: f32,
    /// Shank length, knee joint to the wheel axle.
    pub shank_m: f32,
    /// Radius of the leg links as collision capsules.
    pub link_radius_m: f32,
    /// Wheel radius.
    pub wheel_radius_m: f32,
    /// Wheel width (along its axle, body y).
    pub wheel_width_m: f32,
    /// Where the wheel's centre sits along its axle from the wheel mount's joint, outward (away
    /// from the body's centre line; negative: inward). At most half the wheel's width plus the
    /// link radius either way, so that the axle between the two lies within the shank's end and
    /// the wheel, the collision parts ([`RobotGeometry::check`]).
    pub wheel_offset_m: f32,
    /// Hip joint range `[min, max]`: thigh angle below the outward horizontal.
    pub hip_range_rad: [f32; 2],
    /// Knee joint range `[min, max]`: shank angle relative to the thigh, 0 = straight leg.
    pub knee_range_rad: [f32; 2],
    /// Track (wheel centre to wheel centre across the body) limits `[min, max]`.
    pub track_range_m: [f32; 2],
    /// Clearance (ground to body underside) limits `[min, max]`.
    pub clearance_range_m: [f32; 2],
    /// Track of the default pose.
    pub default_track_m: f32,
    /// Clearance of the default pose.
    pub default_clearance_m: f32,
}

/// The robot this project is built for (docs/robot.md explains every number).
pub const WHEELLEG: RobotGeometry = RobotGeometry {
    body_length_m: 0.50,
    body_width_m: 0.16,
    body_thickness_m: 0.08,
    hip_x_m: 0.20,
    hip_y_m: 0.06,
    thigh_m: 0.08,
    shank_m: 0.16,
    link_radius_m: 0.012,
    wheel_radius_m: 0.05,
    wheel_width_m: 0.04,
    wheel_offset_m: 0.0,
    hip_range_rad: [-1.2, 1.5],
    knee_range_rad: [0.0, 2.8],
    track_range_m: [0.16, 0.56],
    clearance_range_m: [0.04, 0.24],
    default_track_m: 0.36,
    default_clearance_m: 0.12,
};

/// Number of fields of [`RobotGeometry`] a version 3 robot record stores
/// ([`RobotGeometry::to_array`]): all but the wheel offset, which version 4 adds.
pub const GEOMETRY_FIELDS: usize = 20;

/// Why a geometry cannot be driven (a robot record's check; host tools name the description's
/// key instead).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GeometryError {
    /// A length that is not finite and positive, or a hip y below 0.
    BadLength,
    /// A range that is not finite or not ordered.
    BadRange,
    /// The default pose has no leg solution.
    DefaultUnreachable,
    /// A wheel offset that is not finite or beyond [`RobotGeometry::max_wheel_offset_m`].
    BadWheelOffset,
}

impl RobotGeometry {
    /// The fields in declaration order but the wheel offset, as a weights file's robot record
    /// stores them.
    pub fn to_array(&self) -> [f32; GEOMETRY_FIELDS] {
        [
            self.body_length_m,
            self.body_width_m,
            self.body_thickness_m,
            self.hip_x_m,
            self.hip_y_m,
            self.thigh_m,
            self.shank_m,
            self.link_radius_m,
            self.wheel_radius_m,
            self.wheel_width_m,
            self.hip_range_rad[0],
            self.hip_range_rad[1],
            self.knee_range_rad[0],
            self.knee_range_rad[1],
            self.track_range_m[0],
            self.track_range_m[1],
            self.clearance_range_m[0],
            self.clearance_range_m[1],
            self.default_track_m,
            self.default_clearance_m,
        ]
    }

    /// The geometry of [`RobotGeometry::to_array`]'s order with the wheel offset, unchecked
    /// ([`RobotGeometry::check`]).
    pub fn from_array(a: [f32; GEOMETRY_FIELDS], wheel_offset_m: f32) -> RobotGeometry {
        let [body_length_m, body_width_m, body_thickness_m, hip_x_m, hip_y_m, thigh_m, shank_m, link_radius_m, wheel_radius_m, wheel_width_m, hip_min, hip_max, knee_min, knee_max, track_min, track_max, clearance_min, clearance_max, default_track_m, default_clearance_m] =
            a;
        RobotGeometry {
            body_length_m,
            body_width_m,
            body_thickness_m,
            hip_x_m,
            hip_y_m,
            thigh_m,
            shank_m,
            link_radius_m,
            wheel_radius_m,
            wheel_width_m,
            wheel_offset_m,
            hip_range_rad: [hip_min, hip_max],
            knee_range_rad: [knee_min, knee_max],
            track_range_m: [track_min, track_max],
            clearance_range_m: [clearance_min, clearance_max],
            default_track_m,
            default_clearance_m,
        }
    }

    /// Whether the runtime can drive this geometry: finite positive lengths, ordered finite
    /// ranges, a default pose with a leg solution. (A robot description is checked more
    /// closely on the host, each rule naming its key.)
    pub fn check(&self) -> Result<(), GeometryError> {
        let positive = [
            self.body_length_m,
            self.body_width_m,
            self.body_thickness_m,
            self.hip_x_m,
            self.thigh_m,
            self.shank_m,
            self.link_radius_m,
            self.wheel_radius_m,
            self.wheel_width_m,
        ];
        let lengths_ok = positive.iter().all(|v| v.is_finite() && *v > 0.0);
        if !(lengths_ok && self.hip_y_m.is_finite() && self.hip_y_m >= 0.0) {
            return Err(GeometryError::BadLength);
        }
        if !self.wheel_offset_m.is_finite() || self.wheel_offset_m.abs() > self.max_wheel_offset_m()
        {
            return Err(GeometryError::BadWheelOffset);
        }
        let ranges = [
            self.hip_range_rad,
            self.knee_range_rad,
            self.track_range_m,
            self.clearance_range_m,
        ];
        if !ranges
            .iter()
            .all(|r| r[0].is_finite() && r[1].is_finite() && r[0] < r[1])
        {
            return Err(GeometryError::BadRange);
        }
        let default = crate::leg::LegConfig {
            clearance_m: self.default_clearance_m,
            track_m: self.default_track_m,
        };
        if self.leg_ik(default).is_err() {
            return Err(GeometryError::DefaultUnreachable);
        }
        Ok(())
    }

    /// The largest wheel offset either way along the axle: half the wheel's width plus the link
    /// radius, where the axle between mount and wheel still lies within the shank's capsule end
    /// and the wheel's cylinder.
    pub fn max_wheel_offset_m(&self) -> f32 {
        0.5 * self.wheel_width_m + self.link_radius_m
    }

    /// Height of the body centre above the ground at a given clearance.
    pub fn body_centre_height_m(&self, clearance_m: f32) -> f32 {
        clearance_m + 0.5 * self.body_thickness_m
    }

    /// Hip joint position of a leg in the body frame.
    pub fn hip_in_body(&self, leg: LegId) -> Vector3<f32> {
        Vector3::new(
            leg.fore_sign() * self.hip_x_m,
            leg.side_sign() * self.hip_y_m,
            0.0,
        )
    }
}
