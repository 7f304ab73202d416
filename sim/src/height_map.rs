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

const HALF_CELLS: f32 = 0.5 * (HEIGHT_MAP_SIDE as f32 - 1.0);
/// Distance from the map centre to its farthest cell centre: obstacles farther away are skipped.
const REACH_M: f32 = HALF_CELLS * HEIGHT_MAP_CELL_M * core::f32::consts::SQRT_2;

/// World position of the centre of cell (`row`, `col`) for a robot at `position` with heading
/// (cos, sin) = `heading`. The renderer uses exactly this arithmetic, so tests can too.
#[inline]
pub fn cell_centre_world(
    position: Point2<f32>,
    heading: (f32, f32),
    row: usize,
    col: usize,
) -> Point2<f32> {
    let (bx, by, sx, sy) = row_line(position, heading, row);
    Point2::new(bx - col as f32 * sx, by - col as f32 * sy)
}

/// The world line of a map row: cell `col` is at `(bx - col * sx, by - col * sy)`.
#[inline]
fn row_line(position: Point2<f32>, (cos, sin): (f32, f32), row: usize) -> (f32, f32, f32, f32) {
    let ahead_m = (HALF_CELLS - row as f32) * HEIGHT_MAP_CELL_M;
    let left_m = HALF_CELLS * HEIGHT_MAP_CELL_M;
    // Robot frame (ahead, left) to world: ahead along (cos, sin), left along (-sin, cos).
    let bx = position.x + ahead_m * cos - left_m * sin;
    let by = position.y + ahead_m * sin + left_m * cos;
    (bx, by, -HEIGHT_MAP_CELL_M * sin, HEIGHT_MAP_CELL_M * cos)
}

/// Columns `c` (as reals) for which `lo <= base - c * step <= hi`, or `None` if none.
#[inline]
fn column_span(base: f32, step: f32, lo: f32, hi: f32) -> Option<(f32, f32)> {
    if step.abs() < 1e-9 {
        return (base >= lo && base <= hi).then_some((f32::NEG_INFINITY, f32::INFINITY));
    }
    let a = (base - hi) / step;
    let b = (base - lo) / step;
    Some(if a <= b { (a, b) } else { (b, a) })
}

/// Renders the height map of `boxes` seen from `position` with heading `yaw_rad` into `out`.
pub fn render(boxes: &[GroundBox], position: Point2<f32>, yaw_rad: f32, out: &mut HeightMap) {
    out.fill(0.0);
    let (sin, cos) = yaw_rad.sin_cos();
    for b in boxes {
        if b.min_x_m > position.x + REACH_M
            || b.max_x_m < position.x - REACH_M
            || b.min_y_m > position.y + REACH_M
            || b.max_y_m < position.y - REACH_M
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
        let row_first = (HALF_CELLS - ahead_max / HEIGHT_MAP_CELL_M - 1.0)
            .ceil()
            .max(0.0);
        let row_last = (HALF_CELLS - ahead_min / HEIGHT_MAP_CELL_M + 1.0)
            .floor()
            .min(HEIGHT_MAP_SIDE as f32 - 1.0);
        if row_first > row_last {
            continue;
        }
        for row in row_first as usize..=row_last as usize {
            let (bx, by, sx, sy) = row_line(position, (cos, sin), row);
            let Some((xa, xb)) = column_span(bx, sx, b.min_x_m, b.max_x_m) else {
                continue;
            };
            let Some((ya, yb)) = column_span(by, sy, b.min_y_m, b.max_y_m) else {
                continue;
            };
            let first = (xa.max(ya) - 1.0).ceil().max(0.0);
            let last = (xb.min(yb) + 1.0).floor().min(HEIGHT_MAP_SIDE as f32 - 1.0);
            if first > last {
                continue;
            }
            let (first, last) = (first as usize, last as usize);
            let cells = &mut out[row * HEIGHT_MAP_SIDE + first..=row * HEIGHT_MAP_SIDE + last];
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
