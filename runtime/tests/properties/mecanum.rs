//! Mecanum base.

use super::*;

fn any_velocity() -> impl Strategy<Value = BaseVelocity> {
    (-2.0f32..2.0, -2.0f32..2.0, -4.0f32..4.0).prop_map(|(vx_mps, vy_mps, yaw_rate_radps)| {
        BaseVelocity {
            vx_mps,
            vy_mps,
            yaw_rate_radps,
        }
    })
}

fn close(a: f32, b: f32, scale: f32) -> bool {
    (a - b).abs() <= 1e-5 * scale.max(1.0)
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(4096))]

    /// Forward kinematics undoes inverse kinematics at every track the legs can hold.
    #[test]
    fn mecanum_forward_undoes_inverse(v in any_velocity(), track_m in 0.16f32..0.56) {
        let base = MecanumBase::new(&WHEELLEG, track_m).unwrap();
        let wheels = base.wheel_speeds(v).unwrap();
        let back = base.body_velocity(wheels).unwrap();
        prop_assert!(close(back.vx_mps, v.vx_mps, 2.0), "{v:?} -> {back:?}");
        prop_assert!(close(back.vy_mps, v.vy_mps, 2.0), "{v:?} -> {back:?}");
        prop_assert!(close(back.yaw_rate_radps, v.yaw_rate_radps, 4.0), "{v:?} -> {back:?}");
    }

    /// Odometry is the least-squares inverse: for any measured wheel speeds (slipping wheels
    /// included), the wheel speeds of the estimated velocity give the same estimate again, and
    /// the residual is orthogonal to every body motion (a slip does not bias the estimate).
    #[test]
    fn mecanum_odometry_is_a_projection(radps in prop::array::uniform4(-60.0f32..60.0),
                                        track_m in 0.16f32..0.56) {
        let base = MecanumBase::new(&WHEELLEG, track_m).unwrap();
        let measured = WheelSpeeds { radps };
        let v = base.body_velocity(measured).unwrap();
        let projected = base.wheel_speeds(v).unwrap();
        let again = base.body_velocity(projected).unwrap();
        prop_assert!(close(again.vx_mps, v.vx_mps, 3.0));
        prop_assert!(close(again.vy_mps, v.vy_mps, 3.0));
        prop_assert!(close(again.yaw_rate_radps, v.yaw_rate_radps, 10.0));
        let residual = WheelSpeeds {
            radps: core::array::from_fn(|i| measured.radps[i] - projected.radps[i]),
        };
        let bias = base.body_velocity(residual).unwrap();
        prop_assert!(bias.vx_mps.abs() < 1e-4 && bias.vy_mps.abs() < 1e-4
            && bias.yaw_rate_radps.abs() < 1e-3, "{bias:?}");
    }

    /// The speed scale keeps every wheel within its limit and scales no more than needed.
    #[test]
    fn speed_scale_respects_the_wheel_limit(v in any_velocity(), track_m in 0.16f32..0.56,
                                            limit in 1.0f32..60.0) {
        let base = MecanumBase::new(&WHEELLEG, track_m).unwrap();
        let s = base.speed_scale(v, limit).unwrap();
        prop_assert!(s > 0.0 && s <= 1.0);
        let scaled = BaseVelocity {
            vx_mps: s * v.vx_mps,
            vy_mps: s * v.vy_mps,
            yaw_rate_radps: s * v.yaw_rate_radps,
        };
        let peak = base.wheel_speeds(scaled).unwrap().max_abs_radps();
        prop_assert!(peak <= limit * (1.0 + 1e-5), "{peak} > {limit}");
        if s < 1.0 {
            prop_assert!(peak >= limit * (1.0 - 1e-4), "scaled down further than needed");
        }
    }

    /// Motor turns and joint angles convert both ways for every axis of the node map.
    #[test]
    fn node_map_conversions_round_trip(index in 0usize..16, angle in -6.0f32..6.0,
                                       offset in -5.0f32..5.0) {
        let axis = Axis::from_index(index).unwrap();
        let mut cal = NodeMap::NOMINAL.get(axis);
        cal.zero_offset_turns = offset;
        let back = cal.to_angle_rad(cal.to_motor_turns(angle));
        prop_assert!((back - angle).abs() < 1e-5 * 9.0 * 6.0, "{axis:?}: {angle} -> {back}");
        let speed = cal.to_speed_radps(cal.to_motor_turns_per_s(angle));
        prop_assert!((speed - angle).abs() < 1e-5);
    }
}
