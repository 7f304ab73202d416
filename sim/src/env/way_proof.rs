//! The proof that a step's way is clear: one bisection, shared by the simulator
//! ([`Env::check_transition`](super::Env::check_transition)) and the planner, each bringing its
//! own clearance values ([`WayClearance`]).
//!
//! A pose at clearance `d` from every obstacle keeps the stretch of motion within `d / D` of it
//! clear, where `D` bounds how far any point of the robot moves over the whole step. So a stretch
//! whose two ends' clearances sum to more than its travel is clear; any other stretch is split in
//! half, until every stretch is covered, a pose touches, or a stretch shorter than
//! [`GRAZE_TOLERANCE_M`] of motion is still not covered (the robot would graze an obstacle within
//! that tolerance).
//!
//! Both users run this same function, so their proofs split at the same fractions with the same
//! caps: where a caller's values are never above the simulator's, it splits every stretch the
//! simulator splits (and maybe more), and a proof it completes is one the simulator completes.

use super::GRAZE_TOLERANCE_M;

/// Stretches the proof holds at once: one per halving level, and a step's motion (under 0.2 m)
/// halves below [`GRAZE_TOLERANCE_M`] in 11 levels; a full stack (only with a robot that moves
/// kilometres per step) is a way not proven clear.
const PROOF_STACK: usize = 40;

/// How far the proof looks for the clearance of a pose that ends a stretch of `travel_m`: a
/// stretch needs its two ends' clearances to sum to more than its travel, so a little past half
/// of it. Capped values are lower bounds, so the proof stays sound; a capped pair may just split
/// once more, and fewer part/obstacle pairs get an exact query.
pub(crate) fn proof_cap_m(travel_m: f32) -> f32 {
    0.5 * travel_m * (1.0 + 1.0e-3) + GRAZE_TOLERANCE_M
}

/// A pose of the proof: where along the step it is, and what is known of its clearance.
#[derive(Clone, Copy, Debug)]
pub(crate) struct ProofPose {
    /// Fraction of the step (0 = start, 1 = end).
    pub t: f32,
    /// A cheap lower bound on the clearance up to `cap_m`: at most 0 when the pose may touch.
    pub cheap_m: f32,
    /// A tighter value, once asked for ([`WayClearance::exact_m`]).
    exact_m: Option<f32>,
    /// How far the clearance is looked for ([`proof_cap_m`] of the stretch the pose ends).
    pub cap_m: f32,
}

impl ProofPose {
    /// The best lower bound on the pose's clearance known so far.
    fn best_m(&self) -> f32 {
        self.exact_m.unwrap_or(self.cheap_m.max(0.0))
    }
}

/// Where a proof's clearance values come from.
pub(crate) trait WayClearance {
    /// Why a way is not proven clear.
    type Refusal;

    /// A cheap lower bound on the clearance (up to `cap_m`) of the pose at fraction `t` of the
    /// step, at most 0 where the pose may touch; a refusal when the pose cannot be placed (the
    /// legs cannot take it).
    fn cheap_m(&mut self, t: f32, cap_m: f32) -> Result<f32, Self::Refusal>;

    /// A value no lower than `pose.cheap_m` and never above the true clearance, asked for when
    /// the cheap values leave a stretch unproven or the pose may touch: `None` when the pose
    /// touches (or, for a caller without exact values, may touch).
    fn exact_m(&mut self, pose: &ProofPose) -> Result<Option<f32>, Self::Refusal>;

    /// The refusal for a way that touches or grazes an obstacle.
    fn touches(&self) -> Self::Refusal;
}

/// Proves the way of a step clear: its motion bound `bound_m` (no point of the robot moves
/// farther over the step), the clearances from `clearance`. The start may touch (within
/// rounding of a pose the contact rule accepted): it then counts as clearance 0, and the motion
/// must prove itself from the other end.
pub(crate) fn prove_way<C: WayClearance>(
    clearance: &mut C,
    bound_m: f32,
) -> Result<(), C::Refusal> {
    let pose = |clearance: &mut C, t: f32, cap_m: f32| -> Result<ProofPose, C::Refusal> {
        let mut pose = ProofPose {
            t,
            cheap_m: clearance.cheap_m(t, cap_m)?,
            exact_m: None,
            cap_m,
        };
        // A pose whose bound cannot rule out touching gets its exact value at once: a pose that
        // touches ends the proof there (the start counts as 0 instead).
        if pose.cheap_m <= 0.0 && t != 0.0 {
            pose.exact_m = Some(
                clearance
                    .exact_m(&pose)?
                    .ok_or_else(|| clearance.touches())?,
            );
        }
        Ok(pose)
    };
    let cap_m = proof_cap_m(bound_m);
    let end = pose(clearance, 1.0, cap_m)?;
    let start = pose(clearance, 0.0, cap_m)?;
    let mut open: heapless::Vec<(ProofPose, ProofPose), PROOF_STACK> = heapless::Vec::new();
    open.push((start, end)).map_err(|_| clearance.touches())?;
    while let Some((mut a, mut b)) = open.pop() {
        let travel_m = bound_m * (b.t - a.t);
        if a.best_m() + b.best_m() > travel_m {
            continue;
        }
        for pose in [&mut a, &mut b] {
            if pose.exact_m.is_some() {
                continue;
            }
            let exact_m = match clearance.exact_m(pose)? {
                Some(exact_m) => exact_m,
                None if pose.t == 0.0 => 0.0,
                None => return Err(clearance.touches()),
            };
            pose.exact_m = Some(exact_m);
            // The other stretch that ends at this pose is waiting in the stack.
            for (c, d) in open.iter_mut() {
                for other in [c, d] {
                    if other.t == pose.t {
                        other.exact_m = Some(exact_m);
                    }
                }
            }
        }
        if a.best_m() + b.best_m() > travel_m {
            continue;
        }
        if travel_m < GRAZE_TOLERANCE_M {
            return Err(clearance.touches());
        }
        let mid = pose(clearance, 0.5 * (a.t + b.t), proof_cap_m(travel_m))?;
        if open.push((mid, b)).is_err() || open.push((a, mid)).is_err() {
            return Err(clearance.touches());
        }
    }
    Ok(())
}
