//! The broad phase: the robot's precomputed boxes per yaw and leg configuration, and the cheap
//! box and separating-axis tests that decide most poses and steps without the simulator.

use super::legs::LegLattice;
use super::legs::LEG_COLS;
use super::legs::LEG_ROWS;
use super::moves::Pose;
use crate::collision::Part;
use crate::collision::RobotParts;
use crate::collision::PART_COUNT;
use nalgebra::Point2;
use nalgebra::Vector3;
use parry3d::bounding_volume::{Aabb, BoundingVolume};
use wheelleg_runtime::robot::RobotGeometry;

/// Slack added to precomputed bounding boxes: they are computed at the origin and shifted, which
/// rounds differently from the simulator's boxes computed in place (by ~1e-7 m). Only ever makes
/// the fast path fall back to exact checks.
pub(super) const AABB_SLACK_M: f32 = 1.0e-4;

/// One convex robot part, placed relative to the body centre's ground point.
#[derive(Clone, Copy, Debug)]
pub(super) enum Convex {
    /// A box: centre, unit axes, half extents along them.
    Cuboid {
        centre: Vector3<f32>,
        axes: [Vector3<f32>; 3],
        half: [f32; 3],
    },
    /// A cylinder: centre, unit axle, half length, radius.
    Cylinder {
        centre: Vector3<f32>,
        axle: Vector3<f32>,
        half_length: f32,
        radius: f32,
    },
    /// A capsule: segment end points, radius.
    Capsule {
        a: Vector3<f32>,
        b: Vector3<f32>,
        radius: f32,
    },
}

impl Convex {
    pub(super) fn from_part(part: &Part) -> Self {
        match part {
            Part::Body { pose, shape } => Convex::Cuboid {
                centre: pose.translation.vector,
                axes: [
                    pose.rotation * Vector3::x(),
                    pose.rotation * Vector3::y(),
                    pose.rotation * Vector3::z(),
                ],
                half: shape.half_extents.into(),
            },
            // parry's cylinders stand along their local y axis, here the axle.
            Part::Wheel { pose, shape } => Convex::Cylinder {
                centre: pose.translation.vector,
                axle: pose.rotation * Vector3::y(),
                half_length: shape.half_height,
                radius: shape.radius,
            },
            Part::Link(capsule) => Convex::Capsule {
                a: capsule.segment.a.coords,
                b: capsule.segment.b.coords,
                radius: capsule.radius,
            },
        }
    }

    /// Centre and half width of the part's projection on the unit vector `n`.
    pub(super) fn projection(&self, n: &Vector3<f32>) -> (f32, f32) {
        match self {
            Convex::Cuboid { centre, axes, half } => (
                centre.dot(n),
                (0..3).map(|i| half[i] * axes[i].dot(n).abs()).sum(),
            ),
            Convex::Cylinder {
                centre,
                axle,
                half_length,
                radius,
            } => {
                let along = axle.dot(n);
                (
                    centre.dot(n),
                    half_length * along.abs() + radius * (1.0 - along * along).max(0.0).sqrt(),
                )
            }
            Convex::Capsule { a, b, radius } => {
                (0.5 * (a + b).dot(n), 0.5 * (b - a).dot(n).abs() + radius)
            }
        }
    }
}

impl Convex {
    /// Segments inside the part: for a link its axis, for a wheel its axle and two diameters
    /// of its middle disc (one horizontal, one as near vertical as the axle allows); none for
    /// the body, whose boxes the separating-axis test decides whole.
    fn inner_segments(&self) -> heapless::Vec<(Vector3<f32>, Vector3<f32>), 3> {
        let mut out = heapless::Vec::new();
        match *self {
            Convex::Cuboid { .. } => {}
            Convex::Capsule { a, b, .. } => {
                out.push((a, b)).expect("room for one");
            }
            Convex::Cylinder {
                centre,
                axle,
                half_length,
                radius,
            } => {
                let along = axle * half_length;
                out.push((centre - along, centre + along)).expect("room");
                let across = axle.cross(&Vector3::z());
                if across.norm() > 1.0e-3 {
                    let across = across.normalize();
                    let up = axle.cross(&across);
                    for d in [across, up] {
                        out.push((centre - d * radius, centre + d * radius))
                            .expect("room");
                    }
                }
            }
        }
        out
    }

    /// Whether the part, shifted by `by`, surely meets the box `centre ± half`: a segment
    /// inside the part runs through the box shrunk by `depth_m` on every side. The part then
    /// overlaps the box by at least that much, which an exact intersection test cannot miss.
    pub(super) fn surely_meets(
        &self,
        by: &Vector3<f32>,
        centre: &Vector3<f32>,
        half: &Vector3<f32>,
        depth_m: f32,
    ) -> bool {
        let lo = centre - half.add_scalar(-depth_m) - by;
        let hi = centre + half.add_scalar(-depth_m) - by;
        if (0..3).any(|i| lo[i] >= hi[i]) {
            return false;
        }
        self.inner_segments()
            .iter()
            .any(|(a, b)| segment_meets_box(a, b, &lo, &hi))
    }
}

/// Whether the segment from `a` to `b` meets the box `lo..hi` (Liang-Barsky clipping).
fn segment_meets_box(
    a: &Vector3<f32>,
    b: &Vector3<f32>,
    lo: &Vector3<f32>,
    hi: &Vector3<f32>,
) -> bool {
    let d = b - a;
    let (mut t0, mut t1) = (0.0f32, 1.0f32);
    for i in 0..3 {
        if d[i] == 0.0 {
            if a[i] < lo[i] || a[i] > hi[i] {
                return false;
            }
            continue;
        }
        let (mut near, mut far) = ((lo[i] - a[i]) / d[i], (hi[i] - a[i]) / d[i]);
        if near > far {
            std::mem::swap(&mut near, &mut far);
        }
        t0 = t0.max(near);
        t1 = t1.min(far);
        if t0 > t1 {
            return false;
        }
    }
    true
}

/// An obstacle's box, for the separating-axis filter.
#[derive(Clone, Copy, Debug)]
pub(super) struct ObstacleBox {
    /// As the simulator builds it, loosened by the slack.
    pub(super) aabb: Aabb,
    pub(super) centre: Vector3<f32>,
    pub(super) half: Vector3<f32>,
}

impl ObstacleBox {
    /// The largest gap between the projections of `part`, shifted by `by`, and of this box
    /// over the axes tried (world x, y, z, the body's horizontal axes, a link's horizontal
    /// normal): positive means a separating axis, so they do not touch (both are convex).
    pub(super) fn gap(
        &self,
        part: &Convex,
        by: &Vector3<f32>,
        body_axes: &[Vector3<f32>; 2],
    ) -> f32 {
        let gap = |n: &Vector3<f32>| {
            let (centre, half) = part.projection(n);
            let own = self.half.x * n.x.abs() + self.half.y * n.y.abs() + self.half.z * n.z.abs();
            (centre + by.dot(n) - self.centre.dot(n)).abs() - half - own
        };
        let world = [Vector3::x(), Vector3::y(), Vector3::z()];
        let mut best = world
            .iter()
            .chain(body_axes)
            .map(gap)
            .fold(f32::NEG_INFINITY, f32::max);
        if let Convex::Capsule { a, b, .. } = part {
            let d = b - a;
            let normal = Vector3::new(-d.y, d.x, 0.0);
            if normal.norm() > 1.0e-6 {
                best = best.max(gap(&normal.normalize()));
            }
        }
        best
    }
}

/// The robot's parts at one pose relative to its body centre's ground point, with bounding
/// boxes: the whole robot's, and each part's.
#[derive(Clone, Copy, Debug)]
pub(super) struct PartBoxes {
    pub(super) whole: Aabb,
    pub(super) boxes: [Aabb; PART_COUNT],
    pub(super) parts: [Convex; PART_COUNT],
    /// The body's horizontal axes.
    pub(super) body_axes: [Vector3<f32>; 2],
}

pub(super) fn part_boxes(parts: &RobotParts) -> PartBoxes {
    let convex = parts.parts().map(|p| Convex::from_part(&p));
    let body_axes = match convex[0] {
        Convex::Cuboid { axes, .. } => [axes[0], axes[1]],
        _ => [Vector3::x(), Vector3::y()],
    };
    PartBoxes {
        whole: parts.aabb().loosened(AABB_SLACK_M),
        boxes: parts.parts().map(|p| p.aabb().loosened(AABB_SLACK_M)),
        parts: convex,
        body_axes,
    }
}

/// What the cheap geometric tests can tell about a pose, before the simulator's exact test.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Contact {
    /// Surely touches no obstacle.
    Clear,
    /// Surely collides: the body box, or a segment inside a wheel or link, overlaps an obstacle
    /// box.
    Collides,
    /// Within a hair of touching: only the exact test can tell.
    Unknown,
}

/// Classifies the robot's parts, shifted to `position`, against the obstacles.
///
/// The simulator's exact test only looks at part/obstacle pairs whose boxes meet; for those,
/// a separating axis with room to spare proves the pair apart. The body is a box turned about
/// the vertical only, so against an axis-aligned obstacle box the five axes tried (world x, y,
/// z, body x, y) are all the separating-axis theorem needs: overlap on all five, with room to
/// spare, proves a collision. A wheel or a link proves one when a segment inside it runs through
/// the obstacle box with room to spare ([`Convex::surely_meets`]). Only what neither settles is
/// left to the exact test.
pub(super) fn classify(
    boxes: &PartBoxes,
    position: Point2<f32>,
    obstacles: &[ObstacleBox],
) -> Contact {
    let by = Vector3::new(position.x, position.y, 0.0);
    let whole = shifted(&boxes.whole, position);
    let mut unknown = false;
    for o in obstacles.iter().filter(|o| o.aabb.intersects(&whole)) {
        for (index, (b, part)) in boxes.boxes.iter().zip(&boxes.parts).enumerate() {
            if !o.aabb.intersects(&shifted(b, position)) {
                continue;
            }
            match o.gap(part, &by, &boxes.body_axes) {
                gap if gap > AABB_SLACK_M => {}
                gap if index == 0 && gap < -AABB_SLACK_M => return Contact::Collides,
                _ if part.surely_meets(&by, &o.centre, &o.half, AABB_SLACK_M) => {
                    return Contact::Collides
                }
                _ => unknown = true,
            }
        }
    }
    if unknown {
        Contact::Unknown
    } else {
        Contact::Clear
    }
}

/// The robot's boxes at one yaw, per leg configuration (indexed `row * LEG_COLS + col`) and the
/// whole robot over all of them.
pub(super) struct YawBoxes {
    pub(super) all: Aabb,
    /// Reachable configurations only, in the order of `ordinal`.
    pub(super) per_config: Vec<PartBoxes>,
    /// Index into `per_config` of cell `row * LEG_COLS + col`.
    pub(super) ordinal: Vec<u16>,
}

impl YawBoxes {
    pub(super) fn get(&self, row: usize, col: usize) -> &PartBoxes {
        &self.per_config[self.ordinal[row * LEG_COLS + col] as usize]
    }
}

impl YawBoxes {
    pub(super) fn new(geometry: &RobotGeometry, lattice: &LegLattice, yaw_steps: i32) -> Self {
        let origin = Pose {
            position: Point2::origin(),
            yaw_steps,
        };
        let mut per_config = Vec::with_capacity(LEG_ROWS * LEG_COLS);
        let mut ordinal = vec![u16::MAX; LEG_ROWS * LEG_COLS];
        let mut all = Aabb::new_invalid();
        for (row, col) in lattice.reachable.iter() {
            let state = lattice.state(&origin, row, col);
            let parts = RobotParts::new(
                geometry,
                state.position,
                state.yaw_rad(),
                state.leg_config(geometry),
            )
            .expect("reachable by construction of the lattice");
            let boxes = part_boxes(&parts);
            all.merge(&boxes.whole);
            ordinal[row * LEG_COLS + col] = per_config.len() as u16;
            per_config.push(boxes);
        }
        YawBoxes {
            all,
            per_config,
            ordinal,
        }
    }
}

pub(super) fn shifted(aabb: &Aabb, position: Point2<f32>) -> Aabb {
    let by = Vector3::new(position.x, position.y, 0.0);
    Aabb::new(aabb.mins + by, aabb.maxs + by)
}

/// Half of the most any point of the robot moves in one step, rounded up
/// ([`Env::motion_bound_m`]: a diagonal move 0.071 m, a 5 degree turn at 0.45 m reach 0.04 m,
/// a leg step a few centimetres). The planner looks for obstacles this far around a step's
/// ends; a larger bound is left to the simulator.
pub(super) const SWEEP_GROW_M: f32 = 0.1;

/// Whether some part, grown by `grow_m` around the span of its boxes at the start (`start`
/// shifted to `from`) and at the end (`end` shifted to `to`), meets an obstacle box: the
/// simulator's `ObstacleSet::sweep_may_touch` on the planner's (slightly larger) boxes, so a
/// step this finds clear the simulator accepts without further tests.
pub(super) fn sweep_meets(
    start: &PartBoxes,
    from: Point2<f32>,
    end: &PartBoxes,
    to: Point2<f32>,
    grow_m: f32,
    obstacles: &[ObstacleBox],
) -> bool {
    let whole = shifted(&start.whole, from)
        .merged(&shifted(&end.whole, to))
        .loosened(grow_m);
    obstacles
        .iter()
        .filter(|o| o.aabb.intersects(&whole))
        .any(|o| {
            start.boxes.iter().zip(&end.boxes).any(|(a, b)| {
                shifted(a, from)
                    .merged(&shifted(b, to))
                    .loosened(grow_m)
                    .intersects(&o.aabb)
            })
        })
}
