//! What a robot's geometry allows: the poses it can command and the passages they open.
//!
//! Poses are the ones the policy can reach: the default pose and every (clearance, track) pair a
//! run of clearance and track steps leads to through poses with a leg solution. Passages are
//! worked out on the legs' cross-section (body box, link capsules, wheel cylinders), exactly,
//! before any margin a scene generator adds.

use crate::description::RobotDescription;
use serde::Serialize;
use std::collections::{HashSet, VecDeque};
use wheelleg_runtime::leg::LegConfig;
use wheelleg_runtime::robot::{LegId, RobotGeometry};

/// One pose on the action lattice, as the policy commands it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Pose {
    /// Ground to body underside.
    pub clearance_m: f32,
    /// Wheel centre to wheel centre.
    pub track_m: f32,
}

/// A passage and the pose that opens it.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Passage {
    /// How wide (gap, slab) or free (bar's width) the passage is, in metres.
    pub width_m: f32,
    /// How high the obstacle under the body may be (bar, slab), in metres; for a gap, how tall
    /// the robot stands in it.
    pub height_m: f32,
    /// The pose.
    pub pose: Pose,
}

/// What the robot's geometry allows.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Reach {
    /// The robot's name.
    pub robot: String,
    /// Poses on the lattice reachable from the default pose.
    pub lattice_poses: usize,
    /// Lowest and highest clearance among them.
    pub clearance_m: [f32; 2],
    /// Narrowest and widest track among them.
    pub track_m: [f32; 2],
    /// The default pose.
    pub default_pose: Pose,
    /// The default pose's width across its widest part (what a gap must exceed without a
    /// squeeze).
    pub default_width_m: f32,
    /// The default pose's free height and width under the body, between the wheels.
    pub default_tunnel: Passage,
    /// The tallest bar the body can be lifted over (free height under the body, and the free
    /// width between the legs at that pose).
    pub lift: Passage,
    /// The widest slab the legs can straddle (free width between the wheels, and the free
    /// height under the body at that pose).
    pub spread: Passage,
    /// The narrowest gap the robot fits through (its widest part at that pose, and its height).
    pub squeeze: Passage,
    /// The five behaviours of the paper, each with whether this robot has it.
    pub behaviours: Vec<Behaviour>,
}

/// One behaviour and whether the robot has it.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Behaviour {
    /// `straight`, `around`, `lift`, `spread` or `squeeze`.
    pub name: &'static str,
    /// Whether the geometry allows it.
    pub available: bool,
    /// Why, in figures.
    pub reason: String,
}

/// The poses reachable from the default pose by clearance and track steps.
pub fn lattice_poses(description: &RobotDescription) -> Vec<Pose> {
    let g = &description.robot.geometry;
    let a = &description.robot.actions;
    let pose = |(c, t): (i32, i32)| Pose {
        clearance_m: g.default_clearance_m + c as f32 * a.clearance_step_m,
        track_m: g.default_track_m + t as f32 * a.track_step_m,
    };
    let reachable = |p: Pose| {
        g.is_reachable(LegConfig {
            clearance_m: p.clearance_m,
            track_m: p.track_m,
        })
    };
    let mut seen = HashSet::new();
    let mut queue = VecDeque::new();
    let mut poses = Vec::new();
    if reachable(pose((0, 0))) {
        seen.insert((0, 0));
        queue.push_back((0, 0));
    }
    while let Some(at) = queue.pop_front() {
        poses.push(pose(at));
        for (dc, dt) in [(1, 0), (-1, 0), (0, 1), (0, -1)] {
            let next = (at.0 + dc, at.1 + dt);
            // The ranges bound the lattice; the guard against a runaway walk is the IK's
            // range check, which refuses anything outside them.
            if !seen.contains(&next) && reachable(pose(next)) {
                seen.insert(next);
                queue.push_back(next);
            }
        }
    }
    poses
}

/// The legs' cross-section at a pose, in the leg plane of a left leg: `y` outward from the
/// body's centre line, `z` up from the ground.
struct Section {
    body_half_width_m: f32,
    underside_m: f32,
    /// Link capsules as (start, end) points and their radius.
    links: [([f32; 2], [f32; 2]); 2],
    link_radius_m: f32,
    wheel_inner_m: f32,
    wheel_outer_m: f32,
    wheel_top_m: f32,
}

impl Section {
    fn at(g: &RobotGeometry, pose: Pose) -> Option<Section> {
        let config = LegConfig {
            clearance_m: pose.clearance_m,
            track_m: pose.track_m,
        };
        let joints = g.leg_ik(config).ok()?;
        let points = g.leg_points(LegId::FrontLeft, joints);
        let ground_z = -g.body_centre_height_m(pose.clearance_m);
        let yz = |p: nalgebra::Point3<f32>| [p.y, p.z - ground_z];
        Some(Section {
            body_half_width_m: 0.5 * g.body_width_m,
            underside_m: pose.clearance_m,
            links: [
                (yz(points.hip), yz(points.knee)),
                (yz(points.knee), yz(points.wheel_mount)),
            ],
            link_radius_m: g.link_radius_m,
            wheel_inner_m: points.wheel.y - 0.5 * g.wheel_width_m,
            wheel_outer_m: points.wheel.y + 0.5 * g.wheel_width_m,
            wheel_top_m: 2.0 * g.wheel_radius_m,
        })
    }

    /// Points along the links, 2,000 a link: a capsule's extreme within 0.1 mm on a 0.2 m
    /// link.
    fn link_points(&self) -> impl Iterator<Item = [f32; 2]> + '_ {
        const N: usize = 2_000;
        self.links.iter().flat_map(|&(a, b)| {
            (0..=N).map(move |i| {
                let s = i as f32 / N as f32;
                [a[0] + s * (b[0] - a[0]), a[1] + s * (b[1] - a[1])]
            })
        })
    }

    /// Half the robot's width across its widest part.
    fn outer_half_width_m(&self) -> f32 {
        let links = self
            .link_points()
            .map(|p| p[0] + self.link_radius_m)
            .fold(f32::NEG_INFINITY, f32::max);
        self.body_half_width_m.max(links).max(self.wheel_outer_m)
    }

    /// Half the free width under the body: between the wheels and any part of the links that
    /// comes below the body's underside.
    fn tunnel_half_width_m(&self) -> f32 {
        let links = self
            .link_points()
            .filter(|p| p[1] - self.link_radius_m < self.underside_m)
            .map(|p| p[0] - self.link_radius_m)
            .fold(f32::INFINITY, f32::min);
        let wheels = if self.wheel_top_m > 0.0 {
            self.wheel_inner_m
        } else {
            f32::INFINITY
        };
        links.min(wheels).max(0.0)
    }

    /// The tunnel's free height: the body's underside, or lower where a link dips inside the
    /// tunnel's half width `half` above the ground.
    fn tunnel_height_m(&self, half: f32) -> f32 {
        self.link_points()
            .filter(|p| p[0] - self.link_radius_m < half)
            .map(|p| p[1] - self.link_radius_m)
            .fold(self.underside_m, f32::min)
            .max(0.0)
    }

    fn height_m(&self, g: &RobotGeometry) -> f32 {
        self.underside_m + g.body_thickness_m
    }
}

/// What `description`'s geometry allows.
pub fn reach(description: &RobotDescription) -> Reach {
    let g = &description.robot.geometry;
    let poses = lattice_poses(description);
    let default_pose = Pose {
        clearance_m: g.default_clearance_m,
        track_m: g.default_track_m,
    };
    let sections: Vec<(Pose, Section)> = poses
        .iter()
        .filter_map(|&p| Some((p, Section::at(g, p)?)))
        .collect();
    let span = |f: fn(&Pose) -> f32| {
        poses
            .iter()
            .map(f)
            .fold([f32::INFINITY, f32::NEG_INFINITY], |s, v| {
                [s[0].min(v), s[1].max(v)]
            })
    };
    let tunnel = |(pose, s): &(Pose, Section)| {
        let half = s.tunnel_half_width_m();
        Passage {
            width_m: 2.0 * half,
            height_m: s.tunnel_height_m(half),
            pose: *pose,
        }
    };
    let gap = |(pose, s): &(Pose, Section)| Passage {
        width_m: 2.0 * s.outer_half_width_m(),
        height_m: s.height_m(g),
        pose: *pose,
    };
    let default = sections
        .iter()
        .find(|(p, _)| *p == default_pose)
        .or(sections.first());
    let empty = Passage {
        width_m: 0.0,
        height_m: 0.0,
        pose: default_pose,
    };
    let default_tunnel = default.map(tunnel).unwrap_or(empty);
    let default_gap = default.map(gap).unwrap_or(empty);
    // Ties go to the wider (lift) or taller (spread, squeeze) passage.
    fn best(
        passages: impl Iterator<Item = Passage>,
        key: fn(&Passage) -> (f32, f32),
    ) -> Option<Passage> {
        passages.reduce(|a, b| if key(&b) > key(&a) { b } else { a })
    }
    let lift = best(sections.iter().map(tunnel), |p| (p.height_m, p.width_m)).unwrap_or(empty);
    let spread = best(sections.iter().map(tunnel), |p| (p.width_m, p.height_m)).unwrap_or(empty);
    let squeeze = best(sections.iter().map(gap), |p| (-p.width_m, p.height_m)).unwrap_or(empty);
    let mm = |v: f32| v * 1000.0;
    let behaviours = vec![
        Behaviour {
            name: "straight",
            available: !poses.is_empty(),
            reason: "drives on its wheels in the default pose".into(),
        },
        Behaviour {
            name: "around",
            available: !poses.is_empty(),
            reason: "turns and drives sideways in the default pose".into(),
        },
        Behaviour {
            name: "lift",
            available: lift.height_m > default_tunnel.height_m,
            reason: format!(
                "free height under the body {:.0} mm lifted against {:.0} mm in the default pose",
                mm(lift.height_m),
                mm(default_tunnel.height_m)
            ),
        },
        Behaviour {
            name: "spread",
            available: spread.width_m > default_tunnel.width_m,
            reason: format!(
                "free width between the wheels {:.0} mm spread against {:.0} mm in the default pose",
                mm(spread.width_m),
                mm(default_tunnel.width_m)
            ),
        },
        Behaviour {
            name: "squeeze",
            available: squeeze.width_m < default_gap.width_m,
            reason: format!(
                "{:.0} mm wide squeezed against {:.0} mm in the default pose",
                mm(squeeze.width_m),
                mm(default_gap.width_m)
            ),
        },
    ];
    Reach {
        robot: description.name.clone(),
        lattice_poses: poses.len(),
        clearance_m: span(|p| p.clearance_m),
        track_m: span(|p| p.track_m),
        default_pose,
        default_width_m: default_gap.width_m,
        default_tunnel,
        lift,
        spread,
        squeeze,
        behaviours,
    }
}

impl Reach {
    /// The report as a person reads it.
    pub fn to_text(&self) -> String {
        let mm = |v: f32| v * 1000.0;
        let pose = |p: Pose| {
            format!(
                "clearance {:.0} mm, track {:.0} mm",
                mm(p.clearance_m),
                mm(p.track_m)
            )
        };
        let mut out = format!(
            "robot:           {}\n\
             lattice poses:   {} reachable from the default pose ({})\n\
             clearance:       {:.0} to {:.0} mm\n\
             track:           {:.0} to {:.0} mm\n\
             default pose:    {:.0} mm wide; under the body {:.0} mm free height, {:.0} mm free width\n\
             lift over:       a bar up to {:.0} mm high and {:.0} mm wide ({})\n\
             spread over:     a slab up to {:.0} mm wide and {:.0} mm high ({})\n\
             squeeze through: a gap wider than {:.0} mm, {:.0} mm tall ({})\n\
             behaviours:\n",
            self.robot,
            self.lattice_poses,
            pose(self.default_pose),
            mm(self.clearance_m[0]),
            mm(self.clearance_m[1]),
            mm(self.track_m[0]),
            mm(self.track_m[1]),
            mm(self.default_width_m),
            mm(self.default_tunnel.height_m),
            mm(self.default_tunnel.width_m),
            mm(self.lift.height_m),
            mm(self.lift.width_m),
            pose(self.lift.pose),
            mm(self.spread.width_m),
            mm(self.spread.height_m),
            pose(self.spread.pose),
            mm(self.squeeze.width_m),
            mm(self.squeeze.height_m),
            pose(self.squeeze.pose),
        );
        for b in &self.behaviours {
            out.push_str(&format!(
                "  {:<9} {}  {}\n",
                b.name,
                if b.available { "yes" } else { "no " },
                b.reason
            ));
        }
        out.push_str("(exact figures on the legs' cross-section, before any margin)\n");
        out
    }
}
