//! Presets: a pipeline (frontend options, passes, backend and its options) in one TOML
//! file. Built-in presets live in `passes/` and are embedded in the binary.

use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::back::{gcode, grbl, rrf};
use crate::diag::Diagnostic;
use crate::front;
use crate::machine::{Controller, DwellUnit, Flavour, Machine};

/// The output format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Emit {
    /// RepRapFirmware 3.x.
    Rrf,
    /// Plain ISO/LinuxCNC G-code.
    #[default]
    Gcode,
    /// Grbl 1.1 (plain G-code restricted to Grbl's words; subprograms expanded).
    Grbl,
    /// The IR text dump.
    Ir,
}

/// One pass of a preset.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PassSpec {
    /// The pass name (see `ncpost passes`).
    pub name: String,
    /// Its options.
    #[serde(default)]
    pub options: toml::Table,
}

/// A pipeline definition.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Preset {
    /// One line about what it is for.
    pub description: String,
    /// Output format.
    pub emit: Emit,
    /// Passes, in order.
    pub passes: Vec<PassSpec>,
    /// The machine the kinematics, feed and limits passes compute for.
    pub machine: Option<Machine>,
    /// A polar machine (turntable and radial arm), for the polar passes.
    pub polar: Option<crate::machine::polar::Polar>,
    /// G-code frontend options.
    pub gcode_input: front::gcode::Options,
    /// APT CL frontend options.
    pub cl_input: front::cl::Options,
    /// HPGL frontend options (pen to cutter: depths, heights, feeds, spindle).
    pub hpgl_input: front::hpgl::Options,
    /// Plain G-code backend options.
    pub gcode: gcode::Options,
    /// RepRapFirmware backend options.
    pub rrf: rrf::Options,
    /// Grbl backend options.
    pub grbl: grbl::Options,
    /// Tolerances of `ncpost run --verify` (the readback of the printed program).
    pub verify: crate::readback::Settings,
}

/// Built-in presets: (name, TOML text).
pub const BUILTIN: &[(&str, &str)] = &[
    ("default", include_str!("../passes/default.toml")),
    ("duet-cnc", include_str!("../passes/duet-cnc.toml")),
    ("emoc-x5", include_str!("../passes/emoc-x5.toml")),
    ("trunnion-bc", include_str!("../passes/trunnion-bc.toml")),
    ("head-table", include_str!("../passes/head-table.toml")),
    ("head-head-ab", include_str!("../passes/head-head-ab.toml")),
    (
        "polar-printer",
        include_str!("../passes/polar-printer.toml"),
    ),
    ("pcb-mill", include_str!("../passes/pcb-mill.toml")),
];

impl Preset {
    /// Parses preset TOML text.
    ///
    /// ```
    /// let p = ncpost::preset::Preset::from_toml("emit = \"rrf\"\n[[passes]]\nname = \"verify\"\n").unwrap();
    /// assert_eq!(p.passes[0].name, "verify");
    /// ```
    pub fn from_toml(text: &str) -> Result<Preset, Diagnostic> {
        let mut preset: Preset = toml::from_str(text)
            .map_err(|e: toml::de::Error| Diagnostic::settings(e.to_string()))?;
        preset.resolve_flavours();
        Ok(preset)
    }

    /// Gives the controllers that name no firmware flavour the one this preset's
    /// backend prints for: RepRapFirmware in FDM mode for a polar printer and in CNC
    /// mode otherwise, Grbl, LinuxCNC for plain G-code.
    ///
    /// ```
    /// use ncpost::machine::Flavour;
    /// let p = ncpost::preset::Preset::builtin("polar-printer").unwrap();
    /// assert_eq!(p.polar.unwrap().controller.flavour, Some(Flavour::RrfFdm));
    /// ```
    pub fn resolve_flavours(&mut self) {
        let Some(flavour) = self.backend_flavour() else {
            return;
        };
        for c in [
            self.polar.as_mut().map(|p| &mut p.controller),
            self.machine.as_mut().map(|m| &mut m.controller),
        ]
        .into_iter()
        .flatten()
        {
            c.flavour.get_or_insert(flavour);
        }
        // The target controller refuses an arc whose end is off its circle beyond its own
        // tolerance (Grbl: error:33 beyond 0.005 mm and 0.1 % of the radius, and the job
        // stops there): the frontend's check is no looser, so such an arc is an error
        // at its line and column (`strict_arcs = false` keeps it).
        let target = self.controller().and_then(|c| c.flavour).unwrap_or(flavour);
        if let Some(t) = target.arc_tolerance() {
            let tol = &mut self.gcode_input.arc_tolerance;
            *tol = tol.min(t.absolute);
        }
        // A plain G-code preset prints `G4 P` in the unit its controller reads: LinuxCNC
        // reads seconds, so `G4 P500` for half a second would wait 500 s there.
        if self.emit == Emit::Gcode
            && let Some(f) = self.controller().and_then(|c| c.flavour)
        {
            self.gcode
                .dwell_milliseconds
                .get_or_insert(f.dwell() != DwellUnit::Seconds);
        }
    }

    /// The firmware this preset's backend prints for: RepRapFirmware in FDM mode for a
    /// polar printer and in CNC mode otherwise, Grbl, LinuxCNC for plain G-code; none
    /// for the IR dump.
    ///
    /// ```
    /// use ncpost::machine::Flavour;
    /// use ncpost::preset::Preset;
    /// let p = |n| Preset::builtin(n).unwrap().backend_flavour();
    /// assert_eq!(p("pcb-mill"), Some(Flavour::Linuxcnc));
    /// assert_eq!(p("duet-cnc"), Some(Flavour::RrfCnc));
    /// ```
    pub fn backend_flavour(&self) -> Option<Flavour> {
        Some(match self.emit {
            Emit::Rrf if self.polar.is_some() => Flavour::RrfFdm,
            Emit::Rrf => Flavour::RrfCnc,
            Emit::Grbl => Flavour::Grbl,
            Emit::Gcode => Flavour::Linuxcnc,
            Emit::Ir => return None,
        })
    }

    /// The controller the run's timing follows: the polar machine's, else the
    /// machine's.
    pub fn controller(&self) -> Option<&Controller> {
        self.polar
            .as_ref()
            .map(|p| &p.controller)
            .or(self.machine.as_ref().map(|m| &m.controller))
    }

    /// A built-in preset by name.
    pub fn builtin(name: &str) -> Option<Preset> {
        BUILTIN
            .iter()
            .find(|(n, _)| *n == name)
            .and_then(|(_, text)| Preset::from_toml(text).ok())
    }

    /// A built-in preset by name, or else a preset file at that path.
    pub fn load(name_or_path: &str) -> Result<Preset, Diagnostic> {
        if let Some(p) = Preset::builtin(name_or_path) {
            return Ok(p);
        }
        let path = Path::new(name_or_path);
        if path.exists() {
            let text = std::fs::read_to_string(path).map_err(|e| {
                Diagnostic::settings(format!("cannot read preset {name_or_path}: {e}"))
            })?;
            return Preset::from_toml(&text).map_err(|e| {
                Diagnostic::settings(format!("preset {name_or_path}: {}", e.message))
            });
        }
        let names: Vec<&str> = BUILTIN.iter().map(|(n, _)| *n).collect();
        Err(Diagnostic::settings(format!(
            "no preset `{name_or_path}`: not a built-in ({}) and no such file",
            names.join(", ")
        )))
    }
}
