//! The intermediate representation: a stream of [`Block`]s.
//!
//! # Invariants
//! Every frontend produces, every pass keeps and the validator (`valid`) checks:
//! 1. Every block carries the [`Span`] of the source line it came from; passes that split
//!    or add blocks give them the span of the block they stand for.
//! 2. Motion targets are absolute, in millimetres and degrees, after modal resolution:
//!    G90/G91, G20/G21, M82/M83 and G92 offsets are already applied, so a pass never
//!    re-derives modal state. Coordinates are in the *program frame without G92 offsets*
//!    (the frame the machine moves in continuously); [`OffsetChange`] blocks record the
//!    offsets a backend must add back when printing.
//! 3. An axis whose position is not known (program start, after homing or probing, after
//!    a line the frontend could not evaluate) is absent from [`Joints::known`]. Nothing
//!    prints or computes with an unknown axis value.
//! 4. Before inverse kinematics a target may be a tool [`Pose`] (tip point and unit tool
//!    axis); backends accept joint vectors only ([`Target::Joints`]).
//! 5. Nothing the frontend does not understand is dropped: comments, unknown words,
//!    meta commands and quoted strings travel in order as [`Command`], [`Verbatim`] or
//!    [`Comment`] data.
//! 6. All numbers are finite `f64`.

pub mod cycle;
pub mod dump;
mod modal;
mod printed;
pub use printed::as_printed;
mod track;

pub use modal::{CycleSeries, Dialect, Modal, MotionMode};
pub use track::{Step, Tracker};

use nalgebra::{Point3, Unit, Vector3};

/// The words of a command: UTF-8 text kept in place up to 23 bytes (`M3 S19.053`,
/// `M42 P0 S1`), shared on the heap beyond. It reads as a `&str`.
///
/// The polar printer's screw gets a new `M3 S…` on most moves (157,000 commands in 5 MB of
/// print G-code); as `String`s each was an allocation in one pass and a free in the
/// backend, often on the other thread.
///
/// ```
/// use ncpost::ir::Text;
/// let t = Text::from("M3 S19.053");
/// assert_eq!(t, "M3 S19.053");
/// assert!(t.starts_with("M3") && !t.is_heap_allocated());
/// ```
pub type Text = smol_str::SmolStr;

/// Where a block came from: the whole source line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Span {
    /// Byte offset of the line in the input.
    pub offset: u64,
    /// Length of the line in bytes, without its terminator.
    pub len: u32,
    /// 1-based line number.
    pub line: u32,
}

/// A machine axis. `E` is the extruder (or any feeder) axis of printers. In settings files
/// it is written as its letter (`"X"`).
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize, serde::Deserialize,
)]
pub enum Axis {
    /// Linear X.
    X,
    /// Linear Y.
    Y,
    /// Linear Z.
    Z,
    /// Rotary about X.
    A,
    /// Rotary about Y.
    B,
    /// Rotary about Z.
    C,
    /// Secondary linear parallel to X.
    U,
    /// Secondary linear parallel to Y.
    V,
    /// Secondary linear parallel to Z.
    W,
    /// Extruder.
    E,
}

/// Number of axes an IR position holds.
pub const AXIS_COUNT: usize = 10;

impl Axis {
    /// All axes, in index order (also the order they are printed in).
    pub const ALL: [Axis; AXIS_COUNT] = [
        Axis::X,
        Axis::Y,
        Axis::Z,
        Axis::A,
        Axis::B,
        Axis::C,
        Axis::U,
        Axis::V,
        Axis::W,
        Axis::E,
    ];

    /// Index into position arrays.
    pub fn index(self) -> usize {
        self as usize
    }

    /// The upper-case word letter.
    pub fn letter(self) -> char {
        b"XYZABCUVWE"[self.index()] as char
    }

    /// The axis a word letter names, either case.
    pub fn from_letter(letter: char) -> Option<Axis> {
        Some(match letter.to_ascii_uppercase() {
            'X' => Axis::X,
            'Y' => Axis::Y,
            'Z' => Axis::Z,
            'A' => Axis::A,
            'B' => Axis::B,
            'C' => Axis::C,
            'U' => Axis::U,
            'V' => Axis::V,
            'W' => Axis::W,
            'E' => Axis::E,
            _ => return None,
        })
    }

    /// A, B and C are rotary (degrees); the rest are lengths (mm).
    pub fn is_rotary(self) -> bool {
        matches!(self, Axis::A | Axis::B | Axis::C)
    }
}

/// A set of axes, as a bit mask.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Hash)]
pub struct AxisSet(u16);

impl AxisSet {
    /// No axis.
    pub const EMPTY: AxisSet = AxisSet(0);
    /// Every axis.
    pub const ALL: AxisSet = AxisSet((1 << AXIS_COUNT) - 1);
    /// X, Y and Z.
    pub const XYZ: AxisSet = AxisSet(0b111);

    /// Whether `axis` is in the set.
    pub fn contains(self, axis: Axis) -> bool {
        self.0 & (1 << axis.index()) != 0
    }
    /// Adds `axis`.
    pub fn insert(&mut self, axis: Axis) {
        self.0 |= 1 << axis.index();
    }
    /// Removes `axis`.
    pub fn remove(&mut self, axis: Axis) {
        self.0 &= !(1 << axis.index());
    }
    /// Whether the set is empty.
    pub fn is_empty(self) -> bool {
        self.0 == 0
    }
    /// Axes in both sets.
    pub fn intersection(self, other: AxisSet) -> AxisSet {
        AxisSet(self.0 & other.0)
    }
    /// Axes in `self` but not in `other`.
    pub fn difference(self, other: AxisSet) -> AxisSet {
        AxisSet(self.0 & !other.0)
    }
    /// Axes in either set.
    pub fn union(self, other: AxisSet) -> AxisSet {
        AxisSet(self.0 | other.0)
    }
    /// The axes in index order.
    pub fn iter(self) -> impl Iterator<Item = Axis> {
        // Lowest axis first.
        let mut bits = self.0 & AxisSet::ALL.0;
        std::iter::from_fn(move || {
            if bits == 0 {
                return None;
            }
            let i = bits.trailing_zeros() as usize;
            bits &= bits - 1;
            Some(Axis::ALL[i])
        })
    }
}

impl FromIterator<Axis> for AxisSet {
    fn from_iter<I: IntoIterator<Item = Axis>>(iter: I) -> Self {
        let mut set = AxisSet::EMPTY;
        for a in iter {
            set.insert(a);
        }
        set
    }
}

/// A joint vector: one value per axis, with the set of axes whose value is known.
///
/// Values of unknown axes are meaningless (kept at 0) and never printed.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Joints {
    /// Values in mm (linear) or degrees (rotary), indexed by [`Axis::index`].
    pub values: [f64; AXIS_COUNT],
    /// Axes whose value is known.
    pub known: AxisSet,
}

impl Joints {
    /// No axis known.
    pub const NONE: Joints = Joints {
        values: [0.0; AXIS_COUNT],
        known: AxisSet::EMPTY,
    };

    /// The same axes known, at the same values; what unknown axes hold is not compared
    /// (zero by invariant 3).
    ///
    /// ```
    /// use ncpost::ir::{Axis, Joints};
    /// let mut a = Joints::default();
    /// a.set(Axis::X, 1.0);
    /// let mut b = a;
    /// assert!(a.same_known(&b));
    /// b.set(Axis::Y, 0.0);
    /// assert!(!a.same_known(&b));
    /// ```
    pub fn same_known(&self, other: &Joints) -> bool {
        self.known == other.known
            && self
                .known
                .iter()
                .all(|a| self.values[a.index()] == other.values[a.index()])
    }

    /// These joints with every axis `update` knows taken from it: where a move to
    /// `update` ends.
    ///
    /// ```
    /// use ncpost::ir::{Axis, Joints};
    /// let mut at = Joints::default();
    /// at.set(Axis::X, 1.0);
    /// at.set(Axis::Y, 2.0);
    /// let mut to = Joints::default();
    /// to.set(Axis::Y, 5.0);
    /// to.set(Axis::E, 0.5);
    /// let end = at.updated_by(&to);
    /// assert_eq!((end.get(Axis::X), end.get(Axis::Y), end.get(Axis::E)), (Some(1.0), Some(5.0), Some(0.5)));
    /// assert_eq!(end.get(Axis::Z), None);
    /// ```
    pub fn updated_by(&self, update: &Joints) -> Joints {
        let mut values = self.values;
        for (k, v) in values.iter_mut().enumerate() {
            if update.known.contains(Axis::ALL[k]) {
                *v = update.values[k];
            }
        }
        Joints {
            values,
            known: self.known.union(update.known),
        }
    }

    /// The value of `axis`, if known.
    pub fn get(&self, axis: Axis) -> Option<f64> {
        self.known.contains(axis).then(|| self.values[axis.index()])
    }
    /// Sets `axis` to a known value.
    pub fn set(&mut self, axis: Axis, value: f64) {
        self.values[axis.index()] = value;
        self.known.insert(axis);
    }
    /// Forgets the value of the axes in `axes`.
    pub fn forget(&mut self, axes: AxisSet) {
        for a in axes.iter() {
            self.values[a.index()] = 0.0;
        }
        self.known = self.known.difference(axes);
    }
    /// The X, Y, Z values as a point, unknown ones as 0.
    pub fn xyz(&self) -> Point3<f64> {
        Point3::new(self.values[0], self.values[1], self.values[2])
    }
}

/// A tool pose in the part frame, before inverse kinematics.
///
/// Small enough to sit in a [`Target`] without making it larger than a joint vector, so
/// a CL point needs no allocation: the rare axes besides the pose are boxed instead.
#[derive(Debug, Clone, PartialEq)]
pub struct Pose {
    /// Tool tip point, mm.
    pub tip: Point3<f64>,
    /// Unit tool axis, pointing from the tip into the spindle.
    pub axis: Unit<Vector3<f64>>,
    /// Axes not covered by the pose (the extruder, secondary linears); `None` when there
    /// are none (see [`Pose::extra`]).
    pub extra_axes: Option<Box<Joints>>,
}

impl Pose {
    /// A pose with no other axes.
    pub fn new(tip: Point3<f64>, axis: Unit<Vector3<f64>>) -> Pose {
        Pose {
            tip,
            axis,
            extra_axes: None,
        }
    }

    /// The axes not covered by the pose ([`Joints::NONE`] when there are none).
    ///
    /// ```
    /// use nalgebra::{Point3, Vector3};
    /// use ncpost::ir::{Joints, Pose};
    /// let p = Pose::new(Point3::origin(), Vector3::z_axis());
    /// assert_eq!(p.extra(), &Joints::NONE);
    /// ```
    pub fn extra(&self) -> &Joints {
        self.extra_axes.as_deref().unwrap_or(&Joints::NONE)
    }
}

// A pose in a target costs no more room than a joint vector.
#[cfg(target_pointer_width = "64")]
const _: () = assert!(std::mem::size_of::<Pose>() <= std::mem::size_of::<Joints>());

/// Where a motion goes.
#[derive(Debug, Clone, PartialEq)]
pub enum Target {
    /// Machine axis values (G-code input, or after inverse kinematics).
    Joints(Joints),
    /// A tool pose (CL input, before inverse kinematics).
    Pose(Pose),
}

impl Target {
    /// The joint vector, if this target is one.
    pub fn joints(&self) -> Option<&Joints> {
        match self {
            Target::Joints(j) => Some(j),
            Target::Pose(_) => None,
        }
    }
    /// The joint vector, mutably.
    pub fn joints_mut(&mut self) -> Option<&mut Joints> {
        match self {
            Target::Joints(j) => Some(j),
            Target::Pose(_) => None,
        }
    }
}

/// The plane an arc lies in (G17, G18, G19).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Plane {
    /// G17: first axis X, second Y, normal Z.
    XY,
    /// G18: first axis Z, second X, normal Y.
    ZX,
    /// G19: first axis Y, second Z, normal X.
    YZ,
}

impl Plane {
    /// The (first, second, normal) axes; clockwise is seen from the normal's positive side.
    pub fn axes(self) -> (Axis, Axis, Axis) {
        match self {
            Plane::XY => (Axis::X, Axis::Y, Axis::Z),
            Plane::ZX => (Axis::Z, Axis::X, Axis::Y),
            Plane::YZ => (Axis::Y, Axis::Z, Axis::X),
        }
    }
    /// The G-code that selects the plane.
    pub fn gcode(self) -> &'static str {
        match self {
            Plane::XY => "G17",
            Plane::ZX => "G18",
            Plane::YZ => "G19",
        }
    }
}

/// A circular (or helical) arc.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Arc {
    /// G2 (true) or G3.
    pub clockwise: bool,
    /// The arc's plane.
    pub plane: Plane,
    /// Absolute centre (X, Y, Z; the component along the plane normal is unused), mm.
    pub center: Vector3<f64>,
    /// Full turns in addition to the partial arc (`P` minus one); 0 for a plain arc.
    pub extra_turns: u32,
}

/// Kind of a motion.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum MotionKind {
    /// G0.
    Rapid,
    /// G1.
    Linear,
    /// G2 or G3.
    Arc(Arc),
}

/// How F is interpreted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum FeedMode {
    /// G94: mm/min (deg/min when only rotary axes move).
    PerMinute,
    /// G93: the move takes 1/F minutes.
    InverseTime,
    /// G95: mm per spindle revolution.
    PerRevolution,
}

/// The feed in force for a motion.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Feed {
    /// Feed mode.
    pub mode: FeedMode,
    /// The rate in the mode's unit (converted to mm), if one has been set.
    pub rate: Option<f64>,
}

/// A move.
#[derive(Debug, Clone, PartialEq)]
pub struct Motion {
    /// Rapid, linear or arc.
    pub kind: MotionKind,
    /// The absolute target.
    pub target: Target,
    /// Feed in force.
    pub feed: Feed,
    /// Axes the source named on this block (kept so a move that changes nothing stays a
    /// move).
    pub written: AxisSet,
    /// G53: the target is in machine coordinates; afterwards the written axes are unknown
    /// in the program frame.
    pub machine_frame: bool,
    /// Words that ride on the move and are passed through as written (`S` laser power,
    /// `M63 P1`, tool vectors `I J K` under G43.5, ...), upper-case letters.
    pub extra: String,
}

/// A G92-family offset change.
#[derive(Debug, Clone, PartialEq)]
pub struct OffsetChange {
    /// Which code: `G92`, `G92.1`, `G92.2` or `G92.3`.
    pub code: OffsetCode,
    /// For G92: the program-frame values declared for the written axes.
    pub declared: Joints,
    /// The offsets in force afterwards (program = IR + offset), per axis.
    pub offsets: [f64; AXIS_COUNT],
}

/// The G92 family.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OffsetCode {
    /// G92: declare the current position.
    Set,
    /// G92.1: clear offsets (and forget them).
    Clear,
    /// G92.2: suspend offsets.
    Suspend,
    /// G92.3: restore suspended offsets.
    Restore,
}

impl OffsetCode {
    /// The G-code.
    pub fn gcode(self) -> &'static str {
        match self {
            OffsetCode::Set => "G92",
            OffsetCode::Clear => "G92.1",
            OffsetCode::Suspend => "G92.2",
            OffsetCode::Restore => "G92.3",
        }
    }
}

/// Controller modes a pass-through command was written in, so the backend can put the
/// controller into them before printing it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct WrittenModes {
    /// The command has axis words written in inches (G20).
    pub inch: bool,
    /// The command has axis words written in relative mode (G91).
    pub relative: bool,
    /// Extruder words were relative (M83, or G91).
    pub relative_e: bool,
    /// The arc plane, for a line that moves along arcs or runs a cycle (G2/G3, G73-G89)
    /// in it.
    pub plane: Option<Plane>,
}

/// A command the IR does not model, kept as its words (`M3 S12000`, `T2 M6`, `G28 X Y`).
#[derive(Debug, Clone, PartialEq)]
pub struct Command {
    /// The words as written, separated by single spaces, without line number,
    /// checksum or comments.
    pub text: Text,
    /// For a G code with coordinates (`G28 Z5`, `G38.2 Z-3`): the units and distance mode
    /// they were written in, which the backend puts the controller into first. `None`
    /// when the words do not depend on modes (`M3 S1000`, `M201 X2500`, `G28 X Y`).
    pub modes: Option<WrittenModes>,
    /// Axes whose position is unknown after it (homing, probing, macro calls).
    pub clobbers: AxisSet,
}

impl Command {
    /// `M2` / `M30`: the program ends here, and nothing runs after it.
    ///
    /// ```
    /// use ncpost::ir::{AxisSet, Command};
    /// let c = |t: &str| Command { text: t.into(), modes: None, clobbers: AxisSet::EMPTY };
    /// assert!(c("M30").ends_program() && c("m02").ends_program());
    /// assert!(!c("M3 S1000").ends_program() && !c("M0").ends_program());
    /// ```
    pub fn ends_program(&self) -> bool {
        self.has_m_code(&[2, 30])
    }

    /// `M0`, `M1`, `M2`, `M30`: the machine stops here (a pause, or the end), so
    /// anything left running (a spindle, a screw) keeps running in the stopped machine.
    ///
    /// ```
    /// use ncpost::ir::{AxisSet, Command};
    /// let c = |t: &str| Command { text: t.into(), modes: None, clobbers: AxisSet::EMPTY };
    /// assert!(c("M0").stops_machine() && c("M30").stops_machine());
    /// assert!(!c("M3 S1000").stops_machine());
    /// ```
    pub fn stops_machine(&self) -> bool {
        self.has_m_code(&[0, 1, 2, 30])
    }

    /// Whether one of the words is an M code numbered in `codes` (`M02` is M2).
    fn has_m_code(&self, codes: &[u32]) -> bool {
        self.text.split_whitespace().any(|w| {
            w.strip_prefix(['M', 'm'])
                .and_then(|n| n.parse::<u32>().ok())
                .is_some_and(|n| codes.contains(&n))
        })
    }
}

/// Why a line travels as text.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum VerbatimReason {
    /// Parameters, expressions or dialect statements the IR does not evaluate.
    Unevaluated,
    /// Control flow (o-words, RepRapFirmware meta commands) or a line inside it.
    ControlFlow,
    /// A subprogram body (Fanuc `O` program after the main program).
    Subprogram,
    /// The `%` tape delimiter or an `O` program number.
    Delimiter,
}

/// A line passed through exactly as written.
#[derive(Debug, Clone, PartialEq)]
pub struct Verbatim {
    /// The source line, without its terminator.
    pub text: String,
    /// Why it was not lowered.
    pub reason: VerbatimReason,
    /// Axes whose position is unknown after it.
    pub clobbers: AxisSet,
    /// For a line at the top level: the modes it was written in, which the backend
    /// establishes before printing it. `None` inside control flow or a subprogram,
    /// where nothing may be inserted.
    pub modes: Option<WrittenModes>,
    /// The line changes none of units, distance and extruder modes.
    pub keeps_modes: bool,
    /// A canned-cycle line as the frontend resolved it (or why it could not): the
    /// [`Tracker`] takes the position after it from there.
    pub cycle: Option<cycle::CycleLine>,
}

impl Verbatim {
    /// Where the line leaves the axes it moves and the frontend knows the end of (a
    /// resolved canned cycle); these axes are also in `clobbers`, so a follower that does
    /// not read this forgets them.
    pub fn ends_at(&self) -> Option<&Joints> {
        self.cycle.as_ref()?.resolved().map(|c| &c.end)
    }

    /// Follows the line from `pos`: the axes it clobbers become unknown, then those it
    /// [ends at](Verbatim::ends_at) are known there.
    pub fn follow(&self, pos: &mut Joints) {
        pos.forget(self.clobbers);
        if let Some(end) = self.ends_at() {
            for a in end.known.iter() {
                pos.set(a, end.values[a.index()]);
            }
        }
    }
}

/// How a comment was written.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CommentStyle {
    /// `( ... )`.
    Paren,
    /// `; ...`.
    Semicolon,
}

/// A comment; `text` excludes the delimiters.
#[derive(Debug, Clone, PartialEq)]
pub struct Comment {
    /// The comment text.
    pub text: String,
    /// How it was written.
    pub style: CommentStyle,
}

/// What a block does.
#[derive(Debug, Clone, PartialEq)]
pub enum BlockKind {
    /// A move.
    Motion(Motion),
    /// G4: wait.
    Dwell {
        /// Seconds.
        seconds: f64,
    },
    /// G92 family.
    Offset(OffsetChange),
    /// A command passed through as words.
    Command(Command),
    /// A line passed through as text.
    Verbatim(Verbatim),
    /// A line that holds only comments (they are in [`Block::comments`]).
    Comment,
}

/// The comment a frontend adds to the statement that sets a rotated coordinate frame it
/// does not apply to the tool poses that follow (NX `MSYS` under `msys = "ignore"`, APT
/// `CSYS`). A pass that finds tool axes it cannot reach says so in its help: the frame
/// may be why.
pub const FRAME_NOT_APPLIED: &str = " ncpost: rotated frame not applied to the points";

/// Whether `block` carries the [`FRAME_NOT_APPLIED`] note.
///
/// ```
/// use ncpost::ir::{Block, BlockKind, Comment, CommentStyle, Span, FRAME_NOT_APPLIED, frame_not_applied};
/// let mut b = Block::new(Span::default(), BlockKind::Comment);
/// assert!(!frame_not_applied(&b));
/// b.comments.push(Comment { text: FRAME_NOT_APPLIED.into(), style: CommentStyle::Semicolon });
/// assert!(frame_not_applied(&b));
/// ```
pub fn frame_not_applied(block: &Block) -> bool {
    block.comments.iter().any(|c| c.text == FRAME_NOT_APPLIED)
}

/// One statement of the program.
#[derive(Debug, Clone, PartialEq)]
pub struct Block {
    /// The source line.
    pub span: Span,
    /// What it does.
    pub kind: BlockKind,
    /// Comments written on the line, in order.
    pub comments: Vec<Comment>,
}

// Every pass moves each block at least once: the size bound keeps that cheap.
#[cfg(target_pointer_width = "64")]
const _: () = assert!(std::mem::size_of::<Block>() <= 256);

impl Block {
    /// A block with no comments.
    pub fn new(span: Span, kind: BlockKind) -> Block {
        Block {
            span,
            kind,
            comments: Vec::new(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The bit-by-bit iteration gives every set's axes in index order, as filtering
    /// [`Axis::ALL`] does.
    #[test]
    fn axis_sets_iterate_in_index_order() {
        for (i, a) in Axis::ALL.iter().enumerate() {
            assert_eq!(a.index(), i);
        }
        for mask in 0..(1u16 << AXIS_COUNT) {
            let set = AxisSet(mask);
            let filtered: Vec<Axis> = Axis::ALL.into_iter().filter(|&a| set.contains(a)).collect();
            assert_eq!(set.iter().collect::<Vec<_>>(), filtered, "{mask:#b}");
        }
    }
}
