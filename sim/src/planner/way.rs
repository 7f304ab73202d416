//! The planner's proof of the way there: the simulator's bisection of a step, run with cheap
//! clearance bounds alone (see [`way_proven`]).

use super::moves::PoseKey;
use super::search::FastMap;
use crate::collision::place_parts;
use crate::collision::CLEARANCE_SLACK_M;
use crate::env::proof_cap_m;
use crate::env::prove_way;
use crate::env::Env;
use crate::env::ProofPose;
use crate::env::WayClearance;
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

/// Whether the simulator's proof of the way from `from` to `to` (`Env::check_transition`,
/// motion bound `bound_m`) surely succeeds, decided without parry: the end pose is already
/// known clear (the caller's test), and this runs the simulator's own bisection
/// ([`prove_way`]) with the cheap bounds alone ([`PlannerClearance`]), each no higher than the
/// value the simulator uses at the same pose. So this only ever says yes where the simulator
/// says yes, and the caller asks the simulator whenever this says no.
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
    // Every pose on the way has its centre within the motion bound of the start, every part
    // within the reach of its centre, and only clearances up to the cap count.
    let near = env
        .obstacles()
        .near(from.position, env.reach_m() + bound_m + cap_m);
    prove_way(
        &mut PlannerClearance {
            env,
            cache,
            from: (from, from_key, from_cell),
            to: (to, to_key, to_cell),
            near,
        },
        bound_m,
    )
    .is_ok()
}

/// The planner's clearance values for [`prove_way`]: at the ends the lattice states' cached
/// bounds ([`state_clearance_m`]), in between the box-gap bound of the parts less
/// [`STATE_MARGIN_M`]. Each is no higher than the simulator's value at the same pose, and there
/// are no exact values: a pose these do not show clear ends the proof (the start counts as 0,
/// as in the simulator).
struct PlannerClearance<'a, 'c> {
    env: &'a Env,
    cache: &'c mut StateClearance,
    from: (&'a RobotState, PoseKey, usize),
    to: (&'a RobotState, PoseKey, usize),
    /// The obstacles any pose on the way can be near.
    near: Vec<usize>,
}

impl WayClearance for PlannerClearance<'_, '_> {
    /// Not proven here; the simulator decides.
    type Refusal = ();

    fn cheap_m(&mut self, t: f32, cap_m: f32) -> Result<f32, ()> {
        let env = self.env;
        if t == 0.0 || t == 1.0 {
            let (state, key, cell) = if t == 0.0 { self.from } else { self.to };
            return Ok(state_clearance_m(env, self.cache, state, key, cell, cap_m));
        }
        let parts = env
            .parts_between(self.from.0, self.to.0, t)
            .map_err(|_| ())?;
        Ok(env.obstacles().parts_clearance_lower_bound_m(
            &parts,
            env.reach_m(),
            cap_m,
            Some(&self.near),
        ) - STATE_MARGIN_M)
    }

    fn exact_m(&mut self, pose: &ProofPose) -> Result<Option<f32>, ()> {
        Ok((pose.cheap_m > 0.0).then_some(pose.cheap_m))
    }

    fn touches(&self) {}
}
