//! `--verify`: where the readback meets the pipeline. The programmed path is tapped at
//! the input of the first machine pass (`ik`, `polar-ik`, `densify`; without one, at the
//! backend's input) into a queue, and the printed bytes are teed to the readback as the
//! backend writes them; the readback reads both in step, so neither the path nor the
//! text is kept.

use std::collections::VecDeque;
use std::io::Write;
use std::sync::{Arc, Mutex};

use crate::diag::Diagnostic;
use crate::ir::Block;
use crate::machine::Controller;
use crate::motion::{Model, Timing};
use crate::preset::{Emit, Preset};
use crate::readback::{Checker, Kinematics, Queue, Reader, Tap, Tolerances, Verifier};

/// The passes the programmed path is tapped before (the first of them in the preset).
const MACHINE_PASSES: [&str; 3] = ["ik", "polar-ik", "densify"];

/// Whether and how a pipeline verifies.
pub(super) struct Mode {
    on: bool,
    /// The run-wide timing (`--timing`), over the controller's.
    timing: Option<Timing>,
}

/// The mode of a pipeline of `preset`: `on` when the run says, else the preset's
/// `[verify] enabled`, else off.
pub(super) fn mode(on: Option<bool>, preset: &Preset, timing: Option<Timing>) -> Mode {
    Mode {
        on: on.or(preset.verify.enabled).unwrap_or(false),
        timing,
    }
}

/// Whether `preset` verifies on the command line when the run does not say: its
/// `[verify] enabled`, else when it has a `[machine]` or `[polar]` table.
///
/// ```
/// use ncpost::preset::Preset;
/// let p = |n| Preset::builtin(n).unwrap();
/// assert!(ncpost::pipeline::verify_by_default(&p("polar-printer")));
/// assert!(!ncpost::pipeline::verify_by_default(&p("default")));
/// ```
pub fn by_default(preset: &Preset) -> bool {
    preset
        .verify
        .enabled
        .unwrap_or(preset.machine.is_some() || preset.polar.is_some())
}

/// A tolerance option of pass `name`: the preset's value, else the pass's default.
fn pass_option(preset: &Preset, name: &str, key: &str) -> Option<f64> {
    let value = |t: &toml::Table| {
        t.get(key)
            .and_then(|v| v.as_float().or(v.as_integer().map(|i| i as f64)))
    };
    let spec = preset.passes.iter().find(|p| p.name == name)?;
    value(&spec.options).or_else(|| {
        let defaults: toml::Table =
            toml::from_str(&(crate::passes::lookup(name)?.defaults)()).ok()?;
        value(&defaults)
    })
}

/// The tolerances of `preset`'s run: the `[verify]` section over the passes' own.
pub(super) fn tolerances(preset: &Preset) -> Tolerances {
    let tip = pass_option(preset, "densify", "tip_tolerance")
        .or_else(|| pass_option(preset, "polar-ik", "tolerance"))
        .unwrap_or(0.01);
    let axis = pass_option(preset, "densify", "axis_tolerance").unwrap_or(0.05);
    Tolerances::new(&preset.verify, tip, axis)
}

/// The tap of one run: where it sits and what it records into.
pub(super) struct TapPoint {
    /// The stage whose input is the programmed path (the backend: the number of passes).
    pub at: usize,
    tap: Tap,
    queue: Queue,
}

impl TapPoint {
    /// Records a batch arriving at the tap's stage.
    pub fn record(&mut self, blocks: &[Block]) {
        if let Ok(mut q) = self.queue.lock() {
            self.tap.record(blocks, &mut *q);
        }
    }
}

/// The verification of one run of `preset`: the tap and the verifier of the printed
/// text, or `None` when the preset prints no G-code.
fn plan(preset: &Preset, timing: Option<Timing>) -> Option<(TapPoint, Verifier)> {
    if preset.emit == Emit::Ir {
        return None;
    }
    let kin = match (&preset.polar, &preset.machine) {
        (Some(p), _) => {
            let center = preset
                .passes
                .iter()
                .find(|s| s.name == "polar-ik")
                .and_then(|s| s.options.get("center"))
                .and_then(|c| c.clone().try_into::<[f64; 2]>().ok())
                .unwrap_or([0.0, 0.0]);
            Kinematics::Polar {
                r: p.r_axis,
                theta: p.theta_axis,
                center,
                table: [p.omega_max.to_radians(), p.alpha_max.to_radians()],
            }
        }
        (None, Some(m)) => Kinematics::Machine(Box::new(m.clone())),
        (None, None) => Kinematics::Cartesian,
    };
    let at = preset
        .passes
        .iter()
        .position(|p| MACHINE_PASSES.contains(&p.name.as_str()))
        .unwrap_or(preset.passes.len());
    // Without a machine the program is read as the backend's firmware reads it (its
    // G0 rule, minimum speed and dwell unit), not as RepRapFirmware's defaults.
    let controller = preset
        .controller()
        .cloned()
        .unwrap_or_else(|| Controller::of(preset.backend_flavour()));
    let timing = timing.unwrap_or(controller.timing);
    let model = Model::new(&controller).with_timing(timing);
    let queue: Queue = Arc::new(Mutex::new(VecDeque::new()));
    let tol = tolerances(preset);
    let polar = preset.polar.as_ref();
    let reader = Reader::new(model.clone(), controller.flavour, polar);
    let checker = Checker::new(kin.clone(), &model, tol, polar, queue.clone());
    let tap = TapPoint {
        at,
        tap: Tap::new(kin),
        queue,
    };
    let verifier = Verifier::new(reader, checker, tol, polar.is_some());
    // Under trapezoid timing the printed moves are timed with their neighbours, as the
    // passes that place valve commands and screw speeds timed them.
    Some((
        tap,
        match timing {
            Timing::ConstantVelocity => verifier,
            Timing::Trapezoid => verifier.with_planner(model),
        },
    ))
}

/// The tap and the teed writer of a run of `preset` into `out`, verifying as `mode` says.
pub(super) fn start<W: Write>(mode: &Mode, preset: &Preset, out: W) -> (Option<TapPoint>, Tee<W>) {
    match mode.on.then(|| plan(preset, mode.timing)).flatten() {
        Some((tap, verifier)) => (Some(tap), Tee::new(out, Some(verifier))),
        None => (None, Tee::new(out, None)),
    }
}

/// The backend's writer with the printed bytes teed to the readback.
pub(super) struct Tee<W> {
    inner: W,
    verifier: Option<Verifier>,
}

impl<W: Write> Tee<W> {
    /// Writes to `inner`, reading what is written with `verifier` when there is one.
    pub fn new(inner: W, verifier: Option<Verifier>) -> Self {
        Tee { inner, verifier }
    }

    /// The readback's report (nothing without a verifier) and the writer.
    pub fn finish(self) -> (Vec<Diagnostic>, W) {
        let diags = self.verifier.map(|v| v.finish().1).unwrap_or_default();
        (diags, self.inner)
    }
}

impl<W: Write> Write for Tee<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.inner.write(buf)?;
        if let Some(v) = &mut self.verifier {
            v.bytes(&buf[..n]);
        }
        Ok(n)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}
