//! The description file: the shipped robot bit for bit, every bad description refused with its
//! key named.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use wheelleg_robot::{RobotDescription, SHIPPED_TOML};
use wheelleg_runtime::action::ActionLattice;
use wheelleg_runtime::can::node_map::Axis;
use wheelleg_runtime::robot::{Robot, RobotGeometry};

fn geometry_bits(g: &RobotGeometry) -> Vec<u32> {
    [
        g.body_length_m,
        g.body_width_m,
        g.body_thickness_m,
        g.hip_x_m,
        g.hip_y_m,
        g.thigh_m,
        g.shank_m,
        g.link_radius_m,
        g.wheel_radius_m,
        g.wheel_width_m,
        g.wheel_offset_m,
        g.hip_range_rad[0],
        g.hip_range_rad[1],
        g.knee_range_rad[0],
        g.knee_range_rad[1],
        g.track_range_m[0],
        g.track_range_m[1],
        g.clearance_range_m[0],
        g.clearance_range_m[1],
        g.default_track_m,
        g.default_clearance_m,
    ]
    .iter()
    .map(|v| v.to_bits())
    .collect()
}

fn lattice_bits(a: &ActionLattice) -> [u32; 4] {
    [
        a.move_step_m.to_bits(),
        a.yaw_step_deg.to_bits(),
        a.clearance_step_m.to_bits(),
        a.track_step_m.to_bits(),
    ]
}

#[test]
fn the_shipped_file_is_the_compiled_robot_bit_for_bit() {
    let shipped = RobotDescription::from_toml(SHIPPED_TOML).unwrap();
    let compiled = Robot::WHEELLEG;
    assert_eq!(shipped.name, "wheelleg");
    assert_eq!(shipped.bit_rate_bps, 1_000_000);
    assert_eq!(
        geometry_bits(&shipped.robot.geometry),
        geometry_bits(&compiled.geometry)
    );
    assert_eq!(
        lattice_bits(&shipped.robot.actions),
        lattice_bits(&compiled.actions)
    );
    for axis in Axis::ALL {
        assert_eq!(
            shipped.robot.can.node_id(axis),
            compiled.can.node_id(axis),
            "{axis:?}"
        );
        let (a, b) = (shipped.robot.can.get(axis), compiled.can.get(axis));
        assert_eq!(a.gear_ratio.to_bits(), b.gear_ratio.to_bits(), "{axis:?}");
        assert_eq!(a.direction.to_bits(), b.direction.to_bits(), "{axis:?}");
        assert_eq!(a.zero_offset_turns.to_bits(), b.zero_offset_turns.to_bits());
    }
    assert_eq!(shipped.robot, compiled);
    assert_eq!(RobotDescription::shipped(), shipped);
}

#[test]
fn a_written_description_reads_back_to_itself() {
    let offset = SHIPPED_TOML.replace("width_m = 0.04\n", "width_m = 0.04\noffset_m = 0.03\n");
    for text in [
        SHIPPED_TOML,
        include_str!("../../robots/strider.toml"),
        offset.as_str(),
    ] {
        let description = RobotDescription::from_toml(text).unwrap();
        let again = RobotDescription::from_toml(&description.to_toml()).unwrap();
        assert_eq!(again, description);
        // The offset is written only where there is one.
        assert_eq!(
            description.to_toml().contains("offset_m"),
            description.robot.geometry.wheel_offset_m != 0.0
        );
        assert!(
            description.to_toml().contains("thigh_m = "),
            "{}",
            description.to_toml()
        );
    }
}

#[test]
fn the_second_robot_has_its_own_node_ids() {
    let strider = RobotDescription::from_toml(include_str!("../../robots/strider.toml")).unwrap();
    let first = strider.robot.can.node_id(Axis::ALL[0]).get();
    assert_eq!(first, 21);
    assert_ne!(strider.robot.geometry, Robot::WHEELLEG.geometry);
}

/// The shipped file with `from` replaced by `to` (which must occur once).
fn edited(from: &str, to: &str) -> String {
    assert_eq!(SHIPPED_TOML.matches(from).count(), 1, "{from}");
    SHIPPED_TOML.replacen(from, to, 1)
}

#[test]
fn bad_descriptions_are_refused_naming_the_key() {
    let cases: Vec<(String, &str, &str)> = vec![
        (
            edited("thigh_m = 0.08", "thigh_m = 0.08\nfoot_m = 0.01"),
            "legs.foot_m",
            "unknown field `foot_m`",
        ),
        (edited("shank_m = 0.16\n", ""), "legs", "missing field `shank_m`"),
        (edited("[wheels]", "[wheels"), "", "TOML parse error"),
        (edited("length_m = 0.50", "length_m = -0.50"), "body.length_m", "above 0"),
        (
            edited("width_m = 0.04\n", "width_m = 0.04\noffset_m = 0.04\n"),
            "wheels.offset_m",
            "more than half the wheel's width plus the link radius (0.032 m)",
        ),
        (
            edited("width_m = 0.04\n", "width_m = 0.04\noffset_m = nan\n"),
            "wheels.offset_m",
            "NaN m is more than",
        ),
        (
            edited("thigh_m = 0.08", "thigh_m = \"long\""),
            "legs.thigh_m",
            "invalid type",
        ),
        (
            edited("knee_range_rad = [0.0, 2.8]", "knee_range_rad = [2.8, 0.0]"),
            "legs.knee_range_rad",
            "the smaller first",
        ),
        (
            edited("thigh_m = 0.08", "thigh_m = 0.01").replacen("shank_m = 0.16", "shank_m = 0.01", 1),
            "legs",
            "cannot stand on the ground",
        ),
        (
            edited("clearance_range_m = [0.04, 0.24]", "clearance_range_m = [0.04, 0.34]"),
            "pose.clearance_range_m",
            "reached at no track",
        ),
        (
            edited("track_range_m = [0.16, 0.56]", "track_range_m = [0.16, 0.66]"),
            "pose.track_range_m",
            "reached at no clearance",
        ),
        (
            edited("default_clearance_m = 0.12", "default_clearance_m = 0.22"),
            "pose.default_clearance_m",
            "no leg solution",
        ),
        (
            edited("track_range_m = [0.16, 0.56]", "track_range_m = [0.03, 0.56]"),
            "pose.track_range_m",
            "into each other",
        ),
        (
            edited(
                "front_right_knee = { node_id = 5,",
                "front_right_knee = { node_id = 2,",
            ),
            "can.axes.front_right_knee.node_id",
            "also can.axes.front_left_knee's",
        ),
        (
            edited("rear_left_hip = { node_id = 7,", "rear_left_hip = { node_id = 0,"),
            "can.axes.rear_left_hip.node_id",
            "outside 1 to 63",
        ),
        (
            edited("rear_left_hip = { node_id = 7,", "rear_left_hip = { node_id = 64,"),
            "can.axes.rear_left_hip.node_id",
            "outside 1 to 63",
        ),
        (
            edited(
                "front_left_knee = { node_id = 2, direction = 1,",
                "front_left_knee = { node_id = 2, direction = 2,",
            ),
            "can.axes.front_left_knee.direction",
            "1 or -1",
        ),
        (
            edited(
                "front_left_wheel = { node_id = 13, direction = 1, gear_ratio = 1.0, control_mode = \"velocity\"",
                "front_left_wheel = { node_id = 13, direction = 1, gear_ratio = 1.0, control_mode = \"position\"",
            ),
            "can.axes.front_left_wheel.control_mode",
            "velocity",
        ),
        (
            edited(
                "rear_right_knee = { node_id = 11, direction = 1, gear_ratio = 9.0, control_mode = \"position\" }\n",
                "",
            ),
            "can.axes",
            "missing field `rear_right_knee`",
        ),
        (
            edited("bit_rate_bps = 1000000", "bit_rate_bps = 1000001"),
            "can.bit_rate_bps",
            "not a standard CAN bit rate",
        ),
        (
            edited("name = \"wheelleg\"", "name = \"my robot\""),
            "name",
            "letters, digits",
        ),
        (
            edited("yaw_step_deg = 5.0", "yaw_step_deg = nan"),
            "actions.yaw_step_deg",
            "finite",
        ),
    ];
    let mut wrong = Vec::new();
    for (text, key, says) in cases {
        match RobotDescription::from_toml(&text) {
            Ok(_) => wrong.push(format!("accepted; expected {key}: {says}")),
            Err(error) if error.key != key || !error.to_string().contains(says) => {
                wrong.push(format!("expected {key}: '{says}', got {error}"))
            }
            Err(_) => {}
        }
    }
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
}
