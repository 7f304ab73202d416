//! A robot's front and side views in metres, at several poses at once: the picture a person
//! holds against their robot (`wheelleg robot check --picture`).

use super::{draw_error, Canvas, RenderError, FONT};
use plotters::prelude::*;
use wheelleg_runtime::leg::LegConfig;
use wheelleg_runtime::robot::{LegId, RobotGeometry};

/// Pixels per metre of the views.
const PX_PER_M: f32 = 1000.0;
/// Room around each view's plot: margin, labels, caption, in pixels.
const MARGIN_PX: u32 = 12;
const LABELS_PX: u32 = 48;
const CAPTION_PX: u32 = 30;

/// The colour of the `i`th pose.
fn pose_colour(i: usize) -> RGBColor {
    const COLOURS: [RGBColor; 6] = [
        RGBColor(40, 40, 40),
        RGBColor(200, 60, 40),
        RGBColor(40, 110, 200),
        RGBColor(30, 150, 70),
        RGBColor(170, 90, 190),
        RGBColor(220, 150, 30),
    ];
    COLOURS[i % COLOURS.len()]
}

/// One pose's points in a view: (horizontal, up from the ground) in metres.
struct Drawn {
    body: [(f32, f32); 2],
    links: Vec<[(f32, f32); 2]>,
    /// Wheels seen along their axle (side view, circles) or across it (front view, boxes), as
    /// their bounding boxes.
    wheels: Vec<[(f32, f32); 2]>,
    wheels_round: bool,
}

/// The outline of the ellipse inscribed in `bounds`, as a closed path.
fn outline(bounds: [(f32, f32); 2], round: bool) -> Vec<(f32, f32)> {
    let [(x0, y0), (x1, y1)] = bounds;
    if !round {
        return vec![(x0, y0), (x1, y0), (x1, y1), (x0, y1), (x0, y0)];
    }
    let (cx, cy, rx, ry) = (
        0.5 * (x0 + x1),
        0.5 * (y0 + y1),
        0.5 * (x1 - x0),
        0.5 * (y1 - y0),
    );
    (0..=48)
        .map(|i| {
            let a = i as f32 * core::f32::consts::TAU / 48.0;
            (cx + rx * a.cos(), cy + ry * a.sin())
        })
        .collect()
}

/// The front view (body y across, z up) and the side view (body x along, z up) of `geometry`
/// at each labelled pose; poses without a leg solution are left out (and named in the
/// caption). One colour per pose, a legend in each view.
pub fn robot_views(
    name: &str,
    geometry: &RobotGeometry,
    poses: &[(String, LegConfig)],
) -> Result<Canvas, RenderError> {
    let g = geometry;
    let mut front = Vec::new();
    let mut side = Vec::new();
    let mut labels = Vec::new();
    let mut skipped = Vec::new();
    for (label, legs) in poses {
        let Ok(joints) = g.leg_ik(*legs) else {
            skipped.push(label.clone());
            continue;
        };
        let lift = g.body_centre_height_m(legs.clearance_m);
        let up = |z: f32| z + lift;
        let (mut f_links, mut f_wheels, mut s_links, mut s_wheels) =
            (vec![], vec![], vec![], vec![]);
        for leg in [LegId::FrontLeft, LegId::FrontRight] {
            let p = g.leg_points(leg, joints);
            f_links.push([(p.hip.y, up(p.hip.z)), (p.knee.y, up(p.knee.z))]);
            f_links.push([
                (p.knee.y, up(p.knee.z)),
                (p.wheel_mount.y, up(p.wheel_mount.z)),
            ]);
            if p.wheel_mount != p.wheel {
                // The axle out to the wheel's centre.
                f_links.push([
                    (p.wheel_mount.y, up(p.wheel_mount.z)),
                    (p.wheel.y, up(p.wheel.z)),
                ]);
            }
            let half = 0.5 * g.wheel_width_m;
            f_wheels.push([
                (p.wheel.y - half, up(p.wheel.z) - g.wheel_radius_m),
                (p.wheel.y + half, up(p.wheel.z) + g.wheel_radius_m),
            ]);
        }
        for leg in [LegId::FrontLeft, LegId::RearLeft] {
            let p = g.leg_points(leg, joints);
            s_links.push([(p.hip.x, up(p.hip.z)), (p.wheel.x, up(p.wheel.z))]);
            s_wheels.push([
                (
                    p.wheel.x - g.wheel_radius_m,
                    up(p.wheel.z) - g.wheel_radius_m,
                ),
                (
                    p.wheel.x + g.wheel_radius_m,
                    up(p.wheel.z) + g.wheel_radius_m,
                ),
            ]);
        }
        let (bottom, top) = (legs.clearance_m, legs.clearance_m + g.body_thickness_m);
        front.push(Drawn {
            body: [(-0.5 * g.body_width_m, bottom), (0.5 * g.body_width_m, top)],
            links: f_links,
            wheels: f_wheels,
            wheels_round: false,
        });
        side.push(Drawn {
            body: [
                (-0.5 * g.body_length_m, bottom),
                (0.5 * g.body_length_m, top),
            ],
            links: s_links,
            wheels: s_wheels,
            wheels_round: true,
        });
        labels.push(label.clone());
    }
    let extent = |views: &[Drawn]| {
        let mut hi = (0.1f32, 0.1f32);
        for v in views {
            for [a, b] in v.links.iter().chain(&v.wheels).chain([&v.body]) {
                hi.0 = hi.0.max(a.0.abs()).max(b.0.abs());
                hi.1 = hi.1.max(a.1).max(b.1);
            }
        }
        (hi.0 + 0.03, hi.1 + 0.03)
    };
    let (front_w, front_h) = extent(&front);
    let (side_w, side_h) = extent(&side);
    let height_m = front_h.max(side_h);
    let px = |m: f32| (m * PX_PER_M).ceil() as u32;
    let view_px = |half_w: f32| (px(2.0 * half_w) + LABELS_PX + 2 * MARGIN_PX, px(height_m));
    let (fw, _) = view_px(front_w);
    let (sw, _) = view_px(side_w);
    let plot_h = px(height_m) + LABELS_PX + CAPTION_PX + 2 * MARGIN_PX;
    let mut canvas = Canvas::new((fw + sw) as usize, plot_h as usize);
    {
        let root = canvas.area()?;
        root.fill(&WHITE).map_err(draw_error)?;
        let (left, right) = root.split_horizontally(fw);
        let note = if skipped.is_empty() {
            String::new()
        } else {
            format!(" (no leg solution: {})", skipped.join(", "))
        };
        for (area, views, half_w, title, across) in [
            (&left, &front, front_w, "front view", "y (m), left +"),
            (&right, &side, side_w, "side view", "x (m), ahead +"),
        ] {
            let mut chart = ChartBuilder::on(area)
                .caption(format!("{name}: {title}{note}"), (FONT, 16))
                .margin(MARGIN_PX)
                .x_label_area_size(LABELS_PX)
                .y_label_area_size(LABELS_PX)
                .build_cartesian_2d(-half_w..half_w, 0.0f32..height_m)
                .map_err(draw_error)?;
            chart
                .configure_mesh()
                .bold_line_style(RGBColor(225, 225, 220))
                .light_line_style(RGBColor(240, 240, 236))
                .x_desc(across)
                .y_desc("z (m), up from the ground")
                .label_style((FONT, 12))
                .axis_desc_style((FONT, 13))
                .x_label_formatter(&|x| format!("{x:.2}"))
                .y_label_formatter(&|y| format!("{y:.2}"))
                .draw()
                .map_err(draw_error)?;
            for (i, (view, label)) in views.iter().zip(&labels).enumerate() {
                let colour = pose_colour(i);
                let thickness = (2.0 * g.link_radius_m * PX_PER_M).max(1.0) as u32;
                chart
                    .draw_series(std::iter::once(Rectangle::new(
                        view.body,
                        colour.stroke_width(2),
                    )))
                    .map_err(draw_error)?
                    .label(label.clone())
                    .legend(move |(x, y)| {
                        Rectangle::new([(x, y - 4), (x + 14, y + 4)], colour.filled())
                    });
                chart
                    .draw_series(
                        view.links
                            .iter()
                            .map(|l| PathElement::new(l.to_vec(), colour.stroke_width(thickness))),
                    )
                    .map_err(draw_error)?;
                chart
                    .draw_series(view.wheels.iter().map(|w| {
                        PathElement::new(outline(*w, view.wheels_round), colour.stroke_width(2))
                    }))
                    .map_err(draw_error)?;
            }
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.85))
                .border_style(RGBColor(120, 120, 120))
                .label_font((FONT, 12))
                .position(SeriesLabelPosition::UpperRight)
                .draw()
                .map_err(draw_error)?;
        }
    }
    Ok(canvas)
}

#[cfg(test)]
mod tests {
    use super::*;
    use wheelleg_runtime::robot::WHEELLEG;

    #[test]
    fn every_pose_is_drawn_in_its_colour_and_an_unreachable_one_is_named() {
        let poses = vec![
            (
                "default".to_string(),
                LegConfig {
                    clearance_m: 0.12,
                    track_m: 0.36,
                },
            ),
            (
                "spread".to_string(),
                LegConfig {
                    clearance_m: 0.06,
                    track_m: 0.56,
                },
            ),
            (
                "impossible".to_string(),
                LegConfig {
                    clearance_m: 0.24,
                    track_m: 0.56,
                },
            ),
        ];
        let canvas = robot_views("wheelleg", &WHEELLEG, &poses).unwrap();
        let has = |colour: RGBColor| {
            (0..canvas.height()).any(|y| {
                (0..canvas.width())
                    .any(|x| canvas.pixel(x, y) == Some([colour.0, colour.1, colour.2]))
            })
        };
        assert!(has(pose_colour(0)) && has(pose_colour(1)));
        assert!(
            !has(pose_colour(2)),
            "the unreachable pose has no colour of its own"
        );
        // At 1 mm a pixel, the front view spans the widest track and the side view the body.
        assert!(canvas.width() > 560 + 500);
    }
}
