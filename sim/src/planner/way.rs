//! The planner's proof of the way there: the simulator's bisection of a step, replayed with
//! cheap clearance bounds alone (see [`way_proven`]).

use super::moves::PoseKey;
use super::search::FastMap;
use crate::collision::place_parts;
use crate::collision::CLEARANCE_SLACK_M;
use crate::env::proof_cap_m;
use crate::env::Env;
use crate::env::GRAZE_TOLERANCE_M;
use crate::state::RobotState;
use nalgebra::Point2;

/// How far [`state_clearance_m`] looks for a lattice state's clearance: more than the cap of
/// any step's proof ([`proof_cap_m`] of the largest motion bound, about 0.08 m).
pub(super) const STATE_CAP_M: f32 = 0.25;

/// What [`state_clearance_m`] takes off for rounding: its bound comes from the same function
/// as the simulator's, with another cap (and possibly another position, a few ulps away), so
/// it may differ from the simulator's in the last bits; 5 um is far more than that (a few
/// ulps of the positions here are under 1 um) and far less than anything that matters.
pub(super) const STATE_MARGIN_M: f32 = 5.0e-6;

/// Per lattice state (pose key, leg cell): the position its bound was computed at and
/// `ObstacleSet::clearance_lower_bound_m` up to [`STATE_CAP_M`] there.
pub(super) type StateClearance = FastMap<(PoseKey, usize), (Point2<f32>, f32)>;

/// A lower bound on the clearance the simulator's proof of a step sees at the lattice state
/// `state` (pose key `key`, leg cell `cell`) at either end of a step whose proof caps its ends
/// at `cap_m` (never above [`STATE_CAP_M`]): the simulator's cheap bound there is
/// `clearance_lower_bound_m(parts, cap_m)`, which is `min(cap_m, B) - slack` for the parts'
/// box-gap bound `B`, and its exact value, when it asks parry, is no lower. Worked out once per
/// state, at the first position met with the key; a position `d` away from it (the same
/// lattice pose reached by another sequence of moves, rounding differently) has a clearance at
/// most `d` lower (every part moves by `d`).
pub(super) fn state_clearance_m(
    env: &Env,
    cache: &mut StateClearance,
    state: &RobotState,
    key: PoseKey,
    cell: usize,
    cap_m: f32,
) -> f32 {
    let (at, bound_m) = *cache.entry((key, cell)).or_insert_with(|| {
        let geometry = env.geometry();
        let bound_m = place_parts(
            geometry,
            state.position,
            state.yaw_rad(),
            state.leg_config(geometry),
        )
        .map_or(f32::NEG_INFINITY, |parts| {
            env.obstacles()
                .parts_clearance_lower_bound_m(&parts, env.reach_m(), STATE_CAP_M, None)
        });
        (state.position, bound_m)
    });
    (cap_m - CLEARANCE_SLACK_M).min(bound_m) - (state.position - at).norm() - STATE_MARGIN_M
}

/// Stretches the planner's proof holds at once (one per halving level: a step's motion halves
/// below the graze tolerance in 11 levels); deeper, the simulator decides.
pub(super) const WAY_PROOF_STACK: usize = 24;

/// Whether the simulator's proof of the way from `from` to `to` (`Env::check_transition`,
/// motion bound `bound_m`) surely succeeds, decided without parry: the end pose is already
/// known clear (the caller's test), and this replays the simulator's bisection with the cheap
/// bounds alone, each no higher than the value the simulator uses at the same pose.
///
/// The simulator splits a stretch only when its values at the ends do not cover the travel;
/// these values are lower, so this proof splits that stretch too, at the same fraction, with the
/// same caps. So every pose the simulator places is placed here (the same `Env::pose_between`:
/// a pose the legs cannot take ends this proof), every stretch the simulator ends with is one
/// this proof covered, and none is shorter than the graze tolerance. A pose whose cheap bound is
/// not above 0 ends this proof (the simulator might ask parry there and find it touching),
/// except the start, which the simulator counts as 0. The verdict is the simulator's: this only
/// ever says yes where it says yes, and the caller asks the simulator whenever this says no.
///
/// `from` and `to` come with their pose keys and leg cells, for [`state_clearance_m`].
pub(super) fn way_proven(
    env: &Env,
    cache: &mut StateClearance,
    (from, from_key, from_cell): (&RobotState, PoseKey, usize),
    (to, to_key, to_cell): (&RobotState, PoseKey, usize),
    bound_m: f32,
) -> bool {
    let cap_m = proof_cap_m(bound_m);
    if cap_m > STATE_CAP_M {
        return false;
    }
    let end_m = state_clearance_m(env, cache, to, to_key, to_cell, cap_m);
    if end_m <= 0.0 {
        return false;
    }
    let start_m = state_clearance_m(env, cache, from, from_key, from_cell, cap_m).max(0.0);
    // Every pose on the way has its centre within the motion bound of the start, every part
    // within the reach of its centre, and only clearances up to the cap count.
    let near = env
        .obstacles()
        .near(from.position, env.reach_m() + bound_m + cap_m);
    // Stretches still to prove: (fraction, clearance bound) at each end.
    let mut open: heapless::Vec<((f32, f32), (f32, f32)), WAY_PROOF_STACK> = heapless::Vec::new();
    open.push(((0.0, start_m), (1.0, end_m)))
        .expect("room for one");
    while let Some(((a_t, a_m), (b_t, b_m))) = open.pop() {
        let travel_m = bound_m * (b_t - a_t);
        if a_m + b_m > travel_m {
            continue;
        }
        if travel_m < GRAZE_TOLERANCE_M {
            return false;
        }
        let t = 0.5 * (a_t + b_t);
        let Ok(parts) = env.parts_between(from, to, t) else {
            return false;
        };
        let mid_m = env.obstacles().parts_clearance_lower_bound_m(
            &parts,
            env.reach_m(),
            proof_cap_m(travel_m),
            Some(&near),
        ) - STATE_MARGIN_M;
        if mid_m <= 0.0 {
            return false;
        }
        if open.push(((t, mid_m), (b_t, b_m))).is_err()
            || open.push(((a_t, a_m), (t, mid_m))).is_err()
        {
            return false;
        }
    }
    true
}
