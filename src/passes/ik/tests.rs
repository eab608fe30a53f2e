//! Tests of `ik` on generated programs.
use super::*;
use crate::ir::{Command, Feed, FeedMode, Pose, Span};
use crate::machine::builtin as machine;
use nalgebra::Point3;
use proptest::prelude::*;

/// One block of a test program: 0 a rapid, 1 and 2 a linear move to a pose (tool
/// axis at `theta` from vertical, degrees, at azimuth `phi`), 3 a joint move, 4 a
/// homing command that clobbers everything.
fn block(line: u32, what: u8, tip: (f64, f64, f64), theta: f64, phi: f64) -> Block {
    let span = Span {
        offset: u64::from(line) * 10,
        len: 5,
        line,
    };
    let feed = Feed {
        mode: FeedMode::PerMinute,
        rate: Some(800.0),
    };
    let (st, ct) = theta.to_radians().sin_cos();
    let (sp, cp) = phi.to_radians().sin_cos();
    let axis = Unit::new_normalize(Vector3::new(st * cp, st * sp, ct));
    let tip = Point3::new(tip.0, tip.1, tip.2);
    let (kind, target) = match what {
        0 => (MotionKind::Rapid, Target::Pose(Pose::new(tip, axis))),
        1 | 2 => (MotionKind::Linear, Target::Pose(Pose::new(tip, axis))),
        3 => {
            let mut j = Joints::default();
            for (a, v) in [
                (Axis::X, tip.x),
                (Axis::Y, tip.y),
                (Axis::Z, tip.z),
                (Axis::A, theta - 90.0),
                (Axis::B, theta - 90.0),
                (Axis::C, phi),
            ] {
                j.set(a, v);
            }
            (MotionKind::Linear, Target::Joints(j))
        }
        _ => {
            let c = Command {
                text: "G28".into(),
                modes: None,
                clobbers: AxisSet::ALL,
            };
            return Block::new(span, BlockKind::Command(c));
        }
    };
    let written = match &target {
        Target::Joints(j) => j.known,
        _ => AxisSet::XYZ,
    };
    Block::new(
        span,
        BlockKind::Motion(Motion {
            kind,
            target,
            feed,
            written,
            machine_frame: false,
            extra: String::new(),
        }),
    )
}

/// Tilts that reach the singularity cone, the E-moc's A limits and beyond.
fn theta() -> impl Strategy<Value = f64> {
    prop_oneof![
        Just(0.0),
        Just(0.004),
        Just(180.0),
        0.0f64..180.0,
        80.0f64..100.0
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(300))]

    /// Running batches gives what the pass gives block by block:
    /// the same blocks, diagnostics and state, however the program is cut into
    /// batches; holds, swings, unreachable poses, flips and retracts included.
    #[test]
    fn run_batch_is_run(
        preset in 0usize..4,
        retract in any::<bool>(),
        steps in prop::collection::vec(
            (0u8..5, (-50.0f64..50.0, -50.0f64..50.0, 0.0f64..50.0), theta(),
             prop_oneof![Just(0.0), Just(90.0), -180.0f64..180.0]),
            1..40),
        cuts in prop::collection::vec(1usize..8, 1..10),
    ) {
        let m = machine(["emoc-x5", "trunnion-bc", "head-table", "head-head-ab"][preset]);
        let options = Options {
            on_flip: if retract { OnFlip::Retract } else { OnFlip::Error },
            ..Options::default()
        };
        let program: Vec<Block> = steps
            .iter()
            .zip(1..)
            .map(|(&(what, tip, theta, phi), line)| block(line, what, tip, theta, phi))
            .collect();

        let mut by_run = Ik::new(m.clone(), options.clone()).unwrap();
        let (mut want, mut want_diags) = (Vec::new(), Vec::new());
        for b in program.clone() {
            by_run.block(b, &mut Output::new(&mut want, &mut want_diags));
        }
        by_run.finish(&mut Output::new(&mut want, &mut want_diags));

        let mut by_batch = Ik::new(m, options).unwrap();
        let (mut got, mut got_diags) = (Vec::new(), Vec::new());
        let mut rest = program;
        for &n in cuts.iter().cycle() {
            if rest.is_empty() {
                break;
            }
            let tail = rest.split_off(n.min(rest.len()));
            let mut batch = std::mem::replace(&mut rest, tail);
            // The pipeline hands each batch an empty output.
            let mut out = Vec::new();
            by_batch.run(&mut batch, &mut Output::new(&mut out, &mut got_diags));
            prop_assert!(batch.is_empty());
            got.append(&mut out);
        }
        let mut out = Vec::new();
        by_batch.finish(&mut Output::new(&mut out, &mut got_diags));
        got.append(&mut out);
        prop_assert_eq!(&got, &want);
        prop_assert_eq!(&got_diags, &want_diags);
        prop_assert_eq!(by_batch.prev, by_run.prev);
        prop_assert_eq!(by_batch.held, by_run.held);
        prop_assert_eq!(by_batch.last_axis, by_run.last_axis);
    }
}
