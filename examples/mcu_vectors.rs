//! Test vectors for the controller firmware (`controller/`), and the evaluation of the
//! controller's decision stack on the host.
//!
//! ```text
//! cargo run --release --example mcu_vectors -- vectors OUT_DIR [--decisions N]
//! cargo run --release --example mcu_vectors -- evaluate [--scenes N] [--whole-map]
//! ```
//!
//! Both drive the held-out complex scenes (`eval/heldout-complex-s1000000.json`) with the
//! firmware's own decision stack: this file compiles `controller/src/stack.rs` itself, so the
//! host decides with the very code the firmware runs, on the host's build of the runtime
//! (AVX2 kernel where the CPU has it).
//!
//! `vectors` writes, for scripts/mcu.sh:
//! - `decisions.bin`: at least N observations (whole episodes, in order) as the controller
//!   receives them (height map and state in millimetres, then the guard's fine window), and
//!   `decisions.expected`: the host's decision record for each (logits, greedy action and its
//!   guard verdict, the action taken, the guard level, candidates checked);
//! - `episode.bin`: one held-out episode driven through the host's closed loop (simulated
//!   ODrive axes on an in-process CAN bus), as the controller meets it: the start-up, each
//!   decision's observation, and per control period the frames the axes sent; with
//!   `episode.frames.expected` (every frame the host's controller sent, with its period) and
//!   `episode.decisions.expected`.
//!
//! `evaluate` runs the scenes to their end with the stack and prints success and
//! collision-free rates as JSON; `--whole-map` lets the guard read the whole 1 cm map in
//! metres, as the host's `eval --guard-map fine` does, instead of the controller's window.

use std::cell::RefCell;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::rc::Rc;

use embedded_can::{Frame, Id};
use wheelleg::closed_loop::{ClosedLoop, Driver, DriverError, LoopConfig, StepKind};
use wheelleg::hil::onboard::{DecisionRecord, Observation, OnboardDriver};
use wheelleg_firmware_sim::candump::{CandumpWriter, DEFAULT_EPOCH_US};
use wheelleg_runtime::action::Action;
use wheelleg_runtime::can::decode;
use wheelleg_runtime::guard::{CollisionGuard, GridMap, HeightMapRef, DEFAULT_MARGIN_M};
use wheelleg_sim::env::{Env, EnvConfig, Status};
use wheelleg_sim::height_map::MapGrid;
use wheelleg_sim::scenario::Scenario;

const SCENES: &str = "eval/heldout-complex-s1000000.json";
const WEIGHTS: &str = "weights/policy.wlw";
const VERSION: u32 = 1;
const TAG_END: u8 = 0;
const TAG_STARTUP: u8 = 1;
const TAG_DECISION: u8 = 2;
const TAG_TICK: u8 = 3;

type Result<T> = std::result::Result<T, String>;

fn main() {
    if let Err(error) = run() {
        eprintln!("mcu_vectors: {error}");
        std::process::exit(1);
    }
}

fn run() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let value = |name: &str| -> Result<Option<usize>> {
        match args.iter().position(|a| a == name) {
            Some(i) => args
                .get(i + 1)
                .and_then(|v| v.parse().ok())
                .map(Some)
                .ok_or_else(|| format!("{name} needs a number")),
            None => Ok(None),
        }
    };
    let weights = std::fs::read(WEIGHTS).map_err(|e| format!("{WEIGHTS}: {e}"))?;
    // The scenes are read for the robot the weights were trained for.
    let robot = OnboardDriver::new(&weights)
        .map_err(|e| format!("{WEIGHTS}: {}", e.0))?
        .robot();
    let simulated = wheelleg_sim::robot::SimulatedRobot::new(robot.geometry, robot.actions)
        .map_err(|e| format!("{WEIGHTS}: {e}"))?;
    let json = std::fs::read_to_string(SCENES).map_err(|e| format!("{SCENES}: {e}"))?;
    let scenes =
        wheelleg_sim::scenario_file::parse(&json, &simulated).map_err(|e| e.to_string())?;
    match args.first().map(String::as_str) {
        Some("vectors") => {
            let out = PathBuf::from(args.get(1).ok_or("vectors needs OUT_DIR")?);
            std::fs::create_dir_all(&out).map_err(|e| format!("{}: {e}", out.display()))?;
            let wanted = value("--decisions")?.unwrap_or(1000);
            vectors(&weights, &scenes, &out, wanted)
        }
        Some("evaluate") => {
            let count = value("--scenes")?.unwrap_or(scenes.len()).min(scenes.len());
            let whole_map = args.iter().any(|a| a == "--whole-map");
            evaluate(&weights, scenes.get(..count).unwrap_or(&[]), whole_map)
        }
        _ => {
            Err("usage: mcu_vectors vectors OUT_DIR [--decisions N] | evaluate [--scenes N]".into())
        }
    }
}

/// What the controller receives for one decision, and what the host decided on it.
struct Decided {
    observation: Observation,
    window_mm_le: Vec<u8>,
    record: DecisionRecord,
    /// The guard's strict verdict on the greedy action on the whole fine map in metres (the
    /// host's `--guard-map fine`), to set beside the window's.
    full_map_verdict: bool,
}

/// The controller's decision stack on the world's observations, with the whole fine map's
/// verdict beside the window's.
struct Robot<'w> {
    driver: OnboardDriver<'w>,
    guard: CollisionGuard,
}

impl<'w> Robot<'w> {
    fn new(weights: &'w [u8]) -> Result<Robot<'w>> {
        let driver = OnboardDriver::new(weights).map_err(|e| format!("{WEIGHTS}: {}", e.0))?;
        let window = driver.window();
        if window.side != MapGrid::GUARD_FINE.side || window.cell_m != MapGrid::GUARD_FINE.cell_m {
            return Err("the controller's fine map is not the host's GUARD_FINE".into());
        }
        let guard = CollisionGuard::new(&driver.robot(), DEFAULT_MARGIN_M);
        Ok(Robot { driver, guard })
    }

    /// One decision on `env` as it is now.
    fn decide(&mut self, env: &Env) -> Result<Decided> {
        self.decide_with(env, false)
    }

    /// One decision; with `whole_map`, the guard reads the whole fine map in metres (the
    /// host's `--guard-map fine`) instead of the controller's window.
    fn decide_with(&mut self, env: &Env, whole_map: bool) -> Result<Decided> {
        let decided = self.driver.decide_on(env, whole_map).map_err(|e| e.0)?;
        let bounds = self.driver.window();
        let grid = GridMap::new(self.driver.fine_map_m(), bounds.side, bounds.cell_m)
            .map_err(|e| e.to_string())?;
        let greedy = Action::from_index(usize::from(decided.record.greedy)).unwrap_or_default();
        let full_map_verdict = self
            .guard
            .check(HeightMapRef::Grid(grid), decided.observation.legs(), greedy)
            .is_ok();
        Ok(Decided {
            observation: decided.observation,
            window_mm_le: decided.window_mm_le,
            record: decided.record,
            full_map_verdict,
        })
    }
}

fn push_u32(out: &mut Vec<u8>, value: u32) {
    out.extend_from_slice(&value.to_le_bytes());
}

/// An observation record: flags (bit 0: first decision of an episode), map, state, window.
fn push_observation(out: &mut Vec<u8>, decided: &Decided, first: bool) {
    push_u32(out, u32::from(first));
    for h in decided.observation.height_mm {
        out.extend_from_slice(&h.to_le_bytes());
    }
    for s in decided.observation.state_mm {
        out.extend_from_slice(&s.to_le_bytes());
    }
    out.extend_from_slice(&decided.window_mm_le);
}

fn write(path: &Path, bytes: &[u8]) -> Result<()> {
    std::fs::write(path, bytes).map_err(|e| format!("{}: {e}", path.display()))
}

fn vectors(weights: &[u8], scenes: &[Scenario], out: &Path, wanted: usize) -> Result<()> {
    let mut robot = Robot::new(weights)?;
    let bounds = robot.driver.window();
    let mut records = Vec::new();
    let mut expected = Vec::new();
    let (mut count, mut episodes, mut disagreements) = (0usize, 0usize, 0usize);
    for scene in scenes {
        if count >= wanted {
            break;
        }
        let mut env = Env::new(scene, EnvConfig::default()).map_err(|e| format!("{e:?}"))?;
        robot.driver.reset();
        let mut first = true;
        while !env.status().is_done() {
            let decided = robot.decide(&env)?;
            push_observation(&mut records, &decided, first);
            expected.extend_from_slice(&decided.record.to_bytes());
            disagreements +=
                usize::from(decided.full_map_verdict != (decided.record.greedy_verdict == 0));
            first = false;
            count += 1;
            env.step(decided.record.action())
                .map_err(|_| "stepped a finished episode")?;
        }
        episodes += 1;
    }
    let mut header = Vec::new();
    header.extend_from_slice(b"WLDV");
    for word in [
        VERSION,
        count as u32,
        2 * bounds.cells() as u32,
        bounds.side as u32,
        (bounds.cell_m * 1.0e6).round() as u32,
        bounds.first_row as u32,
        bounds.rows as u32,
        bounds.first_col as u32,
        bounds.cols as u32,
    ] {
        push_u32(&mut header, word);
    }
    header.extend_from_slice(&records);
    write(&out.join("decisions.bin"), &header)?;
    write(&out.join("decisions.expected"), &expected)?;

    let episode = record_episode(weights, scenes, out)?;
    println!(
        "{{\"decisions\": {count}, \"episodes\": {episodes}, \"window_rows\": {}, \"window_cols\": {}, \
         \"greedy_verdicts_window_vs_full_map_differ\": {disagreements}, \"episode_scene\": \"{}\", \
         \"episode_decisions\": {}, \"episode_ticks\": {}, \"episode_frames_sent\": {}}}",
        bounds.rows, bounds.cols, episode.scene, episode.decisions, episode.ticks, episode.frames
    );
    Ok(())
}

/// The log the rig writes, readable while it writes.
#[derive(Clone, Default)]
struct SharedLog(Rc<RefCell<Vec<u8>>>);

impl Write for SharedLog {
    fn write(&mut self, bytes: &[u8]) -> std::io::Result<usize> {
        self.0.borrow_mut().extend_from_slice(bytes);
        Ok(bytes.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

/// The closed loop's driver: the controller's stack, remembering each decision and where in
/// the bus log it was taken.
struct Recorder<'w> {
    robot: Robot<'w>,
    log: SharedLog,
    decisions: Vec<(usize, Decided)>,
}

impl Driver for Recorder<'_> {
    fn describe(&self) -> String {
        "the controller's decision stack".into()
    }

    fn decide(&mut self, env: &Env) -> std::result::Result<Action, DriverError> {
        let decided = self.robot.decide(env).map_err(DriverError)?;
        let action = decided.record.action();
        let at = self.log.0.borrow().len();
        self.decisions.push((at, decided));
        Ok(action)
    }
}

struct EpisodeSummary {
    scene: String,
    decisions: usize,
    ticks: usize,
    frames: usize,
}

/// Set in a recorded frame's id for a remote (RTR) frame (the controller's check program reads
/// it back the same way: `controller/src/check/qemu.rs`).
const REMOTE_FLAG: u16 = 0x8000;

/// One logged frame: where its line starts in the log, its time, the frame.
struct Logged {
    offset: usize,
    time_us: u64,
    /// The standard id, with [`REMOTE_FLAG`] for a remote frame.
    id: u16,
    /// The DLC (a remote frame's asks for that many bytes and carries none).
    dlc: u8,
    data: Vec<u8>,
    command: bool,
}

fn parse_log(text: &str) -> Result<Vec<Logged>> {
    let mut offset = 0;
    let mut frames = Vec::new();
    for line in text.split_inclusive('\n') {
        let start = offset;
        offset += line.len();
        let entry = wheelleg_firmware_sim::candump::parse_line(line.trim_end(), frames.len() + 1)
            .map_err(|e| format!("bus log: {e:?}"))?;
        let frame = &entry.frame;
        let (_, message) = decode(frame).map_err(|e| format!("bus log: {e:?}"))?;
        let id = match frame.id() {
            Id::Standard(id) if frame.is_remote_frame() => id.as_raw() | REMOTE_FLAG,
            Id::Standard(id) => id.as_raw(),
            Id::Extended(_) => return Err("bus log: an extended id".into()),
        };
        frames.push(Logged {
            offset: start,
            time_us: entry.time_us,
            id,
            dlc: frame.dlc() as u8,
            data: frame.data().to_vec(),
            command: message.is_command(),
        });
    }
    Ok(frames)
}

fn push_frame(out: &mut Vec<u8>, frame: &Logged) {
    out.extend_from_slice(&frame.id.to_le_bytes());
    out.push(frame.dlc);
    let mut data = [0u8; 8];
    data[..frame.data.len().min(8)].copy_from_slice(&frame.data[..frame.data.len().min(8)]);
    out.extend_from_slice(&data);
}

/// Drives held-out scenes through the host's closed loop with the controller's stack until
/// one succeeds with every step moved as commanded (no step undone by the world: the
/// controller does not know the simulator's verdicts), and writes it as the episode vectors.
fn record_episode(weights: &[u8], scenes: &[Scenario], out: &Path) -> Result<EpisodeSummary> {
    for scene in scenes {
        let log = SharedLog::default();
        let mut closed =
            ClosedLoop::in_process(scene, LoopConfig::default()).map_err(|e| e.to_string())?;
        closed.log_to(CandumpWriter::new(
            Box::new(log.clone()),
            "can0",
            DEFAULT_EPOCH_US,
        ));
        let start_legs = closed.env().state().leg_config(closed.env().geometry());
        closed.start().map_err(|e| e.to_string())?;
        let mut recorder = Recorder {
            robot: Robot::new(weights)?,
            log: log.clone(),
            decisions: Vec::new(),
        };
        let mut clean = true;
        while !closed.is_done() {
            let action = recorder.decide(closed.env()).map_err(|e| e.to_string())?;
            let step = closed.step(action).map_err(|e| e.to_string())?;
            clean &= matches!(step.kind, StepKind::Moved | StepKind::Refused);
        }
        if !(clean && closed.fault().is_none() && closed.env().status() == Status::Success) {
            continue;
        }
        drop(closed);
        let text = String::from_utf8(log.0.borrow().clone()).map_err(|e| e.to_string())?;
        let frames = parse_log(&text)?;

        let mut episode = Vec::new();
        episode.extend_from_slice(b"WLEP");
        push_u32(&mut episode, VERSION);
        push_u32(&mut episode, start_legs.clearance_m.to_bits());
        push_u32(&mut episode, start_legs.track_m.to_bits());
        episode.push(TAG_STARTUP);
        let mut sent = Vec::new();
        let mut decisions = Vec::new();
        let mut next_decision = recorder.decisions.iter().peekable();
        let (mut ticks, mut frames_sent) = (0usize, 0usize);
        // A period in which nothing was sent or received leaves no line in the log (the
        // start-up's roll call waits through such periods): it is recorded empty, so that the
        // controller's periods line up with the recording's.
        let period_us = (1.0e6 / LoopConfig::default().rig.motion.control_rate_hz) as u64;
        let first_us = frames.first().map_or(0, |f| f.time_us);
        let mut at = 0;
        while at < frames.len() {
            let time_us = frames[at].time_us;
            let period = ((time_us - first_us) as f64 / period_us as f64).round() as usize;
            while ticks < period {
                ticks += 1;
                episode.push(TAG_TICK);
                episode.push(0);
            }
            let end = frames[at..]
                .iter()
                .position(|f| f.time_us != time_us)
                .map_or(frames.len(), |n| at + n);
            let group = &frames[at..end];
            while let Some((_, decided)) =
                next_decision.next_if(|(offset, _)| *offset <= group[0].offset)
            {
                episode.push(TAG_DECISION);
                push_observation(&mut episode, decided, decisions.is_empty());
                decisions.extend_from_slice(&decided.record.to_bytes());
            }
            // A period: the frames the axes sent, then the controller's.
            let received: Vec<&Logged> = group.iter().filter(|f| !f.command).collect();
            if group.iter().skip_while(|f| !f.command).any(|f| !f.command) {
                return Err("bus log: feedback after commands within one period".into());
            }
            ticks += 1;
            episode.push(TAG_TICK);
            episode.push(u8::try_from(received.len()).map_err(|_| "too many frames")?);
            for frame in received {
                push_frame(&mut episode, frame);
            }
            for frame in group.iter().filter(|f| f.command) {
                push_u32(&mut sent, ticks as u32);
                push_frame(&mut sent, frame);
                frames_sent += 1;
            }
            at = end;
        }
        for (_, decided) in next_decision {
            episode.push(TAG_DECISION);
            push_observation(&mut episode, decided, decisions.is_empty());
            decisions.extend_from_slice(&decided.record.to_bytes());
        }
        episode.push(TAG_END);
        write(&out.join("episode.bin"), &episode)?;
        write(&out.join("episode.frames.expected"), &sent)?;
        write(&out.join("episode.decisions.expected"), &decisions)?;
        return Ok(EpisodeSummary {
            scene: scene.name.clone(),
            decisions: recorder.decisions.len(),
            ticks,
            frames: frames_sent,
        });
    }
    Err("no held-out scene ran clean through the closed loop".into())
}

fn evaluate(weights: &[u8], scenes: &[Scenario], whole_map: bool) -> Result<()> {
    let mut robot = Robot::new(weights)?;
    let (mut success, mut collision_free, mut decisions) = (0usize, 0usize, 0usize);
    let mut failed = Vec::new();
    for scene in scenes {
        let mut env = Env::new(scene, EnvConfig::default()).map_err(|e| format!("{e:?}"))?;
        robot.driver.reset();
        while !env.status().is_done() {
            let decided = robot.decide_with(&env, whole_map)?;
            decisions += 1;
            env.step(decided.record.action())
                .map_err(|_| "stepped a finished episode")?;
        }
        let succeeded = env.status() == Status::Success;
        success += usize::from(succeeded);
        if !succeeded {
            failed.push(format!("\"{}\"", scene.name));
        }
        collision_free += usize::from(succeeded && env.collisions() == 0);
    }
    let n = scenes.len().max(1) as f64;
    println!(
        "{{\"scenes\": {}, \"guard_map\": \"{}\", \"success_rate\": {:.4}, \"collision_free_rate\": {:.4}, \"decisions\": {decisions}, \"failed\": [{}]}}",
        scenes.len(),
        if whole_map { "whole fine map, metres" } else { "controller window, millimetres" },
        success as f64 / n,
        collision_free as f64 / n,
        failed.join(", ")
    );
    Ok(())
}
