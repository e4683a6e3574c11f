//! Sine, cosine and the exponential without library calls, for the hot loops of the focused
//! closed forms, where glibc's `sincos` and `exp` (called, not inlined, and with `errno`
//! wrappers) took nearly half the time. Both are fdlibm's algorithms: Cody–Waite reduction (by
//! `π/2` in four parts of 33 bits, by `ln 2` in two, from `__ieee754_rem_pio2` and
//! `__ieee754_exp`; each product with the reduction's integer is exact in range), then fdlibm's
//! minimax polynomials (`__kernel_sin`, `__kernel_cos`, and `exp`'s rational form). Rounding uses
//! the `1.5·2⁵²` shift and no fused multiply-add, so they inline on any x86-64. Within 2 ulp of
//! the standard library (tested: 1.04 for `sin_cos` up to `|x| = 2²⁰`, 1 for `exp`); outside
//! their ranges and for non-finite input they defer to the standard library.

// the coefficients as fdlibm publishes them, digits beyond a double's included
#![allow(clippy::excessive_precision)]

/// `π/2` as four parts of 33 significant bits.
const PIO2_1: f64 = 1.570_796_326_734_125_6;
const PIO2_2: f64 = 6.077_100_506_303_966e-11;
const PIO2_3: f64 = 2.022_266_248_711_166_5e-21;
const PIO2_3T: f64 = 8.478_427_660_368_9e-32;

/// Adding and subtracting this rounds a double below `2⁵¹` to the nearest integer.
const ROUND: f64 = 6_755_399_441_055_744.0;

/// fdlibm `__kernel_sin` coefficients on `[−π/4, π/4]`.
const S: [f64; 6] = [
    -1.666_666_666_666_663_2e-1,
    8.333_333_333_322_49e-3,
    -1.984_126_982_985_795e-4,
    2.755_731_370_707_006_8e-6,
    -2.505_076_025_340_686_3e-8,
    1.589_690_995_211_55e-10,
];

/// fdlibm `__kernel_cos` coefficients on `[−π/4, π/4]`.
const C: [f64; 6] = [
    4.166_666_666_666_660_2e-2,
    -1.388_888_888_887_411e-3,
    2.480_158_728_947_673e-5,
    -2.755_731_435_139_066_3e-7,
    2.087_572_321_298_175e-9,
    -1.135_964_755_778_819_5e-11,
];

/// Largest `|x|` reduced here (the products `n·PIO2_k` are exact up to this).
const REDUCE_MAX: f64 = 1_048_576.0;

/// `(sin x, cos x)`.
#[inline]
pub fn sin_cos(x: f64) -> (f64, f64) {
    // also sends NaN and ±∞ to the standard library
    if x.is_nan() || x.abs() > REDUCE_MAX {
        return x.sin_cos();
    }
    sin_cos_in_range(x)
}

/// [`sin_cos`] for `|x| ≤ 2²⁰` without a branch (the quadrant by selects), so loops over it
/// vectorise; meaningless outside that range.
#[inline(always)]
pub fn sin_cos_in_range(x: f64) -> (f64, f64) {
    let shifted = x * std::f64::consts::FRAC_2_PI + ROUND;
    let n = shifted - ROUND;
    // the quadrant n mod 4 sits in the low bits of the shifted sum
    let quadrant = shifted.to_bits() & 3;
    let r = (((x - n * PIO2_1) - n * PIO2_2) - n * PIO2_3) - n * PIO2_3T;
    let z = r * r;
    let sin_poly = S[0] + z * (S[1] + z * (S[2] + z * (S[3] + z * (S[4] + z * S[5]))));
    let sin = r + r * z * sin_poly;
    let cos_poly = z * (C[0] + z * (C[1] + z * (C[2] + z * (C[3] + z * (C[4] + z * C[5])))));
    // 1 − z/2 + z²·p, with the rounding of 1 − z/2 carried (fdlibm's form)
    let hz = 0.5 * z;
    let w = 1.0 - hz;
    let cos = w + (((1.0 - w) - hz) + z * cos_poly);
    // quadrants 0‥3: (s, c), (c, −s), (−s, −c), (−c, s)
    let odd = quadrant & 1 == 1;
    let sign = if quadrant & 2 == 2 { -1.0 } else { 1.0 };
    let (a, b) = if odd { (cos, -sin) } else { (sin, cos) };
    (a * sign, b * sign)
}

/// `ln 2` as a 32-bit head and the rest; `1/ln 2`.
const LN2_HI: f64 = 6.931_471_803_691_238e-1;
const LN2_LO: f64 = 1.908_214_929_270_587_7e-10;
const INV_LN2: f64 = std::f64::consts::LOG2_E;

/// fdlibm `__ieee754_exp` coefficients of `R(r²)`.
const P: [f64; 5] = [
    1.666_666_666_666_660_2e-1,
    -2.777_777_777_701_559_3e-3,
    6.613_756_321_437_934e-5,
    -1.653_390_220_546_525_2e-6,
    4.138_136_797_057_238_5e-8,
];

/// `e^x`.
#[inline]
pub fn exp(x: f64) -> f64 {
    // the scale 2^k stays a normal double; also sends NaN and ±∞ to the standard library
    if x.is_nan() || x.abs() > 708.0 {
        return x.exp();
    }
    exp_in_range(x)
}

/// [`exp`] for `|x| ≤ 708` without a branch, so loops over it vectorise; meaningless outside
/// that range.
#[inline(always)]
pub fn exp_in_range(x: f64) -> f64 {
    let shifted = x * INV_LN2 + ROUND;
    let k = shifted - ROUND;
    let hi = x - k * LN2_HI;
    let lo = k * LN2_LO;
    let r = hi - lo;
    let t = r * r;
    let c = r - t * (P[0] + t * (P[1] + t * (P[2] + t * (P[3] + t * P[4]))));
    let y = 1.0 - ((lo - (r * c) / (2.0 - c)) - hi);
    // 2^k (|k| ≤ 1022) from its exponent bits; k sits in the low bits of the shifted sum
    let k_bits = shifted.to_bits().wrapping_sub(ROUND.to_bits());
    y * f64::from_bits(k_bits.wrapping_add(1023) << 52)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Units in the last place of `want` between `got` and `want` (absolute near zero: an ulp of
    /// 1 for values below `2⁻⁵³` of it would be meaningless).
    fn ulps(got: f64, want: f64) -> f64 {
        (got - want).abs() / (want.abs().max(1e-3) * f64::EPSILON)
    }

    /// Against the standard library over random angles up to 10, 10³ and 2²⁰ in size, near
    /// multiples of π/2 (where the reduction cancels) and at the edges; beyond 2²⁰ and for
    /// non-finite input the standard library's own values.
    #[test]
    fn matches_the_standard_library() {
        let mut rng = crate::math::stream_rng(1, 0);
        let mut worst = 0.0f64;
        for scale in [10.0, 1e3, REDUCE_MAX] {
            for _ in 0..200_000 {
                let x = scale * (2.0 * crate::math::uniform(&mut rng) - 1.0);
                let (s, c) = sin_cos(x);
                worst = worst.max(ulps(s, x.sin())).max(ulps(c, x.cos()));
            }
        }
        for k in -1000..1000 {
            for d in [-1e-9, -1e-15, 0.0, 1e-15, 1e-9] {
                let x = k as f64 * std::f64::consts::FRAC_PI_2 + d;
                let (s, c) = sin_cos(x);
                worst = worst.max(ulps(s, x.sin())).max(ulps(c, x.cos()));
            }
        }
        eprintln!("worst {worst:.2} ulp");
        assert!(worst <= 2.0, "worst {worst} ulp");
        for x in [0.0, -0.0, f64::MIN_POSITIVE, REDUCE_MAX, -REDUCE_MAX] {
            let (s, c) = sin_cos(x);
            assert!(ulps(s, x.sin()) <= 2.0 && ulps(c, x.cos()) <= 2.0, "{x}");
        }
        for x in [
            2.0 * REDUCE_MAX,
            1e300,
            f64::INFINITY,
            f64::NAN,
            f64::NEG_INFINITY,
        ] {
            let (s, c) = sin_cos(x);
            let (ws, wc) = x.sin_cos();
            assert!(
                s.to_bits() == ws.to_bits() || (s.is_nan() && ws.is_nan()),
                "{x}"
            );
            assert!(
                c.to_bits() == wc.to_bits() || (c.is_nan() && wc.is_nan()),
                "{x}"
            );
        }
    }

    /// Against the standard library over random arguments up to 1, 30 and 708 in size, at the
    /// integers and the edges; beyond ±708 and for non-finite input the standard library's own.
    #[test]
    fn exp_matches_the_standard_library() {
        let mut rng = crate::math::stream_rng(2, 0);
        let mut worst = 0.0f64;
        let mut check = |x: f64| {
            let (got, want) = (exp(x), x.exp());
            worst = worst.max((got - want).abs() / (want * f64::EPSILON));
        };
        for scale in [1.0, 30.0, 708.0] {
            for _ in 0..200_000 {
                check(scale * (2.0 * crate::math::uniform(&mut rng) - 1.0));
            }
        }
        for k in -708..=708 {
            check(k as f64);
        }
        for x in [0.0, -0.0, 1e-300, -1e-300, 708.0, -708.0] {
            check(x);
        }
        eprintln!("worst {worst:.2} ulp");
        assert!(worst <= 2.0, "worst {worst} ulp");
        for x in [
            709.0,
            -709.0,
            -800.0,
            1e300,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NAN,
        ] {
            let (got, want) = (exp(x), x.exp());
            assert!(
                got.to_bits() == want.to_bits() || (got.is_nan() && want.is_nan()),
                "{x}"
            );
        }
    }
}
