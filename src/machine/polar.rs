//! A polar machine: a turntable θ and a radial arm r (seed 002, the pellet printer), with
//! its screw extruder and valve.
//!
//! The controller interpolates r and θ linearly, as a Cartesian firmware would with r on
//! one axis and θ (degrees) on another, so F applies to the Euclidean joint distance
//! (`controller.feed_rule = "euclidean"`).
//!
//! The arm reaches `0..=r_max`, or `-r_max..=r_max` when `negative_r` says it can pass
//! through the centre. The screw and valve settings are read by the passes that set the
//! extrusion rate and time the valve; `polar-ik` reads the axes, the arm range, the table
//! limits and the origin policy.

use serde::{Deserialize, Serialize};

use super::Controller;
use crate::diag::Diagnostic;
use crate::ir::Axis;

/// What the motion does where the path meets the table centre (r = 0).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum OriginPolicy {
    /// The arm crosses the centre to negative r: a line through the origin keeps θ and r
    /// passes through zero (needs `negative_r = true`).
    SignedRadius,
    /// The arm stops at the centre, the table turns on the spot, the arm goes on.
    RotateInPlace,
}

/// The screw extruder (seed 002 §2): a speed command turns it, so material follows from
/// revolutions, not from an E axis.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Screw {
    /// The slicer's E units (mm of filament) one screw revolution delivers.
    pub e_per_rev: f64,
    /// Highest screw speed, rev/min.
    pub max_rpm: f64,
    /// Lowest screw speed that still extrudes steadily, rev/min (0: no floor).
    pub min_rpm: f64,
    /// The command that sets the screw speed; `{rpm}` is replaced by the speed.
    pub rpm_command: String,
}

impl Default for Screw {
    fn default() -> Self {
        Screw {
            e_per_rev: 1.0,
            max_rpm: 100.0,
            min_rpm: 0.0,
            rpm_command: "M3 S{rpm}".into(),
        }
    }
}

/// The solenoid valve that closes the screw's outlet (seed 002 §4.3): it reacts late, so
/// its commands must be issued ahead of the extrusion they belong to.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Valve {
    /// From the open command to material flowing, s.
    pub open_delay_s: f64,
    /// From the close command to the flow stopping, s.
    pub close_delay_s: f64,
    /// The command that opens the valve.
    pub open_command: String,
    /// The command that closes the valve.
    pub close_command: String,
}

impl Default for Valve {
    fn default() -> Self {
        Valve {
            open_delay_s: 0.2,
            close_delay_s: 0.1,
            open_command: "M42 P0 S1".into(),
            close_command: "M42 P0 S0".into(),
        }
    }
}

/// A polar machine definition (the `[polar]` table of a preset).
///
/// ```
/// use ncpost::machine::polar::{OriginPolicy, Polar};
/// let p: Polar = toml::from_str("negative_r = true\n[valve]\nopen_delay_s = 0.3\n").unwrap();
/// assert_eq!(p.origin_policy(), OriginPolicy::SignedRadius);
/// assert_eq!(p.valve.close_command, "M42 P0 S0");
/// assert!(p.check().is_ok());
/// ```
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Polar {
    /// What the machine is.
    pub name: String,
    /// The axis letter r is emitted as (mm).
    pub r_axis: Axis,
    /// The axis letter θ is emitted as (degrees, continuous).
    pub theta_axis: Axis,
    /// Largest radius the arm reaches, mm.
    pub r_max: f64,
    /// The arm may pass through the centre to negative r (its range is then
    /// `-r_max..=r_max`, otherwise `0..=r_max`).
    pub negative_r: bool,
    /// What happens at the centre; unset: `signed-radius` when `negative_r`, else
    /// `rotate-in-place`.
    pub origin: Option<OriginPolicy>,
    /// Highest table speed, deg/s.
    pub omega_max: f64,
    /// Highest table acceleration, deg/s².
    pub alpha_max: f64,
    /// The screw extruder.
    pub screw: Screw,
    /// The valve on the screw's outlet.
    pub valve: Valve,
    /// Feed rule, speeds and accelerations of the controller (per emitted axis).
    pub controller: Controller,
}

impl Default for Polar {
    fn default() -> Self {
        Polar {
            name: String::new(),
            r_axis: Axis::X,
            theta_axis: Axis::Y,
            r_max: 150.0,
            negative_r: false,
            origin: None,
            omega_max: 180.0,
            alpha_max: 360.0,
            screw: Screw::default(),
            valve: Valve::default(),
            controller: Controller::default(),
        }
    }
}

fn positive(value: f64, what: &str) -> Result<(), Diagnostic> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(Diagnostic::settings(format!(
            "polar: {what} must be a positive number (got {value})"
        )))
    }
}

fn non_negative(value: f64, what: &str) -> Result<(), Diagnostic> {
    if value.is_finite() && value >= 0.0 {
        Ok(())
    } else {
        Err(Diagnostic::settings(format!(
            "polar: {what} must be zero or more (got {value})"
        )))
    }
}

impl Polar {
    /// The origin policy in force: `origin`, or the one `negative_r` implies.
    pub fn origin_policy(&self) -> OriginPolicy {
        self.origin.unwrap_or(if self.negative_r {
            OriginPolicy::SignedRadius
        } else {
            OriginPolicy::RotateInPlace
        })
    }

    /// Smallest radius the arm reaches, mm.
    pub fn r_min(&self) -> f64 {
        if self.negative_r { -self.r_max } else { 0.0 }
    }

    /// Reports the first invalid setting.
    ///
    /// ```
    /// let mut p = ncpost::machine::polar::Polar::default();
    /// p.theta_axis = p.r_axis;
    /// assert!(p.check().is_err());
    /// ```
    pub fn check(&self) -> Result<(), Diagnostic> {
        if self.r_axis == self.theta_axis {
            return Err(Diagnostic::settings(
                "polar: r_axis and theta_axis must be different axes",
            ));
        }
        if self.r_axis == Axis::E || self.theta_axis == Axis::E {
            return Err(Diagnostic::settings(
                "polar: E is the extruder; r and θ need other axis letters",
            ));
        }
        if self.r_axis.is_rotary() {
            return Err(Diagnostic::settings(format!(
                "polar: r is a length; {} is a rotary axis letter",
                self.r_axis.letter()
            )));
        }
        positive(self.r_max, "r_max")?;
        positive(self.omega_max, "omega_max")?;
        positive(self.alpha_max, "alpha_max")?;
        if self.origin_policy() == OriginPolicy::SignedRadius && !self.negative_r {
            return Err(Diagnostic::settings(
                "polar: origin = \"signed-radius\" needs an arm that passes the centre (negative_r = true)",
            ));
        }
        positive(self.screw.e_per_rev, "screw.e_per_rev")?;
        positive(self.screw.max_rpm, "screw.max_rpm")?;
        non_negative(self.screw.min_rpm, "screw.min_rpm")?;
        if self.screw.min_rpm > self.screw.max_rpm {
            return Err(Diagnostic::settings(
                "polar: screw.min_rpm is above screw.max_rpm",
            ));
        }
        if !self.screw.rpm_command.contains("{rpm}") {
            return Err(Diagnostic::settings(
                "polar: screw.rpm_command must contain {rpm}",
            ));
        }
        non_negative(self.valve.open_delay_s, "valve.open_delay_s")?;
        non_negative(self.valve.close_delay_s, "valve.close_delay_s")?;
        if self.valve.open_command.trim().is_empty() || self.valve.close_command.trim().is_empty() {
            return Err(Diagnostic::settings(
                "polar: valve.open_command and valve.close_command must not be empty",
            ));
        }
        Ok(())
    }
}
