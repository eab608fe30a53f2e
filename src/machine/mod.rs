//! The machine model: axes, kinematics and controller facts of a two-rotary 5-axis machine.
//!
//! One definition (the `[machine]` table of a preset) describes the linear axes, the two
//! rotary axes (on the table or in the head, their direction, pivot, limits, preference and
//! calibration offset) and the controller (how it interprets F, its speed limits). The
//! kinematics passes (`ik`, `unwrap-rotary`, `densify`), `feed` and `limits` all read it.
//!
//! # Frames and conventions
//! - The *part frame* is the CL data's frame. When every rotary is at its kinematic zero
//!   it coincides with the *machine frame* the linear axes move in (the seed's rule: the
//!   CAM origin is the machine's work origin).
//! - Rotary joint values are degrees. A joint value `j` turns its element by
//!   `direction * (j - zero_offset)` degrees, right-handed about the +X, +Y or +Z machine
//!   direction of its letter (A, B, C). Table axes usually have `direction = -1`: a positive
//!   C turns the table clockwise seen from above, so the tool moves counter-clockwise
//!   around the part, as ISO requires.
//! - Rotaries are listed from the base outward: on a table, the first carries the second
//!   (a cradle A carrying a C table); in a head, the first carries the second (a C fork
//!   carrying an A tilt). A table pivot is a point on the axis in the machine frame at zero;
//!   a head pivot is a point on the axis relative to the tool tip at zero, so a head pivot
//!   includes the tool length.
//! - X, Y, Z are the tool tip's position in the machine frame when the head rotaries are
//!   at zero (the usual "tool tip" control point with tool length compensation).

pub mod angle;
mod chain;
mod config_g;
mod flavour;
pub mod grid;
mod inverse;
pub mod polar;

pub use chain::{PathEnd, ToolPose, Turns};
pub use flavour::{ArcTolerance, Code, DwellUnit, Flavour, ProgramEnd, RRF_MIN_SPEED, RapidRule};
pub use inverse::{Orientation, Solutions};

use serde::{Deserialize, Serialize};

use crate::diag::Diagnostic;
use crate::ir::Axis;

/// Where a rotary axis sits.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Mount {
    /// It turns the part.
    Table,
    /// It turns the tool.
    Head,
}

/// The letter of a rotary axis: A about X, B about Y, C about Z.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum RotaryLetter {
    /// About X.
    A,
    /// About Y.
    B,
    /// About Z.
    C,
}

impl RotaryLetter {
    /// The coordinate index (0 = X, 1 = Y, 2 = Z) of the direction it turns about.
    pub fn index(self) -> usize {
        match self {
            RotaryLetter::A => 0,
            RotaryLetter::B => 1,
            RotaryLetter::C => 2,
        }
    }

    /// The IR axis.
    pub fn axis(self) -> Axis {
        match self {
            RotaryLetter::A => Axis::A,
            RotaryLetter::B => Axis::B,
            RotaryLetter::C => Axis::C,
        }
    }
}

/// Which of the two inverse-kinematics solutions a machine prefers when limits and
/// continuity do not decide.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Prefer {
    /// The solution where this axis is positive (or zero).
    Positive,
    /// The solution where this axis is negative (or zero).
    Negative,
    /// No preference.
    #[default]
    None,
}

/// One rotary axis.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Rotary {
    /// A, B or C.
    pub axis: RotaryLetter,
    /// Table or head.
    pub on: Mount,
    /// +1 or -1: the sense a positive joint value turns the element in.
    #[serde(default = "one")]
    pub direction: f64,
    /// A point on the axis: machine frame at zero (table) or relative to the tool tip at
    /// zero (head), mm.
    #[serde(default)]
    pub pivot: [f64; 3],
    /// Lowest joint value, degrees (none for a cyclic axis).
    #[serde(default)]
    pub min: Option<f64>,
    /// Highest joint value, degrees.
    #[serde(default)]
    pub max: Option<f64>,
    /// The axis turns without end; any angle plus a multiple of 360 is the same pose.
    #[serde(default)]
    pub cyclic: bool,
    /// Which solution to take when limits and continuity do not decide.
    #[serde(default)]
    pub prefer: Prefer,
    /// Calibration: the joint value at which the axis is at its true kinematic zero
    /// (from `bed.g` probing), degrees.
    #[serde(default)]
    pub zero_offset: f64,
}

fn one() -> f64 {
    1.0
}

/// Travel of a linear axis, mm.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Travel {
    /// Lowest position.
    pub min: f64,
    /// Highest position.
    pub max: f64,
}

/// The linear axes' travel.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Linear {
    /// X travel.
    #[serde(rename = "X")]
    pub x: Travel,
    /// Y travel.
    #[serde(rename = "Y")]
    pub y: Travel,
    /// Z travel.
    #[serde(rename = "Z")]
    pub z: Travel,
}

/// How the controller turns F into time (SPEC §2, §8).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FeedRule {
    /// NIST RS274NGC 2.1.2.5, as RepRapFirmware and LinuxCNC in G94: F is the XYZ speed
    /// (mm/min) when any of X, Y, Z moves, otherwise the rotary speed (deg/min).
    #[default]
    Nist,
    /// G93: each move takes 1/F minutes.
    InverseTime,
    /// F is the Euclidean speed over all joints (mm and degrees mixed).
    Euclidean,
}

/// Per-axis values (mm or degrees based), for axes the machine has.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PerAxis {
    /// X.
    #[serde(rename = "X", default, skip_serializing_if = "Option::is_none")]
    pub x: Option<f64>,
    /// Y.
    #[serde(rename = "Y", default, skip_serializing_if = "Option::is_none")]
    pub y: Option<f64>,
    /// Z.
    #[serde(rename = "Z", default, skip_serializing_if = "Option::is_none")]
    pub z: Option<f64>,
    /// A.
    #[serde(rename = "A", default, skip_serializing_if = "Option::is_none")]
    pub a: Option<f64>,
    /// B.
    #[serde(rename = "B", default, skip_serializing_if = "Option::is_none")]
    pub b: Option<f64>,
    /// C.
    #[serde(rename = "C", default, skip_serializing_if = "Option::is_none")]
    pub c: Option<f64>,
}

impl PerAxis {
    /// The value for `axis`, if given.
    pub fn get(&self, axis: Axis) -> Option<f64> {
        match axis {
            Axis::X => self.x,
            Axis::Y => self.y,
            Axis::Z => self.z,
            Axis::A => self.a,
            Axis::B => self.b,
            Axis::C => self.c,
            _ => None,
        }
    }
}

/// Per-axis driver assignments for `M584` (`"0.0"`, `"0.1:0.2"`).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Drivers {
    /// X.
    #[serde(rename = "X", default, skip_serializing_if = "Option::is_none")]
    pub x: Option<String>,
    /// Y.
    #[serde(rename = "Y", default, skip_serializing_if = "Option::is_none")]
    pub y: Option<String>,
    /// Z.
    #[serde(rename = "Z", default, skip_serializing_if = "Option::is_none")]
    pub z: Option<String>,
    /// A.
    #[serde(rename = "A", default, skip_serializing_if = "Option::is_none")]
    pub a: Option<String>,
    /// B.
    #[serde(rename = "B", default, skip_serializing_if = "Option::is_none")]
    pub b: Option<String>,
    /// C.
    #[serde(rename = "C", default, skip_serializing_if = "Option::is_none")]
    pub c: Option<String>,
}

impl Drivers {
    /// The driver of `axis`, if given.
    pub fn get(&self, axis: Axis) -> Option<&str> {
        match axis {
            Axis::X => self.x.as_deref(),
            Axis::Y => self.y.as_deref(),
            Axis::Z => self.z.as_deref(),
            Axis::A => self.a.as_deref(),
            Axis::B => self.b.as_deref(),
            Axis::C => self.c.as_deref(),
            _ => None,
        }
    }
}

/// How the controller's time is modelled (the motion-time model, one layer up, implements them).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Timing {
    /// No acceleration: every block runs at its speed from start to end.
    #[default]
    ConstantVelocity,
    /// Trapezoidal speed profiles with per-axis acceleration and jerk-limited junctions.
    Trapezoid,
}

impl std::str::FromStr for Timing {
    type Err = Diagnostic;
    /// `constant-velocity` or `trapezoid`.
    fn from_str(s: &str) -> Result<Self, Diagnostic> {
        match s {
            "constant-velocity" => Ok(Timing::ConstantVelocity),
            "trapezoid" => Ok(Timing::Trapezoid),
            _ => Err(Diagnostic::settings(format!(
                "unknown timing `{s}`; use constant-velocity or trapezoid"
            ))),
        }
    }
}

/// What the controller does with F and how fast it can go.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Controller {
    /// How F is interpreted.
    pub feed_rule: FeedRule,
    /// The controller never moves slower than this, mm/min: a slower F is raised to it,
    /// so the block runs faster than programmed. Unset: the flavour's own
    /// ([`Flavour::min_speed`]: RepRapFirmware 30 mm/min, `M203 I` lowers it; Grbl 1;
    /// LinuxCNC none), RepRapFirmware's without a flavour ([`RRF_MIN_SPEED`]). Read it
    /// with [`Controller::min_speed`].
    #[serde(skip_serializing_if = "Option::is_none")]
    pub min_speed: Option<f64>,
    /// Highest speed per axis, mm/min or deg/min (`M203`).
    pub max_feed: PerAxis,
    /// Acceleration per axis, mm/s² or deg/s² (`M201`).
    pub acceleration: PerAxis,
    /// Stepper drivers per axis (`M584`); axes without one are left out.
    pub drivers: Drivers,
    /// How time is modelled (`constant-velocity` or `trapezoid`).
    pub timing: Timing,
    /// Motion blocks the trapezoid model plans ahead (a firmware's queue length).
    pub lookahead: usize,
    /// Instantaneous speed change allowed per axis at a junction, mm/min or deg/min
    /// (RepRapFirmware `M566`); an axis without one stops to change speed.
    pub jerk: PerAxis,
    /// The firmware (`rrf-fdm`, `rrf-cnc`, `grbl`, `linuxcnc`, `marlin`, `klipper`); a
    /// preset that names none gets the one of its backend. Without one, rapids run at a
    /// fixed `rapid_feed`.
    pub flavour: Option<Flavour>,
}

impl Controller {
    /// The controller of `flavour`'s firmware as it comes: its minimum speed, `G0` rule
    /// and dwell unit, no caps (a preset without a machine is timed and read back so).
    ///
    /// ```
    /// use ncpost::machine::{Controller, Flavour};
    /// assert_eq!(Controller::of(Some(Flavour::Grbl)).min_speed(), 1.0);
    /// ```
    pub fn of(flavour: Option<Flavour>) -> Controller {
        Controller {
            flavour,
            ..Controller::default()
        }
    }

    /// The lowest speed the controller moves at, mm/min: the one set, else the
    /// flavour's.
    ///
    /// ```
    /// use ncpost::machine::{Controller, Flavour};
    /// let linuxcnc = Controller { flavour: Some(Flavour::Linuxcnc), ..Controller::default() };
    /// assert_eq!(linuxcnc.min_speed(), 0.0);
    /// assert_eq!(Controller::default().min_speed(), 30.0);
    /// let set = Controller { min_speed: Some(6.0), ..linuxcnc };
    /// assert_eq!(set.min_speed(), 6.0);
    /// ```
    pub fn min_speed(&self) -> f64 {
        self.min_speed
            .unwrap_or_else(|| self.flavour.map_or(RRF_MIN_SPEED, Flavour::min_speed))
    }

    /// How fast `G0` runs on this controller ([`RapidRule::Fixed`] without a flavour).
    pub fn rapid_rule(&self) -> RapidRule {
        self.flavour.map_or(RapidRule::Fixed, Flavour::rapid_rule)
    }

    /// Where this controller's minimum speed is set, for a message that asks to lower it
    /// (RepRapFirmware's `M203 I` without a flavour).
    ///
    /// ```
    /// use ncpost::machine::{Controller, Flavour};
    /// let grbl = Controller { flavour: Some(Flavour::Grbl), ..Controller::default() };
    /// assert!(grbl.min_speed_setting().contains("MINIMUM_FEED_RATE"));
    /// assert!(Controller::default().min_speed_setting().contains("M203 I"));
    /// ```
    pub fn min_speed_setting(&self) -> &'static str {
        self.flavour.unwrap_or(Flavour::RrfCnc).min_speed_setting()
    }
}

impl Default for Controller {
    fn default() -> Self {
        Controller {
            feed_rule: FeedRule::Nist,
            min_speed: None,
            max_feed: PerAxis::default(),
            acceleration: PerAxis::default(),
            drivers: Drivers::default(),
            timing: Timing::ConstantVelocity,
            lookahead: 16,
            jerk: PerAxis::default(),
            flavour: None,
        }
    }
}

/// A two-rotary 5-axis machine.
///
/// ```
/// use ncpost::machine::Machine;
/// let m = Machine::from_toml(r#"
///     name = "cradle"
///     [[rotary]]
///     axis = "A"
///     on = "table"
///     direction = -1
///     pivot = [0, 0, 100]
///     min = -90
///     max = 135
///     [[rotary]]
///     axis = "C"
///     on = "table"
///     direction = -1
///     cyclic = true
/// "#).unwrap();
/// let pose = m.forward(&[10.0, 20.0, 30.0], [30.0, 45.0]);
/// let back = m.inverse(pose.axis);
/// let xyz = m.linear(&pose.tip, [30.0, 45.0]);
/// assert!((xyz[0] - 10.0).abs() < 1e-9 && (xyz[1] - 20.0).abs() < 1e-9 && (xyz[2] - 30.0).abs() < 1e-9);
/// assert!(back.iter().any(|o| (o.angles[0] - 30.0).abs() < 1e-9 && (o.angles[1] - 45.0).abs() < 1e-9));
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Machine {
    /// What the machine is.
    #[serde(default)]
    pub name: String,
    /// The two rotary axes, from the base outward.
    #[serde(deserialize_with = "two_rotaries")]
    pub rotary: [Rotary; 2],
    /// Linear travel (absent: unchecked).
    #[serde(default)]
    pub linear: Option<Linear>,
    /// The controller.
    #[serde(default)]
    pub controller: Controller,
}

/// The `[[rotary]]` tables of a machine definition: exactly two.
fn two_rotaries<'de, D: serde::Deserializer<'de>>(d: D) -> Result<[Rotary; 2], D::Error> {
    let list = Vec::<Rotary>::deserialize(d)?;
    <[Rotary; 2]>::try_from(list).map_err(|list| {
        serde::de::Error::custom(format!(
            "a machine needs exactly two rotary axes, this one has {}",
            list.len()
        ))
    })
}

/// Which elements the two rotaries sit on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Layout {
    /// Both turn the part (trunnion, cradle + table).
    TableTable,
    /// The first turns the part, the second the tool (in either listing order).
    HeadTable,
    /// Both turn the tool (fork head).
    HeadHead,
}

impl Machine {
    /// Parses and checks a machine definition (the body of a preset's `[machine]` table).
    pub fn from_toml(text: &str) -> Result<Machine, Diagnostic> {
        let m: Machine = toml::from_str(text).map_err(|e| Diagnostic::settings(e.to_string()))?;
        m.check()?;
        Ok(m)
    }

    /// Checks what serde cannot: rotaries about different directions, signs of ±1,
    /// limits in order, finite numbers.
    pub fn check(&self) -> Result<(), Diagnostic> {
        if self.rotary[0].axis == self.rotary[1].axis {
            return Err(Diagnostic::settings(format!(
                "both rotary axes are {:?}; they must turn about different directions",
                self.rotary[0].axis
            )));
        }
        for r in &self.rotary {
            let name = r.axis.axis().letter();
            if r.direction != 1.0 && r.direction != -1.0 {
                return Err(Diagnostic::settings(format!(
                    "rotary {name}: direction must be 1 or -1"
                )));
            }
            if !r.pivot.iter().all(|v| v.is_finite()) || !r.zero_offset.is_finite() {
                return Err(Diagnostic::settings(format!(
                    "rotary {name}: pivot and zero_offset must be finite"
                )));
            }
            match (r.cyclic, r.min, r.max) {
                (true, None, None) => {}
                (true, _, _) => {
                    return Err(Diagnostic::settings(format!(
                        "rotary {name}: a cyclic axis has no min or max; leave them out"
                    )));
                }
                (false, Some(lo), Some(hi)) if lo.is_finite() && hi.is_finite() && lo < hi => {}
                (false, _, _) => {
                    return Err(Diagnostic::settings(format!(
                        "rotary {name}: give min < max, or set cyclic = true"
                    )));
                }
            }
        }
        if let Some(l) = &self.linear {
            for (n, t) in [("X", l.x), ("Y", l.y), ("Z", l.z)] {
                if !(t.min.is_finite() && t.max.is_finite() && t.min < t.max) {
                    return Err(Diagnostic::settings(format!("linear {n}: give min < max")));
                }
            }
        }
        let min_speed = self.controller.min_speed();
        if !(min_speed.is_finite() && min_speed >= 0.0) {
            return Err(Diagnostic::settings(
                "controller.min_speed must be a finite number >= 0",
            ));
        }
        Ok(())
    }

    /// The layout.
    pub fn layout(&self) -> Layout {
        match (self.rotary[0].on, self.rotary[1].on) {
            (Mount::Table, Mount::Table) => Layout::TableTable,
            (Mount::Head, Mount::Head) => Layout::HeadHead,
            _ => Layout::HeadTable,
        }
    }

    /// The IR axes of the two rotaries, in listing order.
    pub fn rotary_axes(&self) -> [Axis; 2] {
        [self.rotary[0].axis.axis(), self.rotary[1].axis.axis()]
    }

    /// The rotary that drives `axis`, with its index.
    pub fn rotary_of(&self, axis: Axis) -> Option<(usize, &Rotary)> {
        self.rotary
            .iter()
            .enumerate()
            .find(|(_, r)| r.axis.axis() == axis)
    }

    /// The limits of `axis` (linear or rotary), `None` when unlimited or unknown.
    pub fn limits(&self, axis: Axis) -> Option<(f64, f64)> {
        if let Some((_, r)) = self.rotary_of(axis) {
            return match (r.cyclic, r.min, r.max) {
                (false, Some(lo), Some(hi)) => Some((lo, hi)),
                _ => None,
            };
        }
        let l = self.linear.as_ref()?;
        let t = match axis {
            Axis::X => l.x,
            Axis::Y => l.y,
            Axis::Z => l.z,
            _ => return None,
        };
        Some((t.min, t.max))
    }

    /// The `config.g` fragment (M584, M208, M203, M201) for RepRapFirmware.
    pub fn config_g(&self) -> String {
        config_g::write(self)
    }
}

/// The `[machine]` table of the built-in preset file `passes/<name>.toml`, for the tests
/// of the machine and of the passes that use one.
#[cfg(test)]
pub(crate) fn builtin(name: &str) -> Machine {
    let path = format!("{}/passes/{name}.toml", env!("CARGO_MANIFEST_DIR"));
    let text = std::fs::read_to_string(path).expect("built-in preset file");
    let preset: toml::Table = toml::from_str(&text).expect("preset TOML");
    let table = preset.get("machine").expect("a [machine] table").clone();
    table.try_into().expect("a valid machine")
}
