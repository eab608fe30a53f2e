//! Sine and cosine of rotary angles on the printed grid of `10^-d` degrees, from two small tables.
//!
//! A rotary value the backend prints with `d` decimals is a whole number `n` of units of
//! `10^-d` degrees. Its sine and cosine need no libm call: `n` is split into quarter
//! turns and a rest `r` in integers (exactly, however many turns), `r` into
//! `hi · 2^k + lo`, and the tabulated sines and cosines of the two parts are combined by
//! the angle-addition formula. Each table entry is the sine and cosine of an exact angle
//! (the radians carried in double-double precision), so the result is within about
//! 3e-16 of the true value (a few ulps); for an angle of many turns that is closer
//! than `f64::sin_cos` of the radians, whose argument is itself rounded.

use std::f64::consts::PI;

use super::Machine;
use crate::num::print::{from_units, to_units};

/// `π - PI`: the part of π that `f64` leaves out.
const PI_LO: f64 = 1.224_646_799_147_353_2e-16;

/// The largest `|n|` [`AngleGrid::sin_cos`] takes: up to it every unit count is exact as
/// an `f64`, as the printed joint values it stands for are.
const LIMIT: u64 = 1 << 53;

/// `x` as the sum of two parts of at most 26 significant bits each (Dekker's split), so
/// that either times a number of up to 27 bits is exact.
fn split(x: f64) -> (f64, f64) {
    let t = 134_217_729.0 * x; // 2^27 + 1
    let hi = t - (t - x);
    (hi, x - hi)
}

/// `a + b` as the rounded sum and its rounding error (Knuth's two-sum).
fn two_sum(a: f64, b: f64) -> (f64, f64) {
    let s = a + b;
    let bb = s - a;
    (s, (a - (s - bb)) + (b - bb))
}

/// The radians of one unit (`10^-d` degrees) as an unevaluated sum `hi + lo`.
#[derive(Debug, Clone, Copy)]
struct Radians {
    hi: f64,
    lo: f64,
}

impl Radians {
    /// One unit of `1 / per_degree` degrees (`per_degree` a power of ten up to 10^4).
    fn per_unit(per_degree: f64) -> Radians {
        // 180 · 10^d has at most 21 bits: the products below are exact.
        let d = 180.0 * per_degree;
        let hi = PI / d;
        let (a, b) = split(hi);
        // `PI - a·d` is exact (Sterbenz: a·d is within a factor 2 of PI), which leaves
        // π - hi·d to the rounding of a number of the size of hi's own error.
        let rest = (PI - a * d) - b * d;
        Radians {
            hi,
            lo: (rest + PI_LO) / d,
        }
    }

    /// Sine and cosine of `k` units, `0 <= k < 2^27`, to libm's accuracy at the exact
    /// angle: the rounding of `k · hi` is carried along and added to first order (its
    /// square is below 1e-32).
    fn sin_cos(self, k: i64) -> [f64; 2] {
        let kf = k as f64;
        let (a, b) = split(self.hi);
        let (x, e) = two_sum(kf * a, kf * b);
        let e = e + kf * self.lo;
        let (s, c) = x.sin_cos();
        [s + c * e, c - s * e]
    }
}

/// Sine and cosine of `k` units for `0 <= k <= quarter` (an even number of units),
/// from the first octant so that the argument stays below π/4.
fn entry(unit: Radians, k: i64, quarter: i64) -> [f64; 2] {
    if 2 * k <= quarter {
        unit.sin_cos(k)
    } else {
        let [s, c] = unit.sin_cos(quarter - k);
        [c, s]
    }
}

/// Sines and cosines of the angles of whole units of `10^-d` degrees.
///
/// ```
/// use ncpost::machine::grid::AngleGrid;
/// let g = AngleGrid::new(4).unwrap();
/// let (s, c) = g.sin_cos(300_000).unwrap(); // 30 degrees
/// assert!((s - 0.5).abs() < 1e-16 && (c - 0.75f64.sqrt()).abs() < 2e-16);
/// let (s, c) = g.sin_cos(-900_000).unwrap(); // -90 degrees
/// assert_eq!((s, c.abs()), (-1.0, 0.0));
/// ```
#[derive(Debug, Clone, PartialEq)]
pub struct AngleGrid {
    decimals: u8,
    /// Units in a quarter turn, `90 · 10^d`.
    quarter: i64,
    /// `r = (hi << shift) + lo`, `lo = r & mask`.
    shift: u32,
    mask: i64,
    /// `[sin, cos]` of `lo` units, `lo < 2^shift`.
    lo: Box<[[f64; 2]]>,
    /// `[sin, cos]` of `hi · 2^shift` units, for every `hi` below a quarter turn.
    hi: Box<[[f64; 2]]>,
}

impl AngleGrid {
    /// The most decimals a grid is built for: at 4, the two tables have 1024 and 879
    /// entries (30 KB); every further decimal would triple them.
    pub const MAX_DECIMALS: u8 = 4;

    /// The grid of `10^-decimals` degrees; `None` for more than [`Self::MAX_DECIMALS`].
    pub fn new(decimals: u8) -> Option<AngleGrid> {
        if decimals > Self::MAX_DECIMALS {
            return None;
        }
        let per_degree = 10i64.pow(u32::from(decimals));
        let quarter = 90 * per_degree;
        let unit = Radians::per_unit(per_degree as f64);
        // The split halves the bits of a quarter turn, so the two tables are about the
        // same size.
        let bits = 64 - (quarter - 1).leading_zeros();
        let shift = bits.div_ceil(2);
        let lo = (0..1i64 << shift)
            .map(|k| entry(unit, k, quarter))
            .collect();
        let hi = (0..=(quarter - 1) >> shift)
            .map(|h| entry(unit, h << shift, quarter))
            .collect();
        Some(AngleGrid {
            decimals,
            quarter,
            shift,
            mask: (1 << shift) - 1,
            lo,
            hi,
        })
    }

    /// The decimals of the grid.
    pub fn decimals(&self) -> u8 {
        self.decimals
    }

    /// `deg` in whole units when it lies on the grid: it is the `f64` nearest to that many
    /// units (as [`from_units`] gives it back); `None` otherwise.
    ///
    /// ```
    /// use ncpost::machine::grid::AngleGrid;
    /// let g = AngleGrid::new(4).unwrap();
    /// assert_eq!(g.units(-12.5), Some(-125_000));
    /// assert_eq!(g.units(0.00005), None);
    /// ```
    pub fn units(&self, deg: f64) -> Option<i64> {
        let n = to_units(deg, self.decimals)?;
        (from_units(n, self.decimals) == deg).then_some(n)
    }

    /// The sine and cosine of `n` units; `None` when `|n|` is beyond 2^53.
    pub fn sin_cos(&self, n: i64) -> Option<(f64, f64)> {
        if n.unsigned_abs() > LIMIT {
            return None;
        }
        // Whole quarter turns and the rest, exactly.
        let q = n.div_euclid(self.quarter);
        let r = n.rem_euclid(self.quarter);
        let [s1, c1] = self.hi[(r >> self.shift) as usize];
        let [s2, c2] = self.lo[(r & self.mask) as usize];
        let s = s1 * c2 + c1 * s2;
        let c = c1 * c2 - s1 * s2;
        Some(match q.rem_euclid(4) {
            0 => (s, c),
            1 => (c, -s),
            2 => (-s, -c),
            _ => (-c, s),
        })
    }
}

/// How one rotary's joint value becomes its physical angle ([`Machine::physical`]).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Physical {
    /// The rotary's direction, ±1.
    direction: f64,
    /// The zero offset in units, when it lies on the grid (else 0).
    zero: i64,
    /// Sine and cosine of the zero offset when it does not lie on the grid: it is taken
    /// off by one more angle addition.
    off_grid: Option<(f64, f64)>,
}

/// A machine's two rotaries on an [`AngleGrid`]: the sine and cosine of each one's
/// physical angle ([`Machine::physical`]) at a joint value of whole units, for
/// the kinematic chain ([`crate::machine::Turns`]).
///
/// ```
/// use ncpost::machine::{Machine, grid::RotaryGrid};
/// let m = Machine::from_toml(r#"
///     [[rotary]]
///     axis = "A"
///     on = "table"
///     direction = -1
///     min = -90
///     max = 135
///     [[rotary]]
///     axis = "C"
///     on = "table"
///     cyclic = true
///     zero_offset = 0.25
/// "#).unwrap();
/// let g = RotaryGrid::new(&m, 4).unwrap();
/// for (i, units) in [(0, 123_456), (1, -497_731_203)] {
///     let (s, c) = g.sin_cos(i, units).unwrap();
///     let (s0, c0) = m.physical(i, units as f64 / 1e4).sin_cos();
///     assert!((s - s0).abs() < 1e-12 && (c - c0).abs() < 1e-12);
/// }
/// ```
#[derive(Debug, Clone, PartialEq)]
pub struct RotaryGrid {
    grid: AngleGrid,
    rotary: [Physical; 2],
}

impl RotaryGrid {
    /// The rotaries of `machine` (two, as [`Machine::check`] makes sure) on the grid of
    /// `10^-decimals` degrees; `None` when [`AngleGrid::new`] builds no grid for them.
    pub fn new(machine: &Machine, decimals: u8) -> Option<RotaryGrid> {
        let grid = AngleGrid::new(decimals)?;
        let physical = |i: usize| {
            let r = &machine.rotary[i];
            match grid.units(r.zero_offset) {
                Some(zero) => Physical {
                    direction: r.direction,
                    zero,
                    off_grid: None,
                },
                None => Physical {
                    direction: r.direction,
                    zero: 0,
                    off_grid: Some(r.zero_offset.to_radians().sin_cos()),
                },
            }
        };
        let rotary = [physical(0), physical(1)];
        Some(RotaryGrid { grid, rotary })
    }

    /// The grid.
    pub fn grid(&self) -> &AngleGrid {
        &self.grid
    }

    /// Sine and cosine of rotary `i`'s physical angle at the joint value of `n` units;
    /// `None` when the grid takes no such `n` (see [`AngleGrid::sin_cos`]).
    pub fn sin_cos(&self, i: usize, n: i64) -> Option<(f64, f64)> {
        let p = &self.rotary[i];
        let (s, c) = self.grid.sin_cos(n.checked_sub(p.zero)?)?;
        let (s, c) = match p.off_grid {
            None => (s, c),
            Some((sz, cz)) => (s * cz - c * sz, c * cz + s * sz),
        };
        // direction · (angle - zero): the sine is odd, the cosine even.
        Some((p.direction * s, c))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Sine and cosine of `n` units at `decimals` by plain libm, the angle first reduced
    /// exactly to the first octant in integers (so that its radians are below π/4 and
    /// their rounding costs under 2e-16), then put back by the quadrant's symmetry.
    fn reference(n: i64, decimals: u8) -> (f64, f64) {
        let per = 10i64.pow(u32::from(decimals));
        let quarter = 90 * per;
        let r = n.rem_euclid(4 * quarter);
        let (q, r) = (r / quarter, r % quarter);
        let folded = 2 * r > quarter;
        let k = if folded { quarter - r } else { r };
        let (s, c) = (k as f64 / per as f64).to_radians().sin_cos();
        let (s, c) = if folded { (c, s) } else { (s, c) };
        match q {
            0 => (s, c),
            1 => (c, -s),
            2 => (-s, -c),
            _ => (-c, s),
        }
    }

    fn assert_close(n: i64, d: u8, bound: f64) -> Result<(), TestCaseError> {
        let g = AngleGrid::new(d).expect("a grid");
        let (s, c) = g.sin_cos(n).expect("in range");
        let (s0, c0) = reference(n, d);
        prop_assert!(
            (s - s0).abs() <= bound && (c - c0).abs() <= bound,
            "n = {n} at {d} decimals: ({s:e}, {c:e}) against ({s0:e}, {c0:e})"
        );
        Ok(())
    }

    /// Libm's error at an octant angle (up to ~1e-16 in argument and result) and the
    /// table's (two entries of half an ulp, two products and a sum) stay below this.
    const BOUND: f64 = 4e-16;

    /// The unit's radians in double-double against π / 180 and π / 1 800 000 worked out
    /// to 60 digits (Python's `decimal`).
    #[test]
    fn radians_of_a_unit() {
        let r = Radians::per_unit(1.0);
        assert_eq!(r.hi, 0.017_453_292_519_943_295);
        assert!(
            (r.lo - 2.948_652_270_870_168_6e-19).abs() < 1e-33,
            "{:e}",
            r.lo
        );
        let r = Radians::per_unit(1e4);
        assert_eq!(r.hi, 1.745_329_251_994_329_6e-6);
        assert!(
            (r.lo + 2.574_002_545_227_869_7e-23).abs() < 1e-37,
            "{:e}",
            r.lo
        );
    }

    #[test]
    fn tables_are_small_and_cover_a_quarter_turn() {
        for d in 0..=AngleGrid::MAX_DECIMALS {
            let g = AngleGrid::new(d).expect("a grid");
            let quarter = 90 * 10i64.pow(u32::from(d));
            assert!(((g.hi.len() as i64 - 1) << g.shift) < quarter);
            assert!((g.hi.len() as i64) << g.shift >= quarter);
            assert!(g.lo.len() + g.hi.len() <= 2048, "{d}");
        }
        assert!(AngleGrid::new(AngleGrid::MAX_DECIMALS + 1).is_none());
    }

    #[test]
    fn exact_angles() {
        let g = AngleGrid::new(4).expect("a grid");
        assert_eq!(g.sin_cos(0), Some((0.0, 1.0)));
        for k in -8i64..=8 {
            // `==` takes -0.0 for 0.0.
            let want = [(0.0, 1.0), (1.0, 0.0), (0.0, -1.0), (-1.0, 0.0)][k.rem_euclid(4) as usize];
            assert_eq!(g.sin_cos(k * 900_000), Some(want), "{k}");
        }
        let (s, c) = g.sin_cos(450_000).expect("in range");
        assert_eq!(s, c);
        assert!((s - 0.5f64.sqrt()).abs() <= f64::EPSILON / 2.0);
        for (n, s0) in [
            (300_000, 0.5),
            (-300_000, -0.5),
            (1_500_000, 0.5),
            (2_100_000, -0.5),
        ] {
            let (s, _) = g.sin_cos(n).expect("in range");
            assert!((s - s0).abs() <= f64::EPSILON / 2.0, "{n}: {s}");
        }
    }

    #[test]
    fn beyond_the_limit_is_none() {
        let g = AngleGrid::new(3).expect("a grid");
        assert!(g.sin_cos(1 << 53).is_some());
        assert!(g.sin_cos(-(1 << 53)).is_some());
        assert!(g.sin_cos((1 << 53) + 1).is_none());
        assert!(g.sin_cos(i64::MIN).is_none());
        assert!(g.sin_cos(i64::MAX).is_none());
    }

    #[test]
    fn units_on_the_grid() {
        let g = AngleGrid::new(4).expect("a grid");
        assert_eq!(g.units(0.0), Some(0));
        assert_eq!(g.units(-0.0), Some(0));
        assert_eq!(g.units(49773.1203), Some(497_731_203));
        assert_eq!(g.units(0.1 + 0.2), None, "0.30000000000000004 is not 0.3");
        assert_eq!(g.units(f64::NAN), None);
        assert_eq!(g.units(1e300), None);
    }

    #[test]
    fn every_unit_of_a_turn_at_two_decimals() {
        for n in -36_000..=36_000 {
            assert_close(n, 2, BOUND).unwrap();
        }
    }

    /// Every 7th rest of a quarter turn at four decimals (every entry of both tables is met:
    /// 7 and the 1024-unit table step share no factor) against the plain libm value, in
    /// every quadrant and many turns out: the worst case of the bound, looked for where
    /// it could be, in a time the unoptimised test build can afford.
    #[test]
    fn every_seventh_unit_of_a_quarter_turn_at_four_decimals() {
        let g = AngleGrid::new(4).expect("a grid");
        let mut worst: f64 = 0.0;
        for r in (0..900_000).step_by(7) {
            for base in [0, 900_000, 1_800_000, -900_000, 138 * 3_600_000] {
                let n = base + r;
                let (s, c) = g.sin_cos(n).expect("in range");
                let (s0, c0) = reference(n, 4);
                worst = worst.max((s - s0).abs()).max((c - c0).abs());
            }
        }
        assert!(worst <= BOUND, "{worst:e}");
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2000))]

        /// Any angle, many turns out either way.
        #[test]
        fn sin_cos_is_libm_s(n in -(1i64 << 53)..(1i64 << 53), d in 0u8..=AngleGrid::MAX_DECIMALS) {
            assert_close(n, d, BOUND)?;
        }

        /// Angles of machining size, such as C = 49773.1203 degrees.
        #[test]
        fn machining_angles(deg in -60_000.0f64..60_000.0) {
            let n = to_units(deg, 4).expect("fits");
            assert_close(n, 4, BOUND)?;
        }

        /// Near multiples of 90 degrees, where sine or cosine is near zero or one.
        #[test]
        fn near_quarter_turns(k in -2000i64..2000, near in -3000i64..3000, d in 0u8..=AngleGrid::MAX_DECIMALS) {
            let quarter = 90 * 10i64.pow(u32::from(d));
            assert_close(k * quarter + near, d, BOUND)?;
        }

        /// The rotaries' sines and cosines are those of `Machine::physical`'s radians, to
        /// the rounding of that argument (below 1e-13 for a few turns).
        #[test]
        fn rotary_grid_is_physical(
            deg in -1500.0f64..1500.0,
            zero in -10.0f64..10.0,
            on_grid in proptest::bool::ANY,
            direction in proptest::bool::ANY,
        ) {
            let zero = if on_grid { (zero * 100.0).round() / 100.0 } else { zero };
            let direction = if direction { 1.0 } else { -1.0 };
            let text = format!(
                "[[rotary]]\naxis = \"B\"\non = \"table\"\ndirection = {direction}\ncyclic = true\nzero_offset = {zero}\n\
                 [[rotary]]\naxis = \"C\"\non = \"table\"\ndirection = {}\ncyclic = true\n",
                -direction
            );
            let m = Machine::from_toml(&text).expect("machine");
            let g = RotaryGrid::new(&m, 4).expect("a grid");
            prop_assert_eq!(g.rotary[0].off_grid.is_none(), g.grid.units(zero).is_some());
            prop_assert!(!on_grid || g.rotary[0].off_grid.is_none());
            let n = to_units(deg, 4).expect("fits");
            for i in 0..2 {
                let (s, c) = g.sin_cos(i, n).expect("in range");
                let (s0, c0) = m.physical(i, from_units(n, 4)).sin_cos();
                prop_assert!((s - s0).abs() < 1e-13 && (c - c0).abs() < 1e-13, "{} {} {} {}", s, s0, c, c0);
            }
        }
    }
}
