//! What the policy sees: the robot-centred height map and the robot's own state.
//!
//! The height map is a square grid aligned with the robot: row 0 is the row farthest *ahead*
//! (robot +x) and column 0 the column farthest to the *left* (robot +y), so an image of it shows
//! what is ahead at the top, as a driver would look at it. Heights are of the ground or of the
//! obstacle standing there, in metres above the ground.

/// Cells per side of the height map.
pub const HEIGHT_MAP_SIDE: usize = 32;
/// Number of cells in the height map.
pub const HEIGHT_MAP_CELLS: usize = HEIGHT_MAP_SIDE * HEIGHT_MAP_SIDE;
/// Side of one cell.
pub const HEIGHT_MAP_CELL_M: f32 = 0.05;
/// Length of the state vector: clearance, track, target x and target y in the robot frame.
pub const STATE_LEN: usize = 4;

/// Robot-frame (x forward, y left) position of the centre of cell (`row`, `col`).
pub fn cell_centre_in_robot_m(row: usize, col: usize) -> (f32, f32) {
    let half = 0.5 * (HEIGHT_MAP_SIDE as f32 - 1.0);
    (
        (half - row as f32) * HEIGHT_MAP_CELL_M,
        (half - col as f32) * HEIGHT_MAP_CELL_M,
    )
}
