//! What several test crates share.

/// The shipped network's tensors in a file of the current format version trained for `robot`:
/// weights the tools and the controller take as made for that robot.
pub fn shipped_network_for(robot: &wheelleg_robot::RobotDescription) -> Vec<u8> {
    use wheelleg_runtime::model::format::FORMAT_VERSION;
    use wheelleg_runtime::model::load::open_envelope;
    let shipped = std::fs::read(concat!(env!("CARGO_MANIFEST_DIR"), "/weights/policy.wlw"))
        .expect("weights/policy.wlw");
    let (_, payload) = open_envelope(&shipped).expect("the shipped file's envelope");
    let mut payload = payload.to_vec();
    payload.extend(
        wheelleg_trainer::quantize::file_bytes::robot_bytes(
            FORMAT_VERSION,
            &robot.name,
            &robot.robot,
            robot.bit_rate_bps,
        )
        .expect("the robot record"),
    );
    wheelleg_trainer::quantize::file_bytes::envelope_bytes(FORMAT_VERSION, &payload)
        .expect("the weights file")
}
