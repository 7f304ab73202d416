//! Exact collision between the robot's parts and the obstacles, with parry3d.
//!
//! The robot is 13 convex parts: the body (a box), per leg a thigh and a shank (capsules along
//! the links) and a wheel (a cylinder with its axle along body y). A cheap axis-aligned bounding
//! box test culls part/obstacle pairs first; what survives gets parry's exact intersection test.
//! Touching counts as colliding.

use crate::obstacle::{GroundBox, Obstacle};
use nalgebra::{Isometry3, Point2, Point3, Translation3, UnitQuaternion, Vector3};
use parry3d::bounding_volume::{Aabb, BoundingVolume};
use parry3d::query;
use parry3d::shape::{Capsule, Cuboid, Cylinder, Shape, SupportMap};
use wheelleg_runtime::leg::{IkError, LegConfig};
use wheelleg_runtime::robot::{LegId, RobotGeometry};

/// What [`ObstacleSet::clearance_lower_bound_m`] allows for parry's rounding: its bounds stay
/// below parry's distances by this much, so a proof from the bounds is one parry's values give
/// too. 10 um: a tenth of the graze tolerance of the swept check, a hundred times parry's
/// rounding at these sizes.
pub const CLEARANCE_SLACK_M: f32 = 1.0e-5;

/// The distance between two boxes (0 when they overlap).
fn box_gap_m(a: &Aabb, b: &Aabb) -> f32 {
    let gap = |lo_a: f32, hi_a: f32, lo_b: f32, hi_b: f32| (lo_b - hi_a).max(lo_a - hi_b).max(0.0);
    let dx = gap(a.mins.x, a.maxs.x, b.mins.x, b.maxs.x);
    let dy = gap(a.mins.y, a.maxs.y, b.mins.y, b.maxs.y);
    let dz = gap(a.mins.z, a.maxs.z, b.mins.z, b.maxs.z);
    (dx * dx + dy * dy + dz * dz).sqrt()
}

/// The distance from the segment `a`-`b` to the box `aabb`, up to rounding.
///
/// The squared distance from a point moving along the segment to the box is convex and, between
/// the places where the point crosses one of the box's six planes, a quadratic: its minimum is
/// at a crossing, an end, or where one of those quadratics is stationary. All of them are tried.
fn segment_box_distance_m(a: &Point3<f32>, b: &Point3<f32>, aabb: &Aabb) -> f32 {
    let d = b - a;
    let squared_at = |t: f32| {
        let p = a + d * t;
        let mut sum = 0.0;
        for i in 0..3 {
            let out = (aabb.mins[i] - p[i]).max(p[i] - aabb.maxs[i]).max(0.0);
            sum += out * out;
        }
        sum
    };
    let mut cuts = [0.0f32; 8];
    cuts[1] = 1.0;
    let mut count = 2;
    for i in 0..3 {
        if d[i] != 0.0 {
            for plane in [aabb.mins[i], aabb.maxs[i]] {
                let t = (plane - a[i]) / d[i];
                if t > 0.0 && t < 1.0 {
                    cuts[count] = t;
                    count += 1;
                }
            }
        }
    }
    let cuts = &mut cuts[..count];
    cuts.sort_unstable_by(f32::total_cmp);
    let mut best = cuts
        .iter()
        .map(|&t| squared_at(t))
        .fold(f32::INFINITY, f32::min);
    for pair in cuts.windows(2) {
        let (t0, t1) = (pair[0], pair[1]);
        let middle = a + d * (0.5 * (t0 + t1));
        // On this piece each axis is below, inside or above the box throughout: the squared
        // distance is the sum of (p_i(t) - plane_i)^2 over the axes outside.
        let (mut slope, mut offset) = (0.0f32, 0.0f32);
        for i in 0..3 {
            let plane = if middle[i] < aabb.mins[i] {
                aabb.mins[i]
            } else if middle[i] > aabb.maxs[i] {
                aabb.maxs[i]
            } else {
                continue;
            };
            slope += d[i] * d[i];
            offset += d[i] * (a[i] - plane);
        }
        if slope > 0.0 {
            let t = (-offset / slope).clamp(t0, t1);
            best = best.min(squared_at(t));
        }
    }
    best.sqrt()
}

/// The distance from a box turned about the vertical only (centre and heading from `pose`,
/// half extents `half`) to the axis-aligned box `aabb`, up to rounding: both are upright
/// prisms, so it is the distance of their footprints combined with the vertical gap.
fn upright_box_distance_m(pose: &Isometry3<f32>, half: &Vector3<f32>, aabb: &Aabb) -> f32 {
    let centre = pose.translation.vector;
    let vertical_m = (aabb.mins.z - (centre.z + half.z))
        .max((centre.z - half.z) - aabb.maxs.z)
        .max(0.0);
    let axis_x = pose.rotation * Vector3::x();
    let (u, v) = ([axis_x.x, axis_x.y], [-axis_x.y, axis_x.x]);
    let corner = |su: f32, sv: f32| {
        [
            centre.x + su * half.x * u[0] + sv * half.y * v[0],
            centre.y + su * half.x * u[1] + sv * half.y * v[1],
        ]
    };
    let turned = [
        corner(-1.0, -1.0),
        corner(1.0, -1.0),
        corner(1.0, 1.0),
        corner(-1.0, 1.0),
    ];
    let upright = [
        [aabb.mins.x, aabb.mins.y],
        [aabb.maxs.x, aabb.mins.y],
        [aabb.maxs.x, aabb.maxs.y],
        [aabb.mins.x, aabb.maxs.y],
    ];
    // Footprints apart along one of the four edge directions (separating axis theorem for two
    // rectangles) are as far apart as the nearest corner of one to the other; otherwise they
    // overlap.
    let apart_along = |axis: [f32; 2]| {
        let project = |p: &[f32; 2]| p[0] * axis[0] + p[1] * axis[1];
        let (mut lo_a, mut hi_a, mut lo_b, mut hi_b) = (
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::INFINITY,
            f32::NEG_INFINITY,
        );
        for p in &turned {
            lo_a = lo_a.min(project(p));
            hi_a = hi_a.max(project(p));
        }
        for p in &upright {
            lo_b = lo_b.min(project(p));
            hi_b = hi_b.max(project(p));
        }
        lo_b > hi_a || lo_a > hi_b
    };
    let apart = [[1.0, 0.0], [0.0, 1.0], u, v].into_iter().any(apart_along);
    let horizontal_m = if apart {
        let to_upright = |p: &[f32; 2]| {
            let dx = (aabb.mins.x - p[0]).max(p[0] - aabb.maxs.x).max(0.0);
            let dy = (aabb.mins.y - p[1]).max(p[1] - aabb.maxs.y).max(0.0);
            dx * dx + dy * dy
        };
        let to_turned = |p: &[f32; 2]| {
            let (px, py) = (p[0] - centre.x, p[1] - centre.y);
            let along_u = px * u[0] + py * u[1];
            let along_v = px * v[0] + py * v[1];
            let du = (along_u.abs() - half.x).max(0.0);
            let dv = (along_v.abs() - half.y).max(0.0);
            du * du + dv * dv
        };
        let squared = turned
            .iter()
            .map(to_upright)
            .chain(upright.iter().map(to_turned))
            .fold(f32::INFINITY, f32::min);
        squared.sqrt()
    } else {
        0.0
    };
    horizontal_m.hypot(vertical_m)
}

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
    fn distance_lower_bound_m(&self, obstacle: &Aabb) -> f32 {
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
    fn ball_gap_m(&self, obstacle: &Aabb) -> f32 {
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
    fn placed(&self) -> (Isometry3<f32>, &dyn Shape) {
        match self {
            Part::Body { pose, shape } => (*pose, shape),
            Part::Link(capsule) => (Isometry3::identity(), capsule),
            Part::Wheel { pose, shape } => (*pose, shape),
        }
    }

    fn intersects(&self, obstacle_pose: &Isometry3<f32>, obstacle: &Cuboid) -> bool {
        let (pose, shape) = self.placed();
        // Every pair here is convex-convex, which parry always supports; an unsupported pair
        // would be a programming error, and counting it as a collision is the safe side.
        query::intersection_test(&pose, shape, obstacle_pose, obstacle).unwrap_or(true)
    }
}

/// The robot's parts at one pose, with their bounding boxes.
#[derive(Clone, Debug)]
pub struct RobotParts {
    parts: [Part; PART_COUNT],
    aabbs: [Aabb; PART_COUNT],
    aabb: Aabb,
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
        let (hip, knee, wheel) = (
            body_pose * Point3::from(hip),
            to_world(plane.knee.outward_m, plane.knee.down_m),
            to_world(plane.wheel.outward_m, plane.wheel.down_m),
        );
        slot[0] = Part::Link(Capsule::new(hip, knee, geometry.link_radius_m));
        slot[1] = Part::Link(Capsule::new(knee, wheel, geometry.link_radius_m));
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

/// The static obstacles of a scene, ready for collision queries.
#[derive(Clone, Debug, Default)]
pub struct ObstacleSet {
    boxes: Vec<GroundBox>,
    aabbs: Vec<Aabb>,
    poses: Vec<Isometry3<f32>>,
    shapes: Vec<Cuboid>,
}

impl ObstacleSet {
    /// Prepares a scene's obstacles.
    pub fn new(obstacles: &[Obstacle]) -> Self {
        ObstacleSet::from_boxes(obstacles.iter().map(Obstacle::ground_box).collect())
    }

    /// Prepares boxes that are not the generator's obstacles: what the robot perceives of a
    /// scene ([`crate::local_plan`]), which need not be of the three kinds.
    pub fn from_boxes(boxes: Vec<GroundBox>) -> Self {
        ObstacleSet {
            aabbs: boxes
                .iter()
                .map(|b| {
                    Aabb::new(
                        Point3::new(b.min_x_m, b.min_y_m, 0.0),
                        Point3::new(b.max_x_m, b.max_y_m, b.height_m),
                    )
                })
                .collect(),
            poses: boxes
                .iter()
                .map(|b| Isometry3::from_parts(Translation3::from(b.centre()), Default::default()))
                .collect(),
            shapes: boxes
                .iter()
                .map(|b| Cuboid::new(b.half_extents()))
                .collect(),
            boxes,
        }
    }

    /// The obstacles' boxes.
    pub fn boxes(&self) -> &[GroundBox] {
        &self.boxes
    }

    /// Whether any obstacle's footprint comes within `reach_m` of `centre` (as a square test:
    /// cheap, and conservative).
    pub fn any_within(&self, centre: Point2<f32>, reach_m: f32) -> bool {
        self.boxes.iter().any(|b| {
            b.min_x_m <= centre.x + reach_m
                && b.max_x_m >= centre.x - reach_m
                && b.min_y_m <= centre.y + reach_m
                && b.max_y_m >= centre.y - reach_m
        })
    }

    /// Whether any obstacle's footprint comes within `reach_m` of the straight segment from
    /// `a` to `b` (as a test on the box spanning both ends, grown by `reach_m`: cheap, and
    /// conservative).
    pub fn any_within_span(&self, a: Point2<f32>, b: Point2<f32>, reach_m: f32) -> bool {
        let (min_x, max_x) = (a.x.min(b.x) - reach_m, a.x.max(b.x) + reach_m);
        let (min_y, max_y) = (a.y.min(b.y) - reach_m, a.y.max(b.y) + reach_m);
        self.boxes.iter().any(|g| {
            g.min_x_m <= max_x && g.max_x_m >= min_x && g.min_y_m <= max_y && g.max_y_m >= min_y
        })
    }

    /// Whether the box `aabb` overlaps any obstacle's bounding box.
    pub fn may_touch(&self, aabb: &Aabb) -> bool {
        self.aabbs.iter().any(|b| b.intersects(aabb))
    }

    /// How deep the robot's parts reach into the obstacles: the largest penetration depth of
    /// any part into any obstacle, 0 when nothing touches (a measure for reports and tests of
    /// how bad a contact is; [`ObstacleSet::collides`] is the rule).
    pub fn penetration_m(&self, robot: &RobotParts) -> f32 {
        let mut deepest_m = 0.0f32;
        for (i, obstacle_aabb) in self.aabbs.iter().enumerate() {
            if !obstacle_aabb.intersects(&robot.aabb) {
                continue;
            }
            for (part, part_aabb) in robot.parts.iter().zip(&robot.aabbs) {
                if !part_aabb.intersects(obstacle_aabb) {
                    continue;
                }
                let (pose, shape) = part.placed();
                if let Ok(Some(contact)) =
                    query::contact(&pose, shape, &self.poses[i], &self.shapes[i], 0.0)
                {
                    deepest_m = deepest_m.max(-contact.dist);
                }
            }
        }
        deepest_m
    }

    /// Whether any robot part comes within `margin_m` of any obstacle (touching included):
    /// [`ObstacleSet::collides`] with every obstacle grown by the margin, for motions whose
    /// real pose may stray from the checked one by up to the margin.
    pub fn within_margin(&self, robot: &RobotParts, margin_m: f32) -> bool {
        let robot_aabb = robot.aabb.loosened(margin_m);
        for (i, obstacle_aabb) in self.aabbs.iter().enumerate() {
            if !obstacle_aabb.intersects(&robot_aabb) {
                continue;
            }
            for (part, part_aabb) in robot.parts.iter().zip(&robot.aabbs) {
                if !part_aabb.loosened(margin_m).intersects(obstacle_aabb) {
                    continue;
                }
                let (pose, shape) = part.placed();
                // A contact "predicted" within the margin is a pair closer than the margin
                // (parry's contact query; its plain distance query misjudged box pairs here).
                // Convex-convex, always supported; an error counts as too close (safe side).
                let close = query::contact(&pose, shape, &self.poses[i], &self.shapes[i], margin_m)
                    .map_or(true, |contact| contact.is_some());
                if close {
                    return true;
                }
            }
        }
        false
    }

    /// How far the robot is from the nearest obstacle, looked for up to `up_to_m`: `None` when
    /// a part touches or enters an obstacle (the contact rule of [`ObstacleSet::collides`]),
    /// otherwise the smallest part-to-obstacle distance, or `up_to_m` when nothing is closer.
    /// The swept check of a step ([`crate::env::Env::check_transition`]) proves a stretch of
    /// motion clear from these distances.
    pub fn clearance_m(&self, robot: &RobotParts, up_to_m: f32) -> Option<f32> {
        let mut nearest_m = up_to_m.max(0.0);
        let robot_aabb = robot.aabb.loosened(nearest_m);
        for (i, obstacle_aabb) in self.aabbs.iter().enumerate() {
            if !obstacle_aabb.intersects(&robot_aabb) {
                continue;
            }
            for (part, part_aabb) in robot.parts.iter().zip(&robot.aabbs) {
                // Boxes farther apart than the nearest distance so far cannot lower it.
                if !part_aabb.loosened(nearest_m).intersects(obstacle_aabb) {
                    continue;
                }
                let (pose, shape) = part.placed();
                // parry's contact query with a prediction distance: its plain distance query
                // misjudged box pairs (see `within_margin`). Convex-convex pairs are always
                // supported; an error counts as touching (the safe side).
                match query::contact(&pose, shape, &self.poses[i], &self.shapes[i], nearest_m) {
                    Ok(Some(contact)) if contact.dist <= 0.0 => return None,
                    Ok(Some(contact)) => nearest_m = nearest_m.min(contact.dist),
                    Ok(None) => {}
                    Err(_) => return None,
                }
            }
        }
        Some(nearest_m)
    }

    /// A lower bound on [`ObstacleSet::clearance_m`]`(robot, up_to_m)`, cheap: from the gaps
    /// between the parts' and the obstacles' boxes (a part is inside its box, so it is at least
    /// as far from an obstacle as its box is), less [`CLEARANCE_SLACK_M`] for the rounding of
    /// parry's query. At most 0 when some part may touch an obstacle; `up_to_m` less the slack
    /// when nothing is within `up_to_m`.
    pub fn clearance_lower_bound_m(&self, robot: &RobotParts, up_to_m: f32) -> f32 {
        let mut nearest_m = up_to_m.max(0.0);
        let robot_aabb = robot.aabb.loosened(nearest_m);
        for obstacle_aabb in &self.aabbs {
            if !obstacle_aabb.intersects(&robot_aabb) {
                continue;
            }
            for (part, part_aabb) in robot.parts.iter().zip(&robot.aabbs) {
                let gap_m = box_gap_m(part_aabb, obstacle_aabb);
                // The box gap is all a pair far enough away needs; closer, the part's own
                // shape gives a better bound.
                if gap_m >= nearest_m {
                    continue;
                }
                nearest_m = nearest_m.min(gap_m.max(part.distance_lower_bound_m(obstacle_aabb)));
            }
        }
        nearest_m - CLEARANCE_SLACK_M
    }

    /// A lower bound on [`ObstacleSet::clearance_lower_bound_m`] for the parts `parts` (placed
    /// by [`place_parts`], so without their boxes), for poses placed only to be bounded:
    /// each part/obstacle pair counts with the part's own distance bound (which that function
    /// takes the better of with the box gap), or, when a ball around the part is already
    /// farther than the nearest found, not at all (the ball's distance is below the part's
    /// bound). Equal to it up to rounding, or lower.
    ///
    /// `reach_m` bounds how far any part reaches horizontally from the body centre (every
    /// shape the part bounds measure included): an obstacle whose footprint is farther than
    /// that plus the nearest found is skipped whole. `near`, when given, lists the only
    /// obstacles (indices) that can be within `reach_m + up_to_m` ([`ObstacleSet::near`]).
    pub(crate) fn parts_clearance_lower_bound_m(
        &self,
        parts: &[Part; PART_COUNT],
        reach_m: f32,
        up_to_m: f32,
        near: Option<&[usize]>,
    ) -> f32 {
        let mut nearest_m = up_to_m.max(0.0);
        let Part::Body { pose, .. } = &parts[0] else {
            unreachable!("the body comes first")
        };
        let (x, y) = (pose.translation.x, pose.translation.y);
        let mut visit = |obstacle_aabb: &Aabb| {
            let dx = (obstacle_aabb.mins.x - x)
                .max(x - obstacle_aabb.maxs.x)
                .max(0.0);
            let dy = (obstacle_aabb.mins.y - y)
                .max(y - obstacle_aabb.maxs.y)
                .max(0.0);
            if (dx * dx + dy * dy).sqrt() - reach_m >= nearest_m {
                return;
            }
            for part in parts {
                if part.ball_gap_m(obstacle_aabb) >= nearest_m {
                    continue;
                }
                nearest_m = nearest_m.min(part.distance_lower_bound_m(obstacle_aabb));
            }
        };
        match near {
            Some(near) => near.iter().for_each(|&i| visit(&self.aabbs[i])),
            None => self.aabbs.iter().for_each(visit),
        }
        nearest_m - CLEARANCE_SLACK_M
    }

    /// The obstacles (indices) whose footprint comes within `within_m` of `centre`, as a
    /// square test (so never fewer than a round one would find).
    pub(crate) fn near(&self, centre: Point2<f32>, within_m: f32) -> Vec<usize> {
        (0..self.boxes.len())
            .filter(|&i| {
                let b = &self.boxes[i];
                b.min_x_m <= centre.x + within_m
                    && b.max_x_m >= centre.x - within_m
                    && b.min_y_m <= centre.y + within_m
                    && b.max_y_m >= centre.y - within_m
            })
            .collect()
    }

    /// Whether some part, anywhere within `grow_m` of the box spanning its places in `start`
    /// and `end`, could meet an obstacle's box. When not, a motion from `start` to `end` that
    /// moves no point of the robot farther than `2 * grow_m` touches nothing on the way: every
    /// point of a part at any moment is within `grow_m` of where it was at one end.
    pub fn sweep_may_touch(&self, start: &RobotParts, end: &RobotParts, grow_m: f32) -> bool {
        let whole = start.aabb.merged(&end.aabb).loosened(grow_m);
        self.aabbs.iter().filter(|o| o.intersects(&whole)).any(|o| {
            start
                .aabbs
                .iter()
                .zip(&end.aabbs)
                .any(|(a, b)| a.merged(b).loosened(grow_m).intersects(o))
        })
    }

    /// Whether any robot part intersects any obstacle.
    pub fn collides(&self, robot: &RobotParts) -> bool {
        for (i, obstacle_aabb) in self.aabbs.iter().enumerate() {
            if !obstacle_aabb.intersects(&robot.aabb) {
                continue;
            }
            for (part, part_aabb) in robot.parts.iter().zip(&robot.aabbs) {
                if part_aabb.intersects(obstacle_aabb)
                    && part.intersects(&self.poses[i], &self.shapes[i])
                {
                    return true;
                }
            }
        }
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::obstacle::{ObstacleKind, ObstacleYaw};
    use wheelleg_runtime::robot::WHEELLEG;

    fn robot_at(x_m: f32) -> RobotParts {
        let legs = LegConfig {
            clearance_m: WHEELLEG.default_clearance_m,
            track_m: WHEELLEG.default_track_m,
        };
        RobotParts::new(&WHEELLEG, Point2::new(x_m, 0.0), 0.0, legs).unwrap()
    }

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

    #[test]
    fn margin_and_depth_agree_with_the_contact_rule() {
        // A block 0.20 m long centred 1 m ahead: its near face at x = 0.9 m.
        let set = ObstacleSet::new(&[Obstacle::new(
            ObstacleKind::Block,
            1.0,
            0.0,
            ObstacleYaw::default(),
        )]);
        // Drive up in millimetres until the first contact.
        let touch_m = (0..1000)
            .map(|mm| mm as f32 * 1e-3)
            .find(|&x_m| set.collides(&robot_at(x_m)))
            .unwrap();
        // 2 cm short of it: free, and within a 3 cm margin but not a 1 cm one.
        let near = robot_at(touch_m - 0.02);
        assert!(!set.collides(&near));
        assert_eq!(set.penetration_m(&near), 0.0);
        assert!(!set.within_margin(&near, 0.01));
        assert!(set.within_margin(&near, 0.03));
        // 1 cm further than the first contact: colliding, about 1 cm deep, within any margin.
        let into = robot_at(touch_m + 0.01);
        assert!(set.collides(&into));
        let depth_m = set.penetration_m(&into);
        assert!(depth_m > 0.008 && depth_m < 0.012, "{depth_m}");
        assert!(set.within_margin(&into, 0.0));
    }
}
