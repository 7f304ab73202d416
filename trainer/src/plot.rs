//! Learning curves of several runs on one PNG: success rate, return, collision-free rate and
//! path length against environment steps (2 x 2 panels, one colour per curve).
//!
//! A curve is a [`RunGroup`]: one run, or several seeds of one method drawn as their mean with
//! a shaded band from the lowest to the highest seed at each step. Each run's iterations can be
//! smoothed by a trailing moving average first, because one iteration's rates come from a few
//! dozen episodes.
//!
//! Text is drawn with plotters' pure-Rust `ab_glyph` renderer in the simulator's vendored
//! DejaVu Sans (`wheelleg_sim::render::FONT`), or from the TTF file `font` when one is given.

use crate::error::TrainError;
use crate::runner::{read_metrics, IterationMetrics};
use plotters::prelude::*;
use std::path::{Path, PathBuf};

/// The family name a font given by the user is registered under.
const USER_FONT: &str = "wheelleg-plot-user";

/// The font family the text is drawn in: the TTF file `font`, registered now, or the vendored
/// one.
fn font_family(font: Option<&Path>) -> Result<&'static str, TrainError> {
    let Some(path) = font else {
        wheelleg_sim::render::register_font().map_err(|e| TrainError::Plot(e.to_string()))?;
        return Ok(wheelleg_sim::render::FONT);
    };
    let bytes = std::fs::read(path).map_err(|e| TrainError::io(path, "read font", e))?;
    // plotters keeps fonts for the process lifetime; one leaked copy per plot call is fine.
    let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
    plotters::style::register_font(USER_FONT, FontStyle::Normal, bytes).map_err(|_| {
        TrainError::Font {
            path: path.to_path_buf(),
        }
    })?;
    Ok(USER_FONT)
}

type Series = fn(&IterationMetrics) -> Option<f32>;

/// One curve: a label and the run folders (seeds) averaged into it.
#[derive(Clone, Debug, PartialEq)]
pub struct RunGroup {
    /// Legend text.
    pub label: String,
    /// Run folders, each with a metrics.jsonl.
    pub runs: Vec<PathBuf>,
}

impl RunGroup {
    /// Parses `DIR` (a group of one, labelled by the folder name) or `LABEL=DIR[,DIR...]`.
    pub fn parse(text: &str) -> Result<RunGroup, TrainError> {
        let (label, dirs) = match text.split_once('=') {
            Some((label, dirs)) => (label.to_string(), dirs),
            None => {
                let p = Path::new(text);
                let label = p
                    .file_name()
                    .map_or_else(|| text.to_string(), |n| n.to_string_lossy().into_owned());
                (label, text)
            }
        };
        let runs: Vec<PathBuf> = dirs
            .split(',')
            .filter(|d| !d.is_empty())
            .map(PathBuf::from)
            .collect();
        if label.is_empty() || runs.is_empty() {
            return Err(TrainError::Curve {
                text: text.to_string(),
            });
        }
        Ok(RunGroup { label, runs })
    }
}

/// A curve's points: env steps, then mean, lowest and highest over the group's runs.
type Band = Vec<(f32, f32, f32, f32)>;

/// Trailing moving average over `window` iterations of the values that exist.
fn smooth(points: &[(u64, f32)], window: usize) -> Vec<(u64, f32)> {
    let window = window.max(1);
    (0..points.len())
        .map(|i| {
            let from = (i + 1).saturating_sub(window);
            let slice = &points[from..=i];
            let mean = slice.iter().map(|p| p.1).sum::<f32>() / slice.len() as f32;
            (points[i].0, mean)
        })
        .collect()
}

/// Mean, low and high across runs at every env-step count some run reached.
fn band(runs: &[Vec<IterationMetrics>], series: Series, window: usize) -> Band {
    let mut by_step: std::collections::BTreeMap<u64, Vec<f32>> = Default::default();
    for metrics in runs {
        let points: Vec<(u64, f32)> = metrics
            .iter()
            .filter_map(|x| {
                series(x)
                    .filter(|v| v.is_finite())
                    .map(|v| (x.env_steps, v))
            })
            .collect();
        for (step, v) in smooth(&points, window) {
            by_step.entry(step).or_default().push(v);
        }
    }
    by_step
        .into_iter()
        .map(|(step, vs)| {
            let mean = vs.iter().sum::<f32>() / vs.len() as f32;
            let lo = vs.iter().copied().fold(f32::MAX, f32::min);
            let hi = vs.iter().copied().fold(f32::MIN, f32::max);
            (step as f32, mean, lo, hi)
        })
        .collect()
}

/// Draws the groups' curves into `out` (PNG, `width` x `height` pixels), each run smoothed over
/// `smooth_iterations` iterations (1: as logged).
pub fn plot_runs(
    groups: &[RunGroup],
    out: &Path,
    font: Option<&Path>,
    size: (u32, u32),
    smooth_iterations: usize,
) -> Result<(), TrainError> {
    if groups.is_empty() {
        return Err(TrainError::Nothing {
            what: "runs to plot",
        });
    }
    let data: Vec<(String, Vec<Vec<IterationMetrics>>)> = groups
        .iter()
        .map(|g| {
            let runs = g
                .runs
                .iter()
                // Iterations that finished no episode carry no rates; leave them out.
                .map(|r| {
                    read_metrics(r).map(|m| m.into_iter().filter(|x| x.episodes > 0).collect())
                })
                .collect::<Result<Vec<Vec<_>>, _>>()?;
            Ok((g.label.clone(), runs))
        })
        .collect::<Result<_, TrainError>>()?;
    let font = font_family(font)?;
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
        root.fill(&WHITE).map_err(plot_error)?;
        let areas = root.split_evenly((2, 2));
        let max_steps = data
            .iter()
            .flat_map(|(_, runs)| runs.iter().flatten().map(|x| x.env_steps))
            .max()
            .unwrap_or(1)
            .max(1) as f32;
        for (area, (title, series)) in areas.iter().zip(panels) {
            let bands: Vec<(&String, Band)> = data
                .iter()
                .map(|(name, runs)| (name, band(runs, series, smooth_iterations)))
                .collect();
            let (mut lo, mut hi) = bands
                .iter()
                .flat_map(|(_, b)| b.iter())
                .fold((f32::MAX, f32::MIN), |(a, b), p| (a.min(p.2), b.max(p.3)));
            if lo > hi {
                (lo, hi) = (0.0, 1.0);
            }
            if hi - lo < 1e-6 {
                hi = lo + 1.0;
            }
            let pad = 0.05 * (hi - lo);
            let mut chart = ChartBuilder::on(area)
                .margin(12)
                .caption(title, (font, 18))
                .x_label_area_size(30)
                .y_label_area_size(50)
                .build_cartesian_2d(0f32..max_steps, (lo - pad)..(hi + pad))
                .map_err(plot_error)?;
            chart
                .configure_mesh()
                .label_style((font, 12))
                .x_desc("env steps")
                .x_label_formatter(&|x| format!("{:.2}M", x / 1e6))
                .draw()
                .map_err(plot_error)?;
            for (k, (name, points)) in bands.iter().enumerate() {
                let colour = Palette99::pick(k).to_rgba();
                let spread = points.iter().any(|p| p.3 > p.2);
                if spread {
                    // The band: the highest seed forwards, the lowest backwards, one polygon.
                    let outline: Vec<(f32, f32)> = points
                        .iter()
                        .map(|p| (p.0, p.3))
                        .chain(points.iter().rev().map(|p| (p.0, p.2)))
                        .collect();
                    chart
                        .draw_series(std::iter::once(Polygon::new(
                            outline,
                            colour.mix(0.2).filled(),
                        )))
                        .map_err(plot_error)?;
                }
                let mean: Vec<(f32, f32)> = points.iter().map(|p| (p.0, p.1)).collect();
                let drawn = chart
                    .draw_series(LineSeries::new(mean, colour.stroke_width(2)))
                    .map_err(plot_error)?;
                drawn
                    .label(name.to_string())
                    .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 16, y)], colour));
            }
            chart
                .configure_series_labels()
                .label_font((font, 12))
                .background_style(WHITE.mix(0.8))
                .border_style(BLACK)
                .position(SeriesLabelPosition::LowerRight)
                .draw()
                .map_err(plot_error)?;
        }
        root.present()
            .map_err(|e| TrainError::Plot(format!("cannot write {}: {e}", tmp.display())))?;
    }
    std::fs::rename(&tmp, out).map_err(|e| TrainError::io(out, "move plot to", e))
}

/// A plotters error, whose type depends on the drawing backend, as its message.
fn plot_error(e: impl std::fmt::Display) -> TrainError {
    TrainError::Plot(e.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn groups_parse_from_a_folder_or_a_labelled_list() {
        let g = RunGroup::parse("runs/baseline-s0").unwrap();
        assert_eq!(g.label, "baseline-s0");
        assert_eq!(g.runs, vec![PathBuf::from("runs/baseline-s0")]);
        let g = RunGroup::parse("primary=runs/a,runs/b").unwrap();
        assert_eq!(g.label, "primary");
        assert_eq!(g.runs.len(), 2);
        assert!(RunGroup::parse("primary=")
            .unwrap_err()
            .to_string()
            .contains("LABEL=DIR"));
        assert!(matches!(
            RunGroup::parse("=runs/a"),
            Err(TrainError::Curve { text }) if text == "=runs/a"
        ));
    }

    #[test]
    fn the_band_spans_the_seeds_and_smoothing_averages_trailing_iterations() {
        let run = |rates: &[f32]| -> Vec<IterationMetrics> {
            rates
                .iter()
                .enumerate()
                .map(|(i, &r)| IterationMetrics {
                    env_steps: 100 * (i as u64 + 1),
                    success_rate: r,
                    ..IterationMetrics::default()
                })
                .collect()
        };
        let runs = vec![run(&[0.0, 0.5, 1.0]), run(&[0.2, 0.7, 0.6])];
        let b = band(&runs, |m| Some(m.success_rate), 1);
        assert_eq!(b.len(), 3);
        assert!((b[1].1 - 0.6).abs() < 1e-6 && b[1].2 == 0.5 && b[1].3 == 0.7);
        let b = band(&runs[..1], |m| Some(m.success_rate), 2);
        assert!((b[2].1 - 0.75).abs() < 1e-6, "mean of 0.5 and 1.0");
    }
}
