//! The essential area of a trajectory: the ground the robot's parts swept, plus a margin.
//!
//! The simulator decides collisions only at the poses it checks: the end pose of every step and
//! the half-way pose of every motion (docs/simulator.md). Every robot part lies inside its
//! axis-aligned bounding box, and every obstacle is a box standing on the ground, so an obstacle
//! whose ground footprint misses the ground projection of every part's box at every checked pose
//! cannot touch the robot anywhere along the trajectory. The essential area is the union of those
//! projected boxes, each grown by [`DEFAULT_MARGIN_M`] (or a chosen margin):
//!
//! - it absorbs the exact intersection test's numerical tolerance (parry's GJK decides "touching"
//!   to within about 1e-6 m, and touching counts as a collision);
//! - it keeps re-placed obstacles a step's length away from the robot, so the observations near
//!   the path stay as the policy met them.
//!
//! The half-way pose is included at *every* step, not only where the simulator checks it (near
//! obstacles), because a re-placed obstacle may stand anywhere outside the area.
//!
//! The area is kept both exactly (the list of grown boxes) and as a conservative raster of
//! [`RASTER_CELL_M`] cells, which answers most queries with a few cell lookups.

use super::{ReplayError, Trajectory};
use nalgebra::Point2;
use wheelleg_runtime::leg::{IkError, LegConfig};
use wheelleg_runtime::robot::RobotGeometry;
use wheelleg_sim::collision::RobotParts;
use wheelleg_sim::env::EnvConfig;
use wheelleg_sim::obstacle::{GroundBox, Obstacle};
use wheelleg_sim::state::RobotState;

/// Margin around every swept part box: one translation step (0.05 m), see the module comment.
pub const DEFAULT_MARGIN_M: f32 = 0.05;

/// Side of the raster cells (the height map's cell).
pub const RASTER_CELL_M: f32 = 0.05;

/// An axis-aligned rectangle on the ground, world frame, boundary included.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GroundRect {
    /// Corner with the smallest x and y.
    pub min: Point2<f32>,
    /// Corner with the largest x and y.
    pub max: Point2<f32>,
}

impl GroundRect {
    /// The footprint of an obstacle box.
    pub fn of_box(b: &GroundBox) -> Self {
        GroundRect {
            min: Point2::new(b.min_x_m, b.min_y_m),
            max: Point2::new(b.max_x_m, b.max_y_m),
        }
    }

    /// Whether the two rectangles share a point (touching counts, as in the simulator).
    pub fn intersects(&self, other: &GroundRect) -> bool {
        self.min.x <= other.max.x
            && other.min.x <= self.max.x
            && self.min.y <= other.max.y
            && other.min.y <= self.max.y
    }

    /// The rectangle grown by `margin_m` on every side.
    pub fn grown(&self, margin_m: f32) -> Self {
        GroundRect {
            min: self.min - nalgebra::Vector2::repeat(margin_m),
            max: self.max + nalgebra::Vector2::repeat(margin_m),
        }
    }

    fn merged(&self, other: &GroundRect) -> Self {
        GroundRect {
            min: Point2::new(self.min.x.min(other.min.x), self.min.y.min(other.min.y)),
            max: Point2::new(self.max.x.max(other.max.x), self.max.y.max(other.max.y)),
        }
    }
}

/// The essential area of one trajectory.
#[derive(Clone, Debug)]
pub struct EssentialArea {
    margin_m: f32,
    rects: Vec<GroundRect>,
    bounds: GroundRect,
    /// Raster origin: the corner of cell (0, 0).
    origin: Point2<f32>,
    cols: usize,
    rows: usize,
    /// Row-major; a cell is set when any rectangle touches it.
    cells: Vec<bool>,
}

/// The half-way pose the simulator checks between two consecutive states: position, yaw (the
/// short way round) and leg pose interpolated.
pub fn half_way(
    geometry: &RobotGeometry,
    from: &RobotState,
    to: &RobotState,
) -> (Point2<f32>, f32, LegConfig) {
    let (a, b) = (from.leg_config(geometry), to.leg_config(geometry));
    let legs = LegConfig {
        clearance_m: 0.5 * (a.clearance_m + b.clearance_m),
        track_m: 0.5 * (a.track_m + b.track_m),
    };
    // The same expression as the simulator's, so the pose is bit-for-bit the one it checks.
    let yaw_rad = from.yaw_rad() + 0.5 * from.yaw_turn_rad_to(to);
    let position = from.position + 0.5 * (to.position - from.position);
    (position, yaw_rad, legs)
}

impl EssentialArea {
    /// The area swept along `path` (consecutive states are one step apart, as
    /// [`super::Replay::path`]), every part box grown by `margin_m`.
    pub fn from_path(
        geometry: &RobotGeometry,
        path: &[RobotState],
        margin_m: f32,
    ) -> Result<Self, IkError> {
        let mut rects = Vec::with_capacity(path.len() * 2 * wheelleg_sim::collision::PART_COUNT);
        let mut add = |position: Point2<f32>, yaw_rad: f32, legs: LegConfig| {
            let parts = RobotParts::new(geometry, position, yaw_rad, legs)?;
            for part in parts.parts() {
                let aabb = part.aabb();
                rects.push(
                    GroundRect {
                        min: Point2::new(aabb.mins.x, aabb.mins.y),
                        max: Point2::new(aabb.maxs.x, aabb.maxs.y),
                    }
                    .grown(margin_m),
                );
            }
            Ok::<(), IkError>(())
        };
        for (i, state) in path.iter().enumerate() {
            if i > 0 && path[i - 1] == *state {
                continue;
            }
            add(state.position, state.yaw_rad(), state.leg_config(geometry))?;
            if i > 0 {
                let (position, yaw_rad, legs) = half_way(geometry, &path[i - 1], state);
                add(position, yaw_rad, legs)?;
            }
        }
        Ok(Self::from_rects(rects, margin_m))
    }

    /// The area of a trajectory's replay, with the robot of the episode rules.
    pub fn of_trajectory(
        trajectory: &Trajectory,
        config: EnvConfig,
        margin_m: f32,
    ) -> Result<Self, ReplayError> {
        let replay = trajectory.replay(config)?;
        // Every state on a replayed path passed the simulator's leg check.
        Self::from_path(config.robot.geometry(), &replay.path, margin_m).map_err(|e| {
            ReplayError::Scenario(wheelleg_sim::scenario::ScenarioError {
                scenario: trajectory.scenario.name.clone(),
                field: "robot".into(),
                problem: format!("a pose on the path has no leg solution: {e:?}"),
            })
        })
    }

    /// The area covered by `rects` (already grown), raster built here.
    fn from_rects(rects: Vec<GroundRect>, margin_m: f32) -> Self {
        let Some(first) = rects.first() else {
            return EssentialArea {
                margin_m,
                rects,
                bounds: GroundRect {
                    min: Point2::origin(),
                    max: Point2::origin(),
                },
                origin: Point2::origin(),
                cols: 0,
                rows: 0,
                cells: Vec::new(),
            };
        };
        let bounds = rects.iter().fold(*first, |acc, r| acc.merged(r));
        let origin = Point2::new(
            (bounds.min.x / RASTER_CELL_M).floor() * RASTER_CELL_M,
            (bounds.min.y / RASTER_CELL_M).floor() * RASTER_CELL_M,
        );
        let cols = ((bounds.max.x - origin.x) / RASTER_CELL_M).floor() as usize + 1;
        let rows = ((bounds.max.y - origin.y) / RASTER_CELL_M).floor() as usize + 1;
        let mut area = EssentialArea {
            margin_m,
            rects: Vec::new(),
            bounds,
            origin,
            cols,
            rows,
            cells: vec![false; cols * rows],
        };
        for r in &rects {
            let (c0, r0, c1, r1) = area.cell_span(r);
            for row in r0..=r1 {
                area.cells[row * cols + c0..=row * cols + c1].fill(true);
            }
        }
        area.rects = rects;
        area
    }

    /// Cells touched by `rect`, clamped to the raster: (first col, first row, last col, last
    /// row). A point p lies in cell floor((p - origin) / cell), and any point of `rect` maps
    /// between its corners' cells, so two rectangles that share a point share a cell.
    fn cell_span(&self, rect: &GroundRect) -> (usize, usize, usize, usize) {
        let index = |v: f32, o: f32, n: usize| {
            (((v - o) / RASTER_CELL_M).floor().max(0.0) as usize).min(n.saturating_sub(1))
        };
        (
            index(rect.min.x, self.origin.x, self.cols),
            index(rect.min.y, self.origin.y, self.rows),
            index(rect.max.x, self.origin.x, self.cols),
            index(rect.max.y, self.origin.y, self.rows),
        )
    }

    /// Whether `rect` meets the area (exact: against the grown part boxes themselves).
    pub fn intersects_rect(&self, rect: &GroundRect) -> bool {
        if self.cells.is_empty() || !self.bounds.intersects(rect) {
            return false;
        }
        // The raster is conservative, so an untouched raster proves the rectangle clear.
        let (c0, r0, c1, r1) = self.cell_span(rect);
        let any_cell = (r0..=r1).any(|row| {
            self.cells[row * self.cols + c0..=row * self.cols + c1]
                .iter()
                .any(|&c| c)
        });
        any_cell && self.rects.iter().any(|r| r.intersects(rect))
    }

    /// Whether an obstacle's ground footprint meets the area.
    pub fn intersects_obstacle(&self, obstacle: &Obstacle) -> bool {
        self.intersects_rect(&GroundRect::of_box(&obstacle.ground_box()))
    }

    /// The margin the part boxes were grown by.
    pub fn margin_m(&self) -> f32 {
        self.margin_m
    }

    /// The grown part boxes whose union is the area.
    pub fn rects(&self) -> &[GroundRect] {
        &self.rects
    }

    /// Bounding rectangle of the whole area.
    pub fn bounds(&self) -> GroundRect {
        self.bounds
    }

    /// Area of the raster cells touched, m² (an upper bound of the exact area; for reports).
    pub fn raster_area_m2(&self) -> f32 {
        self.cells.iter().filter(|&&c| c).count() as f32 * RASTER_CELL_M * RASTER_CELL_M
    }

    /// Whether the ground point is in the area.
    pub fn contains(&self, point: Point2<f32>) -> bool {
        self.intersects_rect(&GroundRect {
            min: point,
            max: point,
        })
    }
}
