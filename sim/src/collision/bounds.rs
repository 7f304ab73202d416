//! Cheap lower bounds on the distance between a robot part and an obstacle's box: what culls
//! part/obstacle pairs before parry's exact queries, and what proves a clearance without them.

use nalgebra::{Isometry3, Point3, Vector3};
use parry3d::bounding_volume::Aabb;

/// The point of the box `aabb` nearest to `p` (`p` itself inside).
pub(super) fn nearest_in_box(p: &Point3<f32>, aabb: &Aabb) -> Point3<f32> {
    Point3::from(p.coords.sup(&aabb.mins.coords).inf(&aabb.maxs.coords))
}

/// The distance between two boxes (0 when they overlap).
pub(super) fn box_gap_m(a: &Aabb, b: &Aabb) -> f32 {
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
pub(super) fn segment_box_distance_m(a: &Point3<f32>, b: &Point3<f32>, aabb: &Aabb) -> f32 {
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
pub(super) fn upright_box_distance_m(
    pose: &Isometry3<f32>,
    half: &Vector3<f32>,
    aabb: &Aabb,
) -> f32 {
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
