//! What a description must satisfy for the runtime to drive it, each rule naming its key.

use crate::description::{ControlMode, DescriptionFile};
use std::fmt;
use wheelleg_runtime::can::node_map::Axis;
use wheelleg_runtime::can::protocol::MAX_NODE_ID;
use wheelleg_runtime::can::slcan::BitRate;
use wheelleg_runtime::leg::LegConfig;
use wheelleg_runtime::robot::RobotGeometry;

/// Why a description was refused: the key at fault and what is wrong with it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DescriptionError {
    /// The key's dotted path (`legs.thigh_m`), empty for a file that is not TOML.
    pub key: String,
    /// What is wrong.
    pub message: String,
}

impl DescriptionError {
    /// An error at `key`.
    pub fn new(key: String, message: String) -> DescriptionError {
        DescriptionError { key, message }
    }

    /// A file that is not TOML.
    pub fn syntax(message: String) -> DescriptionError {
        DescriptionError {
            key: String::new(),
            message,
        }
    }
}

impl fmt::Display for DescriptionError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.key.is_empty() || self.key == "." {
            write!(f, "{}", self.message.trim_end())
        } else {
            write!(f, "{}: {}", self.key, self.message.trim_end())
        }
    }
}

impl std::error::Error for DescriptionError {}

fn error(key: &str, message: impl Into<String>) -> DescriptionError {
    DescriptionError::new(key.into(), message.into())
}

fn positive(key: &str, value: f64) -> Result<(), DescriptionError> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(error(
            key,
            format!("{value} must be a finite number above 0"),
        ))
    }
}

fn range(key: &str, range: [f64; 2]) -> Result<(), DescriptionError> {
    if range.iter().all(|v| v.is_finite()) && range[0] < range[1] {
        Ok(())
    } else {
        Err(error(
            key,
            format!(
                "[{}, {}] must be two finite numbers, the smaller first",
                range[0], range[1]
            ),
        ))
    }
}

/// Every rule a description must meet, in the order a person fixes them: numbers, then
/// geometry, then the bus.
pub fn validate(file: &DescriptionFile) -> Result<(), DescriptionError> {
    if file.name.is_empty()
        || !file
            .name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '-' || c == '_')
    {
        return Err(error(
            "name",
            format!(
                "'{}' must be letters, digits, '-' and '_' (it names files and is stored in weights)",
                file.name
            ),
        ));
    }
    numbers(file)?;
    geometry(file)?;
    bus(file)
}

fn numbers(file: &DescriptionFile) -> Result<(), DescriptionError> {
    let (b, l, w, p, a) = (
        &file.body,
        &file.legs,
        &file.wheels,
        &file.pose,
        &file.actions,
    );
    positive("body.length_m", b.length_m)?;
    positive("body.width_m", b.width_m)?;
    positive("body.thickness_m", b.thickness_m)?;
    positive("legs.hip_x_m", l.hip_x_m)?;
    if !(l.hip_y_m.is_finite() && l.hip_y_m >= 0.0) {
        return Err(error(
            "legs.hip_y_m",
            format!(
                "{} must be 0 or more (the left hips; the right ones mirror them)",
                l.hip_y_m
            ),
        ));
    }
    positive("legs.thigh_m", l.thigh_m)?;
    positive("legs.shank_m", l.shank_m)?;
    positive("legs.link_radius_m", l.link_radius_m)?;
    range("legs.hip_range_rad", l.hip_range_rad)?;
    range("legs.knee_range_rad", l.knee_range_rad)?;
    positive("wheels.radius_m", w.radius_m)?;
    positive("wheels.width_m", w.width_m)?;
    // The runtime's own bound, in its precision: what this accepts, a weights file carries.
    let g = file.geometry();
    if !g.wheel_offset_m.is_finite() || g.wheel_offset_m.abs() > g.max_wheel_offset_m() {
        return Err(error(
            "wheels.offset_m",
            format!(
                "{} m is more than half the wheel's width plus the link radius ({} m) either \
                 way: the axle from the wheel mount to the wheel would stand clear of both",
                w.offset_m,
                0.5 * w.width_m + l.link_radius_m
            ),
        ));
    }
    range("pose.clearance_range_m", p.clearance_range_m)?;
    positive("pose.clearance_range_m", p.clearance_range_m[0])?;
    range("pose.track_range_m", p.track_range_m)?;
    if p.track_range_m[0] <= w.width_m {
        return Err(error(
            "pose.track_range_m",
            format!(
                "the narrowest track {} m would put the wheels ({} m wide) into each other",
                p.track_range_m[0], w.width_m
            ),
        ));
    }
    positive("pose.default_clearance_m", p.default_clearance_m)?;
    positive("pose.default_track_m", p.default_track_m)?;
    positive("actions.move_step_m", a.move_step_m)?;
    positive("actions.yaw_step_deg", a.yaw_step_deg)?;
    positive("actions.clearance_step_m", a.clearance_step_m)?;
    positive("actions.track_step_m", a.track_step_m)?;
    if a.yaw_step_deg > 90.0 {
        return Err(error(
            "actions.yaw_step_deg",
            format!("{} is more than a quarter turn per step", a.yaw_step_deg),
        ));
    }
    Ok(())
}

/// Samples per range when looking for a reachable pose: 1 mm on a 0.5 m range.
const REACH_SAMPLES: usize = 500;

fn samples(range: [f32; 2]) -> impl Iterator<Item = f32> {
    (0..=REACH_SAMPLES)
        .map(move |i| range[0] + (range[1] - range[0]) * i as f32 / REACH_SAMPLES as f32)
}

fn reachable(g: &RobotGeometry, clearance_m: f32, track_m: f32) -> bool {
    g.is_reachable(LegConfig {
        clearance_m,
        track_m,
    })
}

/// The part of `range` (one pose coordinate) at which the legs reach some value of `other`
/// (the other coordinate): `(lowest, highest)`. `reachable` takes (this coordinate, other).
fn reach_span(
    range: [f32; 2],
    other: [f32; 2],
    reachable: impl Fn(f32, f32) -> bool,
) -> Option<(f32, f32)> {
    let mut span: Option<(f32, f32)> = None;
    for v in samples(range) {
        if samples(other).any(|o| reachable(v, o)) {
            span = Some(span.map_or((v, v), |(lo, hi)| (lo.min(v), hi.max(v))));
        }
    }
    span
}

/// Both ends of a pose range lie in the span the legs reach (within one sample's width: the
/// span is found on a 1/500 grid).
fn ends_reached(
    (key, what, other): (&str, &str, &str),
    range: [f32; 2],
    reached: (f32, f32),
    names: [&str; 2],
) -> Result<(), DescriptionError> {
    let slack = (range[1] - range[0]) / REACH_SAMPLES as f32;
    for (end, value) in names.into_iter().zip(range) {
        if value < reached.0 - slack || value > reached.1 + slack {
            return Err(error(
                key,
                format!(
                    "the {end} {what}, {value} m, is reached at no {other} in the {other} \
                     range: the legs reach {what}s {:.3} to {:.3} m",
                    reached.0, reached.1
                ),
            ));
        }
    }
    Ok(())
}

fn geometry(file: &DescriptionFile) -> Result<(), DescriptionError> {
    let g = file.geometry();
    let clearances = reach_span(g.clearance_range_m, g.track_range_m, |c, t| {
        reachable(&g, c, t)
    });
    let Some(clearances) = clearances else {
        return Err(error(
            "legs",
            format!(
                "no clearance in pose.clearance_range_m and track in pose.track_range_m is \
                 reachable: with the hips at y = {} m, a {} m thigh and a {} m shank within \
                 the joint ranges, the wheels cannot stand on the ground under those poses",
                g.hip_y_m, g.thigh_m, g.shank_m
            ),
        ));
    };
    let tracks = reach_span(g.track_range_m, g.clearance_range_m, |t, c| {
        reachable(&g, c, t)
    })
    .unwrap_or((g.track_range_m[0], g.track_range_m[0]));
    ends_reached(
        ("pose.clearance_range_m", "clearance", "track"),
        g.clearance_range_m,
        clearances,
        ["lowest", "highest"],
    )?;
    ends_reached(
        ("pose.track_range_m", "track", "clearance"),
        g.track_range_m,
        tracks,
        ["narrowest", "widest"],
    )?;
    let default = LegConfig {
        clearance_m: g.default_clearance_m,
        track_m: g.default_track_m,
    };
    if let Err(why) = g.leg_ik(default) {
        return Err(error(
            "pose.default_clearance_m",
            format!(
                "the default pose (clearance {} m, track {} m) has no leg solution ({why:?})",
                g.default_clearance_m, g.default_track_m
            ),
        ));
    }
    Ok(())
}

fn bus(file: &DescriptionFile) -> Result<(), DescriptionError> {
    let rate = file.can.bit_rate_bps;
    if !BitRate::ALL.iter().any(|r| r.bits_per_s() == rate) {
        return Err(error(
            "can.bit_rate_bps",
            format!(
                "{rate} is not a standard CAN bit rate ({})",
                BitRate::ALL
                    .iter()
                    .map(|r| r.bits_per_s().to_string())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        ));
    }
    let entries = file.can.axes.entries();
    for (i, (axis, key, entry)) in entries.iter().enumerate() {
        let at = |field: &str| format!("can.axes.{key}.{field}");
        if entry.node_id == 0 || entry.node_id > MAX_NODE_ID {
            return Err(DescriptionError::new(
                at("node_id"),
                format!(
                    "{} is outside 1 to {MAX_NODE_ID} (0 is where a factory-fresh ODrive answers)",
                    entry.node_id
                ),
            ));
        }
        if let Some((_, other, _)) = entries
            .iter()
            .take(i)
            .find(|(_, _, e)| e.node_id == entry.node_id)
        {
            return Err(DescriptionError::new(
                at("node_id"),
                format!(
                    "node {} is also can.axes.{other}'s: two axes cannot share a node id",
                    entry.node_id
                ),
            ));
        }
        if entry.direction != 1 && entry.direction != -1 {
            return Err(DescriptionError::new(
                at("direction"),
                format!("{} must be 1 or -1", entry.direction),
            ));
        }
        if !(entry.gear_ratio.is_finite() && entry.gear_ratio > 0.0) {
            return Err(DescriptionError::new(
                at("gear_ratio"),
                format!("{} must be a finite number above 0", entry.gear_ratio),
            ));
        }
        let (wanted, what) = match axis {
            Axis::Joint(..) => (
                ControlMode::Position,
                "a leg joint follows position setpoints",
            ),
            Axis::Wheel(_) => (ControlMode::Velocity, "a wheel follows velocity setpoints"),
        };
        if entry.control_mode != wanted {
            return Err(DescriptionError::new(
                at("control_mode"),
                format!("must be \"{}\": {what}", mode_name(wanted)),
            ));
        }
    }
    Ok(())
}

fn mode_name(mode: ControlMode) -> &'static str {
    match mode {
        ControlMode::Position => "position",
        ControlMode::Velocity => "velocity",
    }
}
