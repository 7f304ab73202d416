//! Stored trajectories, their essential areas, the randomized batch and its file.
//!
//! Source trajectories come from the planner on generated scenes (straight, lift), so every
//! test starts from real solutions. Run in release mode: a few seconds.

use nalgebra::Point2;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use std::path::PathBuf;
use std::sync::OnceLock;
use wheelleg_runtime::action::{Action, Step, COUNT};
use wheelleg_sim::env::{Env, EnvConfig, InvalidAction, Observation, Status};
use wheelleg_sim::generate::{generate, Behaviour, SceneKind};
use wheelleg_sim::obstacle::{is_cell_centre, Obstacle, ObstacleKind, ObstacleYaw};
use wheelleg_sim::planner::{plan, PlanOutcome, PlannerConfig, FALLBACK_WEIGHT};
use wheelleg_sim::scenario::Scenario;
use wheelleg_sim::state::RobotState;
use wheelleg_trainer::trajectory::batch_file::{
    partial_path, BatchFileError, TrajectoryBatch, MAGIC, PREAMBLE_LEN,
};
use wheelleg_trainer::trajectory::randomize::{
    prepare, randomize_batch, randomize_batch_with, randomize_source, RandomizeConfig,
};
use wheelleg_trainer::trajectory::relevance::{relevance, render, trajectory_distance_m};
use wheelleg_trainer::trajectory::sweep::{EssentialArea, GroundRect, DEFAULT_MARGIN_M};
use wheelleg_trainer::trajectory::{behaviour_code, behaviour_of_code, Trajectory};

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("wheelleg-traj-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A planner-made trajectory of a generated scene of `behaviour`.
fn planned(behaviour: Behaviour, seed: u64) -> Trajectory {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let kind = SceneKind::Behaviour(behaviour);
    let scenario = generate(kind, &mut rng, format!("{}-{seed}", behaviour.name()));
    let env = Env::new(&scenario, EnvConfig::default()).unwrap();
    let config = PlannerConfig {
        max_expansions: 20_000,
        heuristic_weight: FALLBACK_WEIGHT,
        ..PlannerConfig::default()
    };
    match plan(&env, &config).outcome {
        PlanOutcome::Solved { actions, .. } => Trajectory::new(scenario, actions, behaviour),
        other => panic!(
            "{} seed {seed}: planner found no plan: {other:?}",
            behaviour.name()
        ),
    }
}

/// Two straight and one lift trajectory, planned once for all tests.
fn sources() -> Vec<Trajectory> {
    static SOURCES: OnceLock<Vec<Trajectory>> = OnceLock::new();
    SOURCES
        .get_or_init(|| {
            vec![
                planned(Behaviour::Straight, 1),
                planned(Behaviour::LiftOver, 2),
                planned(Behaviour::Straight, 3),
            ]
        })
        .clone()
}

/// `trajectory` with one action inserted that collides (and is undone) somewhere near an
/// obstacle: the same path, one collision more.
fn with_a_collision(trajectory: &Trajectory) -> Trajectory {
    let config = EnvConfig::default();
    let mut env = Env::new(&trajectory.scenario, config).unwrap();
    for (i, &next) in trajectory.actions.iter().enumerate() {
        for index in 0..COUNT {
            let action = Action::from_index(index).unwrap();
            let mut probe = env.clone();
            if probe.step(action).unwrap().invalid == Some(InvalidAction::Collision) {
                let mut actions = trajectory.actions.clone();
                actions.insert(i, action);
                return Trajectory {
                    actions,
                    ..trajectory.clone()
                };
            }
        }
        env.step(next).unwrap();
    }
    panic!("no colliding action anywhere along the path");
}

#[test]
fn a_planned_trajectory_replays_to_success_with_its_observations() {
    let config = EnvConfig::default();
    for t in sources() {
        let replay = t.replay(config).unwrap();
        assert!(replay.success(), "{}: {:?}", t.scenario.name, replay.status);
        assert!(replay.collision_free());
        assert_eq!(replay.steps as usize, t.actions.len());
        assert_eq!(replay.path.len(), t.actions.len() + 1);
        let returns = replay.returns(1.0);
        assert!((returns[0] - replay.total_reward()).abs() < 1e-4);

        // The re-rendered samples are what a live episode shows.
        let steps = t.replay_observations(config).unwrap();
        assert_eq!(steps.len(), t.actions.len());
        let mut env = Env::new(&t.scenario, config).unwrap();
        let mut observation = Observation::default();
        for (i, step) in steps.iter().enumerate() {
            env.observe(&mut observation);
            assert_eq!(step.observation, observation, "step {i}");
            assert_eq!(step.action, t.actions[i]);
            let outcome = env.step(step.action).unwrap();
            assert_eq!(step.reward, outcome.reward.total());
            assert_eq!(step.reward, replay.rewards[i]);
            assert_eq!(step.done, i + 1 == steps.len());
        }
        assert_eq!(env.status(), Status::Success);
    }
}

#[test]
fn replay_reports_actions_past_the_end_and_bad_scenes() {
    let t = sources()[0].clone();
    let mut longer = t.clone();
    longer.actions.push(Action::IDLE);
    let e = longer.replay(EnvConfig::default()).unwrap_err();
    assert!(e.to_string().contains("before action"), "{e}");

    let mut bad = t.clone();
    bad.scenario.obstacles.push(Obstacle::new(
        ObstacleKind::Block,
        bad.scenario.start.position.x,
        bad.scenario.start.position.y,
        ObstacleYaw::Deg0,
    ));
    let e = bad.replay(EnvConfig::default()).unwrap_err();
    assert!(e.to_string().contains("inside an obstacle"), "{e}");
}

#[test]
fn undone_actions_are_dropped_and_the_path_stays() {
    let config = EnvConfig::default();
    let t = sources()[1].clone();
    let bumped = with_a_collision(&t);
    let replay = bumped.replay(config).unwrap();
    assert!(replay.success());
    assert_eq!(replay.collisions, 1);
    let pruned = bumped.without_undone_actions(config).unwrap();
    assert_eq!(pruned.actions, t.actions);
    let mut path = replay.path.clone();
    path.dedup();
    let mut pruned_path = pruned.replay(config).unwrap().path;
    pruned_path.dedup();
    assert_eq!(path, pruned_path);

    // Randomizing the bumped source stores the clean actions.
    let randomize = RandomizeConfig {
        per_trajectory: 5,
        ..RandomizeConfig::default()
    };
    let record = randomize_source(&bumped, 0, &randomize).unwrap();
    assert!(record.rejected.is_empty(), "{}", record.rejected);
    let stored: Vec<usize> = record.actions.iter().map(|&a| a as usize).collect();
    let clean: Vec<usize> = t.actions.iter().map(Action::index).collect();
    assert_eq!(stored, clean);
}

#[test]
fn the_essential_area_covers_every_checked_pose_and_nothing_far() {
    let config = EnvConfig::default();
    for t in sources() {
        let area = EssentialArea::of_trajectory(&t, config, DEFAULT_MARGIN_M).unwrap();
        let path = t.replay(config).unwrap().path;
        for s in &path {
            assert!(
                area.contains(s.position),
                "{}: body centre outside",
                t.scenario.name
            );
        }
        // A point a metre beside the whole path is not essential.
        let far = Point2::new(path[0].position.x, path[0].position.y + 1.5);
        assert!(!area.contains(far));
        // Raster and exact rectangles agree on the answer for grid obstacles around the path.
        let b = area.bounds();
        assert!(b.max.x - b.min.x > 0.5, "the area spans the path");
    }
}

/// Source obstacles that meet `area`, by a naive test over the area's rectangles.
fn meets(area: &EssentialArea, o: &Obstacle) -> bool {
    let r = GroundRect::of_box(&o.ground_box());
    area.rects().iter().any(|a| a.intersects(&r))
}

#[test]
fn randomized_scenes_never_put_an_obstacle_in_the_essential_area() {
    let config = RandomizeConfig {
        per_trajectory: 40,
        seed: 9,
        ..RandomizeConfig::default()
    };
    for (index, t) in sources().iter().enumerate() {
        let prepared = prepare(t, &config).unwrap();
        let area = &prepared.area;
        let kept: Vec<Obstacle> = prepared.kept.iter().map(|p| p.unpack().unwrap()).collect();
        let expected: Vec<Obstacle> = t
            .scenario
            .obstacles
            .iter()
            .filter(|o| meets(area, o))
            .copied()
            .collect();
        assert_eq!(
            kept, expected,
            "kept obstacles are those in the area, as they were"
        );
        if t.behaviour == Behaviour::LiftOver {
            assert!(!kept.is_empty(), "the straddled bar is essential");
            assert!(
                kept.len() < t.scenario.obstacles.len(),
                "far bars are dropped"
            );
        }
        let record = randomize_source(t, index as u64, &config).unwrap();
        assert_eq!(record.tried, 40);
        let s = &t.scenario;
        let arena_margin = config.env.arena_margin_m;
        for scene in &record.scenes {
            let mut cells: Vec<(i16, i16)> = record
                .kept
                .iter()
                .chain(scene)
                .map(|p| (p.cell_x, p.cell_y))
                .collect();
            let n = cells.len();
            cells.sort_unstable();
            cells.dedup();
            assert_eq!(cells.len(), n, "one obstacle per cell");
            for p in scene {
                let o = p.unpack().unwrap();
                if record.original_included && std::ptr::eq(scene, &record.scenes[0]) {
                    continue;
                }
                assert!(!meets(area, &o), "{o:?} in the essential area");
                assert!(is_cell_centre(o.centre.x) && is_cell_centre(o.centre.y));
                assert!(o.centre.x >= s.start.position.x.min(s.target.x) - arena_margin);
                assert!(o.centre.x <= s.start.position.x.max(s.target.x) + arena_margin);
                assert!(o.centre.y >= s.start.position.y.min(s.target.y) - arena_margin);
                assert!(o.centre.y <= s.start.position.y.max(s.target.y) + arena_margin);
            }
        }
        // Every kind and yaw is used somewhere.
        let used: Vec<u8> = record.scenes.iter().flatten().map(|p| p.code).collect();
        for code in 0..6 {
            assert!(
                used.contains(&code),
                "{}: obstacle code {code} never drawn",
                s.name
            );
        }
    }
}

#[test]
fn every_stored_trajectory_replays_to_success_without_collision() {
    let dir = scratch("replay");
    let out = dir.join("batch.wltb");
    let sources = sources();
    let mut last = None;
    let stats = randomize_batch(&sources, 30, 4, &out, |p| last = Some(p)).unwrap();
    assert_eq!(stats.sources, 3);
    assert_eq!(stats.sources_rejected, 0, "{:?}", stats.rejections);
    assert_eq!(stats.tried, 90);
    assert!(stats.kept <= stats.tried);
    assert_eq!(stats.originals, 3);
    assert_eq!(last.unwrap().sources_done, 3);
    assert!(
        !partial_path(&out).exists(),
        "the partial file is renamed when done"
    );

    let batch = TrajectoryBatch::load(&out).unwrap();
    assert_eq!(batch.len() as u64, stats.trajectories());
    assert_eq!(batch.file_bytes(), stats.file_bytes);
    for i in 0..batch.len() {
        let t = batch.trajectory(i).unwrap();
        let source = batch.source_of(i).unwrap();
        assert_eq!(t.scenario.start, source.start);
        assert_eq!(t.scenario.target, source.target);
        let r = t.replay(batch.env_config()).unwrap();
        assert!(
            r.success() && r.collisions == 0 && r.invalid_actions == 0,
            "{i}: {r:?}"
        );
    }
    assert!(batch.trajectory(batch.len()).is_none());
    let counts = batch.counts_by_behaviour();
    assert_eq!(counts.iter().sum::<usize>(), batch.len());
    assert!(counts[2] > 0, "lift trajectories stored");

    // Asking again with the same parameters is a no-op that reports the same batch; other
    // parameters are refused rather than overwriting it.
    let again = randomize_batch(&sources, 30, 4, &out, |_| {}).unwrap();
    assert_eq!(again.trajectories(), stats.trajectories());
    let e = randomize_batch(&sources, 30, 5, &out, |_| {}).unwrap_err();
    assert!(
        matches!(e, BatchFileError::Mismatch { field: "seed", .. }),
        "{e}"
    );
    let e = randomize_batch(&sources[..2], 30, 4, &out, |_| {}).unwrap_err();
    assert!(
        matches!(
            e,
            BatchFileError::Mismatch {
                field: "sources",
                ..
            }
        ),
        "{e}"
    );
}

#[test]
fn the_replay_check_catches_an_obstacle_in_the_essential_area() {
    // The negative control of the keep rule: a block put on the path makes the same actions
    // collide, so such a scene could never be kept.
    let config = EnvConfig::default();
    for t in sources() {
        let path = t.replay(config).unwrap().path;
        let area = EssentialArea::of_trajectory(&t, config, DEFAULT_MARGIN_M).unwrap();
        let cell = |v: f32| (v / 0.25).floor() * 0.25 + 0.125;
        let mut tried = 0;
        for state in &path {
            let block = Obstacle::new(
                ObstacleKind::Block,
                cell(state.position.x),
                cell(state.position.y),
                ObstacleYaw::Deg0,
            );
            let mut blocked = t.clone();
            blocked.scenario.obstacles.push(block);
            let Ok(r) = blocked.replay(config) else {
                continue; // the robot would start inside it
            };
            tried += 1;
            assert!(area.intersects_obstacle(&block));
            assert!(r.collisions > 0, "{}: {block:?}", t.scenario.name);
        }
        assert!(tried > 3, "{}: {tried} blocks tried", t.scenario.name);
    }
}

#[test]
fn the_same_seed_gives_the_same_batch() {
    let dir = scratch("seed");
    let sources = sources();
    let run = |name: &str, seed: u64| {
        let out = dir.join(name);
        randomize_batch(&sources, 20, seed, &out, |_| {}).unwrap();
        std::fs::read(out).unwrap()
    };
    let a = run("a.wltb", 7);
    assert_eq!(a, run("b.wltb", 7));
    assert_ne!(a, run("c.wltb", 8));
}

fn small_chunks() -> RandomizeConfig {
    RandomizeConfig {
        per_trajectory: 12,
        seed: 3,
        chunk_scenes: 1,
        ..RandomizeConfig::default()
    }
}

#[test]
fn damaged_or_foreign_files_are_refused_with_a_typed_error() {
    let dir = scratch("damage");
    let out = dir.join("batch.wltb");
    randomize_batch_with(&sources(), &small_chunks(), &out, |_| {}).unwrap();
    let good = std::fs::read(&out).unwrap();
    assert!(TrajectoryBatch::from_bytes(&good).is_ok());

    let mut magic = good.clone();
    magic[0] = b'X';
    assert!(matches!(
        TrajectoryBatch::from_bytes(&magic),
        Err(BatchFileError::BadMagic { .. })
    ));
    assert!(matches!(
        TrajectoryBatch::from_bytes(b"{\"scenarios\":[]}"),
        Err(BatchFileError::BadMagic { .. })
    ));

    let mut version = good.clone();
    version[8] = 2;
    let e = TrajectoryBatch::from_bytes(&version).unwrap_err();
    assert!(
        matches!(
            e,
            BatchFileError::UnsupportedVersion {
                found: 2,
                supported: 1
            }
        ),
        "{e}"
    );
    assert!(e.to_string().contains("version 2"), "{e}");

    let mut header = good.clone();
    header[PREAMBLE_LEN + 1] ^= 0x40;
    assert!(matches!(
        TrajectoryBatch::from_bytes(&header),
        Err(BatchFileError::HeaderCorrupt { .. })
    ));

    let mut body = good.clone();
    let at = good.len() - 5;
    body[at] ^= 0x01;
    let e = TrajectoryBatch::from_bytes(&body).unwrap_err();
    assert!(matches!(e, BatchFileError::ChunkCorrupt { .. }), "{e}");
    assert!(e.to_string().contains("CRC-32"), "{e}");

    let e = TrajectoryBatch::from_bytes(&good[..good.len() - 3]).unwrap_err();
    assert!(matches!(e, BatchFileError::Truncated { .. }), "{e}");
    assert!(e.to_string().contains("truncated"), "{e}");

    // Never a panic, whatever the damage: every prefix, and a flipped bit in every byte.
    for len in 0..good.len() {
        assert!(
            TrajectoryBatch::from_bytes(&good[..len]).is_err(),
            "prefix {len}"
        );
    }
    for at in 0..good.len() {
        let mut bad = good.clone();
        bad[at] ^= 0x10;
        assert!(TrajectoryBatch::from_bytes(&bad).is_err(), "flip at {at}");
    }
    assert_eq!(&good[..8], &MAGIC);
}

#[test]
fn a_killed_generation_resumes_from_its_last_complete_chunk() {
    let dir = scratch("resume");
    let sources = sources();
    let config = small_chunks();
    let whole = dir.join("whole.wltb");
    let full = randomize_batch_with(&sources, &config, &whole, |_| {}).unwrap();
    let good = std::fs::read(&whole).unwrap();

    // Cut the file inside its last chunk and inside its second: as if killed while writing.
    let (_, first_chunk) = wheelleg_trainer::trajectory::batch_file::parse_header(&good).unwrap();
    for cut in [good.len() - 7, first_chunk + 5, first_chunk + 30] {
        let out = dir.join(format!("cut-{cut}.wltb"));
        std::fs::write(partial_path(&out), &good[..cut]).unwrap();
        let loaded = TrajectoryBatch::from_bytes(&good[..cut]);
        assert!(loaded.is_err(), "a cut file does not load");
        let stats = randomize_batch_with(&sources, &config, &out, |_| {}).unwrap();
        assert!(
            stats.discarded_tail_bytes > 0,
            "cut {cut}: the half chunk is dropped"
        );
        assert_eq!(
            std::fs::read(&out).unwrap(),
            good,
            "cut {cut}: same bytes as unbroken"
        );
        assert_eq!(stats.trajectories(), full.trajectories());
        assert_eq!(stats.tried, full.tried);
    }

    // A partial file of other parameters is not continued.
    let out = dir.join("other.wltb");
    std::fs::write(partial_path(&out), &good[..good.len() - 7]).unwrap();
    let other = RandomizeConfig {
        seed: 4,
        ..config.clone()
    };
    let e = randomize_batch_with(&sources, &other, &out, |_| {}).unwrap_err();
    assert!(
        matches!(e, BatchFileError::Mismatch { field: "seed", .. }),
        "{e}"
    );
}

#[test]
fn an_incomplete_batch_is_refused() {
    let dir = scratch("incomplete");
    let out = dir.join("batch.wltb");
    let sources = sources();
    randomize_batch_with(&sources[..2], &small_chunks(), &out, |_| {}).unwrap();
    // The same chunks under a header that promises three sources.
    let two = std::fs::read(&out).unwrap();
    let header = small_chunks().header(&sources).unwrap();
    let mut bytes = wheelleg_trainer::trajectory::batch_file::header_bytes(&header).unwrap();
    let (_, start) = wheelleg_trainer::trajectory::batch_file::parse_header(&two).unwrap();
    bytes.extend_from_slice(&two[start..]);
    let e = TrajectoryBatch::from_bytes(&bytes).unwrap_err();
    assert!(
        matches!(
            e,
            BatchFileError::Incomplete {
                sources_done: 2,
                sources_total: 3
            }
        ),
        "{e}"
    );
}

#[test]
fn a_failed_or_off_grid_source_is_rejected_and_counted() {
    let dir = scratch("reject");
    let mut failing = sources()[0].clone();
    failing.actions.truncate(2);
    let mut off_grid = sources()[2].clone();
    let far = off_grid.scenario.target + nalgebra::Vector2::new(0.0, 0.5);
    off_grid.scenario.obstacles.push(Obstacle::new(
        ObstacleKind::Bar,
        far.x + 0.01,
        far.y,
        ObstacleYaw::Deg0,
    ));
    let out = dir.join("batch.wltb");
    let stats = randomize_batch(&[failing, off_grid], 5, 1, &out, |_| {}).unwrap();
    assert_eq!(stats.sources_rejected, 2);
    assert!(
        stats.rejections[0].1.contains("does not reach"),
        "{:?}",
        stats.rejections
    );
    assert!(
        stats.rejections[1].1.contains("grid"),
        "{:?}",
        stats.rejections
    );
    assert_eq!(TrajectoryBatch::load(&out).unwrap().len(), 0);
}

/// Drives at the target, never around anything: enough to see what an obstacle changes.
fn toward_target(observation: &Observation) -> Action {
    let (x, y) = (observation.state[2], observation.state[3]);
    let step = |v: f32| {
        if v > 0.025 {
            Step::Plus
        } else if v < -0.025 {
            Step::Minus
        } else {
            Step::Zero
        }
    };
    Action {
        move_x: step(x),
        move_y: step(y),
        ..Action::IDLE
    }
}

#[test]
fn relevance_finds_the_obstacle_in_the_way() {
    let scenario = Scenario {
        name: "relevance".into(),
        start: RobotState::new(Point2::new(0.025, 0.125), 0),
        target: Point2::new(1.025, 0.125),
        obstacles: vec![
            // Far to the side: irrelevant.
            Obstacle::new(ObstacleKind::Block, 0.375, -0.625, ObstacleYaw::Deg0),
            // On the straight line: the policy above gets stuck on it.
            Obstacle::new(ObstacleKind::Block, 0.625, 0.125, ObstacleYaw::Deg0),
        ],
    };
    let config = EnvConfig::default();
    let report = relevance(&scenario, config, &mut toward_target).unwrap();
    assert_ne!(report.baseline.status, Status::Success);
    assert_eq!(report.obstacles.len(), 2);
    assert_eq!(report.obstacles[0].relevance_m, 0.0);
    assert!(
        report.obstacles[1].relevance_m > 0.05,
        "{}",
        report.obstacles[1].relevance_m
    );
    assert_eq!(report.obstacles[1].run.status, Status::Success);
    let same = trajectory_distance_m(&report.baseline.centres(), &report.baseline.centres());
    assert_eq!(same, 0.0);

    let canvas = render(
        &scenario,
        &report,
        &wheelleg_runtime::robot::WHEELLEG,
        &config,
    )
    .unwrap();
    let red = (0..canvas.height())
        .flat_map(|y| (0..canvas.width()).map(move |x| (x, y)))
        .filter(|&(x, y)| canvas.pixel(x, y) == Some([255, 0, 0]))
        .count();
    assert!(
        red > 500,
        "the relevant block is drawn fully red ({red} px)"
    );
}

#[test]
fn behaviours_keep_their_file_codes() {
    // A behaviour's index in Behaviour::ALL, as in every batch file written so far; 5 and 6
    // (retired experiments) read as no behaviour, and a batch holding them is refused.
    for (code, b) in Behaviour::ALL.iter().enumerate() {
        assert_eq!(behaviour_code(*b) as usize, code);
        assert_eq!(behaviour_of_code(code as u8), Some(*b));
    }
    for retired in [5, 6, 7] {
        assert_eq!(behaviour_of_code(retired), None);
    }
}
