//! The maps the guard reads: the policy's own, a finer square map, or the window of one that a
//! controller keeps.

use crate::observation::{HEIGHT_MAP_CELLS, HEIGHT_MAP_CELL_M, HEIGHT_MAP_SIDE};

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
    /// The height of cell (`row`, `col`) of the whole map (0 outside what is held); an unknown
    /// height (NaN, only in the maps in metres) as the tallest obstacle
    /// ([`super::UNKNOWN_HEIGHT_M`]: a map in millimetres carries it as
    /// [`super::UNKNOWN_HEIGHT_MM`]).
    pub(super) fn height_at_m(&self, row: usize, col: usize) -> f32 {
        let index = row * self.side() + col;
        match self {
            HeightMapRef::Millimetres(cells) => {
                cells.get(index).map_or(0.0, |&mm| f32::from(mm) * 1.0e-3)
            }
            HeightMapRef::Metres(cells) => cells
                .get(index)
                .map_or(0.0, |&m| super::known_or_tallest_m(m)),
            HeightMapRef::Grid(grid) => grid
                .heights_m
                .get(index)
                .map_or(0.0, |&m| super::known_or_tallest_m(m)),
            HeightMapRef::Window(window) => window.height_m(row, col),
        }
    }

    /// Cells per side.
    pub(super) fn side(&self) -> usize {
        match self {
            HeightMapRef::Grid(grid) => grid.side,
            HeightMapRef::Window(window) => window.bounds.side,
            _ => HEIGHT_MAP_SIDE,
        }
    }

    /// Side of a cell.
    pub(super) fn cell_m(&self) -> f32 {
        match self {
            HeightMapRef::Grid(grid) => grid.cell_m,
            HeightMapRef::Window(window) => window.bounds.cell_m,
            _ => HEIGHT_MAP_CELL_M,
        }
    }

    /// The columns of `row` that may hold a positive height (all but a window's, which knows
    /// each row's first and last): cells outside are skipped, as flat ones would be.
    #[inline]
    pub(super) fn occupied(&self, row: usize) -> core::ops::Range<usize> {
        match self {
            HeightMapRef::Window(window) => window.occupied(row),
            _ => 0..self.side(),
        }
    }

    /// The rows and columns that hold heights: the whole map, or a window's part of it.
    pub(super) fn held(&self) -> (core::ops::Range<usize>, core::ops::Range<usize>) {
        match self {
            HeightMapRef::Window(window) => (window.bounds.rows(), window.bounds.cols()),
            _ => (0..self.side(), 0..self.side()),
        }
    }

    /// Robot-frame (x forward, y left) centre of cell (`row`, `col`), laid out as the policy's
    /// map ([`crate::observation::cell_centre_in_robot_m`]): row 0 ahead, column 0 left, the robot at the centre.
    pub(super) fn cell_centre_m(&self, row: usize, col: usize) -> (f32, f32) {
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
/// Cells outside the window read as flat ground: [`crate::guard::CollisionGuard::fine_window`] chooses the
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
    pub(super) fn occupied(&self, row: usize) -> core::ops::Range<usize> {
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
    pub(super) fn height_m(&self, row: usize, col: usize) -> f32 {
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
