//! The paper's relevance figure, drawn with the simulator's picture pieces
//! (`wheelleg_sim::render`).

use super::RelevanceReport;
use plotters::prelude::*;
use wheelleg_runtime::robot::RobotGeometry;
use wheelleg_sim::env::EnvConfig;
use wheelleg_sim::render::{
    chart_size, draw_error, draw_legend, draw_robot, draw_target, obstacle_rect, scene_chart,
    scene_extent, Canvas, Mark, RenderError, EDGE, FONT, LEGEND_PX, START, TARGET,
};
use wheelleg_sim::scenario::Scenario;

/// Trajectories with every obstacle and without one.
const WITH_ALL: RGBColor = RGBColor(110, 110, 110);
const WITHOUT: RGBColor = RGBColor(220, 40, 30);
/// Obstacles of the right panel, where only the trajectories carry the figure's message.
const FADED: RGBColor = RGBColor(228, 228, 228);
/// A removal that moves the trajectory less than this leaves it where it was.
const MOVED_M: f32 = 0.01;

/// White (no relevance) to red (the most relevant obstacle).
fn relevance_colour(level: f32) -> RGBColor {
    let fade = (255.0 * (1.0 - level.clamp(0.0, 1.0))) as u8;
    RGBColor(255, fade, fade)
}

/// The paper's relevance figure, two charts in world metres and a legend: on the left the
/// scene with each obstacle coloured white (its removal leaves the trajectory where it was) to
/// red (the largest change), labelled by its index, the target and the robot's start; on the
/// right the trajectories: grey with every obstacle, red without the obstacle whose index is at
/// its end (those that moved by more than 1 cm).
pub fn render(
    scenario: &Scenario,
    report: &RelevanceReport,
    geometry: &RobotGeometry,
    config: &EnvConfig,
) -> Result<Canvas, RenderError> {
    let (min, max) = scene_extent(scenario, &report.baseline.path, config.arena_margin_m);
    let (w, h) = chart_size(min, max);
    let mut canvas = Canvas::new(2 * w + LEGEND_PX, h);
    let most_m = report
        .obstacles
        .iter()
        .map(|o| o.relevance_m)
        .fold(0.0f32, f32::max);
    let moved: Vec<_> = report
        .obstacles
        .iter()
        .filter(|o| o.relevance_m > MOVED_M)
        .collect();
    {
        let root = canvas.area()?;
        root.fill(&WHITE).map_err(draw_error)?;
        let (charts, legend_area) = root.split_horizontally(2 * w as u32);
        let (left, right) = charts.split_horizontally(w as u32);
        let label = |text: String, at: (f32, f32), colour: RGBColor| {
            Text::new(text, at, (FONT, 15).into_font().color(&colour))
        };

        let mut chart = scene_chart(&left, min, max, "relevance of each obstacle")?;
        for (i, o) in scenario.obstacles.iter().enumerate() {
            let level = report
                .obstacles
                .get(i)
                .filter(|_| most_m > 0.0)
                .map_or(0.0, |r| r.relevance_m / most_m);
            chart
                .draw_series(obstacle_rect(o, relevance_colour(level)))
                .map_err(draw_error)?;
        }
        chart
            .draw_series(
                scenario
                    .obstacles
                    .iter()
                    .enumerate()
                    .map(|(i, o)| label(i.to_string(), (o.centre.x, o.centre.y), BLACK)),
            )
            .map_err(draw_error)?;
        draw_robot(&mut chart, geometry, &scenario.start, START, 2)?;
        draw_target(&mut chart, scenario.target)?;

        let mut chart = scene_chart(&right, min, max, "trajectories with and without each")?;
        for o in &scenario.obstacles {
            chart
                .draw_series(obstacle_rect(o, FADED))
                .map_err(draw_error)?;
        }
        for o in &moved {
            chart
                .draw_series(LineSeries::new(
                    o.run.path.iter().map(|s| (s.position.x, s.position.y)),
                    WITHOUT.stroke_width(2),
                ))
                .map_err(draw_error)?;
        }
        chart
            .draw_series(LineSeries::new(
                report
                    .baseline
                    .path
                    .iter()
                    .map(|s| (s.position.x, s.position.y)),
                WITH_ALL.stroke_width(4),
            ))
            .map_err(draw_error)?;
        // Paths that end in the same place (stuck at the same obstacle) get their labels side
        // by side instead of on top of each other.
        let mut placed: Vec<(f32, f32)> = Vec::new();
        for o in &moved {
            if let Some(end) = o.run.path.last() {
                let mut at = (end.position.x + 0.04, end.position.y + 0.08);
                while placed
                    .iter()
                    .any(|p| (p.0 - at.0).abs() < 0.08 && (p.1 - at.1).abs() < 0.08)
                {
                    at.0 += 0.08;
                }
                placed.push(at);
                chart
                    .draw_series([label(o.index.to_string(), at, WITHOUT)])
                    .map_err(draw_error)?;
            }
        }
        draw_target(&mut chart, scenario.target)?;

        let mut legend = vec![
            (
                Mark::Fill(relevance_colour(1.0)),
                format!("most relevant: moved {most_m:.3} m"),
            ),
            (Mark::Fill(relevance_colour(0.5)), "half as relevant".into()),
            (Mark::Outline(EDGE), "not relevant".into()),
            (Mark::Line(WITH_ALL), "with every obstacle".into()),
        ];
        legend.extend(moved.iter().map(|o| {
            (
                Mark::Line(WITHOUT),
                format!("without {} (moved {:.3} m)", o.index, o.relevance_m),
            )
        }));
        legend.push((Mark::Outline(START), "start".into()));
        legend.push((Mark::Dot(TARGET), "target".into()));
        draw_legend(&legend_area, &legend)?;
        root.present().map_err(draw_error)?;
    }
    Ok(canvas)
}
