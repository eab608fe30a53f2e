//! The validator: checks the IR invariants listed in [`crate::ir`] on a block stream.
//! It sits beside the IR, not in it, because it reports [`Diagnostic`]s, which point at
//! the IR's spans.

use crate::diag::Diagnostic;
use crate::ir::{Axis, Block, BlockKind, Joints, MotionKind, Target};

/// Streaming verifier: feed it blocks in order; it returns the first broken invariant
/// of each block.
///
/// ```
/// use ncpost::front::gcode::{parse_str, Options};
/// use ncpost::valid::Verifier;
/// let p = parse_str("G0 X0 Y0\nG2 X10 Y0 I5 J0 F100\n", &Options::default()).unwrap();
/// let mut v = Verifier;
/// assert!(p.blocks.iter().all(|b| v.check(b).is_ok()));
/// ```
#[derive(Debug, Default, Clone)]
pub struct Verifier;

impl Verifier {
    /// Checks one block; `Err` is the `ir::invariant` error that names the broken
    /// invariant, at the block's line.
    pub fn check(&mut self, block: &Block) -> Result<(), Diagnostic> {
        self.broken(block).map_err(|what| {
            Diagnostic::error("ir::invariant", format!("IR invariant broken: {what}"))
                .at_span(block.span)
                .with_help("a pass before this one produced an invalid block; please report it")
        })
    }

    /// The broken invariant of `block`, in words.
    fn broken(&mut self, block: &Block) -> Result<(), String> {
        if block.span.line == 0 {
            return Err("block has no source line (invariant 1)".into());
        }
        for c in &block.comments {
            if c.text.contains('\n') {
                return Err("comment text holds a line break".into());
            }
        }
        match &block.kind {
            BlockKind::Motion(m) => {
                let joints = match &m.target {
                    Target::Joints(j) => j,
                    Target::Pose(p) => {
                        if !(p.tip.coords.iter().all(|v| v.is_finite())) {
                            return Err("pose tip is not finite (invariant 6)".into());
                        }
                        if (p.axis.norm() - 1.0).abs() > 1e-9 {
                            return Err("pose tool axis is not a unit vector (invariant 4)".into());
                        }
                        p.extra()
                    }
                };
                check_joints(joints)?;
                if let Some(r) = m.feed.rate
                    && !(r.is_finite() && r >= 0.0)
                {
                    return Err(format!("feed {r} is not a finite non-negative number"));
                }
                if let MotionKind::Arc(arc) = m.kind
                    && !arc.center.iter().all(|v| v.is_finite())
                {
                    return Err("arc centre is not finite (invariant 6)".into());
                }
            }
            BlockKind::Dwell { seconds } => {
                if !(seconds.is_finite() && *seconds >= 0.0) {
                    return Err(format!("dwell {seconds} is not a finite non-negative time"));
                }
            }
            BlockKind::Offset(o) => {
                check_joints(&o.declared)?;
                if !o.offsets.iter().all(|v| v.is_finite()) {
                    return Err("offsets are not finite (invariant 6)".into());
                }
            }
            BlockKind::Command(c) => {
                if c.text.contains('\n') {
                    return Err("command text holds a line break".into());
                }
            }
            BlockKind::Verbatim(v) => {
                if v.text.contains('\n') {
                    return Err("verbatim text holds a line break".into());
                }
            }
            BlockKind::Comment => {
                if block.comments.is_empty() {
                    return Err("comment block without a comment (invariant 5)".into());
                }
            }
        }
        Ok(())
    }
}

/// The first axis of `j` that breaks invariant 3 or 6, as a message.
fn check_joints(j: &Joints) -> Result<(), String> {
    for a in Axis::ALL {
        let v = j.values[a.index()];
        if !v.is_finite() {
            return Err(format!("{} is not finite (invariant 6)", a.letter()));
        }
        if !j.known.contains(a) && v != 0.0 {
            return Err(format!(
                "unknown axis {} holds a value (invariant 3)",
                a.letter()
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Good joints pass; bad ones are stopped with the message of the first bad axis.
    #[test]
    fn joints_checks_find_the_first_bad_axis() {
        let mut j = Joints::default();
        j.set(Axis::X, 1.0);
        j.set(Axis::E, -2.5);
        assert_eq!(check_joints(&j), Ok(()));
        assert_eq!(check_joints(&Joints::default()), Ok(()));

        let mut unknown_value = j;
        unknown_value.values[Axis::C.index()] = 3.0;
        assert_eq!(
            check_joints(&unknown_value),
            Err("unknown axis C holds a value (invariant 3)".into())
        );

        for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            let mut not_finite = unknown_value;
            not_finite.values[Axis::Y.index()] = bad;
            // Y comes before C: its message wins.
            assert_eq!(
                check_joints(&not_finite),
                Err("Y is not finite (invariant 6)".into())
            );
            let mut known_bad = j;
            known_bad.set(Axis::E, bad);
            assert_eq!(
                check_joints(&known_bad),
                Err("E is not finite (invariant 6)".into())
            );
        }
    }
}
