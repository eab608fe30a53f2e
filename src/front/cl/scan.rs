//! The one-pass reader of plain `GOTO/x,y,z[,i,j,k]` lines, most of the lines of a
//! 5-axis CL file. It reads what [`crate::num::scan_decimal_wide`] reads, with
//! the same values (the proptests of the CL frontend hold it to the grammar).

use crate::num::decimal::{
    POW10_INT, ZEROS, eight_digits, exact_decimal, not_digit, scan_decimal_wide,
};

/// A blank between values. With `CHUNK` the line ends at `\n`, which is not a blank.
#[inline(always)]
fn blank<const CHUNK: bool>(c: u8) -> bool {
    c.is_ascii_whitespace() && !(CHUNK && c == b'\n')
}

/// The decimal at `b[at..]` and where it ends, as [`scan_decimal_wide`] reads it.
///
/// CL values are `[-]d.ddd` with one to seven whole digits and at most fourteen digits in
/// all; when sixteen bytes follow the sign such a value is read with two loads and no
/// loop: one digit test of the sixteen bytes finds the point (the first byte that is no
/// digit) and the end (the second), the bytes after the point are shifted over it, and
/// the one run of at most fourteen digits is converted eight at a time. Anything else
/// goes to the general reader.
#[inline(always)]
fn decimal(b: &[u8], at: usize) -> Option<(f64, usize)> {
    let negative = b.get(at) == Some(&b'-');
    let start = at + usize::from(negative);
    if let Some(w) = b
        .get(start..start + 16)
        .and_then(|w| <&[u8; 16]>::try_from(w).ok())
    {
        let (l, h) = w.split_at(8);
        let lo = u64::from_le_bytes(l.try_into().unwrap_or_default()) ^ ZEROS;
        let hi = u64::from_le_bytes(h.try_into().unwrap_or_default()) ^ ZEROS;
        // A byte that carries in the test spoils only the bytes after it; the point
        // does not carry, and the end is the first byte that is no digit after it.
        let (stop_lo, stop_hi) = (not_digit(lo), not_digit(hi));
        // Whole digits (8 when all eight bytes are digits).
        let whole = (stop_lo.trailing_zeros() / 8) as usize;
        let point = (lo >> (8 * (whole & 7))) as u8 == b'.' ^ b'0';
        if (1..8).contains(&whole) && point {
            let after = stop_lo & stop_lo.wrapping_sub(1);
            let end = if after != 0 {
                (after.trailing_zeros() / 8) as usize
            } else {
                8 + (stop_hi.trailing_zeros() / 8) as usize
            };
            // Digits in all, without the point: at most 15 when the end is past the
            // sixteen bytes, and fifteen may go on: the general reader counts them.
            let count = end - 1;
            if count < 15 {
                // The digits before the point stay, the bytes after it move down one.
                let keep = (1u64 << (8 * whole)) - 1;
                let digits_lo = (lo & keep) | (((lo >> 8) | (hi << 56)) & !keep);
                let mantissa = if count <= 8 {
                    eight_digits(digits_lo << (64 - 8 * count))
                } else {
                    let low = count - 8;
                    let digits_hi = hi >> 8;
                    eight_digits(digits_lo) * POW10_INT[low]
                        + eight_digits(digits_hi << (64 - 8 * low))
                };
                let value = exact_decimal(mantissa, count - whole, negative);
                return Some((value, start + end));
            }
        }
    }
    scan_decimal_wide(b, at)
}

/// Reads a plain `GOTO/` line at the start of `b` (blanks around the values, plain
/// decimals, no exponent) into `v`: the count of values and where the line ends. `None`
/// for anything else, and for a seventh value.
///
/// Without `CHUNK` the line is all of `b` (a line's bytes, a statement's code); with it
/// `b` is buffered input and the line ends at the first `\n`, which must be there (its
/// index is returned). Reading sixteen bytes at a time past the values of a line is the
/// point of the chunk: only the last line of a buffer has no bytes after it.
#[inline(always)]
pub(super) fn goto<const CHUNK: bool>(b: &[u8], v: &mut [f64; 6]) -> Option<(usize, usize)> {
    let mut at = 0;
    while b.get(at).is_some_and(|&c| blank::<CHUNK>(c)) {
        at += 1;
    }
    let head = b.get(at..)?.first_chunk::<5>()?;
    // Case folding by `| 0x20` is exact here: only `G`/`g` give `g`, and so on.
    let word = u32::from_le_bytes([head[0], head[1], head[2], head[3]]) | 0x2020_2020;
    if word != u32::from_le_bytes(*b"goto") || head[4] != b'/' {
        return None;
    }
    at += 5;
    let mut n = 0;
    loop {
        while b.get(at).is_some_and(|&c| blank::<CHUNK>(c)) {
            at += 1;
        }
        let (x, end) = decimal(b, at)?;
        *v.get_mut(n)? = x;
        n += 1;
        at = end;
        if b.get(at) == Some(&b',') {
            at += 1;
            continue;
        }
        while b.get(at).is_some_and(|&c| blank::<CHUNK>(c)) {
            at += 1;
        }
        match b.get(at) {
            Some(b',') => at += 1,
            Some(b'\n') if CHUNK => return Some((n, at)),
            None if !CHUNK => return Some((n, at)),
            _ => return None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every way a value may be spelled around the sixteen-byte window reads as the general
    /// reader reads it: same value (bits), same end.
    #[test]
    fn decimals_read_as_the_general_reader_does() {
        let bodies = [
            "0",
            "1",
            "12",
            "1234567",
            "12345678",
            ".5",
            "5.",
            "0.5",
            "1.25",
            "40.060853",
            "0.539410836",
            "0.002347031",
            "1234567.1234567",
            "123456.12345678",
            "1.23456789012345",
            "1.234567890123456",
            "12.3456789012345",
            "1.5.2",
            "1.5e3",
            "7.-",
            "9999999.9999999",
            "25.",
            ".005061",
            ".",
            "0",
            "1234567",
            "12345678",
        ];
        let tails = [
            "",
            ",",
            ",1.5",
            "\n",
            "\r\nGOTO/1",
            " ,",
            "12345678901234567",
        ];
        for body in bodies {
            for sign in ["", "-", "+"] {
                for tail in tails {
                    for pad in 0..20 {
                        let text = format!("{sign}{body}{tail}{}", ",".repeat(pad));
                        let b = text.as_bytes();
                        let got = decimal(b, 0).map(|(v, e)| (v.to_bits(), e));
                        let want = scan_decimal_wide(b, 0).map(|(v, e)| (v.to_bits(), e));
                        assert_eq!(got, want, "{text:?}");
                    }
                }
            }
        }
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig { cases: 4096, ..Default::default() })]

        /// Bytes of numbers, separators and a few others, read from any place.
        #[test]
        fn soup_reads_as_the_general_reader_does(
            bytes in proptest::collection::vec(
                proptest::sample::select(b"0123456789012345678901234..-+,, \n\re".to_vec()),
                0..48,
            ),
            at in 0usize..6,
        ) {
            let got = decimal(&bytes, at).map(|(v, e)| (v.to_bits(), e));
            let want = scan_decimal_wide(&bytes, at).map(|(v, e)| (v.to_bits(), e));
            proptest::prop_assert_eq!(got, want, "{:?}", String::from_utf8_lossy(&bytes));
        }

        /// `[-]ddd.ddd` with any count of digits on either side, or `[-]ddd`, then anything.
        #[test]
        fn numbers_read_as_the_general_reader_does(
            negative in proptest::bool::ANY,
            whole in "[0-9]{0,9}",
            point in proptest::bool::weighted(0.8),
            frac in "[0-9]{0,17}",
            tail in "[-0-9.,\n ]{0,18}",
        ) {
            let sign = if negative { "-" } else { "" };
            let text = if point {
                format!("{sign}{whole}.{frac}{tail}")
            } else {
                format!("{sign}{whole}{tail}")
            };
            let b = text.as_bytes();
            let got = decimal(b, 0).map(|(v, e)| (v.to_bits(), e));
            let want = scan_decimal_wide(b, 0).map(|(v, e)| (v.to_bits(), e));
            proptest::prop_assert_eq!(got, want, "{:?}", text);
        }
    }

    #[test]
    fn lines_end_at_the_newline_in_a_chunk() {
        let mut v = [0.0; 6];
        let b = b"  GOTO/1.5, 2.5 ,-3.25\r\nGOTO/4,5,6\n";
        assert_eq!(goto::<true>(b, &mut v), Some((3, 23)));
        assert_eq!(v[..3], [1.5, 2.5, -3.25]);
        assert_eq!(goto::<false>(&b[..22], &mut v), Some((3, 22)));
        assert_eq!(goto::<false>(&b[..23], &mut v), Some((3, 23)));
        // No newline: the line may go on in the next chunk.
        assert_eq!(goto::<true>(&b[..23], &mut v), None);
        assert_eq!(goto::<true>(b"goto/1,2,3,4,5,6,7\n", &mut v), None);
        assert_eq!(goto::<true>(b"GOTO/1,2,3,\n", &mut v), None);
        assert_eq!(goto::<true>(b"GOTO/1,2,3 $\n", &mut v), None);
        assert_eq!(goto::<true>(b"GOTO 1,2,3\n", &mut v), None);
        assert_eq!(goto::<true>(b"GOTO/1,2,3\n", &mut v), Some((3, 10)));
    }
}
