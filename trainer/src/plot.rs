//! Learning curves of several runs on one PNG: success rate, return, collision-free rate and
//! path length against environment steps (2 x 2 panels, one colour per run).
//!
//! Text is drawn with plotters' pure-Rust `ab_glyph` renderer from a TTF file: `font` if given,
//! else the first of a few common system fonts. Without any font the curves are still drawn,
//! only the labels are left out (plotters has no built-in font).

use crate::runner::{read_metrics, IterationMetrics};
use plotters::prelude::*;
use std::path::{Path, PathBuf};

const FONT_CANDIDATES: &[&str] = &[
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/TTF/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu/DejaVuSans.ttf",
    "/Library/Fonts/Arial.ttf",
    "C:\\Windows\\Fonts\\arial.ttf",
];

const FONT_NAME: &str = "wheelleg-plot";

fn register_font(font: Option<&Path>) -> Result<bool, String> {
    let path = match font {
        Some(p) => Some(p.to_path_buf()),
        None => FONT_CANDIDATES
            .iter()
            .map(PathBuf::from)
            .find(|p| p.exists()),
    };
    let Some(path) = path else {
        return Ok(false);
    };
    let bytes =
        std::fs::read(&path).map_err(|e| format!("cannot read font {}: {e}", path.display()))?;
    // plotters keeps fonts for the process lifetime; one leaked copy per plot call is fine.
    let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
    plotters::style::register_font(FONT_NAME, FontStyle::Normal, bytes)
        .map_err(|_| format!("{} is not a usable TTF font", path.display()))?;
    Ok(true)
}

type Series = fn(&IterationMetrics) -> Option<f32>;

/// Draws the runs' curves into `out` (PNG, `width` x `height` pixels).
pub fn plot_runs(
    runs: &[PathBuf],
    out: &Path,
    font: Option<&Path>,
    size: (u32, u32),
) -> Result<(), String> {
    if runs.is_empty() {
        return Err("no runs to plot".into());
    }
    let data: Vec<(String, Vec<IterationMetrics>)> = runs
        .iter()
        .map(|r| {
            let name = r.file_name().map_or_else(
                || r.display().to_string(),
                |n| n.to_string_lossy().into_owned(),
            );
            // Iterations that finished no episode carry no rates; leave them out of the curves.
            read_metrics(r).map(|m| (name, m.into_iter().filter(|x| x.episodes > 0).collect()))
        })
        .collect::<Result<_, _>>()?;
    let text = register_font(font)?;
    let panels: [(&str, Series); 4] = [
        ("success rate", |m| Some(m.success_rate)),
        ("mean return", |m| Some(m.mean_return)),
        ("collision-free success rate", |m| {
            Some(m.collision_free_rate)
        }),
        ("path length (steps, successes)", |m| m.mean_success_steps),
    ];
    let tmp = out.with_extension("tmp.png");
    {
        let root = BitMapBackend::new(&tmp, size).into_drawing_area();
        root.fill(&WHITE).map_err(|e| e.to_string())?;
        let areas = root.split_evenly((2, 2));
        let max_steps = data
            .iter()
            .flat_map(|(_, m)| m.iter().map(|x| x.env_steps))
            .max()
            .unwrap_or(1)
            .max(1) as f32;
        for (area, (title, series)) in areas.iter().zip(panels) {
            let values: Vec<f32> = data
                .iter()
                .flat_map(|(_, m)| m.iter().filter_map(series))
                .filter(|v| v.is_finite())
                .collect();
            let (mut lo, mut hi) = values
                .iter()
                .fold((f32::MAX, f32::MIN), |(a, b), &v| (a.min(v), b.max(v)));
            if values.is_empty() {
                (lo, hi) = (0.0, 1.0);
            }
            if hi - lo < 1e-6 {
                hi = lo + 1.0;
            }
            let pad = 0.05 * (hi - lo);
            let mut builder = ChartBuilder::on(area);
            builder.margin(12);
            if text {
                builder
                    .caption(title, (FONT_NAME, 18))
                    .x_label_area_size(30)
                    .y_label_area_size(50);
            }
            let mut chart = builder
                .build_cartesian_2d(0f32..max_steps, (lo - pad)..(hi + pad))
                .map_err(|e| e.to_string())?;
            let mut mesh = chart.configure_mesh();
            if text {
                mesh.label_style((FONT_NAME, 12)).x_desc("env steps");
            } else {
                mesh.disable_x_mesh()
                    .disable_y_mesh()
                    .x_labels(0)
                    .y_labels(0);
            }
            mesh.draw().map_err(|e| e.to_string())?;
            for (k, (name, m)) in data.iter().enumerate() {
                let colour = Palette99::pick(k).to_rgba();
                let points: Vec<(f32, f32)> = m
                    .iter()
                    .filter_map(|x| {
                        series(x)
                            .filter(|v| v.is_finite())
                            .map(|v| (x.env_steps as f32, v))
                    })
                    .collect();
                let drawn = chart
                    .draw_series(LineSeries::new(points, colour.stroke_width(2)))
                    .map_err(|e| e.to_string())?;
                if text {
                    drawn
                        .label(name.clone())
                        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], colour));
                }
            }
            if text {
                chart
                    .configure_series_labels()
                    .label_font((FONT_NAME, 12))
                    .background_style(WHITE.mix(0.8))
                    .border_style(BLACK)
                    .position(SeriesLabelPosition::LowerRight)
                    .draw()
                    .map_err(|e| e.to_string())?;
            }
        }
        root.present()
            .map_err(|e| format!("cannot write {}: {e}", tmp.display()))?;
    }
    std::fs::rename(&tmp, out).map_err(|e| format!("cannot move plot to {}: {e}", out.display()))
}
