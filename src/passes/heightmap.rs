//! `heightmap`: Z compensation from a probed height map (RepRapFirmware, bCNC, Grbl log, x,y,z CSV); bilinear, moves split at grid lines and within a tolerance.
//!
//! The PCB mill of seed 001 cuts 60 µm deep into a board that warps by up to 87 µm:
//! without compensation the cut is lost or the tool breaks. Its own software probed a
//! 2-10 mm grid and split every G01 at the grid pitch. This pass does that with a
//! stated error bound.
//!
//! # Options
//! - `map` (required): the height map file, read when the pass is built. Formats and
//!   their details: [`crate::heightmap`] (RepRapFirmware `heightmap.csv` v1/v2/axis
//!   letters, bCNC `.probe`, a Grbl console log of `G38.2` reports, plain `x,y,z` CSV
//!   forming a full grid).
//! - `format` (`"auto"`): `"rrf"`, `"bcnc"`, `"grbl-log"` or `"csv"` to skip detection.
//! - `tolerance` (mm, default `0.001`): the largest vertical distance between an emitted
//!   straight segment and the compensated path (programmed Z + surface), as printed: the
//!   print rounding of the vertices (half a unit of the last decimal in Z, and in X and Y
//!   times the map's steepest slope) is taken from it first, and a tolerance the printed
//!   decimals cannot hold is a settings error.
//! - `outside` (`"error"`): a move whose end point is outside the grid is the error
//!   `heightmap::outside` (the line, the point, the grid's extent). `"clamp"` extends
//!   the map beyond its edges with the nearest edge value (`h(clamp(x), clamp(y))`).
//! - `unprobed` (`"error"`): RepRapFirmware writes `0` for grid points it did not probe
//!   (outside the probing radius, or failed). A move through a cell with such a corner
//!   is the error `heightmap::unprobed`. `"nearest"` fills every unprobed point with the
//!   height of the nearest probed one when the map is read.
//!
//! # What is emitted
//! Every feed move and rapid (G0 is compensated too: a rapid at a low height must not
//! hit the board) from a known X, Y start becomes straight pieces whose vertices are
//! `(x, y, z + h(x, y))`, with the programmed `z` (and every other axis) interpolated
//! along the original move and `h` the bilinear surface. The move is cut at every grid
//! line it crosses; inside a cell the surface along the line is quadratic in the move's
//! parameter `t` (the bilinear term `D u v` with `u`, `v` linear in `t`:
//! `c t²` with `c = D u'(t) v'(t)`, `D = h00 - h10 - h01 + h11`), so a straight piece of
//! parameter length `L` deviates from it by exactly `|c| L² / 4` at its middle; each
//! cell piece is cut into `ceil(L sqrt(|c| / (4 tolerance)))` equal pieces. Z-only moves
//! (plunges) are shifted, not cut. G94 feeds are unchanged; G93 feeds are divided by
//! each piece's share of the move. Comments stay on the last piece.
//!
//! # Frame
//! The map's X, Y (and heights) are in the IR frame: the program's coordinates without
//! G92 offsets, which is what `normalize` prints. Probe the board after setting the same
//! work origin as the job (`ncpost heightmap probe-program` writes the probing program).
//! Heights are added to Z: a board 0.05 mm low at a point (`h = -0.05`) moves the tool
//! 0.05 mm lower there.
//!
//! # Limits
//! Arcs are not compensated here: an arc is the error `heightmap::arc`, telling the user
//! to put `linearize-arcs` before `heightmap` (so one pass owns the chord tolerance and
//! the total error is at most the sum of the two tolerances). A move whose X, Y or Z
//! target is not known (before the first positioning move), and G53 moves (machine
//! coordinates), pass through uncompensated; the first such move gives the warning
//! `heightmap::unknown`. A move from an unknown X, Y start is compensated at its end
//! point only. At most 10 diagnostics of each kind are reported, then a count.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};
use smallvec::SmallVec;

use super::{Output, Pass, PassInfo};
use crate::diag::Diagnostic;
use crate::heightmap::{HeightMap, Missing};
use crate::ir::{Axis, Block, BlockKind, FeedMode, Joints, MotionKind, Target};

/// Which reader to use for the map.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum MapFormat {
    /// Detect from the text.
    #[default]
    Auto,
    /// RepRapFirmware `heightmap.csv`.
    Rrf,
    /// bCNC `.probe`.
    Bcnc,
    /// Grbl console log with `[PRB:...]` reports.
    GrblLog,
    /// `x,y,z` lines.
    Csv,
}

/// What to do with points outside the grid.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Outside {
    /// An error.
    #[default]
    Error,
    /// The nearest edge value.
    Clamp,
}

/// What to do with grid points that were not probed.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Unprobed {
    /// An error for moves through their cells.
    #[default]
    Error,
    /// The height of the nearest probed point.
    Nearest,
}

/// Options of `heightmap`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Options {
    /// The height map file.
    pub map: String,
    /// Its format.
    pub format: MapFormat,
    /// Largest vertical distance of an emitted segment from the compensated path, mm.
    pub tolerance: f64,
    /// Points outside the grid.
    pub outside: Outside,
    /// Grid points that were not probed.
    pub unprobed: Unprobed,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            map: String::new(),
            format: MapFormat::Auto,
            tolerance: 0.001,
            outside: Outside::Error,
            unprobed: Unprobed::Error,
        }
    }
}

/// Registry entry.
pub const INFO: PassInfo = PassInfo {
    name: "heightmap",
    summary: "add a probed height map (RRF heightmap.csv, bCNC .probe, Grbl PRB log, x,y,z CSV) to Z; moves split at grid lines and within a tolerance",
    build: |t, ctx| {
        let options: Options = super::options(t)?;
        let pass = Heightmap::from_file(options)?;
        Ok(Box::new(pass.printed_with(ctx.decimals.map(|d| d.linear))?))
    },
    defaults: || super::to_toml(&Options::default()),
};

/// The `heightmap` pass.
pub struct Heightmap {
    map: HeightMap,
    options: Options,
    /// The IR (uncompensated) position after the last block.
    track: crate::ir::Tracker,
    /// Diagnostics per code so far.
    counts: BTreeMap<&'static str, usize>,
    /// Vertices of the move being cut (reused).
    pieces: Vec<(f64, Joints)>,
    /// How far the printed Z of a vertex may be from its compensated height: the
    /// rounding of Z, and of X and Y times the map's steepest slope (0 when nothing is
    /// printed).
    rounding: f64,
}

/// Reads a map file in `format`.
pub fn read_map(path: &str, format: MapFormat) -> Result<HeightMap, Diagnostic> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| Diagnostic::settings(format!("cannot read `{path}`: {e}")))?;
    let map = match format {
        MapFormat::Auto => HeightMap::parse(&text),
        MapFormat::Rrf => HeightMap::parse_rrf(&text),
        MapFormat::Bcnc => HeightMap::parse_bcnc(&text),
        MapFormat::GrblLog => HeightMap::parse_grbl_log(&text),
        MapFormat::Csv => HeightMap::parse_csv(&text),
    };
    map.map_err(|e| Diagnostic::settings(format!("`{path}`: {}", e.message)))
}

impl Heightmap {
    /// The pass with the map file named in `options`.
    pub fn from_file(options: Options) -> Result<Heightmap, Diagnostic> {
        if options.map.is_empty() {
            return Err(Diagnostic::settings(
                "set the height map file: --pass heightmap:map=heightmap.csv",
            ));
        }
        let map = read_map(&options.map, options.format)?;
        Heightmap::with_map(map, options)
    }

    /// The pass with an already read map (`options.map` is not read).
    pub fn with_map(mut map: HeightMap, options: Options) -> Result<Heightmap, Diagnostic> {
        if !(options.tolerance.is_finite() && options.tolerance > 0.0) {
            return Err(Diagnostic::settings("tolerance must be a number > 0"));
        }
        if options.unprobed == Unprobed::Nearest {
            map.fill_nearest()?;
        }
        Ok(Heightmap {
            map,
            options,
            track: crate::ir::Tracker::default(),
            counts: BTreeMap::new(),
            pieces: Vec::new(),
            rounding: 0.0,
        })
    }

    /// The same pass for a backend that prints linear axes with `decimals`: the pieces
    /// are cut so that the tolerance holds on the printed vertices. Rounding moves Z by
    /// up to half a unit of the last decimal, and X and Y by as much, which changes the
    /// height under them by the map's slope. An error when the tolerance is finer than
    /// the printed numbers can hold.
    pub fn printed_with(mut self, decimals: Option<u8>) -> Result<Heightmap, Diagnostic> {
        let Some(d) = decimals else {
            return Ok(self);
        };
        let q = 0.5 * 10f64.powi(-i32::from(d));
        let [gx, gy] = self.steepest_slopes();
        self.rounding = q * (1.0 + gx + gy);
        if self.rounding >= self.options.tolerance {
            return Err(Diagnostic::settings(format!(
                "heightmap tolerance {} mm is finer than the printed coordinates ({d} \
                 decimals) can hold on this map ({:.4} mm): raise the tolerance or print \
                 more decimals",
                self.options.tolerance, self.rounding
            )));
        }
        Ok(self)
    }

    /// The map's steepest slopes along X and along Y between probed neighbours (a
    /// bilinear cell is no steeper than its edges).
    fn steepest_slopes(&self) -> [f64; 2] {
        let m = &self.map;
        let mut g = [0.0f64; 2];
        for j in 0..m.ys.len() {
            for i in 0..m.xs.len() {
                let Some(h) = m.node(i, j) else { continue };
                if let Some(hx) = (i + 1 < m.xs.len()).then(|| m.node(i + 1, j)).flatten() {
                    g[0] = g[0].max((hx - h).abs() / (m.xs[i + 1] - m.xs[i]));
                }
                if let Some(hy) = (j + 1 < m.ys.len()).then(|| m.node(i, j + 1)).flatten() {
                    g[1] = g[1].max((hy - h).abs() / (m.ys[j + 1] - m.ys[j]));
                }
            }
        }
        g
    }

    /// The map in use.
    pub fn map(&self) -> &HeightMap {
        &self.map
    }

    fn report(
        &mut self,
        code: &'static str,
        out: &mut Output<'_>,
        make: impl FnOnce() -> Diagnostic,
    ) {
        // The pipeline caps repeated diagnostics (and counts every one); only the
        // unknown position is reported once, at the first such move.
        let n = self.counts.entry(code).or_insert(0);
        *n += 1;
        if code != "heightmap::unknown" || *n == 1 {
            out.diag(make());
        }
    }

    fn clamp(&self) -> bool {
        self.options.outside == Outside::Clamp
    }

    fn missing(&mut self, what: Missing, x: f64, y: f64, block: &Block, out: &mut Output<'_>) {
        let ((x0, x1), (y0, y1)) = self.map.extent();
        match what {
            Missing::Outside => self.report("heightmap::outside", out, || {
                Diagnostic::error(
                    "heightmap::outside",
                    format!(
                        "X{x:.4} Y{y:.4} is outside the height map (X {x0}..{x1}, Y {y0}..{y1})"
                    ),
                )
                .at_span(block.span)
                .with_label("moves outside the probed area")
                .with_help("probe an area that covers the job (ncpost heightmap probe-program --area ...), move the job onto the map, or set `outside = \"clamp\"` to extend the edge heights")
            }),
            Missing::Unprobed(nx, ny) => self.report("heightmap::unprobed", out, || {
                Diagnostic::error(
                    "heightmap::unprobed",
                    format!(
                        "the move at X{x:.4} Y{y:.4} crosses a cell whose grid point X{nx} Y{ny} was not probed"
                    ),
                )
                .at_span(block.span)
                .with_help("probe that point again, or set `unprobed = \"nearest\"` to use the nearest probed height")
            }),
        }
    }

    /// Cuts the straight move `from` → `to` into compensated vertices (in `self.pieces`).
    fn cut(
        &mut self,
        from: &Joints,
        to: &Joints,
        start_known: bool,
    ) -> Result<(), (Missing, f64, f64)> {
        self.pieces.clear();
        let clamp = self.clamp();
        let (bx, by) = (to.values[Axis::X.index()], to.values[Axis::Y.index()]);
        let mut ts: SmallVec<[f64; 16]> = SmallVec::new();
        ts.push(0.0);
        let (ax, ay) = if start_known {
            (from.values[Axis::X.index()], from.values[Axis::Y.index()])
        } else {
            (bx, by)
        };
        if start_known {
            for (lines, a, b) in [(&self.map.xs, ax, bx), (&self.map.ys, ay, by)] {
                if a == b {
                    continue;
                }
                let (lo, hi) = (a.min(b), a.max(b));
                let first = lines.partition_point(|&g| g <= lo);
                for &g in &lines[first..] {
                    if g >= hi {
                        break;
                    }
                    ts.push((g - a) / (b - a));
                }
            }
        }
        ts.push(1.0);
        ts.sort_by(f64::total_cmp);
        // The pieces' own share of the tolerance: what the print rounding leaves.
        let tol = self.options.tolerance - self.rounding;
        let vertex = |t: f64,
                      map: &HeightMap,
                      pieces: &mut Vec<(f64, Joints)>|
         -> Result<(), (Missing, f64, f64)> {
            let mut j = if t >= 1.0 || !start_known {
                *to
            } else {
                lerp(from, to, t)
            };
            let (x, y) = (j.values[Axis::X.index()], j.values[Axis::Y.index()]);
            let h = map.height_at(x, y, clamp).map_err(|m| (m, x, y))?;
            j.values[Axis::Z.index()] += h;
            pieces.push((t, j));
            Ok(())
        };
        if !start_known {
            return vertex(1.0, &self.map, &mut self.pieces);
        }
        let mut t0 = 0.0;
        for &t1 in &ts[1..] {
            if t1 - t0 <= 1e-12 && t1 < 1.0 {
                continue;
            }
            let len = t1 - t0;
            let tm = 0.5 * (t0 + t1);
            let (xm, ym) = (ax + (bx - ax) * tm, ay + (by - ay) * tm);
            let cell = self.map.cell(xm, ym);
            let corners = self.map.corners(cell.i, cell.j).map_err(|m| (m, xm, ym))?;
            let d = corners[0] - corners[1] - corners[2] + corners[3];
            let du = if cell.clamped_x {
                0.0
            } else {
                (bx - ax) / (self.map.xs[cell.i + 1] - self.map.xs[cell.i])
            };
            let dv = if cell.clamped_y {
                0.0
            } else {
                (by - ay) / (self.map.ys[cell.j + 1] - self.map.ys[cell.j])
            };
            let c = (d * du * dv).abs();
            let m = ((len * (c / (4.0 * tol)).sqrt()).ceil() as usize).clamp(1, 1_000_000);
            for k in 1..=m {
                let t = if k == m {
                    t1
                } else {
                    t0 + len * k as f64 / m as f64
                };
                vertex(t, &self.map, &mut self.pieces)?;
            }
            t0 = t1;
        }
        Ok(())
    }
}

/// Joints at `t` of the way from `a` to `b` (axes known in `b`; those unknown in `a`
/// take `b`'s value).
fn lerp(a: &Joints, b: &Joints, t: f64) -> Joints {
    let mut j = *b;
    for axis in b.known.iter() {
        if let Some(va) = a.get(axis) {
            let vb = b.values[axis.index()];
            j.values[axis.index()] = va + (vb - va) * t;
        }
    }
    j
}

impl Heightmap {
    /// One block of the input: puts out what becomes of it.
    fn block(&mut self, block: Block, out: &mut Output<'_>) {
        let BlockKind::Motion(m) = &block.kind else {
            self.track.update(&block);
            out.push(block);
            return;
        };
        if let MotionKind::Arc(_) = m.kind {
            self.report("heightmap::arc", out, || {
                Diagnostic::error("heightmap::arc", "heightmap compensates straight moves; this is an arc")
                    .at_span(block.span)
                    .with_help("put linearize-arcs before heightmap: --pass linearize-arcs --pass heightmap:map=FILE")
            });
            self.track.update(&block);
            out.push(block);
            return;
        }
        let to = match &m.target {
            Target::Joints(j) if !m.machine_frame => *j,
            _ => {
                if !m.machine_frame {
                    self.report("heightmap::pose", out, || {
                        Diagnostic::error(
                            "heightmap::pose",
                            "heightmap needs machine positions, not tool poses",
                        )
                        .at_span(block.span)
                        .with_help("put heightmap after ik")
                    });
                }
                self.track.update(&block);
                out.push(block);
                return;
            }
        };
        let known = [Axis::X, Axis::Y, Axis::Z]
            .iter()
            .all(|&a| to.known.contains(a));
        if !known {
            self.report("heightmap::unknown", out, || {
                Diagnostic::warning(
                    "heightmap::unknown",
                    "a move whose X, Y or Z is not known is passed on uncompensated",
                )
                .at_span(block.span)
                .with_help("start the program with a move to absolute X, Y and Z (the first such move is reported)")
            });
            self.track.set_pos(to);
            out.push(block);
            return;
        }
        let from = *self.track.pos();
        let start_known = from.known.contains(Axis::X) && from.known.contains(Axis::Y);
        if let Err((what, x, y)) = self.cut(&from, &to, start_known) {
            self.missing(what, x, y, &block, out);
            self.track.set_pos(to);
            out.push(block);
            return;
        }
        self.track.set_pos(to);
        let Block {
            span,
            kind,
            comments,
        } = block;
        let BlockKind::Motion(m) = kind else { return };
        let n = self.pieces.len();
        let mut comments = Some(comments);
        let mut t_prev = 0.0;
        for (k, &(t, p)) in self.pieces.iter().enumerate() {
            let mut piece = m.clone();
            piece.target = Target::Joints(p);
            piece.written.insert(Axis::Z);
            if piece.feed.mode == FeedMode::InverseTime && n > 1 {
                let share = t - t_prev;
                if share > 0.0 {
                    piece.feed.rate = piece.feed.rate.map(|f| f / share);
                }
            }
            t_prev = t;
            let mut b = Block::new(span, BlockKind::Motion(piece));
            if k + 1 == n {
                b.comments = comments.take().unwrap_or_default();
            }
            out.push(b);
        }
    }
}

impl Pass for Heightmap {
    fn run(&mut self, blocks: &mut Vec<Block>, out: &mut Output<'_>) {
        for block in blocks.drain(..) {
            self.block(block, out);
        }
    }
}
