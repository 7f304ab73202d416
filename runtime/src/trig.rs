//! Sine and cosine for the runtime's angles, bit for bit `libm`'s `sinf` and `cosf` within
//! ±9π/4, `libm`'s `hypotf` and `acosf` on the FPU's square root, floor and ceiling, and isometries built on them.
//!
//! Why not `libm`'s own: beyond ±9π/4 `libm` reduces the argument with `rem_pio2f`, whose
//! large-argument path (Payne-Hanek, in double precision) is some 2.8 KB of a microcontroller's
//! flash; and nalgebra's `Isometry2::new` calls `sincosf`, another 0.5 KB beside `sinf` and
//! `cosf`. The runtime's angles (joint angles, headings, a step's turn, the motion profile's
//! phase) stay within ±9π/4, where these are musl's (and so `libm`'s) code paths unchanged:
//! the same results on the host and the controller as before. Beyond it the argument is
//! first reduced by whole turns (Cody-Waite in single precision: within about 1e-6 of `libm`
//! up to some 10^4 radians).

// musl's constants are kept as musl writes them (they round to the same floats), and `x - x`
// is musl's NaN for an infinite or NaN argument.
#![allow(clippy::excessive_precision, clippy::eq_op)]

use nalgebra::{Isometry2, Translation2, UnitComplex};

/// π/2 and its multiples rounded to double precision (musl's constants).
const PIO2_1: f64 = core::f64::consts::FRAC_PI_2;
const PIO2_2: f64 = 2.0 * core::f64::consts::FRAC_PI_2;
const PIO2_3: f64 = 3.0 * core::f64::consts::FRAC_PI_2;
const PIO2_4: f64 = 4.0 * core::f64::consts::FRAC_PI_2;

/// musl's `__sindf`: sine on [-π/4, π/4] in double precision.
fn k_sin(x: f64) -> f32 {
    const S1: f64 = -0.166_666_666_416_265_235_595;
    const S2: f64 = 0.008_333_329_385_889_463_175_6;
    const S3: f64 = -0.000_198_393_348_360_966_317_347;
    const S4: f64 = 0.000_002_718_311_493_989_821_906_4;
    let z = x * x;
    let w = z * z;
    let r = S3 + z * S4;
    let s = z * x;
    ((x + s * (S1 + z * S2)) + s * w * r) as f32
}

/// musl's `__cosdf`: cosine on [-π/4, π/4] in double precision.
fn k_cos(x: f64) -> f32 {
    const C0: f64 = -0.499_999_997_251_031_003_120;
    const C1: f64 = 0.041_666_623_323_739_063_189_4;
    const C2: f64 = -0.001_388_676_377_460_992_946_92;
    const C3: f64 = 0.000_024_390_448_796_277_409_065_4;
    let z = x * x;
    let w = z * z;
    let r = C2 + z * C3;
    (((1.0 + z * C0) + w * C1) + (w * z) * r) as f32
}

/// `x` in whole turns off ±9π/4 brought within them (identity within).
fn within_turns(x: f32) -> f32 {
    // musl's bound of its last direct interval, about 9π/4.
    if x.to_bits() & 0x7fff_ffff <= 0x40e2_31d5 {
        return x;
    }
    // Cody-Waite in single precision: 2π as a head exact in 12 bits and its tail, so that
    // `turns * TAU_HI` is exact for the turns of |x| up to some 10^4.
    const TAU_HI: f32 = 6.281_25;
    const TAU_LO: f32 = 0.001_935_307_2;
    let turns = libm::roundf(x * (1.0 / core::f32::consts::TAU));
    (x - turns * TAU_HI) - turns * TAU_LO
}

/// `floor(x)`, as `libm::floorf` for every finite `x` but the sign of a zero result.
pub fn floor(x: f32) -> f32 {
    if x.is_nan() || x.abs() >= 8_388_608.0 {
        return x;
    }
    let t = x as i32 as f32;
    if t > x {
        t - 1.0
    } else {
        t
    }
}

/// `ceil(x)`, as `libm::ceilf` for every finite `x` but the sign of a zero result.
pub fn ceil(x: f32) -> f32 {
    -floor(-x)
}

/// The sine of `x` (`libm::sinf` within ±9π/4; NaN for infinities and NaN).
pub fn sin(x: f32) -> f32 {
    if !x.is_finite() {
        return x - x;
    }
    let x = within_turns(x);
    let x64 = f64::from(x);
    let ix = x.to_bits() & 0x7fff_ffff;
    let sign = x.is_sign_negative();
    if ix <= 0x3f49_0fda {
        if ix < 0x3980_0000 {
            return x;
        }
        return k_sin(x64);
    }
    if ix <= 0x407b_53d1 {
        if ix <= 0x4016_cbe3 {
            return if sign {
                -k_cos(x64 + PIO2_1)
            } else {
                k_cos(x64 - PIO2_1)
            };
        }
        return k_sin(if sign {
            -(x64 + PIO2_2)
        } else {
            -(x64 - PIO2_2)
        });
    }
    if ix <= 0x40af_eddf {
        return if sign {
            k_cos(x64 + PIO2_3)
        } else {
            -k_cos(x64 - PIO2_3)
        };
    }
    k_sin(if sign { x64 + PIO2_4 } else { x64 - PIO2_4 })
}

/// The cosine of `x` (`libm::cosf` within ±9π/4; NaN for infinities and NaN).
pub fn cos(x: f32) -> f32 {
    if !x.is_finite() {
        return x - x;
    }
    let x = within_turns(x);
    let x64 = f64::from(x);
    let ix = x.to_bits() & 0x7fff_ffff;
    let sign = x.is_sign_negative();
    if ix <= 0x3f49_0fda {
        if ix < 0x3980_0000 {
            return 1.0;
        }
        return k_cos(x64);
    }
    if ix <= 0x407b_53d1 {
        if ix > 0x4016_cbe3 {
            return -k_cos(if sign { x64 + PIO2_2 } else { x64 - PIO2_2 });
        }
        return if sign {
            k_sin(x64 + PIO2_1)
        } else {
            k_sin(PIO2_1 - x64)
        };
    }
    if ix > 0x40af_eddf {
        return k_cos(if sign { x64 + PIO2_4 } else { x64 - PIO2_4 });
    }
    if sign {
        k_sin(-x64 - PIO2_3)
    } else {
        k_sin(x64 - PIO2_3)
    }
}

/// The square root, correctly rounded: the FPU's `VSQRT.F32` on a Cortex-M4F (musl's
/// software square root and its table are half a kilobyte of flash there), `libm::sqrtf`
/// elsewhere. Both are IEEE 754's correctly rounded result, so they agree bit for bit.
#[cfg(all(target_arch = "arm", target_feature = "fpregs"))]
#[allow(unsafe_code)]
fn sqrt(x: f32) -> f32 {
    // SAFETY: an AAPCS-VFP function of one `f32` in `s0` to one in `s0`, touching nothing else.
    unsafe { wheelleg_vsqrt_f32(x) }
}

// `VSQRT.F32` as a function of the hard-float ABI (argument and result in `s0`): inline
// assembly names the FPU's registers only with the `vfp2` feature, which this target (a
// Cortex-M4F's single-precision FPU) has but does not declare, and which is unstable.
#[cfg(all(target_arch = "arm", target_feature = "fpregs"))]
#[allow(unsafe_code)]
mod vsqrt {
    core::arch::global_asm!(
        ".syntax unified",
        ".thumb",
        ".section .text.wheelleg_vsqrt_f32,\"ax\",%progbits",
        ".global wheelleg_vsqrt_f32",
        ".type wheelleg_vsqrt_f32,%function",
        ".p2align 1",
        ".thumb_func",
        ".fpu fpv4-sp-d16",
        "wheelleg_vsqrt_f32:",
        "    vsqrt.f32 s0, s0",
        "    bx lr",
        ".size wheelleg_vsqrt_f32, . - wheelleg_vsqrt_f32",
    );
}

#[cfg(all(target_arch = "arm", target_feature = "fpregs"))]
#[allow(unsafe_code)]
extern "C" {
    fn wheelleg_vsqrt_f32(x: f32) -> f32;
}

#[cfg(not(all(target_arch = "arm", target_feature = "fpregs")))]
fn sqrt(x: f32) -> f32 {
    libm::sqrtf(x)
}

/// `sqrt(x² + y²)` without undue overflow: musl's `hypotf` (and so `libm::hypotf`, bit for
/// bit), on this module's square root.
pub fn hypot(x: f32, y: f32) -> f32 {
    let x1p90 = f32::from_bits(0x6c80_0000);
    let x1p_90 = f32::from_bits(0x1280_0000);
    let mut uxi = x.to_bits() & (u32::MAX >> 1);
    let mut uyi = y.to_bits() & (u32::MAX >> 1);
    if uxi < uyi {
        core::mem::swap(&mut uxi, &mut uyi);
    }
    let (mut x, mut y) = (f32::from_bits(uxi), f32::from_bits(uyi));
    if uyi == 0xff << 23 {
        return y;
    }
    if uxi >= 0xff << 23 || uyi == 0 || uxi - uyi >= 25 << 23 {
        return x + y;
    }
    let mut z = 1.0;
    if uxi >= (0x7f + 60) << 23 {
        z = x1p90;
        x *= x1p_90;
        y *= x1p_90;
    } else if uyi < (0x7f - 60) << 23 {
        z = x1p_90;
        x *= x1p90;
        y *= x1p90;
    }
    z * sqrt((f64::from(x) * f64::from(x) + f64::from(y) * f64::from(y)) as f32)
}

/// The arccosine of `x` in [0, π] (NaN beyond ±1): musl's `acosf` (and so `libm::acosf`,
/// bit for bit), on this module's square root.
pub fn acos(x: f32) -> f32 {
    const PIO2_HI: f32 = 1.570_796_251_3;
    const PIO2_LO: f32 = 7.549_789_415_9e-8;
    let r = |z: f32| {
        let p = z * (1.666_658_669_7e-1 + z * (-4.274_342_209_1e-2 + z * -8.656_363_003_0e-3));
        p / (1.0 + z * -7.066_296_339_0e-1)
    };
    let x1p_120 = f32::from_bits(0x0380_0000);
    let hx = x.to_bits();
    let ix = hx & 0x7fff_ffff;
    if ix >= 0x3f80_0000 {
        if ix == 0x3f80_0000 {
            if (hx >> 31) != 0 {
                return 2.0 * PIO2_HI + x1p_120;
            }
            return 0.0;
        }
        return 0.0 / (x - x);
    }
    if ix < 0x3f00_0000 {
        if ix <= 0x3280_0000 {
            return PIO2_HI + x1p_120;
        }
        return PIO2_HI - (x - (PIO2_LO - x * r(x * x)));
    }
    if (hx >> 31) != 0 {
        let z = (1.0 + x) * 0.5;
        let s = sqrt(z);
        let w = r(z) * s - PIO2_LO;
        return 2.0 * (PIO2_HI - (s + w));
    }
    let z = (1.0 - x) * 0.5;
    let s = sqrt(z);
    let df = f32::from_bits(s.to_bits() & 0xffff_f000);
    let c = (z - df * df) / (s + df);
    let w = r(z) * s + c;
    2.0 * (df + w)
}

/// The pose at `(x_m, y_m)` turned by `angle_rad`: nalgebra's `Isometry2::new` with this
/// module's sine and cosine.
pub fn isometry(x_m: f32, y_m: f32, angle_rad: f32) -> Isometry2<f32> {
    Isometry2::from_parts(
        Translation2::new(x_m, y_m),
        UnitComplex::from_cos_sin_unchecked(cos(angle_rad), sin(angle_rad)),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_libm_bit_for_bit_within_nine_quarter_turns() {
        let limit = 9.0 * core::f32::consts::FRAC_PI_4;
        let mut x = -limit;
        let mut checked = 0u32;
        while x <= limit {
            assert_eq!(sin(x).to_bits(), libm::sinf(x).to_bits(), "sin({x})");
            assert_eq!(cos(x).to_bits(), libm::cosf(x).to_bits(), "cos({x})");
            x = f32::from_bits(if x < 0.0 {
                x.to_bits() - 997
            } else {
                x.to_bits() + 997
            });
            if x.abs() < 1e-6 {
                x = -x.abs();
                x += 2e-6;
            }
            checked += 1;
        }
        assert!(checked > 100_000, "{checked}");
        for x in [
            0.0f32,
            -0.0,
            1e-30,
            -1e-30,
            f32::MIN_POSITIVE,
            limit,
            -limit,
        ] {
            assert_eq!(sin(x).to_bits(), libm::sinf(x).to_bits(), "sin({x})");
            assert_eq!(cos(x).to_bits(), libm::cosf(x).to_bits(), "cos({x})");
        }
    }

    #[test]
    fn reduces_large_arguments_by_whole_turns() {
        for x in [10.0f32, -10.0, 100.0, -1234.5, 5.0e3] {
            assert!((sin(x) - libm::sinf(x)).abs() < 1e-4, "sin({x})");
            assert!((cos(x) - libm::cosf(x)).abs() < 1e-4, "cos({x})");
        }
        assert!(sin(f32::INFINITY).is_nan() && cos(f32::NAN).is_nan());
    }

    #[test]
    fn hypot_matches_libm_bit_for_bit() {
        let values = [
            0.0f32, -0.0, 1e-30, 3e-20, 0.01, 0.123, -0.5, 1.0, 2.5, -7.25, 1e20, 3e38,
        ];
        for &x in &values {
            for &y in &values {
                assert_eq!(
                    hypot(x, y).to_bits(),
                    libm::hypotf(x, y).to_bits(),
                    "{x} {y}"
                );
            }
        }
        let mut state = 0x1234_5678u32;
        for _ in 0..100_000 {
            state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            let x = (state >> 8) as f32 * 1e-7 - 0.8;
            state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            let y = (state >> 8) as f32 * 1e-7 - 0.8;
            assert_eq!(
                hypot(x, y).to_bits(),
                libm::hypotf(x, y).to_bits(),
                "{x} {y}"
            );
        }
        assert!(hypot(f32::INFINITY, f32::NAN).is_infinite());
    }

    #[test]
    fn acos_matches_libm_bit_for_bit() {
        let mut x = -1.0f32;
        while x <= 1.0 {
            assert_eq!(acos(x).to_bits(), libm::acosf(x).to_bits(), "acos({x})");
            x += 1.0 / 65_536.0 + 1e-9;
        }
        for x in [
            -1.0f32,
            1.0,
            0.0,
            -0.0,
            1e-30,
            0.5,
            -0.5,
            0.499_999_97,
            1.5,
            f32::NAN,
        ] {
            assert_eq!(acos(x).to_bits(), libm::acosf(x).to_bits(), "acos({x})");
        }
    }

    #[test]
    fn floor_and_ceil_match_libm() {
        for x in [
            0.0f32,
            0.5,
            -0.5,
            1.0,
            -1.0,
            1.5,
            -1.5,
            2.999_999_8,
            -3.000_000_2,
            1e7,
            -1e7,
            3e9,
            123.456,
        ] {
            assert_eq!(floor(x), libm::floorf(x), "floor({x})");
            assert_eq!(ceil(x), libm::ceilf(x), "ceil({x})");
        }
        assert!(floor(f32::NAN).is_nan() && ceil(f32::INFINITY).is_infinite());
    }

    #[test]
    fn isometry_is_nalgebras() {
        for (x, y, a) in [
            (0.1f32, -0.2f32, 0.3f32),
            (0.0, 0.0, -3.1),
            (1.0, 2.0, core::f32::consts::PI - 1e-3),
        ] {
            let ours = isometry(x, y, a);
            let theirs = Isometry2::new(nalgebra::Vector2::new(x, y), a);
            assert!((ours.rotation.angle() - theirs.rotation.angle()).abs() < 1e-6);
            assert_eq!(ours.translation, theirs.translation);
        }
    }
}
