//! The range of numbers a program may write, and how a number token is shown in a
//! message.
//!
//! No machine travels a million kilometres, and coordinates far beyond any workspace
//! only turn into floods of errors downstream (every move out of reach, every arc cut
//! into billions of chords). Every frontend refuses a value beyond [`MAX_MAGNITUDE`] at
//! the number, once.

/// The largest magnitude a written value may have (1e12: in millimetres a million
/// kilometres, far beyond any coordinate, feed or speed).
pub const MAX_MAGNITUDE: f64 = 1e12;

/// Whether `v` is a value a program may write: finite and at most [`MAX_MAGNITUDE`].
///
/// ```
/// use ncpost::num::range::in_range;
/// assert!(in_range(-1e12));
/// assert!(!in_range(1e308));
/// assert!(!in_range(f64::NAN));
/// ```
pub fn in_range(v: f64) -> bool {
    v.is_finite() && v.abs() <= MAX_MAGNITUDE
}

/// Characters of a token a message shows at most; longer tokens are cut with `…`.
pub const SHOWN_CHARS: usize = 40;

/// `token` as a message shows it: whole when short, else its first characters and `…`
/// (a number with a million digits is not echoed whole).
///
/// ```
/// use ncpost::num::range::shown;
/// assert_eq!(shown("1.5"), "1.5");
/// let long = "9".repeat(1000);
/// assert_eq!(shown(&long).chars().count(), 41);
/// assert!(shown(&long).ends_with('…'));
/// ```
pub fn shown(token: &str) -> std::borrow::Cow<'_, str> {
    match token.char_indices().nth(SHOWN_CHARS) {
        None => token.into(),
        Some((cut, _)) => format!("{}…", &token[..cut]).into(),
    }
}
