//! Leg configuration sets: the IK-reachable (clearance, track) lattice and bitsets over it.

use super::moves::Pose;
use crate::robot::SimulatedRobot;
use crate::state::RobotState;
use nalgebra::Point2;
use wheelleg_runtime::action::ActionLattice;

/// Capacity of a [`LegSet`] in clearance steps (rows).
pub(crate) const LEG_ROWS: usize = 16;
/// Capacity of a [`LegSet`] in track steps (bits of a row).
pub(crate) const LEG_COLS: usize = 32;

/// A set of leg configurations: bit `t` of row `r` is (clearance row `r`, track column `t`) of
/// the [`LegLattice`]. One `u32` per clearance row makes the one-step dilation in either leg
/// dimension a row shift or a bit shift.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(super) struct LegSet(pub(super) [u32; LEG_ROWS]);

impl LegSet {
    pub(super) fn contains(&self, row: usize, col: usize) -> bool {
        self.0[row] >> col & 1 == 1
    }

    pub(super) fn insert(&mut self, row: usize, col: usize) {
        self.0[row] |= 1 << col;
    }

    pub(super) fn is_empty(&self) -> bool {
        self.0.iter().all(|&w| w == 0)
    }

    /// How many configurations the set holds.
    pub(super) fn len(&self) -> u32 {
        self.0.iter().map(|w| w.count_ones()).sum()
    }

    pub(super) fn is_subset_of(&self, other: &LegSet) -> bool {
        self.0.iter().zip(&other.0).all(|(a, b)| a & !b == 0)
    }

    pub(super) fn union_with(&mut self, other: &LegSet) {
        for (a, b) in self.0.iter_mut().zip(&other.0) {
            *a |= b;
        }
    }

    /// The members of `self` not in `other`.
    pub(super) fn difference(mut self, other: &LegSet) -> LegSet {
        for (a, b) in self.0.iter_mut().zip(&other.0) {
            *a &= !b;
        }
        self
    }

    pub(super) fn intersection(mut self, other: &LegSet) -> LegSet {
        for (a, b) in self.0.iter_mut().zip(&other.0) {
            *a &= b;
        }
        self
    }

    /// The set moved by `dc` rows and `dt` columns (each -1, 0 or +1): contains `(r, t)` when
    /// `self` contains `(r - dc, t - dt)`. Bits pushed past the lattice are cut by the caller's
    /// intersection with the reachable set.
    pub(super) fn shifted(&self, dc: i32, dt: i32) -> LegSet {
        let mut out = [0u32; LEG_ROWS];
        for (row, word) in out.iter_mut().enumerate() {
            let source = row as i32 - dc;
            if (0..LEG_ROWS as i32).contains(&source) {
                let w = self.0[source as usize];
                *word = match dt {
                    1 => w << 1,
                    -1 => w >> 1,
                    _ => w,
                };
            }
        }
        LegSet(out)
    }

    pub(super) fn iter(&self) -> impl Iterator<Item = (usize, usize)> + '_ {
        self.0.iter().enumerate().flat_map(|(row, &word)| {
            let mut rest = word;
            std::iter::from_fn(move || {
                if rest == 0 {
                    return None;
                }
                let col = rest.trailing_zeros() as usize;
                rest &= rest - 1;
                Some((row, col))
            })
        })
    }
}

/// The leg configurations the IK can reach, as (clearance, track) step offsets from the
/// default pose, laid out on the rows and columns of a [`LegSet`].
pub(super) struct LegLattice {
    /// The steps the rows and columns count.
    actions: ActionLattice,
    /// Clearance steps of row 0.
    pub(super) clearance0: i32,
    /// Track steps of column 0.
    pub(super) track0: i32,
    pub(super) reachable: LegSet,
}

impl LegLattice {
    /// # Panics
    ///
    /// If the reachable lattice is larger than [`LEG_ROWS`] by [`LEG_COLS`] steps, which
    /// [`SimulatedRobot::new`] refuses.
    pub(super) fn new(robot: &SimulatedRobot) -> Self {
        let (geometry, actions) = (robot.geometry(), *robot.lattice());
        // Twice the most steps a range holds (SimulatedRobot::new): every reachable pose.
        const SCAN: i32 = 2 * LEG_COLS as i32;
        let mut found = Vec::new();
        for clearance_steps in -SCAN..=SCAN {
            for track_steps in -SCAN..=SCAN {
                let state = RobotState {
                    clearance_steps,
                    track_steps,
                    ..RobotState::new(Point2::origin(), 0, &actions)
                };
                // Exactly the test the simulator applies (RobotParts::new runs this IK).
                if geometry.leg_ik(state.leg_config(geometry)).is_ok() {
                    found.push((clearance_steps, track_steps));
                }
            }
        }
        let clearance0 = found.iter().map(|f| f.0).min().unwrap_or(0);
        let track0 = found.iter().map(|f| f.1).min().unwrap_or(0);
        let mut reachable = LegSet::default();
        for (c, t) in found {
            let (row, col) = ((c - clearance0) as usize, (t - track0) as usize);
            assert!(
                row < LEG_ROWS && col < LEG_COLS,
                "reachable leg lattice exceeds the planner's {LEG_ROWS} x {LEG_COLS} steps"
            );
            reachable.insert(row, col);
        }
        LegLattice {
            actions,
            clearance0,
            track0,
            reachable,
        }
    }

    /// Row and column of a state's leg configuration, if on the lattice.
    pub(super) fn cell(&self, state: &RobotState) -> Option<(usize, usize)> {
        let row = usize::try_from(state.clearance_steps - self.clearance0).ok()?;
        let col = usize::try_from(state.track_steps - self.track0).ok()?;
        (row < LEG_ROWS && col < LEG_COLS && self.reachable.contains(row, col))
            .then_some((row, col))
    }

    pub(super) fn state(&self, pose: &Pose, row: usize, col: usize) -> RobotState {
        RobotState {
            position: pose.position,
            yaw_steps: pose.yaw_steps,
            clearance_steps: self.clearance0 + row as i32,
            track_steps: self.track0 + col as i32,
            lattice: self.actions,
        }
    }
}
