//! `demo --controller qemu`: the on-board stack and the motor commands in the controller
//! firmware's production image in QEMU.

use super::{print_report, Args, ClockArg, LogFile};
use crate::cli::CliResult;
use wheelleg::closed_loop::Tolerance;
use wheelleg_firmware_sim::candump::{CandumpWriter, DEFAULT_EPOCH_US};
use wheelleg_runtime::can::node_map::Axis;
use wheelleg_runtime::robot::Robot;
use wheelleg_sim::env::{Env, EnvConfig};
use wheelleg_sim::render::top_view;
use wheelleg_sim::scenario::Scenario;

/// `demo --controller qemu`: the episode through the firmware in QEMU, the image built with
/// `--policy`'s weights when one is given (their robot `robot`, already checked against
/// `--robot`), in a world of `env_config`.
pub(super) fn run_qemu(
    args: &Args,
    scenario: &Scenario,
    origin: &str,
    robot: &Robot,
    env_config: EnvConfig,
) -> CliResult {
    use wheelleg::hil::{
        find_or_build_image, image_with_weights,
        plant::{PlantClock, PlantFault},
        Faults, Hil, PERIOD_BUDGET_CYCLES,
    };
    let refused = [
        (
            args.can.is_some(),
            "--can (the firmware's CAN adapter is the simulated one)",
        ),
        (args.planner, "--planner"),
        (
            args.policy.is_some() && args.firmware.is_some(),
            "--policy with --firmware (the image's weights are built into it; --policy alone \
             builds an image with them)",
        ),
        (
            !args.stack.is_robot_default(),
            "a stack other than the default robot one",
        ),
        (
            args.tolerance_mm.is_some() || args.tolerance_deg.is_some(),
            "--tolerance-mm or --tolerance-deg (the firmware in the loop runs in lockstep, \
             against the loop's own tolerances)",
        ),
    ];
    if let Some((_, what)) = refused.iter().find(|(given, _)| *given) {
        return Err(format!(
            "--controller qemu runs the firmware's own stack (policy, guard on the fine \
             window, arrival): {what} does not apply"
        )
        .into());
    }
    let clock = match args.clock {
        ClockArg::Lockstep => PlantClock::Lockstep,
        ClockArg::Emulated => PlantClock::Emulated,
    };
    let image = match &args.policy {
        Some(policy) => {
            // The firmware halts at boot on weights its stack refuses: say why here instead.
            let bytes = std::fs::read(policy)
                .map_err(|e| format!("cannot read {}: {e}", policy.display()))?;
            wheelleg::hil::onboard::OnboardDriver::new(&bytes).map_err(|e| {
                format!(
                    "{}: the controller firmware cannot run these weights: {}",
                    policy.display(),
                    e.0
                )
            })?;
            image_with_weights(policy, clock)?
        }
        None => find_or_build_image(args.firmware.as_deref(), clock)?,
    };
    let say = |line: std::fmt::Arguments<'_>| {
        if !args.json {
            outln!("{line}");
        }
    };
    let mut env = Env::new(scenario, env_config).map_err(|e| e.to_string())?;
    let legs = env.state().leg_config(env.geometry());
    let mut faults = Faults::default();
    if let (Some(node), Some(at)) = (args.silent_node, args.silent_at_step) {
        if let Some(axis) = Axis::ALL
            .into_iter()
            .find(|&a| robot.can.node_id(a).get() == node)
        {
            say(format_args!(
                "inject:    node {node} ({axis:?}) goes silent during step {at}"
            ));
            faults.plant.push((at, PlantFault::SilentAxis(axis)));
        }
    }
    if let Some(ms) = args.inject_decision_ms {
        say(format_args!(
            "inject:    decision {} spends {ms} ms more on the controller",
            args.inject_at_step
        ));
        faults.slow_decision = Some((args.inject_at_step, ms));
    }
    say(format_args!(
        "scene:     {} ({origin}); target {:.2} m away",
        scenario.name,
        env.distance_to_target_m()
    ));
    let weights = args.policy.as_ref().map_or_else(
        || "the shipped int8 policy".to_owned(),
        |policy| format!("the int8 policy {}", policy.display()),
    );
    say(format_args!(
        "driver:    the controller firmware {} in QEMU mps2-an386 (Cortex-M4F): {weights}, \
         decision rule, collision guard on the 1 cm fine window, arrival",
        image.display()
    ));
    let timing = match clock {
        PlantClock::Lockstep => "in lockstep",
        PlantClock::Emulated => "on QEMU's instruction clock (250 M instructions/s)",
    };
    say(format_args!(
        "links:     observation link on UART 1 (COBS, CRC-16, postcard); SLCAN adapter on \
         UART 2, 16 simulated ODrive axes behind it, 1 Mbit/s, control 100 Hz {timing}"
    ));
    std::fs::create_dir_all(&args.out)
        .map_err(|e| format!("cannot create {}: {e}", args.out.display()))?;
    let mut hil = Hil::start(&image, robot, legs, clock)?;
    let (log_file, writer) = LogFile::create(args.out.join("bus.log"))?;
    hil.plant()
        .log_to(CandumpWriter::new(writer, "slcan0", DEFAULT_EPOCH_US));
    let wall_clock = std::time::Instant::now();
    let episode = hil.run(&mut env, &faults);
    let taken = hil.plant().take_log();
    let episode = episode?;
    taken.map_err(|e| format!("cannot write the bus log: {e}"))?;
    log_file.commit()?;
    let ram = hil.ram_use()?;
    let busiest_period = hil.busiest_period_instructions()?;
    hil.shutdown()?;
    let report = &episode.report;
    let png = args.out.join("path.png");
    top_view(scenario, &robot.geometry, &report.path, &report.collided_at)?
        .save_png(&png)
        .map_err(|e| format!("cannot write {}: {e}", png.display()))?;
    if args.json {
        let result = match (report.status, report.fault) {
            (_, Some(_)) => "stopped".to_owned(),
            (status, None) => format!("{status:?}"),
        };
        let held = episode.held.map(|held| {
            serde_json::json!({
                "periods": held.steps / 10,
                "max_leg_change_mm": 1e3 * held.max_leg_change_m,
                "max_wheel_speed_sum_turns_per_s": held.max_wheel_speed_sum,
            })
        });
        let timed = clock == PlantClock::Emulated;
        let json = serde_json::json!({
            "scene": scenario.name,
            "clock": format!("{:?}", clock).to_lowercase(),
            "result": result,
            "fault": report.fault.map(|f| f.to_string()),
            "decisions": report.steps,
            "collisions": report.collisions,
            "deadline_misses": episode.deadline_misses,
            "periods": episode.periods,
            "periods_stamped": timed.then_some(episode.timing.periods),
            "periods_late": timed.then_some(episode.timing.late),
            "worst_period_lateness_ms":
                timed.then_some(episode.timing.worst_lateness_us as f64 * 1e-3),
            "axis_watchdog_trips": episode.watchdog_trips,
            "robot_time_s": report.elapsed_s,
            "busiest_period_instructions": busiest_period,
            "ram_bytes": ram.total_bytes(),
            "held_through_slow_decision": held,
        });
        outln!("{json}");
        return match report.fault {
            Some(fault) => Err(format!("robot stopped: {fault}").into()),
            None => Ok(()),
        };
    }
    // The firmware in the loop checks steps against the default tolerances.
    print_report(
        report,
        wall_clock.elapsed().as_secs_f64(),
        &Tolerance::default(),
    );
    outln!(
        "wrote:     {} and {} ({} frames)",
        png.display(),
        args.out.join("bus.log").display(),
        report.traffic.frames
    );
    outln!(
        "RAM:       {} bytes in use on the controller (statics {}, stack at its deepest {}, \
         painted by QEMU's loader)",
        ram.total_bytes(),
        ram.statics_bytes,
        ram.peak_stack_bytes
    );
    outln!(
        "period:    at most {busiest_period} instructions of work in one control period ({:.1} % \
         of its 10 ms at 170 MHz, one cycle per instruction)",
        100.0 * busiest_period as f64 / PERIOD_BUDGET_CYCLES as f64
    );
    if clock == PlantClock::Emulated {
        outln!(
            "clock:     {} periods on QEMU's instruction clock, {} late (the latest {:.3} ms after \
             its due time), {} axis watchdog trips",
            episode.timing.periods,
            episode.timing.late,
            episode.timing.worst_lateness_us as f64 * 1e-3,
            episode.watchdog_trips
        );
    }
    if episode.deadline_misses > 0 {
        outln!(
            "deadline:  {} decisions abandoned at their deadline, decided again",
            episode.deadline_misses
        );
    }
    if let Some(held) = episode.held {
        outln!(
            "held:      through the slow decision {} periods, legs within {:.3} mm, wheels at \
             most {:.4} turns/s",
            held.steps / 10,
            1e3 * held.max_leg_change_m,
            held.max_wheel_speed_sum
        );
    }
    match report.fault {
        Some(fault) => Err(format!("robot stopped: {fault}").into()),
        None => Ok(()),
    }
}
