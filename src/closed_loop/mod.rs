//! The whole system in one loop (docs/can-protocol.md, "Closed loop demo"):
//!
//! ```text
//! world (Env) -> height map + state -> driver (int8 policy or planner) -> Action
//!   -> runtime: setpoint stream -> ODrive CANSimple frames -> bus
//!   -> firmware_sim: 16 simulated axes -> encoder estimates -> bus
//!   -> runtime: measured joint angles (forward kinematics) and wheel speeds (odometry)
//!   -> achieved pose -> the world moves -> next height map
//! ```
//!
//! Why this lives in the root crate and not in `firmware_sim`: `firmware_sim` stands for the
//! motor controllers and knows nothing of obstacles or policies; this loop joins the world
//! simulator, the planner and the policy to the motors, so it belongs to the one crate that
//! depends on all of them, where both `wheelleg demo` and the whole-system tests reach it.
//!
//! # From measured motion back to the world's lattice state
//!
//! The world ([`Env`]) keeps the robot on the action lattice (yaw, clearance and track in whole
//! steps). After each decision the rig reports the achieved pose change (odometry from the
//! measured wheel speeds) and leg configuration (forward kinematics of the measured joint
//! angles), both relative to the step's start. The rule:
//!
//! - **within [`Tolerance`] of the ideal step** (2 mm, 0.2°, 0.5 mm by default, the tolerances
//!   of `firmware_sim/tests/closed_loop.rs`): the world *snaps* to the lattice state the action
//!   leads to. The residual is what the robot's localisation would correct; it is reported per
//!   step and as the odometry drift over the episode, never silently accumulated in the world.
//! - **outside tolerance**: a [`Fault::OffTolerance`]; the loop holds the robot (wheels
//!   stopped, legs at their commanded configuration) and stops, because the world could no
//!   longer say where the robot is.
//! - **the controller stopped the robot** (a silent node, an axis error): [`Fault::SafeStop`];
//!   the rig is already in safe stop (the step's motion slowed to rest along its own path, then
//!   that pose held, wheels at zero; docs/can-protocol.md) and stays so.
//!
//! # Collisions and other refused actions
//!
//! The simulator judges every executed step at the snapped pose and the whole way there, with
//! the same rules as training. When it refuses the step (collision, leaving the arena), its rule
//! is that the action is undone; the robot mirrors that physically by backing out along the
//! exact inverse motion ([`StepKind::Undone`]), also checked against tolerance. An action
//! whose legs the runtime cannot reach is never sent to the motors ([`StepKind::Refused`]);
//! the simulator must agree it is impossible, else [`Fault::KinematicsDisagree`].

pub mod driver;
pub mod success;

mod fault;
mod report;

use nalgebra::{Isometry2, Vector2};
use std::io::Write;
use wheelleg_firmware_sim::bus::Transport;
use wheelleg_firmware_sim::candump::CandumpWriter;
use wheelleg_firmware_sim::rig::{Rig, RigConfig, RigError, StepReport};
use wheelleg_runtime::action::Action;
use wheelleg_runtime::can::NodeMap;
use wheelleg_runtime::motion::{BaseDisplacement, MotionError, StepMotion};
use wheelleg_runtime::robot::{Robot, RobotGeometry};
use wheelleg_sim::env::{Env, EnvConfig, InvalidAction};
use wheelleg_sim::scenario::Scenario;
use wheelleg_sim::state::RobotState;

pub use driver::{Driver, DriverError, PlannerDriver, PolicyDriver};
pub use fault::{Fault, LoopError, StepError};
pub use report::{leg_behaviours, EpisodeReport, LegBehaviour, StepKind, StepRecord, Tracking};

/// The robot's CAN bit rate.
pub const BITRATE_BPS: f64 = 1_000_000.0;

/// How far an achieved step may be from the ideal one before the world refuses to follow.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tolerance {
    /// Distance between ideal and achieved body position.
    pub position_m: f32,
    /// Angle between ideal and achieved heading.
    pub yaw_rad: f32,
    /// Largest difference in clearance or track.
    pub legs_m: f32,
}

impl Default for Tolerance {
    /// 2 mm, 0.2°, 0.5 mm: the tolerances `firmware_sim/tests/closed_loop.rs` proves for one
    /// step on a clean bus (docs/can-protocol.md, "Tolerances of the closed loop"). The lattice
    /// is 50 mm and 5°, so a snap within them can never pick the wrong lattice state.
    fn default() -> Self {
        Tolerance {
            position_m: 0.002,
            yaw_rad: 0.2f32.to_radians(),
            legs_m: 0.0005,
        }
    }
}

/// Settings of the closed loop.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct LoopConfig {
    /// Motors, bus, control rate, safety timeouts, fault injection.
    pub rig: RigConfig,
    /// Episode rules of the world.
    pub env: EnvConfig,
    /// How closely an achieved step must match the ideal one.
    pub tolerance: Tolerance,
    /// The CAN wiring of the robot driven (its description's node ids, directions and gear
    /// ratios); the shipped robot's by default. The geometry is the world's (`env`).
    pub node_map: NodeMap,
}

/// The world and the robot's motors, stepped together.
pub struct ClosedLoop {
    env: Env,
    rig: Rig,
    config: LoopConfig,
    start_pose: Isometry2<f32>,
    path: Vec<RobotState>,
    collided_at: Vec<RobotState>,
    tracking: Tracking,
    fault: Option<Fault>,
}

/// The world's lattice state as a pose.
pub(crate) fn lattice_pose(state: &RobotState) -> Isometry2<f32> {
    Isometry2::new(
        Vector2::new(state.position.x, state.position.y),
        state.yaw_rad(),
    )
}

/// The robot the loop drives: the world's geometry and action lattice, the configured wiring.
fn sim_robot(env: &Env, config: &LoopConfig) -> Robot {
    Robot {
        geometry: *env.geometry(),
        actions: *env.lattice(),
        can: config.node_map,
    }
}

impl ClosedLoop {
    /// The loop on the in-process bus with simulated motors; not started yet
    /// ([`ClosedLoop::start`]).
    pub fn in_process(scenario: &Scenario, config: LoopConfig) -> Result<ClosedLoop, LoopError> {
        let env = Env::new(scenario, config.env)?;
        let legs = env.state().leg_config(env.geometry());
        let rig = Rig::in_process(&sim_robot(&env, &config), config.rig, legs)?;
        Ok(ClosedLoop::with(env, rig, config))
    }

    /// The loop talking to motors elsewhere through `transport` (for example
    /// `firmware_sim --can vcan0` in another process); time is real.
    pub fn remote(
        scenario: &Scenario,
        config: LoopConfig,
        transport: Box<dyn Transport>,
    ) -> Result<ClosedLoop, LoopError> {
        let env = Env::new(scenario, config.env)?;
        let legs = env.state().leg_config(env.geometry());
        let rig = Rig::remote(&sim_robot(&env, &config), config.rig, legs, transport)?;
        Ok(ClosedLoop::with(env, rig, config))
    }

    fn with(env: Env, rig: Rig, config: LoopConfig) -> ClosedLoop {
        ClosedLoop {
            start_pose: lattice_pose(env.state()),
            path: vec![*env.state()],
            collided_at: Vec::new(),
            env,
            rig,
            config,
            tracking: Tracking::default(),
            fault: None,
        }
    }

    /// Logs the bus traffic in `candump -L` format from now on (call before
    /// [`ClosedLoop::start`] to include the start-up frames).
    pub fn log_to(&mut self, writer: CandumpWriter<Box<dyn Write>>) {
        self.rig.log_to(writer);
    }

    /// Stops logging; returns the flushed writer.
    pub fn take_log(&mut self) -> Result<Option<Box<dyn Write>>, LoopError> {
        Ok(self.rig.take_log()?)
    }

    /// Arms the motors at the scenario's start legs.
    pub fn start(&mut self) -> Result<(), LoopError> {
        Ok(self.rig.start_up()?)
    }

    /// The world.
    pub fn env(&self) -> &Env {
        &self.env
    }

    /// The motors and their controller.
    pub fn rig(&self) -> &Rig {
        &self.rig
    }

    /// The motors and their controller, for fault injection.
    pub fn rig_mut(&mut self) -> &mut Rig {
        &mut self.rig
    }

    /// The fault that stopped the robot, if any.
    pub fn fault(&self) -> Option<Fault> {
        self.fault
    }

    /// Whether no more steps can be taken (episode over or robot stopped).
    pub fn is_done(&self) -> bool {
        self.env.status().is_done() || self.fault.is_some()
    }

    fn geometry(&self) -> RobotGeometry {
        *self.env.geometry()
    }

    /// Checks an executed motion; records a fault (and holds the robot) if it went wrong.
    fn check(&mut self, step: u32, report: &StepReport) -> Result<bool, LoopError> {
        if let Some(reason) = report.stopped {
            self.fault = Some(Fault::SafeStop { step, reason });
            return Ok(false);
        }
        let error = StepError::of(report);
        self.tracking.max_error = self.tracking.max_error.max(error);
        if !error.within(&self.config.tolerance) {
            self.fault = Some(Fault::OffTolerance { step, error });
            // Wheels to zero, legs to their commanded configuration, still supervised.
            self.rig.hold(self.config.rig.settle_s)?;
            return Ok(false);
        }
        Ok(true)
    }

    /// Takes one decision through the whole chain. A [`Fault`] is not an error: it is
    /// recorded, the returned record says [`StepKind::Faulted`], and the loop is done.
    pub fn step(&mut self, action: Action) -> Result<StepRecord, LoopError> {
        if self.is_done() {
            return Err(LoopError::Finished);
        }
        let index = self.env.steps();
        let from = *self.env.state();
        let faulted = |report| StepRecord {
            action,
            kind: StepKind::Faulted,
            outcome: None,
            report: Some(report),
            retreat: None,
        };
        let report = match self.rig.step(action) {
            Ok(report) => report,
            Err(RigError::Motion(MotionError::Unreachable(_))) => {
                // The runtime refuses before any frame is sent; the world must agree.
                let outcome = self.env.step(action)?;
                if outcome.invalid.is_none() {
                    self.fault = Some(Fault::KinematicsDisagree {
                        step: index,
                        action,
                    });
                }
                self.tracking.refused += 1;
                return Ok(StepRecord {
                    action,
                    kind: StepKind::Refused,
                    outcome: Some(outcome),
                    report: None,
                    retreat: None,
                });
            }
            Err(e) => return Err(e.into()),
        };
        if !self.check(index, &report)? {
            return Ok(faulted(report));
        }
        // Within tolerance: the world snaps to the lattice state of the action and judges it.
        let outcome = self.env.step(action)?;
        if outcome.invalid.is_none() {
            self.tracking.moved += 1;
            self.path.push(*self.env.state());
            return Ok(StepRecord {
                action,
                kind: StepKind::Moved,
                outcome: Some(outcome),
                report: Some(report),
                retreat: None,
            });
        }
        // The world undid the step (collision, arena, legs): back out along the inverse motion.
        if outcome.invalid == Some(InvalidAction::Collision) {
            self.collided_at.push(from);
        }
        let back = report.ideal_pose.inverse();
        let displacement = BaseDisplacement {
            dx_m: back.translation.x,
            dy_m: back.translation.y,
            dyaw_rad: back.rotation.angle(),
        };
        let geometry = self.geometry();
        let motion = StepMotion::plan_between(
            &geometry,
            self.rig.motion_config(),
            self.rig.legs(),
            from.leg_config(&geometry),
            displacement,
        )?;
        let retreat = self.rig.execute(motion)?;
        if !self.check(index, &retreat)? {
            return Ok(StepRecord {
                retreat: Some(retreat),
                ..faulted(report)
            });
        }
        self.tracking.undone += 1;
        Ok(StepRecord {
            action,
            kind: StepKind::Undone,
            outcome: Some(outcome),
            report: Some(report),
            retreat: Some(retreat),
        })
    }

    /// Runs `driver` until the episode ends or a fault stops the robot, then lets the robot
    /// come to rest and reports.
    pub fn run(&mut self, driver: &mut dyn Driver) -> Result<EpisodeReport, LoopError> {
        while !self.is_done() {
            let action = driver.decide(&self.env)?;
            self.step(action)?;
        }
        self.finish()
    }

    /// Holds the robot still (wheels stopped, legs held; safe stop if the controller is in
    /// it) for the settling time, so the episode ends at rest, and reports.
    pub fn finish(&mut self) -> Result<EpisodeReport, LoopError> {
        self.rig.hold(self.config.rig.settle_s)?;
        Ok(self.report())
    }

    /// The episode so far.
    pub fn report(&self) -> EpisodeReport {
        let world = lattice_pose(self.env.state());
        let odometry = self.start_pose * self.rig.pose();
        let drift = world.inverse() * odometry;
        EpisodeReport {
            status: self.env.status(),
            steps: self.env.steps(),
            collisions: self.env.collisions(),
            fault: self.fault,
            tracking: self.tracking,
            path: self.path.clone(),
            collided_at: self.collided_at.clone(),
            odometry_drift_m: drift.translation.vector.norm(),
            odometry_drift_rad: drift.rotation.angle().abs(),
            elapsed_s: self.rig.now_us() as f64 * 1e-6,
            traffic: self.rig.traffic(),
            bus_load: self.rig.bus_load(BITRATE_BPS),
            feedback: self.rig.feedback().stats(),
        }
    }
}
