//! PNG pictures for people, drawn with `plotters`: a scene's top view with the way the robot
//! took ([`top_view`]), the height map it sees ([`height_map_image`]), a robot's front and
//! side views at its extreme poses ([`robot_views`]), and the pieces other figures share (a chart in world metres, obstacles by kind, the robot's footprint).
//!
//! Every picture has axes in metres and a legend or a colour bar, and draws its text with the
//! vendored DejaVu Sans (`third_party/dejavu`), so it looks the same on every machine.

use crate::obstacle::{Obstacle, ObstacleKind};
use crate::state::RobotState;
use nalgebra::{Point2, Vector2};
use plotters::coord::types::RangedCoordf32;
use plotters::coord::Shift;
use plotters::prelude::*;
use std::fmt;
use std::path::Path;
use std::sync::OnceLock;
use wheelleg_runtime::robot::RobotGeometry;

mod height_map;
mod robot_views;
mod top_view;

pub use height_map::height_map_image;
pub use robot_views::robot_views;
pub use top_view::top_view;

/// Pixels per metre of the charts of scenes.
pub const TOP_VIEW_PX_PER_M: f32 = 200.0;

/// The font family every picture's text is drawn in.
pub const FONT: &str = "sans-serif";

/// DejaVu Sans, registered with plotters as [`FONT`] on first use.
static DEJAVU_SANS: &[u8] = include_bytes!("../../../third_party/dejavu/DejaVuSans.ttf");

/// A picture that could not be drawn (plotters' error, as text).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RenderError(pub String);

impl fmt::Display for RenderError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "cannot draw the picture: {}", self.0)
    }
}

impl std::error::Error for RenderError {}

/// A plotters error as a [`RenderError`].
pub fn draw_error(e: impl fmt::Display) -> RenderError {
    RenderError(e.to_string())
}

/// Registers the vendored font as [`FONT`] (once per process); figures outside this module
/// that draw text call it before drawing.
pub fn register_font() -> Result<(), RenderError> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED.get_or_init(|| {
        plotters::style::register_font(FONT, FontStyle::Normal, DEJAVU_SANS).is_ok()
    });
    ok.then_some(())
        .ok_or_else(|| RenderError("the vendored DejaVu Sans does not load".into()))
}

/// An RGB image.
#[derive(Clone, Debug)]
pub struct Canvas {
    width: usize,
    height: usize,
    rgb: Vec<u8>,
}

impl Canvas {
    /// A white canvas.
    pub fn new(width: usize, height: usize) -> Self {
        Canvas {
            width,
            height,
            rgb: vec![255; 3 * width * height],
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
        (x < self.width && y < self.height).then(|| {
            let i = 3 * (y * self.width + x);
            [self.rgb[i], self.rgb[i + 1], self.rgb[i + 2]]
        })
    }

    /// The canvas as a plotters drawing area (the font registered first).
    pub fn area(&mut self) -> Result<DrawingArea<BitMapBackend<'_>, Shift>, RenderError> {
        register_font()?;
        let size = (self.width as u32, self.height as u32);
        Ok(BitMapBackend::with_buffer(&mut self.rgb, size).into_drawing_area())
    }

    /// Writes the canvas as a PNG, atomically.
    pub fn save_png(&self, path: &Path) -> std::io::Result<()> {
        let mut bytes = Vec::new();
        {
            let mut encoder = png::Encoder::new(&mut bytes, self.width as u32, self.height as u32);
            encoder.set_color(png::ColorType::Rgb);
            encoder.set_depth(png::BitDepth::Eight);
            let mut writer = encoder.write_header().map_err(std::io::Error::other)?;
            writer
                .write_image_data(&self.rgb)
                .map_err(std::io::Error::other)?;
        }
        crate::atomic_write(path, &bytes)
    }
}

/// A chart whose coordinates are world metres.
pub type SceneChart<'a, 'b> =
    ChartContext<'a, BitMapBackend<'b>, Cartesian2d<RangedCoordf32, RangedCoordf32>>;

/// Room around a scene chart's plot: margin, axis labels and caption, in pixels.
const MARGIN_PX: u32 = 12;
const X_LABELS_PX: u32 = 40;
const Y_LABELS_PX: u32 = 52;
const CAPTION_PX: u32 = 30;

/// The world rectangle around `points`, grown by `margin_m` on every side.
pub fn extent(
    points: impl IntoIterator<Item = Point2<f32>>,
    margin_m: f32,
) -> (Point2<f32>, Point2<f32>) {
    let (mut min, mut max) = (
        Point2::new(f32::INFINITY, f32::INFINITY),
        Point2::new(f32::NEG_INFINITY, f32::NEG_INFINITY),
    );
    for p in points {
        min = min.inf(&p);
        max = max.sup(&p);
    }
    if !(min.x.is_finite() && max.x.is_finite()) {
        (min, max) = (Point2::origin(), Point2::origin());
    }
    (
        min - Vector2::repeat(margin_m),
        max + Vector2::repeat(margin_m),
    )
}

/// Pixel size of one scene chart of the world rectangle `min`..`max` at
/// [`TOP_VIEW_PX_PER_M`] (metres on both axes at the same scale), labels and caption included.
pub fn chart_size(min: Point2<f32>, max: Point2<f32>) -> (usize, usize) {
    let plot = |span_m: f32| (span_m.max(0.1) * TOP_VIEW_PX_PER_M).ceil() as u32;
    (
        (plot(max.x - min.x) + Y_LABELS_PX + 2 * MARGIN_PX) as usize,
        (plot(max.y - min.y) + X_LABELS_PX + CAPTION_PX + 2 * MARGIN_PX) as usize,
    )
}

/// A chart of the world rectangle `min`..`max` on `area`: axes in metres with a grid line
/// every obstacle cell, `caption` above.
pub fn scene_chart<'a, 'b>(
    area: &'a DrawingArea<BitMapBackend<'b>, Shift>,
    min: Point2<f32>,
    max: Point2<f32>,
    caption: &str,
) -> Result<SceneChart<'a, 'b>, RenderError> {
    let mut chart = ChartBuilder::on(area)
        .caption(caption, (FONT, 18))
        .margin(MARGIN_PX)
        .x_label_area_size(X_LABELS_PX)
        .y_label_area_size(Y_LABELS_PX)
        .build_cartesian_2d(min.x..max.x, min.y..max.y)
        .map_err(draw_error)?;
    let cells = |span_m: f32| (span_m / crate::obstacle::GRID_CELL_M).round().max(1.0) as usize;
    chart
        .configure_mesh()
        .x_labels(cells(max.x - min.x) / 2 + 1)
        .y_labels(cells(max.y - min.y) / 2 + 1)
        .max_light_lines(1)
        .bold_line_style(RGBColor(225, 225, 220))
        .light_line_style(RGBColor(240, 240, 236))
        .x_desc("x (m)")
        .y_desc("y (m)")
        .label_style((FONT, 13))
        .axis_desc_style((FONT, 14))
        .x_label_formatter(&|x| format!("{x:.2}"))
        .y_label_formatter(&|y| format!("{y:.2}"))
        .draw()
        .map_err(draw_error)?;
    Ok(chart)
}

/// The robot at its start, in every picture.
pub const START: RGBColor = RGBColor(30, 60, 220);
/// The target, in every picture.
pub const TARGET: RGBColor = RGBColor(20, 170, 60);
/// Obstacles' edges.
pub const EDGE: RGBColor = RGBColor(50, 50, 50);

/// Draws the target as a disc.
pub fn draw_target(chart: &mut SceneChart<'_, '_>, target: Point2<f32>) -> Result<(), RenderError> {
    chart
        .draw_series([Circle::new((target.x, target.y), 6, TARGET.filled())])
        .map_err(draw_error)?;
    Ok(())
}

/// The colour of an obstacle kind in every picture.
pub fn kind_colour(kind: ObstacleKind) -> RGBColor {
    match kind {
        ObstacleKind::Bar => RGBColor(200, 60, 40),
        ObstacleKind::Slab => RGBColor(60, 120, 200),
        ObstacleKind::Block => RGBColor(90, 90, 90),
    }
}

/// The name of an obstacle kind in legends, with its height.
pub fn kind_label(kind: ObstacleKind) -> String {
    format!("{} ({:.2} m high)", kind.name(), kind.size_m().2)
}

/// The world rectangle a scene's picture shows: the start, the target, `path` and the
/// obstacles near them, within the arena (the start and target's box grown by
/// `arena_margin_m`, which the robot's centre cannot leave) plus the robot's reach.
pub fn scene_extent(
    scenario: &crate::scenario::Scenario,
    path: &[RobotState],
    arena_margin_m: f32,
) -> (Point2<f32>, Point2<f32>) {
    let ends = [scenario.start.position, scenario.target];
    let (arena_min, arena_max) = extent(ends, arena_margin_m + 0.6);
    let corners = scenario.obstacles.iter().flat_map(|o| {
        let b = o.ground_box();
        [
            Point2::new(b.min_x_m, b.min_y_m),
            Point2::new(b.max_x_m, b.max_y_m),
        ]
    });
    let (min, max) = extent(
        ends.into_iter()
            .chain(path.iter().map(|s| s.position))
            .chain(corners),
        0.1,
    );
    let (min, max) = (min.sup(&arena_min), max.inf(&arena_max));
    // At least 0.6 m around the start and the target, as a robot needs.
    let (near_min, near_max) = extent(ends, 0.6);
    (min.inf(&near_min), max.sup(&near_max))
}

/// An obstacle's footprint as a filled rectangle with a dark edge.
pub fn obstacle_rect(o: &Obstacle, fill: RGBColor) -> [Rectangle<(f32, f32)>; 2] {
    let b = o.ground_box();
    let corners = [(b.min_x_m, b.min_y_m), (b.max_x_m, b.max_y_m)];
    [
        Rectangle::new(corners, fill.filled()),
        Rectangle::new(corners, EDGE.stroke_width(1)),
    ]
}

/// A polyline in world metres.
pub type Polyline = Vec<(f32, f32)>;

/// The body's outline (closed) and the heading tick of the robot at `state`, in world metres.
pub fn body_outline(geometry: &RobotGeometry, state: &RobotState) -> (Polyline, [(f32, f32); 2]) {
    let (half_l, half_w) = (0.5 * geometry.body_length_m, 0.5 * geometry.body_width_m);
    let world = |x: f32, y: f32| {
        let p = state.robot_to_world(Vector2::new(x, y));
        (p.x, p.y)
    };
    let outline = [
        (half_l, half_w),
        (half_l, -half_w),
        (-half_l, -half_w),
        (-half_l, half_w),
        (half_l, half_w),
    ]
    .map(|(x, y)| world(x, y))
    .to_vec();
    let heading = [world(0.0, 0.0), world(half_l, 0.0)];
    (outline, heading)
}

/// The four wheels' contact points of the robot at `state`, in world metres.
pub fn wheel_points(geometry: &RobotGeometry, state: &RobotState) -> [(f32, f32); 4] {
    let track = state.leg_config(geometry).track_m;
    [(1.0, 1.0), (1.0, -1.0), (-1.0, 1.0), (-1.0, -1.0)].map(|(fore, side)| {
        let p = state.robot_to_world(Vector2::new(fore * geometry.hip_x_m, side * 0.5 * track));
        (p.x, p.y)
    })
}

/// Draws the robot's footprint at `state` (body outline, heading, wheels) in `colour`.
pub fn draw_robot(
    chart: &mut SceneChart<'_, '_>,
    geometry: &RobotGeometry,
    state: &RobotState,
    colour: RGBColor,
    width_px: u32,
) -> Result<(), RenderError> {
    let (outline, heading) = body_outline(geometry, state);
    chart
        .draw_series([
            PathElement::new(outline, colour.stroke_width(width_px)),
            PathElement::new(heading.to_vec(), colour.stroke_width(width_px)),
        ])
        .map_err(draw_error)?;
    chart
        .draw_series(
            wheel_points(geometry, state)
                .into_iter()
                .map(|p| Circle::new(p, 3 + width_px, colour.filled())),
        )
        .map_err(draw_error)?;
    Ok(())
}

/// How a legend entry is drawn.
#[derive(Clone, Copy, Debug)]
pub enum Mark {
    /// A filled square (an obstacle kind, a relevance level).
    Fill(RGBColor),
    /// A line (a path).
    Line(RGBColor),
    /// A thin outline (footprints).
    Outline(RGBColor),
    /// A filled disc (the target).
    Dot(RGBColor),
    /// A cross (collisions).
    Cross(RGBColor),
}

/// Width of the legend panel beside a chart, in pixels.
pub const LEGEND_PX: usize = 210;

/// Draws `entries` top down on `area` (a panel beside the chart).
pub fn draw_legend(
    area: &DrawingArea<BitMapBackend<'_>, Shift>,
    entries: &[(Mark, String)],
) -> Result<(), RenderError> {
    let row_px = 22;
    let top = (MARGIN_PX + CAPTION_PX) as i32 + 8;
    for (i, (mark, label)) in entries.iter().enumerate() {
        let y = top + i as i32 * row_px;
        let (x0, x1) = (8, 30);
        match *mark {
            Mark::Fill(c) => area.draw(&Rectangle::new([(x0, y - 6), (x1, y + 6)], c.filled())),
            Mark::Line(c) => {
                area.draw(&PathElement::new(vec![(x0, y), (x1, y)], c.stroke_width(3)))
            }
            Mark::Outline(c) => area.draw(&Rectangle::new(
                [(x0, y - 6), (x1, y + 6)],
                c.stroke_width(1),
            )),
            Mark::Dot(c) => area.draw(&Circle::new(((x0 + x1) / 2, y), 6, c.filled())),
            Mark::Cross(c) => area.draw(&Cross::new(((x0 + x1) / 2, y), 6, c.stroke_width(2))),
        }
        .map_err(draw_error)?;
        area.draw(&Text::new(
            label.as_str(),
            (x1 + 8, y - 7),
            (FONT, 13).into_font().color(&BLACK),
        ))
        .map_err(draw_error)?;
    }
    Ok(())
}
