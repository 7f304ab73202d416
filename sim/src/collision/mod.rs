//! Exact collision between the robot's parts and the obstacles, with parry3d.
//!
//! The robot is 13 convex parts: the body (a box), per leg a thigh and a shank (capsules along
//! the links) and a wheel (a cylinder with its axle along body y). A cheap axis-aligned bounding
//! box test culls part/obstacle pairs first; what survives gets an exact test: closed-form
//! distances for the links and the body against the upright obstacle boxes, parry for the
//! wheels (its distances bounded from below, see `Part::clearance_m`). Touching counts as
//! colliding.

mod bounds;
mod parts;

pub(crate) use parts::place_parts;
pub use parts::{Part, RobotParts, PART_COUNT};

use crate::obstacle::{GroundBox, Obstacle};
use bounds::box_gap_m;
use nalgebra::{Isometry3, Point2, Point3, Translation3};
use parry3d::bounding_volume::{Aabb, BoundingVolume};
use parry3d::query;
use parry3d::shape::Cuboid;

/// What [`ObstacleSet::clearance_lower_bound_m`] allows for parry's rounding: its bounds stay
/// below parry's distances by this much, so a proof from the bounds is one parry's values give
/// too. 10 um: a tenth of the graze tolerance of the swept check, a hundred times parry's
/// rounding at these sizes.
pub const CLEARANCE_SLACK_M: f32 = 1.0e-5;

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

    /// Whether any robot part comes within `margin_m` of any obstacle (touching included), by
    /// [`ObstacleSet::clearance_m`]: [`ObstacleSet::collides`] with every obstacle grown by the
    /// margin, for motions whose real pose may stray from the checked one by up to the margin.
    /// A wheel whose lower bound falls short of the margin counts as within it.
    pub fn within_margin(&self, robot: &RobotParts, margin_m: f32) -> bool {
        // The clearance is never above the true distance, so a pair it cannot show to be the
        // margin apart counts as too close (the safe side).
        self.clearance_m(robot, margin_m)
            .is_none_or(|clearance_m| clearance_m < margin_m)
    }

    /// How far the robot is from the nearest obstacle, looked for up to `up_to_m`: `None` when
    /// a part may touch or enter an obstacle, otherwise the smallest part-to-obstacle distance
    /// (a wheel's from below: `Part::clearance_m`), or `up_to_m` when nothing is closer.
    /// Never above the true distance: the swept check of a step
    /// ([`crate::env::Env::check_transition`]) proves a stretch of motion clear from these
    /// values.
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
                nearest_m = nearest_m.min(part.clearance_m(
                    obstacle_aabb,
                    &self.poses[i],
                    &self.shapes[i],
                    nearest_m,
                )?);
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
                    && part.intersects(obstacle_aabb, &self.poses[i], &self.shapes[i])
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
    use nalgebra::Vector3;
    use wheelleg_runtime::leg::LegConfig;
    use wheelleg_runtime::robot::WHEELLEG;

    fn robot_at(x_m: f32) -> RobotParts {
        let legs = LegConfig {
            clearance_m: WHEELLEG.default_clearance_m,
            track_m: WHEELLEG.default_track_m,
        };
        RobotParts::new(&WHEELLEG, Point2::new(x_m, 0.0), 0.0, legs).unwrap()
    }

    /// Points inside the parts, on their surfaces where the obstacle is near: the least of
    /// their distances to the obstacle is at least the parts' true distance.
    fn points_of(part: &Part, obstacle: &Aabb) -> Vec<Point3<f32>> {
        let toward = |p: Point3<f32>, r: f32| {
            p + (bounds::nearest_in_box(&p, obstacle) - p)
                .try_normalize(1.0e-9)
                .unwrap_or_default()
                * r
        };
        let mut points = Vec::new();
        match part {
            Part::Link(capsule) => {
                for i in 0..=200 {
                    let p = capsule.segment.a
                        + (capsule.segment.b - capsule.segment.a) * (i as f32 / 200.0);
                    points.push(toward(p, capsule.radius * (1.0 - 1.0e-6)));
                }
            }
            Part::Body { pose, shape } => {
                let h = shape.half_extents;
                for i in 0..=20 {
                    for j in 0..=20 {
                        for k in 0..=4 {
                            let f = |n: i32, of: i32| 2.0 * n as f32 / of as f32 - 1.0;
                            points.push(
                                pose * Point3::new(h.x * f(i, 20), h.y * f(j, 20), h.z * f(k, 4)),
                            );
                        }
                    }
                }
            }
            Part::Wheel { pose, shape } => {
                for i in 0..360 {
                    let a = i as f32 * std::f32::consts::TAU / 360.0;
                    for j in 0..=4 {
                        let y = shape.half_height * (j as f32 / 2.0 - 1.0);
                        points.push(
                            pose * Point3::new(shape.radius * a.cos(), y, shape.radius * a.sin()),
                        );
                    }
                }
            }
        }
        points
    }

    fn point_distance_m(p: &Point3<f32>, aabb: &Aabb) -> f32 {
        (p - bounds::nearest_in_box(p, aabb)).norm()
    }

    /// The proof of the way there (`Env::check_transition`) rests on the clearance never being
    /// above the true distance: robots placed at random near a block, each part's clearance
    /// against the least distance of points in it (an upper bound on its true distance), and
    /// a part with a point inside the block (shrunk by 0.1 mm) must collide. parry's own
    /// distances fail this for capsules and cylinders; what they would have got wrong is
    /// printed (`--nocapture`) for docs/simulator.md.
    #[test]
    fn parts_keep_every_point_s_distance() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let set = ObstacleSet::new(&[Obstacle::new(
            ObstacleKind::Block,
            0.0,
            0.0,
            ObstacleYaw::default(),
        )]);
        let block = set.aabbs[0];
        let shrunk = Aabb::new(
            block.mins + Vector3::repeat(1.0e-4),
            block.maxs - Vector3::repeat(1.0e-4),
        );
        let (mut near, mut inside) = (0, 0);
        // parry's contact distance above the sampled one (links, wheels: pairs, over 1 mm,
        // worst), and its intersection test missing a part that enters.
        let (mut over, mut over_1mm, mut pairs) = ([0; 2], [0; 2], [0; 2]);
        let mut worst_m = [0.0f32; 2];
        let (mut entering, mut missed) = ([0; 2], [0; 2]);
        for _ in 0..3000 {
            let legs = LegConfig {
                clearance_m: rng.random_range(0.08..0.2),
                track_m: WHEELLEG.default_track_m + rng.random_range(-0.05..0.05),
            };
            let at = Point2::new(rng.random_range(-0.5..0.5), rng.random_range(-0.5..0.5));
            let Ok(robot) = RobotParts::new(&WHEELLEG, at, rng.random_range(-3.2..3.2), legs)
            else {
                continue;
            };
            for part in robot.parts() {
                let points = points_of(part, &block);
                let sampled_m = points
                    .iter()
                    .map(|p| point_distance_m(p, &block))
                    .fold(f32::INFINITY, f32::min);
                let enters = points.iter().any(|p| point_distance_m(p, &shrunk) == 0.0);
                let clearance = part.clearance_m(&block, &set.poses[0], &set.shapes[0], 0.1);
                let kind = match part {
                    Part::Link(_) => Some(0),
                    Part::Wheel { .. } => Some(1),
                    Part::Body { .. } => None,
                };
                let (pose, shape) = part.placed();
                if let (Some(k), true) = (kind, enters) {
                    entering[k] += 1;
                    if !query::intersection_test(&pose, shape, &set.poses[0], &set.shapes[0])
                        .unwrap_or(true)
                    {
                        missed[k] += 1;
                    }
                } else if let (Some(k), true) = (kind, sampled_m < 0.05) {
                    pairs[k] += 1;
                    if let Ok(Some(contact)) =
                        query::contact(&pose, shape, &set.poses[0], &set.shapes[0], 0.1)
                    {
                        let excess_m = contact.dist - sampled_m;
                        if excess_m > 1.0e-6 {
                            over[k] += 1;
                        }
                        if excess_m > 1.0e-3 {
                            over_1mm[k] += 1;
                        }
                        worst_m[k] = worst_m[k].max(excess_m);
                    }
                }
                if enters {
                    inside += 1;
                    assert!(
                        clearance.is_none(),
                        "{part:?}: clearance {clearance:?} inside the block"
                    );
                    assert!(
                        part.intersects(&block, &set.poses[0], &set.shapes[0]),
                        "{part:?}"
                    );
                } else if sampled_m < 0.05 {
                    near += 1;
                    if let Some(clearance_m) = clearance {
                        assert!(
                            clearance_m <= sampled_m + 1.0e-6,
                            "{part:?}: clearance {clearance_m} m, a point of it {sampled_m} m away"
                        );
                    }
                }
            }
        }
        for (k, kind) in ["capsule", "cylinder"].iter().enumerate() {
            println!(
                "parry, {kind}/box: contact distance above a point's in {} of {} near pairs \
                 (over 1 mm: {}, worst {:.1} mm); intersection test missed {} of {} entering",
                over[k],
                pairs[k],
                over_1mm[k],
                worst_m[k] * 1.0e3,
                missed[k],
                entering[k],
            );
        }
        assert!(near > 2000 && inside > 500, "{near} near, {inside} inside");
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
