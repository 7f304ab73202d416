//! The pictures people look at: the top view shows each obstacle kind in its colour, the way
//! with its collisions, and a legend in text; the height map shows heights on its colour scale.

use nalgebra::Point2;
use plotters::style::RGBColor;
use wheelleg_runtime::robot::WHEELLEG;
use wheelleg_sim::env::{Env, EnvConfig, Observation};
use wheelleg_sim::obstacle::{Obstacle, ObstacleKind, ObstacleYaw};
use wheelleg_sim::render::{height_map_image, kind_colour, top_view, Canvas, LEGEND_PX};
use wheelleg_sim::scenario::Scenario;
use wheelleg_sim::state::RobotState;

fn count(canvas: &Canvas, x_range: std::ops::Range<usize>, hit: impl Fn([u8; 3]) -> bool) -> usize {
    (0..canvas.height())
        .flat_map(|y| x_range.clone().map(move |x| (x, y)))
        .filter(|&(x, y)| canvas.pixel(x, y).is_some_and(&hit))
        .count()
}

fn rgb(c: RGBColor) -> [u8; 3] {
    [c.0, c.1, c.2]
}

fn scene() -> Scenario {
    Scenario {
        name: "every kind".into(),
        start: RobotState::new(
            Point2::new(0.025, 0.125),
            0,
            &wheelleg_runtime::action::ActionLattice::PAPER,
        ),
        target: Point2::new(1.525, 0.125),
        obstacles: vec![
            Obstacle::new(ObstacleKind::Block, 0.625, 0.625, ObstacleYaw::Deg0),
            Obstacle::new(ObstacleKind::Bar, 0.875, 0.125, ObstacleYaw::Deg0),
            Obstacle::new(ObstacleKind::Slab, 1.125, -0.375, ObstacleYaw::Deg90),
        ],
    }
}

#[test]
fn the_top_view_shows_every_kind_the_way_its_collisions_and_a_legend() {
    let scene = scene();
    let path: Vec<RobotState> = (0..6)
        .map(|i| {
            RobotState::new(
                Point2::new(0.025 + 0.1 * i as f32, 0.125),
                0,
                &wheelleg_runtime::action::ActionLattice::PAPER,
            )
        })
        .collect();
    let plain = top_view(&scene, &WHEELLEG, &path, &[]).unwrap();
    let with_collision = top_view(&scene, &WHEELLEG, &path, &path[3..4]).unwrap();
    let chart = 0..plain.width() - LEGEND_PX;
    for kind in ObstacleKind::ALL {
        let colour = rgb(kind_colour(kind));
        assert!(
            count(&plain, chart.clone(), |p| p == colour) > 100,
            "{kind:?} is drawn in its colour"
        );
    }
    let red = |p: [u8; 3]| p == [220, 0, 0];
    assert_eq!(count(&plain, chart.clone(), red), 0);
    assert!(
        count(&with_collision, chart, red) > 20,
        "the collision is marked"
    );
    // The legend's text: dark glyph pixels in the panel beside the chart.
    let legend = plain.width() - LEGEND_PX..plain.width();
    assert!(count(&plain, legend, |p| p.iter().all(|&c| c < 90)) > 300);
}

#[test]
fn the_height_map_shows_a_block_at_the_top_of_its_colour_scale() {
    let mut scene = scene();
    scene.obstacles.truncate(1);
    scene.obstacles[0] = Obstacle::new(ObstacleKind::Block, 0.625, 0.125, ObstacleYaw::Deg0);
    let env = Env::new(&scene, EnvConfig::default()).unwrap();
    let mut observation = Observation::default();
    env.observe(&mut observation);
    let image = height_map_image(&observation.height_map).unwrap();
    // Viridis' top is yellow: strong red and green, little blue.
    let yellow = |p: [u8; 3]| p[0] > 200 && p[1] > 200 && p[2] < 80;
    let with_block = count(&image, 0..image.width(), yellow);
    let mut empty = scene;
    empty.obstacles.clear();
    let env = Env::new(&empty, EnvConfig::default()).unwrap();
    env.observe(&mut observation);
    let flat = height_map_image(&observation.height_map).unwrap();
    // The colour bar's top is yellow in both; the block's 4 x 4 cells of 12 x 12 px only with it.
    let bar_only = count(&flat, 0..flat.width(), yellow);
    assert!(
        with_block >= bar_only + 16 * 100,
        "{with_block} yellow pixels with the block, {bar_only} without"
    );
}
