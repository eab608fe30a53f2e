//! Firmware flavours: what a controller does with the printed words that a time model, a
//! check or a backend depends on. Each fact lives here once, as a plain method of
//! [`Flavour`], with its source:
//!
//! | fact | RRF (FDM / CNC) | Grbl 1.1 | LinuxCNC | Marlin 2 | Klipper |
//! |---|---|---|---|---|---|
//! | `G0` speed ([`Flavour::rapid_rule`]) | modal F / `M203` caps | `$110`.. caps | max velocity | modal F | modal F |
//! | minimum speed, mm/min ([`Flavour::min_speed`]) | 30 (`M203 I`) | 1 (`MINIMUM_FEED_RATE`) | none | 0 (`M205 S`) | none |
//! | F kept to ([`Flavour::feed_digits`]) | 7 digits (float) | 7 digits (float) | 15 (double) | 7 (float) | 15 (double) |
//! | `G4 P` ([`Flavour::dwell`]) | whole ms (`S`: s) | s | s | whole ms (`S`: s) | ms |
//! | arc end off its circle ([`Flavour::arc_tolerance`]) | accepted | error beyond 0.005 mm and 0.1 % (or 0.5 mm) | error beyond 0.0283 mm and 0.1 % | accepted | accepted |
//! | program end ([`Flavour::program_end`]) | `M2`/`M0`; nothing after runs (`M30` deletes a file) | `M30`/`M2`; streamed lines after still run | `M30`/`M2`; nothing after runs | none (`M30` deletes a file); the file's end | none; the file's end |
//! | codes ([`Flavour::has`]) | G93 from 3.5, no cycles | G93, no cycles | G93, cycles | no G93 | no G93, arcs if configured |
//!
//! Sources: the RepRapFirmware G-code dictionary
//! (<https://docs.duet3d.com/en/User_manual/Reference/Gcodes>: `M203 I` "minimum overall
//! movement speed, default 30 mm/min"; `G4 P` milliseconds, `S` seconds; `G93` from 3.5;
//! `M584 S` NIST feed rule); Grbl 1.1 (`config.h` `MINIMUM_FEED_RATE 1.0 // (mm/min)`;
//! `gcode.c`: "[Arc definition error] > 0.005mm AND 0.1% radius", and beyond 0.5 mm
//! always; the Grbl wiki's "Grbl v1.1 Commands": `G4 P` in seconds, `M2`/`M30` program end,
//! no canned cycles); LinuxCNC (G-code reference <https://linuxcnc.org/docs/html/gcode/g-code.html>:
//! `G4 P` seconds, `G81`–`G89`, `G93`; `rs274ngc`: `CENTER_ARC_RADIUS_TOLERANCE_MM` is
//! 2 × 0.01 × √2 mm, `SPIRAL_RELATIVE_TOLERANCE` 0.001; M2/M30 end the program); Marlin
//! (<https://marlinfw.org/docs/gcode/G004.html>: `P` milliseconds, `S` seconds;
//! `M205 S` minimum feedrate, default 0); Klipper (<https://www.klipper3d.org/G-Codes.html>:
//! `G4 P<milliseconds>`, `G2`/`G3` only with `[gcode_arcs]`).
//!
//! The flavour is part of the [`Controller`](super::Controller) of a machine or polar
//! definition; a preset that names none gets the one its backend prints for (see
//! `Preset::from_toml`).

use serde::{Deserialize, Serialize};

/// A firmware, as far as the printed program's meaning differs between them.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Flavour {
    /// RepRapFirmware 3 in FDM mode (M451): `G0` is `G1`, at the modal F.
    RrfFdm,
    /// RepRapFirmware 3 in CNC or laser mode (M453/M452): `G0` at the `M203` caps.
    RrfCnc,
    /// Grbl 1.1: `G0` at the `$110`–`$112` caps; `G4 P` in seconds.
    Grbl,
    /// LinuxCNC: `G0` at the axes' maximum velocity; `G4 P` in seconds; canned cycles.
    Linuxcnc,
    /// Marlin 2: `G0` is `G1`, at the modal F.
    Marlin,
    /// Klipper: `G0` is `G1`, at the modal F.
    Klipper,
}

/// How fast a `G0` runs on the controller.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RapidRule {
    /// At the modal F, the same F as `G1` (FDM firmwares: `G0` is a `G1`).
    ModalFeed,
    /// As fast as the slowest moving axis's cap allows (`M203`, `$110`): F is ignored.
    MaxSpeed,
    /// At a fixed speed the run gives (`rapid_feed`): a controller ncpost has no model
    /// of.
    Fixed,
}

/// The unit a `G4 P` counts in, and how finely the firmware keeps it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DwellUnit {
    /// `P` counts milliseconds and the firmware truncates it to whole ones (`G4 P97.584`
    /// waits 97 ms); `S` gives seconds.
    WholeMilliseconds,
    /// `P` counts milliseconds, fractions kept.
    Milliseconds,
    /// `P` counts seconds, fractions kept.
    Seconds,
}

impl DwellUnit {
    /// The wait a `G4 P` of `p` gives, seconds.
    ///
    /// ```
    /// use ncpost::machine::DwellUnit;
    /// assert_eq!(DwellUnit::WholeMilliseconds.seconds(97.584), 0.097);
    /// assert_eq!(DwellUnit::Seconds.seconds(0.5), 0.5);
    /// ```
    pub fn seconds(self, p: f64) -> f64 {
        match self {
            DwellUnit::WholeMilliseconds => p.trunc() / 1000.0,
            DwellUnit::Milliseconds => p / 1000.0,
            DwellUnit::Seconds => p,
        }
    }
}

/// How far an arc's end may lie off the circle through its start about its centre before
/// the controller refuses the block: it refuses when the two radii differ by more than
/// both `absolute` and `relative` times the radius, or by more than `always`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ArcTolerance {
    /// mm.
    pub absolute: f64,
    /// A share of the radius.
    pub relative: f64,
    /// mm beyond which any radius is refused (infinite where the relative rule alone
    /// decides).
    pub always: f64,
}

impl ArcTolerance {
    /// Whether an arc of start radius `r` whose end radius differs by `dr` (mm) is
    /// refused.
    ///
    /// ```
    /// use ncpost::machine::Flavour;
    /// let grbl = Flavour::Grbl.arc_tolerance().unwrap();
    /// assert!(!grbl.refuses(10.0, 0.009));
    /// assert!(grbl.refuses(10.0, 0.011));
    /// assert!(!grbl.refuses(1.0, 0.004));
    /// // Beyond 0.5 mm Grbl refuses whatever the radius.
    /// assert!(grbl.refuses(1000.0, 0.6));
    /// ```
    pub fn refuses(&self, r: f64, dr: f64) -> bool {
        let dr = dr.abs();
        dr > self.always || (dr > self.absolute && dr > self.relative * r.abs())
    }
}

/// How a program ends on the controller.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ProgramEnd {
    /// The codes that end a program, the preferred one first.
    pub codes: &'static [&'static str],
    /// Lines printed after the end still run (a streamed or file-printing firmware goes
    /// on reading); otherwise nothing after it does, so a stop that must happen goes
    /// before it.
    pub later_lines_run: bool,
}

/// A code whose existence differs between firmwares.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Code {
    /// `G93` inverse time feed.
    InverseTime,
    /// `G81`–`G89` canned cycles.
    CannedCycles,
    /// `G2`/`G3` arcs.
    Arcs,
}

impl Flavour {
    /// How fast `G0` runs.
    ///
    /// ```
    /// use ncpost::machine::{Flavour, RapidRule};
    /// assert_eq!(Flavour::RrfFdm.rapid_rule(), RapidRule::ModalFeed);
    /// assert_eq!(Flavour::Grbl.rapid_rule(), RapidRule::MaxSpeed);
    /// ```
    pub fn rapid_rule(self) -> RapidRule {
        match self {
            Flavour::RrfFdm | Flavour::Marlin | Flavour::Klipper => RapidRule::ModalFeed,
            Flavour::RrfCnc | Flavour::Grbl | Flavour::Linuxcnc => RapidRule::MaxSpeed,
        }
    }

    /// The minimum speed the firmware runs a feed move at unless configured otherwise,
    /// mm/min (slower F is raised to it); 0 when it has none.
    ///
    /// ```
    /// use ncpost::machine::Flavour;
    /// assert_eq!(Flavour::RrfCnc.min_speed(), 30.0);
    /// assert_eq!(Flavour::Grbl.min_speed(), 1.0);
    /// assert_eq!(Flavour::Linuxcnc.min_speed(), 0.0);
    /// ```
    pub fn min_speed(self) -> f64 {
        match self {
            // `M203 I`, default 30 mm/min (0.5 mm/s).
            Flavour::RrfFdm | Flavour::RrfCnc => RRF_MIN_SPEED,
            // `MINIMUM_FEED_RATE`, compiled in.
            Flavour::Grbl => 1.0,
            // `M205 S`, default 0; Klipper and LinuxCNC have none.
            Flavour::Marlin | Flavour::Klipper | Flavour::Linuxcnc => 0.0,
        }
    }

    /// Where the minimum speed is set, for a message that asks to lower it.
    ///
    /// ```
    /// use ncpost::machine::Flavour;
    /// assert!(Flavour::RrfCnc.min_speed_setting().contains("M203 I"));
    /// ```
    pub fn min_speed_setting(self) -> &'static str {
        match self {
            Flavour::RrfFdm | Flavour::RrfCnc => "`M203 I` in config.g (mm/min)",
            Flavour::Grbl => "`MINIMUM_FEED_RATE` in Grbl's config.h (a rebuild)",
            Flavour::Marlin => "`M205 S` (mm/s)",
            Flavour::Klipper | Flavour::Linuxcnc => "nothing: this firmware has no minimum",
        }
    }

    /// The significant digits of F the firmware keeps: a 32-bit float keeps about 7, a
    /// double about 15. More printed digits change nothing on the machine.
    ///
    /// ```
    /// use ncpost::machine::Flavour;
    /// use ncpost::num::print::FEED_MAX_DECIMALS;
    /// // The printer's most decimals still name distinct feeds down to F0.1.
    /// assert!(u32::from(FEED_MAX_DECIMALS) < Flavour::Grbl.feed_digits());
    /// ```
    pub fn feed_digits(self) -> u32 {
        match self {
            Flavour::RrfFdm | Flavour::RrfCnc | Flavour::Grbl | Flavour::Marlin => 7,
            Flavour::Linuxcnc | Flavour::Klipper => 15,
        }
    }

    /// What `G4 P` counts (RepRapFirmware and Marlin also read `G4 S` as seconds).
    ///
    /// ```
    /// use ncpost::machine::{DwellUnit, Flavour};
    /// assert_eq!(Flavour::RrfCnc.dwell(), DwellUnit::WholeMilliseconds);
    /// assert_eq!(Flavour::Grbl.dwell(), DwellUnit::Seconds);
    /// ```
    pub fn dwell(self) -> DwellUnit {
        match self {
            Flavour::RrfFdm | Flavour::RrfCnc | Flavour::Marlin => DwellUnit::WholeMilliseconds,
            Flavour::Klipper => DwellUnit::Milliseconds,
            Flavour::Grbl | Flavour::Linuxcnc => DwellUnit::Seconds,
        }
    }

    /// How far an arc's end may be off its circle before the controller stops on the
    /// block; `None` for firmwares that run such an arc anyway.
    ///
    /// ```
    /// use ncpost::machine::Flavour;
    /// assert_eq!(Flavour::Grbl.arc_tolerance().unwrap().absolute, 0.005);
    /// assert!(Flavour::RrfFdm.arc_tolerance().is_none());
    /// ```
    pub fn arc_tolerance(self) -> Option<ArcTolerance> {
        match self {
            Flavour::Grbl => Some(ArcTolerance {
                absolute: 0.005,
                relative: 0.001,
                always: 0.5,
            }),
            Flavour::Linuxcnc => Some(ArcTolerance {
                absolute: 2.0 * 0.01 * std::f64::consts::SQRT_2,
                relative: 0.001,
                always: f64::INFINITY,
            }),
            Flavour::RrfFdm | Flavour::RrfCnc | Flavour::Marlin | Flavour::Klipper => None,
        }
    }

    /// How a program ends.
    ///
    /// ```
    /// use ncpost::machine::Flavour;
    /// assert_eq!(Flavour::Linuxcnc.program_end().codes[0], "M30");
    /// assert!(!Flavour::Linuxcnc.program_end().later_lines_run);
    /// ```
    pub fn program_end(self) -> ProgramEnd {
        match self {
            // RepRapFirmware's `M30` deletes a file; `M0` (and `M2`) end the file print and
            // run `stop.g`.
            Flavour::RrfFdm | Flavour::RrfCnc => ProgramEnd {
                codes: &["M2", "M0"],
                later_lines_run: false,
            },
            // Marlin's `M30` deletes a file too and `M0` waits for the user: the program ends
            // with the file.
            Flavour::Marlin | Flavour::Klipper => ProgramEnd {
                codes: &[],
                later_lines_run: true,
            },
            Flavour::Grbl => ProgramEnd {
                codes: &["M30", "M2"],
                later_lines_run: true,
            },
            Flavour::Linuxcnc => ProgramEnd {
                codes: &["M30", "M2"],
                later_lines_run: false,
            },
        }
    }

    /// Whether the firmware has `code` (RepRapFirmware's `G93` needs 3.5 or newer).
    ///
    /// ```
    /// use ncpost::machine::{Code, Flavour};
    /// assert!(Flavour::Linuxcnc.has(Code::CannedCycles));
    /// assert!(!Flavour::Marlin.has(Code::InverseTime));
    /// ```
    pub fn has(self, code: Code) -> bool {
        match code {
            Code::InverseTime => matches!(
                self,
                Flavour::RrfFdm | Flavour::RrfCnc | Flavour::Grbl | Flavour::Linuxcnc
            ),
            Code::CannedCycles => self == Flavour::Linuxcnc,
            // Klipper only with a `[gcode_arcs]` section; Marlin with ARC_SUPPORT (on by
            // default).
            Code::Arcs => self != Flavour::Klipper,
        }
    }
}

/// RepRapFirmware's minimum speed when `M203 I` does not set one, mm/min.
pub const RRF_MIN_SPEED: f64 = 30.0;
