//! Mecanum base kinematics: body velocity to wheel speeds and back (odometry).
//!
//! The four wheels sit at the legs' feet: at body x = ±`hip_x_m` (so the wheelbase is
//! `2 * hip_x_m`) and body y = ±`track_m / 2`, where the track is whatever the legs currently
//! hold. Each wheel carries 45° rollers in the usual "X" arrangement (seen from above, the
//! rollers touching the ground form an X), which makes the base holonomic.
//!
//! Sign conventions: body velocity is expressed in the body frame (x forward, y left, yaw
//! counter-clockwise positive, see [`crate::robot`]); a wheel's angular speed is positive when
//! the wheel rolls the robot forward, whichever side of the body it is on. Mapping that to a
//! motor's own direction is the CAN node map's job ([`crate::can::node_map`]).
//!
//! With `r` the wheel radius and `k = hip_x + track / 2` (the lever arm of a roller force about the
//! body centre for 45° rollers), the inverse map is
//!
//! ```text
//! ω_FL = (vx - vy - k·ωz) / r      ω_FR = (vx + vy + k·ωz) / r
//! ω_RL = (vx + vy - k·ωz) / r      ω_RR = (vx - vy + k·ωz) / r
//! ```
//!
//! and the forward map (odometry) is its least-squares inverse: four wheels, three body
//! velocities, so a slipping wheel shows up as a residual instead of corrupting the estimate
//! alone.

use crate::leg::LegConfig;
use crate::robot::{LegId, RobotGeometry};
use nalgebra::{Isometry2, Vector2};

/// Velocity of the body in its own frame.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct BaseVelocity {
    /// Forward speed (body x).
    pub vx_mps: f32,
    /// Leftward speed (body y).
    pub vy_mps: f32,
    /// Counter-clockwise yaw rate.
    pub yaw_rate_radps: f32,
}

impl BaseVelocity {
    /// Standing still.
    pub const ZERO: BaseVelocity = BaseVelocity {
        vx_mps: 0.0,
        vy_mps: 0.0,
        yaw_rate_radps: 0.0,
    };

    /// Whether all three components are finite.
    pub fn is_finite(&self) -> bool {
        self.vx_mps.is_finite() && self.vy_mps.is_finite() && self.yaw_rate_radps.is_finite()
    }
}

/// Angular speeds of the four wheels in [`LegId::ALL`] order; positive rolls the robot forward.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct WheelSpeeds {
    /// One entry per wheel, indexed by [`LegId::index`].
    pub radps: [f32; 4],
}

impl WheelSpeeds {
    /// All wheels stopped.
    pub const ZERO: WheelSpeeds = WheelSpeeds { radps: [0.0; 4] };

    /// Speed of one leg's wheel.
    pub fn get(&self, leg: LegId) -> f32 {
        self.radps.get(leg.index()).copied().unwrap_or(0.0)
    }

    /// Largest absolute wheel speed.
    pub fn max_abs_radps(&self) -> f32 {
        self.radps.iter().fold(0.0, |m, w| m.max(w.abs()))
    }
}

/// Why a base command cannot be executed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BaseError {
    /// A velocity, speed or track is NaN or infinite.
    NotFinite,
    /// The track is not positive, so the lever arm is meaningless.
    BadTrack,
}

/// The base's kinematic parameters at one track.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MecanumBase {
    /// Wheel radius.
    pub wheel_radius_m: f32,
    /// Half the wheelbase: body x of the front wheels.
    pub half_wheelbase_m: f32,
    /// Half the track: body y of the left wheels.
    pub half_track_m: f32,
}

impl MecanumBase {
    /// The base of `geometry` with its legs at `track_m` (wheel centre to wheel centre).
    pub fn new(geometry: &RobotGeometry, track_m: f32) -> Result<MecanumBase, BaseError> {
        if !track_m.is_finite() {
            return Err(BaseError::NotFinite);
        }
        if track_m <= 0.0 {
            return Err(BaseError::BadTrack);
        }
        Ok(MecanumBase {
            wheel_radius_m: geometry.wheel_radius_m,
            half_wheelbase_m: geometry.hip_x_m,
            half_track_m: 0.5 * track_m,
        })
    }

    /// The base of `geometry` with its legs at `config`.
    pub fn at(geometry: &RobotGeometry, config: LegConfig) -> Result<MecanumBase, BaseError> {
        MecanumBase::new(geometry, config.track_m)
    }

    /// Lever arm of a 45° roller's force about the body centre.
    fn lever_m(&self) -> f32 {
        self.half_wheelbase_m + self.half_track_m
    }

    /// Inverse kinematics: the wheel speeds that move the body at `velocity`.
    pub fn wheel_speeds(&self, velocity: BaseVelocity) -> Result<WheelSpeeds, BaseError> {
        if !velocity.is_finite() {
            return Err(BaseError::NotFinite);
        }
        let BaseVelocity {
            vx_mps: vx,
            vy_mps: vy,
            yaw_rate_radps: wz,
        } = velocity;
        let spin = self.lever_m() * wz;
        let r = self.wheel_radius_m;
        Ok(WheelSpeeds {
            radps: LegId::ALL.map(|leg| {
                // Left wheels push the body clockwise when driven forward, right wheels
                // counter-clockwise; diagonal pairs (FL/RR, FR/RL) share a roller direction.
                let diagonal = leg.fore_sign() * leg.side_sign();
                (vx - diagonal * vy - leg.side_sign() * spin) / r
            }),
        })
    }

    /// Forward kinematics (odometry): the body velocity that measured wheel speeds imply.
    pub fn body_velocity(&self, wheels: WheelSpeeds) -> Result<BaseVelocity, BaseError> {
        if wheels.radps.iter().any(|w| !w.is_finite()) {
            return Err(BaseError::NotFinite);
        }
        let r = self.wheel_radius_m;
        let (mut vx, mut vy, mut spin) = (0.0, 0.0, 0.0);
        for leg in LegId::ALL {
            let w = wheels.get(leg);
            vx += w;
            vy -= leg.fore_sign() * leg.side_sign() * w;
            spin -= leg.side_sign() * w;
        }
        Ok(BaseVelocity {
            vx_mps: 0.25 * r * vx,
            vy_mps: 0.25 * r * vy,
            yaw_rate_radps: 0.25 * r * spin / self.lever_m(),
        })
    }

    /// The largest factor `s <= 1` such that `s * velocity` keeps every wheel within
    /// `max_wheel_radps`: scaling all three components together keeps the path's shape.
    pub fn speed_scale(
        &self,
        velocity: BaseVelocity,
        max_wheel_radps: f32,
    ) -> Result<f32, BaseError> {
        let peak = self.wheel_speeds(velocity)?.max_abs_radps();
        if !max_wheel_radps.is_finite() || max_wheel_radps <= 0.0 {
            return Err(BaseError::NotFinite);
        }
        Ok(if peak <= max_wheel_radps {
            1.0
        } else {
            max_wheel_radps / peak
        })
    }
}

/// Dead-reckoned pose of the base on the ground plane, integrated from body velocities.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Odometry {
    /// Pose of the body in the frame where odometry started (x, y in metres, yaw in radians).
    pub pose: Isometry2<f32>,
}

impl Default for Odometry {
    fn default() -> Self {
        Odometry {
            pose: Isometry2::identity(),
        }
    }
}

impl Odometry {
    /// Odometry starting at `pose`.
    pub fn starting_at(pose: Isometry2<f32>) -> Odometry {
        Odometry { pose }
    }

    /// Advances the pose by a body velocity held for `dt_s`. The translation is applied at the
    /// mid-step heading, which is exact to second order and keeps long straight runs while
    /// turning from drifting sideways.
    pub fn integrate(&mut self, velocity: BaseVelocity, dt_s: f32) -> Result<(), BaseError> {
        if !velocity.is_finite() || !dt_s.is_finite() {
            return Err(BaseError::NotFinite);
        }
        let dyaw_rad = velocity.yaw_rate_radps * dt_s;
        let mid = self.pose.rotation.angle() + 0.5 * dyaw_rad;
        let (sin, cos) = (crate::trig::sin(mid), crate::trig::cos(mid));
        let (vx, vy) = (velocity.vx_mps, velocity.vy_mps);
        let world_step_m = Vector2::new(cos * vx - sin * vy, sin * vx + cos * vy) * dt_s;
        let yaw_rad = self.pose.rotation.angle() + dyaw_rad;
        let position_m = self.pose.translation.vector + world_step_m;
        self.pose = crate::trig::isometry(position_m.x, position_m.y, yaw_rad);
        Ok(())
    }

    /// Advances the pose by measured wheel speeds held for `dt_s`.
    pub fn integrate_wheels(
        &mut self,
        base: &MecanumBase,
        wheels: WheelSpeeds,
        dt_s: f32,
    ) -> Result<(), BaseError> {
        let velocity = base.body_velocity(wheels)?;
        self.integrate(velocity, dt_s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robot::WHEELLEG;

    fn base() -> MecanumBase {
        MecanumBase::new(&WHEELLEG, WHEELLEG.default_track_m).unwrap()
    }

    fn close(a: f32, b: f32) -> bool {
        (a - b).abs() < 1e-5
    }

    #[test]
    fn forward_motion_spins_all_wheels_equally() {
        let w = base()
            .wheel_speeds(BaseVelocity {
                vx_mps: 0.1,
                ..BaseVelocity::ZERO
            })
            .unwrap();
        for speed in w.radps {
            assert!(close(speed, 0.1 / WHEELLEG.wheel_radius_m), "{w:?}");
        }
    }

    #[test]
    fn strafing_left_spins_diagonal_pairs_opposite() {
        let w = base()
            .wheel_speeds(BaseVelocity {
                vy_mps: 0.1,
                ..BaseVelocity::ZERO
            })
            .unwrap();
        let expect = 0.1 / WHEELLEG.wheel_radius_m;
        // FL and RR backward, FR and RL forward: the X roller layout.
        assert!(close(w.get(LegId::FrontLeft), -expect));
        assert!(close(w.get(LegId::RearRight), -expect));
        assert!(close(w.get(LegId::FrontRight), expect));
        assert!(close(w.get(LegId::RearLeft), expect));
    }

    #[test]
    fn turning_left_spins_right_wheels_forward_and_uses_the_track() {
        let narrow = MecanumBase::new(&WHEELLEG, 0.2).unwrap();
        let wide = MecanumBase::new(&WHEELLEG, 0.5).unwrap();
        let turn = BaseVelocity {
            yaw_rate_radps: 1.0,
            ..BaseVelocity::ZERO
        };
        let wn = narrow.wheel_speeds(turn).unwrap();
        let ww = wide.wheel_speeds(turn).unwrap();
        assert!(wn.get(LegId::FrontRight) > 0.0 && wn.get(LegId::FrontLeft) < 0.0);
        // A wider stance needs faster wheels for the same yaw rate.
        assert!(ww.max_abs_radps() > wn.max_abs_radps());
        assert!(close(
            ww.get(LegId::RearRight),
            (0.2 + 0.25) / WHEELLEG.wheel_radius_m
        ));
    }

    #[test]
    fn odometry_inverts_the_wheel_map() {
        let b = base();
        for v in [
            BaseVelocity {
                vx_mps: 0.3,
                vy_mps: -0.2,
                yaw_rate_radps: 0.7,
            },
            BaseVelocity {
                vx_mps: -0.05,
                vy_mps: 0.4,
                yaw_rate_radps: -1.3,
            },
        ] {
            let back = b.body_velocity(b.wheel_speeds(v).unwrap()).unwrap();
            assert!(close(back.vx_mps, v.vx_mps), "{v:?} -> {back:?}");
            assert!(close(back.vy_mps, v.vy_mps));
            assert!(close(back.yaw_rate_radps, v.yaw_rate_radps));
        }
    }

    #[test]
    fn speed_scale_respects_the_wheel_limit() {
        let b = base();
        let v = BaseVelocity {
            vx_mps: 1.0,
            vy_mps: 0.5,
            yaw_rate_radps: 0.0,
        };
        let s = b.speed_scale(v, 10.0).unwrap();
        assert!(s < 1.0);
        let scaled = BaseVelocity {
            vx_mps: v.vx_mps * s,
            vy_mps: v.vy_mps * s,
            yaw_rate_radps: 0.0,
        };
        assert!(b.wheel_speeds(scaled).unwrap().max_abs_radps() <= 10.0 + 1e-4);
        assert_eq!(
            b.speed_scale(BaseVelocity::ZERO, 10.0).unwrap(),
            1.0,
            "standing still needs no scaling"
        );
    }

    #[test]
    fn bad_input_is_a_typed_error() {
        assert_eq!(MecanumBase::new(&WHEELLEG, 0.0), Err(BaseError::BadTrack));
        assert_eq!(
            MecanumBase::new(&WHEELLEG, f32::NAN),
            Err(BaseError::NotFinite)
        );
        let mut w = WheelSpeeds::ZERO;
        w.radps[2] = f32::INFINITY;
        assert_eq!(base().body_velocity(w), Err(BaseError::NotFinite));
    }

    #[test]
    fn driving_a_quarter_circle_ends_where_geometry_says() {
        // Forward at 0.1 m/s while turning at pi/2 rad per 1 s: a quarter circle of radius
        // 0.2/pi, ending at (R, R) with yaw pi/2.
        let mut odo = Odometry::default();
        let v = BaseVelocity {
            vx_mps: 0.1,
            vy_mps: 0.0,
            yaw_rate_radps: core::f32::consts::FRAC_PI_2,
        };
        for _ in 0..100 {
            odo.integrate(v, 0.01).unwrap();
        }
        let radius_m = 0.1 / core::f32::consts::FRAC_PI_2;
        assert!((odo.pose.translation.x - radius_m).abs() < 1e-4, "{odo:?}");
        assert!((odo.pose.translation.y - radius_m).abs() < 1e-4);
        assert!((odo.pose.rotation.angle() - core::f32::consts::FRAC_PI_2).abs() < 1e-5);
    }
}
