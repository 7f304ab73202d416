//! Fault soak of the closed loop: many planner-driven episodes on solvable scenes,
//! each with a seeded mix of CAN faults, asserting the documented safe behaviour every time
//! (docs/can-protocol.md, "Safety"; figures in docs/robustness.md):
//!
//! - **lossy bus** (frames dropped, duplicated, delayed by up to 15 ms, after start-up): the
//!   episode either succeeds exactly as planned or stops with a fault; never an error, never a
//!   collision;
//! - **a node goes silent mid-motion** (at a random instant inside a random step; half of
//!   these nodes still hear commands, the other half drop off the bus entirely and run on their
//!   last setpoint until their own watchdog idles them): the controller is in safe stop within
//!   the silence timeout (50 ms) plus one control tick, one encoder period and the largest bus
//!   delay;
//! - **the controller's transmit path hangs mid-motion**: every armed axis's watchdog idles it
//!   between 100 and 101 ms after the last setpoint it received;
//! - always: no collision, judged both by the world on its lattice states and on the robot's
//!   *true* pose (the simulated motors' own motion, which a silent or lying node cannot
//!   corrupt) at the end of every control tick, stops included; every planned step is free
//!   along its whole path (checked at every control tick's pose), which is where the
//!   controlled safe stop rests; at rest, the wheels are stopped and the legs hold.
//!
//! Runs in release (the workspace's test profile is optimised) in well under two minutes.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::indexing_slicing)]

use nalgebra::{Isometry2, Vector2};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::time::Instant;
use wheelleg::closed_loop::{ClosedLoop, Fault, LoopConfig, StepKind};
use wheelleg_firmware_sim::bus::Faults;
use wheelleg_firmware_sim::rig::{true_wheel_speed_sum, Rig, StopReason, TimedFault, TrueSample};
use wheelleg_runtime::can::node_map::Axis;
use wheelleg_runtime::can::protocol::AxisState;
use wheelleg_sim::env::Status;
use wheelleg_sim::state::RobotState;

mod figures;
mod scenes;
mod truth;

use figures::Figures;
use scenes::{plan_states, planned_scenes, Planned};
use truth::{joint_positions, off_path, rest_time_us, true_pose_collides};

/// Episodes of the soak: four fault kinds, cycled, over the scenes.
const EPISODES: u64 = 80;
/// Largest delay a delayed frame gets: longer than a control tick, so frames overtake each
/// other and a stale setpoint can land after a fresh one.
const MAX_DELAY_US: u64 = 15_000;
/// Silence timeout, control tick and encoder period of the default rig (docs/can-protocol.md).
const SILENCE_TIMEOUT_US: u64 = 50_000;
const TICK_US: u64 = 10_000;
const ENCODER_PERIOD_US: u64 = 10_000;
const WATCHDOG_TIMEOUT_US: u64 = 100_000;
const PHYSICS_DT_US: u64 = 1_000;
/// Poses checked along each planned step: one per control tick of a 0.5 s step.
pub(crate) const SWEEP_SAMPLES: u32 = 50;

/// The fault injected into one episode besides the lossy bus.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Injected {
    /// Only the lossy bus.
    None,
    /// This axis stops transmitting (and, if the flag is set, receiving) at this simulated
    /// time.
    Silence(Axis, u64, bool),
    /// The controller stops sending at this simulated time.
    Hang(u64),
}

fn run_episode(planned: &Planned, episode: u64, figures: &mut Figures) {
    let mut rng = ChaCha8Rng::seed_from_u64(9_000 + episode);
    let faults = Faults {
        drop_probability: rng.random_range(0.0..0.06),
        delay_probability: rng.random_range(0.0..0.15),
        delay_us: rng.random_range(500..=MAX_DELAY_US),
        duplicate_probability: rng.random_range(0.0..0.08),
        seed: rng.random(),
    };
    let what = format!("episode {episode} ({}, {faults:?})", planned.scene.name);
    let mut closed_loop = ClosedLoop::in_process(&planned.scene, LoopConfig::default()).unwrap();
    closed_loop.start().unwrap();
    // Faults after start-up: arming is a supervised procedure of its own, not under test here.
    closed_loop.rig().bus().set_faults(faults);
    let start_state = *closed_loop.env().state();
    let start = Isometry2::new(
        Vector2::new(start_state.position.x, start_state.position.y),
        start_state.yaw_rad(),
    );
    let obstacles = closed_loop.env().obstacles().clone();
    closed_loop.rig_mut().record_truth(true);
    // Every control tick of the true motion is checked against the obstacles: at no tick,
    // under control, stopping or at rest, may the robot touch one (the world proves every
    // planned step clear all the way; a fault stops the robot on that way).
    let check_truth = |rig: &mut Rig, figures: &mut Figures, when: &str| {
        let samples = rig.take_truth();
        for sample in &samples {
            figures.true_pose_checks += 1;
            if true_pose_collides(sample, start, &obstacles) {
                figures.contacts.push(episode);
                panic!(
                    "{what}: {when}: the robot's true pose touches an obstacle at {} µs \
                     (stopped at {:?} µs): {sample:?}",
                    sample.at_us,
                    rig.stopped_at_us()
                );
            }
        }
        samples
    };
    let mut truth_log: Vec<TrueSample> = Vec::new();
    let mut faulted_step: Option<(RobotState, RobotState)> = None;
    let fault_step = rng.random_range(0..planned.actions.len());
    let step_us = 500_000;
    let offset_us = rng.random_range(0..step_us);
    let mut injected = Injected::None;
    let mut world_states = vec![start_state];
    for (index, &action) in planned.actions.iter().enumerate() {
        if closed_loop.is_done() {
            break;
        }
        if index == fault_step {
            let at_us = closed_loop.rig().now_us() + offset_us;
            injected = match episode % 4 {
                0 => Injected::None,
                1 | 3 => {
                    let axis = Axis::from_index(rng.random_range(0..16)).unwrap();
                    // A quarter of the episodes each: a mute node that still obeys, and a node
                    // off the bus that the controller cannot command any more.
                    let (fault, deaf) = if episode % 4 == 1 {
                        (TimedFault::Disconnect(axis), true)
                    } else {
                        (TimedFault::Silence(axis), false)
                    };
                    closed_loop.rig_mut().schedule(at_us, fault);
                    Injected::Silence(axis, at_us, deaf)
                }
                _ => {
                    closed_loop
                        .rig_mut()
                        .schedule(at_us, TimedFault::HangCommands);
                    Injected::Hang(at_us)
                }
            };
        }
        let record = closed_loop
            .step(action)
            .unwrap_or_else(|e| panic!("{what}: step {index}: loop error {e}"));
        assert!(
            matches!(record.kind, StepKind::Moved | StepKind::Faulted),
            "{what}: step {index} was {:?}: the planned path is free and reachable",
            record.kind
        );
        let from = *world_states.last().unwrap();
        if record.kind == StepKind::Moved {
            world_states.push(*closed_loop.env().state());
        }
        figures.steps += 1;
        truth_log.extend(check_truth(
            closed_loop.rig_mut(),
            figures,
            &format!("step {index}"),
        ));
        if record.kind == StepKind::Faulted {
            faulted_step = Some((from, from.after(action)));
        }
    }
    let report = closed_loop.finish().unwrap();
    // Let whatever the fault set in motion come to rest (a stop in the last tick of the
    // episode, a watchdog that has just fired), then check the rest state twice.
    closed_loop.rig_mut().hold(0.4).unwrap();
    truth_log.extend(check_truth(closed_loop.rig_mut(), figures, "at rest"));
    let rig = closed_loop.rig();
    figures.episodes += 1;
    let kind = match injected {
        Injected::Silence(_, _, false) => 0,
        Injected::Silence(_, _, true) => 1,
        Injected::Hang(_) => 2,
        Injected::None => 3,
    };
    let stop_figures = &mut figures.stops[kind];
    stop_figures.kind = [
        "silent, hearing",
        "off the bus",
        "controller hung",
        "lossy bus only",
    ][kind];
    if let Some(stop_us) = rig.stopped_at_us() {
        stop_figures.stops += 1;
        stop_figures.worst_stop_to_rest_us = stop_figures
            .worst_stop_to_rest_us
            .max(rest_time_us(&truth_log, stop_us));
    }
    if let Some((from, to)) = faulted_step {
        // Where the stopped robot rests, against the path of the step it stopped in.
        let legs = rig.true_legs().unwrap();
        let (d_m, d_rad, d_legs_m) = off_path(&from, &to, start * rig.true_pose(), legs);
        figures.mid_step_stops += 1;
        stop_figures.worst_off_path_m = stop_figures.worst_off_path_m.max(d_m);
        stop_figures.worst_off_path_rad = stop_figures.worst_off_path_rad.max(d_rad);
        stop_figures.worst_off_path_legs_m = stop_figures.worst_off_path_legs_m.max(d_legs_m);
    }

    // The world never moved through a collision, and moved only along the plan.
    assert_eq!(report.collisions, 0, "{what}");
    assert_eq!(report.path, world_states, "{what}");
    assert_eq!(
        &report.path[..],
        &plan_states(planned)[..report.path.len()],
        "{what}: the world left the planned path"
    );
    match report.fault {
        None => {
            assert_eq!(report.status, Status::Success, "{what}");
            figures.succeeded += 1;
            // Success means every step was within tolerance: the true pose is where the world
            // says, up to the per-step residuals (2 mm each) the snap rule leaves.
            let world = report.path.last().unwrap();
            let truth = start * rig.true_pose();
            let drift = (Vector2::new(world.position.x, world.position.y)
                - truth.translation.vector)
                .norm();
            figures.worst_true_drift_m = figures.worst_true_drift_m.max(drift);
            assert!(
                drift < 0.002 * report.steps as f32,
                "{what}: true pose {drift} m from the world"
            );
        }
        Some(Fault::SafeStop { reason, .. }) => match reason {
            StopReason::Silent(_) => figures.safe_stops_silent += 1,
            StopReason::AxisError(_) => figures.safe_stops_error += 1,
            // The soak injects only silent, lost and erring axes.
            other => panic!("{what}: safe stop for {other:?}"),
        },
        Some(Fault::OffTolerance { .. }) => figures.off_tolerance += 1,
        // The in-process loop has no controller firmware to stop it: either is a bug here.
        Some(Fault::KinematicsDisagree { .. } | Fault::Controller { .. }) => {
            panic!("{what}: {:?}", report.fault)
        }
    }

    // At rest, whatever happened: wheels stopped, legs holding still.
    assert!(
        true_wheel_speed_sum(rig.firmware()) < 1e-3,
        "{what}: wheels still turning at {} turns/s",
        true_wheel_speed_sum(rig.firmware())
    );
    let joints_before: Vec<f32> = joint_positions(rig);
    closed_loop.rig_mut().hold(0.2).unwrap();
    let rig = closed_loop.rig();
    for (before, after) in joints_before.iter().zip(joint_positions(rig)) {
        assert!(
            (after - before).abs() < 1e-4,
            "{what}: a joint moved at rest"
        );
    }

    // A fault injected while the robot was already stopped (by an earlier false alarm of the
    // lossy bus) has nothing left to stop.
    let still_running_at = |at_us: u64| rig.stopped_at_us().is_none_or(|stop| stop >= at_us);
    match injected {
        Injected::None => {}
        Injected::Silence(axis, at_us, deaf) if still_running_at(at_us) => {
            if deaf {
                figures.silent_disconnected += 1;
            } else {
                figures.silent_hearing += 1;
            }
            // The silence happened while the robot was still under control: the controller
            // must have noticed it in time and stopped.
            let stop = rig
                .stopped_at_us()
                .unwrap_or_else(|| panic!("{what}: {axis:?} silent at {at_us} µs, no stop"));
            let bound = SILENCE_TIMEOUT_US + TICK_US + ENCODER_PERIOD_US + faults.delay_us;
            assert!(
                stop - at_us <= bound,
                "{what}: silent {axis:?} detected {} µs after (bound {bound})",
                stop - at_us
            );
            figures.worst_silence_detection_us =
                figures.worst_silence_detection_us.max(stop - at_us);
        }
        Injected::Silence(..) => {}
        Injected::Hang(at_us) => {
            for motor in rig.firmware().axes() {
                if motor.last_setpoint_us() + WATCHDOG_TIMEOUT_US < at_us {
                    // Already idle before the hang (safe stop does not disarm, so this is an
                    // axis the watchdog had already caught).
                    continue;
                }
                assert_eq!(motor.state(), AxisState::Idle, "{what}: {:?}", motor.node());
                let trip = motor
                    .last_watchdog_trip_us()
                    .unwrap_or_else(|| panic!("{what}: {:?} never tripped", motor.node()));
                let after = trip - motor.last_setpoint_us();
                assert!(
                    after > WATCHDOG_TIMEOUT_US && after <= WATCHDOG_TIMEOUT_US + PHYSICS_DT_US,
                    "{what}: {:?} idled {after} µs after its last setpoint",
                    motor.node()
                );
                figures.watchdog_trips += 1;
                figures.worst_watchdog_us = figures.worst_watchdog_us.max(after);
                figures.best_watchdog_us = if figures.best_watchdog_us == 0 {
                    after
                } else {
                    figures.best_watchdog_us.min(after)
                };
            }
            assert!(
                rig.stopped().is_some(),
                "{what}: the controller did not notice"
            );
        }
    }
    let counters = rig.bus().counters();
    figures.frames_sent += counters.sent;
    figures.dropped += counters.dropped;
    figures.delayed += counters.delayed;
    figures.duplicated += counters.duplicated;
}

#[test]
fn the_closed_loop_survives_every_injected_fault_safely() {
    let started = Instant::now();
    let scenes = planned_scenes();
    let mut figures = Figures::default();
    for episode in 0..EPISODES {
        let planned = &scenes[episode as usize % scenes.len()];
        run_episode(planned, episode, &mut figures);
    }
    eprintln!(
        "fault soak: {figures:#?}\nin {:.1} s",
        started.elapsed().as_secs_f64()
    );
    assert_eq!(figures.episodes as u64, EPISODES);
    // The soak really exercised what it claims: faults on the bus, stops of both kinds, and
    // watchdog trips (each assertion above ran, not only the fault-free branch).
    assert!(figures.dropped > 1_000 && figures.delayed > 1_000 && figures.duplicated > 1_000);
    assert!(
        figures.safe_stops_silent >= EPISODES as u32 / 8,
        "{figures:?}"
    );
    assert!(
        figures.safe_stops_error >= EPISODES as u32 / 8,
        "{figures:?}"
    );
    assert!(
        figures.watchdog_trips >= 16 * (EPISODES as u32 / 8),
        "{figures:?}"
    );
    assert!(figures.succeeded >= EPISODES as u32 / 8, "{figures:?}");
    // The goal of the safe stop: a fault never causes a collision, in any episode.
    assert!(figures.contacts.is_empty(), "{figures:?}");
    assert!(
        figures.silent_hearing >= EPISODES as u32 / 8
            && figures.silent_disconnected >= EPISODES as u32 / 8,
        "{figures:?}"
    );
}
