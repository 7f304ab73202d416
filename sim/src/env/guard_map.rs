//! The collision guard's map of another layout than the policy's.

use super::Env;
use crate::height_map;

/// A map of another layout than the policy's, rendered around the robot for the collision
/// guard (`wheelleg_runtime::guard`), with the buffer it is rendered into: what the evaluation
/// and the robot's driver both read when the guard runs on a finer map.
#[derive(Clone, Debug)]
pub struct GuardMap {
    grid: height_map::MapGrid,
    heights_m: Vec<f32>,
}

impl GuardMap {
    /// An empty map of layout `grid`.
    pub fn new(grid: height_map::MapGrid) -> GuardMap {
        GuardMap {
            grid,
            heights_m: vec![0.0; grid.cells()],
        }
    }

    /// Its layout.
    pub fn grid(&self) -> height_map::MapGrid {
        self.grid
    }

    /// Renders the map around `env`'s robot, as the guard reads it; an error names a layout
    /// the guard cannot read (no cells, or a cell that is not a positive length).
    pub fn observe(
        &mut self,
        env: &Env,
    ) -> Result<wheelleg_runtime::guard::HeightMapRef<'_>, wheelleg_runtime::guard::GridMapError>
    {
        env.observe_grid(self.grid, &mut self.heights_m);
        let grid = wheelleg_runtime::guard::GridMap::new(
            &self.heights_m,
            self.grid.side,
            self.grid.cell_m,
        )?;
        Ok(wheelleg_runtime::guard::HeightMapRef::Grid(grid))
    }
}
