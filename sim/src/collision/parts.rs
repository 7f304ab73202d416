//! The robot's 13 convex parts placed in the world for one pose, and their bounding boxes.

use super::bounds::{nearest_in_box, segment_box_distance_m, upright_box_distance_m};
use nalgebra::{Isometry3, Point2, Point3, Translation3, UnitQuaternion, Vector3};
use parry3d::bounding_volume::{Aabb, BoundingVolume};
use parry3d::query;
use parry3d::shape::{Capsule, Cuboid, Cylinder, Shape, SupportMap};
use wheelleg_runtime::leg::{IkError, LegConfig};
use wheelleg_runtime::robot::{LegId, RobotGeometry};

/// Number of robot parts checked for collision.
pub const PART_COUNT: usize = 1 + 3 * 4;

/// One convex part of the robot, placed in the world.
#[derive(Clone, Copy, Debug)]
pub enum Part {
    /// The body box.
    Body {
        /// World pose of the box centre.
        pose: Isometry3<f32>,
        /// The box.
        shape: Cuboid,
    },
    /// A leg link; the capsule's segment is in world coordinates.
    Link(Capsule),
    /// A wheel.
    Wheel {
        /// World pose of the wheel centre, local y along the axle.
        pose: Isometry3<f32>,
        /// The wheel.
        shape: Cylinder,
    },
}

impl Part {
    /// Axis-aligned bounding box in the world.
    pub fn aabb(&self) -> Aabb {
        match self {
            Part::Body { pose, shape } => shape.compute_aabb(pose),
            // The segment is in world coordinates already (parry's `compute_aabb` would move it
            // by the identity first, to the same box).
            Part::Link(capsule) => capsule.local_aabb(),
            Part::Wheel { pose, shape } => {
                WheelReach::new(&pose.rotation, shape).aabb(&pose.translation.vector)
            }
        }
    }

    /// A lower bound on the distance from the part to the axis-aligned box `obstacle` (at most
    /// 0 when they may touch), up to rounding (see [`CLEARANCE_SLACK_M`]):
    /// - a link: the distance from its segment to the box, less the radius (exact);
    /// - the body: a box turned about the vertical only, so both are upright prisms, whose
    ///   distance is the horizontal distance of their footprints and the vertical gap combined
    ///   (exact);
    /// - a wheel: the better of its upright bounding box's distance (as for the body) and its
    ///   axle's distance less its radius (the cylinder lies in the capsule around its axle).
    pub(super) fn distance_lower_bound_m(&self, obstacle: &Aabb) -> f32 {
        match self {
            Part::Link(capsule) => {
                segment_box_distance_m(&capsule.segment.a, &capsule.segment.b, obstacle)
                    - capsule.radius
            }
            Part::Body { pose, shape } => {
                upright_box_distance_m(pose, &shape.half_extents, obstacle)
            }
            Part::Wheel { pose, shape } => {
                let half = Vector3::new(shape.radius, shape.half_height, shape.radius);
                let axle = pose.rotation * Vector3::new(0.0, shape.half_height, 0.0);
                let centre = Point3::from(pose.translation.vector);
                let around_axle_m =
                    segment_box_distance_m(&(centre - axle), &(centre + axle), obstacle)
                        - shape.radius;
                upright_box_distance_m(pose, &half, obstacle).max(around_axle_m)
            }
        }
    }

    /// A lower bound on [`Part::distance_lower_bound_m`], cheaper still: the distance from a
    /// ball around the part (around the shapes that bound measures) to the box.
    pub(super) fn ball_gap_m(&self, obstacle: &Aabb) -> f32 {
        let (centre, radius) = match self {
            Part::Link(capsule) => (
                capsule.segment.a + 0.5 * (capsule.segment.b - capsule.segment.a),
                0.5 * (capsule.segment.b - capsule.segment.a).norm() + capsule.radius,
            ),
            Part::Body { pose, shape } => (
                Point3::from(pose.translation.vector),
                shape.half_extents.norm(),
            ),
            // The upright box (half extents r, h, r) and the capsule around the axle (h + r).
            Part::Wheel { pose, shape } => (
                Point3::from(pose.translation.vector),
                (2.0 * shape.radius * shape.radius + shape.half_height * shape.half_height)
                    .sqrt()
                    .max(shape.half_height + shape.radius),
            ),
        };
        let mut sum = 0.0;
        for i in 0..3 {
            let out = (obstacle.mins[i] - centre[i])
                .max(centre[i] - obstacle.maxs[i])
                .max(0.0);
            sum += out * out;
        }
        sum.sqrt() - radius
    }

    /// The part as parry's queries take it: a pose and a shape.
    pub(super) fn placed(&self) -> (Isometry3<f32>, &dyn Shape) {
        match self {
            Part::Body { pose, shape } => (*pose, shape),
            Part::Link(capsule) => (Isometry3::identity(), capsule),
            Part::Wheel { pose, shape } => (*pose, shape),
        }
    }

    /// Whether the part touches or enters the obstacle box `obstacle` (parry's `pose` and
    /// `shape` of it for the wheel): the link's and the body's distances are exact
    /// ([`Part::distance_lower_bound_m`]), the wheel's comes from parry's intersection test
    /// (which `parts_keep_every_point_s_distance` holds to sampled points).
    pub(super) fn intersects(
        &self,
        obstacle: &Aabb,
        obstacle_pose: &Isometry3<f32>,
        shape: &Cuboid,
    ) -> bool {
        match self {
            Part::Link(_) | Part::Body { .. } => self.distance_lower_bound_m(obstacle) <= 0.0,
            Part::Wheel { .. } => {
                let (pose, wheel) = self.placed();
                // Convex-convex, which parry always supports; an unsupported pair would be a
                // programming error, and counting it as a collision is the safe side.
                query::intersection_test(&pose, wheel, obstacle_pose, shape).unwrap_or(true)
            }
        }
    }

    /// The part's distance to the obstacle box `obstacle` (parry's `pose` and `shape` of it
    /// for the wheel), never above the true distance, looked for up to `up_to_m`; `None` when
    /// they may touch. The proof of the way there rests on this never being too high.
    ///
    /// The link's and the body's distances are exact. The wheel's is the best of its cheap
    /// bound and the gap between the wheel's and the box's extents along two directions:
    /// parry's contact normal and the way from the wheel's centre to the box. Any direction
    /// gives a lower bound (two convex sets are at least as far apart as their shadows on a
    /// line), and the right one gives the distance. parry's own distance is not used: its
    /// contact query with a prediction distance overestimates capsule/box and cylinder/box
    /// distances (in about half the near pairs of `parts_keep_every_point_s_distance`, by up
    /// to millimetres for capsules), where its normal still points nearly the right way.
    pub(super) fn clearance_m(
        &self,
        obstacle: &Aabb,
        obstacle_pose: &Isometry3<f32>,
        shape: &Cuboid,
        up_to_m: f32,
    ) -> Option<f32> {
        let cheap_m = self.distance_lower_bound_m(obstacle);
        let distance_m = match self {
            Part::Link(_) | Part::Body { .. } => cheap_m,
            Part::Wheel { pose, shape: wheel } => {
                let (placed, as_shape) = self.placed();
                let normal = match query::contact(&placed, as_shape, obstacle_pose, shape, up_to_m)
                {
                    Ok(Some(contact)) if contact.dist <= 0.0 => return None,
                    Err(_) => return None,
                    Ok(contact) => contact.map(|c| c.normal1.into_inner()),
                };
                let centre = Point3::from(pose.translation.vector);
                let towards = (nearest_in_box(&centre, obstacle) - centre).try_normalize(1.0e-9);
                [normal, towards]
                    .into_iter()
                    .flatten()
                    .map(|n| wheel_gap_along_m(pose, wheel, obstacle, &n))
                    .fold(cheap_m, f32::max)
            }
        };
        (distance_m > 0.0).then_some(distance_m)
    }
}

/// The gap between the wheel (`pose`, `wheel`) and the box `obstacle` along the unit direction
/// `n` (from the wheel towards the box): the box's least extent along `n` less the wheel's
/// greatest. A lower bound on their distance for any `n`.
fn wheel_gap_along_m(
    pose: &Isometry3<f32>,
    wheel: &Cylinder,
    obstacle: &Aabb,
    n: &Vector3<f32>,
) -> f32 {
    let axle = pose.rotation * Vector3::y();
    let along_axle = axle.dot(n);
    let wheel_m = pose.translation.vector.dot(n)
        + wheel.half_height * along_axle.abs()
        + wheel.radius * (1.0 - along_axle * along_axle).max(0.0).sqrt();
    let box_m: f32 = (0..3)
        .map(|k| {
            n[k] * if n[k] >= 0.0 {
                obstacle.mins[k]
            } else {
                obstacle.maxs[k]
            }
        })
        .sum();
    box_m - wheel_m
}

/// The robot's parts at one pose, with their bounding boxes.
#[derive(Clone, Debug)]
pub struct RobotParts {
    pub(super) parts: [Part; PART_COUNT],
    pub(super) aabbs: [Aabb; PART_COUNT],
    pub(super) aabb: Aabb,
}

impl RobotParts {
    /// Places the robot's parts for a body pose and leg configuration; fails if the legs cannot
    /// reach the configuration.
    pub fn new(
        geometry: &RobotGeometry,
        position: Point2<f32>,
        yaw_rad: f32,
        legs: LegConfig,
    ) -> Result<Self, IkError> {
        let parts = place_parts(geometry, position, yaw_rad, legs)?;
        let Part::Body {
            pose: body_pose, ..
        } = parts[0]
        else {
            unreachable!("the body comes first")
        };
        let wheel_shape = Cylinder::new(0.5 * geometry.wheel_width_m, geometry.wheel_radius_m);
        // The wheels all turn with the body: their boxes' offsets from their centres are the
        // same for all four, worked out once.
        let wheel_reach = WheelReach::new(&body_pose.rotation, &wheel_shape);
        let aabbs = parts.map(|p| match p {
            Part::Wheel { pose, .. } => wheel_reach.aabb(&pose.translation.vector),
            _ => p.aabb(),
        });
        let aabb = aabbs[1..].iter().fold(aabbs[0], |acc, b| acc.merged(b));
        Ok(RobotParts { parts, aabbs, aabb })
    }

    /// The parts.
    pub fn parts(&self) -> &[Part; PART_COUNT] {
        &self.parts
    }

    /// Bounding box of the whole robot.
    pub fn aabb(&self) -> Aabb {
        self.aabb
    }
}

/// The robot's parts for a body pose and leg configuration, as [`RobotParts::new`] places them
/// (the same values), without their bounding boxes; fails if the legs cannot reach the
/// configuration.
pub(crate) fn place_parts(
    geometry: &RobotGeometry,
    position: Point2<f32>,
    yaw_rad: f32,
    legs: LegConfig,
) -> Result<[Part; PART_COUNT], IkError> {
    let joints = geometry.leg_ik(legs)?;
    let body_pose = crate::state::body_pose_at(
        position,
        yaw_rad,
        geometry.body_centre_height_m(legs.clearance_m),
    );
    let body = Part::Body {
        pose: body_pose,
        shape: Cuboid::new(Vector3::new(
            0.5 * geometry.body_length_m,
            0.5 * geometry.body_width_m,
            0.5 * geometry.body_thickness_m,
        )),
    };
    let wheel_shape = Cylinder::new(0.5 * geometry.wheel_width_m, geometry.wheel_radius_m);
    let mut parts = [body; PART_COUNT];
    // The four legs share one solution in the leg plane: its forward kinematics once, then
    // each leg's mirror of it, as `RobotGeometry::leg_points` places it (same arithmetic).
    let plane = geometry.leg_fk(joints);
    for (slot, leg) in parts[1..].chunks_exact_mut(3).zip(LegId::ALL) {
        let hip = geometry.hip_in_body(leg);
        let to_world = |outward_m: f32, down_m: f32| {
            body_pose * Point3::new(hip.x, hip.y + leg.side_sign() * outward_m, hip.z - down_m)
        };
        let (hip, knee, mount, wheel) = (
            body_pose * Point3::from(hip),
            to_world(plane.knee.outward_m, plane.knee.down_m),
            to_world(plane.wheel_mount.outward_m, plane.wheel_mount.down_m),
            to_world(plane.wheel.outward_m, plane.wheel.down_m),
        );
        // The axle between mount and wheel lies within the shank's end and the wheel
        // (`RobotGeometry::max_wheel_offset_m`): no part of its own.
        slot[0] = Part::Link(Capsule::new(hip, knee, geometry.link_radius_m));
        slot[1] = Part::Link(Capsule::new(knee, mount, geometry.link_radius_m));
        slot[2] = Part::Wheel {
            pose: Isometry3::from_parts(Translation3::from(wheel.coords), body_pose.rotation),
            shape: wheel_shape,
        };
    }
    Ok(parts)
}

/// How far a wheel reaches from its centre along each world axis, for its bounding box:
/// parry's box of a cylinder (`Cylinder::compute_aabb`, the support point towards each of the
/// six axis directions) computed with half the work, bit for bit the same. The support point
/// towards `-e` is the mirror of the one towards `e` (a cylinder is symmetric, and the rotation
/// is linear: negating its input negates every rounded product and sum exactly), so three
/// support points give all six faces; the test `wheel_boxes_are_parrys` holds the equality.
struct WheelReach {
    /// Offset from the centre of the support point towards `+e_d`, for each axis `d`.
    towards: [Vector3<f32>; 3],
}

impl WheelReach {
    fn new(rotation: &UnitQuaternion<f32>, shape: &Cylinder) -> Self {
        let towards = [0, 1, 2].map(|d| {
            let mut basis = Vector3::zeros();
            basis[d] = 1.0;
            let local = rotation.inverse_transform_vector(&basis);
            (rotation * shape.local_support_point(&local)).coords
        });
        WheelReach { towards }
    }

    /// The box of the wheel centred at `centre`.
    fn aabb(&self, centre: &Vector3<f32>) -> Aabb {
        let mut mins = Point3::origin();
        let mut maxs = Point3::origin();
        for d in 0..3 {
            maxs[d] = self.towards[d][d] + centre[d];
            mins[d] = -self.towards[d][d] + centre[d];
        }
        Aabb::new(mins, maxs)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wheel_boxes_are_parrys() {
        let shape = Cylinder::new(0.02, 0.05);
        let mut checked = 0;
        for yaw_step in -80..=80 {
            for (x_m, y_m, z_m) in [(0.0, 0.0, 0.05), (-1.37, 0.61, 0.113), (2.9, -3.3, 0.0)] {
                let yaw_rad = (yaw_step as f32 * 5.0).to_radians() + 1.0e-3 * x_m;
                let pose = Isometry3::from_parts(
                    Translation3::new(x_m, y_m, z_m),
                    UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw_rad),
                );
                let ours = WheelReach::new(&pose.rotation, &shape).aabb(&pose.translation.vector);
                let parrys = shape.compute_aabb(&pose);
                for d in 0..3 {
                    assert_eq!(ours.mins[d].to_bits(), parrys.mins[d].to_bits(), "{pose:?}");
                    assert_eq!(ours.maxs[d].to_bits(), parrys.maxs[d].to_bits(), "{pose:?}");
                }
                checked += 1;
            }
        }
        assert_eq!(checked, 161 * 3);
    }
}
