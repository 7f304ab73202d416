//! A look-ahead check on the height map: refuse an action the robot can already see would hit
//! something, or that its legs cannot take.
//!
//! The policy is trained to avoid collisions, but it errs, and an action the world refuses costs a
//! whole decision and, in a real robot, a bump. Everything needed to foresee most of those
//! refusals is on board: the robot's geometry, the height map it just measured and the motion
//! each action commands ([`crate::motion`]). The guard replays that motion against the map; the
//! [`crate::decision::Decider`] then skips the actions it refuses.
//!
//! The model, and why it is only an estimate:
//! - each map cell with a height `h > 0` is a column: the cell's square (side
//!   [`HEIGHT_MAP_CELL_M`] on the policy's map, aligned with the map) from the ground up to `h`.
//!   The map samples each cell at its centre, so an obstacle's true edge lies up to half a cell
//!   beyond or short of the square's edge. The guard's `margin_m` grows (or, negative, shrinks)
//!   every square by that much on each side: half a cell covers everything the map may have
//!   missed, minus half a cell leaves only the sample points, where an obstacle certainly is.
//!   The guard can read a finer map than the policy's ([`GridMap`]): a robot's elevation
//!   mapping keeps one anyway, and at 1 cm cells the default margin covers all the sampling can
//!   hide while the straddles still fit (docs/results.md, "A finer map for the guard");
//! - the robot is the simulator's 13 parts: the body box, per leg a thigh and a shank capsule
//!   in the leg plane and a wheel (a cylinder with its axle along body y);
//! - the step is the path [`crate::motion::StepMotion`] drives: a straight line and a steady
//!   turn, legs moving in a straight line in (clearance, track). It is checked at
//!   [`POSE_FRACTIONS`] of the way. A step moves no point of the robot farther than 94 mm (a
//!   diagonal move, 71 mm, plus a 5-degree turn at the body's corners, 23 mm), so every pose on
//!   the way is within 12 mm of a checked one (or of the start, which the world accepted);
//!   the simulator proves the whole way clear, the guard only samples it.
//! - the cell squares are not turned with the robot: over one step the robot turns at most 5
//!   degrees, which moves a square's corner by under 3 mm.
//!
//! Cost: for each pose, the occupied cells within the robot's reach times 13 parts, a few
//! multiplications each; no allocation.

use crate::action::{Action, CHOICES, DIMS};
use crate::arrival::Arrival;
use crate::decision::{Checked, Decider, ObservationKey};
use crate::leg::LegConfig;
use crate::motion::{target_config, BaseDisplacement};
use crate::observation::{HEIGHT_MAP_CELLS, HEIGHT_MAP_CELL_M, HEIGHT_MAP_SIDE};
use crate::robot::{LegId, RobotGeometry};
use nalgebra::{Isometry2, Point2, Point3};

/// Where along the step (0 = start, 1 = end) the robot's pose is checked.
pub const POSE_FRACTIONS: [f32; 4] = [0.25, 0.5, 0.75, 1.0];

/// The growth of every column the guard uses by default: 5 mm. The robot straddles the widest
/// slab (0.45 m) at full track (0.56 m) with 35 mm between each wheel and the slab's edge, and
/// the map may show that edge up to half a cell (25 mm) farther out than it is; a margin past
/// 10 mm would refuse the straddle outright in the worst alignment, so the default stays well
/// under it. docs/results.md measures the margins from -25 mm to 25 mm.
pub const DEFAULT_MARGIN_M: f32 = 0.005;

/// A height map the guard reads: the policy's map (the runtime's integer millimetres or the
/// host's metres), or a square map of another resolution.
#[derive(Clone, Copy, Debug)]
pub enum HeightMapRef<'a> {
    /// The policy's map, heights in millimetres (its integer inputs).
    Millimetres(&'a [i16; HEIGHT_MAP_CELLS]),
    /// The policy's map, heights in metres.
    Metres(&'a [f32; HEIGHT_MAP_CELLS]),
    /// A robot-centred square map of any size and resolution, heights in metres.
    Grid(GridMap<'a>),
    /// The part of such a map that the robot and one step can touch, heights in millimetres
    /// ([`FineWindow`]): what a controller with a few KiB of RAM keeps.
    Window(&'a FineWindow<'a>),
}

impl HeightMapRef<'_> {
    /// The height of cell (`row`, `col`) of the whole map (0 outside what is held).
    fn height_at_m(&self, row: usize, col: usize) -> f32 {
        let index = row * self.side() + col;
        match self {
            HeightMapRef::Millimetres(cells) => {
                cells.get(index).map_or(0.0, |&mm| f32::from(mm) * 1.0e-3)
            }
            HeightMapRef::Metres(cells) => cells.get(index).copied().unwrap_or(0.0),
            HeightMapRef::Grid(grid) => grid.heights_m.get(index).copied().unwrap_or(0.0),
            HeightMapRef::Window(window) => window.height_m(row, col),
        }
    }

    /// Cells per side.
    fn side(&self) -> usize {
        match self {
            HeightMapRef::Grid(grid) => grid.side,
            HeightMapRef::Window(window) => window.bounds.side,
            _ => HEIGHT_MAP_SIDE,
        }
    }

    /// Side of a cell.
    fn cell_m(&self) -> f32 {
        match self {
            HeightMapRef::Grid(grid) => grid.cell_m,
            HeightMapRef::Window(window) => window.bounds.cell_m,
            _ => HEIGHT_MAP_CELL_M,
        }
    }

    /// The columns of `row` that may hold a positive height (all but a window's, which knows
    /// each row's first and last): cells outside are skipped, as flat ones would be.
    #[inline]
    fn occupied(&self, row: usize) -> core::ops::Range<usize> {
        match self {
            HeightMapRef::Window(window) => window.occupied(row),
            _ => 0..self.side(),
        }
    }

    /// The rows and columns that hold heights: the whole map, or a window's part of it.
    fn held(&self) -> (core::ops::Range<usize>, core::ops::Range<usize>) {
        match self {
            HeightMapRef::Window(window) => (window.bounds.rows(), window.bounds.cols()),
            _ => (0..self.side(), 0..self.side()),
        }
    }

    /// Robot-frame (x forward, y left) centre of cell (`row`, `col`), laid out as the policy's
    /// map ([`crate::observation::cell_centre_in_robot_m`]): row 0 ahead, column 0 left, the robot at the centre.
    fn cell_centre_m(&self, row: usize, col: usize) -> (f32, f32) {
        let half = 0.5 * (self.side() as f32 - 1.0);
        let cell_m = self.cell_m();
        ((half - row as f32) * cell_m, (half - col as f32) * cell_m)
    }
}

/// A robot-centred, robot-aligned square height map of any size and resolution, in metres,
/// laid out as the policy's map (row-major, row 0 ahead, column 0 left, the robot at the
/// centre): what the guard reads when the robot keeps a finer map than the policy's.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GridMap<'a> {
    heights_m: &'a [f32],
    side: usize,
    cell_m: f32,
}

/// Why a [`GridMap`] cannot be made.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GridMapError {
    /// The heights are not `side * side` cells.
    WrongLength {
        /// `side * side` (`usize::MAX` when that overflows).
        expected: usize,
        /// Cells given.
        found: usize,
    },
    /// The cell side is not a positive finite length.
    BadCellSize,
}

impl core::fmt::Display for GridMapError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            GridMapError::WrongLength { expected, found } => {
                write!(f, "grid map has {found} cells, its side needs {expected}")
            }
            GridMapError::BadCellSize => write!(f, "grid map cell size must be positive"),
        }
    }
}

impl<'a> GridMap<'a> {
    /// `side` x `side` cells of `cell_m`, row-major in `heights_m`.
    pub fn new(heights_m: &'a [f32], side: usize, cell_m: f32) -> Result<Self, GridMapError> {
        let expected = side.saturating_mul(side);
        if heights_m.len() != expected || side == 0 {
            return Err(GridMapError::WrongLength {
                expected,
                found: heights_m.len(),
            });
        }
        if !(cell_m.is_finite() && cell_m > 0.0) {
            return Err(GridMapError::BadCellSize);
        }
        Ok(GridMap {
            heights_m,
            side,
            cell_m,
        })
    }

    /// Cells per side.
    pub fn side(&self) -> usize {
        self.side
    }

    /// Side of a cell.
    pub fn cell_m(&self) -> f32 {
        self.cell_m
    }
}

/// Where a [`FineWindow`] lies in its robot-centred square map: rows `first_row..` and
/// columns `first_col..` of a `side` x `side` map of `cell_m` cells (laid out as [`GridMap`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WindowBounds {
    /// Cells per side of the whole map.
    pub side: usize,
    /// Side of a cell.
    pub cell_m: f32,
    /// First row held.
    pub first_row: usize,
    /// Rows held.
    pub rows: usize,
    /// First column held.
    pub first_col: usize,
    /// Columns held.
    pub cols: usize,
}

impl WindowBounds {
    /// Cells held.
    pub fn cells(&self) -> usize {
        self.rows * self.cols
    }

    /// The rows of the whole map held.
    pub fn rows(&self) -> core::ops::Range<usize> {
        self.first_row..self.first_row + self.rows
    }

    /// The columns of the whole map held.
    pub fn cols(&self) -> core::ops::Range<usize> {
        self.first_col..self.first_col + self.cols
    }
}

/// The cells of a finer map that the robot and one step can touch, heights in millimetres:
/// what the guard needs of a 128 x 128 map at 1 cm (64 KiB of `f32`), in about 10 KiB.
///
/// Heights are little-endian `i16` pairs in a byte slice, so that a controller can lend the
/// same bytes to inference first and to the window after (the two are never needed at once).
/// Cells outside the window read as flat ground: [`CollisionGuard::fine_window`] chooses the
/// window so that no column outside can meet any part of the robot along any step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FineWindow<'a> {
    heights_mm_le: &'a [u8],
    bounds: WindowBounds,
    /// Per window row, the first and one past the last column (of the window) with a
    /// positive height: most of a window is flat ground, which the guard need not visit.
    occupied: [(u8, u8); MAX_WINDOW_ROWS],
}

/// Most rows a [`FineWindow`] holds (and columns it indexes in its occupancy table).
pub const MAX_WINDOW_ROWS: usize = 255;

impl<'a> FineWindow<'a> {
    /// The window `bounds` with heights (row-major, `bounds.rows` x `bounds.cols`, `i16`
    /// millimetres, little-endian) in the first `2 * bounds.cells()` bytes of `heights_mm_le`.
    pub fn new(heights_mm_le: &'a [u8], bounds: WindowBounds) -> Result<Self, GridMapError> {
        let expected = bounds.cells().saturating_mul(2);
        let heights_mm_le = heights_mm_le
            .get(..expected)
            .ok_or(GridMapError::WrongLength {
                expected,
                found: heights_mm_le.len(),
            })?;
        let fits = bounds.first_row.saturating_add(bounds.rows) <= bounds.side
            && bounds.first_col.saturating_add(bounds.cols) <= bounds.side;
        if !fits || bounds.side == 0 {
            return Err(GridMapError::WrongLength {
                expected: bounds.side.saturating_mul(bounds.side),
                found: bounds.cells(),
            });
        }
        if !(bounds.cell_m.is_finite() && bounds.cell_m > 0.0) {
            return Err(GridMapError::BadCellSize);
        }
        if bounds.rows > MAX_WINDOW_ROWS || bounds.cols > usize::from(u8::MAX) {
            return Err(GridMapError::WrongLength {
                expected: MAX_WINDOW_ROWS,
                found: bounds.rows.max(bounds.cols),
            });
        }
        let mut occupied = [(0u8, 0u8); MAX_WINDOW_ROWS];
        if bounds.cols > 0 {
            for (span, row) in occupied
                .iter_mut()
                .zip(heights_mm_le.chunks_exact(2 * bounds.cols))
            {
                let mut first = None;
                let mut last = 0;
                for (col, pair) in row.chunks_exact(2).enumerate() {
                    if let &[lo, hi] = pair {
                        if i16::from_le_bytes([lo, hi]) > 0 {
                            first.get_or_insert(col);
                            last = col + 1;
                        }
                    }
                }
                // Columns fit a u8 (checked above).
                *span = first.map_or((0, 0), |first| (first as u8, last as u8));
            }
        }
        Ok(FineWindow {
            heights_mm_le,
            bounds,
            occupied,
        })
    }

    /// The columns of the whole map's `row` that may hold a positive height.
    #[inline]
    fn occupied(&self, row: usize) -> core::ops::Range<usize> {
        let span = row
            .checked_sub(self.bounds.first_row)
            .and_then(|r| self.occupied.get(r));
        match span {
            Some(&(first, last)) => {
                self.bounds.first_col + usize::from(first)
                    ..self.bounds.first_col + usize::from(last)
            }
            None => 0..0,
        }
    }

    /// Where the window lies.
    pub fn bounds(&self) -> WindowBounds {
        self.bounds
    }

    /// Height of cell (`row`, `col`) of the whole map: 0 outside the window.
    #[inline]
    fn height_m(&self, row: usize, col: usize) -> f32 {
        let (Some(r), Some(c)) = (
            row.checked_sub(self.bounds.first_row),
            col.checked_sub(self.bounds.first_col),
        ) else {
            return 0.0;
        };
        if r >= self.bounds.rows || c >= self.bounds.cols {
            return 0.0;
        }
        let at = 2 * (r * self.bounds.cols + c);
        match self.heights_mm_le.get(at..at + 2) {
            Some(&[lo, hi]) => f32::from(i16::from_le_bytes([lo, hi])) * 1.0e-3,
            _ => 0.0,
        }
    }
}

/// Why the guard refuses an action.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Refusal {
    /// The legs cannot take the configuration the action asks for (or one on the way).
    Unreachable,
    /// A part of the robot would meet a column of the height map (grown by the margin) at one
    /// of the checked poses.
    Collision,
}

/// Checks actions against the height map before they are sent.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CollisionGuard {
    geometry: RobotGeometry,
    margin_m: f32,
    /// Cells farther than this from the robot's centre (along x or y) cannot touch it anywhere
    /// along a step.
    reach_m: f32,
}

impl CollisionGuard {
    /// A guard for `geometry` that grows every column's square by `margin_m` on each side
    /// (a square shrinks at most to its bare sample point; non-finite counts as 0).
    /// Heights are not padded: they are measured
    /// to the millimetre, not sampled.
    pub fn new(geometry: RobotGeometry, margin_m: f32) -> CollisionGuard {
        // At least minus half the policy's cell: the bound of every earlier version. A finer
        // map's squares are floored at their sample point where they are used.
        let margin_m = if margin_m.is_finite() {
            margin_m.max(-0.5 * HEIGHT_MAP_CELL_M)
        } else {
            0.0
        };
        let half_track_m = 0.5 * geometry.track_range_m[1] + 0.5 * geometry.wheel_width_m;
        let half_length_m =
            (0.5 * geometry.body_length_m).max(geometry.hip_x_m + geometry.wheel_radius_m);
        // The farthest any part gets from the centre, plus one step of travel and the growth.
        let reach_m =
            crate::trig::hypot(half_length_m, half_track_m.max(0.5 * geometry.body_width_m))
                + crate::action::MOVE_STEP_M * core::f32::consts::SQRT_2
                + margin_m.max(0.0);
        CollisionGuard {
            geometry,
            margin_m,
            reach_m,
        }
    }

    /// The window of a robot-centred `side` x `side` map of `cell_m` cells outside which no
    /// column can meet the robot on any step ([`FineWindow`]).
    ///
    /// Tighter than the square of [`Self::check`]'s reach (which bounds the robot's distance
    /// from its centre in any direction): along each map axis, the robot's extent along that
    /// axis in its own frame, turned by at most one yaw step (the farthest corner of a
    /// rectangle turned by an angle below its diagonal's is at that angle), plus one move step
    /// and the margin; then one cell more, as in [`Self::check`], for the column's own
    /// half-side.
    pub fn fine_window(&self, side: usize, cell_m: f32) -> WindowBounds {
        let g = &self.geometry;
        // The robot's half-extent along its own x and y, for any leg configuration: the
        // body, the wheels at the widest track, and the links (all in the hip's leg plane).
        let half_x_m =
            (0.5 * g.body_length_m).max(g.hip_x_m + g.wheel_radius_m.max(g.link_radius_m));
        let half_y_m = (0.5 * g.body_width_m)
            .max(0.5 * g.track_range_m[1] + 0.5 * g.wheel_width_m)
            .max(g.hip_y_m + g.thigh_m + g.link_radius_m);
        let turn_rad = crate::action::YAW_STEP_DEG.to_radians();
        let (sin, cos) = (crate::trig::sin(turn_rad), crate::trig::cos(turn_rad));
        let travel_m = crate::action::MOVE_STEP_M + self.margin_m.max(0.0);
        let reach_x_m = half_x_m * cos + half_y_m * sin + travel_m;
        let reach_y_m = half_y_m * cos + half_x_m * sin + travel_m;
        let span = |reach_m: f32| {
            let half = 0.5 * (side as f32 - 1.0);
            let cells = if cell_m > 0.0 {
                reach_m / cell_m + 1.0
            } else {
                0.0
            };
            let first = crate::trig::ceil(half - cells).max(0.0) as usize;
            let last = (crate::trig::floor(half + cells)
                .min(side as f32 - 1.0)
                .max(0.0) as usize)
                .max(first);
            (first, (last + 1).min(side) - first.min(side))
        };
        let (first_row, rows) = span(reach_x_m);
        let (first_col, cols) = span(reach_y_m);
        WindowBounds {
            side,
            cell_m,
            first_row,
            rows,
            first_col,
            cols,
        }
    }

    /// Check levels for [`crate::decision::Decider::choose_checked`]: [`Self::allows`] at
    /// level 0 is [`Self::check`], at level 1 [`Self::check_no_deeper`].
    pub const LEVELS: usize = 2;

    /// The check of `level` (see [`Self::LEVELS`]): whether `action` passes it. Levels past
    /// the last refuse everything.
    pub fn allows(
        &self,
        level: usize,
        heights: HeightMapRef<'_>,
        legs: LegConfig,
        action: Action,
    ) -> bool {
        match level {
            0 => self.check(heights, legs, action).is_ok(),
            1 => self.check_no_deeper(heights, legs, action).is_ok(),
            _ => false,
        }
    }

    /// The decider's choice for observation `key` among the actions this guard passes
    /// ([`crate::decision::Decider::choose_checked`] over [`Self::LEVELS`]): what a robot
    /// running the guard does each decision. With an `arrival`, an action that reaches the
    /// target and passes the strict check comes first, where [`Arrival::applies`]. The
    /// returned level is the guard's ([`Self::allows`]), whether or not the action arrives.
    pub fn choose<const STATES: usize, L: Copy + Into<f32>>(
        &self,
        decider: &mut Decider<STATES>,
        key: ObservationKey,
        logits: &[L; DIMS * CHOICES],
        heights: HeightMapRef<'_>,
        legs: LegConfig,
        arrival: Option<&Arrival>,
    ) -> Checked {
        let arrival = arrival.filter(|a| a.applies(decider, key));
        let first = usize::from(arrival.is_some());
        // Levels numbered as if arrival were always asked: 0 arrival, 1 strict, 2 lenient.
        let skipped = 1 - first;
        let mut checked =
            decider.choose_checked(key, logits, first + Self::LEVELS, |level, action| {
                match level + skipped {
                    0 => {
                        arrival.is_some_and(|a| a.reached_by(action))
                            && self.check(heights, legs, action).is_ok()
                    }
                    1 => self.check(heights, legs, action).is_ok(),
                    2 => self.check_no_deeper(heights, legs, action).is_ok(),
                    _ => false,
                }
            });
        checked.level = checked.level.map(|level| level.saturating_sub(first));
        checked
    }

    /// How much every column's square is grown on each side (negative: shrunk).
    pub fn margin_m(&self) -> f32 {
        self.margin_m
    }

    /// Whether `action`, taken from leg configuration `legs`, stays clear of the height map
    /// `heights` (seen from the robot's current pose) at every checked pose of its step.
    pub fn check(
        &self,
        heights: HeightMapRef<'_>,
        legs: LegConfig,
        action: Action,
    ) -> Result<(), Refusal> {
        self.check_from(heights, &Isometry2::identity(), legs, action)
    }

    /// [`Self::check`] of `action` taken from the pose `from` (in the frame of the robot that
    /// measured `heights`) with leg configuration `legs`: a step of a plan ahead, judged on the
    /// map measured now. Parts beyond the map's edge meet nothing: the caller keeps plans
    /// within the map.
    pub fn check_from(
        &self,
        heights: HeightMapRef<'_>,
        from: &Isometry2<f32>,
        legs: LegConfig,
        action: Action,
    ) -> Result<(), Refusal> {
        match self.deepest_overlap_m(heights, legs, action, Some(0.0), None, from)? {
            overlap_m if overlap_m >= 0.0 => Err(Refusal::Collision),
            _ => Ok(()),
        }
    }

    /// The lenient check, for when [`CollisionGuard::check`] refuses everything: the robot
    /// already overlaps a column where it stands (the grown columns claim more than is there),
    /// so an action passes if its step goes no deeper into any column than the current pose
    /// is, column by column: a column the robot does not overlap now must stay clear. (A
    /// check of the deepest overlap alone let a step into a new column pass as long as it went
    /// no deeper than the old one: on the 1 cm map, where a robot within 10 mm of an obstacle
    /// overlaps its grown columns, that was a collision.)
    pub fn check_no_deeper(
        &self,
        heights: HeightMapRef<'_>,
        legs: LegConfig,
        action: Action,
    ) -> Result<(), Refusal> {
        let here = Parts::place(&self.geometry, legs).ok_or(Refusal::Unreachable)?;
        match self.deepest_overlap_m(
            heights,
            legs,
            action,
            Some(OVERLAP_TOLERANCE_M),
            Some(&here),
            &Isometry2::identity(),
        )? {
            excess_m if excess_m >= OVERLAP_TOLERANCE_M => Err(Refusal::Collision),
            _ => Ok(()),
        }
    }

    /// The deepest overlap of any part with any column over the step's checked poses (0:
    /// touching; negative: no overlap, and then not exact, as columns that cannot reach the
    /// robot are skipped), stopping early once it reaches `stop_m`. Given the robot's parts
    /// `here` at its current pose, each column's overlap counts only past that pose's overlap
    /// with the same column (when positive).
    fn deepest_overlap_m(
        &self,
        heights: HeightMapRef<'_>,
        legs: LegConfig,
        action: Action,
        stop_m: Option<f32>,
        here: Option<&Parts>,
        from: &Isometry2<f32>,
    ) -> Result<f32, Refusal> {
        let target = target_config(legs, action);
        if !self.geometry.is_reachable(target) {
            return Err(Refusal::Unreachable);
        }
        let base = BaseDisplacement::of_action(action);
        let mut deepest_m = f32::NEG_INFINITY;
        for t in POSE_FRACTIONS {
            let legs_t = LegConfig {
                clearance_m: legs.clearance_m + t * (target.clearance_m - legs.clearance_m),
                track_m: legs.track_m + t * (target.track_m - legs.track_m),
            };
            let parts = Parts::place(&self.geometry, legs_t).ok_or(Refusal::Unreachable)?;
            let inverse = (from * base.isometry_at(t)).inverse();
            let (x0_m, y0_m) = (from.translation.x, from.translation.y);
            let (held_rows, held_cols) = heights.held();
            let rows = intersect(self.cells_within_reach(&heights, x0_m), held_rows);
            let cols = intersect(self.cells_within_reach(&heights, y0_m), held_cols);
            for row in rows {
                for col in intersect(cols.clone(), heights.occupied(row)) {
                    let (x_m, y_m) = heights.cell_centre_m(row, col);
                    let height_m = heights.height_at_m(row, col);
                    if height_m.is_nan() || height_m <= 0.0 {
                        continue;
                    }
                    let centre = inverse * Point2::new(x_m, y_m);
                    let column = Column {
                        x_m: centre.x,
                        y_m: centre.y,
                        half_m: (0.5 * heights.cell_m() + self.margin_m).max(0.0),
                        height_m,
                    };
                    if !parts.may_touch(&column) {
                        continue;
                    }
                    let mut overlap_m = parts.overlap_m(&column);
                    if let Some(here) = here {
                        let now = Column { x_m, y_m, ..column };
                        if here.may_touch(&now) {
                            overlap_m -= here.overlap_m(&now).max(0.0);
                        }
                    }
                    deepest_m = deepest_m.max(overlap_m);
                    if stop_m.is_some_and(|stop_m| deepest_m >= stop_m) {
                        return Ok(deepest_m);
                    }
                }
            }
        }
        Ok(deepest_m)
    }

    /// The rows (or columns: the map is square and centred) whose cells lie within the
    /// robot's reach of `centre_m` along that axis (x for rows, y for columns; 0 for the
    /// robot that measured the map).
    fn cells_within_reach(
        &self,
        heights: &HeightMapRef<'_>,
        centre_m: f32,
    ) -> core::ops::Range<usize> {
        let side = heights.side() as f32;
        // Rows count down from +x, columns from +y: the centre's index.
        let half = 0.5 * (side - 1.0) - centre_m / heights.cell_m();
        // One cell more: a column's square reaches half a cell past its centre.
        let cells = self.reach_m / heights.cell_m() + 1.0;
        // Saturating casts: a huge reach covers the whole map, never more.
        let first = crate::trig::ceil(half - cells).max(0.0) as usize;
        let last = crate::trig::floor(half + cells).min(side - 1.0) as usize;
        first..last + 1
    }
}

/// The indices in both ranges.
fn intersect(a: core::ops::Range<usize>, b: core::ops::Range<usize>) -> core::ops::Range<usize> {
    let start = a.start.max(b.start);
    start..a.end.min(b.end).max(start)
}

/// Overlap the lenient check forgives on top of the current pose's, per column: rounding.
const OVERLAP_TOLERANCE_M: f32 = 1.0e-4;

/// A column of the height map in the frame of the robot at the checked pose: a square from the
/// ground up to its height.
struct Column {
    x_m: f32,
    y_m: f32,
    half_m: f32,
    height_m: f32,
}

/// The robot's parts at one leg configuration, in its own frame with z measured from the ground.
struct Parts {
    clearance_m: f32,
    body_half_x_m: f32,
    body_half_y_m: f32,
    /// Per leg: hip, knee and wheel centre.
    legs: [[Point3<f32>; 3]; 4],
    link_radius_m: f32,
    wheel_radius_m: f32,
    wheel_half_width_m: f32,
    /// Half the extent of the whole robot along its x and y: a column beyond cannot touch it.
    half_extent_m: (f32, f32),
}

impl Parts {
    fn place(geometry: &RobotGeometry, legs: LegConfig) -> Option<Parts> {
        let joints = geometry.leg_ik(legs).ok()?;
        let centre_height_m = geometry.body_centre_height_m(legs.clearance_m);
        let mut points = [[Point3::origin(); 3]; 4];
        for (slot, leg) in points.iter_mut().zip(LegId::ALL) {
            let p = geometry.leg_points(leg, joints);
            *slot = [p.hip, p.knee, p.wheel].map(|q| Point3::new(q.x, q.y, q.z + centre_height_m));
        }
        let mut half_extent_m = (0.5 * geometry.body_length_m, 0.5 * geometry.body_width_m);
        for [hip, knee, wheel] in &points {
            let reach_x_m = hip.x.abs() + geometry.wheel_radius_m.max(geometry.link_radius_m);
            let reach_y_m = (wheel.y.abs() + 0.5 * geometry.wheel_width_m)
                .max(knee.y.abs().max(hip.y.abs()) + geometry.link_radius_m);
            half_extent_m.0 = half_extent_m.0.max(reach_x_m);
            half_extent_m.1 = half_extent_m.1.max(reach_y_m);
        }
        Some(Parts {
            half_extent_m,
            clearance_m: legs.clearance_m,
            body_half_x_m: 0.5 * geometry.body_length_m,
            body_half_y_m: 0.5 * geometry.body_width_m,
            legs: points,
            link_radius_m: geometry.link_radius_m,
            wheel_radius_m: geometry.wheel_radius_m,
            wheel_half_width_m: 0.5 * geometry.wheel_width_m,
        })
    }

    /// Whether `column` is within the robot's extent at all (if not, it overlaps nothing).
    fn may_touch(&self, column: &Column) -> bool {
        column.x_m.abs() - column.half_m <= self.half_extent_m.0
            && column.y_m.abs() - column.half_m <= self.half_extent_m.1
    }

    /// How deep the deepest part reaches into `column` (0: touching, as the simulator counts
    /// it; negative: apart). For the body box it is the least of its overlaps along x, y and z;
    /// for the round parts, radius minus distance.
    fn overlap_m(&self, column: &Column) -> f32 {
        let half_m = column.half_m;
        let body_m = (self.body_half_x_m + half_m - column.x_m.abs())
            .min(self.body_half_y_m + half_m - column.y_m.abs())
            .min(column.height_m - self.clearance_m);
        let (link_reach_m, wheel_reach_m) = (self.link_radius_m, self.wheel_radius_m);
        let mut deepest_m = body_m;
        for [hip, knee, wheel] in &self.legs {
            // Every point of a leg is in its leg plane, at the hip's x.
            let dx_m = ((column.x_m - hip.x).abs() - half_m).max(0.0);
            for (a, b) in [(hip, knee), (knee, wheel)] {
                let d_yz_m = segment_rect_distance_m(
                    (a.y, a.z),
                    (b.y, b.z),
                    (column.y_m - half_m, 0.0),
                    (column.y_m + half_m, column.height_m),
                );
                deepest_m = deepest_m.max(link_reach_m - crate::trig::hypot(dx_m, d_yz_m));
            }
            // Wheel: a disc in the x-z plane, as wide as the wheel along y.
            let dy_m = (column.y_m - wheel.y).abs() - half_m;
            let side_m = self.wheel_half_width_m - dy_m;
            let dx_m = ((column.x_m - wheel.x).abs() - half_m).max(0.0);
            let dz_m = (wheel.z - column.height_m).max(0.0);
            deepest_m = deepest_m.max(side_m.min(wheel_reach_m - crate::trig::hypot(dx_m, dz_m)));
        }
        deepest_m
    }
}

/// Distance in a plane from the segment `a`-`b` to the axis-aligned rectangle `lo`-`hi` (0 when
/// they meet). Two disjoint convex polygons are nearest at a vertex of one of them, so the
/// distance is the least of the segment's ends to the rectangle and the rectangle's corners to
/// the segment, once a crossing is ruled out.
fn segment_rect_distance_m(a: (f32, f32), b: (f32, f32), lo: (f32, f32), hi: (f32, f32)) -> f32 {
    if segment_crosses_rect(a, b, lo, hi) {
        return 0.0;
    }
    let point_to_rect = |p: (f32, f32)| {
        let dx = (lo.0 - p.0).max(p.0 - hi.0).max(0.0);
        let dy = (lo.1 - p.1).max(p.1 - hi.1).max(0.0);
        crate::trig::hypot(dx, dy)
    };
    let point_to_segment = |p: (f32, f32)| {
        let (dx, dy) = (b.0 - a.0, b.1 - a.1);
        let length_sq = dx * dx + dy * dy;
        let t = if length_sq > 0.0 {
            (((p.0 - a.0) * dx + (p.1 - a.1) * dy) / length_sq).clamp(0.0, 1.0)
        } else {
            0.0
        };
        crate::trig::hypot(a.0 + t * dx - p.0, a.1 + t * dy - p.1)
    };
    let corners = [lo, (hi.0, lo.1), hi, (lo.0, hi.1)];
    corners
        .into_iter()
        .map(point_to_segment)
        .chain([a, b].into_iter().map(point_to_rect))
        .fold(f32::INFINITY, f32::min)
}

/// Whether the segment `a`-`b` has a point in the closed rectangle `lo`-`hi` (Liang-Barsky
/// clipping: the parameter interval left after each slab must stay non-empty).
fn segment_crosses_rect(a: (f32, f32), b: (f32, f32), lo: (f32, f32), hi: (f32, f32)) -> bool {
    let (mut t0, mut t1) = (0.0f32, 1.0f32);
    for (start, delta, min, max) in [(a.0, b.0 - a.0, lo.0, hi.0), (a.1, b.1 - a.1, lo.1, hi.1)] {
        if delta == 0.0 {
            if start < min || start > max {
                return false;
            }
            continue;
        }
        let (mut enter, mut leave) = ((min - start) / delta, (max - start) / delta);
        if enter > leave {
            core::mem::swap(&mut enter, &mut leave);
        }
        t0 = t0.max(enter);
        t1 = t1.min(leave);
        if t0 > t1 {
            return false;
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::action::Step;
    use crate::observation::cell_centre_in_robot_m;
    use crate::robot::WHEELLEG;

    fn flat() -> [f32; HEIGHT_MAP_CELLS] {
        [0.0; HEIGHT_MAP_CELLS]
    }

    fn default_legs() -> LegConfig {
        LegConfig {
            clearance_m: WHEELLEG.default_clearance_m,
            track_m: WHEELLEG.default_track_m,
        }
    }

    fn forward() -> Action {
        let mut action = Action::IDLE;
        action.set(crate::action::Dim::MoveX, Step::Plus);
        action
    }

    /// Puts a block of `height_m` over robot-frame x in `[x0, x1]`, y in `[y0, y1]` (cell
    /// centres inside count).
    fn block(map: &mut [f32; HEIGHT_MAP_CELLS], x: (f32, f32), y: (f32, f32), height_m: f32) {
        for row in 0..HEIGHT_MAP_SIDE {
            for col in 0..HEIGHT_MAP_SIDE {
                let (cx, cy) = cell_centre_in_robot_m(row, col);
                if cx >= x.0 && cx <= x.1 && cy >= y.0 && cy <= y.1 {
                    map[row * HEIGHT_MAP_SIDE + col] = height_m;
                }
            }
        }
    }

    #[test]
    fn a_grid_map_is_checked_for_its_size_and_cell() {
        let cells = [0.0f32; 16];
        assert_eq!(
            GridMap::new(&cells, 5, 0.01),
            Err(GridMapError::WrongLength {
                expected: 25,
                found: 16
            })
        );
        assert_eq!(
            GridMap::new(&[], 0, 0.01),
            Err(GridMapError::WrongLength {
                expected: 0,
                found: 0
            })
        );
        assert_eq!(
            GridMap::new(&cells, 4, f32::NAN),
            Err(GridMapError::BadCellSize)
        );
        assert_eq!(GridMap::new(&cells, 4, 0.0), Err(GridMapError::BadCellSize));
        let grid = GridMap::new(&cells, 4, 0.01).unwrap();
        assert_eq!((grid.side(), grid.cell_m()), (4, 0.01));
    }

    #[test]
    fn a_grid_map_of_the_policy_layout_gets_the_policy_maps_verdicts() {
        // The same cells read through either door: every action, on a map with a wall, a
        // slab and a bar around the robot.
        let mut map = flat();
        block(&mut map, (0.3, 0.8), (0.2, 0.8), 0.4);
        block(&mut map, (-0.4, -0.1), (-0.25, 0.25), 0.05);
        block(&mut map, (0.05, 0.25), (-0.5, -0.42), 0.15);
        let grid = GridMap::new(&map, HEIGHT_MAP_SIDE, HEIGHT_MAP_CELL_M).unwrap();
        for margin_m in [-0.01, 0.0, DEFAULT_MARGIN_M, 0.02] {
            let guard = CollisionGuard::new(WHEELLEG, margin_m);
            for index in 0..crate::action::COUNT {
                let action = Action::from_index(index).unwrap();
                assert_eq!(
                    guard.check(HeightMapRef::Grid(grid), default_legs(), action),
                    guard.check(HeightMapRef::Metres(&map), default_legs(), action),
                    "{action:?} at margin {margin_m}"
                );
            }
        }
    }

    #[test]
    fn flat_ground_lets_every_reachable_action_through() {
        let guard = CollisionGuard::new(WHEELLEG, DEFAULT_MARGIN_M);
        let map = flat();
        for index in 0..crate::action::COUNT {
            let action = Action::from_index(index).unwrap();
            let reachable = WHEELLEG.is_reachable(target_config(default_legs(), action));
            let verdict = guard.check(HeightMapRef::Metres(&map), default_legs(), action);
            assert_eq!(verdict.is_ok(), reachable, "{action:?}: {verdict:?}");
        }
    }

    #[test]
    fn a_wall_just_ahead_refuses_forward_but_not_backward() {
        let guard = CollisionGuard::new(WHEELLEG, DEFAULT_MARGIN_M);
        let mut map = flat();
        // The wheels' front edge is at hip_x + radius = 0.25 m; a tall wall from 0.31 m.
        block(&mut map, (0.31, 0.8), (-0.8, 0.8), 0.5);
        let mut backward = Action::IDLE;
        backward.set(crate::action::Dim::MoveX, Step::Minus);
        let map_ref = HeightMapRef::Metres(&map);
        assert_eq!(
            guard.check(map_ref, default_legs(), forward()),
            Err(Refusal::Collision)
        );
        assert_eq!(guard.check(map_ref, default_legs(), backward), Ok(()));
        assert_eq!(guard.check(map_ref, default_legs(), Action::IDLE), Ok(()));
    }

    /// A 1 cm, 128 x 128 map with tall walls over robot-frame x >= `front_m` and y >= `left_m`.
    fn walls_1cm(front_m: f32, left_m: f32) -> [f32; 128 * 128] {
        let mut map = [0.0; 128 * 128];
        for row in 0..128 {
            for col in 0..128 {
                let (x, y) = ((63.5 - row as f32) * 0.01, (63.5 - col as f32) * 0.01);
                if x >= front_m || y >= left_m {
                    map[row * 128 + col] = 0.4;
                }
            }
        }
        map
    }

    #[test]
    fn the_lenient_check_forgives_an_overlap_where_the_robot_stands_but_no_new_contact() {
        let guard = CollisionGuard::new(WHEELLEG, DEFAULT_MARGIN_M);
        let legs = default_legs();
        let overlap = |map: &[f32], action| {
            let grid = HeightMapRef::Grid(GridMap::new(map, 128, 0.01).unwrap());
            guard
                .deepest_overlap_m(grid, legs, action, None, None, &Isometry2::identity())
                .unwrap()
        };
        // A wall on the left that the standing robot overlaps (the grown columns claim more
        // than is there) by a few millimetres, and one ahead that a forward step enters less
        // deeply than that.
        let far_m = 0.63;
        let left_m = (0..150)
            .map(|i| 0.4 - 0.002 * i as f32)
            .find(|&y| overlap(&walls_1cm(far_m, y), Action::IDLE) > 0.008)
            .expect("a left wall the robot overlaps");
        let here_m = overlap(&walls_1cm(far_m, left_m), Action::IDLE);
        let front_m = (0..100)
            .map(|i| 0.5 - 0.002 * i as f32)
            .find(|&x| overlap(&walls_1cm(x, 1.0), forward()) > 0.001)
            .expect("a front wall a forward step enters");
        let map = walls_1cm(front_m, left_m);
        let grid = HeightMapRef::Grid(GridMap::new(&map, 128, 0.01).unwrap());
        assert!(overlap(&walls_1cm(front_m, 1.0), forward()) < here_m);
        // Strict: everything that keeps the wall on the left overlapped is refused.
        assert_eq!(guard.check(grid, legs, forward()), Err(Refusal::Collision));
        // Lenient: standing still is forgiven, a step into the wall ahead is not, although
        // it goes less deep than the robot already overlaps the left wall.
        assert_eq!(guard.check_no_deeper(grid, legs, Action::IDLE), Ok(()));
        assert_eq!(
            guard.check_no_deeper(grid, legs, forward()),
            Err(Refusal::Collision)
        );
        let mut away = Action::IDLE;
        away.set(crate::action::Dim::MoveY, Step::Minus);
        assert_eq!(guard.check_no_deeper(grid, legs, away), Ok(()));
    }

    #[test]
    fn a_step_ahead_in_a_plan_is_judged_from_where_it_starts() {
        let guard = CollisionGuard::new(WHEELLEG, DEFAULT_MARGIN_M);
        // A wall a few steps ahead: clear from here, hit from 0.15 m further on, and from a
        // pose turned round at that place a step backwards (towards the wall) hits it too.
        let map = walls_1cm(0.45, 1.0);
        let grid = HeightMapRef::Grid(GridMap::new(&map, 128, 0.01).unwrap());
        let legs = default_legs();
        assert_eq!(guard.check(grid, legs, forward()), Ok(()));
        let on = Isometry2::new(nalgebra::Vector2::new(0.15, 0.0), 0.0);
        assert_eq!(
            guard.check_from(grid, &on, legs, forward()),
            Err(Refusal::Collision)
        );
        let turned = Isometry2::new(nalgebra::Vector2::new(0.15, 0.0), core::f32::consts::PI);
        let mut backward = Action::IDLE;
        backward.set(crate::action::Dim::MoveX, Step::Minus);
        assert_eq!(
            guard.check_from(grid, &turned, legs, backward),
            Err(Refusal::Collision)
        );
        assert_eq!(guard.check_from(grid, &turned, legs, forward()), Ok(()));
        // The identity is the plain check.
        assert_eq!(
            guard.check_from(grid, &Isometry2::identity(), legs, forward()),
            guard.check(grid, legs, forward())
        );
    }

    #[test]
    fn a_low_bar_between_the_wheels_passes_under_a_high_body_only() {
        let guard = CollisionGuard::new(WHEELLEG, 0.01);
        let mut map = flat();
        // A bar across the centre line, narrower than the gap between the wheels, 0.10 m high.
        block(&mut map, (0.0, 0.05), (-0.06, 0.06), 0.10);
        let map_ref = HeightMapRef::Metres(&map);
        let low = LegConfig {
            clearance_m: 0.08,
            track_m: WHEELLEG.default_track_m,
        };
        let high = LegConfig {
            clearance_m: 0.16,
            track_m: WHEELLEG.default_track_m,
        };
        assert_eq!(
            guard.check(map_ref, low, Action::IDLE),
            Err(Refusal::Collision)
        );
        assert_eq!(guard.check(map_ref, high, Action::IDLE), Ok(()));
    }

    #[test]
    fn where_everything_is_refused_the_lenient_level_lets_the_robot_back_off_only() {
        let guard = CollisionGuard::new(WHEELLEG, 0.025);
        let mut map = flat();
        // A wall whose first cells are centred 25 mm beyond the front wheels' reach: grown by
        // 25 mm, the columns overlap the wheels by 25 mm, so the strict check refuses even
        // standing still, and backing off too (its first quarter is still 12 mm inside).
        block(&mut map, (0.275, 0.8), (-0.8, 0.8), 0.5);
        let map_ref = HeightMapRef::Metres(&map);
        let mut backward = Action::IDLE;
        backward.set(crate::action::Dim::MoveX, Step::Minus);
        assert_eq!(
            guard.check(map_ref, default_legs(), Action::IDLE),
            Err(Refusal::Collision)
        );
        assert_eq!(
            guard.check_no_deeper(map_ref, default_legs(), backward),
            Ok(())
        );
        assert_eq!(
            guard.check_no_deeper(map_ref, default_legs(), Action::IDLE),
            Ok(())
        );
        assert_eq!(
            guard.check_no_deeper(map_ref, default_legs(), forward()),
            Err(Refusal::Collision)
        );
        assert!(guard.allows(1, map_ref, default_legs(), backward));
        assert!(!guard.allows(0, map_ref, default_legs(), backward));
        assert!(!guard.allows(CollisionGuard::LEVELS, map_ref, default_legs(), backward));
    }

    #[test]
    fn arrival_goes_first_only_where_the_guard_passes_it() {
        let guard = CollisionGuard::new(WHEELLEG, DEFAULT_MARGIN_M);
        // The target 6 cm ahead: one step forward arrives. The policy wants to turn in place.
        let arrival = Arrival::new(nalgebra::Vector2::new(0.06, 0.0), 0.05);
        let mut logits = [0.0f32; DIMS * CHOICES];
        for head in 0..DIMS {
            logits[head * CHOICES + 1] = 2.0;
        }
        logits[2 * CHOICES + 2] = 3.0;
        let choose_on = |map: &[f32; HEIGHT_MAP_CELLS]| {
            guard.choose(
                &mut Decider::<4>::new(),
                ObservationKey(7),
                &logits,
                HeightMapRef::Metres(map),
                default_legs(),
                Some(&arrival),
            )
        };
        let checked = choose_on(&flat());
        assert!(arrival.reached_by(checked.action), "{checked:?}");
        assert_eq!(checked.action.move_x, Step::Plus);
        assert_eq!(checked.level, Some(0), "the guard's strict level passed it");
        // A wall just beyond the wheels: every arriving step is refused, so the policy's turn.
        let mut walled = flat();
        block(&mut walled, (0.31, 0.8), (-0.8, 0.8), 0.5);
        let checked = choose_on(&walled);
        assert!(!arrival.reached_by(checked.action), "{checked:?}");
        assert_eq!(checked.action.yaw, Step::Plus);
        assert_eq!(checked.level, Some(0));
    }

    #[test]
    fn millimetres_and_metres_agree() {
        let guard = CollisionGuard::new(WHEELLEG, DEFAULT_MARGIN_M);
        let mut map = flat();
        block(&mut map, (0.2, 0.4), (0.15, 0.4), 0.07);
        let mut map_mm = [0i16; HEIGHT_MAP_CELLS];
        for (mm, m) in map_mm.iter_mut().zip(map.iter()) {
            *mm = libm::roundf(m * 1000.0) as i16;
        }
        for index in 0..crate::action::COUNT {
            let action = Action::from_index(index).unwrap();
            assert_eq!(
                guard.check(HeightMapRef::Metres(&map), default_legs(), action),
                guard.check(HeightMapRef::Millimetres(&map_mm), default_legs(), action),
            );
        }
    }

    #[test]
    fn unreachable_legs_are_refused() {
        let guard = CollisionGuard::new(WHEELLEG, 0.0);
        let legs = LegConfig {
            clearance_m: WHEELLEG.clearance_range_m[1],
            track_m: WHEELLEG.default_track_m,
        };
        let mut up = Action::IDLE;
        up.set(crate::action::Dim::Clearance, Step::Plus);
        let map = flat();
        assert_eq!(
            guard.check(HeightMapRef::Metres(&map), legs, up),
            Err(Refusal::Unreachable)
        );
    }

    #[test]
    fn bad_heights_and_margins_do_not_panic() {
        let guard = CollisionGuard::new(WHEELLEG, f32::NAN);
        assert_eq!(guard.margin_m(), 0.0);
        let mut map = [f32::NAN; HEIGHT_MAP_CELLS];
        map[0] = f32::INFINITY;
        map[1] = -1.0;
        let verdict = guard.check(HeightMapRef::Metres(&map), default_legs(), forward());
        assert_eq!(verdict, Ok(()));
        let bad_legs = LegConfig {
            clearance_m: f32::NAN,
            track_m: 0.3,
        };
        assert_eq!(
            guard.check(HeightMapRef::Metres(&map), bad_legs, forward()),
            Err(Refusal::Unreachable)
        );
    }

    #[test]
    fn segment_rect_distance_cases() {
        let (lo, hi) = ((0.0, 0.0), (1.0, 1.0));
        assert_eq!(segment_rect_distance_m((0.5, 0.5), (3.0, 3.0), lo, hi), 0.0);
        assert_eq!(
            segment_rect_distance_m((-1.0, 0.5), (2.0, 0.5), lo, hi),
            0.0
        );
        assert!((segment_rect_distance_m((2.0, -1.0), (2.0, 2.0), lo, hi) - 1.0).abs() < 1e-6);
        // A diagonal passing the corner (1, 1) at distance sqrt(2).
        let d = segment_rect_distance_m((1.0, 3.0), (3.0, 1.0), lo, hi);
        assert!((d - core::f32::consts::SQRT_2).abs() < 1e-6, "{d}");
    }

    /// The fine window gives the whole map's verdicts: every action, from several leg
    /// configurations, among blocks scattered over the whole 1 cm map, most of them near the
    /// window's edge (where a window one cell too small would be caught).
    #[test]
    fn fine_window_keeps_the_whole_maps_verdicts() {
        const SIDE: usize = 128;
        const CELL_M: f32 = 0.01;
        let guard = CollisionGuard::new(WHEELLEG, DEFAULT_MARGIN_M);
        let bounds = guard.fine_window(SIDE, CELL_M);
        assert!(bounds.rows < SIDE && bounds.cols < SIDE, "{bounds:?}");
        assert!(bounds.cells() <= 5600, "{bounds:?}");
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut next = move |n: usize| {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed % n as u64) as usize
        };
        let mut refused = 0;
        let mut checked = 0;
        for _case in 0..12 {
            let mut mm = [0i16; SIDE * SIDE];
            for _block in 0..6 {
                // Corners near the window's edge, rows or columns.
                let near = |first: usize, len: usize, pick: usize| match pick % 3 {
                    0 => first.saturating_sub(4) + pick % 8,
                    1 => (first + len).saturating_sub(4) + pick % 8,
                    _ => pick % SIDE,
                };
                let r0 = near(bounds.first_row, bounds.rows, next(1000)).min(SIDE - 1);
                let c0 = near(bounds.first_col, bounds.cols, next(1000)).min(SIDE - 1);
                let (h, w) = (1 + next(30), 1 + next(30));
                let height = 20 + next(300) as i16;
                for row in r0..(r0 + h).min(SIDE) {
                    for col in c0..(c0 + w).min(SIDE) {
                        mm[row * SIDE + col] = height;
                    }
                }
            }
            let mut metres = [0.0f32; SIDE * SIDE];
            for (m, &h) in metres.iter_mut().zip(&mm) {
                *m = f32::from(h) * 1.0e-3;
            }
            let grid = HeightMapRef::Grid(GridMap::new(&metres, SIDE, CELL_M).unwrap());
            let mut bytes = [0u8; 2 * 5600];
            let mut len = 0;
            for row in bounds.rows() {
                for col in bounds.cols() {
                    bytes[len..len + 2].copy_from_slice(&mm[row * SIDE + col].to_le_bytes());
                    len += 2;
                }
            }
            let fine = FineWindow::new(&bytes[..len], bounds).unwrap();
            let window = HeightMapRef::Window(&fine);
            for legs in [
                default_legs(),
                LegConfig {
                    clearance_m: 0.04,
                    track_m: 0.56,
                },
                LegConfig {
                    clearance_m: 0.24,
                    track_m: 0.16,
                },
            ] {
                for index in 0..crate::action::COUNT {
                    let action = Action::from_index(index).unwrap();
                    let whole = guard.check(grid, legs, action);
                    assert_eq!(
                        whole,
                        guard.check(window, legs, action),
                        "{action:?} {legs:?}"
                    );
                    assert_eq!(
                        guard.check_no_deeper(grid, legs, action),
                        guard.check_no_deeper(window, legs, action),
                        "{action:?} {legs:?}"
                    );
                    refused += usize::from(whole == Err(Refusal::Collision));
                    checked += 1;
                }
            }
        }
        // Not a vacuous comparison: many actions meet a block.
        assert!(refused > checked / 20, "{refused} of {checked}");
    }
}
