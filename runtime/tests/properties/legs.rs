//! Leg kinematics.

use super::*;

/// Tolerance of IK then FK: f32 trigonometry on links of 8 and 16 cm loses about 1e-6 m; 5e-6
/// leaves room without hiding a wrong formula (a wrong sign moves the wheel by centimetres).
const LEG_TOLERANCE_M: f32 = 5e-6;

fn any_config_in_limits() -> impl Strategy<Value = LegConfig> {
    let [c0, c1] = WHEELLEG.clearance_range_m;
    let [t0, t1] = WHEELLEG.track_range_m;
    (c0..=c1, t0..=t1).prop_map(|(clearance_m, track_m)| LegConfig {
        clearance_m,
        track_m,
    })
}

proptest! {
    // About half the joint pairs land outside the command limits and are rejected.
    #![proptest_config(ProptestConfig { cases: 4096, max_global_rejects: 50_000,
                                        ..ProptestConfig::default() })]

    /// Every reachable configuration comes back from FK of its IK solution, with the wheel axle
    /// horizontal and the joints inside their ranges.
    #[test]
    fn ik_then_fk_returns_the_configuration(config in any_config_in_limits()) {
        if let Ok(joints) = WHEELLEG.leg_ik(config) {
            let back = WHEELLEG.config_from_joints(joints);
            prop_assert!((back.clearance_m - config.clearance_m).abs() < LEG_TOLERANCE_M,
                "{config:?} -> {joints:?} -> {back:?}");
            prop_assert!((back.track_m - config.track_m).abs() < LEG_TOLERANCE_M,
                "{config:?} -> {joints:?} -> {back:?}");
            let axle = joints.hip_rad + joints.knee_rad + joints.wheel_mount_rad;
            prop_assert!(axle.abs() < 1e-6);
            let [h0, h1] = WHEELLEG.hip_range_rad;
            let [k0, k1] = WHEELLEG.knee_range_rad;
            prop_assert!((h0 - 1e-5..=h1 + 1e-5).contains(&joints.hip_rad));
            prop_assert!((k0 - 1e-5..=k1 + 1e-5).contains(&joints.knee_rad));
        }
    }

    /// The reachable set is exactly the image of the joint ranges: any joint angles in range
    /// whose configuration lies in the command limits are found again by IK (IK is complete,
    /// not just sound). The knee is kept 0.05 rad off straight, where acos loses precision.
    #[test]
    fn fk_then_ik_returns_the_joints(hip in -1.2f32..1.5, knee in 0.05f32..2.8) {
        let joints = JointAngles { hip_rad: hip, knee_rad: knee, wheel_mount_rad: -(hip + knee) };
        let config = WHEELLEG.config_from_joints(joints);
        let [c0, c1] = WHEELLEG.clearance_range_m;
        let [t0, t1] = WHEELLEG.track_range_m;
        prop_assume!((c0..=c1).contains(&config.clearance_m) && (t0..=t1).contains(&config.track_m));
        let again = WHEELLEG.leg_ik(config);
        prop_assert!(again.is_ok(), "{joints:?} -> {config:?} -> {again:?}");
        let again = again.unwrap();
        prop_assert!((again.hip_rad - hip).abs() < 1e-3, "{joints:?} -> {again:?}");
        prop_assert!((again.knee_rad - knee).abs() < 1e-3, "{joints:?} -> {again:?}");
    }

    /// IK is total: any floats at all give finite angles or a reason, never NaN angles.
    #[test]
    fn ik_is_total(clearance_m in any_f32(), track_m in any_f32()) {
        match WHEELLEG.leg_ik(LegConfig { clearance_m, track_m }) {
            Ok(j) => prop_assert!(j.hip_rad.is_finite() && j.knee_rad.is_finite()
                && j.wheel_mount_rad.is_finite()),
            Err(IkError::NotFinite) => prop_assert!(!clearance_m.is_finite() || !track_m.is_finite()),
            Err(_) => {}
        }
    }
}
