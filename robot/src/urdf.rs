//! URDF in and out: the format robots are already described in.
//!
//! **In** ([`import`]): a robot of the paper's kind. Its root link's collision box is the body;
//! four legs hang off it, mirrored left and right and front and rear, each a chain of three
//! revolute joints (hip, knee, wheel mount) whose axes are parallel to the body's x axis, ending
//! in a continuous wheel joint whose axis is parallel to body y. At zero joint angles a leg lies
//! straight along the outward horizontal at the body's mid-height (the description's zero
//! angles). Lengths come from the joint origins, the wheel from the wheel link's collision
//! cylinder, the link radius from the thigh's and shank's collision cylinders or capsules, the
//! ranges from the joint limits; an axis may point either way round. Fixed joints to links that
//! carry nothing movable (sensors, covers) are ignored. Anything else is refused with the joint
//! or link named and the rule it breaks.
//!
//! What URDF has no field for (the commanded pose's ranges, the action lattice, the CAN bus)
//! comes from the file's own `<wheelleg>` element where [`export`] wrote one, and otherwise
//! takes the documented defaults: pose ranges the joint limits reach, rounded inward to the
//! centimetre, the default pose at their middle on the lattice, the paper's action lattice and
//! the shipped robot's CAN map (nodes 1 to 16, joints 9:1, right wheels reversed), which the
//! user edits in the written TOML.
//!
//! **Out** ([`export`]): the description as a URDF that RViz, MuJoCo and Isaac Lab load, with
//! nominal masses (uniform density 1,000 kg/m³, not the robot's) so that simulators accept it.

use crate::description::{
    ActionKeys, BodyKeys, CanKeys, DescriptionFile, LegKeys, PoseKeys, RobotDescription, WheelKeys,
};
use crate::validate::validate;
use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use std::collections::HashMap;
use wheelleg_runtime::leg::LegConfig;
use wheelleg_runtime::robot::LegId;

/// Tolerance on directions and on the legs' mirror symmetry: a micrometre, or a micro-radian.
const TOLERANCE: f64 = 1e-6;

/// Nominal density of the exported masses, kg/m³.
const NOMINAL_DENSITY_KG_PER_M3: f64 = 1000.0;

/// Why a URDF was refused.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct UrdfError(pub String);

impl std::fmt::Display for UrdfError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for UrdfError {}

fn refuse<T>(message: impl Into<String>) -> Result<T, UrdfError> {
    Err(UrdfError(message.into()))
}

fn isometry(origin: &urdf_rs::Pose) -> Isometry3<f64> {
    let [x, y, z] = origin.xyz.0;
    let [r, p, yaw] = origin.rpy.0;
    Isometry3::from_parts(
        Translation3::new(x, y, z),
        UnitQuaternion::from_euler_angles(r, p, yaw),
    )
}

fn parallel(a: &Vector3<f64>, b: &Vector3<f64>) -> bool {
    a.norm() > 0.0 && a.normalize().cross(&b.normalize()).norm() < TOLERANCE
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= TOLERANCE * a.abs().max(b.abs()).max(1.0)
}

/// One leg as read from its chain.
#[derive(Clone, Debug)]
struct LegRead {
    hip_name: String,
    fore: f64,
    side: f64,
    hip_x_m: f64,
    hip_y_m: f64,
    thigh_m: f64,
    shank_m: f64,
    link_radius_m: f64,
    hip_range_rad: [f64; 2],
    knee_range_rad: [f64; 2],
    wheel_radius_m: f64,
    wheel_width_m: f64,
    wheel_offset_m: f64,
}

struct Tree<'a> {
    urdf: &'a urdf_rs::Robot,
    links: HashMap<&'a str, &'a urdf_rs::Link>,
}

impl<'a> Tree<'a> {
    /// A link's joints that move something: revolute, continuous and the rest, but not a fixed
    /// joint to a link that carries nothing movable.
    fn moving_children(&self, link: &str) -> Vec<&'a urdf_rs::Joint> {
        self.urdf
            .joints
            .iter()
            .filter(|j| j.parent.link == link)
            .filter(|j| j.joint_type != urdf_rs::JointType::Fixed || self.moves(&j.child.link))
            .collect()
    }

    fn moves(&self, link: &str) -> bool {
        self.urdf
            .joints
            .iter()
            .filter(|j| j.parent.link == link)
            .any(|j| j.joint_type != urdf_rs::JointType::Fixed || self.moves(&j.child.link))
    }

    fn link(&self, name: &str) -> Result<&'a urdf_rs::Link, UrdfError> {
        match self.links.get(name) {
            Some(link) => Ok(link),
            None => refuse(format!(
                "link '{name}' is a joint's child but is not defined"
            )),
        }
    }

    /// The one moving joint below `link`, of type `kind`.
    fn next(
        &self,
        link: &str,
        role: &str,
        kind: urdf_rs::JointType,
    ) -> Result<&'a urdf_rs::Joint, UrdfError> {
        let children = self.moving_children(link);
        let [joint] = children.as_slice() else {
            return refuse(format!(
                "link '{link}' carries {} moving joints where a leg's {role} joint should be the only one",
                children.len()
            ));
        };
        if joint.joint_type != kind {
            return refuse(format!(
                "joint '{}' ({role}) is {:?}; a leg's {role} joint is {kind:?}",
                joint.name, joint.joint_type
            ));
        }
        Ok(joint)
    }
}

fn link_radius(link: &urdf_rs::Link) -> Option<f64> {
    link.collision.iter().find_map(|c| match c.geometry {
        urdf_rs::Geometry::Cylinder { radius, .. } | urdf_rs::Geometry::Capsule { radius, .. } => {
            Some(radius)
        }
        _ => None,
    })
}

/// The limits of a revolute joint as the description's angle: `k` is +1 where the joint's
/// positive turn is the description's (thigh or shank further below the outward horizontal),
/// -1 where the axis points the other way round.
fn limits(joint: &urdf_rs::Joint, k: f64) -> Result<[f64; 2], UrdfError> {
    let (lo, hi) = (joint.limit.lower, joint.limit.upper);
    if !(lo.is_finite() && hi.is_finite() && lo < hi) {
        return refuse(format!(
            "joint '{}' has limits [{lo}, {hi}]; a leg joint needs finite limits, lower below upper",
            joint.name
        ));
    }
    Ok(if k > 0.0 { [lo, hi] } else { [-hi, -lo] })
}

fn read_leg(
    tree: &Tree,
    hip: &urdf_rs::Joint,
    body: &Isometry3<f64>,
) -> Result<LegRead, UrdfError> {
    let frame_hip = body.inverse() * isometry(&hip.origin);
    let p = frame_hip.translation.vector;
    if p.z.abs() > TOLERANCE {
        return refuse(format!(
            "joint '{}' is {:.4} m above the body box's centre; the hips must sit at the body's mid-height",
            hip.name, p.z
        ));
    }
    if p.x.abs() <= TOLERANCE {
        return refuse(format!(
            "joint '{}' is on the body's y-z plane; the legs stand in front of and behind it",
            hip.name
        ));
    }
    let (fore, side) = (p.x.signum(), if p.y < 0.0 { -1.0 } else { 1.0 });
    let outward = Vector3::new(0.0, side, 0.0);
    let x_axis = Vector3::x();
    // Each revolute joint: axis parallel to body x; the description's sign of its angle.
    let sign = |joint: &urdf_rs::Joint, frame: &Isometry3<f64>| -> Result<f64, UrdfError> {
        let axis = frame.rotation * Vector3::from(joint.axis.xyz.0);
        if !parallel(&axis, &x_axis) {
            return refuse(format!(
                "joint '{}' turns about ({:.3}, {:.3}, {:.3}) in the body frame; a leg joint turns about the body's x axis",
                joint.name, axis.x, axis.y, axis.z
            ));
        }
        // A positive turn about s * x takes the outward direction (side * y) up when
        // s * side > 0; the description's angles turn it down.
        Ok(-axis.x.signum() * side)
    };
    let straight = |joint: &urdf_rs::Joint, parent: &Isometry3<f64>, what: &str| {
        let along = parent.rotation * Vector3::from(joint.origin.xyz.0);
        let length = Vector3::from(joint.origin.xyz.0).norm();
        if length <= TOLERANCE || !parallel(&along, &outward) || along.dot(&outward) <= 0.0 {
            return refuse(format!(
                "joint '{}' sits at ({:.4}, {:.4}, {:.4}) from the {what}'s joint in the body frame; at zero angles a leg lies straight along the outward horizontal",
                joint.name, along.x, along.y, along.z
            ));
        }
        Ok(length)
    };
    let k_hip = sign(hip, &frame_hip)?;
    let thigh_link = tree.link(&hip.child.link)?;
    let knee = tree.next(&hip.child.link, "knee", urdf_rs::JointType::Revolute)?;
    let thigh_m = straight(knee, &frame_hip, "hip")?;
    let frame_knee = frame_hip * isometry(&knee.origin);
    let k_knee = sign(knee, &frame_knee)?;
    let shank_link = tree.link(&knee.child.link)?;
    let mount = tree.next(
        &knee.child.link,
        "wheel mount",
        urdf_rs::JointType::Revolute,
    )?;
    let shank_m = straight(mount, &frame_knee, "knee")?;
    let frame_mount = frame_knee * isometry(&mount.origin);
    sign(mount, &frame_mount)?;
    let wheel = tree.next(&mount.child.link, "wheel", urdf_rs::JointType::Continuous)?;
    // The wheel may sit along its axle from the mount (body y at zero angles), not across it.
    let offset = frame_mount.rotation * Vector3::from(wheel.origin.xyz.0);
    let wheel_offset_m = offset.dot(&outward);
    if (offset - outward * wheel_offset_m).norm() > TOLERANCE {
        return refuse(format!(
            "joint '{}' sits at ({:.4}, {:.4}, {:.4}) from the wheel mount's joint in the body frame; the wheel turns on the mount's axle, offset along it (body y) only",
            wheel.name, offset.x, offset.y, offset.z
        ));
    }
    let frame_wheel = frame_mount * isometry(&wheel.origin);
    let wheel_axis = frame_wheel.rotation * Vector3::from(wheel.axis.xyz.0);
    if !parallel(&wheel_axis, &Vector3::y()) {
        return refuse(format!(
            "joint '{}' turns about ({:.3}, {:.3}, {:.3}) in the body frame; a wheel turns about the body's y axis",
            wheel.name, wheel_axis.x, wheel_axis.y, wheel_axis.z
        ));
    }
    let wheel_link = tree.link(&wheel.child.link)?;
    if !tree.moving_children(&wheel.child.link).is_empty() {
        return refuse(format!(
            "link '{}' (a wheel) carries moving joints; a leg ends at its wheel",
            wheel_link.name
        ));
    }
    let (wheel_radius_m, wheel_width_m) = wheel_link
        .collision
        .iter()
        .find_map(|c| match c.geometry {
            urdf_rs::Geometry::Cylinder { radius, length } => {
                let axis = frame_wheel.rotation * isometry(&c.origin).rotation * Vector3::z();
                parallel(&axis, &Vector3::y()).then_some((radius, length))
            }
            _ => None,
        })
        .ok_or_else(|| {
            UrdfError(format!(
                "link '{}' has no collision cylinder along the body's y axis; the wheel's radius and width come from it",
                wheel_link.name
            ))
        })?;
    let radii = [link_radius(thigh_link), link_radius(shank_link)];
    let link_radius_m = radii
        .iter()
        .flatten()
        .fold(None, |m: Option<f64>, &r| Some(m.map_or(r, |m| m.max(r))));
    let Some(link_radius_m) = link_radius_m else {
        return refuse(format!(
            "links '{}' and '{}' have no collision cylinder or capsule; the legs' link radius comes from them",
            thigh_link.name, shank_link.name
        ));
    };
    Ok(LegRead {
        hip_name: hip.name.clone(),
        fore,
        side,
        hip_x_m: p.x.abs(),
        hip_y_m: p.y.abs(),
        thigh_m,
        shank_m,
        link_radius_m,
        hip_range_rad: limits(hip, k_hip)?,
        knee_range_rad: limits(knee, k_knee)?,
        wheel_radius_m,
        wheel_width_m,
        wheel_offset_m,
    })
}

/// Reads a URDF's text into a checked description, named after the URDF's robot (characters a
/// description name cannot hold become `_`).
pub fn import(text: &str) -> Result<RobotDescription, UrdfError> {
    let urdf = urdf_rs::read_from_string(text)
        .map_err(|e| UrdfError(format!("not a URDF this reader understands: {e}")))?;
    let links: HashMap<&str, &urdf_rs::Link> =
        urdf.links.iter().map(|l| (l.name.as_str(), l)).collect();
    let tree = Tree { urdf: &urdf, links };
    let roots: Vec<&urdf_rs::Link> = urdf
        .links
        .iter()
        .filter(|l| !urdf.joints.iter().any(|j| j.child.link == l.name))
        .collect();
    let [root] = roots.as_slice() else {
        return refuse(format!(
            "the URDF has {} root links; a robot has one, its body",
            roots.len()
        ));
    };
    let (size, body) = root
        .collision
        .iter()
        .find_map(|c| match &c.geometry {
            urdf_rs::Geometry::Box { size } => Some((size.0, isometry(&c.origin))),
            _ => None,
        })
        .ok_or_else(|| {
            UrdfError(format!(
                "link '{}' (the root, the body) has no collision box; the body's size comes from it",
                root.name
            ))
        })?;
    if body.rotation.angle() > TOLERANCE {
        return refuse(format!(
            "link '{}': the body's collision box is rotated; its edges must lie along the body frame's axes",
            root.name
        ));
    }
    let hips = tree.moving_children(&root.name);
    if hips.len() != 4 {
        return refuse(format!(
            "link '{}' (the body) carries {} moving joints; a robot of this kind has four hips",
            root.name,
            hips.len()
        ));
    }
    let mut legs = Vec::new();
    for hip in hips {
        if hip.joint_type != urdf_rs::JointType::Revolute {
            return refuse(format!(
                "joint '{}' (a hip) is {:?}; a leg's hip joint is Revolute",
                hip.name, hip.joint_type
            ));
        }
        legs.push(read_leg(&tree, hip, &body)?);
    }
    let Some(first) = legs.first().cloned() else {
        return refuse("the body carries no legs");
    };
    for (fore, side) in [(1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)] {
        let count = legs
            .iter()
            .filter(|l| l.fore == fore && l.side == side)
            .count();
        if count != 1 {
            let corner = match (fore > 0.0, side > 0.0) {
                (true, true) => "front left",
                (true, false) => "front right",
                (false, true) => "rear left",
                (false, false) => "rear right",
            };
            return refuse(format!(
                "{count} hips at the body's {corner}; a robot of this kind has one leg at each corner"
            ));
        }
    }
    for leg in &legs {
        let pairs = [
            ("hip x", leg.hip_x_m, first.hip_x_m),
            ("hip y", leg.hip_y_m, first.hip_y_m),
            ("thigh length", leg.thigh_m, first.thigh_m),
            ("shank length", leg.shank_m, first.shank_m),
            ("link radius", leg.link_radius_m, first.link_radius_m),
            (
                "hip lower limit",
                leg.hip_range_rad[0],
                first.hip_range_rad[0],
            ),
            (
                "hip upper limit",
                leg.hip_range_rad[1],
                first.hip_range_rad[1],
            ),
            (
                "knee lower limit",
                leg.knee_range_rad[0],
                first.knee_range_rad[0],
            ),
            (
                "knee upper limit",
                leg.knee_range_rad[1],
                first.knee_range_rad[1],
            ),
            ("wheel radius", leg.wheel_radius_m, first.wheel_radius_m),
            ("wheel width", leg.wheel_width_m, first.wheel_width_m),
            ("wheel offset", leg.wheel_offset_m, first.wheel_offset_m),
        ];
        if let Some((what, a, b)) = pairs.iter().find(|(_, a, b)| !close(*a, *b)) {
            return refuse(format!(
                "the legs of joints '{}' and '{}' are not mirror images: {what} {a} against {b}",
                leg.hip_name, first.hip_name
            ));
        }
    }
    let own = own_element(text)?;
    let shipped = DescriptionFile::from_description(&RobotDescription::shipped());
    let name = if valid_name(&urdf.name) {
        urdf.name.clone()
    } else {
        urdf.name
            .chars()
            .map(|c| {
                if c.is_ascii_alphanumeric() || c == '-' {
                    c
                } else {
                    '_'
                }
            })
            .collect()
    };
    let mut file = DescriptionFile {
        name,
        body: BodyKeys {
            length_m: size[0],
            width_m: size[1],
            thickness_m: size[2],
        },
        legs: LegKeys {
            hip_x_m: first.hip_x_m,
            hip_y_m: first.hip_y_m,
            thigh_m: first.thigh_m,
            shank_m: first.shank_m,
            link_radius_m: first.link_radius_m,
            hip_range_rad: first.hip_range_rad,
            knee_range_rad: first.knee_range_rad,
        },
        wheels: WheelKeys {
            radius_m: first.wheel_radius_m,
            width_m: first.wheel_width_m,
            offset_m: first.wheel_offset_m,
        },
        pose: PoseKeys {
            clearance_range_m: [0.0, 0.0],
            track_range_m: [0.0, 0.0],
            default_clearance_m: 0.0,
            default_track_m: 0.0,
        },
        // The shipped robot's lattice and CAN map: the documented defaults the user edits.
        actions: shipped.actions,
        can: shipped.can,
    };
    match own {
        Some(own) => {
            file.pose = own.pose;
            file.actions = own.actions;
            file.can = own.can;
        }
        None => file.pose = default_pose(&file)?,
    }
    validate(&file).map_err(|e| UrdfError(format!("the description read from the URDF: {e}")))?;
    RobotDescription::from_toml(&toml::to_string(&file).unwrap_or_default())
        .map_err(|e| UrdfError(format!("the description read from the URDF: {e}")))
}

fn valid_name(name: &str) -> bool {
    !name.is_empty()
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
}

/// The tables of `<wheelleg>` that URDF has no field for.
#[derive(serde::Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
struct OwnElement {
    pose: PoseKeys,
    actions: ActionKeys,
    can: CanKeys,
}

fn own_element(text: &str) -> Result<Option<OwnElement>, UrdfError> {
    let doc = roxmltree::Document::parse(text)
        .map_err(|e| UrdfError(format!("not well-formed XML: {e}")))?;
    let Some(node) = doc
        .root_element()
        .children()
        .find(|n| n.has_tag_name("wheelleg"))
    else {
        return Ok(None);
    };
    let body = node.text().unwrap_or_default();
    toml::from_str(body)
        .map(Some)
        .map_err(|e| UrdfError(format!("the <wheelleg> element: {e}")))
}

/// The pose ranges the joint limits reach, rounded inward to the centimetre, and the default
/// pose at the lattice point nearest their middle that the legs reach.
fn default_pose(file: &DescriptionFile) -> Result<PoseKeys, UrdfError> {
    let mut probe = file.clone();
    // Wide ranges, so that only the joint limits and the legs' reach bound the search.
    let reach_m = file.legs.thigh_m + file.legs.shank_m;
    probe.pose = PoseKeys {
        clearance_range_m: [1e-3, reach_m + file.wheels.radius_m],
        track_range_m: [
            file.wheels.width_m + 1e-3,
            2.0 * (file.legs.hip_y_m + reach_m),
        ],
        default_clearance_m: 0.0,
        default_track_m: 0.0,
    };
    let g = probe.geometry();
    let cm = |i: i32| f64::from(i) / 100.0;
    let mut reachable = Vec::new();
    for c in 1..=((g.clearance_range_m[1] * 100.0) as i32) {
        for t in 1..=((g.track_range_m[1] * 100.0) as i32) {
            let config = LegConfig {
                clearance_m: cm(c) as f32,
                track_m: cm(t) as f32,
            };
            if cm(t) > file.wheels.width_m && g.is_reachable(config) {
                reachable.push((c, t));
            }
        }
    }
    let span = |f: fn(&(i32, i32)) -> i32| {
        let lo = reachable.iter().map(f).min();
        let hi = reachable.iter().map(f).max();
        lo.zip(hi)
    };
    let (Some(c), Some(t)) = (span(|p| p.0), span(|p| p.1)) else {
        return refuse(
            "the legs reach no pose within their joint limits: the wheels cannot stand on the ground",
        );
    };
    let middle = ((c.0 + c.1) / 2, (t.0 + t.1) / 2);
    let default = reachable
        .iter()
        .min_by_key(|p| (p.0 - middle.0).pow(2) + (p.1 - middle.1).pow(2))
        .copied()
        .unwrap_or(middle);
    Ok(PoseKeys {
        clearance_range_m: [cm(c.0), cm(c.1)],
        track_range_m: [cm(t.0), cm(t.1)],
        default_clearance_m: cm(default.0),
        default_track_m: cm(default.1),
    })
}

fn leg_prefix(leg: LegId) -> &'static str {
    match leg {
        LegId::FrontLeft => "front_left",
        LegId::FrontRight => "front_right",
        LegId::RearLeft => "rear_left",
        LegId::RearRight => "rear_right",
    }
}

/// The shortest decimal that reads back to `value`.
fn num(value: f32) -> String {
    value.to_string()
}

fn inertial(mass_kg: f64, ixx: f64, iyy: f64, izz: f64) -> String {
    format!(
        "    <inertial>\n      <mass value=\"{mass_kg:.6}\"/>\n      <inertia ixx=\"{ixx:.9}\" ixy=\"0\" ixz=\"0\" iyy=\"{iyy:.9}\" iyz=\"0\" izz=\"{izz:.9}\"/>\n    </inertial>\n"
    )
}

/// A link whose geometry is a cylinder along body y (`rpy` turns its z onto y), centred
/// `centre_y` from the link's origin.
fn cylinder_link(name: &str, radius: f32, length: f32, centre_y: f32) -> String {
    let (r, l) = (f64::from(radius), f64::from(length));
    let mass = NOMINAL_DENSITY_KG_PER_M3 * std::f64::consts::PI * r * r * l;
    let across = mass * (3.0 * r * r + l * l) / 12.0;
    let along = mass * r * r / 2.0;
    let geometry = format!(
        "      <origin xyz=\"0 {} 0\" rpy=\"1.5707963267948966 0 0\"/>\n      <geometry><cylinder radius=\"{}\" length=\"{}\"/></geometry>\n",
        num(centre_y),
        num(radius),
        num(length)
    );
    format!(
        "  <link name=\"{name}\">\n{}    <visual>\n{geometry}    </visual>\n    <collision>\n{geometry}    </collision>\n  </link>\n",
        inertial(mass, across, along, across)
    )
}

/// The description as URDF text; [`import`] reads it back to the same description.
pub fn export(description: &RobotDescription) -> String {
    let g = &description.robot.geometry;
    let (l, w, t) = (
        f64::from(g.body_length_m),
        f64::from(g.body_width_m),
        f64::from(g.body_thickness_m),
    );
    let body_mass = NOMINAL_DENSITY_KG_PER_M3 * l * w * t;
    let mut out = format!(
        "<?xml version=\"1.0\"?>\n<!-- {name}: written by `wheelleg robot urdf` from its robot description. Masses are nominal (uniform density 1,000 kg/m3), not the robot's. -->\n<robot name=\"{name}\">\n  <link name=\"body\">\n{}    <visual>\n      <geometry><box size=\"{} {} {}\"/></geometry>\n    </visual>\n    <collision>\n      <geometry><box size=\"{} {} {}\"/></geometry>\n    </collision>\n  </link>\n",
        inertial(body_mass, body_mass * (w * w + t * t) / 12.0, body_mass * (l * l + t * t) / 12.0, body_mass * (l * l + w * w) / 12.0),
        num(g.body_length_m),
        num(g.body_width_m),
        num(g.body_thickness_m),
        num(g.body_length_m),
        num(g.body_width_m),
        num(g.body_thickness_m),
        name = description.name,
    );
    for leg in LegId::ALL {
        let prefix = leg_prefix(leg);
        let side = leg.side_sign();
        // The description's angles turn a left leg's outward (+y) down: about -x.
        let axis = format!("{} 0 0", num(-side));
        let joint = |name: &str, parent: &str, child: &str, y: f32, range: [f32; 2]| {
            format!(
                "  <joint name=\"{prefix}_{name}\" type=\"revolute\">\n    <origin xyz=\"{} {} 0\"/>\n    <parent link=\"{parent}\"/>\n    <child link=\"{child}\"/>\n    <axis xyz=\"{axis}\"/>\n    <limit lower=\"{}\" upper=\"{}\" effort=\"100\" velocity=\"10\"/>\n  </joint>\n",
                if name == "hip" { num(leg.fore_sign() * g.hip_x_m) } else { "0".into() },
                num(y),
                num(range[0]),
                num(range[1]),
            )
        };
        let thigh = format!("{prefix}_thigh");
        let shank = format!("{prefix}_shank");
        let mount = format!("{prefix}_wheel_mount");
        let wheel = format!("{prefix}_wheel");
        out.push_str(&cylinder_link(
            &thigh,
            g.link_radius_m,
            g.thigh_m,
            side * 0.5 * g.thigh_m,
        ));
        out.push_str(&joint(
            "hip",
            "body",
            &thigh,
            side * g.hip_y_m,
            g.hip_range_rad,
        ));
        out.push_str(&cylinder_link(
            &shank,
            g.link_radius_m,
            g.shank_m,
            side * 0.5 * g.shank_m,
        ));
        out.push_str(&joint(
            "knee",
            &thigh,
            &shank,
            side * g.thigh_m,
            g.knee_range_rad,
        ));
        // The wheel mount carries the wheel: a small link of its own, nominal mass.
        out.push_str(&format!(
            "  <link name=\"{mount}\">\n{}  </link>\n",
            inertial(0.01, 1e-6, 1e-6, 1e-6)
        ));
        // The mount's range keeps the axle level over the hip's and knee's: -(hip + knee).
        let mount_range = [
            -(g.hip_range_rad[1] + g.knee_range_rad[1]),
            -(g.hip_range_rad[0] + g.knee_range_rad[0]),
        ];
        out.push_str(&joint(
            "wheel_mount",
            &shank,
            &mount,
            side * g.shank_m,
            mount_range,
        ));
        out.push_str(&cylinder_link(
            &wheel,
            g.wheel_radius_m,
            g.wheel_width_m,
            0.0,
        ));
        out.push_str(&format!(
            "  <joint name=\"{prefix}_wheel\" type=\"continuous\">\n    <origin xyz=\"0 {} 0\"/>\n    <parent link=\"{mount}\"/>\n    <child link=\"{wheel}\"/>\n    <axis xyz=\"0 1 0\"/>\n  </joint>\n",
            // `+ 0.0` writes a zero offset on a right leg as 0, not -0.
            num(side * g.wheel_offset_m + 0.0)
        ));
    }
    let file = DescriptionFile::from_description(description);
    let own = OwnElement {
        pose: file.pose,
        actions: file.actions,
        can: file.can,
    };
    let own_toml = toml::to_string(&own).unwrap_or_default();
    out.push_str(&format!(
        "  <!-- What URDF has no field for: the commanded pose, the action lattice and the CAN bus (wheelleg's robot description). -->\n  <wheelleg>\n{}  </wheelleg>\n</robot>\n",
        escape(&own_toml)
    ));
    out
}

fn escape(text: &str) -> String {
    text.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}
