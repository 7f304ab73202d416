//! The controller firmware in the loop (`src/hil`): the production image in QEMU, the world and
//! the simulated motors on the host, joined by the observation link and the SLCAN adapter link.
//!
//! Run by `scripts/hil.sh` (`cargo test --workspace --release --test hil -- --ignored`), which
//! installs `scripts/embedded-toolchain.sh`'s QEMU and nightly toolchain and builds the images:
//! the tests take minutes, so the workspace's plain test run leaves them out. Without QEMU every
//! test prints a SKIPPED line and passes.
//!
//! - `WHEELLEG_HIL_SCENES` held-out complex scenes (default 2; after the first
//!   `WHEELLEG_HIL_SKIP`, default 0) reach exactly the
//!   outcomes (success, decisions, collisions) of the in-process closed loop driven by the same
//!   on-board stack, and the bus log decodes with ODrive's DBC (`tools/check_dbc.py`); the
//!   firmware's RAM in use (statics and its painted stack) fits 128 KiB, and its busiest control
//!   period (SysTick-timed work, read from its RAM) fits 10 ms at 170 MHz;
//! - each fault brings the robot to the safe state (wheels stopped, legs held) within the
//!   firmware's timeout, and the firmware says why;
//! - on the emulated clock (QEMU's instruction clock, which the firmware's decisions cost as
//!   on a board), the same scenes reach the same outcomes with every control period's
//!   setpoints on the bus within 1 ms of their due time and no axis watchdog tripping; a
//!   decision made 500 ms slow is abandoned at its deadline while the robot holds (legs
//!   within 0.5 mm, wheels stopped), and the robot goes on; the faults as in lockstep.

use std::path::{Path, PathBuf};
use wheelleg::closed_loop::{ClosedLoop, Driver, LoopConfig};
use wheelleg::hil::onboard::OnboardDriver;
use wheelleg::hil::plant::{PlantClock, PlantFault};
use wheelleg::hil::wire::stop_reason;
use wheelleg::hil::{
    find_or_build_image, qemu_available, Faults, Hil, HilEpisode, LinkFault, PERIOD_BUDGET_CYCLES,
};
use wheelleg_firmware_sim::candump::{CandumpWriter, DEFAULT_EPOCH_US};
use wheelleg_runtime::can::node_map::{Axis, Joint};
use wheelleg_runtime::robot::LegId;
use wheelleg_sim::env::{Env, EnvConfig};
use wheelleg_sim::scenario::Scenario;

mod support;

const SCENES: &str = "eval/heldout-complex-s1000000.json";

/// RAM of the budget's part (an STM32G474-class Cortex-M4F).
const RAM_BUDGET_BYTES: u32 = 128 * 1024;

/// Health timeout (50 ms) and the period in which the silence is seen, in control periods.
const HEALTH_PERIODS: u32 = 5 + 2;
/// The adapter's timeout (5 periods) and the period of the poll.
const CAN_LINK_PERIODS: u32 = 5 + 2;
/// The observation link's timeout (1 s).
const OBSERVATION_PERIODS: u32 = 100;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// The held-out scenes a run asks for: `WHEELLEG_HIL_SKIP` (default 0) left out, then
/// `WHEELLEG_HIL_SCENES` (default 2).
fn chosen_scenes() -> (usize, usize) {
    let var = |name: &str, default: usize| {
        std::env::var(name)
            .ok()
            .and_then(|n| n.parse().ok())
            .unwrap_or(default)
    };
    (var("WHEELLEG_HIL_SKIP", 0), var("WHEELLEG_HIL_SCENES", 2))
}

fn scenes() -> Vec<Scenario> {
    let json = std::fs::read_to_string(root().join(SCENES)).expect("held-out scenes");
    wheelleg_sim::scenario_file::parse(&json, &wheelleg_sim::robot::SimulatedRobot::SHIPPED)
        .expect("scenes parse")
}

/// Both clocks the loop runs on.
const CLOCKS: [PlantClock; 2] = [PlantClock::Lockstep, PlantClock::Emulated];

/// The image for `clock`, or `None` (with the SKIPPED line) when QEMU is missing.
fn image(test: &str, clock: PlantClock) -> Option<PathBuf> {
    if !qemu_available() {
        println!("SKIPPED {test}: qemu-system-arm is missing (bash scripts/embedded-toolchain.sh)");
        return None;
    }
    Some(find_or_build_image(None, clock).unwrap_or_else(|e| panic!("{e}")))
}

fn run(
    image: &Path,
    clock: PlantClock,
    scene: &Scenario,
    faults: &Faults,
    log: Option<&Path>,
) -> (Hil, HilEpisode) {
    let mut env = Env::new(scene, EnvConfig::default()).expect("scene");
    let legs = env.state().leg_config(env.geometry());
    let mut hil = Hil::start(
        image,
        &wheelleg_runtime::robot::Robot::WHEELLEG,
        legs,
        clock,
    )
    .unwrap_or_else(|e| panic!("{e}"));
    if let Some(path) = log {
        let file = std::fs::File::create(path).expect("log file");
        let writer: Box<dyn std::io::Write + Send> = Box::new(std::io::BufWriter::new(file));
        hil.plant()
            .log_to(CandumpWriter::new(writer, "slcan0", DEFAULT_EPOCH_US));
    }
    let episode = hil.run(&mut env, faults).unwrap_or_else(|e| panic!("{e}"));
    if log.is_some() {
        hil.plant().take_log().expect("log flushed");
    }
    (hil, episode)
}

#[test]
#[ignore = "the firmware in QEMU, minutes: scripts/hil.sh runs it"]
fn firmware_in_the_loop_reaches_the_in_process_outcomes() {
    let Some(image) = image(
        "firmware_in_the_loop_reaches_the_in_process_outcomes",
        PlantClock::Lockstep,
    ) else {
        return;
    };
    let (skip, count) = chosen_scenes();
    let weights = std::fs::read(root().join("weights/policy.wlw")).expect("weights");
    let out = root().join("target/hil");
    std::fs::create_dir_all(&out).expect("out dir");
    let mut differs = Vec::new();
    let mut worst_period = 0;
    for scene in scenes().iter().skip(skip).take(count) {
        let expected = in_process_outcome(scene, &weights);
        let log = out.join(format!("{}.log", scene.name));
        let (mut hil, got) = run(
            &image,
            PlantClock::Lockstep,
            scene,
            &Faults::default(),
            Some(&log),
        );
        let ram = hil.ram_use().unwrap_or_else(|e| panic!("{e}"));
        let busiest = hil
            .busiest_period_instructions()
            .unwrap_or_else(|e| panic!("{e}"));
        hil.shutdown().expect("shutdown");
        // The control periods ran (SysTick measured their work) and the busiest fits its
        // 10 ms at 170 MHz, one cycle per instruction.
        assert!(
            busiest > 10_000 && busiest <= PERIOD_BUDGET_CYCLES,
            "{}: busiest control period {busiest} instructions",
            scene.name
        );
        worst_period = worst_period.max(busiest);
        // The stack was painted and reached into the paint; with the statics it fits the
        // budget's 128 KiB of an STM32G474-class part.
        assert!(
            ram.peak_stack_bytes > 1024 && ram.total_bytes() <= RAM_BUDGET_BYTES,
            "{}: {ram:?}",
            scene.name
        );
        let got = got.report;
        let line = format!(
            "{}: host {:?} {} decisions {} collisions; firmware {:?} {} decisions {} collisions, \
             RAM {} bytes (stack {}), busiest period {busiest} instructions",
            scene.name,
            expected.0,
            expected.1,
            expected.2,
            got.status,
            got.steps,
            got.collisions,
            ram.total_bytes(),
            ram.peak_stack_bytes
        );
        // Printed as it comes: a run over many scenes shows its progress.
        println!("{line}");
        if got.fault.is_some() || (got.status, got.steps, got.collisions) != expected {
            differs.push(format!("{line}; fault {:?}", got.fault));
        }
        let checked = std::process::Command::new("python3")
            .arg(root().join("tools/check_dbc.py"))
            .arg(&log)
            .output()
            .expect("python3 runs tools/check_dbc.py");
        if !checked.status.success() {
            differs.push(format!(
                "{}: the bus log does not decode with ODrive's DBC: {}",
                scene.name,
                String::from_utf8_lossy(&checked.stderr)
            ));
        }
    }
    println!(
        "busiest control period over {count} scenes: {worst_period} instructions ({:.1} % of \
         {PERIOD_BUDGET_CYCLES} cycles)",
        100.0 * worst_period as f64 / PERIOD_BUDGET_CYCLES as f64
    );
    assert!(
        differs.is_empty(),
        "{} of {count} scenes differ from the host's closed loop:\n{}",
        differs.len(),
        differs.join("\n")
    );
}

/// Runs scene 0 with `faults` and checks the firmware's safe stop: its reason, that it came
/// within `within` periods of `since` (the fault's period), and, where the motors still hear
/// the firmware, that the wheels stand and the legs hold half a second later.
fn expect_stop(
    test: &str,
    faults: Faults,
    reason: u8,
    within: u32,
    since: impl Fn(&HilEpisode) -> u32,
    motors_reachable: bool,
) -> Vec<HilEpisode> {
    CLOCKS
        .into_iter()
        .map(|clock| {
            let test = format!("{test} ({clock:?} clock)");
            expect_stop_on(
                &test,
                clock,
                &faults,
                reason,
                within,
                &since,
                motors_reachable,
            )
        })
        .collect()
}

/// [`expect_stop`] on one clock.
fn expect_stop_on(
    test: &str,
    clock: PlantClock,
    faults: &Faults,
    reason: u8,
    within: u32,
    since: &impl Fn(&HilEpisode) -> u32,
    motors_reachable: bool,
) -> HilEpisode {
    let Some(image) = image(test, clock) else {
        return empty_episode();
    };
    let scene = scenes().into_iter().next().expect("a scene");
    let (hil, episode) = run(&image, clock, &scene, faults, None);
    let stop = episode
        .stop
        .unwrap_or_else(|| panic!("{test}: no safe stop: {:?}", episode.report));
    assert_eq!(stop.reason, reason, "{test}: {stop}");
    let from = since(&episode);
    assert!(
        stop.tick >= from && stop.tick <= from + within,
        "{test}: stopped in period {} for a fault in period {from} (timeout {within})",
        stop.tick
    );
    if motors_reachable {
        // Half a second in safe stop, then the motors' own state.
        assert!(hil.wait_periods(20), "{test}: the firmware stopped ticking");
        let before = hil.plant().truth();
        assert!(hil.wait_periods(50), "{test}: the firmware stopped ticking");
        let after = hil.plant().truth();
        assert!(
            after.wheel_speed_sum < 0.05,
            "{test}: wheels still turn: {} turns/s",
            after.wheel_speed_sum
        );
        let moved_m = (after.legs.clearance_m - before.legs.clearance_m)
            .abs()
            .max((after.legs.track_m - before.legs.track_m).abs());
        assert!(
            moved_m < 0.0005,
            "{test}: legs moved {moved_m} m in safe stop"
        );
        let drift_m = (before.pose.inverse() * after.pose)
            .translation
            .vector
            .norm();
        assert!(
            drift_m < 0.0005,
            "{test}: the base moved {drift_m} m in safe stop"
        );
    }
    println!("{test}: {stop}");
    hil.shutdown().expect("shutdown");
    episode
}

fn empty_episode() -> HilEpisode {
    HilEpisode {
        report: wheelleg::closed_loop::EpisodeReport {
            status: wheelleg_sim::env::Status::Running,
            steps: 0,
            collisions: 0,
            fault: None,
            tracking: Default::default(),
            path: Vec::new(),
            collided_at: Vec::new(),
            odometry_drift_m: 0.0,
            odometry_drift_rad: 0.0,
            elapsed_s: 0.0,
            traffic: Default::default(),
            bus_load: None,
            feedback: Default::default(),
        },
        stop: None,
        rejected: 1,
        last_step_tick: None,
        injected: Vec::new(),
        deadline_misses: 0,
        held: None,
        periods: 0,
        timing: Default::default(),
        watchdog_trips: 0,
    }
}

fn injected_period(episode: &HilEpisode) -> u32 {
    episode
        .injected
        .first()
        .map_or(u32::MAX, |(p, _)| *p as u32)
}

fn after_last_step(episode: &HilEpisode) -> u32 {
    episode.last_step_tick.unwrap_or(u32::MAX)
}

#[test]
#[ignore = "the firmware in QEMU, minutes: scripts/hil.sh runs it"]
fn a_silent_axis_stops_the_robot_within_the_health_timeout() {
    let knee = Axis::Joint(LegId::ALL[1], Joint::Knee);
    let episodes = expect_stop(
        "a_silent_axis_stops_the_robot_within_the_health_timeout",
        Faults {
            plant: vec![(2, PlantFault::SilentAxis(knee))],
            ..Faults::default()
        },
        stop_reason::SILENT_AXES,
        HEALTH_PERIODS,
        injected_period,
        true,
    );
    for stop in episodes.iter().filter_map(|e| e.stop) {
        assert!(stop.axes.contains(knee), "{stop}");
    }
}

#[test]
#[ignore = "the firmware in QEMU, minutes: scripts/hil.sh runs it"]
fn lost_frames_on_the_can_link_stop_the_robot() {
    expect_stop(
        "lost_frames_on_the_can_link_stop_the_robot",
        Faults {
            plant: vec![(2, PlantFault::DropFrames(0.8))],
            ..Faults::default()
        },
        stop_reason::SILENT_AXES,
        // Some axis misses five estimates in a row within a few periods at this loss.
        HEALTH_PERIODS + 20,
        injected_period,
        true,
    );
}

#[test]
#[ignore = "the firmware in QEMU, minutes: scripts/hil.sh runs it"]
fn a_dead_can_link_stops_the_robot_within_the_adapter_timeout() {
    expect_stop(
        "a_dead_can_link_stops_the_robot_within_the_adapter_timeout",
        Faults {
            plant: vec![(2, PlantFault::DeadLink)],
            ..Faults::default()
        },
        stop_reason::CAN_LINK,
        CAN_LINK_PERIODS,
        injected_period,
        // Nothing reaches the motors any more: their own watchdog (100 ms) idles them.
        false,
    );
}

#[test]
#[ignore = "the firmware in QEMU, minutes: scripts/hil.sh runs it"]
fn a_stalled_observation_link_stops_the_robot_within_its_timeout() {
    expect_stop(
        "a_stalled_observation_link_stops_the_robot_within_its_timeout",
        Faults {
            link: Some(LinkFault::StallAt(3)),
            ..Faults::default()
        },
        stop_reason::OBSERVATION_STALLED,
        OBSERVATION_PERIODS + 2,
        after_last_step,
        true,
    );
}

#[test]
#[ignore = "the firmware in QEMU, minutes: scripts/hil.sh runs it"]
fn corrupt_observation_frames_are_refused_and_stop_the_robot() {
    let episodes = expect_stop(
        "corrupt_observation_frames_are_refused_and_stop_the_robot",
        Faults {
            link: Some(LinkFault::CorruptAt(3)),
            ..Faults::default()
        },
        stop_reason::OBSERVATION_CORRUPT,
        OBSERVATION_PERIODS + 2,
        after_last_step,
        true,
    );
    assert!(
        episodes.iter().all(|e| e.rejected > 0),
        "no frame was refused"
    );
}

/// The in-process closed loop's outcome of `scene` with the same on-board stack.
fn in_process_outcome(scene: &Scenario, weights: &[u8]) -> (wheelleg_sim::env::Status, u32, u32) {
    let mut driver = OnboardDriver::new(weights).expect("stack");
    let mut host = ClosedLoop::in_process(scene, LoopConfig::default()).expect("loop");
    host.start().expect("start-up");
    while !host.is_done() {
        let action = driver.decide(host.env()).expect("decision");
        host.step(action).expect("step");
    }
    let expected = host.finish().expect("finish");
    (expected.status, expected.steps, expected.collisions)
}

#[test]
#[ignore = "the firmware in QEMU, minutes: scripts/hil.sh runs it"]
fn on_the_emulated_clock_every_period_is_on_time_and_the_outcomes_hold() {
    let test = "on_the_emulated_clock_every_period_is_on_time_and_the_outcomes_hold";
    let Some(image) = image(test, PlantClock::Emulated) else {
        return;
    };
    let (skip, count) = chosen_scenes();
    let weights = std::fs::read(root().join("weights/policy.wlw")).expect("weights");
    let mut differs = Vec::new();
    let (mut periods, mut worst_lateness_us) = (0, 0);
    for scene in scenes().iter().skip(skip).take(count) {
        let expected = in_process_outcome(scene, &weights);
        let (hil, got) = run(
            &image,
            PlantClock::Emulated,
            scene,
            &Faults::default(),
            None,
        );
        hil.shutdown().expect("shutdown");
        let report = &got.report;
        let line = format!(
            "{}: host {:?} {} decisions {} collisions; firmware {:?} {} decisions {} \
             collisions; {} periods, {} late (worst {:.3} ms), {} watchdog trips, {} deadlines \
             missed",
            scene.name,
            expected.0,
            expected.1,
            expected.2,
            report.status,
            report.steps,
            report.collisions,
            got.timing.periods,
            got.timing.late,
            got.timing.worst_lateness_us as f64 * 1e-3,
            got.watchdog_trips,
            got.deadline_misses
        );
        println!("{line}");
        periods += got.timing.periods;
        worst_lateness_us = worst_lateness_us.max(got.timing.worst_lateness_us);
        let outcome = (report.status, report.steps, report.collisions);
        if report.fault.is_some()
            || outcome != expected
            || got.timing.periods < 100
            || got.timing.late > 0
            || got.watchdog_trips > 0
        {
            differs.push(format!("{line}; fault {:?}", report.fault));
        }
    }
    println!(
        "emulated clock over {count} scenes: {periods} periods, the latest {:.3} ms after its \
         due time",
        worst_lateness_us as f64 * 1e-3
    );
    assert!(
        differs.is_empty(),
        "{} of {count} scenes late, tripped or off the host's outcomes:\n{}",
        differs.len(),
        differs.join("\n")
    );
}

#[test]
#[ignore = "the firmware in QEMU, minutes: scripts/hil.sh runs it"]
fn a_slow_decision_holds_the_robot_and_then_it_goes_on() {
    let test = "a_slow_decision_holds_the_robot_and_then_it_goes_on";
    let Some(image) = image(test, PlantClock::Emulated) else {
        return;
    };
    let weights = std::fs::read(root().join("weights/policy.wlw")).expect("weights");
    let scene = scenes().into_iter().next().expect("a scene");
    let expected = in_process_outcome(&scene, &weights);
    // 500 ms in the second decision (the first starts the robot up): past the 100 ms deadline.
    let faults = Faults {
        slow_decision: Some((2, 500)),
        ..Faults::default()
    };
    let (hil, got) = run(&image, PlantClock::Emulated, &scene, &faults, None);
    hil.shutdown().expect("shutdown");
    let held = got.held.expect("the slow decision was watched");
    println!(
        "{test}: held {} periods, legs moved {:.4} mm, wheels at most {:.5} turns/s; {} \
         deadline missed; {} late periods, {} watchdog trips; {:?} in {} decisions",
        held.steps / 10,
        1e3 * held.max_leg_change_m,
        held.max_wheel_speed_sum,
        got.deadline_misses,
        got.timing.late,
        got.watchdog_trips,
        got.report.status,
        got.report.steps
    );
    assert!(held.steps >= 450, "{test}: watched only {} ms", held.steps);
    assert!(held.max_leg_change_m < 0.0005, "{test}: {held:?}");
    assert!(held.max_wheel_speed_sum < 0.05, "{test}: {held:?}");
    assert_eq!(got.deadline_misses, 1, "{test}");
    assert_eq!((got.timing.late, got.watchdog_trips), (0, 0), "{test}");
    assert_eq!(got.report.fault, None, "{test}");
    assert_eq!(
        (got.report.status, got.report.steps, got.report.collisions),
        expected,
        "{test}"
    );
}

#[test]
#[ignore = "the firmware in QEMU, minutes: scripts/hil.sh runs it"]
fn another_robot_s_weights_run_on_the_firmware() {
    use rand::SeedableRng;
    use wheelleg_sim::generate::{generate, SceneRobot};
    let test = "another_robot_s_weights_run_on_the_firmware";
    if !qemu_available() {
        println!("SKIPPED {test}: qemu-system-arm is missing (bash scripts/embedded-toolchain.sh)");
        return;
    }
    let strider = wheelleg_robot::RobotDescription::load(&root().join("robots/strider.toml"))
        .expect("robots/strider.toml");
    let out = root().join("target/hil");
    std::fs::create_dir_all(&out).expect("out dir");
    let weights_path = out.join("strider.wlw");
    let weights = support::shipped_network_for(&strider);
    std::fs::write(&weights_path, &weights).expect("weights written");
    let image = wheelleg::hil::image_with_weights(&weights_path, PlantClock::Emulated)
        .unwrap_or_else(|e| panic!("{e}"));
    // A straight scene fitted to the strider, its target moved to within one step: the first
    // decision arrives (the arrival rule), so the episode is short and its outcome certain.
    let simulated = wheelleg_sim::robot::SimulatedRobot::of(&strider).expect("simulated robot");
    let mut rng = rand::rngs::StdRng::seed_from_u64(2);
    let mut scene = generate(
        SceneRobot::of(&simulated),
        wheelleg_sim::generate::SceneKind::Behaviour(wheelleg_sim::generate::Behaviour::Straight),
        &mut rng,
        "strider-straight".into(),
    );
    let yaw_rad = scene.start.yaw_rad();
    let ahead_m = EnvConfig::default().success_radius_m + 0.02;
    scene.target = scene.start.position;
    scene.target.x += ahead_m * yaw_rad.cos();
    scene.target.y += ahead_m * yaw_rad.sin();
    let env_config = EnvConfig {
        robot: simulated,
        ..EnvConfig::default()
    };
    // The host's in-process loop with the firmware's stack on the same weights and robot.
    let mut driver = OnboardDriver::new(&weights).expect("stack");
    let config = LoopConfig {
        env: env_config,
        node_map: strider.robot.can,
        ..LoopConfig::default()
    };
    let mut host = ClosedLoop::in_process(&scene, config).expect("loop");
    host.start().expect("start-up");
    while !host.is_done() {
        let action = driver.decide(host.env()).expect("decision");
        host.step(action).expect("step");
    }
    let expected = host.finish().expect("finish");

    let mut env = Env::new(&scene, env_config).expect("scene");
    let legs = env.state().leg_config(env.geometry());
    let mut hil = Hil::start(&image, &strider.robot, legs, PlantClock::Emulated)
        .unwrap_or_else(|e| panic!("{e}"));
    let log = out.join("strider.log");
    let file = std::fs::File::create(&log).expect("log file");
    let writer: Box<dyn std::io::Write + Send> = Box::new(std::io::BufWriter::new(file));
    hil.plant()
        .log_to(CandumpWriter::new(writer, "slcan0", DEFAULT_EPOCH_US));
    let got = hil
        .run(&mut env, &Faults::default())
        .unwrap_or_else(|e| panic!("{e}"));
    hil.plant().take_log().expect("log flushed");
    hil.shutdown().expect("shutdown");
    let report = &got.report;
    println!(
        "{test}: host {:?} in {} decisions; firmware {:?} in {} decisions, {} periods, {} late, \
         {} watchdog trips",
        expected.status,
        expected.steps,
        report.status,
        report.steps,
        got.timing.periods,
        got.timing.late,
        got.watchdog_trips
    );
    assert_eq!(report.fault, None, "{test}");
    assert_eq!(report.status, wheelleg_sim::env::Status::Success, "{test}");
    assert_eq!(
        (report.status, report.steps, report.collisions),
        (expected.status, expected.steps, expected.collisions),
        "{test}"
    );
    assert_eq!((got.timing.late, got.watchdog_trips), (0, 0), "{test}");
    // Every frame on the bus is the strider's (nodes 21 to 36): the roll call, the arming and
    // the setpoints went to its node map, read from the weights at boot.
    let text = std::fs::read_to_string(&log).expect("log");
    let mut frames = 0;
    for line in text.lines() {
        let id = line
            .split_whitespace()
            .nth(2)
            .and_then(|f| f.split('#').next())
            .expect("a candump line");
        let node = u32::from_str_radix(id, 16).expect("hex id") >> 5;
        assert!((21..=36).contains(&node), "{test}: {line}");
        frames += 1;
    }
    assert!(frames > 500, "{test}: {frames} frames");
}
