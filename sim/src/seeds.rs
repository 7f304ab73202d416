//! The seeds by purpose: where each command draws its scenes (and its other random choices)
//! by default. Training and the sets that measure it never share a seed, so no figure is
//! measured on scenes a policy was trained or chosen on (docs/results.md, "Held-out sets and
//! rules").

/// Training: the curriculum's scenes and draws (`wheelleg train --seed`, `wheelleg generate`).
pub const TRAINING: u64 = 0;
/// The held-out sets every reported figure is measured on (`wheelleg eval`, `wheelleg demo`).
pub const HELD_OUT: u64 = 1_000_000;
/// The exporter's calibration scenes; `CALIBRATION + 1` its held-out int8/float agreement,
/// `CALIBRATION + 2` its quantization-aware fine-tuning rollouts (`wheelleg export`).
pub const CALIBRATION: u64 = 2_000_000;
/// The validation sets that choose between checkpoints and recipes.
pub const VALIDATION: u64 = 3_000_000;
/// Expert labels: round `r` of `wheelleg train label` draws its scenes from
/// `EXPERT_LABELS + r`.
pub const EXPERT_LABELS: u64 = 4_000_000;

/// The seeds that make measuring sets: scenes drawn from them must never be trained on.
pub const MEASURING: [u64; 5] = [
    HELD_OUT,
    CALIBRATION,
    CALIBRATION + 1,
    CALIBRATION + 2,
    VALIDATION,
];

/// The measuring set `seed` makes, if it makes one.
pub fn measuring_set(seed: u64) -> Option<&'static str> {
    match seed {
        HELD_OUT => Some("the held-out sets"),
        s if (CALIBRATION..CALIBRATION + 3).contains(&s) => Some("the exporter's calibration"),
        VALIDATION => Some("the validation sets"),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_measuring_seed_is_named_and_no_training_seed_is() {
        for seed in MEASURING {
            assert!(measuring_set(seed).is_some(), "{seed}");
        }
        for seed in [
            TRAINING,
            1,
            EXPERT_LABELS,
            EXPERT_LABELS + 1,
            CALIBRATION + 3,
        ] {
            assert_eq!(measuring_set(seed), None, "{seed}");
        }
    }
}
