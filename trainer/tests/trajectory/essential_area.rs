//! Essential areas, and randomized scenes that keep obstacles out of them.

use super::*;

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

#[test]
fn the_essential_area_is_the_simulated_robots() {
    // The area of a trajectory is swept by the robot of its episode rules: a body 30 cm longer
    // than the shipped one's sweeps more along the very same path.
    let shipped = EnvConfig::default();
    let long = EnvConfig {
        robot: wheelleg_sim::robot::SimulatedRobot::new(
            wheelleg_runtime::robot::RobotGeometry {
                body_length_m: shipped.robot.geometry().body_length_m + 0.3,
                ..*shipped.robot.geometry()
            },
            *shipped.robot.lattice(),
        )
        .unwrap(),
        ..shipped
    };
    let mut compared = 0;
    for t in sources() {
        // The longer body does not fit every source's scene.
        let Ok(area) = EssentialArea::of_trajectory(&t, long, DEFAULT_MARGIN_M) else {
            continue;
        };
        let path = t.replay(long).unwrap().path;
        let swept = |config: EnvConfig| {
            EssentialArea::from_path(config.robot.geometry(), &path, DEFAULT_MARGIN_M)
                .unwrap()
                .rects()
                .to_vec()
        };
        assert_eq!(area.rects(), swept(long), "{}", t.scenario.name);
        assert_ne!(area.rects(), swept(shipped), "{}", t.scenario.name);
        compared += 1;
    }
    assert!(compared > 0, "no source fits the longer body");
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
        let r = t.replay(batch.env_config().unwrap()).unwrap();
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
