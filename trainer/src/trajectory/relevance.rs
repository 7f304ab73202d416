//! The paper's relevance test ("Attend task-relevant components of the observation"): roll the
//! greedy policy in a scene, then again with each obstacle removed in turn; an obstacle whose
//! removal moves the trajectory far is one the policy attends to.
//!
//! The distance between two trajectories is the symmetric mean closest-point distance between
//! their paths of body centres (polylines): the mean, over the points of each path, of the
//! distance to the other path, averaged over both directions. It is 0 for the same path, does
//! not depend on how many steps either took to trace the same curve, and grows with how far
//! apart the paths run.

use crate::network_f32::NetworkF32;
use nalgebra::{Point2, Vector2};
use wheelleg_runtime::action::{Action, CHOICES, DIMS};
use wheelleg_runtime::decision::{Decider, ObservationKey};
use wheelleg_runtime::robot::RobotGeometry;
use wheelleg_sim::env::{Env, EnvConfig, Observation, Status};
use wheelleg_sim::obstacle::GRID_CELL_M;
use wheelleg_sim::render::{Canvas, TOP_VIEW_PX_PER_M};
use wheelleg_sim::scenario::{Scenario, ScenarioError};
use wheelleg_sim::state::RobotState;

/// One episode of a policy.
#[derive(Clone, Debug, PartialEq)]
pub struct PolicyRun {
    /// States from the start to the end, one per step.
    pub path: Vec<RobotState>,
    /// How it ended.
    pub status: Status,
    /// Collisions (undone actions).
    pub collisions: u32,
}

impl PolicyRun {
    /// The body centres along the path.
    pub fn centres(&self) -> Vec<Point2<f32>> {
        self.path.iter().map(|s| s.position).collect()
    }
}

/// The relevance of one obstacle.
#[derive(Clone, Debug, PartialEq)]
pub struct ObstacleRelevance {
    /// Index of the removed obstacle in the scenario.
    pub index: usize,
    /// Distance between the trajectory without it and the one with all obstacles, m.
    pub relevance_m: f32,
    /// The episode without it.
    pub run: PolicyRun,
}

/// The relevance of every obstacle of a scene.
#[derive(Clone, Debug, PartialEq)]
pub struct RelevanceReport {
    /// The episode with every obstacle.
    pub baseline: PolicyRun,
    /// Per obstacle, in scenario order.
    pub obstacles: Vec<ObstacleRelevance>,
}

/// A float policy acting by the robot's rule (`wheelleg_runtime::decision::Decider`): the most
/// probable joint action not yet taken at the current observation.
pub struct DecidingPolicy<'a> {
    network: &'a NetworkF32,
    decider: Decider,
}

impl<'a> DecidingPolicy<'a> {
    /// `network` with nothing taken yet.
    pub fn new(network: &'a NetworkF32) -> DecidingPolicy<'a> {
        DecidingPolicy {
            network,
            decider: Decider::new(),
        }
    }

    /// The action for `observation`.
    pub fn act(&mut self, observation: &Observation) -> Action {
        let (logits, _) = self
            .network
            .forward(&observation.height_map, &observation.state);
        let mut head_logits = [0.0f32; DIMS * CHOICES];
        for (out, &l) in head_logits.iter_mut().zip(&logits) {
            *out = l;
        }
        let key = ObservationKey::of_metres(&observation.height_map, &observation.state);
        self.decider.choose(key, &head_logits)
    }
}

/// Runs `policy` in `scenario` until the episode ends.
pub fn roll(
    scenario: &Scenario,
    config: EnvConfig,
    policy: &mut dyn FnMut(&Observation) -> Action,
) -> Result<PolicyRun, ScenarioError> {
    let mut env = Env::new(scenario, config)?;
    let mut observation = Observation::default();
    let mut path = vec![*env.state()];
    while !env.status().is_done() {
        env.observe(&mut observation);
        let action = policy(&observation);
        if env.step(action).is_err() {
            break;
        }
        path.push(*env.state());
    }
    Ok(PolicyRun {
        path,
        status: env.status(),
        collisions: env.collisions(),
    })
}

/// Distance from `p` to the segment `a`-`b`.
fn point_segment_m(p: Point2<f32>, a: Point2<f32>, b: Point2<f32>) -> f32 {
    let ab: Vector2<f32> = b - a;
    let len2 = ab.norm_squared();
    let t = if len2 > 0.0 {
        ((p - a).dot(&ab) / len2).clamp(0.0, 1.0)
    } else {
        0.0
    };
    (p - (a + t * ab)).norm()
}

/// Mean over the points of `a` of the distance to the polyline `b`.
fn directed_mean_m(a: &[Point2<f32>], b: &[Point2<f32>]) -> f32 {
    if a.is_empty() || b.is_empty() {
        return 0.0;
    }
    let nearest = |p: Point2<f32>| {
        if b.len() == 1 {
            return (p - b[0]).norm();
        }
        b.windows(2)
            .map(|w| point_segment_m(p, w[0], w[1]))
            .fold(f32::INFINITY, f32::min)
    };
    a.iter().map(|&p| nearest(p)).sum::<f32>() / a.len() as f32
}

/// The symmetric mean closest-point distance between two paths (see the module comment), m.
pub fn trajectory_distance_m(a: &[Point2<f32>], b: &[Point2<f32>]) -> f32 {
    0.5 * (directed_mean_m(a, b) + directed_mean_m(b, a))
}

/// Rolls `policy` with all obstacles and with each removed in turn.
pub fn relevance(
    scenario: &Scenario,
    config: EnvConfig,
    policy: &mut dyn FnMut(&Observation) -> Action,
) -> Result<RelevanceReport, ScenarioError> {
    let baseline = roll(scenario, config, policy)?;
    let centres = baseline.centres();
    let mut obstacles = Vec::with_capacity(scenario.obstacles.len());
    for index in 0..scenario.obstacles.len() {
        let mut without = scenario.clone();
        without.obstacles.remove(index);
        let run = roll(&without, config, policy)?;
        obstacles.push(ObstacleRelevance {
            index,
            relevance_m: trajectory_distance_m(&centres, &run.centres()),
            run,
        });
    }
    Ok(RelevanceReport {
        baseline,
        obstacles,
    })
}

/// Maps world points to pixels of one panel (world +x right, +y up).
struct Panel {
    min: Point2<f32>,
    height_px: usize,
    x_offset_px: i64,
}

impl Panel {
    fn px(&self, p: Point2<f32>) -> (i64, i64) {
        let x = ((p.x - self.min.x) * TOP_VIEW_PX_PER_M).round() as i64 + self.x_offset_px;
        let y = self.height_px as i64 - 1 - ((p.y - self.min.y) * TOP_VIEW_PX_PER_M).round() as i64;
        (x, y)
    }
}

/// 3 x 5 pixel digits, one row per 3 bits (most significant bit left).
const DIGITS: [[u8; 5]; 10] = [
    [7, 5, 5, 5, 7],
    [2, 6, 2, 2, 7],
    [7, 1, 7, 4, 7],
    [7, 1, 7, 1, 7],
    [5, 5, 7, 1, 1],
    [7, 4, 7, 1, 7],
    [7, 4, 7, 5, 7],
    [7, 1, 1, 1, 1],
    [7, 5, 7, 5, 7],
    [7, 5, 7, 1, 7],
];
/// Pixels per font dot.
const FONT_SCALE: i64 = 3;

/// Writes a number centred at `centre`.
fn draw_number(canvas: &mut Canvas, centre: (i64, i64), number: usize, colour: [u8; 3]) {
    let text = number.to_string();
    let advance = 4 * FONT_SCALE;
    let width = text.len() as i64 * advance - FONT_SCALE;
    let (x0, y0) = (centre.0 - width / 2, centre.1 - 5 * FONT_SCALE / 2);
    for (k, digit) in text.bytes().enumerate() {
        let glyph = DIGITS[(digit - b'0') as usize];
        for (row, bits) in glyph.iter().enumerate() {
            for col in 0..3 {
                if bits & (4 >> col) != 0 {
                    let x = x0 + k as i64 * advance + col * FONT_SCALE;
                    let y = y0 + row as i64 * FONT_SCALE;
                    canvas.fill_rect(x, y, x + FONT_SCALE - 1, y + FONT_SCALE - 1, colour);
                }
            }
        }
    }
}

/// White (no relevance) to red (the most relevant obstacle).
fn relevance_colour(level: f32) -> [u8; 3] {
    let t = level.clamp(0.0, 1.0);
    let fade = (255.0 * (1.0 - t)) as u8;
    [255, fade, fade]
}

fn draw_path(
    canvas: &mut Canvas,
    panel: &Panel,
    path: &[RobotState],
    colour: [u8; 3],
    thick: bool,
) {
    for pair in path.windows(2) {
        let (a, b) = (panel.px(pair[0].position), panel.px(pair[1].position));
        canvas.line(a, b, colour);
        if thick {
            canvas.line((a.0 + 1, a.1), (b.0 + 1, b.1), colour);
            canvas.line((a.0, a.1 + 1), (b.0, b.1 + 1), colour);
        }
    }
    if let Some(last) = path.last() {
        canvas.disc(panel.px(last.position), if thick { 4 } else { 3 }, colour);
    }
}

fn draw_body(canvas: &mut Canvas, panel: &Panel, geometry: &RobotGeometry, state: &RobotState) {
    let (half_l, half_w) = (0.5 * geometry.body_length_m, 0.5 * geometry.body_width_m);
    let corners = [
        (half_l, half_w),
        (half_l, -half_w),
        (-half_l, -half_w),
        (-half_l, half_w),
    ]
    .map(|(x, y)| panel.px(state.robot_to_world(Vector2::new(x, y))));
    for i in 0..4 {
        canvas.line(corners[i], corners[(i + 1) % 4], [30, 60, 220]);
    }
    canvas.line(
        panel.px(state.position),
        panel.px(state.robot_to_world(Vector2::new(half_l, 0.0))),
        [30, 60, 220],
    );
}

/// The paper's relevance figure: on the left the scene with each obstacle coloured white (its
/// removal leaves the trajectory where it was) to red (the largest change), numbered by its
/// index, the target as a blue disc and the robot's start outlined; on the right the
/// trajectories: grey with every obstacle, red without the obstacle whose number is at its end
/// (only those that moved by more than 1 cm are numbered).
pub fn render(
    scenario: &Scenario,
    report: &RelevanceReport,
    geometry: &RobotGeometry,
    config: &EnvConfig,
) -> Canvas {
    // The arena (the robot's centre cannot leave it) plus the robot's reach.
    let margin = config.arena_margin_m + 0.3;
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
    let gap = 12;
    let mut canvas = Canvas::new(2 * width + gap, height, [255, 255, 255]);
    canvas.fill_rect(
        width as i64,
        0,
        (width + gap) as i64 - 1,
        height as i64,
        [90, 90, 90],
    );
    let panels = [0, (width + gap) as i64].map(|x_offset_px| Panel {
        min,
        height_px: height,
        x_offset_px,
    });
    let max_relevance_m = report
        .obstacles
        .iter()
        .map(|o| o.relevance_m)
        .fold(0.0f32, f32::max);
    for (p, panel) in panels.iter().enumerate() {
        canvas.grid(min, max, GRID_CELL_M, |q| panel.px(q), [232, 232, 228]);
        for (i, o) in scenario.obstacles.iter().enumerate() {
            let b = o.ground_box();
            let (x0, y0) = panel.px(Point2::new(b.min_x_m, b.min_y_m));
            let (x1, y1) = panel.px(Point2::new(b.max_x_m, b.max_y_m));
            let fill = if p == 0 {
                let level = report
                    .obstacles
                    .get(i)
                    .filter(|_| max_relevance_m > 0.0)
                    .map_or(0.0, |r| r.relevance_m / max_relevance_m);
                relevance_colour(level)
            } else {
                [236, 236, 236]
            };
            canvas.fill_rect(x0, y0, x1, y1, fill);
            let edge = [60, 60, 60];
            canvas.line((x0, y0), (x1, y0), edge);
            canvas.line((x1, y0), (x1, y1), edge);
            canvas.line((x1, y1), (x0, y1), edge);
            canvas.line((x0, y1), (x0, y0), edge);
        }
        if p == 0 {
            for (i, o) in scenario.obstacles.iter().enumerate() {
                draw_number(&mut canvas, panel.px(o.centre), i, [0, 0, 0]);
            }
            draw_body(&mut canvas, panel, geometry, &scenario.start);
        } else {
            for o in &report.obstacles {
                if o.relevance_m > 0.01 {
                    draw_path(&mut canvas, panel, &o.run.path, [220, 40, 30], false);
                }
            }
            draw_path(
                &mut canvas,
                panel,
                &report.baseline.path,
                [110, 110, 110],
                true,
            );
            // Paths that end in the same place (stuck at the same obstacle) get their numbers
            // side by side instead of on top of each other.
            let mut labels: Vec<(i64, i64)> = Vec::new();
            for o in &report.obstacles {
                if o.relevance_m > 0.01 {
                    if let Some(end) = o.run.path.last() {
                        let (x, y) = panel.px(end.position);
                        let mut at = (x + 12, y - 12);
                        while labels
                            .iter()
                            .any(|l| (l.0 - at.0).abs() < 16 && (l.1 - at.1).abs() < 18)
                        {
                            at.0 += 16;
                        }
                        labels.push(at);
                        draw_number(&mut canvas, at, o.index, [200, 30, 20]);
                    }
                }
            }
        }
        canvas.disc(panel.px(scenario.target), 6, [30, 60, 220]);
    }
    canvas
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn distance_is_zero_for_the_same_path_and_grows_with_offset() {
        let a: Vec<Point2<f32>> = (0..10).map(|i| Point2::new(0.05 * i as f32, 0.0)).collect();
        assert_eq!(trajectory_distance_m(&a, &a), 0.0);
        // The same line traced with other steps is the same path.
        let b: Vec<Point2<f32>> = (0..5)
            .map(|i| Point2::new(0.1125 * i as f32, 0.0))
            .collect();
        assert!(trajectory_distance_m(&a, &b) < 1e-6);
        let c: Vec<Point2<f32>> = a.iter().map(|p| p + Vector2::new(0.0, 0.2)).collect();
        assert!((trajectory_distance_m(&a, &c) - 0.2).abs() < 1e-5);
    }
}
