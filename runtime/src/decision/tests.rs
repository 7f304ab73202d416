use super::*;
use crate::action::Step;

const A: ObservationKey = ObservationKey(1);
const B: ObservationKey = ObservationKey(2);

fn argmax_per_head(logits: &[f32; DIMS * CHOICES]) -> Action {
    let mut indices = [0usize; DIMS];
    for (h, index) in indices.iter_mut().enumerate() {
        for c in 1..CHOICES {
            if logits[h * CHOICES + c] > logits[h * CHOICES + *index] {
                *index = c;
            }
        }
    }
    Action::from_head_indices(indices).unwrap()
}

/// Move x: forward clearly best, then idle; other heads: idle clearly best.
pub(crate) fn forward_logits() -> [f32; DIMS * CHOICES] {
    let mut logits = [0.0f32; DIMS * CHOICES];
    logits[0] = -5.0;
    logits[1] = 1.0;
    logits[2] = 2.0;
    for h in 1..DIMS {
        logits[h * CHOICES + 1] = 3.0;
    }
    logits
}

#[test]
fn at_a_fresh_observation_it_is_the_per_head_argmax() {
    let logits = [
        0.1, 0.5, 0.2, 1.0, -1.0, 0.0, 0.3, 0.3, 0.1, -2.0, -1.0, -3.0, 0.0, 0.0, 0.0,
    ];
    assert_eq!(
        Decider::<4>::new().choose(A, &logits),
        argmax_per_head(&logits)
    );
}

#[test]
fn a_repeated_observation_gets_the_next_most_probable_action() {
    let logits = forward_logits();
    let mut decider = Decider::<4>::new();
    let first = decider.choose(A, &logits);
    assert_eq!(first.move_x, Step::Plus);
    // Refused: the robot sees the same observation again.
    let second = decider.choose(A, &logits);
    // Next best: keep every head at its best but switch move x to idle (loses 1.0), rather
    // than any other head (loses at least 3.0).
    assert_eq!(second, Action::IDLE);
    assert!(decider.was_taken(A, first) && decider.was_taken(A, Action::IDLE));
    assert_eq!(decider.taken_count(A), 2);
    // Elsewhere the best action is fresh again...
    assert_eq!(decider.choose(B, &logits), first);
    // ...and coming back to A (a cycle A -> B -> A) does not repeat what A already did.
    let third = decider.choose(A, &logits);
    assert_ne!(third, first);
    assert_ne!(third, second);
    assert_eq!(decider.taken_count(A), 3);
    assert_eq!(decider.remembered(), 2);
}

#[test]
fn an_action_remembered_as_taken_is_passed_over_as_a_chosen_one_is() {
    let logits = forward_logits();
    let mut chosen = Decider::<2>::new();
    let first = chosen.choose(A, &logits);
    let mut remembered = Decider::<2>::new();
    remembered.remember_taken(A, first);
    assert!(remembered.was_taken(A, first));
    assert_eq!(remembered.taken_count(A), 1);
    assert_eq!(remembered, chosen);
    assert_eq!(remembered.choose(A, &logits), chosen.choose(A, &logits));
    // New observations take slots, the oldest evicted, as choosing does.
    for key in [B, ObservationKey(3)] {
        remembered.remember_taken(key, first);
        chosen.choose(key, &logits);
    }
    assert_eq!(remembered, chosen);
    assert!(!remembered.was_taken(A, first));
}

#[test]
fn the_oldest_observation_is_forgotten_first() {
    let logits = forward_logits();
    let mut decider = Decider::<2>::new();
    let best = decider.choose(A, &logits);
    decider.choose(B, &logits);
    decider.choose(ObservationKey(3), &logits); // evicts A
    assert_eq!(decider.remembered(), 2);
    assert!(!decider.was_taken(A, best));
    assert!(decider.was_taken(B, best));
    assert_eq!(decider.choose(A, &logits), best, "A is fresh again");
    decider.reset();
    assert_eq!(decider.remembered(), 0);
    // No memory at all is the plain most probable action, every time.
    let mut none = Decider::<0>::new();
    assert_eq!(none.choose(A, &logits), best);
    assert_eq!(none.choose(A, &logits), best);
}

#[test]
fn taking_everything_starts_over_instead_of_running_dry() {
    let logits = [0i16; DIMS * CHOICES];
    let mut decider = Decider::<1>::new();
    let mut seen = [false; COUNT];
    for _ in 0..COUNT {
        let action = decider.choose(A, &logits);
        assert!(!seen[action.index()], "an action was chosen twice");
        seen[action.index()] = true;
    }
    assert_eq!(decider.taken_count(A), COUNT);
    assert_eq!(
        decider.choose(A, &logits),
        Action::from_index(0).unwrap(),
        "the full set starts over"
    );
    assert_eq!(decider.taken_count(A), 1);
}

#[test]
fn a_check_skips_refused_actions_without_remembering_them() {
    let mut decider: Decider = Decider::new();
    let logits = forward_logits();
    let forward = argmax_per_head(&logits);
    let mut asked = 0;
    let checked = decider.choose_checked(A, &logits, 1, |_, action| {
        asked += 1;
        action != forward
    });
    assert_eq!(checked.level, Some(0));
    assert_eq!(checked.checks, 2);
    assert_eq!(asked, 2);
    assert_ne!(checked.action, forward);
    // The refused action was not taken, so without the check it is still the first choice.
    assert!(!decider.was_taken(A, forward));
    assert!(decider.was_taken(A, checked.action));
    assert_eq!(decider.choose(A, &logits), forward);
}

#[test]
fn a_lenient_level_is_asked_only_when_the_strict_one_refuses_everything() {
    let mut decider: Decider = Decider::new();
    let logits = forward_logits();
    let forward = argmax_per_head(&logits);
    // Level 0 refuses everything; level 1 refuses only the forward move.
    let checked = decider.choose_checked(A, &logits, 2, |level, action| {
        level == 1 && action != forward
    });
    assert_eq!(checked.level, Some(1));
    assert_eq!(checked.checks, COUNT + 2);
    assert_ne!(checked.action, forward);
}

#[test]
fn a_check_that_refuses_everything_falls_back_to_the_plain_choice() {
    let mut decider: Decider = Decider::new();
    let logits = forward_logits();
    let checked = decider.choose_checked(A, &logits, 2, |_, _| false);
    assert_eq!(checked.level, None);
    assert_eq!(checked.checks, 2 * COUNT);
    assert_eq!(checked.action, argmax_per_head(&logits));
    assert_eq!(decider.taken_count(A), 1);
}

#[test]
fn a_decision_out_of_time_is_abandoned_and_remembers_nothing() {
    let mut decider: Decider = Decider::new();
    let logits = forward_logits();
    // Time runs out after three refused candidates.
    let mut budget = 3;
    let abandoned = decider.choose_checked_in_time(A, &logits, 2, |_, _| {
        if budget == 0 {
            return None;
        }
        budget -= 1;
        Some(false)
    });
    assert_eq!(abandoned, None);
    assert_eq!(decider.taken_count(A), 0);
    // Decided again in time, the observation meets the same first candidate as a fresh one.
    let mut fresh: Decider = Decider::new();
    assert_eq!(decider.choose(A, &logits), fresh.choose(A, &logits));
}

#[test]
fn the_default_memory_is_about_five_kilobytes() {
    // 128 observations x (8-byte key + 32-byte set) + two counters: the 5 KB the docs state.
    assert!(core::mem::size_of::<Decider>() <= 128 * 40 + 16);
}

#[test]
fn nan_logits_never_panic_and_never_win() {
    let mut logits = [0.0f32; DIMS * CHOICES];
    logits[0] = f32::NAN;
    let action = Decider::<1>::new().choose(A, &logits);
    assert_ne!(action.move_x, Step::Minus);
    let all_nan = [f32::NAN; DIMS * CHOICES];
    assert_eq!(
        Decider::<1>::new().choose(A, &all_nan),
        Action::from_index(0).unwrap()
    );
}

#[test]
fn keys_tell_observations_apart_and_float_and_integer_inputs_agree() {
    let height_mm = [0i16, 150, -3, 42];
    let state_mm = [80i32, 460, -1200, 35];
    let key = ObservationKey::of_mm(&height_mm, &state_mm);
    let height_m = [0.0f32, 0.15, -0.003, 0.0421];
    let state_m = [0.08f32, 0.46, -1.2, 0.0349];
    assert_eq!(ObservationKey::of_metres(&height_m, &state_m), key);
    let mut moved = state_mm;
    moved[2] += 1;
    assert_ne!(ObservationKey::of_mm(&height_mm, &moved), key);
    let mut lifted = height_mm;
    lifted[3] = 43;
    assert_ne!(ObservationKey::of_mm(&lifted, &state_mm), key);
    // Absurd inputs saturate instead of wrapping or panicking.
    let _ = ObservationKey::of_metres(&[f32::NAN, 1.0e9], &[f32::INFINITY]);
}
