//! Composed scenes: a behaviour needed amid clutter.
//!
//! The behaviour scenes teach one passage in an empty arena, and the complex scenes rarely need a
//! leg behaviour at all (a way round is nearly always there). A composed scene needs one where
//! other obstacles stand: one or two fences across the whole arena (the behaviour scenes' own
//! passage geometry, [`super::fence_cells`]), 2 to 5 obstacles of any kind scattered before,
//! between and after them, never on the passage's lane, the opening up to one cell to either
//! side of the start's cell (and of the previous opening), any start yaw, and the target beyond
//! the last fence or inside its passage (astride the bar or the slab, in the corridor).
//!
//! Every draw flows from the caller's `rng`; the variant drawn is appended to the scene's name
//! (`composed-7-spread+lift-beyond`), so that an evaluation can split its results by variant
//! ([`ComposedVariant::of_name`]).

use super::{cell_index, fence_cells, fence_rows, layout, random_obstacle, StartYaw};
use super::{Behaviour, Layout, SceneRobot};
use crate::env::horizontal_reach_m;
use crate::obstacle::{cell_centre_m, Obstacle, ObstacleYaw, GRID_CELL_M};
use crate::scenario::Scenario;
use nalgebra::Point2;
use rand::Rng;

/// The pairs of fences a scene may hold, first fence first: those whose way through both fits
/// the episode's 100 steps with room for the leg changes and the turns to line up with each
/// passage, as `sim/tests/composed.rs` proves. A slab with a second fence does not: the spread
/// pose alone takes 10 leg steps there and 10 back, and the test's way through a slab and bars
/// came to 100 steps before the target.
pub const COMPOSED_PAIRS: [(Behaviour, Behaviour); 4] = [
    (Behaviour::LiftOver, Behaviour::LiftOver),
    (Behaviour::LiftOver, Behaviour::Squeeze),
    (Behaviour::Squeeze, Behaviour::LiftOver),
    (Behaviour::Squeeze, Behaviour::Squeeze),
];

/// The fence behaviours, in the order single-fence scenes draw them.
const SINGLE_FENCES: [Behaviour; 3] = [
    Behaviour::LiftOver,
    Behaviour::SpreadOver,
    Behaviour::Squeeze,
];

/// Share of scenes with two fences.
const TWO_FENCE_SHARE: f64 = 0.4;
/// Share of scenes whose target lies inside the last fence's passage.
const IN_PASSAGE_SHARE: f64 = 0.25;
/// Free cells between one fence's last row and the next fence's first: 0.75 m, room for the
/// robot (0.5 m long) to stand clear of both fences and change its legs between them.
const FENCE_GAP_CELLS: i32 = 3;
/// How near the passage's lane clutter may come (ground distance of its footprint): the robot
/// turning in place at full spread sweeps a circle of about 0.42 m radius.
const LANE_CLEAR_M: f32 = 0.45;
/// How far before a fence's first row (and after its last) the lane runs along the passage's
/// centre line: room to line up before entering.
const LANE_LEAD_M: f32 = 0.45;
/// Clutter obstacles per scene.
const CLUTTER: std::ops::RangeInclusive<usize> = 2..=5;
/// Clutter cells drawn at most per scene (cells on the lane are refused).
const CLUTTER_ATTEMPTS: usize = 300;

/// Where a composed scene's target lies.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum ComposedEnding {
    /// Past the last fence.
    Beyond,
    /// Inside the last fence's passage: on the bar, on the middle slab row, in the corridor.
    InPassage,
}

impl ComposedEnding {
    /// Name used in scene names.
    pub const fn name(self) -> &'static str {
        match self {
            ComposedEnding::Beyond => "beyond",
            ComposedEnding::InPassage => "in",
        }
    }
}

/// What a composed scene holds: its fences, in the order the robot meets them, and where its
/// target lies.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub struct ComposedVariant {
    /// The fences' behaviours (one or two).
    pub fences: Vec<Behaviour>,
    /// Where the target lies.
    pub ending: ComposedEnding,
}

impl ComposedVariant {
    /// The variant's name: fences joined by `+`, then the ending (`spread+lift-beyond`).
    pub fn name(&self) -> String {
        let fences: Vec<&str> = self.fences.iter().map(|b| b.name()).collect();
        format!("{}-{}", fences.join("+"), self.ending.name())
    }

    /// The variant a composed scene's name ends with, if it is one.
    pub fn of_name(scene_name: &str) -> Option<ComposedVariant> {
        let (rest, ending) = scene_name.rsplit_once('-')?;
        let ending = match ending {
            "beyond" => ComposedEnding::Beyond,
            "in" => ComposedEnding::InPassage,
            _ => return None,
        };
        let fences_name = rest.rsplit_once('-').map_or(rest, |(_, f)| f);
        let fences = fences_name
            .split('+')
            .map(|f| SINGLE_FENCES.into_iter().find(|b| b.name() == f).ok_or(()))
            .collect::<Result<Vec<_>, ()>>()
            .ok()?;
        (1..=2)
            .contains(&fences.len())
            .then_some(ComposedVariant { fences, ending })
    }

    fn draw(rng: &mut impl Rng) -> ComposedVariant {
        let fences = if rng.random_bool(TWO_FENCE_SHARE) {
            let (a, b) = COMPOSED_PAIRS[rng.random_range(0..COMPOSED_PAIRS.len())];
            vec![a, b]
        } else {
            vec![SINGLE_FENCES[rng.random_range(0..SINGLE_FENCES.len())]]
        };
        let ending = if rng.random_bool(IN_PASSAGE_SHARE) {
            ComposedEnding::InPassage
        } else {
            ComposedEnding::Beyond
        };
        ComposedVariant { fences, ending }
    }
}

/// One fence as placed: its first row's cell index along x, its opening's cell index along y.
#[derive(Clone, Copy, Debug)]
struct PlacedFence {
    behaviour: Behaviour,
    first_row: i32,
    opening: i32,
}

impl PlacedFence {
    fn last_row(&self) -> i32 {
        self.first_row + fence_rows(self.behaviour) - 1
    }

    fn line_y_m(&self) -> f32 {
        cell_centre_m(self.opening)
    }

    fn obstacles(&self) -> impl Iterator<Item = Obstacle> + '_ {
        (self.first_row..=self.last_row()).flat_map(move |row| {
            fence_cells(self.behaviour)
                .into_iter()
                .map(move |(m, kind)| {
                    Obstacle::new(
                        kind,
                        cell_centre_m(row),
                        cell_centre_m(self.opening + m),
                        ObstacleYaw::Deg0,
                    )
                })
        })
    }

    /// Where the robot stands when it is inside the passage: on the bar, on the middle slab
    /// row, between the corridor's two rows; on the robot's lattice.
    fn inside_m(&self, robot: &SceneRobot) -> Point2<f32> {
        let first_x = cell_centre_m(self.first_row);
        let depth_m = (fence_rows(self.behaviour) - 1) as f32 * GRID_CELL_M;
        Point2::new(
            robot.on_start_lattice(robot.start_lattice_index(first_x + 0.5 * depth_m)),
            self.line_y_m(),
        )
    }
}

/// A composed scene, its variant appended to `name`. The caller redraws scenes that do not
/// validate (start or target not free), as for every kind.
pub(super) fn composed_scene(
    robot: &SceneRobot,
    rng: &mut impl Rng,
    name: String,
    start_yaw: StartYaw,
) -> Scenario {
    // Fences of a behaviour the robot lacks are drawn again (no draw is repeated for a robot
    // that has every fence, so the shipped robot's scenes stay as they were); a robot with no
    // fence at all gets them as drawn, and its callers refuse composed scenes.
    let any_fence = robot.has_a_fence();
    let variant = loop {
        let variant = ComposedVariant::draw(rng);
        if !any_fence || variant.fences.iter().all(|&b| robot.has(b).is_ok()) {
            break variant;
        }
    };
    let Layout { start, target } = layout(robot, rng, 0.5, start_yaw);
    let path_cell = cell_index(start.position.y);
    // The first fence as in the behaviour scenes: its first row in the first cell whose centre
    // is at least the robot's fence lead ahead of the start, so the robot starts clear of it
    // at any yaw.
    let lead_m = robot.fence_lead_m();
    let mut first_row = cell_index(start.position.x + lead_m) + 1;
    if cell_centre_m(first_row - 1) >= start.position.x + lead_m {
        first_row -= 1;
    }
    let mut opening = path_cell;
    let mut fences = Vec::with_capacity(variant.fences.len());
    for &behaviour in &variant.fences {
        opening += rng.random_range(-1..=1);
        fences.push(PlacedFence {
            behaviour,
            first_row,
            opening,
        });
        first_row += fence_rows(behaviour) + FENCE_GAP_CELLS;
    }
    let last = *fences.last().expect("one or two fences");
    let target = match variant.ending {
        ComposedEnding::InPassage => last.inside_m(robot),
        ComposedEnding::Beyond => {
            // Far enough past the last row's centre that the robot standing there at any yaw
            // is clear of the fence (half the row, the robot's reach and 2 cm; never under
            // 0.55 m, the shipped robot's): a target the fence still reaches could need the
            // passing pose lined up with it, which a target off the passage's line rules out.
            // As far as the layout's target when that lies further.
            let clear_m = 0.5 * GRID_CELL_M + horizontal_reach_m(robot.geometry()) + 0.02;
            let past_m = cell_centre_m(last.last_row()) + clear_m.max(0.55);
            let x = target.x.max(robot.on_start_lattice(
                robot.start_lattice_index(past_m + 0.5 * robot.robot().lattice().move_step_m),
            ));
            Point2::new(x, target.y)
        }
    };
    let lane = lane(start.position, &fences, target, variant.ending);
    let mut obstacles: Vec<Obstacle> = fences.iter().flat_map(PlacedFence::obstacles).collect();
    let fence_row = |row: i32| {
        fences
            .iter()
            .any(|f| (f.first_row..=f.last_row()).contains(&row))
    };
    let (x0, x1) = (
        cell_index(start.position.x - 0.5),
        cell_index(target.x + 0.5),
    );
    let clutter = rng.random_range(CLUTTER);
    let mut placed = 0;
    for _ in 0..CLUTTER_ATTEMPTS {
        if placed == clutter {
            break;
        }
        let candidate = random_obstacle(rng, x0..=x1, path_cell - 4..=path_cell + 4);
        if fence_row(cell_index(candidate.centre.x)) {
            continue;
        }
        let footprint = candidate.ground_box();
        if obstacles.iter().any(|o| o.centre == candidate.centre)
            || lane
                .iter()
                .any(|&p| footprint.ground_distance_m(p) < LANE_CLEAR_M)
        {
            continue;
        }
        obstacles.push(candidate);
        placed += 1;
    }
    Scenario {
        name: format!("{name}-{}", variant.name()),
        start,
        target,
        obstacles,
    }
}

/// Points every 0.025 m along the passage's lane: from the start to the line through each
/// fence's opening `LANE_LEAD_M` before its first row, along that line to as far past its last
/// row, and on to the target (which ends the lane inside the last passage for an in-passage
/// ending).
fn lane(
    start: Point2<f32>,
    fences: &[PlacedFence],
    target: Point2<f32>,
    ending: ComposedEnding,
) -> Vec<Point2<f32>> {
    let mut corners = vec![start];
    for (i, fence) in fences.iter().enumerate() {
        let y = fence.line_y_m();
        corners.push(Point2::new(cell_centre_m(fence.first_row) - LANE_LEAD_M, y));
        let last = i + 1 == fences.len();
        if !(last && ending == ComposedEnding::InPassage) {
            corners.push(Point2::new(
                cell_centre_m(fence.last_row()) + LANE_LEAD_M,
                y,
            ));
        }
    }
    corners.push(target);
    let mut points = vec![start];
    for pair in corners.windows(2) {
        let (a, b) = (pair[0], pair[1]);
        let pieces = ((b - a).norm() / 0.025).ceil().max(1.0) as usize;
        points.extend((1..=pieces).map(|k| a + (b - a) * (k as f32 / pieces as f32)));
    }
    points
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn variant_names_round_trip() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        for _ in 0..50 {
            let v = ComposedVariant::draw(&mut rng);
            let name = format!("composed-12-{}", v.name());
            assert_eq!(ComposedVariant::of_name(&name), Some(v), "{name}");
        }
        assert_eq!(ComposedVariant::of_name("complex-3"), None);
        assert_eq!(ComposedVariant::of_name("composed-3-maze-in"), None);
    }
}
