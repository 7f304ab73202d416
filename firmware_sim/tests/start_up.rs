//! The rig's start-up against the simulated bus: the roll call (Get_Version to every node)
//! refuses a missing node, two devices on one node id and firmware the codec does not speak,
//! before anything is armed; a healthy bus is asked, cleared and armed in that order; the rig
//! configures the watchdog its fault handling relies on.

use std::io::Write;
use std::sync::{Arc, Mutex};
use wheelleg_firmware_sim::axis::{AxisConfig, SimAxis};
use wheelleg_firmware_sim::candump::{parse_log, CandumpWriter, DEFAULT_EPOCH_US};
use wheelleg_firmware_sim::rig::{Rig, RigConfig, RigError};
use wheelleg_runtime::can::host::{RollCallProblem, RollCallRefusal};
use wheelleg_runtime::can::node_map::{Axis, Joint};
use wheelleg_runtime::can::protocol::{decode, AxisState, CmdId, Message, NodeId, Version};
use wheelleg_runtime::leg::LegConfig;
use wheelleg_runtime::robot::{LegId, Robot, WHEELLEG};

fn rig(config: RigConfig) -> Rig {
    let legs = LegConfig {
        clearance_m: WHEELLEG.default_clearance_m,
        track_m: WHEELLEG.default_track_m,
    };
    Rig::in_process(&Robot::WHEELLEG, config, legs).unwrap()
}

/// Start-up was refused for `axis` with `problem`, the message names the node and the axis,
/// and nothing was armed or commanded.
fn assert_refused(rig: &mut Rig, axis: Axis, problem: RollCallProblem, words: &str) {
    let err = rig.start_up().unwrap_err();
    let node = Robot::WHEELLEG.can.node_id(axis);
    match &err {
        RigError::StartupRefused(refusal) => assert_eq!(
            *refusal,
            RollCallRefusal {
                axis,
                node,
                problem
            }
        ),
        other => panic!("expected a refusal for {axis:?}, got {other:?}"),
    }
    let shown = err.to_string();
    let named = format!("node {} ({axis})", node.get());
    assert!(
        shown.contains(&named) && shown.contains(words),
        "{shown:?} should contain {named:?} and {words:?}"
    );
    for motor in rig.firmware().axes() {
        assert_eq!(motor.state(), AxisState::Idle, "{shown}");
        assert_eq!(
            motor.stats().commands,
            0,
            "only requests were sent: {shown}"
        );
    }
}

#[test]
fn a_missing_node_is_refused_by_name() {
    let mut rig = rig(RigConfig::default());
    let knee = Axis::Joint(LegId::RearRight, Joint::Knee);
    rig.firmware_mut().axis_mut(knee).unwrap().set_silent(true);
    assert_refused(&mut rig, knee, RollCallProblem::Missing, "missing");
}

#[test]
fn two_devices_on_one_node_id_are_refused() {
    let mut rig = rig(RigConfig::default());
    let hip = Axis::Joint(LegId::FrontRight, Joint::Hip);
    let node = Robot::WHEELLEG.can.node_id(hip);
    // Firmware that answers Get_Version (0.5.x has none, so two 0.5.x boards on one id are
    // not told apart this way), and a second board left on node 4: it answers every request
    // too.
    rig.firmware_mut().set_version(Some(Version::ODRIVE_0_5_6));
    let second = AxisConfig {
        version: Some(Version::ODRIVE_0_5_6),
        ..AxisConfig::JOINT
    };
    rig.firmware_mut().add_axis(SimAxis::new(node, second, 0.0));
    assert_refused(
        &mut rig,
        hip,
        RollCallProblem::TwoDevices,
        "two devices share this node id",
    );
}

#[test]
fn firmware_0_6_is_refused_by_name() {
    let mut rig = rig(RigConfig::default());
    let wheel = Axis::Wheel(LegId::RearLeft);
    let v0_6_11 = Version {
        fw_version_minor: 6,
        fw_version_revision: 11,
        ..Version::ODRIVE_0_5_6
    };
    rig.firmware_mut()
        .axis_mut(wheel)
        .unwrap()
        .config_mut()
        .version = Some(v0_6_11);
    assert_refused(
        &mut rig,
        wheel,
        RollCallProblem::UnsupportedFirmware(v0_6_11),
        "reports fw 0.6.11",
    );
}

#[test]
fn a_silent_bus_fails_start_up_with_every_node_silent() {
    let mut rig = rig(RigConfig::default());
    for axis in Axis::ALL {
        rig.firmware_mut().axis_mut(axis).unwrap().set_silent(true);
    }
    match rig.start_up() {
        Err(RigError::StartupFailed(health)) => assert_eq!(health.silent.0, 0xFFFF),
        other => panic!("expected StartupFailed, got {other:?}"),
    }
}

#[derive(Clone, Default)]
struct SharedBuf(Arc<Mutex<Vec<u8>>>);

impl Write for SharedBuf {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0.lock().unwrap().extend_from_slice(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

#[test]
fn start_up_asks_every_node_then_clears_errors_then_arms() {
    let mut rig = rig(RigConfig::default());
    // A latched error from before start-up (an earlier run's Estop) is cleared by start-up.
    let wheel = Axis::Wheel(LegId::FrontLeft);
    rig.firmware_mut()
        .axis_mut(wheel)
        .unwrap()
        .handle(&Message::Estop, 0);
    let buf = SharedBuf::default();
    rig.log_to(CandumpWriter::new(
        Box::new(buf.clone()),
        "can0",
        DEFAULT_EPOCH_US,
    ));
    rig.start_up().unwrap();
    rig.take_log().unwrap();
    let text = String::from_utf8(buf.0.lock().unwrap().clone()).unwrap();
    let frames: Vec<(NodeId, Message)> = parse_log(&text)
        .unwrap()
        .iter()
        .map(|e| decode(&e.frame).unwrap())
        .collect();
    let host = |m: &Message| m.is_command();
    let commands: Vec<&(NodeId, Message)> = frames.iter().filter(|(_, m)| host(m)).collect();
    // Three rounds of 16 requests, then 16 Clear_Errors, then the modes, then closed loop.
    let requests = commands
        .iter()
        .take_while(|(_, m)| *m == Message::Request(CmdId::GetVersion))
        .count();
    assert_eq!(requests, 48);
    let after: Vec<&Message> = commands.iter().skip(requests).map(|(_, m)| m).collect();
    assert!(after[..16].iter().all(|m| **m == Message::ClearErrors));
    assert!(after[16..32]
        .iter()
        .all(|m| matches!(m, Message::SetControllerMode { .. })));
    assert!(after[32..48]
        .iter()
        .all(|m| **m == Message::SetAxisState(AxisState::ClosedLoopControl)));
    // The axes run 0.5.x, which has no Get_Version: none answered, each was heard by its
    // heartbeat and accepted.
    assert!(!frames.iter().any(|(_, m)| matches!(m, Message::Version(_))));
    for axis in Axis::ALL {
        let fb = rig.feedback().axis(axis).unwrap();
        assert_eq!(fb.version, None);
        assert_eq!(fb.axis_state, Some(AxisState::ClosedLoopControl), "{axis}");
        assert_eq!(fb.axis_error, 0, "{axis}");
    }
}

#[test]
fn the_rig_configures_the_watchdog_its_safety_relies_on() {
    let watched = rig(RigConfig::default());
    assert!(watched
        .firmware()
        .axes()
        .iter()
        .all(|a| a.config().watchdog_timeout_us == 100_000));
    // Without it, a controller that stops sending leaves every axis armed: the watchdog is
    // what idles them.
    for (timeout_us, idled) in [(100_000, true), (0, false)] {
        let mut rig = rig(RigConfig {
            watchdog_timeout_us: timeout_us,
            ..RigConfig::default()
        });
        rig.start_up().unwrap();
        rig.pause_commands(true);
        rig.hold(0.5).unwrap();
        for motor in rig.firmware().axes() {
            assert_eq!(
                motor.state() == AxisState::Idle,
                idled,
                "watchdog {timeout_us} µs"
            );
        }
    }
}
