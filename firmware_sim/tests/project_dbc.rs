//! docs/wheelleg.dbc must describe exactly the node map and message set the runtime uses.

use wheelleg_runtime::can::node_map::{Axis, AxisKind, NodeMap};
use wheelleg_runtime::can::protocol::{frame_id, CmdId};

#[test]
fn project_dbc_has_every_message_of_every_node() {
    let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../docs/wheelleg.dbc");
    let dbc = std::fs::read_to_string(path).expect("docs/wheelleg.dbc");
    let ids: Vec<u32> = dbc
        .lines()
        .filter_map(|l| l.strip_prefix("BO_ "))
        .filter_map(|l| l.split_whitespace().next()?.parse().ok())
        .collect();
    let mut expected = Vec::new();
    for axis in Axis::ALL {
        let setpoint = match axis.kind() {
            AxisKind::Joint => CmdId::SetInputPos,
            AxisKind::Wheel => CmdId::SetInputVel,
        };
        for cmd in [
            CmdId::Heartbeat,
            CmdId::Estop,
            CmdId::SetAxisState,
            CmdId::GetEncoderEstimates,
            CmdId::SetControllerMode,
            setpoint,
            CmdId::ClearErrors,
        ] {
            expected.push(u32::from(
                frame_id(NodeMap::NOMINAL.node_id(axis), cmd).as_raw(),
            ));
        }
    }
    let mut got = ids.clone();
    got.sort_unstable();
    expected.sort_unstable();
    assert_eq!(got, expected, "regenerate with tools/gen_dbc.py");
}
