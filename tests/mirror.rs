//! The `mirror` pass: the shift is the program's largest value (arc bulges included), and
//! the printed program is the mirror image.

use ncpost::back::gcode::write_string;
use ncpost::diag::Diagnostic;
use ncpost::front::gcode::{Options as GOptions, parse_str};
use ncpost::ir::Block;
use ncpost::passes::mirror::{Mirror, MirrorAxis, Options};
use ncpost::passes::{Output, Pass};

fn run(src: &str, options: Options) -> (Vec<Block>, Vec<Diagnostic>) {
    let p = parse_str(src, &GOptions::default()).unwrap();
    let mut pass = Mirror::new(options).unwrap();
    let (mut blocks, mut diags) = (Vec::new(), Vec::new());
    pass.run(
        &mut p.blocks.clone(),
        &mut Output::new(&mut blocks, &mut diags),
    );
    pass.finish(&mut Output::new(&mut blocks, &mut diags));
    (blocks, diags)
}

#[test]
fn shift_is_the_largest_x_including_arc_bulges() {
    // A half circle from (0,0) to (0,10) about (0,5): counter-clockwise it reaches
    // X 5, clockwise X -5.
    let (b, d) = run("G0 X0 Y0\nG3 X0 Y10 I0 J5\nG1 X-3\n", Options::default());
    let (_, cw) = run("G0 X0 Y0\nG2 X0 Y10 I0 J5\nG1 X-3\n", Options::default());
    assert!(cw[0].message.contains("shift 0,"), "{}", cw[0].message);
    assert!(d[0].message.contains("shift 5"), "{}", d[0].message);
    let text = write_string(&b, &Default::default()).unwrap();
    assert_eq!(text, "G21 G90\nG0 X5 Y0\nG94 G17\nG2 X5 Y10 I0 J5\nG1 X8\n");
}

#[test]
fn given_shift_streams_and_y_axis() {
    let o = Options {
        axis: MirrorAxis::Y,
        shift: Some(20.0),
    };
    let (b, _) = run("G0 X1 Y2\nG17 G2 X3 Y2 I1 J0\nG18 G2 X5 Z1 I1 K0\n", o);
    let text = write_string(&b, &Default::default()).unwrap();
    assert_eq!(
        text,
        "G21 G90\nG0 X1 Y18\nG94 G17\nG3 X3 Y18 I1 J0\nG18\nG18 G2 X5 Z1 I1 K0\n"
    );
}
