//! `wheelleg demo [--scenarios FILE [--name NAME]] [--policy FILE | --planner] [--stack policy|robot|full] [--can IFACE |
//! slcan:tcp:HOST:PORT] [--controller host|qemu] [--out DIR] [--seed S]`: the closed loop (world -> policy or planner -> CAN -> motors -> measured motion
//! -> world) on one scene, with a picture of the achieved path and the bus traffic as a
//! `candump -L` log. The shipped policy is built into the binary, so the demo drives the same
//! way from any folder. With `--controller qemu` the on-board stack and the motor commands run
//! in the controller firmware's production image in QEMU, on its two serial links
//! ([`wheelleg::hil`]).
//!
//! Exit status: 0 when the episode ran to its end (success or not: a policy failing a scene is
//! a result, not an error); non-zero when the robot had to be stopped (a [`Fault`]: silent
//! node, axis error, step off its ideal) or the loop could not run at all. Outputs are written
//! in every case where the loop started.

mod bus;
mod qemu;

use super::robot::RobotArg;
use super::stack_args::StackArgs;
use super::CliResult;
use bus::{open_slcan, open_socketcan, LogFile};
use qemu::run_qemu;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use std::borrow::Cow;
use std::io::Write;
use std::path::PathBuf;
use wheelleg::closed_loop::{
    leg_behaviours, ClosedLoop, Driver, EpisodeReport, Fault, LoopConfig, LoopError, PlannerDriver,
    PolicyDriver, Tolerance, BITRATE_BPS,
};
use wheelleg_firmware_sim::candump::{CandumpWriter, DEFAULT_EPOCH_US};
use wheelleg_firmware_sim::rig::RigError;
use wheelleg_robot::RobotDescription;
use wheelleg_runtime::action::ActionLattice;
use wheelleg_runtime::can::node_map::{Axis, NodeMap};
use wheelleg_sim::env::{Env, EnvConfig, Status};
use wheelleg_sim::generate::{generate, SceneKind, SceneRobot};
use wheelleg_sim::planner::PlannerConfig;
use wheelleg_sim::render::top_view;
use wheelleg_sim::robot::SimulatedRobot;
use wheelleg_sim::scenario::Scenario;
use wheelleg_stack::policy::Int8Policy;

/// The shipped int8 policy (`weights/policy.wlw`, its model card beside it), built into the
/// binary: the demo's driver when neither `--policy` nor `--planner` is given.
pub const SHIPPED_WEIGHTS: &[u8] = include_bytes!("../../weights/policy.wlw");

/// How the shipped weights are named in the demo's report.
const SHIPPED_LABEL: &str = "shipped weights/policy.wlw, built in";

/// Composed scenes (a leg behaviour's fence amid clutter) drawn from the seed until the planner
/// solves one: a default scene the demo cannot finish would demonstrate nothing.
const MAX_SCENE_DRAWS: u32 = 20;

/// Planner effort when choosing the default scene: solvable scenes plan in well under this,
/// while proving one unsolvable can take minutes, so a draw that needs more is skipped.
const SCENE_CHOICE_EXPANSIONS: usize = 5_000;

/// Where the robot's controller runs (`--controller`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ControllerArg {
    /// In this process: the host's control loop.
    Host,
    /// The controller firmware in QEMU.
    Qemu,
}

/// The motors' clock in the firmware's loop (`--clock`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ClockArg {
    /// One control period per status poll of the firmware.
    Lockstep,
    /// QEMU's instruction clock, stamped by the firmware.
    Emulated,
}

/// Arguments of `demo`.
#[derive(clap::Args)]
pub struct Args {
    /// Scenario file (JSON); the first scenario, or the one named by --name. Default: a
    /// generated composed scene, a leg behaviour amid clutter (see --seed).
    #[arg(long, alias = "scenario")]
    scenarios: Option<PathBuf>,
    /// Name of the scenario to run from --scenarios.
    #[arg(long, requires = "scenarios")]
    name: Option<String>,
    /// The policy: a weights file (.wlw). Default: the shipped policy, built into the binary.
    #[arg(long, alias = "weights", conflicts_with = "planner")]
    policy: Option<PathBuf>,
    /// Drive by the exact planner's action sequence instead of a policy (see
    /// --max-expansions; proving a hard scene can take minutes).
    #[arg(long)]
    planner: bool,
    /// SocketCAN interface with the motors on it (for example vcan0, with
    /// `firmware_sim --can vcan0` running), or slcan:tcp:HOST:PORT for motors behind an SLCAN
    /// adapter on TCP (`firmware_sim --slcan tcp:HOST:PORT`). Default: in-process bus with
    /// simulated motors.
    #[arg(long)]
    can: Option<String>,
    /// Where the robot's on-board stack runs: `host` (in this process) or `qemu` (the
    /// controller firmware's production image in QEMU's mps2-an386, its observation link and
    /// SLCAN adapter link on two UARTs, the simulated motors behind the adapter;
    /// docs/controller.md). The firmware drives with its built-in policy, guard and arrival.
    #[arg(long, value_name = "WHERE", value_enum, default_value_t = ControllerArg::Host)]
    controller: ControllerArg,
    /// The firmware image for --controller qemu. Default: the production image of
    /// controller/ for the --clock, built when missing.
    #[arg(long, value_name = "ELF")]
    firmware: Option<PathBuf>,
    /// With --controller qemu, what the motors' time follows: `lockstep` (one control period
    /// per poll of the firmware, however fast QEMU runs) or `emulated` (QEMU's instruction
    /// clock at 250 M instructions/s, which the firmware's decisions cost as on a board; the
    /// image is built with its `emulated-clock` feature).
    #[arg(long, value_enum, default_value_t = ClockArg::Lockstep)]
    clock: ClockArg,
    /// With --controller qemu, a slow decision: the firmware spends this many milliseconds
    /// busy in one decision (see --inject-at-step), and must hold the robot through them.
    #[arg(long, value_name = "MS")]
    inject_decision_ms: Option<u32>,
    /// ...in this decision (1-based; the first starts the robot up).
    #[arg(long, default_value_t = 2, requires = "inject_decision_ms")]
    inject_at_step: u32,
    /// With --controller qemu, print one JSON object (result, decisions, periods, timing,
    /// watchdog trips, the hold through a slow decision) instead of the report.
    #[arg(long)]
    json: bool,
    /// Output directory for path.png and bus.log (created if missing).
    #[arg(long, default_value = "out/demo")]
    out: PathBuf,
    /// Seed of the generated composed scene (the default's: a bar to lift over beyond clutter,
    /// 24 decisions with the legs lifted and narrowed).
    #[arg(long, default_value_t = 5)]
    seed: u64,
    /// Planner effort, in expanded states.
    #[arg(long, default_value_t = 200_000)]
    max_expansions: usize,
    /// How far a step may end from its ideal pose before the loop holds the robot, in
    /// millimetres. Default: the loop's own, 2 mm, what the simulated motors keep on a clean
    /// bus; a real-time link through a host's scheduler (SocketCAN, SLCAN) can lag by more for
    /// a moment.
    #[arg(long, value_name = "MM")]
    tolerance_mm: Option<f32>,
    /// The same for the heading, in degrees. Default: the loop's own, 0.2.
    #[arg(long, value_name = "DEG")]
    tolerance_deg: Option<f32>,
    /// Fault injection (in-process bus only): this CAN node id goes silent...
    #[arg(long, requires = "silent_at_step")]
    silent_node: Option<u8>,
    /// ...from this decision on (1-based).
    #[arg(long, requires = "silent_node")]
    silent_at_step: Option<u32>,
    /// The decision stack.
    #[command(flatten)]
    stack: StackArgs,
    /// The robot: its geometry in the world, its node map on the bus; the weights must be
    /// trained for it.
    #[command(flatten)]
    robot: RobotArg,
}

/// The scene to run and how it was chosen.
fn scene(
    args: &Args,
    env_config: EnvConfig,
    planner: &PlannerConfig,
) -> Result<(Scenario, String), String> {
    let simulated = env_config.robot;
    if let Some(path) = &args.scenarios {
        let scenarios = wheelleg_sim::scenario_file::load(path, &simulated)
            .map_err(|e| format!("{}: {e}", path.display()))?;
        let chosen = match &args.name {
            Some(name) => scenarios
                .into_iter()
                .find(|s| &s.name == name)
                .ok_or_else(|| format!("{}: no scenario named {name:?}", path.display()))?,
            None => scenarios
                .into_iter()
                .next()
                .ok_or_else(|| format!("{}: contains no scenario", path.display()))?,
        };
        let origin = format!("from {}", path.display());
        return Ok((chosen, origin));
    }
    let mut rng = ChaCha8Rng::seed_from_u64(args.seed);
    let quick = PlannerConfig {
        max_expansions: planner.max_expansions.min(SCENE_CHOICE_EXPANSIONS),
        ..*planner
    };
    for draw in 0..MAX_SCENE_DRAWS {
        let scenario = generate(
            SceneRobot::of(&simulated),
            SceneKind::Composed,
            &mut rng,
            format!("composed-seed{}-{draw}", args.seed),
        );
        let env = Env::new(&scenario, env_config).map_err(|e| e.to_string())?;
        if PlannerDriver::new(&env, &quick).is_ok() {
            let origin = format!(
                "generated composed scene (seed {}, draw {}: first the planner solves)",
                args.seed,
                draw + 1
            );
            return Ok((scenario, origin));
        }
    }
    Err(format!(
        "none of the first {MAX_SCENE_DRAWS} composed scenes of seed {} is solvable within {} \
         planner expansions; try another --seed",
        args.seed, quick.max_expansions
    ))
}

/// A policy's weights file (built in or read) and how to name it.
type Weights = (Cow<'static, [u8]>, String);

/// The policy's weights and how to name them, or `None` when the planner drives. A file named
/// by `--policy` must exist: a missing one is an error, never a silent change of driver.
fn weights(args: &Args) -> Result<Option<Weights>, String> {
    if args.planner {
        return Ok(None);
    }
    match &args.policy {
        Some(path) if path.is_file() => std::fs::read(path)
            .map(|bytes| Some((Cow::Owned(bytes), path.display().to_string())))
            .map_err(|e| format!("cannot read {}: {e}", path.display())),
        Some(path) => Err(format!("--policy {}: no such file", path.display())),
        None => Ok(Some((
            Cow::Borrowed(SHIPPED_WEIGHTS),
            SHIPPED_LABEL.to_owned(),
        ))),
    }
}

/// The loop's tolerance with `--tolerance-mm` and `--tolerance-deg` in place of its own.
fn tolerance(args: &Args, lattice: &ActionLattice) -> Result<Tolerance, String> {
    // Half a lattice step: beyond it the world could snap a step to the wrong lattice state.
    for (flag, value, most) in [
        (
            "--tolerance-mm",
            args.tolerance_mm,
            0.5e3 * lattice.move_step_m,
        ),
        (
            "--tolerance-deg",
            args.tolerance_deg,
            0.5 * lattice.yaw_step_deg,
        ),
    ] {
        if let Some(value) = value.filter(|v| !(*v > 0.0 && *v < most)) {
            return Err(format!(
                "{flag} {value}: must be above 0 and below {most} (half a lattice step)"
            ));
        }
    }
    let own = Tolerance::default();
    Ok(Tolerance {
        position_m: args.tolerance_mm.map_or(own.position_m, |mm| 1e-3 * mm),
        yaw_rad: args.tolerance_deg.map_or(own.yaw_rad, f32::to_radians),
        ..own
    })
}

/// The loop on the chosen bus, not started.
fn closed_loop(
    args: &Args,
    scenario: &Scenario,
    robot: &RobotDescription,
    tolerance: Tolerance,
) -> Result<ClosedLoop, String> {
    let config = LoopConfig {
        tolerance,
        env: EnvConfig {
            robot: SimulatedRobot::of(robot)?,
            ..LoopConfig::default().env
        },
        node_map: robot.robot.can,
        ..LoopConfig::default()
    };
    let Some(iface) = &args.can else {
        return ClosedLoop::in_process(scenario, config).map_err(|e| e.to_string());
    };
    if args.silent_node.is_some() {
        return Err(
            "--silent-node needs the in-process bus (on SocketCAN use `firmware_sim \
                    --silent-node N`)"
                .to_owned(),
        );
    }
    let transport = match iface.strip_prefix("slcan:") {
        Some(endpoint) => open_slcan(endpoint)?,
        None => open_socketcan(iface)?,
    };
    ClosedLoop::remote(scenario, config, transport).map_err(|e| e.to_string())
}

/// Runs `demo`.
pub fn run(args: Args) -> CliResult {
    let qemu_only = [
        (args.clock != ClockArg::Lockstep, "--clock"),
        (args.inject_decision_ms.is_some(), "--inject-decision-ms"),
        (args.json, "--json"),
    ];
    if let Some((_, flag)) = qemu_only
        .iter()
        .find(|(given, _)| *given && args.controller == ControllerArg::Host)
    {
        return Err(
            format!("{flag} applies to the firmware in the loop: add --controller qemu").into(),
        );
    }
    let planner = PlannerConfig {
        max_expansions: args.max_expansions,
        ..PlannerConfig::default()
    };
    let (robot, simulated) = args.robot.simulated()?;
    let weights = weights(&args)?;
    if let Some((bytes, label)) = &weights {
        let policy = Int8Policy::from_bytes(bytes)
            .map_err(|e| format!("{label}: not a usable policy weights file: {e}"))?;
        robot.accepts(&policy.model().trained_for, label)?;
    }
    let tolerance = tolerance(&args, simulated.lattice())?;
    if let Some(node) = args.silent_node {
        if !Axis::ALL
            .iter()
            .any(|&a| robot.robot.can.node_id(a).get() == node)
        {
            return Err(format!(
                "--silent-node {node}: robot '{}' has no such node",
                robot.name
            )
            .into());
        }
    }
    let env_config = EnvConfig {
        robot: simulated,
        ..LoopConfig::default().env
    };
    let (scenario, origin) = scene(&args, env_config, &planner)?;
    if args.controller == ControllerArg::Qemu {
        return run_qemu(&args, &scenario, &origin, &robot.robot, env_config);
    }
    let mut closed_loop = closed_loop(&args, &scenario, &robot, tolerance)?;

    // Both drivers decide from the world as it is at the start of the episode.
    let mut driver: Box<dyn Driver + '_> = match &weights {
        Some((bytes, label)) => Box::new(PolicyDriver::new(bytes, label, args.stack.config()?)?),
        None => Box::new(
            PlannerDriver::new(closed_loop.env(), &planner)
                .map_err(|e| format!("--planner: the planner cannot drive: {e}"))?,
        ),
    };
    outln!(
        "scene:     {} ({origin}); target {:.2} m away",
        scenario.name,
        closed_loop.env().distance_to_target_m()
    );
    outln!("driver:    {}", driver.describe());
    match &args.can {
        None => {
            outln!("bus:       in-process, 16 simulated ODrive axes, 1 Mbit/s, control 100 Hz")
        }
        Some(iface) => match iface.strip_prefix("slcan:") {
            Some(endpoint) => outln!(
                "bus:       SLCAN adapter at {endpoint} (1 Mbit/s), motors on its bus, real time"
            ),
            None => outln!("bus:       SocketCAN {iface}, motors on the bus, real time"),
        },
    }

    std::fs::create_dir_all(&args.out)
        .map_err(|e| format!("cannot create {}: {e}", args.out.display()))?;
    let interface = match args.can.as_deref() {
        None => "can0",
        Some(iface) if iface.starts_with("slcan:") => "slcan0",
        Some(iface) => iface,
    };
    let (log_file, writer) = LogFile::create(args.out.join("bus.log"))?;
    let writer: Box<dyn Write> = writer;
    closed_loop.log_to(CandumpWriter::new(writer, interface, DEFAULT_EPOCH_US));
    let started = closed_loop.start();
    if let Err(e) = started {
        let _ = closed_loop.take_log();
        log_file.discard();
        return Err(match (&args.can, e) {
            (Some(iface), LoopError::Rig(RigError::StartupFailed(_))) => {
                let run = match iface.strip_prefix("slcan:") {
                    Some(endpoint) => format!("firmware_sim --slcan {endpoint}"),
                    None => format!("firmware_sim --can {iface}"),
                };
                format!("no motor controllers answered on {iface}: is `{run}` running?").into()
            }
            (_, e) => e.into(),
        });
    }

    let wall_clock = std::time::Instant::now();
    let mut failure: Option<LoopError> = None;
    while !closed_loop.is_done() {
        let step = closed_loop.env().steps() + 1;
        if let (Some(node), Some(at)) = (args.silent_node, args.silent_at_step) {
            if step == at {
                inject_silence(&mut closed_loop, &robot.robot.can, node);
            }
        }
        let decided = driver.decide(closed_loop.env()).map_err(LoopError::from);
        if let Err(e) = decided.and_then(|action| closed_loop.step(action)) {
            failure = Some(e);
            break;
        }
    }
    let report = match failure {
        None => closed_loop.finish()?,
        // Still write what happened before the loop broke.
        Some(_) => closed_loop.report(),
    };
    closed_loop.take_log()?;
    log_file.commit()?;
    let png = args.out.join("path.png");
    top_view(
        &scenario,
        simulated.geometry(),
        &report.path,
        &report.collided_at,
    )?
    .save_png(&png)
    .map_err(|e| format!("cannot write {}: {e}", png.display()))?;

    print_report(&report, wall_clock.elapsed().as_secs_f64(), &tolerance);
    outln!(
        "wrote:     {} and {} ({} frames)",
        png.display(),
        args.out.join("bus.log").display(),
        report.traffic.frames
    );
    if let Some(e) = failure {
        return Err(e.into());
    }
    match report.fault {
        Some(fault) => Err(format!("robot stopped: {fault}").into()),
        None => Ok(()),
    }
}

fn inject_silence(closed_loop: &mut ClosedLoop, node_map: &NodeMap, node: u8) {
    let step = closed_loop.env().steps() + 1;
    if let Some(axis) = Axis::ALL
        .into_iter()
        .find(|&a| node_map.node_id(a).get() == node)
    {
        if let Some(sim) = closed_loop.rig_mut().firmware_mut().axis_mut(axis) {
            outln!("inject:    node {node} ({axis:?}) goes silent before step {step}");
            sim.set_silent(true);
        }
    }
}

/// What the legs did along `path`: each behaviour with the decisions and the stretch of ground
/// it took.
fn describe_behaviours(path: &[wheelleg_sim::state::RobotState]) -> String {
    let found = leg_behaviours(path);
    if found.is_empty() {
        return "stayed in the default pose".into();
    }
    found
        .iter()
        .map(|b| {
            let what = match b.name {
                "lift" => "lifted the body",
                "spread" => "spread the legs",
                _ => "narrowed the legs",
            };
            let plural = if b.most_steps == 1 { "" } else { "s" };
            format!(
                "{what} ({}, up to {} lattice step{plural}) from decision {} to {}, \
                 ({:.2}, {:.2}) m to ({:.2}, {:.2}) m",
                b.name,
                b.most_steps,
                b.states.0,
                b.states.1,
                b.from_m.0,
                b.from_m.1,
                b.to_m.0,
                b.to_m.1
            )
        })
        .collect::<Vec<_>>()
        .join("; ")
}

/// `value` to the thousandth, so that a tolerance prints as given (2, not 2.0000002).
fn thousandths(value: f32) -> f32 {
    (value * 1e3).round() / 1e3
}

fn print_report(report: &EpisodeReport, wall_s: f64, tolerance: &Tolerance) {
    let result = match (report.status, report.fault) {
        (_, Some(Fault::SafeStop { .. } | Fault::Controller { .. })) => {
            "stopped safely (fault below)".to_owned()
        }
        (_, Some(_)) => "stopped (fault below)".to_owned(),
        (Status::Success, None) => "SUCCESS: reached the target".to_owned(),
        (Status::TooFar, None) => "failed: drove too far from the target".to_owned(),
        (Status::StepLimit, None) => "failed: step limit".to_owned(),
        (Status::Running, None) => "incomplete".to_owned(),
    };
    outln!("result:    {result}");
    outln!("legs:      {}", describe_behaviours(&report.path));
    let t = &report.tracking;
    outln!(
        "steps:     {} decisions ({} moved, {} undone by the world, {} refused by the legs), \
         {} collisions",
        report.steps,
        t.moved,
        t.undone,
        t.refused,
        report.collisions
    );
    outln!(
        "tracking:  worst step vs ideal {:.4} mm, {:.4}°, legs {:.4} mm (tolerance {} mm, {}°, \
         {} mm); odometry drift {:.3} mm, {:.4}° over the episode",
        1e3 * t.max_error.position_m,
        t.max_error.yaw_rad.to_degrees(),
        1e3 * t.max_error.legs_m,
        thousandths(1e3 * tolerance.position_m),
        thousandths(tolerance.yaw_rad.to_degrees()),
        thousandths(1e3 * tolerance.legs_m),
        1e3 * report.odometry_drift_m,
        report.odometry_drift_rad.to_degrees()
    );
    if let Some(load) = report.bus_load {
        outln!(
            "bus load:  {:.1} % nominal, {:.1} % worst-case stuffing at {:.0} Mbit/s \
             ({:.0} frames/s; {} feedback frames used, {} malformed)",
            100.0 * load.nominal,
            100.0 * load.worst_case,
            BITRATE_BPS / 1e6,
            load.frames_per_s,
            report.feedback.accepted,
            report.feedback.malformed
        );
    }
    outln!(
        "time:      {:.1} s robot time in {:.1} s wall clock",
        report.elapsed_s,
        wall_s
    );
    if let Some(fault) = report.fault {
        outln!("fault:     {fault}");
    }
}
