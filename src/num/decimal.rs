//! Decimal numbers as G-code and CL data write them (`-1.25`, `.5`, `3.`): read exactly as
//! `str::parse::<f64>` would. Programs write positions and feeds with a few decimals, so
//! almost every value has at most 15 digits; those are read with Clinger's fast path (the
//! digits form an exact integer, and one division by an exact power of ten rounds
//! correctly). Longer values go to `str::parse`.

/// Powers of ten a mantissa of at most 15 digits is divided by, exactly.
const POW10: [f64; 16] = [
    1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15,
];

/// Parses a whole string as a decimal (`-1.25`, `.5`, `3.`): [`scan_decimal`] over all of
/// it. A string that is not a plain decimal (an exponent, `inf`) is read as `str::parse`
/// reads it, so callers that re-read text the IR carries get what they always got.
///
/// ```
/// use ncpost::num::parse_decimal;
/// assert_eq!(parse_decimal("-1.25"), Some(-1.25));
/// assert_eq!(parse_decimal(".5"), Some(0.5));
/// assert_eq!(parse_decimal("1.2.3"), None);
/// ```
pub fn parse_decimal(s: &str) -> Option<f64> {
    match scan_decimal(s.as_bytes(), 0) {
        Some((value, end)) if end == s.len() => Some(value),
        _ => s.parse().ok(),
    }
}

/// Reads a plain decimal (sign, digits, at most one point, at least one digit) at
/// `b[at..]` and returns it with where it ends, in the same pass that finds its end.
/// `None` without a digit; what follows the number (`,`, `e`, a blank) is the caller's
/// to read.
///
/// ```
/// use ncpost::num::scan_decimal;
/// assert_eq!(scan_decimal(b"GOTO/-1.25,3", 5), Some((-1.25, 10)));
/// assert_eq!(scan_decimal(b".5e3", 0), Some((0.5, 2)));
/// assert_eq!(scan_decimal(b"-,", 0), None);
/// assert_eq!(scan_decimal(b"0.12345678901234567", 0), Some((0.12345678901234567, 19)));
/// ```
pub fn scan_decimal(b: &[u8], mut at: usize) -> Option<(f64, usize)> {
    let start = at;
    let negative = match b.get(at) {
        Some(b'-') => {
            at += 1;
            true
        }
        Some(b'+') => {
            at += 1;
            false
        }
        _ => false,
    };
    let mut mantissa = 0u64;
    let whole = at;
    at = read_digits(b, at, &mut mantissa);
    let mut count = at - whole;
    let mut frac = 0;
    if b.get(at) == Some(&b'.') {
        let start = at + 1;
        at = read_digits(b, start, &mut mantissa);
        frac = at - start;
        count += frac;
    }
    match count {
        0 => None,
        1..=15 => Some((exact_decimal(mantissa, frac, negative), at)),
        // More digits than the fast path reads exactly (the mantissa wrapped).
        _ => std::str::from_utf8(&b[start..at])
            .ok()?
            .parse()
            .ok()
            .map(|v| (v, at)),
    }
}

/// Reads the ASCII digits of `b` from `at` into `mantissa` (wrapping: the caller counts
/// the digits and refuses too many); returns where they end.
fn read_digits(b: &[u8], mut at: usize, mantissa: &mut u64) -> usize {
    while at < b.len() && b[at].is_ascii_digit() {
        *mantissa = mantissa
            .wrapping_mul(10)
            .wrapping_add(u64::from(b[at] - b'0'));
        at += 1;
    }
    at
}

/// `±mantissa / 10^frac` for a mantissa of at most 15 digits: both are exact in f64, so
/// the one division rounds correctly (Clinger's fast path), as `str::parse` does. The
/// sign is applied after the division, which gives the same value as dividing a negative
/// mantissa (rounding to nearest is symmetric), and `-0` for `-0.0`.
pub(crate) fn exact_decimal(mantissa: u64, frac: usize, negative: bool) -> f64 {
    debug_assert!(mantissa < 1 << 52 && frac < 16);
    let value = mantissa as f64 / POW10[frac];
    if negative { -value } else { value }
}

#[cfg(test)]
mod tests {
    use super::{parse_decimal, scan_decimal};

    #[test]
    fn decimal_fast_path_matches_std() {
        for s in [
            "0",
            "-0",
            "1.",
            ".5",
            "-.5",
            "+2.25",
            "123.456789",
            "0.1",
            "99999.99999",
            "1234567890.12345",
            "0.30000000000000004",
            "1e5",
            "inf",
        ] {
            assert_eq!(parse_decimal(s), s.parse::<f64>().ok(), "{s}");
        }
        for i in 0..200_000u64 {
            let s = format!("{}.{:05}", i / 7, (i * 7919) % 100_000);
            assert_eq!(parse_decimal(&s), s.parse::<f64>().ok(), "{s}");
        }
        assert_eq!(parse_decimal("."), None);
        assert_eq!(parse_decimal("1.2.3"), None);
        assert_eq!(parse_decimal(""), None);
    }

    proptest::proptest! {
        /// Any sign, up to 18 digits and at most one point, anywhere: the same bits as
        /// `str::parse` (also the sign of zero), or both reject.
        #[test]
        fn decimal_matches_std_bitwise(s in "[+-]?[0-9]{0,18}(\\.[0-9]{0,18})?|[0-9.]{0,6}") {
            let bits = |v: Option<f64>| v.map(f64::to_bits);
            proptest::prop_assert_eq!(bits(parse_decimal(&s)), bits(s.parse::<f64>().ok()), "{}", s);
        }

        /// A number inside other text ends where its plain digits end, with the value
        /// `str::parse` gives to those bytes.
        #[test]
        fn scan_matches_std_on_the_number_it_ends(
            b in proptest::collection::vec(proptest::sample::select(b"0123456789..--+, eE\x8a\xff/:".to_vec()), 0..40),
            at in 0usize..8,
        ) {
            if let Some((v, end)) = scan_decimal(&b, at) {
                let s = std::str::from_utf8(&b[at..end]).expect("ASCII");
                proptest::prop_assert_eq!(Some(v.to_bits()), s.parse::<f64>().ok().map(f64::to_bits), "{:?}", s);
            }
        }
    }
}
