//! What `wheelleg robot check` reports, held to the shipped robot's documented passages.

#![allow(clippy::unwrap_used, clippy::expect_used, clippy::panic)]

use wheelleg_robot::reach::reach;
use wheelleg_robot::RobotDescription;

#[test]
fn the_shipped_robot_opens_the_passages_its_scenes_need() {
    let report = reach(&RobotDescription::shipped());
    // docs/robot.md: clearance 0.04 to 0.24 m and track 0.16 to 0.56 m reached on the lattice.
    assert!((report.clearance_m[0] - 0.04).abs() < 1e-4, "{report:?}");
    assert!((report.clearance_m[1] - 0.24).abs() < 1e-4, "{report:?}");
    assert!((report.track_m[0] - 0.16).abs() < 1e-4, "{report:?}");
    assert!((report.track_m[1] - 0.56).abs() < 1e-4, "{report:?}");
    // The scene generators' passages (sim/src/generate): a 0.15 m bar is lifted over, a
    // 0.45 m slab straddled, a 0.30 m gap squeezed through; the default pose does none.
    assert!(report.lift.height_m > 0.15 && report.default_tunnel.height_m < 0.15);
    assert!(report.spread.width_m > 0.45 && report.default_tunnel.width_m < 0.45);
    assert!(report.squeeze.width_m < 0.30 && report.default_width_m > 0.30);
    assert!(report.behaviours.iter().all(|b| b.available), "{report:?}");
    let text = report.to_text();
    assert!(
        text.contains("squeeze") && text.contains("lift over"),
        "{text}"
    );
}

#[test]
fn a_robot_without_knee_travel_has_no_squeeze_or_lift() {
    // Straight, locked legs: every pose is one hip angle, so height and track move together
    // along one arc and the legs cannot fold under the body.
    let text = wheelleg_robot::SHIPPED_TOML
        .replacen(
            "knee_range_rad = [0.0, 2.8]",
            "knee_range_rad = [0.0, 0.001]",
            1,
        )
        .replacen(
            "clearance_range_m = [0.04, 0.24]",
            "clearance_range_m = [0.11, 0.13]",
            1,
        )
        .replacen(
            "track_range_m = [0.16, 0.56]",
            "track_range_m = [0.5, 0.56]",
            1,
        );
    let description = RobotDescription::from_toml(&text);
    // Either the description is refused for ranges its legs cannot reach, naming the key, or
    // its report says which behaviours it lacks; it never passes as a robot with all five.
    match description {
        Err(e) => assert!(e.key.starts_with("pose.") || e.key == "legs", "{e}"),
        Ok(d) => {
            let report = reach(&d);
            assert!(report.behaviours.iter().any(|b| !b.available), "{report:?}");
        }
    }
}
