//! The robot's parts against one map column: the distances and crossings the guard's check is
//! made of.

use crate::leg::LegConfig;
use crate::robot::{LegId, RobotGeometry};
use nalgebra::Point3;

/// The indices in both ranges.
pub(super) fn intersect(
    a: core::ops::Range<usize>,
    b: core::ops::Range<usize>,
) -> core::ops::Range<usize> {
    let start = a.start.max(b.start);
    start..a.end.min(b.end).max(start)
}

/// Overlap the lenient check forgives on top of the current pose's, per column: rounding.
pub(super) const OVERLAP_TOLERANCE_M: f32 = 1.0e-4;

/// A column of the height map in the frame of the robot at the checked pose: a square from the
/// ground up to its height.
pub(super) struct Column {
    pub(super) x_m: f32,
    pub(super) y_m: f32,
    pub(super) half_m: f32,
    pub(super) height_m: f32,
}

/// The robot's parts at one leg configuration, in its own frame with z measured from the ground.
pub(super) struct Parts {
    clearance_m: f32,
    body_half_x_m: f32,
    body_half_y_m: f32,
    /// Per leg: hip, knee, wheel mount and wheel centre.
    legs: [Leg; 4],
    /// Per leg: the box beyond which a column is apart from it ([`Self::leg_is_apart`]).
    leg_boxes: [LegBox; 4],
    link_radius_m: f32,
    wheel_radius_m: f32,
    wheel_half_width_m: f32,
}

/// How far beyond a leg's intervals a column must be for the leg's distances to be skipped:
/// well above their rounding, so that a skipped leg's overlap was surely negative and the
/// verdict (an overlap at or above 0) is the one the distances would give.
const CULL_SLACK_M: f32 = 1.0e-5;

/// The relative slack of the tests that skip a part's distance, likewise well above the
/// distances' rounding.
const SKIP_SLACK: f32 = 1.0e-3;

impl Parts {
    pub(super) fn place(geometry: &RobotGeometry, legs: LegConfig) -> Option<Parts> {
        let joints = geometry.leg_ik(legs).ok()?;
        let centre_height_m = geometry.body_centre_height_m(legs.clearance_m);
        let mut points = [[Point3::origin(); 4]; 4];
        for (slot, leg) in points.iter_mut().zip(LegId::ALL) {
            let p = geometry.leg_points(leg, joints);
            *slot = [p.hip, p.knee, p.wheel_mount, p.wheel]
                .map(|q| Point3::new(q.x, q.y, q.z + centre_height_m));
        }
        // Every point of a leg is in its leg plane, at the hip's x; each box is widened by the
        // larger of a link's and the wheel's reach, and by [`CULL_SLACK_M`]. Worked out once
        // per pose, not per column.
        let reach_x_m = geometry.wheel_radius_m.max(geometry.link_radius_m) + CULL_SLACK_M;
        let reach_y_m = geometry.link_radius_m.max(0.5 * geometry.wheel_width_m) + CULL_SLACK_M;
        let leg_boxes = points.map(|[hip, knee, mount, wheel]| LegBox {
            x_m: hip.x,
            reach_x_m,
            low_y_m: hip.y.min(knee.y).min(mount.y).min(wheel.y) - reach_y_m,
            high_y_m: hip.y.max(knee.y).max(mount.y).max(wheel.y) + reach_y_m,
        });
        Some(Parts {
            clearance_m: legs.clearance_m,
            body_half_x_m: 0.5 * geometry.body_length_m,
            body_half_y_m: 0.5 * geometry.body_width_m,
            legs: points,
            leg_boxes,
            link_radius_m: geometry.link_radius_m,
            wheel_radius_m: geometry.wheel_radius_m,
            wheel_half_width_m: 0.5 * geometry.wheel_width_m,
        })
    }

    /// How deep the deepest part reaches into `column` (0: touching, as the simulator counts
    /// it; negative: apart, and then not exact, as the legs the column is apart from
    /// ([`Self::leg_is_apart`]) are skipped). For the body box it is the least of its overlaps
    /// along x, y and z; for the round parts, radius minus distance.
    pub(super) fn overlap_m(&self, column: &Column) -> f32 {
        let half_m = column.half_m;
        let body_m = (self.body_half_x_m + half_m - column.x_m.abs())
            .min(self.body_half_y_m + half_m - column.y_m.abs())
            .min(column.height_m - self.clearance_m);
        // Most columns near the robot are near one leg at most: the others' thirteen distances
        // would only say they are apart.
        self.legs
            .iter()
            .zip(&self.leg_boxes)
            .filter(|(_, leg_box)| !leg_box.is_apart(column))
            .map(|(leg, _)| self.leg_overlap_m(leg, column))
            .fold(body_m, f32::max)
    }

    /// Whether `column`'s square lies outside the box of leg `index` (its points' y interval
    /// and the hip's x, widened), so that [`Self::leg_overlap_m`] is surely negative.
    #[cfg(test)]
    pub(super) fn leg_is_apart(&self, index: usize, column: &Column) -> bool {
        self.leg_boxes[index].is_apart(column)
    }

    /// The legs' hip, knee, wheel mount and wheel centre.
    #[cfg(test)]
    pub(super) fn legs(&self) -> &[Leg; 4] {
        &self.legs
    }

    /// How deep `leg`'s thigh, shank and wheel reach into `column` (see [`Self::overlap_m`];
    /// negative and then not exact where each part is surely apart).
    pub(super) fn leg_overlap_m(&self, [hip, knee, mount, wheel]: &Leg, column: &Column) -> f32 {
        // A link's distance costs six `hypotf`s and the wheel's one, in double precision (in
        // software on the controller): the links are first tested across the leg plane and
        // the wheel in its own plane, and most columns near a leg are apart from most of it.
        let dx_m = across_m(hip, column);
        let mut deepest_m = f32::NEG_INFINITY;
        if !self.links_are_apart(dx_m) {
            for (a, b) in [(hip, knee), (knee, mount)] {
                deepest_m = deepest_m.max(self.link_overlap_m(a, b, dx_m, column));
            }
        }
        let gaps = self.wheel_gaps(wheel, column);
        if !self.wheel_is_apart(&gaps) {
            deepest_m = deepest_m.max(self.wheel_overlap_m(&gaps));
        }
        deepest_m
    }

    /// How deep the link from `a` to `b` (a capsule in the leg plane, `dx_m` from the column's
    /// square across it: [`across_m`]) reaches into `column`: its radius less its distance.
    pub(super) fn link_overlap_m(
        &self,
        a: &Point3<f32>,
        b: &Point3<f32>,
        dx_m: f32,
        column: &Column,
    ) -> f32 {
        let d_yz_m = segment_rect_distance_m(
            (a.y, a.z),
            (b.y, b.z),
            (column.y_m - column.half_m, 0.0),
            (column.y_m + column.half_m, column.height_m),
        );
        self.link_radius_m - crate::trig::hypot(dx_m, d_yz_m)
    }

    /// Whether a column `dx_m` across from the leg plane is farther from both links than their
    /// radius by more than the rounding. (A test in the leg plane too, by the links' boxes,
    /// spared a fifth of the rest on the controller but did not fit its flash.)
    pub(super) fn links_are_apart(&self, dx_m: f32) -> bool {
        dx_m > self.link_radius_m * (1.0 + SKIP_SLACK)
    }

    /// The gaps between `column` and the wheel (a disc in the x-z plane, as wide as the wheel
    /// along y) centred at `wheel`.
    pub(super) fn wheel_gaps(&self, wheel: &Point3<f32>, column: &Column) -> WheelGaps {
        let dy_m = (column.y_m - wheel.y).abs() - column.half_m;
        WheelGaps {
            side_m: self.wheel_half_width_m - dy_m,
            dx_m: ((column.x_m - wheel.x).abs() - column.half_m).max(0.0),
            dz_m: (wheel.z - column.height_m).max(0.0),
        }
    }

    /// How deep the wheel reaches into the column of `gaps`.
    pub(super) fn wheel_overlap_m(&self, gaps: &WheelGaps) -> f32 {
        gaps.side_m
            .min(self.wheel_radius_m - crate::trig::hypot(gaps.dx_m, gaps.dz_m))
    }

    /// Whether the wheel is apart from the column of `gaps` along its axle, or farther from it
    /// than its radius by more than the rounding in the x-z plane.
    pub(super) fn wheel_is_apart(&self, gaps: &WheelGaps) -> bool {
        let reach_m = self.wheel_radius_m * (1.0 + SKIP_SLACK);
        gaps.side_m < 0.0 || gaps.dx_m * gaps.dx_m + gaps.dz_m * gaps.dz_m > reach_m * reach_m
    }
}

/// Where a leg is, widened by its parts' reach: a column whose square lies outside is apart
/// from every part of the leg.
#[derive(Clone, Copy)]
struct LegBox {
    /// The hip's x: every point of a leg is in its leg plane.
    x_m: f32,
    /// How far a part reaches from the leg plane along x.
    reach_x_m: f32,
    /// The points' y interval, widened.
    low_y_m: f32,
    high_y_m: f32,
}

impl LegBox {
    fn is_apart(&self, column: &Column) -> bool {
        let half_m = column.half_m;
        (column.x_m - self.x_m).abs() - half_m > self.reach_x_m
            || column.y_m + half_m < self.low_y_m
            || column.y_m - half_m > self.high_y_m
    }
}

/// A leg's hip, knee, wheel mount and wheel centre. (The axle between mount and wheel lies
/// within the shank's end and the wheel: [`RobotGeometry::max_wheel_offset_m`].)
pub(super) type Leg = [Point3<f32>; 4];

/// Where a column is from a wheel: its overlap along the axle, and its gaps from the centre
/// along x and down z.
pub(super) struct WheelGaps {
    side_m: f32,
    dx_m: f32,
    dz_m: f32,
}

/// How far `column`'s square is across from the leg plane through `hip` (0 where it meets it).
pub(super) fn across_m(hip: &Point3<f32>, column: &Column) -> f32 {
    ((column.x_m - hip.x).abs() - column.half_m).max(0.0)
}

/// Distance in a plane from the segment `a`-`b` to the axis-aligned rectangle `lo`-`hi` (0 when
/// they meet). Two disjoint convex polygons are nearest at a vertex of one of them, so the
/// distance is the least of the segment's ends to the rectangle and the rectangle's corners to
/// the segment, once a crossing is ruled out.
pub(super) fn segment_rect_distance_m(
    a: (f32, f32),
    b: (f32, f32),
    lo: (f32, f32),
    hi: (f32, f32),
) -> f32 {
    if segment_crosses_rect(a, b, lo, hi) {
        return 0.0;
    }
    let point_to_rect = |p: (f32, f32)| {
        let dx = (lo.0 - p.0).max(p.0 - hi.0).max(0.0);
        let dy = (lo.1 - p.1).max(p.1 - hi.1).max(0.0);
        crate::trig::hypot(dx, dy)
    };
    let point_to_segment = |p: (f32, f32)| {
        let (dx, dy) = (b.0 - a.0, b.1 - a.1);
        let length_sq = dx * dx + dy * dy;
        let t = if length_sq > 0.0 {
            (((p.0 - a.0) * dx + (p.1 - a.1) * dy) / length_sq).clamp(0.0, 1.0)
        } else {
            0.0
        };
        crate::trig::hypot(a.0 + t * dx - p.0, a.1 + t * dy - p.1)
    };
    let corners = [lo, (hi.0, lo.1), hi, (lo.0, hi.1)];
    corners
        .into_iter()
        .map(point_to_segment)
        .chain([a, b].into_iter().map(point_to_rect))
        .fold(f32::INFINITY, f32::min)
}

/// Whether the segment `a`-`b` has a point in the closed rectangle `lo`-`hi` (Liang-Barsky
/// clipping: the parameter interval left after each slab must stay non-empty).
pub(super) fn segment_crosses_rect(
    a: (f32, f32),
    b: (f32, f32),
    lo: (f32, f32),
    hi: (f32, f32),
) -> bool {
    let (mut t0, mut t1) = (0.0f32, 1.0f32);
    for (start, delta, min, max) in [(a.0, b.0 - a.0, lo.0, hi.0), (a.1, b.1 - a.1, lo.1, hi.1)] {
        if delta == 0.0 {
            if start < min || start > max {
                return false;
            }
            continue;
        }
        let (mut enter, mut leave) = ((min - start) / delta, (max - start) / delta);
        if enter > leave {
            core::mem::swap(&mut enter, &mut leave);
        }
        t0 = t0.max(enter);
        t1 = t1.min(leave);
        if t0 > t1 {
            return false;
        }
    }
    true
}
