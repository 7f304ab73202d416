//! PNG pictures for people: a scene's top view and the height map the robot sees.
//!
//! A few filled rectangles, lines and discs are all these pictures need, so they are drawn
//! into an RGB buffer here rather than pulling a 2-D graphics stack into the simulator.

use crate::height_map::HeightMap;
use crate::obstacle::ObstacleKind;
use crate::scenario::Scenario;
use crate::state::RobotState;
use nalgebra::{Point2, Vector2};
use std::path::Path;
use wheelleg_runtime::observation::HEIGHT_MAP_SIDE;
use wheelleg_runtime::robot::RobotGeometry;

/// Pixels per metre of top views.
pub const TOP_VIEW_PX_PER_M: f32 = 200.0;
/// Tallest height shown at full colour (the block's height).
const FULL_SCALE_HEIGHT_M: f32 = 0.40;

/// An RGB image.
#[derive(Clone, Debug)]
pub struct Canvas {
    width: usize,
    height: usize,
    pixels: Vec<[u8; 3]>,
}

impl Canvas {
    /// A canvas filled with `colour`.
    pub fn new(width: usize, height: usize, colour: [u8; 3]) -> Self {
        Canvas {
            width,
            height,
            pixels: vec![colour; width * height],
        }
    }

    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// The colour at (x, y), or `None` outside.
    pub fn pixel(&self, x: usize, y: usize) -> Option<[u8; 3]> {
        (x < self.width && y < self.height).then(|| self.pixels[y * self.width + x])
    }

    fn put(&mut self, x: i64, y: i64, colour: [u8; 3]) {
        if x >= 0 && y >= 0 && (x as usize) < self.width && (y as usize) < self.height {
            self.pixels[y as usize * self.width + x as usize] = colour;
        }
    }

    /// Fills the pixel rectangle between two corners (both included; clipped to the canvas).
    pub fn fill_rect(&mut self, x0: i64, y0: i64, x1: i64, y1: i64, colour: [u8; 3]) {
        for y in y0.min(y1)..=y0.max(y1) {
            for x in x0.min(x1)..=x0.max(x1) {
                self.put(x, y, colour);
            }
        }
    }

    /// Grid lines every `cell_m` metres over the world rectangle `min`..`max`, placed on the
    /// canvas by `px` (top views and the relevance figure share it).
    pub fn grid(
        &mut self,
        min: Point2<f32>,
        max: Point2<f32>,
        cell_m: f32,
        px: impl Fn(Point2<f32>) -> (i64, i64),
        colour: [u8; 3],
    ) {
        let mut x = (min.x / cell_m).ceil() * cell_m;
        while x <= max.x {
            self.line(px(Point2::new(x, min.y)), px(Point2::new(x, max.y)), colour);
            x += cell_m;
        }
        let mut y = (min.y / cell_m).ceil() * cell_m;
        while y <= max.y {
            self.line(px(Point2::new(min.x, y)), px(Point2::new(max.x, y)), colour);
            y += cell_m;
        }
    }

    /// Draws a one-pixel line between two pixels (clipped to the canvas).
    pub fn line(&mut self, a: (i64, i64), b: (i64, i64), colour: [u8; 3]) {
        let steps = (b.0 - a.0).abs().max((b.1 - a.1).abs()).max(1);
        for i in 0..=steps {
            let t = i as f32 / steps as f32;
            let x = a.0 as f32 + t * (b.0 - a.0) as f32;
            let y = a.1 as f32 + t * (b.1 - a.1) as f32;
            self.put(x.round() as i64, y.round() as i64, colour);
        }
    }

    /// Fills a disc of `radius` pixels (clipped to the canvas).
    pub fn disc(&mut self, centre: (i64, i64), radius: i64, colour: [u8; 3]) {
        for dy in -radius..=radius {
            for dx in -radius..=radius {
                if dx * dx + dy * dy <= radius * radius {
                    self.put(centre.0 + dx, centre.1 + dy, colour);
                }
            }
        }
    }

    /// Writes the canvas as a PNG, atomically.
    pub fn save_png(&self, path: &Path) -> std::io::Result<()> {
        let mut bytes = Vec::new();
        {
            let mut encoder = png::Encoder::new(&mut bytes, self.width as u32, self.height as u32);
            encoder.set_color(png::ColorType::Rgb);
            encoder.set_depth(png::BitDepth::Eight);
            let mut writer = encoder.write_header().map_err(std::io::Error::other)?;
            let flat: Vec<u8> = self.pixels.iter().flatten().copied().collect();
            writer
                .write_image_data(&flat)
                .map_err(std::io::Error::other)?;
        }
        crate::atomic_write(path, &bytes)
    }
}

fn kind_colour(kind: ObstacleKind) -> [u8; 3] {
    match kind {
        ObstacleKind::Bar => [200, 60, 40],
        ObstacleKind::Slab => [60, 120, 200],
        ObstacleKind::Block => [70, 70, 70],
    }
}

/// Maps world points to pixels of a top view (world +x to the right, +y up).
struct View {
    min: Point2<f32>,
    height_px: usize,
}

impl View {
    fn px(&self, p: Point2<f32>) -> (i64, i64) {
        let x = ((p.x - self.min.x) * TOP_VIEW_PX_PER_M).round() as i64;
        let y = self.height_px as i64 - 1 - ((p.y - self.min.y) * TOP_VIEW_PX_PER_M).round() as i64;
        (x, y)
    }
}

/// Top view of a scenario: obstacles coloured by kind (darker is taller), the target (green),
/// the robot's footprint at the start (blue) and, if given, the path of body centres (orange)
/// with the footprint at its end.
pub fn top_view(scenario: &Scenario, geometry: &RobotGeometry, path: &[RobotState]) -> Canvas {
    let margin = 0.6;
    let mut min = Point2::new(
        scenario.start.position.x.min(scenario.target.x),
        scenario.start.position.y.min(scenario.target.y),
    );
    let mut max = Point2::new(
        scenario.start.position.x.max(scenario.target.x),
        scenario.start.position.y.max(scenario.target.y),
    );
    min -= Vector2::repeat(margin);
    max += Vector2::repeat(margin);
    let width = ((max.x - min.x) * TOP_VIEW_PX_PER_M).ceil() as usize;
    let height = ((max.y - min.y) * TOP_VIEW_PX_PER_M).ceil() as usize;
    let view = View {
        min,
        height_px: height,
    };
    let mut canvas = Canvas::new(width, height, [245, 245, 240]);
    // Grid lines every obstacle cell, for reading positions.
    let cell = crate::obstacle::GRID_CELL_M;
    canvas.grid(min, max, cell, |p| view.px(p), [225, 225, 220]);
    let mut obstacles = scenario.obstacles.clone();
    // Tall obstacles drawn last, so they stay visible where boxes overlap.
    obstacles.sort_by(|a, b| a.kind.size_m().2.total_cmp(&b.kind.size_m().2));
    for o in &obstacles {
        let b = o.ground_box();
        let shade = 1.0 - 0.5 * (b.height_m / FULL_SCALE_HEIGHT_M).min(1.0);
        let colour =
            kind_colour(o.kind).map(|c| (c as f32 * shade + 255.0 * (1.0 - shade) * 0.3) as u8);
        let (x0, y0) = view.px(Point2::new(b.min_x_m, b.min_y_m));
        let (x1, y1) = view.px(Point2::new(b.max_x_m, b.max_y_m));
        canvas.fill_rect(x0, y0, x1, y1, colour);
    }
    for pair in path.windows(2) {
        canvas.line(
            view.px(pair[0].position),
            view.px(pair[1].position),
            [240, 140, 20],
        );
    }
    draw_footprint(&mut canvas, &view, geometry, &scenario.start, [30, 60, 220]);
    if let Some(last) = path.last() {
        draw_footprint(&mut canvas, &view, geometry, last, [240, 140, 20]);
    }
    canvas.disc(view.px(scenario.target), 5, [20, 170, 60]);
    canvas
}

fn draw_footprint(
    canvas: &mut Canvas,
    view: &View,
    geometry: &RobotGeometry,
    state: &RobotState,
    colour: [u8; 3],
) {
    let half_l = 0.5 * geometry.body_length_m;
    let half_w = 0.5 * geometry.body_width_m;
    let corners = [
        (half_l, half_w),
        (half_l, -half_w),
        (-half_l, -half_w),
        (-half_l, half_w),
    ]
    .map(|(x, y)| view.px(state.robot_to_world(Vector2::new(x, y))));
    for i in 0..4 {
        canvas.line(corners[i], corners[(i + 1) % 4], colour);
    }
    // Heading tick, and the wheels as discs at their contact points.
    canvas.line(
        view.px(state.position),
        view.px(state.robot_to_world(Vector2::new(half_l, 0.0))),
        colour,
    );
    let track = state.leg_config(geometry).track_m;
    for (fore, side) in [(1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)] {
        let wheel = state.robot_to_world(Vector2::new(fore * geometry.hip_x_m, side * 0.5 * track));
        canvas.disc(view.px(wheel), 4, colour);
    }
}

/// The height map as the robot sees it, 8 px per cell: ahead at the top, left at the left;
/// black is ground, white is 0.40 m or more.
pub fn height_map_image(map: &HeightMap) -> Canvas {
    const SCALE: usize = 8;
    let mut canvas = Canvas::new(HEIGHT_MAP_SIDE * SCALE, HEIGHT_MAP_SIDE * SCALE, [0, 0, 0]);
    for row in 0..HEIGHT_MAP_SIDE {
        for col in 0..HEIGHT_MAP_SIDE {
            let level = (map[row * HEIGHT_MAP_SIDE + col] / FULL_SCALE_HEIGHT_M).clamp(0.0, 1.0);
            let grey = (40.0 + 215.0 * level) as u8;
            let colour = if map[row * HEIGHT_MAP_SIDE + col] > 0.0 {
                [grey, grey, grey]
            } else {
                [0, 0, 0]
            };
            let (x0, y0) = ((col * SCALE) as i64, (row * SCALE) as i64);
            canvas.fill_rect(x0, y0, x0 + SCALE as i64 - 1, y0 + SCALE as i64 - 1, colour);
        }
    }
    // The robot's centre, for orientation.
    let c = (HEIGHT_MAP_SIDE * SCALE / 2) as i64;
    canvas.disc((c, c), 2, [30, 60, 220]);
    canvas
}
