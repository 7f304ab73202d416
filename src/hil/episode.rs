//! One episode through the firmware: observations and windows out, decisions and step reports
//! in, the world moved as the in-process loop moves it, and the faults injected on the way.

use super::plant::{HoldWatch, PeriodTiming};
use super::*;

impl Hil {
    /// Runs one episode of `env` with `faults`; the robot is left at rest (or in safe stop).
    pub fn run(&mut self, env: &mut Env, faults: &Faults) -> Result<HilEpisode, HilError> {
        let tolerance = Tolerance::default();
        let mut tracking = Tracking::default();
        let mut path = vec![*env.state()];
        let mut collided_at = Vec::new();
        let start_pose = crate::closed_loop::lattice_pose(env.state());
        let mut odometry = Isometry2::identity();
        let mut fault = None;
        let mut stop = None;
        let mut rejected = 0u32;
        let mut last_step_tick = None;
        let mut first = true;
        let mut plant_faults = faults.plant.clone();
        let mut slow_decision = faults.slow_decision;
        let (mut deadline_misses, mut held) = (0u32, None);
        while !env.status().is_done() && fault.is_none() {
            let decision = env.steps() + 1;
            let slow = match slow_decision {
                Some((at, ms)) if at == decision => {
                    slow_decision = None;
                    self.send(ToController::DelayNextDecision { ms }, false)?;
                    true
                }
                _ => false,
            };
            let (stall, corrupt) = match faults.link {
                Some(LinkFault::StallAt(at)) => (decision >= at, false),
                Some(LinkFault::CorruptAt(at)) => (false, decision >= at),
                None => (false, false),
            };
            if stall {
                // Nothing more is sent: the firmware must stop by itself.
                let answer = self.answer(&mut rejected)?;
                stop = stopped(answer, &self.robot)?;
                fault = stop.map(|s| Fault::Controller {
                    step: env.steps(),
                    reason: s,
                });
                break;
            }
            env.observe(&mut self.sim_observation);
            let (height_mm, state_mm) = observation_mm(&self.sim_observation);
            let height_mm_le: Vec<u8> = height_mm
                .as_flattened()
                .iter()
                .flat_map(|h| h.to_le_bytes())
                .collect();
            self.send(
                ToController::Observation {
                    new_episode: first,
                    height_mm_le: &height_mm_le,
                    state_mm,
                },
                corrupt,
            )?;
            first = false;
            if corrupt {
                // Keep sending the corrupt observation until the firmware gives up on the link.
                loop {
                    match self.receive()? {
                        FromController::Rejected { .. } => {
                            rejected += 1;
                            self.send(
                                ToController::Observation {
                                    new_episode: false,
                                    height_mm_le: &height_mm_le,
                                    state_mm,
                                },
                                true,
                            )?;
                        }
                        other => {
                            stop = stopped(other, &self.robot)?;
                            break;
                        }
                    }
                }
                fault = stop.map(|s| Fault::Controller {
                    step: env.steps(),
                    reason: s,
                });
                break;
            }
            match self.answer(&mut rejected)? {
                FromController::WindowPlease => {}
                other => {
                    stop = stopped(other, &self.robot)?;
                    fault = stop.map(|s| Fault::Controller {
                        step: env.steps(),
                        reason: s,
                    });
                    break;
                }
            }
            let window = self.window_bytes(env);
            if slow {
                self.plant().begin_watch();
            }
            self.send(
                ToController::Window {
                    heights_mm_le: &window,
                },
                false,
            )?;
            let answer = self.answer(&mut rejected)?;
            if slow {
                held = self.plant().end_watch();
            }
            let action = match answer {
                FromController::Decision { action, .. } => Action::from_index(usize::from(action))
                    .ok_or_else(|| {
                        HilError::Protocol(format!("the firmware decided on action {action}"))
                    })?,
                // Abandoned: the robot held; the same state is observed and decided again.
                FromController::DeadlineMissed { .. } => {
                    deadline_misses += 1;
                    if deadline_misses > MAX_DEADLINE_MISSES {
                        return Err(HilError::Protocol(format!(
                            "the firmware missed its decision deadline {deadline_misses} \
                             times in one episode"
                        )));
                    }
                    continue;
                }
                other => {
                    return Err(HilError::Protocol(format!(
                        "expected a decision, got {other:?}"
                    )))
                }
            };
            // Faults of the CAN side start in the middle of this step.
            let polls = self.plant().polls();
            plant_faults.retain(|(at, f)| {
                if *at == decision {
                    self.plant().schedule(polls + 10, *f);
                    false
                } else {
                    true
                }
            });
            let from = *env.state();
            let from_legs = from.leg_config(env.geometry());
            let ideal = BaseDisplacement::of_action(action, &self.robot.actions);
            let ideal_legs = target_config(from_legs, action, &self.robot.actions);
            let index = env.steps();
            match self.answer(&mut rejected)? {
                FromController::StepDone {
                    moved: false,
                    pose,
                    tick,
                    ..
                } => {
                    last_step_tick = Some(tick);
                    odometry = pose_of(pose);
                    let outcome = env.step(action).map_err(|_| finished())?;
                    if outcome.invalid.is_none() {
                        fault = Some(Fault::KinematicsDisagree {
                            step: index,
                            action,
                        });
                    }
                    tracking.refused += 1;
                }
                FromController::StepDone {
                    pose, legs_m, tick, ..
                } => {
                    last_step_tick = Some(tick);
                    let report = step_report(ideal.isometry(), odometry, pose, ideal_legs, legs_m);
                    odometry = pose_of(pose);
                    let error = StepError::of(&report);
                    tracking.max_error = max_error(tracking.max_error, error);
                    if !error.within(&tolerance) {
                        fault = Some(Fault::OffTolerance { step: index, error });
                        continue;
                    }
                    let outcome = env.step(action).map_err(|_| finished())?;
                    if outcome.invalid.is_none() {
                        tracking.moved += 1;
                        path.push(*env.state());
                        continue;
                    }
                    // The world undid the step: the firmware backs out of it.
                    if outcome.invalid == Some(InvalidAction::Collision) {
                        collided_at.push(from);
                    }
                    self.send(ToController::Collided, false)?;
                    match self.answer(&mut rejected)? {
                        FromController::StepDone {
                            pose, legs_m, tick, ..
                        } => {
                            last_step_tick = Some(tick);
                            let back = ideal.isometry().inverse();
                            let report = step_report(back, odometry, pose, from_legs, legs_m);
                            odometry = pose_of(pose);
                            let error = StepError::of(&report);
                            tracking.max_error = max_error(tracking.max_error, error);
                            if !error.within(&tolerance) {
                                fault = Some(Fault::OffTolerance { step: index, error });
                                continue;
                            }
                            tracking.undone += 1;
                        }
                        other => {
                            stop = stopped(other, &self.robot)?;
                            fault = stop.map(|s| Fault::Controller {
                                step: index,
                                reason: s,
                            });
                        }
                    }
                }
                other => {
                    stop = stopped(other, &self.robot)?;
                    fault = stop.map(|s| Fault::Controller {
                        step: index,
                        reason: s,
                    });
                }
            }
        }
        let plant = self.plant();
        let world = crate::closed_loop::lattice_pose(env.state());
        let drift = world.inverse() * (start_pose * odometry);
        let report = EpisodeReport {
            status: env.status(),
            steps: env.steps(),
            collisions: env.collisions(),
            fault,
            tracking,
            path,
            collided_at,
            odometry_drift_m: drift.translation.vector.norm(),
            odometry_drift_rad: drift.rotation.angle().abs(),
            elapsed_s: plant.now_us() as f64 * 1e-6,
            traffic: plant.traffic(),
            bus_load: plant.bus_load(BITRATE_BPS),
            feedback: BusStats {
                accepted: plant.delivered().min(u64::from(u32::MAX)) as u32,
                ..BusStats::default()
            },
        };
        Ok(HilEpisode {
            report,
            stop,
            rejected,
            last_step_tick,
            injected: plant.injected().to_vec(),
            deadline_misses,
            held,
            periods: plant.polls(),
            timing: plant.timing(),
            watchdog_trips: plant.watchdog_trips(),
        })
    }

    /// The fine window of the world's 1 cm map around the robot, as the firmware reads it.
    fn window_bytes(&mut self, env: &Env) -> Vec<u8> {
        env.observe_grid(MapGrid::GUARD_FINE, &mut self.fine);
        onboard::window_mm_le(&self.fine, &self.window)
    }
}

/// One episode through the firmware.
#[derive(Clone, Debug)]
pub struct HilEpisode {
    /// What `demo` prints.
    pub report: EpisodeReport,
    /// The firmware's safe stop, if it reported one.
    pub stop: Option<ControllerStop>,
    /// Frames the firmware refused (corrupt ones).
    pub rejected: u32,
    /// The firmware's control period at the end of its last step (or retreat).
    pub last_step_tick: Option<u32>,
    /// The CAN side's faults, with the control period each took effect in.
    pub injected: Vec<(u64, PlantFault)>,
    /// Decisions the firmware abandoned at their deadline (each decided again).
    pub deadline_misses: u32,
    /// The robot while the slow decision ran ([`Faults::slow_decision`]), if one was asked.
    pub held: Option<HoldWatch>,
    /// The firmware's control periods (its status polls of the CAN adapter).
    pub periods: u64,
    /// The periods against their due times, on the emulated clock.
    pub timing: PeriodTiming,
    /// Watchdog expiries of the axes.
    pub watchdog_trips: u32,
}

/// Abandoned decisions an episode tolerates before the loop gives up on the firmware.
const MAX_DEADLINE_MISSES: u32 = 10;

fn finished() -> HilError {
    HilError::Protocol("the world's episode ended before the firmware's".into())
}

fn stopped(answer: FromController, robot: &Robot) -> Result<Option<ControllerStop>, HilError> {
    match answer {
        FromController::Stopped { reason, axes, tick } => Ok(Some(ControllerStop {
            reason,
            axes: AxisSet(axes),
            tick,
            node_ids: ControllerStop::node_ids(&robot.can),
        })),
        other => Err(HilError::Protocol(format!(
            "expected the firmware's report, got {other:?}"
        ))),
    }
}

fn pose_of([x, y, yaw]: [f32; 3]) -> Isometry2<f32> {
    Isometry2::new(nalgebra::Vector2::new(x, y), yaw)
}

/// A step's report as the rig makes it, from the firmware's odometry before and after.
fn step_report(
    ideal_pose: Isometry2<f32>,
    before: Isometry2<f32>,
    after: [f32; 3],
    ideal_legs: LegConfig,
    [clearance_m, track_m]: [f32; 2],
) -> StepReport {
    StepReport {
        ideal_pose,
        achieved_pose: before.inverse() * pose_of(after),
        ideal_legs,
        achieved_legs: LegConfig {
            clearance_m,
            track_m,
        },
        stopped: None,
    }
}

fn max_error(a: StepError, b: StepError) -> StepError {
    StepError {
        position_m: a.position_m.max(b.position_m),
        yaw_rad: a.yaw_rad.max(b.yaw_rad),
        legs_m: a.legs_m.max(b.legs_m),
    }
}
