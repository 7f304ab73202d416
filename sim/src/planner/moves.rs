//! Base poses and the 27 base moves, with the leg steps each move may take along.

use nalgebra::Point2;
use wheelleg_runtime::action::Action;
use wheelleg_runtime::action::Step;
use wheelleg_runtime::action::COUNT;

/// Base pose: where the body centre is and which way it faces.
#[derive(Clone, Copy, Debug)]
pub(super) struct Pose {
    pub(super) position: Point2<f32>,
    pub(super) yaw_steps: i32,
}

pub(super) type PoseKey = (i32, i32, i32);

impl Pose {
    pub(super) fn key(&self) -> PoseKey {
        (
            (self.position.x * 1.0e4).round() as i32,
            (self.position.y * 1.0e4).round() as i32,
            self.yaw_steps,
        )
    }
}

pub(super) fn step_of(sign: i32) -> Step {
    match sign {
        -1 => Step::Minus,
        1 => Step::Plus,
        _ => Step::Zero,
    }
}

/// One of the 27 base moves, with the leg steps the allowed-action mask permits alongside it.
pub(super) struct BaseMove {
    /// The move with both leg dimensions at zero.
    pub(super) action: Action,
    /// Allowed (clearance, track) steps with this move; never the idle action.
    pub(super) leg_steps: Vec<(i32, i32)>,
    /// The same steps, fewest leg dimensions moving first: the order in which the planner tries
    /// to prove a step to a leg configuration from its possible predecessors. The fewer the
    /// legs move, the smaller the step's motion bound and the fewer poses its proof places.
    pub(super) proof_order: Vec<(i32, i32)>,
}

impl BaseMove {
    pub(super) fn all(allowed: &[bool; COUNT]) -> Vec<BaseMove> {
        let mut moves = Vec::with_capacity(27);
        for mx in -1..=1 {
            for my in -1..=1 {
                for yaw in -1..=1 {
                    let action = Action {
                        move_x: step_of(mx),
                        move_y: step_of(my),
                        yaw: step_of(yaw),
                        ..Action::IDLE
                    };
                    let leg_steps = (-1..=1)
                        .flat_map(|dc| (-1..=1).map(move |dt| (dc, dt)))
                        .filter(|&(dc, dt)| {
                            let full = Action {
                                clearance: step_of(dc),
                                track: step_of(dt),
                                ..action
                            };
                            full != Action::IDLE && allowed[full.index()]
                        })
                        .collect::<Vec<_>>();
                    let mut proof_order = leg_steps.clone();
                    proof_order.sort_by_key(|&(dc, dt)| dc.abs() + dt.abs());
                    moves.push(BaseMove {
                        action,
                        leg_steps,
                        proof_order,
                    });
                }
            }
        }
        moves
    }

    pub(super) fn with_legs(&self, dc: i32, dt: i32) -> Action {
        Action {
            clearance: step_of(dc),
            track: step_of(dt),
            ..self.action
        }
    }
}
