//! Firmware flavours: what a controller does with the printed words a time model depends
//! on (so far: how fast a `G0` runs).
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
}
