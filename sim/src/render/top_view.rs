//! A scene from above with the way the robot took: what `wheelleg render` and `wheelleg demo`
//! save.

use super::*;
use crate::scenario::Scenario;

/// Colours of the robot's way.
const WAY: RGBColor = RGBColor(240, 140, 20);
const COLLISION: RGBColor = RGBColor(220, 0, 0);

/// At most this many footprints are drawn along the way (every k-th state beyond it).
const MAX_FOOTPRINTS: usize = 40;

/// Top view of a scenario in world metres: obstacles by kind, the target, the robot's
/// footprint at the start and, if given, the body centre's path with the footprint along it
/// and at its end; `collided` marks the states from which a step was undone for a collision.
/// A legend beside the chart names each mark. The chart shows the default episode rules'
/// arena.
pub fn top_view(
    scenario: &Scenario,
    geometry: &RobotGeometry,
    path: &[RobotState],
    collided: &[RobotState],
) -> Result<Canvas, RenderError> {
    let arena_margin_m = crate::env::EnvConfig::default().arena_margin_m;
    let (min, max) = scene_extent(scenario, path, arena_margin_m);
    let (chart_w, chart_h) = chart_size(min, max);
    let mut canvas = Canvas::new(chart_w + LEGEND_PX, chart_h);
    {
        let root = canvas.area()?;
        root.fill(&RGBColor(250, 250, 247)).map_err(draw_error)?;
        let (left, right) = root.split_horizontally(chart_w as u32);
        let mut chart = scene_chart(&left, min, max, &scenario.name)?;
        let mut legend = Vec::new();
        let mut obstacles = scenario.obstacles.clone();
        // Tall obstacles drawn last, so they stay visible where boxes overlap.
        obstacles.sort_by(|a, b| a.kind.size_m().2.total_cmp(&b.kind.size_m().2));
        for o in &obstacles {
            chart
                .draw_series(obstacle_rect(o, kind_colour(o.kind)))
                .map_err(draw_error)?;
        }
        for kind in ObstacleKind::ALL {
            if scenario.obstacles.iter().any(|o| o.kind == kind) {
                legend.push((Mark::Fill(kind_colour(kind)), kind_label(kind)));
            }
        }
        if path.len() > 1 {
            let every = path.len().div_ceil(MAX_FOOTPRINTS).max(1);
            for state in path.iter().step_by(every) {
                let (outline, _) = body_outline(geometry, state);
                chart
                    .draw_series([PathElement::new(outline, WAY.mix(0.35).stroke_width(1))])
                    .map_err(draw_error)?;
            }
            chart
                .draw_series(LineSeries::new(
                    path.iter().map(|s| (s.position.x, s.position.y)),
                    WAY.stroke_width(2),
                ))
                .map_err(draw_error)?;
            legend.push((Mark::Outline(WAY), "footprint along the way".into()));
            legend.push((
                Mark::Line(WAY),
                format!("body centre, {} moves", path.len() - 1),
            ));
        }
        draw_robot(&mut chart, geometry, &scenario.start, START, 2)?;
        legend.push((Mark::Outline(START), "start".into()));
        if let Some(last) = path.last().filter(|_| path.len() > 1) {
            draw_robot(&mut chart, geometry, last, WAY, 2)?;
            legend.push((Mark::Outline(WAY), "end".into()));
        }
        draw_target(&mut chart, scenario.target)?;
        legend.push((Mark::Dot(TARGET), "target".into()));
        if !collided.is_empty() {
            chart
                .draw_series(collided.iter().map(|s| {
                    Cross::new((s.position.x, s.position.y), 7, COLLISION.stroke_width(3))
                }))
                .map_err(draw_error)?;
            legend.push((
                Mark::Cross(COLLISION),
                format!("collision, step undone ({})", collided.len()),
            ));
        }
        draw_legend(&right, &legend)?;
        root.present().map_err(draw_error)?;
    }
    Ok(canvas)
}
