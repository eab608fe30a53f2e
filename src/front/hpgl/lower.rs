//! HPGL commands to IR blocks: pen strokes become plunge, cut and retract moves.
//!
//! The state is the plotter's (pen position in plotter units, pen up/down, absolute or
//! relative, scaling, polygon mode) plus what the milling program has done (Z known
//! and where, spindle, tool). A pen-down stroke is held back until it moves, so a pen
//! that goes down and up again at one point (a drill mark) becomes a drill plunge;
//! consecutive pen-up moves are merged into one travel. Everything else is written as
//! it comes: a command gives its blocks at once, or at the latest at the next command.

use std::collections::HashSet;

use nalgebra::Vector3;

use super::Options;
use super::reader::{Command, Value};
use crate::diag::Diagnostic;
use crate::ir::{
    Arc, Axis, AxisSet, Block, BlockKind, Comment, CommentStyle, Feed, FeedMode, Joints, Motion,
    MotionKind, Plane, Span, Target,
};

/// `plotter = user * f + o`, per axis (`SC` with `IP`).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Scaling {
    fx: f64,
    fy: f64,
    ox: f64,
    oy: f64,
}

/// The pen's stroke state.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Stroke {
    /// Pen up.
    Up,
    /// Pen down, not yet moved since it went down. `drill`: it went down here (a
    /// `PD` or a pen-down move), so lifting it now marks a hole; after a circle the
    /// pen is down without a mark.
    Down { drill: bool, span: Span },
    /// Cutting: the tool is at cut depth.
    Cutting,
}

/// Lowers commands one at a time into blocks.
pub(super) struct Lowerer {
    opt: Options,
    /// Pen position, plotter units.
    pos: (f64, f64),
    absolute: bool,
    stroke: Stroke,
    /// The IR position (X, Y, Z as far as known), mm.
    ir: Joints,
    feed: Feed,
    /// A pen-up travel not yet written (mm), with its span.
    travel: Option<((f64, f64), Span)>,
    tool: Option<u32>,
    spindle_on: bool,
    /// `IP`: P1 and P2 (plotter units), when set.
    ip: Option<[f64; 4]>,
    /// `SC` parameters as written, when scaling is on.
    sc: Option<Vec<f64>>,
    scaling: Option<Scaling>,
    /// Polygon mode: the start of the current subpolygon and whether it has cut edges.
    polygon: Option<((f64, f64), bool)>,
    /// Warnings already given: code, and the mnemonic for `hpgl::ignored`.
    warned: HashSet<(&'static str, [u8; 2])>,
    /// The last command's span (for the end of the program).
    last_span: Option<Span>,
}

/// Commands that set up the page, pen width, fill or text attributes, none of which
/// moves a cutter: comments without a warning.
const NO_GEOMETRY: &[[u8; 2]] = &[
    *b"BP", *b"PG", *b"NR", *b"WU", *b"PW", *b"TR", *b"LA", *b"FT", *b"PT", *b"PS", *b"NP", *b"PC",
    *b"CR", *b"MC", *b"SV", *b"DI", *b"DR", *b"SI", *b"SR", *b"SL", *b"ES", *b"TD", *b"SS", *b"SA",
    *b"CS", *b"CA", *b"AC", *b"UL", *b"OI", *b"OP", *b"OS", *b"OE",
];

fn comment_block(span: Span, text: String) -> Block {
    // A comment holds one line.
    let text = text.replace(['\n', '\r'], " ");
    Block {
        span,
        kind: BlockKind::Comment,
        comments: vec![Comment {
            text,
            style: CommentStyle::Semicolon,
        }],
    }
}

fn command_block(span: Span, text: String) -> Block {
    Block::new(
        span,
        BlockKind::Command(crate::ir::Command {
            text: text.into(),
            modes: None,
            clobbers: AxisSet::EMPTY,
        }),
    )
}

impl Lowerer {
    pub fn new(opt: Options) -> Self {
        Lowerer {
            opt,
            pos: (0.0, 0.0),
            absolute: true,
            stroke: Stroke::Up,
            ir: Joints::default(),
            feed: Feed {
                mode: FeedMode::PerMinute,
                rate: None,
            },
            travel: None,
            tool: None,
            spindle_on: false,
            ip: None,
            sc: None,
            scaling: None,
            polygon: None,
            warned: HashSet::new(),
            last_span: None,
        }
    }

    fn mm(&self, p: (f64, f64)) -> (f64, f64) {
        (p.0 / self.opt.units_per_mm, p.1 / self.opt.units_per_mm)
    }

    /// A user-unit point to plotter units (absolute).
    fn to_plotter(&self, x: f64, y: f64) -> (f64, f64) {
        match self.scaling {
            Some(s) => (x * s.fx + s.ox, y * s.fy + s.oy),
            None => (x, y),
        }
    }

    /// A user-unit displacement to plotter units.
    fn delta_to_plotter(&self, dx: f64, dy: f64) -> (f64, f64) {
        match self.scaling {
            Some(s) => (dx * s.fx, dy * s.fy),
            None => (dx, dy),
        }
    }

    fn warn_once(&mut self, cmd: &Command, diags: &mut Vec<Diagnostic>, d: Diagnostic) {
        let name = if d.code == "hpgl::ignored" {
            cmd.mnemonic
        } else {
            [0; 2]
        };
        if self.warned.insert((d.code, name)) {
            diags.push(cmd.diag(d));
        }
    }

    // ---- IR output ------------------------------------------------------------------

    fn motion(&mut self, span: Span, kind: MotionKind, to: Joints, written: AxisSet) -> Block {
        self.ir = to;
        Block::new(
            span,
            BlockKind::Motion(Motion {
                kind,
                target: Target::Joints(to),
                feed: self.feed,
                written,
                machine_frame: false,
                extra: String::new(),
            }),
        )
    }

    fn z_move(&mut self, span: Span, z: f64, rapid: bool, out: &mut Vec<Block>) {
        let mut to = self.ir;
        to.set(Axis::Z, z);
        let kind = if rapid {
            MotionKind::Rapid
        } else {
            self.feed.rate = Some(self.opt.plunge_feed);
            MotionKind::Linear
        };
        let b = self.motion(span, kind, to, [Axis::Z].into_iter().collect());
        out.push(b);
    }

    fn xy_move(&mut self, span: Span, p: (f64, f64), kind: MotionKind, out: &mut Vec<Block>) {
        let mut to = self.ir;
        to.set(Axis::X, p.0);
        to.set(Axis::Y, p.1);
        let b = self.motion(span, kind, to, [Axis::X, Axis::Y].into_iter().collect());
        out.push(b);
    }

    /// Retracts to the safe height unless the tool is there.
    fn ensure_safe(&mut self, span: Span, out: &mut Vec<Block>) {
        if self.ir.get(Axis::Z) != Some(self.opt.safe_z) {
            self.z_move(span, self.opt.safe_z, true, out);
        }
    }

    /// Writes the pending travel; `to` (mm) is where the tool must be in XY.
    fn go_to(&mut self, span: Span, to: (f64, f64), out: &mut Vec<Block>) {
        self.travel = None;
        let here = (self.ir.get(Axis::X), self.ir.get(Axis::Y));
        if here == (Some(to.0), Some(to.1)) {
            return;
        }
        self.ensure_safe(span, out);
        self.xy_move(span, to, MotionKind::Rapid, out);
    }

    fn spindle(&mut self, span: Span, out: &mut Vec<Block>) {
        if self.spindle_on {
            return;
        }
        self.spindle_on = true;
        if self.opt.spindle_rpm > 0.0 {
            out.push(command_block(span, format!("M3 S{}", self.opt.spindle_rpm)));
        }
    }

    /// Down to `depth` below zero at the plunge feed, from the approach height.
    fn plunge(&mut self, span: Span, depth: f64, out: &mut Vec<Block>) {
        let at = self.mm(self.pos);
        self.go_to(span, at, out);
        self.ensure_safe(span, out);
        self.spindle(span, out);
        if self.opt.approach_z < self.opt.safe_z {
            self.z_move(span, self.opt.approach_z, true, out);
        }
        self.z_move(span, -depth, false, out);
    }

    /// Lifts the pen: a drill mark becomes a hole, a cut retracts.
    fn end_stroke(&mut self, span: Span, out: &mut Vec<Block>) {
        match self.stroke {
            Stroke::Up => {}
            Stroke::Down { drill: false, .. } => {}
            Stroke::Down { drill: true, span } => {
                self.plunge(span, self.opt.drill_depth, out);
                self.z_move(span, self.opt.safe_z, true, out);
            }
            Stroke::Cutting => self.z_move(span, self.opt.safe_z, true, out),
        }
        self.stroke = Stroke::Up;
    }

    /// The pen goes down at the current position.
    fn pen_down(&mut self, span: Span) {
        if self.stroke == Stroke::Up {
            self.stroke = Stroke::Down { drill: true, span };
        }
    }

    /// Moves the pen to `to` (plotter units) in its current state.
    fn move_to(&mut self, span: Span, to: (f64, f64), out: &mut Vec<Block>) {
        if self.stroke == Stroke::Up {
            self.pos = to;
            self.travel = Some((self.mm(to), span));
            return;
        }
        if to == self.pos {
            return;
        }
        if let Stroke::Down { .. } = self.stroke {
            self.plunge(span, self.opt.cut_depth, out);
            self.stroke = Stroke::Cutting;
        }
        self.pos = to;
        self.feed.rate = Some(self.opt.cut_feed);
        let p = self.mm(to);
        self.xy_move(span, p, MotionKind::Linear, out);
        if let Some((_, cut)) = &mut self.polygon {
            *cut = true;
        }
    }

    /// An arc about `center` (plotter units) through `sweep` degrees (counter-clockwise
    /// positive, in plotter space) from the current position.
    fn arc_to(&mut self, span: Span, center: (f64, f64), sweep: f64, out: &mut Vec<Block>) {
        let (sx, sy) = (self.pos.0 - center.0, self.pos.1 - center.1);
        if sweep == 0.0 || (sx == 0.0 && sy == 0.0) {
            return;
        }
        let turns = (sweep.abs() / 360.0 + 1e-12).floor();
        let full = turns >= 1.0;
        let end = if full {
            self.pos
        } else {
            let (s, c) = sweep.to_radians().sin_cos();
            (center.0 + sx * c - sy * s, center.1 + sx * s + sy * c)
        };
        if self.stroke == Stroke::Up {
            // A pen-up arc draws nothing: travel to its end.
            self.pos = end;
            self.travel = Some((self.mm(end), span));
            return;
        }
        if let Stroke::Down { .. } = self.stroke {
            self.plunge(span, self.opt.cut_depth, out);
            self.stroke = Stroke::Cutting;
        }
        self.pos = end;
        self.feed.rate = Some(self.opt.cut_feed);
        let c = self.mm(center);
        let arc = Arc {
            clockwise: sweep < 0.0,
            plane: Plane::XY,
            center: Vector3::new(c.0, c.1, 0.0),
            extra_turns: if full { turns as u32 - 1 } else { 0 },
        };
        let p = self.mm(end);
        self.xy_move(span, p, MotionKind::Arc(arc), out);
        if let Some((_, cut)) = &mut self.polygon {
            *cut = true;
        }
    }

    /// The closing edge of a polygon-mode subpolygon, when it has cut edges.
    fn close_subpolygon(&mut self, span: Span, out: &mut Vec<Block>) {
        if let Some((start, true)) = self.polygon
            && self.pos != start
            && self.stroke != Stroke::Up
        {
            self.move_to(span, start, out);
        }
    }

    // ---- Commands -------------------------------------------------------------------

    /// Lowers one command into `out`.
    pub fn command(&mut self, cmd: &Command, out: &mut Vec<Block>, diags: &mut Vec<Diagnostic>) {
        self.last_span = Some(cmd.span);
        let span = cmd.span;
        match &cmd.mnemonic {
            b"LB" => {
                self.warn_once(
                    cmd,
                    diags,
                    Diagnostic::warning("hpgl::label", "labels (LB) are not cut").with_help(
                        "plot text as strokes (vector font) in the CAD program to cut it",
                    ),
                );
                out.push(comment_block(
                    span,
                    format!("HPGL label: {}", String::from_utf8_lossy(&cmd.text[2..])),
                ));
                return;
            }
            b"DT" => return,
            b"CO" => {
                let text: Vec<String> = cmd
                    .params
                    .iter()
                    .map(|p| match &p.value {
                        Value::Str(s) => s.clone(),
                        Value::Num(v) => v.to_string(),
                    })
                    .collect();
                out.push(comment_block(span, text.join(" ")));
                return;
            }
            _ => {}
        }
        let nums = match cmd.numbers() {
            Ok(n) => n,
            Err(d) => {
                diags.push(d);
                return;
            }
        };
        match &cmd.mnemonic {
            b"IN" => {
                self.end_stroke(span, out);
                self.absolute = true;
                self.ip = None;
                self.sc = None;
                self.scaling = None;
                self.polygon = None;
            }
            b"PA" | b"PR" => {
                self.absolute = cmd.mnemonic == *b"PA";
                self.moves(cmd, &nums, out, diags);
            }
            b"PU" => {
                self.close_subpolygon(span, out);
                self.end_stroke(span, out);
                self.moves(cmd, &nums, out, diags);
                if let Some((start, cut)) = &mut self.polygon {
                    // A pen-up move starts a new subpolygon.
                    *start = self.pos;
                    *cut = false;
                }
            }
            b"PD" => {
                self.pen_down(span);
                self.moves(cmd, &nums, out, diags);
            }
            b"SP" => self.select_pen(cmd, &nums, out, diags),
            b"CI" => self.circle(cmd, &nums, out, diags),
            b"AA" | b"AR" => self.arc(cmd, &nums, out, diags),
            b"IP" => self.input_points(cmd, &nums, diags),
            b"SC" => self.scale_points(cmd, nums, diags),
            b"LT" => {
                if !nums.is_empty() {
                    self.warn_once(
                        cmd,
                        diags,
                        Diagnostic::warning(
                            "hpgl::line-type",
                            "line types (dashes) are cut as solid lines",
                        ),
                    );
                }
            }
            b"VS" => {}
            b"PM" => self.polygon_mode(cmd, &nums, out),
            b"EP" | b"FP" => self.polygon_edges(cmd, diags),
            _ => self.pass_on(cmd, out, diags),
        }
    }

    /// `EP`, `FP`: nothing to cut beyond the polygon's edges (one warning).
    fn polygon_edges(&mut self, cmd: &Command, diags: &mut Vec<Diagnostic>) {
        self.warn_once(
            cmd,
            diags,
            Diagnostic::warning(
                "hpgl::polygon",
                format!(
                    "{}: polygons are cut along their edges as they are defined, once; edge and fill commands add nothing",
                    cmd.name()
                ),
            ),
        );
    }

    /// `IP`: the scaling points P1 and P2, in plotter units.
    fn input_points(&mut self, cmd: &Command, nums: &[f64], diags: &mut Vec<Diagnostic>) {
        match nums.len() {
            0 => self.ip = None,
            2 => match self.ip {
                Some([x1, y1, x2, y2]) => {
                    self.ip = Some([nums[0], nums[1], nums[0] + x2 - x1, nums[1] + y2 - y1])
                }
                None => self.ip = Some([nums[0], nums[1], f64::NAN, f64::NAN]),
            },
            4 => self.ip = Some([nums[0], nums[1], nums[2], nums[3]]),
            n => {
                diags.push(
                    cmd.diag(Diagnostic::error(
                        "hpgl::parameters",
                        format!("IP takes 0, 2 or 4 numbers, not {n}"),
                    ))
                    .with_help("write `IP p1x,p1y,p2x,p2y;`"),
                );
                return;
            }
        }
        self.rescale(cmd, diags);
    }

    /// `SC`: the user units the scaling points stand for.
    fn scale_points(&mut self, cmd: &Command, nums: Vec<f64>, diags: &mut Vec<Diagnostic>) {
        if !matches!(nums.len(), 0 | 4..=7) {
            diags.push(
                cmd.diag(Diagnostic::error(
                    "hpgl::parameters",
                    format!("SC takes 0 or 4 to 7 numbers, not {}", nums.len()),
                ))
                .with_help("write `SC xmin,xmax,ymin,ymax;`"),
            );
            return;
        }
        self.sc = (!nums.is_empty()).then_some(nums);
        self.rescale(cmd, diags);
    }

    /// A command that does not move the pen: a comment (with a warning unless it only
    /// sets up the plotter).
    fn pass_on(&mut self, cmd: &Command, out: &mut Vec<Block>, diags: &mut Vec<Diagnostic>) {
        let span = cmd.span;
        if !NO_GEOMETRY.contains(&cmd.mnemonic) {
            self.warn_once(
            cmd,
            diags,
            Diagnostic::warning(
                "hpgl::ignored",
                format!("{} does not move the pen; passed on as a comment", cmd.name()),
            )
            .with_help("the frontend cuts IN SP PU PD PA PR CI AA AR; IP SC LT VS PM EP FP are understood"),
        );
        }
        let mut text = String::from_utf8_lossy(&cmd.text).into_owned();
        if text.len() > 200 {
            let mut end = 200;
            while !text.is_char_boundary(end) {
                end -= 1;
            }
            text.truncate(end);
            text.push_str("...");
        }
        out.push(comment_block(span, format!("HPGL {text}")));
    }

    /// Pairs of coordinates of `PA`, `PR`, `PU`, `PD`, in the current mode.
    fn moves(
        &mut self,
        cmd: &Command,
        nums: &[f64],
        out: &mut Vec<Block>,
        diags: &mut Vec<Diagnostic>,
    ) {
        for pair in nums.chunks(2) {
            let [x, y] = pair else {
                let p = &cmd.params[nums.len() - 1];
                diags.push(
                    cmd.diag_at(
                        Diagnostic::error(
                            "hpgl::odd-coordinates",
                            format!(
                                "{} ends with an X without a Y (an odd count of numbers: {})",
                                cmd.name(),
                                nums.len()
                            ),
                        ),
                        p.start,
                        p.end,
                    )
                    .with_label("X without Y")
                    .with_help("coordinates come in x,y pairs"),
                );
                return;
            };
            let to = if self.absolute {
                self.to_plotter(*x, *y)
            } else {
                let d = self.delta_to_plotter(*x, *y);
                (self.pos.0 + d.0, self.pos.1 + d.1)
            };
            self.move_to(cmd.span, to, out);
        }
    }

    fn select_pen(
        &mut self,
        cmd: &Command,
        nums: &[f64],
        out: &mut Vec<Block>,
        diags: &mut Vec<Diagnostic>,
    ) {
        let span = cmd.span;
        let n = match nums {
            [] => 0.0,
            [n] => *n,
            _ => {
                return diags.push(
                    cmd.diag(Diagnostic::error(
                        "hpgl::parameters",
                        format!("SP takes one pen number, not {}", nums.len()),
                    ))
                    .with_help("write `SP1;`"),
                );
            }
        };
        if !(n >= 0.0 && n.fract() == 0.0 && n <= 1e6) {
            let p = &cmd.params[0];
            return diags.push(
                cmd.diag_at(
                    Diagnostic::error("hpgl::pen", format!("`{n}` is not a pen number")),
                    p.start,
                    p.end,
                )
                .with_help("pens are numbered 0 (none), 1, 2, ..."),
            );
        }
        let n = n as u32;
        self.close_subpolygon(span, out);
        self.end_stroke(span, out);
        if n == 0 {
            // No pen: the plotter puts the pen away; the spindle stops.
            if self.spindle_on {
                self.spindle_on = false;
                if self.opt.spindle_rpm > 0.0 {
                    out.push(command_block(span, "M5".into()));
                }
            }
            return;
        }
        if self.tool == Some(n) {
            return;
        }
        self.tool = Some(n);
        self.ensure_safe(span, out);
        if self.spindle_on {
            self.spindle_on = false;
            if self.opt.spindle_rpm > 0.0 {
                out.push(command_block(span, "M5".into()));
            }
        }
        if self.opt.tool_change.is_empty() {
            out.push(comment_block(span, format!("pen {n}")));
        } else {
            out.push(command_block(
                span,
                self.opt.tool_change.replace("{n}", &n.to_string()),
            ));
        }
    }

    fn circle(
        &mut self,
        cmd: &Command,
        nums: &[f64],
        out: &mut Vec<Block>,
        diags: &mut Vec<Diagnostic>,
    ) {
        let span = cmd.span;
        let Some(&r) = nums.first().filter(|_| nums.len() <= 2) else {
            return diags.push(
                cmd.diag(Diagnostic::error(
                    "hpgl::parameters",
                    format!(
                        "CI takes a radius and a chord angle, not {} numbers",
                        nums.len()
                    ),
                ))
                .with_help("write `CI radius;` or `CI radius,chord;`"),
            );
        };
        if r == 0.0 {
            return;
        }
        self.anisotropic(cmd, diags);
        // The radius in plotter units along X; a negative radius starts at 180 degrees.
        let rp = self.delta_to_plotter(r, 0.0).0;
        let center = self.pos;
        let was = self.stroke;
        self.close_subpolygon(span, out);
        self.end_stroke(span, out);
        // Pen up to the start, down, round, up, back to the centre.
        self.move_to(span, (center.0 + rp, center.1), out);
        self.stroke = Stroke::Down { drill: false, span };
        self.arc_to(span, center, 360.0, out);
        self.end_stroke(span, out);
        self.move_to(span, center, out);
        if was != Stroke::Up {
            self.stroke = Stroke::Down { drill: false, span };
        }
    }

    fn arc(
        &mut self,
        cmd: &Command,
        nums: &[f64],
        out: &mut Vec<Block>,
        diags: &mut Vec<Diagnostic>,
    ) {
        if !matches!(nums.len(), 3 | 4) {
            return diags.push(
                cmd.diag(Diagnostic::error(
                    "hpgl::parameters",
                    format!(
                        "{} takes a centre, an angle and a chord angle, not {} numbers",
                        cmd.name(),
                        nums.len()
                    ),
                ))
                .with_help("write `AA x,y,angle;`"),
            );
        }
        self.anisotropic(cmd, diags);
        let center = if cmd.mnemonic == *b"AA" {
            self.to_plotter(nums[0], nums[1])
        } else {
            let d = self.delta_to_plotter(nums[0], nums[1]);
            (self.pos.0 + d.0, self.pos.1 + d.1)
        };
        // A mirroring scale turns the sense of rotation.
        let flip = self.scaling.is_some_and(|s| s.fx * s.fy < 0.0);
        let sweep = if flip { -nums[2] } else { nums[2] };
        self.arc_to(cmd.span, center, sweep, out);
    }

    /// Warns (once) that arcs under unequal X and Y scales are drawn as circles.
    fn anisotropic(&mut self, cmd: &Command, diags: &mut Vec<Diagnostic>) {
        if let Some(s) = self.scaling
            && (s.fx.abs() - s.fy.abs()).abs() > 1e-9 * s.fx.abs().max(s.fy.abs())
            && self.warned.insert(("hpgl::anisotropic-arc", [0; 2]))
        {
            diags.push(cmd.diag(
                Diagnostic::warning(
                    "hpgl::anisotropic-arc",
                    "the X and Y scales differ: arcs and circles are cut as circles (radius along X), not as ellipses",
                )
                .with_help("use isotropic scaling (`SC ...,1`) for drawings with arcs"),
            ));
        }
    }

    fn polygon_mode(&mut self, cmd: &Command, nums: &[f64], out: &mut Vec<Block>) {
        let span = cmd.span;
        match nums.first().copied().unwrap_or(0.0) {
            0.0 => self.polygon = Some((self.pos, false)),
            1.0 => {
                self.close_subpolygon(span, out);
                // The next subpolygon starts here.
                self.polygon = self.polygon.map(|_| (self.pos, false));
            }
            _ => {
                self.close_subpolygon(span, out);
                self.polygon = None;
            }
        }
    }

    /// Recomputes the scaling from `IP` and `SC`.
    fn rescale(&mut self, cmd: &Command, diags: &mut Vec<Diagnostic>) {
        let Some(sc) = &self.sc else {
            self.scaling = None;
            return;
        };
        let Some([p1x, p1y, p2x, p2y]) = self.ip.filter(|p| p.iter().all(|v| v.is_finite())) else {
            self.scaling = None;
            diags.push(cmd.diag(
                Diagnostic::warning(
                    "hpgl::scale-without-ip",
                    "SC without IP P1 and P2 is not applied: the plotter's default P1 and P2 depend on the device and paper",
                )
                .with_help("put `IP p1x,p1y,p2x,p2y;` before SC, or plot without scaling"),
            ));
            return;
        };
        let kind = sc.get(4).copied().unwrap_or(0.0);
        let bad = |what: &str| {
            cmd.diag(Diagnostic::error(
                "hpgl::scale",
                format!("SC {what}: the scaling is not applied"),
            ))
            .with_help("give xmin != xmax and ymin != ymax, and P1 != P2 in IP")
        };
        let s = if kind == 2.0 {
            // Point factor: xmin, xfactor, ymin, yfactor.
            let (xmin, fx, ymin, fy) = (sc[0], sc[1], sc[2], sc[3]);
            if fx == 0.0 || fy == 0.0 {
                self.scaling = None;
                return diags.push(bad("has a zero factor"));
            }
            Scaling {
                fx,
                fy,
                ox: p1x - xmin * fx,
                oy: p1y - ymin * fy,
            }
        } else {
            let (xmin, xmax, ymin, ymax) = (sc[0], sc[1], sc[2], sc[3]);
            if xmin == xmax || ymin == ymax || p1x == p2x || p1y == p2y {
                self.scaling = None;
                return diags.push(bad("maps a range of zero size"));
            }
            let fx = (p2x - p1x) / (xmax - xmin);
            let fy = (p2y - p1y) / (ymax - ymin);
            if kind == 1.0 {
                // Isotropic: the smaller factor for both, the slack shared by
                // `left` and `bottom` percent (default 50).
                let f = fx.abs().min(fy.abs());
                let (gx, gy) = (f * fx.signum(), f * fy.signum());
                let left = sc.get(5).copied().unwrap_or(50.0) / 100.0;
                let bottom = sc.get(6).copied().unwrap_or(50.0) / 100.0;
                let slack_x = (p2x - p1x) - gx * (xmax - xmin);
                let slack_y = (p2y - p1y) - gy * (ymax - ymin);
                Scaling {
                    fx: gx,
                    fy: gy,
                    ox: p1x + slack_x * left - xmin * gx,
                    oy: p1y + slack_y * bottom - ymin * gy,
                }
            } else {
                Scaling {
                    fx,
                    fy,
                    ox: p1x - xmin * fx,
                    oy: p1y - ymin * fy,
                }
            }
        };
        self.scaling = Some(s);
    }

    /// The end of the input: lift the pen, stop the spindle, end the program.
    pub fn finish(&mut self, out: &mut Vec<Block>) {
        let Some(span) = self.last_span else {
            return;
        };
        self.close_subpolygon(span, out);
        self.end_stroke(span, out);
        if let Some((p, s)) = self.travel {
            self.go_to(s, p, out);
        }
        if self.ir.get(Axis::Z).is_some() {
            self.ensure_safe(span, out);
        }
        if self.spindle_on {
            self.spindle_on = false;
            if self.opt.spindle_rpm > 0.0 {
                out.push(command_block(span, "M5".into()));
            }
        }
        if !self.opt.end_command.is_empty() {
            out.push(command_block(span, self.opt.end_command.clone()));
        }
    }
}
