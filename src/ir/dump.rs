//! Stable text form of the IR (`--emit ir`, `--dump-after`), fixed at 4 decimals.

use std::fmt::Write;

use crate::ir::{
    Axis, AxisSet, Block, BlockKind, CommentStyle, FeedMode, Joints, Motion, MotionKind, Target,
    VerbatimReason,
};

/// Appends one block's dump line (without a newline) to `out`.
///
/// ```
/// use ncpost::front::gcode::{parse_str, Options};
/// use ncpost::ir::dump;
/// let p = parse_str("G1 X1 F100 (cut)\n", &Options::default()).unwrap();
/// let mut s = String::new();
/// dump::write_block(&mut s, &p.blocks[0]);
/// assert_eq!(s, "1: linear X1.0000 feed=100.0000/min written=X (cut)");
/// ```
pub fn write_block(out: &mut String, block: &Block) {
    let _ = write!(out, "{}: ", block.span.line);
    match &block.kind {
        BlockKind::Motion(m) => motion(out, m),
        BlockKind::Dwell { seconds } => {
            let _ = write!(out, "dwell {seconds:.4}s");
        }
        BlockKind::Offset(o) => {
            out.push_str(o.code.gcode());
            joints(out, &o.declared);
            out.push_str(" offsets");
            let mut any = false;
            for a in Axis::ALL {
                let v = o.offsets[a.index()];
                if v != 0.0 {
                    let _ = write!(out, " {}{v:.4}", a.letter());
                    any = true;
                }
            }
            if !any {
                out.push_str(" none");
            }
        }
        BlockKind::Command(c) => {
            let _ = write!(out, "command {:?}", c.text);
            let modes = c.modes.unwrap_or_default();
            if modes.inch {
                out.push_str(" inch");
            }
            if modes.relative {
                out.push_str(" relative");
            }
            if !c.clobbers.is_empty() {
                out.push_str(" clobbers=");
                axes(out, c.clobbers);
            }
        }
        BlockKind::Verbatim(v) => {
            let reason = match v.reason {
                VerbatimReason::Unevaluated => "unevaluated",
                VerbatimReason::ControlFlow => "control-flow",
                VerbatimReason::Subprogram => "subprogram",
                VerbatimReason::Delimiter => "delimiter",
            };
            let _ = write!(out, "verbatim {reason} {:?}", v.text);
            if !v.clobbers.is_empty() {
                out.push_str(" clobbers=");
                axes(out, v.clobbers);
            }
            if let Some(end) = v.ends_at() {
                // A canned cycle the frontend resolved: where it leaves the tool.
                out.push_str(" ends");
                joints(out, end);
            }
        }
        BlockKind::Comment => out.push_str("comment"),
    }
    for c in &block.comments {
        match c.style {
            CommentStyle::Paren => {
                let _ = write!(out, " ({})", c.text);
            }
            CommentStyle::Semicolon => {
                let _ = write!(out, " ;{}", c.text);
            }
        }
    }
}

/// A move: kind, target, arc, feed and the words it was written with.
fn motion(out: &mut String, m: &Motion) {
    out.push_str(match m.kind {
        MotionKind::Rapid => "rapid",
        MotionKind::Linear => "linear",
        MotionKind::Arc(a) if a.clockwise => "arc-cw",
        MotionKind::Arc(_) => "arc-ccw",
    });
    match &m.target {
        Target::Joints(j) => joints(out, &quiet_e(j, m.written)),
        Target::Pose(p) => {
            let _ = write!(
                out,
                " tip=({:.4}, {:.4}, {:.4}) axis=({:.6}, {:.6}, {:.6})",
                p.tip.x, p.tip.y, p.tip.z, p.axis.x, p.axis.y, p.axis.z
            );
            joints(out, p.extra());
        }
    }
    if let MotionKind::Arc(a) = m.kind {
        let (u, v, _) = a.plane.axes();
        let _ = write!(
            out,
            " {} center {}{:.4} {}{:.4}",
            a.plane.gcode(),
            u.letter(),
            a.center[u.index()],
            v.letter(),
            a.center[v.index()]
        );
        if a.extra_turns > 0 {
            let _ = write!(out, " turns=+{}", a.extra_turns);
        }
    }
    if !matches!(m.kind, MotionKind::Rapid) || m.feed.rate.is_some() {
        match m.feed.rate {
            Some(r) => {
                let _ = write!(out, " feed={r:.4}");
            }
            None => out.push_str(" feed=none"),
        }
        out.push_str(match m.feed.mode {
            FeedMode::PerMinute => "/min",
            FeedMode::InverseTime => "/inverse-time",
            FeedMode::PerRevolution => "/rev",
        });
    }
    if m.machine_frame {
        out.push_str(" machine-frame");
    }
    out.push_str(" written=");
    axes(out, m.written);
    if !m.extra.is_empty() {
        let _ = write!(out, " extra={:?}", m.extra);
    }
}

/// The extruder starts known at 0; on machines that never use it, leave it out.
fn quiet_e(j: &Joints, written: AxisSet) -> Joints {
    let mut j = *j;
    if j.get(Axis::E) == Some(0.0) && !written.contains(Axis::E) {
        j.forget(std::iter::once(Axis::E).collect());
    }
    j
}

fn joints(out: &mut String, j: &Joints) {
    for a in j.known.iter() {
        let _ = write!(out, " {}{:.4}", a.letter(), j.values[a.index()]);
    }
}

fn axes(out: &mut String, set: AxisSet) {
    if set == AxisSet::ALL {
        out.push_str("all");
    } else if set.is_empty() {
        out.push('-');
    } else {
        out.extend(set.iter().map(Axis::letter));
    }
}

/// The dump of many blocks, one line each.
pub fn to_string(blocks: &[Block]) -> String {
    let mut s = String::new();
    for b in blocks {
        write_block(&mut s, b);
        s.push('\n');
    }
    s
}
