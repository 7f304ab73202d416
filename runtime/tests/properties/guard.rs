//! Collision guard.

use super::*;
use wheelleg_runtime::robot::Robot;

fn any_height_map_mm() -> impl Strategy<Value = Vec<i16>> {
    // Mostly bare ground with a few obstacles, plus the extremes a broken sensor sends.
    proptest::collection::vec(
        prop_oneof![
            8 => Just(0i16),
            2 => 1i16..600,
            1 => any::<i16>(),
        ],
        wheelleg_runtime::observation::HEIGHT_MAP_CELLS,
    )
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(512))]

    /// On any height map, leg configuration, margin and action the guard answers without
    /// panicking, the strict check never passes what the lenient one refuses, and a guarded
    /// choice is always one of the 243 actions.
    #[test]
    fn the_guard_answers_anything(
        heights in any_height_map_mm(),
        clearance_m in any_f32(),
        track_m in any_f32(),
        margin_m in any_f32(),
        index in 0usize..wheelleg_runtime::action::COUNT,
    ) {
        use wheelleg_runtime::action::Action;
        use wheelleg_runtime::guard::{CollisionGuard, HeightMapRef};
        let guard = CollisionGuard::new(&Robot::WHEELLEG, margin_m);
        let map: &[i16; wheelleg_runtime::observation::HEIGHT_MAP_CELLS] =
            heights.as_slice().try_into().unwrap();
        let legs = LegConfig { clearance_m, track_m };
        let action = Action::from_index(index).unwrap();
        let strict = guard.check(HeightMapRef::Millimetres(map), legs, action);
        let lenient = guard.check_no_deeper(HeightMapRef::Millimetres(map), legs, action);
        if lenient.is_err() {
            prop_assert!(strict.is_err());
        }
        let mut decider: wheelleg_runtime::decision::Decider<4> =
            wheelleg_runtime::decision::Decider::new();
        let logits = [0.0f32; 15];
        let checked = decider.choose_checked(
            wheelleg_runtime::decision::ObservationKey(1),
            &logits,
            CollisionGuard::LEVELS,
            |level, a| guard.allows(level, HeightMapRef::Millimetres(map), legs, a),
        );
        prop_assert!(checked.action.index() < wheelleg_runtime::action::COUNT);
    }
}
