//! A polar machine: a turntable θ and a radial arm r (seed 002, the pellet printer), with
//! its screw extruder and valve.
//!
//! The controller interpolates r and θ linearly, as a Cartesian firmware would with r on
//! one axis and θ (degrees) on another, so F applies to the Euclidean joint distance
//! (`controller.feed_rule = "euclidean"`).

use serde::{Deserialize, Serialize};

use super::Controller;
use crate::ir::Axis;

/// A polar machine definition (the `[polar]` table of a preset).
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
    /// The arm may pass through the centre to negative r.
    pub negative_r: bool,
    /// Highest table speed, deg/s.
    pub omega_max: f64,
    /// Highest table acceleration, deg/s².
    pub alpha_max: f64,
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
            omega_max: 180.0,
            alpha_max: 360.0,
            controller: Controller::default(),
        }
    }
}
