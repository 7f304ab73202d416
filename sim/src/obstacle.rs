//! The three obstacle kinds and their footprints.
//!
//! Obstacles stand on the ground centred on 0.25 m grid cells with yaw 0 or 90 degrees, so every
//! obstacle is an axis-aligned box in the world frame: collision and height-map queries use that.

use nalgebra::{Point2, Vector3};
use serde::{Deserialize, Serialize};

/// Side of the square grid cells obstacles are centred on.
pub const GRID_CELL_M: f32 = 0.25;

/// What an obstacle is, and so how the robot must deal with it.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ObstacleKind {
    /// Long, narrow and tall: passed only by straddling it lengthwise with the body lifted.
    Bar,
    /// Short and wide: passed only by spreading the legs (which lowers the body).
    Slab,
    /// Too tall to pass over: driven around, or squeezed between.
    Block,
}

impl ObstacleKind {
    /// All kinds.
    pub const ALL: [ObstacleKind; 3] = [ObstacleKind::Bar, ObstacleKind::Slab, ObstacleKind::Block];

    /// Size at yaw 0: (length along world x, width along world y, height).
    pub const fn size_m(self) -> (f32, f32, f32) {
        match self {
            ObstacleKind::Bar => (0.25, 0.08, 0.15),
            ObstacleKind::Slab => (0.25, 0.45, 0.05),
            ObstacleKind::Block => (0.20, 0.20, 0.40),
        }
    }

    /// The kind's name in scenario files.
    pub const fn name(self) -> &'static str {
        match self {
            ObstacleKind::Bar => "bar",
            ObstacleKind::Slab => "slab",
            ObstacleKind::Block => "block",
        }
    }
}

/// Yaw of an obstacle: only the two grid-aligned orientations exist.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Default)]
pub enum ObstacleYaw {
    /// Length along world x.
    #[default]
    Deg0,
    /// Length along world y.
    Deg90,
}

impl ObstacleYaw {
    /// The yaw in degrees.
    pub const fn degrees(self) -> f32 {
        match self {
            ObstacleYaw::Deg0 => 0.0,
            ObstacleYaw::Deg90 => 90.0,
        }
    }
}

/// An obstacle placed in the world.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Obstacle {
    /// Its kind.
    pub kind: ObstacleKind,
    /// Centre of its footprint on the ground.
    pub centre: Point2<f32>,
    /// Its orientation.
    pub yaw: ObstacleYaw,
}

/// An axis-aligned box in the world frame, resting on the ground.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GroundBox {
    /// Minimum world x.
    pub min_x_m: f32,
    /// Maximum world x.
    pub max_x_m: f32,
    /// Minimum world y.
    pub min_y_m: f32,
    /// Maximum world y.
    pub max_y_m: f32,
    /// Top height above the ground.
    pub height_m: f32,
}

impl GroundBox {
    /// Whether the ground point lies in the footprint (boundary included).
    #[inline]
    pub fn contains(&self, x_m: f32, y_m: f32) -> bool {
        x_m >= self.min_x_m && x_m <= self.max_x_m && y_m >= self.min_y_m && y_m <= self.max_y_m
    }

    /// Distance on the ground from `point` to the footprint (0 on or inside it).
    pub fn ground_distance_m(&self, point: Point2<f32>) -> f32 {
        let dx_m = (self.min_x_m - point.x)
            .max(point.x - self.max_x_m)
            .max(0.0);
        let dy_m = (self.min_y_m - point.y)
            .max(point.y - self.max_y_m)
            .max(0.0);
        dx_m.hypot(dy_m)
    }

    /// Half extents (x, y, z) of the box.
    pub fn half_extents(&self) -> Vector3<f32> {
        Vector3::new(
            0.5 * (self.max_x_m - self.min_x_m),
            0.5 * (self.max_y_m - self.min_y_m),
            0.5 * self.height_m,
        )
    }

    /// Centre of the box in 3-D.
    pub fn centre(&self) -> Vector3<f32> {
        Vector3::new(
            0.5 * (self.min_x_m + self.max_x_m),
            0.5 * (self.min_y_m + self.max_y_m),
            0.5 * self.height_m,
        )
    }
}

impl Obstacle {
    /// A new obstacle.
    pub fn new(kind: ObstacleKind, x_m: f32, y_m: f32, yaw: ObstacleYaw) -> Self {
        Obstacle {
            kind,
            centre: Point2::new(x_m, y_m),
            yaw,
        }
    }

    /// The obstacle's box in the world frame.
    pub fn ground_box(&self) -> GroundBox {
        let (length, width, height_m) = self.kind.size_m();
        let (half_x, half_y) = match self.yaw {
            ObstacleYaw::Deg0 => (0.5 * length, 0.5 * width),
            ObstacleYaw::Deg90 => (0.5 * width, 0.5 * length),
        };
        GroundBox {
            min_x_m: self.centre.x - half_x,
            max_x_m: self.centre.x + half_x,
            min_y_m: self.centre.y - half_y,
            max_y_m: self.centre.y + half_y,
            height_m,
        }
    }
}

/// Centre of the grid cell with index `i` along one axis (cells are centred on 0.125 + 0.25 i).
pub fn cell_centre_m(index: i32) -> f32 {
    (index as f32 + 0.5) * GRID_CELL_M
}

/// Whether a coordinate is a grid cell centre (to within rounding noise).
pub fn is_cell_centre(value_m: f32) -> bool {
    let index = (value_m / GRID_CELL_M - 0.5).round();
    (cell_centre_m(index as i32) - value_m).abs() < 1e-4
}
