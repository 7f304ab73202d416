//! The loop itself, driven by the planner and by random int8 policies: every step tracks the
//! ideal one, refused steps are backed out of, a silent node stops the robot safely.

use super::*;

#[test]
fn planner_driver_reaches_the_target_and_every_step_matches_the_ideal_step() {
    let mut scenes = solvable_scenes(SceneKind::Complex, 21, 3);
    // Lift-over scenes change the clearance on the way: the legs are exercised too.
    scenes.extend(solvable_scenes(
        SceneKind::Behaviour(Behaviour::LiftOver),
        22,
        1,
    ));
    for scene in &scenes {
        let mut closed_loop = ClosedLoop::in_process(scene, LoopConfig::default()).unwrap();
        closed_loop.start().unwrap();
        let mut driver = PlannerDriver::new(closed_loop.env(), &planner()).unwrap();
        let planned = driver.planned_steps();
        let mut legs_moved = false;
        while !closed_loop.is_done() {
            let action = driver.decide(closed_loop.env()).unwrap();
            let before = *closed_loop.env().state();
            let record = closed_loop.step(action).unwrap();
            assert_eq!(record.kind, StepKind::Moved, "{}: {action:?}", scene.name);
            let report = record.report.unwrap();
            assert_within(
                StepError::of(&report),
                &format!("{} {action:?}", scene.name),
            );
            // The world moved to exactly the lattice state the action leads to.
            assert_eq!(*closed_loop.env().state(), before.after(action));
            legs_moved |= action.clearance != Step::Zero || action.track != Step::Zero;
        }
        let report = closed_loop.finish().unwrap();
        eprintln!(
            "{}: {:?} in {} steps, worst {:?}, drift {:.3} mm, bus {:?}",
            scene.name,
            report.status,
            report.steps,
            report.tracking.max_error,
            1e3 * report.odometry_drift_m,
            report.bus_load
        );
        assert_eq!(report.status, Status::Success, "{}", scene.name);
        assert_eq!(report.steps as usize, planned);
        assert_eq!(report.collisions, 0);
        assert_eq!(report.fault, None);
        assert_eq!(report.path.len(), planned + 1);
        assert_eq!(report.feedback.malformed, 0);
        // Odometry alone (no snapping) stays within a millimetre of the world over an episode.
        assert!(report.odometry_drift_m < 0.001, "{report:?}");
        // The bus load measured matches the computed one (docs/can-protocol.md: 37.3 %).
        let load = report.bus_load.unwrap();
        assert!((load.nominal - 0.373).abs() < 0.01, "{load:?}");
        if scene.name.starts_with("lift") {
            assert!(legs_moved, "the lift-over plan changed the legs");
        }
    }
}

/// Random networks mostly ask for legs the robot cannot reach (refused: nothing moves); take
/// the first seed whose policy moves the robot in at least `min_moves` steps of pure
/// simulation over `scenes`, so the motors have something to track.
fn moving_random_policy(scenes: &[Scenario], min_moves: usize) -> Vec<u8> {
    for seed in 0..40 {
        let bytes = random_policy_bytes(seed);
        let mut moves = 0;
        for scene in scenes {
            let mut env = Env::new(scene, LoopConfig::default().env).unwrap();
            let mut driver = PolicyDriver::new(&bytes, "random", Preset::Policy.config()).unwrap();
            while !env.status().is_done() {
                let before = *env.state();
                env.step(driver.decide(&env).unwrap()).unwrap();
                moves += usize::from(*env.state() != before);
            }
        }
        if moves >= min_moves {
            eprintln!("random policy seed {seed}: {moves} moves");
            return bytes;
        }
    }
    panic!("no random policy among 40 seeds moves {min_moves} times");
}

#[test]
fn random_int8_policy_runs_the_loop_and_tracks_the_ideal_steps() {
    let mut rng = ChaCha8Rng::seed_from_u64(31);
    let scenes: Vec<Scenario> = (0..2)
        .map(|i| {
            generate(
                wheelleg_sim::generate::SceneRobot::shipped(),
                SceneKind::Complex,
                &mut rng,
                format!("complex-{i}"),
            )
        })
        .collect();
    let dir = scratch_dir("random-policy");
    let path = dir.join("random.wlw");
    wheelleg_sim::atomic_write(&path, &moving_random_policy(&scenes, 10)).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let mut moved = 0;
    for scene in &scenes {
        let mut closed_loop = ClosedLoop::in_process(scene, LoopConfig::default()).unwrap();
        let log = SharedLog::default();
        closed_loop.log_to(CandumpWriter::new(
            Box::new(log.clone()),
            "can0",
            DEFAULT_EPOCH_US,
        ));
        closed_loop.start().unwrap();
        let mut driver = PolicyDriver::new(&bytes, "random.wlw", Preset::Policy.config()).unwrap();
        let mut kinds = Vec::new();
        while !closed_loop.is_done() {
            let action = driver.decide(closed_loop.env()).unwrap();
            let record = closed_loop.step(action).unwrap();
            for report in record.report.iter().chain(&record.retreat) {
                assert_within(StepError::of(report), &format!("{} {action:?}", scene.name));
            }
            kinds.push(record.kind);
        }
        let report = closed_loop.finish().unwrap();
        closed_loop.take_log().unwrap();
        eprintln!(
            "{}: {:?} after {} steps ({:?}), {} collisions",
            scene.name, report.status, report.steps, report.tracking, report.collisions
        );
        // It runs to the end of the episode without a fault; random weights do not succeed.
        assert_eq!(report.fault, None);
        assert!(report.status.is_done());
        assert!(!kinds.contains(&StepKind::Faulted));
        assert_eq!(report.feedback.malformed, 0);
        moved += report.tracking.moved + report.tracking.undone;
        // Every frame on the bus decodes as CANSimple.
        let text = log.text();
        let entries = parse_log(&text).unwrap();
        assert_eq!(entries.len() as u64, report.traffic.frames);
        for entry in &entries {
            wheelleg_runtime::can::decode(&entry.frame)
                .unwrap_or_else(|e| panic!("{entry:?}: {e:?}"));
        }
        // The world through the motors is the world of pure simulation: same verdict.
        let mut env = Env::new(scene, LoopConfig::default().env).unwrap();
        let mut driver = PolicyDriver::new(&bytes, "random.wlw", Preset::Policy.config()).unwrap();
        let status = simulate(&mut env, &mut driver).unwrap();
        assert_eq!(status, report.status);
        assert_eq!(env.steps(), report.steps);
        assert_eq!(env.collisions(), report.collisions);
        assert_eq!(env.state(), report.path.last().unwrap());
    }
    assert!(moved >= 10, "only {moved} steps moved the motors");
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A candump log kept in memory, readable after the writer is boxed away.
#[derive(Clone, Default)]
struct SharedLog(std::sync::Arc<std::sync::Mutex<Vec<u8>>>);

impl SharedLog {
    fn text(&self) -> String {
        String::from_utf8(self.0.lock().unwrap().clone()).unwrap()
    }
}

impl std::io::Write for SharedLog {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0.lock().unwrap().extend_from_slice(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

#[test]
fn a_step_the_world_refuses_is_backed_out_of() {
    // Straight ahead into a block: the world undoes the step that touches it, the robot drives
    // back to where the world says it is.
    let json = r#"{"scenarios":[{"name":"wall","robot":{"x":0.025,"y":0.025,"yaw_deg":0},
        "target":{"x":1.025,"y":0.025},
        "obstacles":[{"kind":"block","x":0.625,"y":0.125,"yaw_deg":0},
                     {"kind":"block","x":0.625,"y":-0.125,"yaw_deg":0}]}]}"#;
    let scene =
        wheelleg_sim::scenario_file::parse(json, &wheelleg_sim::robot::SimulatedRobot::SHIPPED)
            .unwrap()[0]
            .clone();
    let mut closed_loop = ClosedLoop::in_process(&scene, LoopConfig::default()).unwrap();
    closed_loop.start().unwrap();
    let forward_turning = Action {
        move_x: Step::Plus,
        ..Action::IDLE
    };
    let mut undone = None;
    for _ in 0..20 {
        let before = *closed_loop.env().state();
        let record = closed_loop.step(forward_turning).unwrap();
        if record.kind == StepKind::Undone {
            assert_eq!(
                record.outcome.unwrap().invalid,
                Some(InvalidAction::Collision)
            );
            assert_eq!(*closed_loop.env().state(), before);
            undone = Some(record);
            break;
        }
        assert_eq!(record.kind, StepKind::Moved);
    }
    let record = undone.expect("the robot reached the block");
    assert_within(StepError::of(&record.report.unwrap()), "into the block");
    assert_within(StepError::of(&record.retreat.unwrap()), "backing out");
    let report = closed_loop.report();
    assert_eq!(report.collisions, 1);
    assert_eq!(report.tracking.undone, 1);
    // Odometry agrees the robot is back where the world has it.
    assert!(report.odometry_drift_m < 0.001, "{report:?}");
    assert_eq!(report.fault, None);
}

#[test]
fn a_silent_node_mid_episode_stops_the_robot_safely_and_is_reported() {
    let scene = &solvable_scenes(SceneKind::Complex, 41, 1)[0];
    let mut closed_loop = ClosedLoop::in_process(scene, LoopConfig::default()).unwrap();
    closed_loop.start().unwrap();
    let mut driver = PlannerDriver::new(closed_loop.env(), &planner()).unwrap();
    assert!(driver.planned_steps() > 3);
    for _ in 0..2 {
        let action = driver.decide(closed_loop.env()).unwrap();
        assert_eq!(closed_loop.step(action).unwrap().kind, StepKind::Moved);
    }
    let silent = Axis::Wheel(LegId::RearLeft);
    closed_loop
        .rig_mut()
        .firmware_mut()
        .axis_mut(silent)
        .unwrap()
        .set_silent(true);
    let world_before = *closed_loop.env().state();
    let action = driver.decide(closed_loop.env()).unwrap();
    let record = closed_loop.step(action).unwrap();
    assert_eq!(record.kind, StepKind::Faulted);
    match closed_loop.fault() {
        Some(Fault::SafeStop {
            step: 2,
            reason: StopReason::Silent(set),
        }) => assert!(set.contains(silent)),
        other => panic!("expected a silent-node safe stop in step 3, got {other:?}"),
    }
    // The world does not move on a step the robot did not finish.
    assert_eq!(*closed_loop.env().state(), world_before);
    assert!(closed_loop.is_done());
    assert!(matches!(closed_loop.step(action), Err(LoopError::Finished)));
    // Wheels stopped, legs held: the knee does not move while the robot stands in safe stop.
    let knee = Axis::Joint(LegId::FrontRight, Joint::Knee);
    let knee_before = closed_loop.rig().firmware().axis(knee).unwrap().pos_turns();
    let report = closed_loop.finish().unwrap();
    let knee_after = closed_loop.rig().firmware().axis(knee).unwrap().pos_turns();
    assert!(true_wheel_speed_sum(closed_loop.rig().firmware()) < 1e-3);
    assert!((knee_after - knee_before).abs() < 1e-4);
    assert_eq!(report.status, Status::Running);
    let message = report.fault.unwrap().to_string();
    assert!(
        message.contains("node 15") && message.contains("silent"),
        "{message}"
    );
}

#[test]
fn success_rates_of_simulation_and_closed_loop_agree_for_the_planner() {
    let scenes = solvable_scenes(SceneKind::Complex, 51, 3);
    let comparison = compare_success(&scenes, &LoopConfig::default(), |env| {
        PlannerDriver::new(env, &planner())
    })
    .unwrap();
    eprintln!("{comparison:?}");
    assert_eq!(comparison.scenes, 3);
    assert_eq!(comparison.simulation_percent(), 100.0);
    assert_eq!(comparison.closed_loop_percent(), 100.0);
    assert!(comparison.gap_points() <= 2.0);
    assert_eq!(comparison.closed_loop_faults, 0);
}
