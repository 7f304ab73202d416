//! The robot-centred, robot-aligned height map the policy sees.
//!
//! Each cell holds the height of whatever stands at the cell's centre point (0 for bare ground):
//! the exact point sample of the scene, not an average. Obstacles are world-axis-aligned boxes
//! and the map is a rotated grid, so an obstacle covers, in each map row, one contiguous run of
//! cells: the renderer computes that run from the row's line equation (a scanline fill) and
//! confirms every cell of it with the exact point-in-box test, so the cost is per covered cell,
//! not per cell times obstacles.

use crate::obstacle::GroundBox;
use nalgebra::Point2;
use wheelleg_runtime::observation::{HEIGHT_MAP_CELLS, HEIGHT_MAP_CELL_M, HEIGHT_MAP_SIDE};

/// Heights of the map's cells in metres, row-major (row 0 ahead, column 0 left).
pub type HeightMap = [f32; HEIGHT_MAP_CELLS];

/// The layout of a robot-centred square map: cells per side and the side of a cell.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MapGrid {
    /// Cells per side.
    pub side: usize,
    /// Side of a cell.
    pub cell_m: f32,
}

impl MapGrid {
    /// The policy's map: 32 x 32 cells of 0.05 m.
    pub const POLICY: MapGrid = MapGrid {
        side: HEIGHT_MAP_SIDE,
        cell_m: HEIGHT_MAP_CELL_M,
    };

    /// A finer map for the collision guard: 128 x 128 cells of 0.01 m (1.28 m square, past
    /// the robot's reach over a step in every direction). At 1 cm the guard's default margin
    /// covers the half cell the sampling may hide.
    pub const GUARD_FINE: MapGrid = MapGrid {
        side: 128,
        cell_m: 0.01,
    };

    /// Cells in the map.
    pub const fn cells(self) -> usize {
        self.side * self.side
    }

    pub(crate) fn half_cells(self) -> f32 {
        0.5 * (self.side as f32 - 1.0)
    }
}

/// World position of the centre of cell (`row`, `col`) of the policy's map for a robot at
/// `position` with heading (cos, sin) = `heading`. The renderer uses exactly this arithmetic,
/// so tests can too.
#[inline]
pub fn cell_centre_world(
    position: Point2<f32>,
    heading: (f32, f32),
    row: usize,
    col: usize,
) -> Point2<f32> {
    let (bx, by, sx, sy) = row_line(MapGrid::POLICY, position, heading, row);
    Point2::new(bx - col as f32 * sx, by - col as f32 * sy)
}

/// The world line of a map row: cell `col` is at `(bx - col * sx, by - col * sy)`.
#[inline]
fn row_line(
    grid: MapGrid,
    position: Point2<f32>,
    (cos, sin): (f32, f32),
    row: usize,
) -> (f32, f32, f32, f32) {
    let half = grid.half_cells();
    let ahead_m = (half - row as f32) * grid.cell_m;
    let left_m = half * grid.cell_m;
    // Robot frame (ahead, left) to world: ahead along (cos, sin), left along (-sin, cos).
    let bx = position.x + ahead_m * cos - left_m * sin;
    let by = position.y + ahead_m * sin + left_m * cos;
    (bx, by, -grid.cell_m * sin, grid.cell_m * cos)
}

/// The smallest step along a row, per column, whose column span [`column_span`] computes
/// (see [`render`]).
const MIN_STEP_M: f32 = 1.0e-5;

/// Columns `c` (as reals) for which `lo <= base - c * step <= hi` (an empty span when none);
/// `inverse_step` is `1 / step`, or `None` when the step is too small for a good guess (then
/// every column). The span is only a guess within rounding (the caller widens it by a column
/// each side and confirms every cell exactly), so multiplying by the inverse, cheaper than
/// dividing, is as good.
#[inline]
fn column_span(base: f32, step: f32, inverse_step: Option<f32>, lo: f32, hi: f32) -> (f32, f32) {
    let Some(inverse_step) = inverse_step else {
        return (f32::NEG_INFINITY, f32::INFINITY);
    };
    debug_assert!(step.abs() >= MIN_STEP_M);
    let a = (base - hi) * inverse_step;
    let b = (base - lo) * inverse_step;
    if a <= b {
        (a, b)
    } else {
        (b, a)
    }
}

/// `x.ceil()` as an index clamped to `0..=last`: without SSE4.1 (the default x86-64 target)
/// `f32::ceil` is a library call, and the renderer takes a few per row of every obstacle.
#[inline]
fn ceil_index(x: f32, last: usize) -> Option<usize> {
    if x.is_nan() || x > last as f32 {
        return None;
    }
    if x <= 0.0 {
        return Some(0);
    }
    // 0 < x <= last: truncation is the floor, one more unless x is whole.
    let whole = x as usize;
    Some(if (whole as f32) < x { whole + 1 } else { whole })
}

/// `x.floor()` as an index clamped to `0..=last`, `None` below 0 (see [`ceil_index`]).
#[inline]
fn floor_index(x: f32, last: usize) -> Option<usize> {
    if x.is_nan() || x < 0.0 {
        return None;
    }
    if x >= last as f32 {
        return Some(last);
    }
    Some(x as usize)
}

/// Renders the height map of `boxes` seen from `position` with heading `yaw_rad` into `out`.
pub fn render(boxes: &[GroundBox], position: Point2<f32>, yaw_rad: f32, out: &mut HeightMap) {
    render_grid(boxes, position, yaw_rad, MapGrid::POLICY, out);
}

/// [`render`] on a map of any layout `grid` (a finer one for the collision guard). `out` must
/// hold `grid.cells()` heights; a shorter one is left all zero.
#[inline(always)]
pub fn render_grid(
    boxes: &[GroundBox],
    position: Point2<f32>,
    yaw_rad: f32,
    grid: MapGrid,
    out: &mut [f32],
) {
    out.fill(0.0);
    if grid.side == 0 || out.len() < grid.cells() {
        return;
    }
    let half_cells = grid.half_cells();
    // Distance from the map centre to its farthest cell centre: obstacles farther away are
    // skipped.
    let reach_m = half_cells * grid.cell_m * core::f32::consts::SQRT_2;
    let (sin, cos) = yaw_rad.sin_cos();
    // Every row steps along the same line direction: its inverses once per map.
    let (_, _, sx, sy) = row_line(grid, position, (cos, sin), 0);
    // A step this small (the heading within 0.01 degrees of an axis) makes the span a poor
    // guess: the rounding of the cell centres (about 1e-7 m) moves a boundary crossing by that
    // over the step, beyond the renderer's one column of slack (at 270 degrees, 0.05 m times
    // the rounded cosine, 2e-9 m, put it 45 columns off and lost boundary cells). The whole
    // row is then tried, still cell by cell exactly, narrowed by the other axis's span.
    let inverse = |step: f32| (step.abs() >= MIN_STEP_M).then(|| 1.0 / step);
    let (inverse_sx, inverse_sy) = (inverse(sx), inverse(sy));
    for b in boxes {
        if b.min_x_m > position.x + reach_m
            || b.max_x_m < position.x - reach_m
            || b.min_y_m > position.y + reach_m
            || b.max_y_m < position.y - reach_m
        {
            continue;
        }
        // Rows the box can touch: its corners' distance ahead of the robot, with one row of
        // slack each side for rounding; every cell is confirmed exactly below.
        let mut ahead_min = f32::INFINITY;
        let mut ahead_max = f32::NEG_INFINITY;
        for (x, y) in [
            (b.min_x_m, b.min_y_m),
            (b.min_x_m, b.max_y_m),
            (b.max_x_m, b.min_y_m),
            (b.max_x_m, b.max_y_m),
        ] {
            let ahead = (x - position.x) * cos + (y - position.y) * sin;
            ahead_min = ahead_min.min(ahead);
            ahead_max = ahead_max.max(ahead);
        }
        let last_index = grid.side - 1;
        let (Some(row_first), Some(row_last)) = (
            ceil_index(half_cells - ahead_max / grid.cell_m - 1.0, last_index),
            floor_index(half_cells - ahead_min / grid.cell_m + 1.0, last_index),
        ) else {
            continue;
        };
        for row in row_first..=row_last {
            let (bx, by, sx, sy) = row_line(grid, position, (cos, sin), row);
            let (xa, xb) = column_span(bx, sx, inverse_sx, b.min_x_m, b.max_x_m);
            let (ya, yb) = column_span(by, sy, inverse_sy, b.min_y_m, b.max_y_m);
            let (Some(first), Some(last)) = (
                ceil_index(xa.max(ya) - 1.0, last_index),
                floor_index(xb.min(yb) + 1.0, last_index),
            ) else {
                continue;
            };
            if first > last {
                continue;
            }
            let cells = &mut out[row * grid.side + first..=row * grid.side + last];
            for (col, cell) in (first..=last).zip(cells) {
                let x = bx - col as f32 * sx;
                let y = by - col as f32 * sy;
                if b.contains(x, y) && *cell < b.height_m {
                    *cell = b.height_m;
                }
            }
        }
    }
}

/// Reference renderer: tests every cell against every box. Slow and obviously right; the tests
/// hold [`render`] equal to it.
pub fn render_naive(boxes: &[GroundBox], position: Point2<f32>, yaw_rad: f32, out: &mut HeightMap) {
    let (sin, cos) = yaw_rad.sin_cos();
    for row in 0..HEIGHT_MAP_SIDE {
        for col in 0..HEIGHT_MAP_SIDE {
            let p = cell_centre_world(position, (cos, sin), row, col);
            out[row * HEIGHT_MAP_SIDE + col] = boxes
                .iter()
                .filter(|b| b.contains(p.x, p.y))
                .map(|b| b.height_m)
                .fold(0.0, f32::max);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// A box of the given centre and half sizes, of a random height.
    fn random_height_box(
        rng: &mut rand_chacha::ChaCha8Rng,
        (x, y): (f32, f32),
        (hx, hy): (f32, f32),
    ) -> GroundBox {
        GroundBox {
            min_x_m: x - hx,
            max_x_m: x + hx,
            min_y_m: y - hy,
            max_y_m: y + hy,
            height_m: rng.random_range(0.01..0.5),
        }
    }

    #[test]
    fn a_finer_grid_is_the_point_sample_at_its_own_cell_centres() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let grid = MapGrid::GUARD_FINE;
        let mut fast = vec![0.0; grid.cells()];
        for case in 0..200 {
            let boxes: Vec<GroundBox> = (0..rng.random_range(1..8))
                .map(|_| {
                    let centre = (rng.random_range(-0.7..0.7), rng.random_range(-0.7..0.7));
                    let half = (rng.random_range(0.02..0.3), rng.random_range(0.02..0.3));
                    random_height_box(&mut rng, centre, half)
                })
                .collect();
            let position = Point2::new(rng.random_range(-0.2..0.2), rng.random_range(-0.2..0.2));
            let yaw_rad: f32 = rng.random_range(-4.0..4.0);
            render_grid(&boxes, position, yaw_rad, grid, &mut fast);
            let (sin, cos) = yaw_rad.sin_cos();
            for row in 0..grid.side {
                let (bx, by, sx, sy) = row_line(grid, position, (cos, sin), row);
                for col in 0..grid.side {
                    let (x, y) = (bx - col as f32 * sx, by - col as f32 * sy);
                    let naive = boxes
                        .iter()
                        .filter(|b| b.contains(x, y))
                        .map(|b| b.height_m)
                        .fold(0.0, f32::max);
                    assert_eq!(
                        fast[row * grid.side + col],
                        naive,
                        "case {case} {row} {col}"
                    );
                }
            }
        }
        // Too short an output is left empty, not overrun.
        let mut short = vec![1.0; 10];
        render_grid(&[], Point2::origin(), 0.0, grid, &mut short);
        assert!(short.iter().all(|&h| h == 0.0));
    }

    #[test]
    fn the_scanline_renderer_is_the_naive_one_on_many_scenes() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let (mut fast, mut naive) = ([0.0; HEIGHT_MAP_CELLS], [0.0; HEIGHT_MAP_CELLS]);
        for case in 0..20_000 {
            let boxes: Vec<GroundBox> = (0..rng.random_range(1..14))
                .map(|_| {
                    // Grid-centred footprints of the obstacles' sizes, and now and then an odd
                    // one (thin, or off the grid).
                    let cell = |rng: &mut rand_chacha::ChaCha8Rng| {
                        (rng.random_range(-6..6) as f32 + 0.5) * 0.25
                    };
                    let (x, y) = (cell(&mut rng), cell(&mut rng));
                    let (hx, hy) = match rng.random_range(0..4) {
                        0 => (0.125, 0.04),
                        1 => (0.125, 0.225),
                        2 => (0.1, 0.1),
                        _ => (rng.random_range(0.001..0.3), rng.random_range(0.001..0.3)),
                    };
                    let half = if rng.random_bool(0.5) {
                        (hx, hy)
                    } else {
                        (hy, hx)
                    };
                    random_height_box(&mut rng, (x, y), half)
                })
                .collect();
            // On and off the 5 cm lattice, yaws on and off the 5 degree lattice.
            let position = if case % 2 == 0 {
                Point2::new(
                    0.025 + 0.05 * rng.random_range(-20..20) as f32,
                    0.025 + 0.05 * rng.random_range(-20..20) as f32,
                )
            } else {
                Point2::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0))
            };
            let yaw_rad = if rng.random_bool(0.5) {
                (rng.random_range(0..72) as f32 * 5.0).to_radians()
            } else {
                rng.random_range(-4.0..4.0)
            };
            render(&boxes, position, yaw_rad, &mut fast);
            render_naive(&boxes, position, yaw_rad, &mut naive);
            let differ: Vec<(usize, f32, f32)> = (0..HEIGHT_MAP_CELLS)
                .filter(|&i| fast[i] != naive[i])
                .map(|i| (i, fast[i], naive[i]))
                .collect();
            assert!(
                differ.is_empty(),
                "case {case}: cells (index, fast, naive) {differ:?} differ; {boxes:?} at \
                 {position:?} yaw {yaw_rad}"
            );
        }
    }
}
