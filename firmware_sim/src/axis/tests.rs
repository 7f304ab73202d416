use super::*;
use embedded_can::Frame;

fn armed(config: AxisConfig, mode: ControlMode) -> SimAxis {
    let mut a = SimAxis::new(NodeId::new(1).unwrap(), config, 0.0);
    a.handle(
        &Message::SetControllerMode {
            control_mode: mode,
            input_mode: InputMode::Passthrough,
        },
        0,
    );
    a.handle(&Message::SetAxisState(AxisState::ClosedLoopControl), 0);
    assert_eq!(a.state(), AxisState::ClosedLoopControl);
    a
}

/// `config` with the 100 ms watchdog the project's own loops configure.
fn watched(config: AxisConfig) -> AxisConfig {
    AxisConfig {
        watchdog_timeout_us: 100_000,
        ..config
    }
}

fn run(a: &mut SimAxis, from_us: u64, to_us: u64, feed: Option<Message>) {
    let mut t = from_us;
    while t < to_us {
        t += 1_000;
        if let Some(m) = feed {
            if t % 10_000 == 0 {
                a.handle(&m, t);
            }
        }
        a.step(0.001, t);
    }
}

#[test]
fn velocity_mode_reaches_the_setpoint_within_the_acceleration_limit() {
    let mut a = armed(AxisConfig::WHEEL, ControlMode::Velocity);
    let cmd = Message::SetInputVel {
        vel_turns_per_s: 5.0,
        torque_ff_nm: 0.0,
    };
    a.handle(&cmd, 0);
    a.step(0.001, 1_000);
    // First millisecond: capped by 100 turns/s² -> 0.1 turns/s.
    assert!((a.vel_turns_per_s() - 0.1).abs() < 1e-5);
    run(&mut a, 1_000, 500_000, Some(cmd));
    assert!((a.vel_turns_per_s() - 5.0).abs() < 1e-3);
}

#[test]
fn position_mode_settles_on_the_target() {
    let mut a = armed(AxisConfig::JOINT, ControlMode::Position);
    let cmd = Message::SetInputPos {
        pos_turns: 2.0,
        vel_ff_turns_per_s: 0.0,
        torque_ff_nm: 0.0,
    };
    a.handle(&cmd, 0);
    run(&mut a, 0, 1_000_000, Some(cmd));
    assert!((a.pos_turns() - 2.0).abs() < 1e-4, "{}", a.pos_turns());
    assert_eq!(a.error(), 0);
}

#[test]
fn watchdog_idles_the_axis_and_the_wheel_spins_down() {
    let mut a = armed(watched(AxisConfig::WHEEL), ControlMode::Velocity);
    let cmd = Message::SetInputVel {
        vel_turns_per_s: 5.0,
        torque_ff_nm: 0.0,
    };
    run(&mut a, 0, 300_000, Some(cmd));
    assert_eq!(a.state(), AxisState::ClosedLoopControl);
    // Commands stop at 300 ms: the watchdog fires 100 ms later.
    run(&mut a, 300_000, 390_000, None);
    assert_eq!(a.state(), AxisState::ClosedLoopControl);
    run(&mut a, 390_000, 900_000, None);
    assert_eq!(a.state(), AxisState::Idle);
    assert_eq!(a.error(), axis_error::WATCHDOG_TIMER_EXPIRED);
    assert!(a.vel_turns_per_s().abs() < 1e-3);
    // Latched: re-arming fails until errors are cleared.
    a.handle(
        &Message::SetAxisState(AxisState::ClosedLoopControl),
        900_000,
    );
    assert_eq!(a.state(), AxisState::Idle);
    a.handle(&Message::ClearErrors, 900_000);
    a.handle(
        &Message::SetAxisState(AxisState::ClosedLoopControl),
        900_000,
    );
    assert_eq!(a.state(), AxisState::ClosedLoopControl);
}

#[test]
fn out_of_range_setpoints_and_estop_latch_errors() {
    let mut a = armed(AxisConfig::JOINT, ControlMode::Position);
    a.handle(
        &Message::SetInputPos {
            pos_turns: 50.0,
            vel_ff_turns_per_s: 0.0,
            torque_ff_nm: 0.0,
        },
        0,
    );
    assert_eq!(a.error(), axis_error::CONTROLLER_FAILED);
    assert_eq!(a.state(), AxisState::Idle);
    assert_eq!(a.stats().refused, 1);
    let mut w = armed(AxisConfig::WHEEL, ControlMode::Velocity);
    w.handle(
        &Message::SetInputVel {
            vel_turns_per_s: 11.0,
            torque_ff_nm: 0.0,
        },
        0,
    );
    assert_eq!(w.error(), axis_error::CONTROLLER_FAILED);
    let mut e = armed(AxisConfig::WHEEL, ControlMode::Velocity);
    e.handle(&Message::Estop, 0);
    assert_eq!(e.error(), axis_error::ESTOP_REQUESTED);
    assert_eq!(e.state(), AxisState::Idle);
}

#[test]
fn a_deaf_axis_runs_on_its_last_setpoint_until_its_watchdog() {
    let mut a = armed(watched(AxisConfig::WHEEL), ControlMode::Velocity);
    let go = Message::SetInputVel {
        vel_turns_per_s: 5.0,
        torque_ff_nm: 0.0,
    };
    run(&mut a, 0, 300_000, Some(go));
    a.set_deaf(true);
    // The stop command is lost: the wheel keeps its speed until the watchdog fires.
    let stop = Message::SetInputVel {
        vel_turns_per_s: 0.0,
        torque_ff_nm: 0.0,
    };
    run(&mut a, 300_000, 390_000, Some(stop));
    assert!((a.vel_turns_per_s() - 5.0).abs() < 1e-3);
    assert_eq!(a.stats().watchdog_trips, 0);
    run(&mut a, 390_000, 1_000_000, Some(stop));
    assert_eq!(a.state(), AxisState::Idle);
    assert_eq!(a.error(), axis_error::WATCHDOG_TIMER_EXPIRED);
    assert!(a.vel_turns_per_s().abs() < 1e-3);
}

#[test]
fn reports_come_at_their_rates_and_silence_suppresses_them() {
    let mut a = SimAxis::new(NodeId::new(5).unwrap(), AxisConfig::JOINT, 0.0);
    let mut out = Vec::new();
    let mut t = 0;
    while t < 1_000_000 {
        a.poll_tx(t, &mut out);
        t += 1_000;
    }
    let heartbeats = out.iter().filter(|f| f.raw_id() == (5 << 5 | 0x01)).count();
    let estimates = out.iter().filter(|f| f.raw_id() == (5 << 5 | 0x09)).count();
    assert_eq!((heartbeats, estimates), (10, 100));
    out.clear();
    a.set_silent(true);
    a.handle(&Message::Request(CmdId::GetEncoderEstimates), t);
    a.poll_tx(t + 100_000, &mut out);
    assert!(out.is_empty());
}

#[test]
fn an_unconfigured_axis_never_trips_its_watchdog() {
    for (config, mode) in [
        (AxisConfig::WHEEL, ControlMode::Velocity),
        (AxisConfig::JOINT, ControlMode::Position),
    ] {
        assert_eq!(config.watchdog_timeout_us, 0, "off unless configured");
        let mut a = armed(config, mode);
        // Armed, then nothing for a minute: a client may wait for the heartbeat to confirm
        // closed loop before it streams setpoints, however long that takes.
        run(&mut a, 0, 60_000_000, None);
        assert_eq!(a.state(), AxisState::ClosedLoopControl);
        assert_eq!((a.error(), a.stats().watchdog_trips), (0, 0));
        assert_eq!(a.last_watchdog_trip_us(), None);
        // Setpoints, then silence again: still no trip.
        let go = Message::SetInputVel {
            vel_turns_per_s: 1.0,
            torque_ff_nm: 0.0,
        };
        run(&mut a, 60_000_000, 60_100_000, Some(go));
        run(&mut a, 60_100_000, 70_000_000, None);
        assert_eq!(a.state(), AxisState::ClosedLoopControl);
        assert_eq!(a.error(), 0);
    }
}

#[test]
fn a_configured_watchdog_is_fed_by_setpoints_and_trips_after_its_timeout() {
    let mut a = armed(AxisConfig::WHEEL, ControlMode::Velocity);
    a.config_mut().watchdog_timeout_us = 50_000;
    let go = Message::SetInputVel {
        vel_turns_per_s: 2.0,
        torque_ff_nm: 0.0,
    };
    // A setpoint every 10 ms for a second: fed, never tripped.
    run(&mut a, 0, 1_000_000, Some(go));
    assert_eq!(a.state(), AxisState::ClosedLoopControl);
    assert_eq!(a.last_setpoint_us(), 1_000_000);
    // A request is not a setpoint: it does not feed the watchdog.
    a.handle(&Message::Request(CmdId::GetVersion), 1_020_000);
    run(&mut a, 1_000_000, 1_050_000, None);
    assert_eq!(a.state(), AxisState::ClosedLoopControl, "at the timeout");
    run(&mut a, 1_050_000, 1_051_000, None);
    assert_eq!(a.state(), AxisState::Idle, "one step past it");
    assert_eq!(a.error(), axis_error::WATCHDOG_TIMER_EXPIRED);
    assert_eq!(a.last_watchdog_trip_us(), Some(1_051_000));
    assert_eq!(a.stats().watchdog_trips, 1);
    // A refused setpoint does not feed it either: out of range latches an error instead.
    let mut b = armed(AxisConfig::WHEEL, ControlMode::Velocity);
    b.config_mut().watchdog_timeout_us = 50_000;
    b.handle(&go, 10_000);
    assert_eq!(b.last_setpoint_us(), 10_000);
    b.handle(
        &Message::SetInputVel {
            vel_turns_per_s: 99.0,
            torque_ff_nm: 0.0,
        },
        40_000,
    );
    assert_eq!(b.last_setpoint_us(), 10_000);
}

#[test]
fn get_version_is_answered_with_the_configured_version() {
    let mut a = SimAxis::new(NodeId::new(9).unwrap(), AxisConfig::JOINT, 0.0);
    // 0.5.x by default: no Get_Version, so no answer, asked or not.
    assert_eq!(a.config().version, None);
    assert!(Version::ODRIVE_0_5_6.speaks_this_codec());
    let mut out = Vec::new();
    // Never sent unasked.
    let mut t = 0;
    while t < 1_000_000 {
        a.poll_tx(t, &mut out);
        t += 1_000;
    }
    a.handle(&Message::Request(CmdId::GetVersion), t);
    a.poll_tx(t, &mut out);
    assert!(out.iter().all(|f| f.raw_id() != 9 << 5));
    out.clear();
    let v0_6_11 = Version {
        fw_version_minor: 6,
        fw_version_revision: 11,
        ..Version::ODRIVE_0_5_6
    };
    for (version, want) in [
        (Version::ODRIVE_0_5_6, [2, 3, 6, 56, 0, 5, 6, 0]),
        (v0_6_11, [2, 3, 6, 56, 0, 6, 11, 0]),
    ] {
        a.config_mut().version = Some(version);
        a.handle(&Message::Request(CmdId::GetVersion), t);
        a.poll_tx(t, &mut out);
        let answers: Vec<_> = out.drain(..).filter(|f| f.raw_id() == 9 << 5).collect();
        assert_eq!(answers.len(), 1);
        assert_eq!(answers[0].data(), &want);
        t += 1_000;
    }
    // Clear_Errors as before: every latched bit goes.
    a.handle(&Message::SetAxisState(AxisState::EncoderIndexSearch), t);
    assert_eq!(a.error(), axis_error::INVALID_STATE);
    a.handle(&Message::ClearErrors, t);
    assert_eq!(a.error(), 0);
}
