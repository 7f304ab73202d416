//! The height map the robot sees, in its own frame, with a colour bar: what `wheelleg render`
//! saves beside each top view.

use super::*;
use crate::height_map::{HeightMap, MapGrid};
use wheelleg_runtime::observation::HEIGHT_MAP_SIDE;

/// Tallest height of the colour scale (the block's height).
const FULL_SCALE_HEIGHT_M: f32 = 0.40;
/// Pixels per map cell.
const CELL_PX: u32 = 12;
/// Width of the colour bar's panel.
const BAR_PX: u32 = 110;

/// The colour of a height: light grey for the ground, viridis from just above it to
/// [`FULL_SCALE_HEIGHT_M`] and above.
fn height_colour(height_m: f32) -> RGBColor {
    if height_m <= 0.0 {
        RGBColor(236, 236, 232)
    } else {
        ViridisRGB::get_color((height_m / FULL_SCALE_HEIGHT_M).clamp(0.0, 1.0))
    }
}

/// The height map as the robot sees it: ahead up, the robot's right to the right, metres from
/// its centre on both axes, each cell coloured by its height (colour bar beside it), the
/// robot's centre and heading marked.
pub fn height_map_image(map: &HeightMap) -> Result<Canvas, RenderError> {
    let grid = MapGrid::POLICY;
    let half_m = 0.5 * HEIGHT_MAP_SIDE as f32 * grid.cell_m;
    let plot_px = HEIGHT_MAP_SIDE as u32 * CELL_PX;
    let (w, h) = (
        plot_px + Y_LABELS_PX + 2 * MARGIN_PX,
        plot_px + X_LABELS_PX + CAPTION_PX + 2 * MARGIN_PX,
    );
    let mut canvas = Canvas::new((w + BAR_PX) as usize, h as usize);
    {
        let root = canvas.area()?;
        root.fill(&WHITE).map_err(draw_error)?;
        let (left, right) = root.split_horizontally(w);
        let mut chart = ChartBuilder::on(&left)
            .caption("height map (robot frame)", (FONT, 18))
            .margin(MARGIN_PX)
            .x_label_area_size(X_LABELS_PX)
            .y_label_area_size(Y_LABELS_PX)
            .build_cartesian_2d(-half_m..half_m, -half_m..half_m)
            .map_err(draw_error)?;
        chart
            .configure_mesh()
            .disable_mesh()
            .x_desc("right of the robot (m)")
            .y_desc("ahead (m)")
            .label_style((FONT, 13))
            .axis_desc_style((FONT, 14))
            .x_label_formatter(&|x| format!("{x:.1}"))
            .y_label_formatter(&|y| format!("{y:.1}"))
            .draw()
            .map_err(draw_error)?;
        let half = grid.half_cells();
        let cell_m = grid.cell_m;
        chart
            .draw_series((0..HEIGHT_MAP_SIDE * HEIGHT_MAP_SIDE).map(|i| {
                let (row, col) = (i / HEIGHT_MAP_SIDE, i % HEIGHT_MAP_SIDE);
                let ahead_m = (half - row as f32) * cell_m;
                let right_m = (col as f32 - half) * cell_m;
                Rectangle::new(
                    [
                        (right_m - 0.5 * cell_m, ahead_m - 0.5 * cell_m),
                        (right_m + 0.5 * cell_m, ahead_m + 0.5 * cell_m),
                    ],
                    height_colour(map[i]).filled(),
                )
            }))
            .map_err(draw_error)?;
        let robot = RGBColor(220, 30, 30);
        chart
            .draw_series([
                PathElement::new(vec![(0.0, 0.0), (0.0, 0.15)], robot.stroke_width(2)),
                PathElement::new(
                    vec![(-0.03, 0.11), (0.0, 0.15), (0.03, 0.11)],
                    robot.stroke_width(2),
                ),
            ])
            .map_err(draw_error)?;
        chart
            .draw_series([Circle::new((0.0, 0.0), 4, robot.filled())])
            .map_err(draw_error)?;
        let mut bar = ChartBuilder::on(&right)
            .margin_top(MARGIN_PX + CAPTION_PX)
            .margin_bottom(MARGIN_PX + X_LABELS_PX)
            .margin_right(8)
            .y_label_area_size(56)
            .build_cartesian_2d(0.0f32..1.0, 0.0f32..FULL_SCALE_HEIGHT_M)
            .map_err(draw_error)?;
        bar.configure_mesh()
            .disable_mesh()
            .disable_x_axis()
            .y_desc("height (m)")
            .label_style((FONT, 13))
            .axis_desc_style((FONT, 14))
            .y_label_formatter(&|y| format!("{y:.2}"))
            .draw()
            .map_err(draw_error)?;
        let steps = 80;
        bar.draw_series((0..steps).map(|k| {
            let (lo, hi) = (
                FULL_SCALE_HEIGHT_M * k as f32 / steps as f32,
                FULL_SCALE_HEIGHT_M * (k + 1) as f32 / steps as f32,
            );
            let colour = if k == 0 {
                height_colour(0.0)
            } else {
                height_colour(lo)
            };
            Rectangle::new([(0.0, lo), (1.0, hi)], colour.filled())
        }))
        .map_err(draw_error)?;
        root.present().map_err(draw_error)?;
    }
    Ok(canvas)
}
