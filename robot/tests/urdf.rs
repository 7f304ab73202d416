//! URDF out and back in gives the same description; URDFs outside the class are refused with
//! the joint or link named.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use wheelleg_robot::urdf::{export, import};
use wheelleg_robot::RobotDescription;

fn strider() -> RobotDescription {
    RobotDescription::from_toml(include_str!("../../robots/strider.toml")).unwrap()
}

/// The strider with its wheels `offset_m` outboard of the wheel mounts (its own: 15 mm).
fn strider_offset(offset_m: f64) -> RobotDescription {
    let text = include_str!("../../robots/strider.toml")
        .replace("offset_m = 0.015\n", &format!("offset_m = {offset_m}\n"));
    RobotDescription::from_toml(&text).unwrap()
}

#[test]
fn an_exported_urdf_imports_to_the_same_description() {
    for description in [
        RobotDescription::shipped(),
        strider(),
        strider_offset(0.04),
        strider_offset(-0.01),
    ] {
        let urdf = export(&description);
        assert_eq!(import(&urdf).unwrap(), description, "{urdf}");
    }
}

#[test]
fn a_wheel_offset_along_its_axle_is_read_from_the_wheel_joint() {
    // Every wheel joint 0.03 m outward of its mount: +y on the left, -y on the right.
    let mut urdf = export(&RobotDescription::shipped());
    for (leg, y) in [
        ("front_left", "0.03"),
        ("front_right", "-0.03"),
        ("rear_left", "0.03"),
        ("rear_right", "-0.03"),
    ] {
        let from = format!(
            "<joint name=\"{leg}_wheel\" type=\"continuous\">\n    <origin xyz=\"0 0 0\"/>"
        );
        let to = format!(
            "<joint name=\"{leg}_wheel\" type=\"continuous\">\n    <origin xyz=\"0 {y} 0\"/>"
        );
        assert!(urdf.contains(&from), "{from}");
        urdf = urdf.replacen(&from, &to, 1);
    }
    let imported = import(&urdf).unwrap();
    assert_eq!(imported.robot.geometry.wheel_offset_m, 0.03);
    assert_eq!(export(&imported), urdf);
}

#[test]
fn a_urdf_without_the_own_element_gets_the_documented_defaults() {
    let urdf = export(&strider());
    let start = urdf.find("  <!-- What URDF").unwrap();
    let end = urdf.find("</wheelleg>\n").unwrap() + "</wheelleg>\n".len();
    let plain = format!("{}{}", &urdf[..start], &urdf[end..]);
    let imported = import(&plain).unwrap();
    let want = strider().robot.geometry;
    let got = imported.robot.geometry;
    // The shape is the URDF's; the pose ranges are what the joint limits reach.
    assert_eq!(
        (got.thigh_m, got.shank_m, got.hip_x_m, got.hip_y_m),
        (want.thigh_m, want.shank_m, want.hip_x_m, want.hip_y_m)
    );
    assert_eq!(got.hip_range_rad, want.hip_range_rad);
    assert_eq!(got.wheel_radius_m, want.wheel_radius_m);
    assert!(got.clearance_range_m[1] >= want.clearance_range_m[1] - 0.01);
    assert!(got.is_reachable(wheelleg_runtime::leg::LegConfig {
        clearance_m: got.default_clearance_m,
        track_m: got.default_track_m,
    }));
    // The CAN map's documented defaults: nodes 1 to 16.
    assert_eq!(
        imported
            .robot
            .can
            .node_id(wheelleg_runtime::can::Axis::ALL[0])
            .get(),
        1
    );
}

/// The shipped robot's URDF with `from` replaced by `to` (first occurrence).
fn edited(from: &str, to: &str) -> String {
    let urdf = export(&RobotDescription::shipped());
    assert!(urdf.contains(from), "{from}");
    urdf.replacen(from, to, 1)
}

#[test]
fn urdfs_outside_the_class_are_refused_naming_the_joint() {
    let urdf = export(&RobotDescription::shipped());
    let knee_axis = urdf.find("<child link=\"front_left_shank\"/>").unwrap();
    let knee_axis_at = knee_axis + urdf[knee_axis..].find("<axis xyz=\"-1 0 0\"/>").unwrap();
    let mut knee_about_y = urdf.clone();
    knee_about_y.replace_range(
        knee_axis_at..knee_axis_at + "<axis xyz=\"-1 0 0\"/>".len(),
        "<axis xyz=\"0 1 0\"/>",
    );
    let cases: Vec<(String, &str)> = vec![
        ("not xml <".into(), "not a URDF"),
        (
            edited("<joint name=\"front_left_hip\" type=\"revolute\">", "<joint name=\"front_left_hip\" type=\"prismatic\">"),
            "joint 'front_left_hip' (a hip) is Prismatic",
        ),
        (knee_about_y, "joint 'front_left_knee' turns about"),
        (
            edited("<joint name=\"rear_right_knee\" type=\"revolute\">", "<joint name=\"rear_right_knee\" type=\"continuous\">"),
            "joint 'rear_right_knee' (knee) is Continuous",
        ),
        (
            edited("<joint name=\"front_left_wheel\" type=\"continuous\">\n    <origin xyz=\"0 0 0\"/>", "<joint name=\"front_left_wheel\" type=\"continuous\">\n    <origin xyz=\"0 0 0.02\"/>"),
            "joint 'front_left_wheel' sits at (0.0000, 0.0000, 0.0200) from the wheel mount's joint",
        ),
        (
            edited("<joint name=\"front_left_wheel\" type=\"continuous\">\n    <origin xyz=\"0 0 0\"/>", "<joint name=\"front_left_wheel\" type=\"continuous\">\n    <origin xyz=\"0 0.02 0\"/>"),
            "are not mirror images: wheel offset",
        ),
        (
            edited("<child link=\"front_left_wheel\"/>\n    <axis xyz=\"0 1 0\"/>", "<child link=\"front_left_wheel\"/>\n    <axis xyz=\"1 0 0\"/>"),
            "joint 'front_left_wheel' turns about",
        ),
        (
            edited("<origin xyz=\"0.2 0.06 0\"/>", "<origin xyz=\"0.2 0.06 0.03\"/>"),
            "the hips must sit at the body's mid-height",
        ),
        (
            edited("<origin xyz=\"0.2 0.06 0\"/>", "<origin xyz=\"0.21 0.06 0\"/>"),
            "are not mirror images: hip x",
        ),
        (
            edited("<origin xyz=\"0 0.08 0\"/>", "<origin xyz=\"0 0.08 -0.02\"/>"),
            "joint 'front_left_knee' sits at",
        ),
        (
            export(&RobotDescription::shipped())
                .replace("<box size=\"0.5 0.16 0.08\"/>", "<sphere radius=\"0.1\"/>"),
            "link 'body' (the root, the body) has no collision box",
        ),
        (
            {
                let hip = urdf.find("  <joint name=\"rear_right_hip\"").unwrap();
                let end = hip + urdf[hip..].find("</joint>\n").unwrap() + "</joint>\n".len();
                format!("{}{}", &urdf[..hip], &urdf[end..])
            },
            "2 root links",
        ),
        (
            edited("<limit lower=\"-1.2\" upper=\"1.5\"", "<limit lower=\"1.5\" upper=\"-1.2\""),
            "lower below upper",
        ),
        (
            edited("<joint name=\"rear_right_hip\" type=\"revolute\">\n    <origin xyz=\"-0.2 -0.06 0\"/>", "<joint name=\"rear_right_hip\" type=\"revolute\">\n    <origin xyz=\"-0.2 0.06 0\"/>"),
            "joint 'rear_right_knee' sits at",
        ),
    ];
    let mut wrong = Vec::new();
    for (text, says) in cases {
        match import(&text) {
            Ok(_) => wrong.push(format!("accepted; expected '{says}'")),
            Err(e) if !e.to_string().contains(says) => {
                wrong.push(format!("expected '{says}', got {e}"))
            }
            Err(_) => {}
        }
    }
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
}
