//! The simulated axes over a real SocketCAN interface. Runs only where a `vcan*` interface
//! exists (`ip link add dev vcan0 type vcan && ip link set up vcan0`); elsewhere it says why it
//! skipped and passes.

#[cfg(all(feature = "socketcan", target_os = "linux"))]
#[test]
fn axes_answer_over_socketcan() {
    use std::time::{Duration, Instant};
    use wheelleg_firmware_sim::bus::Transport;
    use wheelleg_firmware_sim::firmware::Firmware;
    use wheelleg_firmware_sim::socketcan::{find_vcan, SocketCan};
    use wheelleg_runtime::can::host::{Commander, FeedbackTracker, TxQueue};
    use wheelleg_runtime::can::protocol::AxisState;
    use wheelleg_runtime::can::{Axis, CanFrame, NodeMap};
    use wheelleg_runtime::leg::LegConfig;
    use wheelleg_runtime::robot::WHEELLEG;

    let Some(iface) = find_vcan() else {
        eprintln!(
            "SKIPPED axes_answer_over_socketcan: no vcan interface on this machine \
             (create one with `ip link add dev vcan0 type vcan && ip link set up vcan0`)"
        );
        return;
    };
    let (mut host, mut fw_bus) = match (SocketCan::open(&iface), SocketCan::open(&iface)) {
        (Ok(h), Ok(f)) => (h, f),
        (Err(e), _) | (_, Err(e)) => {
            eprintln!("SKIPPED axes_answer_over_socketcan: cannot open {iface}: {e}");
            return;
        }
    };
    let legs = LegConfig {
        clearance_m: WHEELLEG.default_clearance_m,
        track_m: WHEELLEG.default_track_m,
    };
    let mut firmware = Firmware::for_robot(&WHEELLEG, &NodeMap::NOMINAL, legs).unwrap();
    let commander = Commander::new(NodeMap::NOMINAL);
    let mut tracker = FeedbackTracker::new(NodeMap::NOMINAL);
    let mut tx: TxQueue<CanFrame, 64> = TxQueue::new();
    commander.queue_startup(&mut tx).unwrap();
    while let Some(f) = tx.pop() {
        host.send(&f, 0).unwrap();
    }
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_millis(500) {
        let now_us = t0.elapsed().as_micros() as u64;
        firmware.run(&mut fw_bus, now_us, 0.001).unwrap();
        while let Some(f) = host.recv(now_us).unwrap() {
            tracker.receive(&f, now_us);
        }
        std::thread::sleep(Duration::from_millis(1));
    }
    for axis in Axis::ALL {
        let fb = tracker.axis(axis).unwrap();
        assert_eq!(
            fb.axis_state,
            Some(AxisState::ClosedLoopControl),
            "{axis:?}"
        );
    }
    assert_eq!(tracker.stats().malformed, 0);
}

#[cfg(not(all(feature = "socketcan", target_os = "linux")))]
#[test]
fn axes_answer_over_socketcan() {
    eprintln!("SKIPPED axes_answer_over_socketcan: built without the `socketcan` feature");
}
