//! Decimal numbers as G-code and CL data write them (`-1.25`, `.5`, `3.`): read exactly as
//! `str::parse::<f64>` would, with Clinger's fast path for up to 15 digits.

/// Powers of ten a mantissa of at most 15 digits is divided by, exactly.
const POW10: [f64; 16] = [
    1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15,
];

/// [`POW10`], then its negatives: the divisors of [`exact_decimal`], which carry the sign.
const SIGNED_POW10: [f64; 32] = {
    let mut t = [0.0; 32];
    let mut i = 0;
    while i < 16 {
        t[i] = POW10[i];
        t[i + 16] = -POW10[i];
        i += 1;
    }
    t
};

/// Parses a G-code decimal (`-1.25`, `.5`, `3.`): exactly as `str::parse::<f64>`, with a
/// fast path for up to 15 digits, where the digits form an exact integer and dividing by
/// an exact power of ten rounds once, correctly (Clinger's fast path).
pub fn parse_decimal(s: &str) -> Option<f64> {
    let bytes = s.as_bytes();
    let (negative, digits) = match bytes.first() {
        Some(b'-') => (true, &bytes[1..]),
        Some(b'+') => (false, &bytes[1..]),
        _ => (false, bytes),
    };
    // At most 15 digits and a point: the mantissa is exact and cannot overflow.
    if digits.len() > 16 {
        return s.parse().ok();
    }
    let mut mantissa: u64 = 0;
    let mut point = usize::MAX;
    for (i, &b) in digits.iter().enumerate() {
        let d = b.wrapping_sub(b'0');
        if d < 10 {
            mantissa = mantissa * 10 + d as u64;
        } else if b == b'.' && point == usize::MAX {
            point = i;
        } else {
            return s.parse().ok();
        }
    }
    let (count, frac) = if point == usize::MAX {
        (digits.len(), 0)
    } else {
        (digits.len() - 1, digits.len() - 1 - point)
    };
    if count == 0 {
        return None;
    }
    if count > 15 {
        return s.parse().ok();
    }
    Some(exact_decimal(mantissa, frac, negative))
}

/// Reads a plain decimal (sign, digits, at most one point, at least one digit) at
/// `b[at..]` and returns it with where it ends: the same value as [`parse_decimal`] on
/// those bytes, read in the same pass that finds their end. `None` without a digit; what
/// follows the number (`,`, `e`, a blank) is the caller's to read.
///
/// ```
/// use ncpost::num::scan_decimal;
/// assert_eq!(scan_decimal(b"GOTO/-1.25,3", 5), Some((-1.25, 10)));
/// assert_eq!(scan_decimal(b".5e3", 0), Some((0.5, 2)));
/// assert_eq!(scan_decimal(b"-,", 0), None);
/// assert_eq!(scan_decimal(b"0.12345678901234567", 0), Some((0.12345678901234567, 19)));
/// ```
// Inlined: the G-code lexer's loop reads every number of every line through it.
#[inline(always)]
pub fn scan_decimal(b: &[u8], at: usize) -> Option<(f64, usize)> {
    scan_decimal_by(b, at, read_digits)
}

/// [`scan_decimal`] reading up to eight digits at a time: the same results, faster on
/// numbers with many digits (CL data prints six to nine decimals), slower on the short
/// words of G-code.
///
/// ```
/// use ncpost::num::scan_decimal_wide;
/// assert_eq!(scan_decimal_wide(b"GOTO/40.060853,0.1", 5), Some((40.060853, 14)));
/// assert_eq!(scan_decimal_wide(b"-0.539410836", 0), Some((-0.539410836, 12)));
/// ```
#[inline(always)]
pub fn scan_decimal_wide(b: &[u8], at: usize) -> Option<(f64, usize)> {
    scan_decimal_by(b, at, read_digits_wide)
}

#[inline(always)]
fn scan_decimal_by(
    b: &[u8],
    mut at: usize,
    read_digits: impl Fn(&[u8], usize, &mut u64) -> usize,
) -> Option<(f64, usize)> {
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
        // The mantissa wrapped: the standard parser, on the same (ASCII) bytes.
        _ => long_decimal(&b[start..at]).map(|v| (v, at)),
    }
}

/// [`parse_decimal`] on the bytes of a number too long for the exact fast path (rare;
/// kept out of line so the callers' loops stay small).
#[cold]
#[inline(never)]
fn long_decimal(b: &[u8]) -> Option<f64> {
    std::str::from_utf8(b).ok().and_then(parse_decimal)
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

/// `b'0'` in every byte: XOR turns digits into 0..=9 and every other byte into 10 or more.
pub(crate) const ZEROS: u64 = 0x3030_3030_3030_3030;

/// The high bit of each byte of `v` (bytes already XORed with [`ZEROS`]) that is not a
/// digit. A byte of 0x8a or more carries into the next one, which can only spoil bytes
/// after the first non-digit.
#[inline(always)]
pub(crate) fn not_digit(v: u64) -> u64 {
    (v.wrapping_add(0x7676_7676_7676_7676) | v) & 0x8080_8080_8080_8080
}

/// [`read_digits`] eight bytes at a time while they lie in `b`.
#[inline(always)]
fn read_digits_wide(b: &[u8], mut at: usize, mantissa: &mut u64) -> usize {
    while let Some(chunk) = b.get(at..).and_then(<[u8]>::first_chunk::<8>) {
        let v = u64::from_le_bytes(*chunk) ^ ZEROS;
        let n = (not_digit(v).trailing_zeros() / 8) as usize;
        if n == 0 {
            return at;
        }
        // The first byte is the leading digit: shifting the others out leaves zeros before it.
        *mantissa = mantissa
            .wrapping_mul(POW10_INT[n])
            .wrapping_add(eight_digits(v << (64 - 8 * n)));
        at += n;
        if n < 8 {
            return at;
        }
    }
    read_digits(b, at, mantissa)
}

/// The number written by eight digit values (0..=9), one per byte, the first (lowest)
/// byte the leading digit: pairs, then fours, then all eight, a multiplication each.
#[inline(always)]
pub(crate) fn eight_digits(v: u64) -> u64 {
    let v = (v.wrapping_mul(10 * 256 + 1) >> 8) & 0x00ff_00ff_00ff_00ff;
    let v = (v.wrapping_mul(100 * 65_536 + 1) >> 16) & 0x0000_ffff_0000_ffff;
    v.wrapping_mul(10_000 * (1 << 32) + 1) >> 32
}

/// `10^n` for the digits [`read_digits_wide`] reads at once (and for the printer's digit
/// counts, up to 10^9).
pub(crate) const POW10_INT: [u64; 10] = [
    1,
    10,
    100,
    1_000,
    10_000,
    100_000,
    1_000_000,
    10_000_000,
    100_000_000,
    1_000_000_000,
];

/// `±mantissa / 10^frac` for a mantissa of at most 15 digits: both are exact in f64, so
/// the one division rounds correctly (Clinger's fast path), as `str::parse` does.
///
/// The mantissa is below 2^52, so it converts by setting it into the mantissa field of
/// 2^52 and taking 2^52 off (exact), with instructions that write all of a register:
/// `cvtsi2sd` keeps the register's upper half, which can make each number's division
/// wait for the one before. The sign is the divisor's, from a table (no branch):
/// `a / -b` is `-(a / b)` in every rounding to nearest, and `0 / -b` is `-0`.
#[inline(always)]
pub(crate) fn exact_decimal(mantissa: u64, frac: usize, negative: bool) -> f64 {
    const TWO_52: f64 = 4_503_599_627_370_496.0;
    debug_assert!(mantissa < 1 << 52 && frac < 16);
    let m = f64::from_bits(mantissa | TWO_52.to_bits()) - TWO_52;
    m / SIGNED_POW10[usize::from(negative) * 16 + (frac & 15)]
}

#[cfg(test)]
mod tests {
    use super::{eight_digits, parse_decimal, scan_decimal, scan_decimal_wide};

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
        ] {
            assert_eq!(parse_decimal(s), s.parse::<f64>().ok(), "{s}");
        }
        for i in 0..200_000u64 {
            let s = format!("{}.{:05}", i / 7, (i * 7919) % 100_000);
            assert_eq!(parse_decimal(&s), s.parse::<f64>().ok(), "{s}");
        }
        assert_eq!(parse_decimal("."), None);
        assert_eq!(parse_decimal("1.2.3"), None);
    }

    proptest::proptest! {
        /// Any sign, up to 18 digits and at most one point, anywhere: the same bits as
        /// `str::parse` (also the sign of zero), or both reject.
        #[test]
        fn decimal_matches_std_bitwise(s in "[+-]?[0-9]{0,18}(\\.[0-9]{0,18})?|[0-9.]{0,6}") {
            let bits = |v: Option<f64>| v.map(f64::to_bits);
            proptest::prop_assert_eq!(bits(parse_decimal(&s)), bits(s.parse::<f64>().ok()), "{}", s);
        }

        /// Reading eight digits at a time ends every number where the plain reader does,
        /// with the same bits, from any start in any mix of digits, points, signs and
        /// other bytes (also bytes of 0x8a and above, which carry in the digit test).
        #[test]
        fn wide_scan_matches_plain_scan(
            b in proptest::collection::vec(proptest::sample::select(b"0123456789..--+, eE\x8a\xff/:".to_vec()), 0..40),
            digits in "[0-9]{0,24}",
            at in 0usize..8,
        ) {
            let mut b = b;
            // Long digit runs too: the random mix rarely makes eight in a row.
            b.splice(b.len() / 2..b.len() / 2, digits.bytes());
            let bits = |r: Option<(f64, usize)>| r.map(|(v, end)| (v.to_bits(), end));
            proptest::prop_assert_eq!(bits(scan_decimal_wide(&b, at)), bits(scan_decimal(&b, at)), "{:?}", b);
        }
    }

    #[test]
    fn eight_digits_reads_every_digit_in_every_place() {
        for place in 0..8 {
            for d in 0..10u64 {
                let v = d << (8 * place);
                assert_eq!(eight_digits(v), d * 10u64.pow(7 - place));
            }
        }
        assert_eq!(
            eight_digits(u64::from_le_bytes(*b"99999999") ^ 0x3030_3030_3030_3030),
            99_999_999
        );
        assert_eq!(
            eight_digits(u64::from_le_bytes(*b"12345678") ^ 0x3030_3030_3030_3030),
            12_345_678
        );
    }
}
