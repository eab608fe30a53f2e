//! Height maps of a board or bed: readers for RepRapFirmware, bCNC, Grbl probe logs and x,y,z CSV; bilinear interpolation; probing programs.
//!
//! A [`HeightMap`] is a rectilinear grid (sorted X and Y grid lines, not necessarily
//! evenly spaced) with one height per node, mm, `None` for a node that was not probed.
//! The surface is bilinear in each cell: for `u, v` in `[0, 1]` across the cell,
//! `h = h00 (1-u)(1-v) + h10 u (1-v) + h01 (1-u) v + h11 u v`.
//!
//! # Formats ([`HeightMap::parse`] detects them)
//! - **RepRapFirmware `heightmap.csv`** (written by `G29 S0`): a first line
//!   `RepRapFirmware height map file v1|v2 ...`, a label line and a value line, then one
//!   row of heights per Y grid line from `ymin` up. Label lines: v1
//!   `xmin,xmax,ymin,ymax,radius,spacing,xnum,ynum`; v2
//!   `xmin,xmax,ymin,ymax,radius,xspacing,yspacing,xnum,ynum`; RRF 3.3 and later
//!   `axis0,axis1,min0,max0,min1,max1,radius,spacing0,spacing1,num0,num1` with the axis
//!   letters (`X,Y`) first in the value line. Grid lines are at `min + i * spacing`, as
//!   the firmware places them (a spacing of 59.99 gives 30, 89.99, ... 269.96). A bare `0`
//!   (no decimal point) is a point the firmware did not probe (outside `radius`, or a
//!   failed probe): it is `None`, while `0.000` is a measured zero.
//! - **bCNC `.probe`**: three header lines `xmin xmax xn`, `ymin ymax yn`,
//!   `zmin zmax feed`, then `x y z` lines (rows separated by blank lines). The header's
//!   grid is checked against the points.
//! - **Grbl probe log**: a console log holding the `[PRB:x,y,z:1]` reports of `G38.2`
//!   (see [`probe_program`]). PRB positions are machine coordinates; the last
//!   `[G54:x,y,z]` and `[G92:x,y,z]` lines of the log (answers to `$#`) before the reports
//!   are subtracted, and `[TLO:z]` from Z, to get work coordinates. A failed probe
//!   (`:0`) is an error. Reports must be in mm (`$13=0`).
//! - **Plain CSV**: one `x,y,z` point per line (commas, semicolons or blanks), `#`
//!   comments and a non-numeric header line allowed. The points must form a full grid:
//!   every combination of the distinct X and Y values exactly once (values within
//!   1e-6 mm are the same line); otherwise the error names a missing or repeated point.

use crate::diag::Diagnostic;
use std::fmt::Write as _;

/// Two coordinates closer than this (mm) are the same grid line.
pub const SAME_LINE: f64 = 1e-6;

/// Which reader a map was read with.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// RepRapFirmware `heightmap.csv`.
    Rrf,
    /// bCNC `.probe`.
    Bcnc,
    /// Grbl console log with `[PRB:...]` reports.
    GrblLog,
    /// `x,y,z` lines.
    Csv,
}

/// A height map on a rectilinear grid.
#[derive(Debug, Clone, PartialEq)]
pub struct HeightMap {
    /// X grid lines, increasing, mm (at least 2).
    pub xs: Vec<f64>,
    /// Y grid lines, increasing, mm (at least 2).
    pub ys: Vec<f64>,
    /// Heights, row by row (`z[j * xs.len() + i]` at `(xs[i], ys[j])`), mm; `None` where
    /// not probed.
    pub z: Vec<Option<f64>>,
    /// The format it was read from.
    pub format: Format,
}

/// Why a height is not available at a point.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Missing {
    /// The point is outside the grid.
    Outside,
    /// A corner of the point's cell was not probed: `(x, y)` of that node.
    Unprobed(f64, f64),
}

/// The cell a point falls in, with the point's cell coordinates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Cell {
    /// Column: the cell spans `xs[i]..xs[i+1]`.
    pub i: usize,
    /// Row: the cell spans `ys[j]..ys[j+1]`.
    pub j: usize,
    /// `(x - xs[i]) / (xs[i+1] - xs[i])`, clamped into `[0, 1]`.
    pub u: f64,
    /// `(y - ys[j]) / (ys[j+1] - ys[j])`, clamped into `[0, 1]`.
    pub v: f64,
    /// X was outside the grid (and clamped).
    pub clamped_x: bool,
    /// Y was outside the grid (and clamped).
    pub clamped_y: bool,
}

fn num(s: &str) -> Option<f64> {
    let v: f64 = s.trim().parse().ok()?;
    v.is_finite().then_some(v)
}

fn locate(lines: &[f64], x: f64) -> (usize, f64, bool) {
    let n = lines.len();
    let k = lines.partition_point(|&g| g <= x);
    let i = k.clamp(1, n - 1) - 1;
    let (a, b) = (lines[i], lines[i + 1]);
    let u = (x - a) / (b - a);
    let clamped = x < lines[0] || x > lines[n - 1];
    (i, u.clamp(0.0, 1.0), clamped)
}

impl HeightMap {
    /// Reads a map in any of the formats, detected from the text.
    ///
    /// ```
    /// let map = ncpost::heightmap::HeightMap::parse("0,0,0\n10,0,0.1\n0,10,0\n10,10,0.3\n").unwrap();
    /// assert!((map.height(5.0, 5.0).unwrap() - 0.1).abs() < 1e-12);
    /// ```
    pub fn parse(text: &str) -> Result<HeightMap, Diagnostic> {
        let first = text
            .lines()
            .map(str::trim)
            .find(|l| !l.is_empty())
            .unwrap_or("");
        if first.starts_with("RepRapFirmware height map file") {
            Self::parse_rrf(text)
        } else if text.contains("[PRB:") {
            Self::parse_grbl_log(text)
        } else if !first.contains(',') && !first.contains(';') && is_bcnc_header(text) {
            Self::parse_bcnc(text)
        } else {
            Self::parse_csv(text)
        }
    }

    /// Reads a RepRapFirmware `heightmap.csv` (v1, v2, or v2 with axis letters).
    pub fn parse_rrf(text: &str) -> Result<HeightMap, Diagnostic> {
        Self::parse_rrf_text(text).map_err(Diagnostic::settings)
    }

    /// Reads a bCNC `.probe` file.
    pub fn parse_bcnc(text: &str) -> Result<HeightMap, Diagnostic> {
        Self::parse_bcnc_text(text).map_err(Diagnostic::settings)
    }

    /// Reads `x,y,z` points (commas, semicolons or blanks between the numbers).
    pub fn parse_csv(text: &str) -> Result<HeightMap, Diagnostic> {
        Self::parse_csv_text(text).map_err(Diagnostic::settings)
    }

    /// Reads the `[PRB:x,y,z:1]` reports of a Grbl console log, in work coordinates.
    pub fn parse_grbl_log(text: &str) -> Result<HeightMap, Diagnostic> {
        Self::parse_grbl_log_text(text).map_err(Diagnostic::settings)
    }

    /// A map from points that must form a full rectilinear grid.
    ///
    /// ```
    /// use ncpost::heightmap::HeightMap;
    /// let err = HeightMap::from_points(&[[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]).unwrap_err();
    /// assert!(err.message.contains("no point at X1 Y1"), "{err}");
    /// ```
    pub fn from_points(points: &[[f64; 3]]) -> Result<HeightMap, Diagnostic> {
        Self::from_points_text(points).map_err(Diagnostic::settings)
    }

    /// [`HeightMap::parse_rrf`], its error in words.
    fn parse_rrf_text(text: &str) -> Result<HeightMap, String> {
        let mut lines = text.lines().map(str::trim).filter(|l| !l.is_empty());
        let head = lines.next().unwrap_or("");
        if !head.starts_with("RepRapFirmware height map file") {
            return Err("not a RepRapFirmware height map: the first line must be `RepRapFirmware height map file v2 ...`".into());
        }
        let labels: Vec<&str> = lines
            .next()
            .ok_or("the height map has no label line")?
            .split(',')
            .map(str::trim)
            .collect();
        let values: Vec<&str> = lines
            .next()
            .ok_or("the height map has no grid line")?
            .split(',')
            .map(str::trim)
            .collect();
        if labels.len() != values.len() {
            return Err(format!(
                "the grid line has {} values for {} labels",
                values.len(),
                labels.len()
            ));
        }
        let get = |names: &[&str]| -> Result<&str, String> {
            names
                .iter()
                .find_map(|n| labels.iter().position(|l| l == n).map(|i| values[i]))
                .ok_or_else(|| format!("the height map's label line has no `{}`", names[0]))
        };
        let getn = |names: &[&str]| -> Result<f64, String> {
            let s = get(names)?;
            num(s).ok_or_else(|| format!("`{s}` ({}) is not a number", names[0]))
        };
        if labels.contains(&"axis0") {
            let (a0, a1) = (get(&["axis0"])?, get(&["axis1"])?);
            if !a0.eq_ignore_ascii_case("X") || !a1.eq_ignore_ascii_case("Y") {
                return Err(format!(
                    "the height map is over axes {a0},{a1}; only X,Y maps compensate Z"
                ));
            }
        }
        let xmin = getn(&["xmin", "min0"])?;
        let ymin = getn(&["ymin", "min1"])?;
        let xsp = getn(&["xspacing", "spacing0", "spacing"])?;
        let ysp = getn(&["yspacing", "spacing1", "spacing"])?;
        let xn = getn(&["xnum", "num0", "num_x"])?;
        let yn = getn(&["ynum", "num1", "num_y"])?;
        if !(xsp > 0.0 && ysp > 0.0) {
            return Err("the height map's spacing must be > 0".into());
        }
        if xn.fract() != 0.0 || yn.fract() != 0.0 || xn < 2.0 || yn < 2.0 || xn * yn > 1e7 {
            return Err(format!(
                "the height map must have at least 2 x 2 points (it says {xn} x {yn})"
            ));
        }
        let (xn, yn) = (xn as usize, yn as usize);
        let xs: Vec<f64> = (0..xn).map(|i| xmin + i as f64 * xsp).collect();
        let ys: Vec<f64> = (0..yn).map(|j| ymin + j as f64 * ysp).collect();
        let mut z = Vec::with_capacity(xn * yn);
        for j in 0..yn {
            let row = lines
                .next()
                .ok_or_else(|| format!("the height map has {j} rows of heights, not {yn}"))?;
            let cells: Vec<&str> = row.split(',').map(str::trim).collect();
            if cells.len() != xn {
                return Err(format!(
                    "row {} of the height map has {} values, not {xn}",
                    j + 1,
                    cells.len()
                ));
            }
            for c in cells {
                if c == "0" {
                    z.push(None);
                } else {
                    z.push(Some(num(c).ok_or_else(|| {
                        format!("`{c}` in row {} of the height map is not a number", j + 1)
                    })?));
                }
            }
        }
        Ok(HeightMap {
            xs,
            ys,
            z,
            format: Format::Rrf,
        })
    }

    /// [`HeightMap::parse_bcnc`], its error in words.
    fn parse_bcnc_text(text: &str) -> Result<HeightMap, String> {
        let mut lines = text.lines().map(str::trim).filter(|l| !l.is_empty());
        let mut header = [[0.0; 3]; 3];
        for (k, h) in header.iter_mut().enumerate() {
            let line = lines.next().ok_or("the bCNC probe file has no header")?;
            let v = triple(line).ok_or_else(|| {
                format!(
                    "header line {} of the bCNC probe file is not three numbers: `{line}`",
                    k + 1
                )
            })?;
            *h = v;
        }
        let points: Vec<[f64; 3]> = lines
            .map(|l| triple(l).ok_or_else(|| format!("`{l}` is not `x y z`")))
            .collect::<Result<_, _>>()?;
        let mut map = Self::from_points_text(&points)?;
        map.format = Format::Bcnc;
        let [xmin, xmax, xn] = header[0];
        let [ymin, ymax, yn] = header[1];
        let ok = (map.xs.len() as f64 - xn).abs() < 0.5
            && (map.ys.len() as f64 - yn).abs() < 0.5
            && (map.xs[0] - xmin).abs() < 1e-3
            && (map.xs[map.xs.len() - 1] - xmax).abs() < 1e-3
            && (map.ys[0] - ymin).abs() < 1e-3
            && (map.ys[map.ys.len() - 1] - ymax).abs() < 1e-3;
        if !ok {
            return Err(format!(
                "the bCNC header says X {xmin}..{xmax} in {xn} points and Y {ymin}..{ymax} in {yn}, but the points form X {}..{} ({}) and Y {}..{} ({})",
                map.xs[0],
                map.xs[map.xs.len() - 1],
                map.xs.len(),
                map.ys[0],
                map.ys[map.ys.len() - 1],
                map.ys.len()
            ));
        }
        Ok(map)
    }

    /// [`HeightMap::parse_csv`], its error in words.
    fn parse_csv_text(text: &str) -> Result<HeightMap, String> {
        let mut points = Vec::new();
        for (k, line) in text.lines().enumerate() {
            let line = line.split('#').next().unwrap_or("").trim();
            if line.is_empty() {
                continue;
            }
            match triple(line) {
                Some(p) => points.push(p),
                None if points.is_empty() && !line.chars().any(|c| c.is_ascii_digit()) => {} // header
                None => {
                    return Err(format!(
                        "line {} of the CSV height map is not `x,y,z`: `{line}`",
                        k + 1
                    ));
                }
            }
        }
        let mut map = Self::from_points_text(&points)?;
        map.format = Format::Csv;
        Ok(map)
    }

    /// [`HeightMap::parse_grbl_log`], its error in words.
    fn parse_grbl_log_text(text: &str) -> Result<HeightMap, String> {
        let mut g54 = [0.0; 3];
        let mut g92 = [0.0; 3];
        let mut tlo = 0.0;
        let mut points = Vec::new();
        for (k, line) in text.lines().enumerate() {
            let mut rest = line;
            while let Some(open) = rest.find('[') {
                let Some(close) = rest[open..].find(']') else {
                    break;
                };
                let item = &rest[open + 1..open + close];
                rest = &rest[open + close + 1..];
                let Some((tag, body)) = item.split_once(':') else {
                    continue;
                };
                let values = |s: &str| -> Option<[f64; 3]> {
                    let v: Vec<f64> = s.split(',').map(num).collect::<Option<_>>()?;
                    (v.len() >= 3).then(|| [v[0], v[1], v[2]])
                };
                match tag {
                    "G54" => g54 = values(body).ok_or(format!("line {}: bad `[{item}]`", k + 1))?,
                    "G92" => g92 = values(body).ok_or(format!("line {}: bad `[{item}]`", k + 1))?,
                    "TLO" => tlo = num(body).ok_or(format!("line {}: bad `[{item}]`", k + 1))?,
                    "PRB" => {
                        let (pos, ok) = body.rsplit_once(':').unwrap_or((body, "1"));
                        if ok.trim() != "1" {
                            return Err(format!(
                                "line {}: `[{item}]` is a probe that did not touch; probe again",
                                k + 1
                            ));
                        }
                        let p = values(pos).ok_or(format!("line {}: bad `[{item}]`", k + 1))?;
                        points.push([
                            p[0] - g54[0] - g92[0],
                            p[1] - g54[1] - g92[1],
                            p[2] - g54[2] - g92[2] - tlo,
                        ]);
                    }
                    _ => {}
                }
            }
        }
        let mut map = Self::from_points_text(&points)?;
        map.format = Format::GrblLog;
        Ok(map)
    }

    /// [`HeightMap::from_points`], its error in words.
    fn from_points_text(points: &[[f64; 3]]) -> Result<HeightMap, String> {
        let lines = |k: usize| -> Vec<f64> {
            let mut v: Vec<f64> = points.iter().map(|p| p[k]).collect();
            v.sort_by(f64::total_cmp);
            v.dedup_by(|a, b| (*a - *b).abs() <= SAME_LINE);
            v
        };
        let (xs, ys) = (lines(0), lines(1));
        if xs.len() < 2 || ys.len() < 2 {
            return Err(format!(
                "the height map needs at least 2 x 2 points on a grid; it has {} point(s) over {} X and {} Y value(s)",
                points.len(),
                xs.len(),
                ys.len()
            ));
        }
        let index = |lines: &[f64], x: f64| -> usize {
            let k = lines.partition_point(|&g| g < x - SAME_LINE);
            k.min(lines.len() - 1)
        };
        let mut z = vec![None; xs.len() * ys.len()];
        for p in points {
            let (i, j) = (index(&xs, p[0]), index(&ys, p[1]));
            let cell = &mut z[j * xs.len() + i];
            if cell.is_some() {
                return Err(format!(
                    "the height map has two points at X{} Y{}; it must be a regular grid",
                    p[0], p[1]
                ));
            }
            *cell = Some(p[2]);
        }
        if let Some(k) = z.iter().position(Option::is_none) {
            let (i, j) = (k % xs.len(), k / xs.len());
            return Err(format!(
                "the points are not a full grid: no point at X{} Y{} ({} X lines x {} Y lines need {} points, there are {})",
                xs[i],
                ys[j],
                xs.len(),
                ys.len(),
                xs.len() * ys.len(),
                points.len()
            ));
        }
        Ok(HeightMap {
            xs,
            ys,
            z,
            format: Format::Csv,
        })
    }

    /// The grid's extent: `((xmin, xmax), (ymin, ymax))`.
    pub fn extent(&self) -> ((f64, f64), (f64, f64)) {
        (
            (self.xs[0], self.xs[self.xs.len() - 1]),
            (self.ys[0], self.ys[self.ys.len() - 1]),
        )
    }

    /// Whether `(x, y)` lies on the grid (edges included).
    pub fn contains(&self, x: f64, y: f64) -> bool {
        let ((x0, x1), (y0, y1)) = self.extent();
        x >= x0 && x <= x1 && y >= y0 && y <= y1
    }

    /// The node height at column `i`, row `j`.
    pub fn node(&self, i: usize, j: usize) -> Option<f64> {
        self.z[j * self.xs.len() + i]
    }

    /// The cell of `(x, y)`, clamping a point outside the grid to the nearest cell.
    pub fn cell(&self, x: f64, y: f64) -> Cell {
        let (i, u, clamped_x) = locate(&self.xs, x);
        let (j, v, clamped_y) = locate(&self.ys, y);
        Cell {
            i,
            j,
            u,
            v,
            clamped_x,
            clamped_y,
        }
    }

    /// The four node heights of a cell, `[h00, h10, h01, h11]`.
    pub fn corners(&self, i: usize, j: usize) -> Result<[f64; 4], Missing> {
        let mut out = [0.0; 4];
        for (k, (di, dj)) in [(0, 0), (1, 0), (0, 1), (1, 1)].into_iter().enumerate() {
            out[k] = self
                .node(i + di, j + dj)
                .ok_or(Missing::Unprobed(self.xs[i + di], self.ys[j + dj]))?;
        }
        Ok(out)
    }

    /// The bilinear height at `(x, y)`; outside the grid the nearest edge point's height
    /// when `clamp`, else [`Missing::Outside`].
    pub fn height_at(&self, x: f64, y: f64, clamp: bool) -> Result<f64, Missing> {
        if !clamp && !self.contains(x, y) {
            return Err(Missing::Outside);
        }
        let c = self.cell(x, y);
        let [h00, h10, h01, h11] = self.corners(c.i, c.j)?;
        Ok(bilinear([h00, h10, h01, h11], c.u, c.v))
    }

    /// The bilinear height at a point of the grid.
    pub fn height(&self, x: f64, y: f64) -> Result<f64, Missing> {
        self.height_at(x, y, false)
    }

    /// Fills every unprobed node with the height of the nearest probed node (ties: the
    /// first in row order). Errors when no node was probed.
    pub fn fill_nearest(&mut self) -> Result<(), Diagnostic> {
        let probed: Vec<(f64, f64, f64)> = (0..self.z.len())
            .filter_map(|k| {
                let (i, j) = (k % self.xs.len(), k / self.xs.len());
                self.z[k].map(|h| (self.xs[i], self.ys[j], h))
            })
            .collect();
        if probed.is_empty() {
            return Err(Diagnostic::settings("the height map has no probed point"));
        }
        for k in 0..self.z.len() {
            if self.z[k].is_some() {
                continue;
            }
            let (x, y) = (self.xs[k % self.xs.len()], self.ys[k / self.xs.len()]);
            let mut best = (f64::INFINITY, 0.0);
            for &(px, py, h) in &probed {
                let d = (px - x).powi(2) + (py - y).powi(2);
                if d < best.0 {
                    best = (d, h);
                }
            }
            self.z[k] = Some(best.1);
        }
        Ok(())
    }

    /// Number of nodes that were not probed.
    pub fn unprobed(&self) -> usize {
        self.z.iter().filter(|h| h.is_none()).count()
    }
}

/// Bilinear interpolation of the corner heights `[h00, h10, h01, h11]` at `(u, v)`.
pub fn bilinear(h: [f64; 4], u: f64, v: f64) -> f64 {
    let [h00, h10, h01, h11] = h;
    h00 + (h10 - h00) * u + (h01 - h00) * v + (h00 - h10 - h01 + h11) * u * v
}

fn triple(line: &str) -> Option<[f64; 3]> {
    let v: Vec<f64> = line
        .split([',', ';', ' ', '\t'])
        .filter(|s| !s.is_empty())
        .map(num)
        .collect::<Option<_>>()?;
    (v.len() == 3).then(|| [v[0], v[1], v[2]])
}

fn is_bcnc_header(text: &str) -> bool {
    let heads: Vec<Option<[f64; 3]>> = text
        .lines()
        .map(str::trim)
        .filter(|l| !l.is_empty())
        .take(3)
        .map(triple)
        .collect();
    // `xmin xmax xn` / `ymin ymax yn`: whole point counts, max above min.
    matches!(
        heads.as_slice(),
        [Some(a), Some(b), Some(_)] if a[2].fract() == 0.0 && b[2].fract() == 0.0 && a[1] > a[0] && b[1] > b[0]
    ) && text.lines().filter(|l| l.trim().is_empty()).count() > 0
}

/// The controller a probing program is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ProbeEmit {
    /// RepRapFirmware: `M557` grid + `G29 S0` (writes `heightmap.csv`).
    Rrf,
    /// Grbl: a `G38.2` per grid point.
    Grbl,
}

/// What to probe.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProbeOptions {
    /// `[x0, y0, x1, y1]`, mm, in the job's work frame.
    pub area: [f64; 4],
    /// Grid pitch, mm (the last line is moved out so the grid covers the area).
    pub pitch: f64,
    /// The controller.
    pub emit: ProbeEmit,
    /// Z to travel at between points, mm (Grbl).
    pub safe_z: f64,
    /// Z the probe moves down to at most, mm (Grbl; `G38.2` alarms if it does not touch).
    pub depth: f64,
    /// Probing feed, mm/min (Grbl).
    pub feed: f64,
}

/// The grid lines `probe_program` probes: `x0 + i * pitch` until `x1` is covered.
pub fn probe_lines(a: f64, b: f64, pitch: f64) -> Vec<f64> {
    let n = ((b - a) / pitch - 1e-9).ceil().max(1.0) as usize + 1;
    (0..n).map(|i| a + i as f64 * pitch).collect()
}

/// A probing program for the area: RepRapFirmware `M557` + `G29 S0`, or a Grbl `G38.2`
/// grid (serpentine order) whose console log [`HeightMap::parse_grbl_log`] reads.
///
/// ```
/// use ncpost::heightmap::{probe_program, ProbeEmit, ProbeOptions};
/// let o = ProbeOptions { area: [0.0, 0.0, 20.0, 10.0], pitch: 10.0, emit: ProbeEmit::Rrf,
///                        safe_z: 2.0, depth: -1.0, feed: 20.0 };
/// let text = probe_program(&o).unwrap();
/// assert!(text.contains("M557 X0:20 Y0:10 P3:2"));
/// assert!(text.contains("G29 S0"));
/// ```
pub fn probe_program(o: &ProbeOptions) -> Result<String, Diagnostic> {
    probe_text(o).map_err(Diagnostic::settings)
}

/// [`probe_program`], its error in words.
fn probe_text(o: &ProbeOptions) -> Result<String, String> {
    let [x0, y0, x1, y1] = o.area;
    if !o.area.iter().all(|v| v.is_finite()) || x1 <= x0 || y1 <= y0 {
        return Err("the area must be X0,Y0,X1,Y1 with X1 > X0 and Y1 > Y0".into());
    }
    if !(o.pitch.is_finite() && o.pitch > 0.0) {
        return Err("the pitch must be a number > 0".into());
    }
    let xs = probe_lines(x0, x1, o.pitch);
    let ys = probe_lines(y0, y1, o.pitch);
    if xs.len() * ys.len() > 100_000 {
        return Err(format!(
            "{} x {} points is too many; use a larger pitch",
            xs.len(),
            ys.len()
        ));
    }
    let f = |v: f64| {
        let s = format!("{v:.3}");
        let s = s.trim_end_matches('0').trim_end_matches('.').to_string();
        if s == "-0" { "0".to_string() } else { s }
    };
    let (xe, ye) = (xs[xs.len() - 1], ys[ys.len() - 1]);
    let mut t = String::new();
    match o.emit {
        ProbeEmit::Rrf => {
            let _ = writeln!(
                t,
                "; ncpost heightmap probe-program: {} x {} points, pitch {} mm, X{}..{} Y{}..{}",
                xs.len(),
                ys.len(),
                f(o.pitch),
                f(x0),
                f(xe),
                f(y0),
                f(ye)
            );
            t.push_str("; needs a Z probe defined by M558 in config.g (its dive height H and speed F apply)\n");
            t.push_str("; G29 S0 probes the grid and saves sys/heightmap.csv: then --pass heightmap:map=heightmap.csv\n");
            t.push_str("G21 G90\n");
            let _ = writeln!(
                t,
                "M557 X{}:{} Y{}:{} P{}:{}",
                f(x0),
                f(xe),
                f(y0),
                f(ye),
                xs.len(),
                ys.len()
            );
            t.push_str("G29 S0\n");
        }
        ProbeEmit::Grbl => {
            if !(o.safe_z.is_finite() && o.depth.is_finite() && o.depth < o.safe_z) {
                return Err("the probe depth must be below the safe Z".into());
            }
            if !(o.feed.is_finite() && o.feed > 0.0) {
                return Err("the probing feed must be a number > 0".into());
            }
            let _ = writeln!(
                t,
                "(ncpost heightmap probe-program: {} x {} points, pitch {} mm, X{}..{} Y{}..{})",
                xs.len(),
                ys.len(),
                f(o.pitch),
                f(x0),
                f(xe),
                f(y0),
                f(ye)
            );
            t.push_str(
                "(set the work origin on the board first; probe wired to the board and the tool)\n",
            );
            t.push_str("(Grbl answers each G38.2 with [PRB:x,y,z:1] in machine coordinates, in mm with $13=0)\n");
            t.push_str("(send $# before the run and save the whole console log; then --pass heightmap:map=LOG)\n");
            t.push_str("G21 G90\n");
            let _ = writeln!(t, "G0 Z{}", f(o.safe_z));
            for (j, &y) in ys.iter().enumerate() {
                let row: Vec<f64> = if j % 2 == 0 {
                    xs.clone()
                } else {
                    xs.iter().rev().copied().collect()
                };
                for x in row {
                    let _ = writeln!(t, "G0 X{} Y{}", f(x), f(y));
                    let _ = writeln!(t, "G38.2 Z{} F{}", f(o.depth), f(o.feed));
                    let _ = writeln!(t, "G0 Z{}", f(o.safe_z));
                }
            }
            t.push_str("M2\n");
        }
    }
    Ok(t)
}
