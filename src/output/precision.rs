//! The precision numbers are written with in the JSON outputs: what their readers can
//! use, not the 17 digits of an f64, which were most of a pose message's bytes.

/// Decimals of metres and metres per second: millimetres.
pub const METRE_DECIMALS: i32 = 3;
/// Decimals of a quaternion's components: 1e-6, about 1e-4° of rotation.
pub const QUATERNION_DECIMALS: i32 = 6;
/// Significant digits of a variance or covariance.
pub const COVARIANCE_DIGITS: usize = 4;
/// Decimals of latitude and longitude in degrees: 1e-8° is about a millimetre.
pub const DEGREE_DECIMALS: i32 = 8;

/// `x` to `d` decimals. Numbers too large to have any (and NaN, infinities) as they are.
pub fn decimals(x: f64, d: i32) -> f64 {
    if !x.is_finite() || x.abs() >= 1e15 {
        return x;
    }
    let m = 10f64.powi(d);
    // A power of ten up to 1e22 is exact, so the quotient is the double nearest the
    // rounded decimal, which serde_json then prints in its short form; `+ 0.0` makes a
    // rounded -0.0004 "0.0", not "-0.0".
    (x * m).round() / m + 0.0
}

/// `x` to `digits` significant digits (at least one).
pub fn significant(x: f64, digits: usize) -> f64 {
    if x == 0.0 || !x.is_finite() {
        return x;
    }
    // Through the decimal text: exact at any magnitude, where powers of ten beyond
    // 1e22 are not.
    format!("{:.*e}", digits.max(1) - 1, x).parse().unwrap_or(x)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn decimals_round_to_the_nearest_and_print_short() {
        assert_eq!(decimals(1.234_567_890_123, 3), 1.235);
        assert_eq!(
            serde_json::to_string(&decimals(-0.000_4, 3)).expect("json"),
            "0.0"
        );
        assert_eq!(decimals(47.123_456_789_012, 8), 47.123_456_79);
        assert_eq!(
            serde_json::to_string(&decimals(0.1 + 0.2, 3)).expect("json"),
            "0.3"
        );
        assert_eq!(decimals(1e300, 3), 1e300);
        assert!(decimals(f64::NAN, 3).is_nan());
    }

    #[test]
    fn significant_keeps_digits_at_every_magnitude() {
        assert_eq!(significant(0.012_345_678, 4), 0.012_35);
        assert_eq!(significant(-123_456.7, 4), -123_500.0);
        assert_eq!(significant(9.999_9e-27, 4), 1e-26);
        assert_eq!(
            serde_json::to_string(&significant(1.234_567_8e-25, 4)).expect("json"),
            "1.235e-25"
        );
        assert_eq!(significant(0.0, 4), 0.0);
        assert_eq!(significant(f64::INFINITY, 4), f64::INFINITY);
    }
}
