use super::geometry::segment_rect_distance_m;
use super::*;
use crate::action::Step;
use crate::observation::cell_centre_in_robot_m;
use crate::observation::{HEIGHT_MAP_CELLS, HEIGHT_MAP_SIDE};
use crate::robot::{Robot, WHEELLEG};

fn flat() -> [f32; HEIGHT_MAP_CELLS] {
    [0.0; HEIGHT_MAP_CELLS]
}

fn default_legs() -> LegConfig {
    LegConfig {
        clearance_m: WHEELLEG.default_clearance_m,
        track_m: WHEELLEG.default_track_m,
    }
}

fn forward() -> Action {
    let mut action = Action::IDLE;
    action.set(crate::action::Dim::MoveX, Step::Plus);
    action
}

/// Puts a block of `height_m` over robot-frame x in `[x0, x1]`, y in `[y0, y1]` (cell
/// centres inside count).
fn block(map: &mut [f32; HEIGHT_MAP_CELLS], x: (f32, f32), y: (f32, f32), height_m: f32) {
    for row in 0..HEIGHT_MAP_SIDE {
        for col in 0..HEIGHT_MAP_SIDE {
            let (cx, cy) = cell_centre_in_robot_m(row, col);
            if cx >= x.0 && cx <= x.1 && cy >= y.0 && cy <= y.1 {
                map[row * HEIGHT_MAP_SIDE + col] = height_m;
            }
        }
    }
}

#[test]
fn a_grid_map_is_checked_for_its_size_and_cell() {
    let cells = [0.0f32; 16];
    assert_eq!(
        GridMap::new(&cells, 5, 0.01),
        Err(GridMapError::WrongLength {
            expected: 25,
            found: 16
        })
    );
    assert_eq!(
        GridMap::new(&[], 0, 0.01),
        Err(GridMapError::WrongLength {
            expected: 0,
            found: 0
        })
    );
    assert_eq!(
        GridMap::new(&cells, 4, f32::NAN),
        Err(GridMapError::BadCellSize)
    );
    assert_eq!(GridMap::new(&cells, 4, 0.0), Err(GridMapError::BadCellSize));
    let grid = GridMap::new(&cells, 4, 0.01).unwrap();
    assert_eq!((grid.side(), grid.cell_m()), (4, 0.01));
}

#[test]
fn a_grid_map_of_the_policy_layout_gets_the_policy_maps_verdicts() {
    // The same cells read through either door: every action, on a map with a wall, a
    // slab and a bar around the robot.
    let mut map = flat();
    block(&mut map, (0.3, 0.8), (0.2, 0.8), 0.4);
    block(&mut map, (-0.4, -0.1), (-0.25, 0.25), 0.05);
    block(&mut map, (0.05, 0.25), (-0.5, -0.42), 0.15);
    let grid = GridMap::new(&map, HEIGHT_MAP_SIDE, HEIGHT_MAP_CELL_M).unwrap();
    for margin_m in [-0.01, 0.0, DEFAULT_MARGIN_M, 0.02] {
        let guard = CollisionGuard::new(&Robot::WHEELLEG, margin_m);
        for index in 0..crate::action::COUNT {
            let action = Action::from_index(index).unwrap();
            assert_eq!(
                guard.check(HeightMapRef::Grid(grid), default_legs(), action),
                guard.check(HeightMapRef::Metres(&map), default_legs(), action),
                "{action:?} at margin {margin_m}"
            );
        }
    }
}

#[test]
fn flat_ground_lets_every_reachable_action_through() {
    let guard = CollisionGuard::new(&Robot::WHEELLEG, DEFAULT_MARGIN_M);
    let map = flat();
    for index in 0..crate::action::COUNT {
        let action = Action::from_index(index).unwrap();
        let reachable = WHEELLEG.is_reachable(target_config(
            default_legs(),
            action,
            &Robot::WHEELLEG.actions,
        ));
        let verdict = guard.check(HeightMapRef::Metres(&map), default_legs(), action);
        assert_eq!(verdict.is_ok(), reachable, "{action:?}: {verdict:?}");
    }
}

#[test]
fn a_wall_just_ahead_refuses_forward_but_not_backward() {
    let guard = CollisionGuard::new(&Robot::WHEELLEG, DEFAULT_MARGIN_M);
    let mut map = flat();
    // The wheels' front edge is at hip_x + radius = 0.25 m; a tall wall from 0.31 m.
    block(&mut map, (0.31, 0.8), (-0.8, 0.8), 0.5);
    let mut backward = Action::IDLE;
    backward.set(crate::action::Dim::MoveX, Step::Minus);
    let map_ref = HeightMapRef::Metres(&map);
    assert_eq!(
        guard.check(map_ref, default_legs(), forward()),
        Err(Refusal::Collision)
    );
    assert_eq!(guard.check(map_ref, default_legs(), backward), Ok(()));
    assert_eq!(guard.check(map_ref, default_legs(), Action::IDLE), Ok(()));
}

/// A 1 cm, 128 x 128 map with tall walls over robot-frame x >= `front_m` and y >= `left_m`.
fn walls_1cm(front_m: f32, left_m: f32) -> [f32; 128 * 128] {
    let mut map = [0.0; 128 * 128];
    for row in 0..128 {
        for col in 0..128 {
            let (x, y) = ((63.5 - row as f32) * 0.01, (63.5 - col as f32) * 0.01);
            if x >= front_m || y >= left_m {
                map[row * 128 + col] = 0.4;
            }
        }
    }
    map
}

#[test]
fn the_lenient_check_forgives_an_overlap_where_the_robot_stands_but_no_new_contact() {
    let guard = CollisionGuard::new(&Robot::WHEELLEG, DEFAULT_MARGIN_M);
    let legs = default_legs();
    let overlap = |map: &[f32], action| {
        let grid = HeightMapRef::Grid(GridMap::new(map, 128, 0.01).unwrap());
        guard
            .deepest_overlap_m(grid, legs, action, None, None, &Isometry2::identity())
            .unwrap()
    };
    // A wall on the left that the standing robot overlaps (the grown columns claim more
    // than is there) by a few millimetres, and one ahead that a forward step enters less
    // deeply than that.
    let far_m = 0.63;
    let left_m = (0..150)
        .map(|i| 0.4 - 0.002 * i as f32)
        .find(|&y| overlap(&walls_1cm(far_m, y), Action::IDLE) > 0.008)
        .expect("a left wall the robot overlaps");
    let here_m = overlap(&walls_1cm(far_m, left_m), Action::IDLE);
    let front_m = (0..100)
        .map(|i| 0.5 - 0.002 * i as f32)
        .find(|&x| overlap(&walls_1cm(x, 1.0), forward()) > 0.001)
        .expect("a front wall a forward step enters");
    let map = walls_1cm(front_m, left_m);
    let grid = HeightMapRef::Grid(GridMap::new(&map, 128, 0.01).unwrap());
    assert!(overlap(&walls_1cm(front_m, 1.0), forward()) < here_m);
    // Strict: everything that keeps the wall on the left overlapped is refused.
    assert_eq!(guard.check(grid, legs, forward()), Err(Refusal::Collision));
    // Lenient: standing still is forgiven, a step into the wall ahead is not, although
    // it goes less deep than the robot already overlaps the left wall.
    assert_eq!(guard.check_no_deeper(grid, legs, Action::IDLE), Ok(()));
    assert_eq!(
        guard.check_no_deeper(grid, legs, forward()),
        Err(Refusal::Collision)
    );
    let mut away = Action::IDLE;
    away.set(crate::action::Dim::MoveY, Step::Minus);
    assert_eq!(guard.check_no_deeper(grid, legs, away), Ok(()));
}

#[test]
fn a_step_ahead_in_a_plan_is_judged_from_where_it_starts() {
    let guard = CollisionGuard::new(&Robot::WHEELLEG, DEFAULT_MARGIN_M);
    // A wall a few steps ahead: clear from here, hit from 0.15 m further on, and from a
    // pose turned round at that place a step backwards (towards the wall) hits it too.
    let map = walls_1cm(0.45, 1.0);
    let grid = HeightMapRef::Grid(GridMap::new(&map, 128, 0.01).unwrap());
    let legs = default_legs();
    assert_eq!(guard.check(grid, legs, forward()), Ok(()));
    let on = Isometry2::new(nalgebra::Vector2::new(0.15, 0.0), 0.0);
    assert_eq!(
        guard.check_from(grid, &on, legs, forward()),
        Err(Refusal::Collision)
    );
    let turned = Isometry2::new(nalgebra::Vector2::new(0.15, 0.0), core::f32::consts::PI);
    let mut backward = Action::IDLE;
    backward.set(crate::action::Dim::MoveX, Step::Minus);
    assert_eq!(
        guard.check_from(grid, &turned, legs, backward),
        Err(Refusal::Collision)
    );
    assert_eq!(guard.check_from(grid, &turned, legs, forward()), Ok(()));
    // The identity is the plain check.
    assert_eq!(
        guard.check_from(grid, &Isometry2::identity(), legs, forward()),
        guard.check(grid, legs, forward())
    );
}

#[test]
fn a_low_bar_between_the_wheels_passes_under_a_high_body_only() {
    let guard = CollisionGuard::new(&Robot::WHEELLEG, 0.01);
    let mut map = flat();
    // A bar across the centre line, narrower than the gap between the wheels, 0.10 m high.
    block(&mut map, (0.0, 0.05), (-0.06, 0.06), 0.10);
    let map_ref = HeightMapRef::Metres(&map);
    let low = LegConfig {
        clearance_m: 0.08,
        track_m: WHEELLEG.default_track_m,
    };
    let high = LegConfig {
        clearance_m: 0.16,
        track_m: WHEELLEG.default_track_m,
    };
    assert_eq!(
        guard.check(map_ref, low, Action::IDLE),
        Err(Refusal::Collision)
    );
    assert_eq!(guard.check(map_ref, high, Action::IDLE), Ok(()));
}

#[test]
fn where_everything_is_refused_the_lenient_level_lets_the_robot_back_off_only() {
    let guard = CollisionGuard::new(&Robot::WHEELLEG, 0.025);
    let mut map = flat();
    // A wall whose first cells are centred 25 mm beyond the front wheels' reach: grown by
    // 25 mm, the columns overlap the wheels by 25 mm, so the strict check refuses even
    // standing still, and backing off too (its first quarter is still 12 mm inside).
    block(&mut map, (0.275, 0.8), (-0.8, 0.8), 0.5);
    let map_ref = HeightMapRef::Metres(&map);
    let mut backward = Action::IDLE;
    backward.set(crate::action::Dim::MoveX, Step::Minus);
    assert_eq!(
        guard.check(map_ref, default_legs(), Action::IDLE),
        Err(Refusal::Collision)
    );
    assert_eq!(
        guard.check_no_deeper(map_ref, default_legs(), backward),
        Ok(())
    );
    assert_eq!(
        guard.check_no_deeper(map_ref, default_legs(), Action::IDLE),
        Ok(())
    );
    assert_eq!(
        guard.check_no_deeper(map_ref, default_legs(), forward()),
        Err(Refusal::Collision)
    );
    assert!(guard.allows(1, map_ref, default_legs(), backward));
    assert!(!guard.allows(0, map_ref, default_legs(), backward));
    assert!(!guard.allows(CollisionGuard::LEVELS, map_ref, default_legs(), backward));
}

#[test]
fn arrival_goes_first_only_where_the_guard_passes_it() {
    let guard = CollisionGuard::new(&Robot::WHEELLEG, DEFAULT_MARGIN_M);
    // The target 6 cm ahead: one step forward arrives. The policy wants to turn in place.
    let arrival = Arrival::new(
        nalgebra::Vector2::new(0.06, 0.0),
        0.05,
        &Robot::WHEELLEG.actions,
    );
    let mut logits = [0.0f32; DIMS * CHOICES];
    for head in 0..DIMS {
        logits[head * CHOICES + 1] = 2.0;
    }
    logits[2 * CHOICES + 2] = 3.0;
    let choose_on = |map: &[f32; HEIGHT_MAP_CELLS]| {
        guard.choose(
            &mut Decider::<4>::new(),
            ObservationKey(7),
            &logits,
            HeightMapRef::Metres(map),
            default_legs(),
            Some(&arrival),
        )
    };
    let checked = choose_on(&flat());
    assert!(arrival.reached_by(checked.action), "{checked:?}");
    assert_eq!(checked.action.move_x, Step::Plus);
    assert_eq!(checked.level, Some(0), "the guard's strict level passed it");
    // A wall just beyond the wheels: every arriving step is refused, so the policy's turn.
    let mut walled = flat();
    block(&mut walled, (0.31, 0.8), (-0.8, 0.8), 0.5);
    let checked = choose_on(&walled);
    assert!(!arrival.reached_by(checked.action), "{checked:?}");
    assert_eq!(checked.action.yaw, Step::Plus);
    assert_eq!(checked.level, Some(0));
}

#[test]
fn millimetres_and_metres_agree() {
    let guard = CollisionGuard::new(&Robot::WHEELLEG, DEFAULT_MARGIN_M);
    let mut map = flat();
    block(&mut map, (0.2, 0.4), (0.15, 0.4), 0.07);
    let mut map_mm = [0i16; HEIGHT_MAP_CELLS];
    for (mm, m) in map_mm.iter_mut().zip(map.iter()) {
        *mm = libm::roundf(m * 1000.0) as i16;
    }
    for index in 0..crate::action::COUNT {
        let action = Action::from_index(index).unwrap();
        assert_eq!(
            guard.check(HeightMapRef::Metres(&map), default_legs(), action),
            guard.check(HeightMapRef::Millimetres(&map_mm), default_legs(), action),
        );
    }
}

#[test]
fn unreachable_legs_are_refused() {
    let guard = CollisionGuard::new(&Robot::WHEELLEG, 0.0);
    let legs = LegConfig {
        clearance_m: WHEELLEG.clearance_range_m[1],
        track_m: WHEELLEG.default_track_m,
    };
    let mut up = Action::IDLE;
    up.set(crate::action::Dim::Clearance, Step::Plus);
    let map = flat();
    assert_eq!(
        guard.check(HeightMapRef::Metres(&map), legs, up),
        Err(Refusal::Unreachable)
    );
}

#[test]
fn bad_heights_and_margins_do_not_panic() {
    let guard = CollisionGuard::new(&Robot::WHEELLEG, f32::NAN);
    assert_eq!(guard.margin_m(), 0.0);
    let mut map = [f32::NAN; HEIGHT_MAP_CELLS];
    map[0] = f32::INFINITY;
    map[1] = -1.0;
    // Nothing known around the robot: no move is taken for a move over free ground.
    let verdict = guard.check(HeightMapRef::Metres(&map), default_legs(), forward());
    assert_eq!(verdict, Err(Refusal::Collision));
    let bad_legs = LegConfig {
        clearance_m: f32::NAN,
        track_m: 0.3,
    };
    assert_eq!(
        guard.check(HeightMapRef::Metres(&map), bad_legs, forward()),
        Err(Refusal::Unreachable)
    );
}

#[test]
fn segment_rect_distance_cases() {
    let (lo, hi) = ((0.0, 0.0), (1.0, 1.0));
    assert_eq!(segment_rect_distance_m((0.5, 0.5), (3.0, 3.0), lo, hi), 0.0);
    assert_eq!(
        segment_rect_distance_m((-1.0, 0.5), (2.0, 0.5), lo, hi),
        0.0
    );
    assert!((segment_rect_distance_m((2.0, -1.0), (2.0, 2.0), lo, hi) - 1.0).abs() < 1e-6);
    // A diagonal passing the corner (1, 1) at distance sqrt(2).
    let d = segment_rect_distance_m((1.0, 3.0), (3.0, 1.0), lo, hi);
    assert!((d - core::f32::consts::SQRT_2).abs() < 1e-6, "{d}");
}

/// The fine window gives the whole map's verdicts: every action, from several leg
/// configurations, among blocks scattered over the whole 1 cm map, most of them near the
/// window's edge (where a window one cell too small would be caught).
#[test]
fn fine_window_keeps_the_whole_maps_verdicts() {
    const SIDE: usize = 128;
    const CELL_M: f32 = 0.01;
    let guard = CollisionGuard::new(&Robot::WHEELLEG, DEFAULT_MARGIN_M);
    let bounds = guard.fine_window(SIDE, CELL_M);
    assert!(bounds.rows < SIDE && bounds.cols < SIDE, "{bounds:?}");
    assert!(bounds.cells() <= 5600, "{bounds:?}");
    let mut seed = 0x2545_f491_4f6c_dd1du64;
    let mut next = move |n: usize| {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        (seed % n as u64) as usize
    };
    let mut refused = 0;
    let mut checked = 0;
    for _case in 0..12 {
        let mut mm = [0i16; SIDE * SIDE];
        for _block in 0..6 {
            // Corners near the window's edge, rows or columns.
            let near = |first: usize, len: usize, pick: usize| match pick % 3 {
                0 => first.saturating_sub(4) + pick % 8,
                1 => (first + len).saturating_sub(4) + pick % 8,
                _ => pick % SIDE,
            };
            let r0 = near(bounds.first_row, bounds.rows, next(1000)).min(SIDE - 1);
            let c0 = near(bounds.first_col, bounds.cols, next(1000)).min(SIDE - 1);
            let (h, w) = (1 + next(30), 1 + next(30));
            let height = 20 + next(300) as i16;
            for row in r0..(r0 + h).min(SIDE) {
                for col in c0..(c0 + w).min(SIDE) {
                    mm[row * SIDE + col] = height;
                }
            }
        }
        let mut metres = [0.0f32; SIDE * SIDE];
        for (m, &h) in metres.iter_mut().zip(&mm) {
            *m = f32::from(h) * 1.0e-3;
        }
        let grid = HeightMapRef::Grid(GridMap::new(&metres, SIDE, CELL_M).unwrap());
        let mut bytes = [0u8; 2 * 5600];
        let mut len = 0;
        for row in bounds.rows() {
            for col in bounds.cols() {
                bytes[len..len + 2].copy_from_slice(&mm[row * SIDE + col].to_le_bytes());
                len += 2;
            }
        }
        let fine = FineWindow::new(&bytes[..len], bounds).unwrap();
        let window = HeightMapRef::Window(&fine);
        for legs in [
            default_legs(),
            LegConfig {
                clearance_m: 0.04,
                track_m: 0.56,
            },
            LegConfig {
                clearance_m: 0.24,
                track_m: 0.16,
            },
        ] {
            for index in 0..crate::action::COUNT {
                let action = Action::from_index(index).unwrap();
                let whole = guard.check(grid, legs, action);
                assert_eq!(
                    whole,
                    guard.check(window, legs, action),
                    "{action:?} {legs:?}"
                );
                assert_eq!(
                    guard.check_no_deeper(grid, legs, action),
                    guard.check_no_deeper(window, legs, action),
                    "{action:?} {legs:?}"
                );
                refused += usize::from(whole == Err(Refusal::Collision));
                checked += 1;
            }
        }
    }
    // Not a vacuous comparison: many actions meet a block.
    assert!(refused > checked / 20, "{refused} of {checked}");
}

#[test]
fn a_leg_or_part_skipped_as_apart_from_a_column_overlaps_it_nowhere() {
    use super::geometry::{across_m, Column, Parts};
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    // Skipped and kept legs, then parts of kept legs, and contacts among the kept parts.
    let (mut legs_apart, mut parts_apart, mut parts_near, mut touching) = (0, 0, 0, 0);
    for _ in 0..200 {
        let legs = LegConfig {
            clearance_m: rng.random_range(0.04..0.24),
            track_m: rng.random_range(0.16..0.56),
        };
        let Some(parts) = Parts::place(&WHEELLEG, legs) else {
            continue;
        };
        for _ in 0..500 {
            let column = Column {
                x_m: rng.random_range(-0.5..0.5),
                y_m: rng.random_range(-0.5..0.5),
                half_m: rng.random_range(0.0..0.03),
                height_m: rng.random_range(0.0..0.4),
            };
            for (leg, points) in parts.legs().iter().enumerate() {
                let [hip, knee, mount, wheel] = points;
                let dx_m = across_m(hip, &column);
                let links_apart = parts.links_are_apart(dx_m);
                let gaps = parts.wheel_gaps(wheel, &column);
                let each = [
                    (links_apart, parts.link_overlap_m(hip, knee, dx_m, &column)),
                    (
                        links_apart,
                        parts.link_overlap_m(knee, mount, dx_m, &column),
                    ),
                    (parts.wheel_is_apart(&gaps), parts.wheel_overlap_m(&gaps)),
                ];
                let whole_m = each.iter().map(|e| e.1).fold(f32::NEG_INFINITY, f32::max);
                if parts.leg_is_apart(leg, &column) {
                    legs_apart += 1;
                    assert!(whole_m < 0.0, "leg {leg} skipped at {whole_m} m");
                    continue;
                }
                for (part, (apart, overlap_m)) in each.into_iter().enumerate() {
                    if apart {
                        parts_apart += 1;
                        assert!(overlap_m < 0.0, "part {part} skipped at {overlap_m} m");
                    } else {
                        parts_near += 1;
                        touching += usize::from(overlap_m >= 0.0);
                    }
                }
                // What the check uses: the kept parts' deepest, exact where it is not negative.
                let kept_m = parts.leg_overlap_m(points, &column);
                assert!(kept_m == whole_m || (kept_m < 0.0 && whole_m < 0.0));
            }
        }
    }
    assert!(
        legs_apart > 1000 && parts_apart > 1000 && parts_near > 1000 && touching > 100,
        "{legs_apart} {parts_apart} {parts_near} {touching}"
    );
}

#[test]
fn an_unknown_cell_is_never_free_ground() {
    let guard = CollisionGuard::new(&Robot::WHEELLEG, DEFAULT_MARGIN_M);
    let mut backward = Action::IDLE;
    backward.set(crate::action::Dim::MoveX, Step::Minus);
    // Unknown cells where a_wall_just_ahead_refuses_forward_but_not_backward has its wall.
    let mut map = flat();
    block(&mut map, (0.31, 0.8), (-0.8, 0.8), f32::NAN);
    assert!(map.iter().any(|h| h.is_nan()));
    let metres = HeightMapRef::Metres(&map);
    assert_eq!(
        guard.check(metres, default_legs(), forward()),
        Err(Refusal::Collision)
    );
    assert_eq!(guard.check(metres, default_legs(), backward), Ok(()));
    // In millimetres, as the controller receives a map: the unknown cells are the tallest.
    let mm: [i16; HEIGHT_MAP_CELLS] = core::array::from_fn(|i| height_mm(map[i]));
    assert!(mm.contains(&UNKNOWN_HEIGHT_MM));
    let millimetres = HeightMapRef::Millimetres(&mm);
    assert_eq!(
        guard.check(millimetres, default_legs(), forward()),
        Err(Refusal::Collision)
    );
    assert_eq!(guard.check(millimetres, default_legs(), backward), Ok(()));
    assert_eq!(height_mm(0.1234), 123);
    assert_eq!(height_mm(-0.0006), -1);
    assert_eq!(height_mm(1.0e9), i16::MAX);
}
