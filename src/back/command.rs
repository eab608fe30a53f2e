//! Commands and lines passed through as text: the words a firmware does not run, the
//! modes the controller must be in first, and what the controller no longer knows after
//! them.

use std::io::Write;

use super::{Emitter, Flavor, Modes, grbl, rrf};
use crate::diag::Diagnostic;
use crate::ir::{Block, Comment, CommentStyle};

impl<W: Write> Emitter<W> {
    pub(super) fn command(
        &mut self,
        block: &Block,
        cmd: &crate::ir::Command,
        diags: &mut Vec<Diagnostic>,
    ) -> Result<(), Diagnostic> {
        let mut text = cmd.text.as_str();
        let mut comments = std::borrow::Cow::Borrowed(&block.comments[..]);
        let split = self.unsupported_words(block, cmd)?;
        let kept;
        if let Some((k, removed, policy, wording)) = split {
            let msg = format!("`{removed}` is not supported by {}", wording.firmware);
            match policy {
                rrf::Unsupported::Error => {
                    return Err(Diagnostic::error(wording.code, msg)
                        .at_span(block.span)
                        .with_help(format!("remove it, or set the {} option `unsupported` to \"comment\" or \"keep\"", wording.option)));
                }
                rrf::Unsupported::Comment => {
                    diags.push(
                        Diagnostic::warning(wording.code, msg)
                            .at_span(block.span)
                            .with_help(format!("it is written as a comment; set the {} option `unsupported = \"keep\"` {}", wording.option, wording.keep_help)),
                    );
                    let mut c = vec![(wording.note)(&removed)];
                    c.extend(block.comments.iter().cloned());
                    comments = std::borrow::Cow::Owned(c);
                    kept = k;
                    text = &kept;
                    if text.is_empty() {
                        return self.end_line(&comments, false);
                    }
                }
                rrf::Unsupported::Keep => {}
            }
        }
        if let Some(modes) = cmd.modes {
            self.command_modes(modes);
        }
        self.text(text);
        self.end_line(&comments, true)?;
        self.forget(cmd.clobbers);
        if calls_program(text) {
            // The controller returns from a subprogram or macro in the modes its body
            // left (LinuxCNC and Fanuc keep modal state across M99): distance mode,
            // units, plane, motion mode (a canned cycle, even), feed mode and feed are
            // whatever the body set, so the next move states them all again.
            self.modes = Modes::default();
            return Ok(());
        }
        // M82/M83 pass through; the next E move puts back the output's own mode.
        for w in text.split_whitespace() {
            if let Some(n) = w
                .strip_prefix(['M', 'm'])
                .and_then(crate::num::parse_decimal)
            {
                if n == 82.0 {
                    self.modes.e_relative = Some(false);
                } else if n == 83.0 {
                    self.modes.e_relative = Some(true);
                }
            }
        }
        // A command's F (probing, homing) changes the modal feed.
        if cmd
            .text
            .split_whitespace()
            .any(|w| w.starts_with(['F', 'f']))
        {
            self.modes.feed = None;
        }
        Ok(())
    }

    /// The words of `cmd` this firmware does not run (the rest of the command kept),
    /// with what the policy says about them in its terms; `None` for most commands.
    fn unsupported_words(
        &self,
        block: &Block,
        cmd: &crate::ir::Command,
    ) -> Result<Option<Split>, Diagnostic> {
        // The words this firmware does not run (the rest of the command kept), with what
        // the policy says about them in its terms; most commands have none and are
        // checked without allocating.
        Ok(match self.flavor {
            Flavor::Grbl(g) => {
                if cmd.text.split_whitespace().any(grbl::is_subprogram_word) {
                    return Err(grbl_subprogram(block, &cmd.text));
                }
                let (k, removed) = grbl::split_words(&cmd.text, &g);
                (!removed.is_empty()).then(|| {
                    let wording = Unsupported {
                        code: "grbl::unsupported",
                        firmware: "Grbl 1.1",
                        option: "grbl",
                        keep_help: "for a build that runs it (grblHAL)",
                        note: |removed| Comment {
                            text: format!("{removed}: not supported by Grbl"),
                            style: CommentStyle::Paren,
                        },
                    };
                    (k, removed, g.unsupported, wording)
                })
            }
            // `any_unsupported` holds exactly when the split removes something.
            Flavor::Rrf { unsupported, .. } if rrf::any_unsupported(&cmd.text) => {
                let (k, removed) = rrf::split_unsupported(&cmd.text);
                let wording = Unsupported {
                    code: "rrf::unsupported",
                    firmware: "RepRapFirmware",
                    option: "rrf",
                    keep_help: "if your macros implement it",
                    note: |removed| Comment {
                        text: format!(" {removed} (not supported by RepRapFirmware)"),
                        style: CommentStyle::Semicolon,
                    },
                };
                Some((k, removed, unsupported, wording))
            }
            _ => None,
        })
    }

    /// Puts the controller into the units, distance mode and plane a command's
    /// coordinates were written in.
    fn command_modes(&mut self, modes: crate::ir::WrittenModes) {
        let metric = !modes.inch;
        if self.modes.metric != Some(metric) {
            self.text(if metric { "G21" } else { "G20" });
            self.modes.metric = Some(metric);
        }
        let absolute = !modes.relative;
        if self.modes.absolute != Some(absolute) {
            self.text(if absolute { "G90" } else { "G91" });
            self.modes.absolute = Some(absolute);
        }
        // A subprogram call: its body starts in the caller's plane.
        if let Some(plane) = modes.plane
            && self.modes.plane != Some(plane)
        {
            self.text(plane.gcode());
            self.modes.plane = Some(plane);
        }
    }

    /// Prints a line as written, first putting the controller into the modes it was
    /// written in (at the top level only).
    pub(super) fn verbatim(
        &mut self,
        block: &Block,
        v: &crate::ir::Verbatim,
        diags: &mut Vec<Diagnostic>,
    ) -> Result<(), Diagnostic> {
        if let Flavor::Grbl(g) = self.flavor
            && self.grbl_verbatim(block, v, g, diags)?
        {
            return Ok(());
        }
        if matches!(self.flavor, Flavor::Rrf { .. })
            && matches!(
                v.reason,
                crate::ir::VerbatimReason::Unevaluated | crate::ir::VerbatimReason::ControlFlow
            )
            && self.rrf_ngc_line(block, v, diags)?
        {
            return Ok(());
        }
        if v.reason == crate::ir::VerbatimReason::Delimiter {
            self.line.push_str(&v.text);
            return self.end_line(&block.comments, false);
        }
        if let Some(m) = v.modes {
            if self.modes.metric != Some(!m.inch) {
                self.text(if m.inch { "G20" } else { "G21" });
            }
            if self.modes.absolute != Some(!m.relative) {
                self.text(if m.relative { "G91" } else { "G90" });
            }
            // E modes only where this output has used them or the line moves E (LinuxCNC
            // lacks M82/M83).
            if let Some(plane) = m.plane
                && self.modes.plane != Some(plane)
            {
                self.text(plane.gcode());
                self.modes.plane = Some(plane);
            }
            if self.modes.e_relative != Some(m.relative_e)
                && crate::num::lexer::has_word(&v.text, 'E')
            {
                self.text(if m.relative_e { "M83" } else { "M82" });
                self.modes.e_relative = Some(m.relative_e);
            }
            if !self.line.is_empty() {
                self.end_line(&[], true)?;
            }
        }
        self.line.push_str(&v.text);
        self.end_line(&block.comments, false)?;
        self.forget(v.clobbers);
        let kept = v.modes.filter(|_| v.keeps_modes);
        self.modes = Modes {
            metric: kept.map(|m| !m.inch),
            absolute: kept.map(|m| !m.relative),
            // Aligned above when the line moves E; otherwise it is untouched.
            e_relative: kept.and(self.modes.e_relative),
            plane: if v.keeps_modes {
                self.modes.plane
            } else {
                None
            },
            ..Modes::default()
        };
        Ok(())
    }

    /// A copied line in RS274/NGC or Fanuc macro syntax, for RepRapFirmware, which reads
    /// neither: a line that only sets parameters is left out as a comment with a warning
    /// (nothing RepRapFirmware runs can read the value, and the line is not one of its
    /// commands), any other use is an error. `Ok(true)` when the line is dealt
    /// with, `Ok(false)` when it is RepRapFirmware's own (printed as written).
    fn rrf_ngc_line(
        &mut self,
        block: &Block,
        v: &crate::ir::Verbatim,
        diags: &mut Vec<Diagnostic>,
    ) -> Result<bool, Diagnostic> {
        let text = v.text.trim();
        if !crate::num::lexer::has_ngc_syntax(text) {
            return Ok(false);
        }
        if !crate::num::lexer::sets_parameters_only(text) {
            return Err(rrf_unevaluated(block, text));
        }
        diags.push(
            Diagnostic::warning(
                "rrf::parameter",
                format!("RepRapFirmware has no numbered parameters: `{text}` is left out as a comment"),
            )
            .at_span(block.span)
            .with_help("the value it sets feeds no line RepRapFirmware can run (one that uses it is an error)"),
        );
        let note = Comment {
            text: format!(" {text} (left out: RepRapFirmware has no numbered parameters)"),
            style: CommentStyle::Semicolon,
        };
        self.push_comment(&note, CommentStyle::Semicolon);
        self.end_line(&block.comments, false)?;
        self.forget(v.clobbers);
        Ok(true)
    }

    /// A line the IR passes as text, for Grbl: `%` is left out, an `O` number becomes a
    /// comment, subprograms, control flow, parameters and expressions are errors, and a
    /// line of plain words the IR does not model (probing, canned cycles) is checked
    /// word by word. `Ok(true)` when the line is dealt with, `Ok(false)` to print it as
    /// written.
    pub(super) fn grbl_verbatim(
        &mut self,
        block: &Block,
        v: &crate::ir::Verbatim,
        g: grbl::Settings,
        diags: &mut Vec<Diagnostic>,
    ) -> Result<bool, Diagnostic> {
        use crate::ir::VerbatimReason;
        let text = v.text.trim();
        let cut = text.find(['(', ';']).unwrap_or(text.len());
        let (code, rest) = (text[..cut].trim(), text[cut..].trim());
        let body = matches!(
            v.reason,
            VerbatimReason::Subprogram | VerbatimReason::ControlFlow
        );
        if body && (self.grbl_quiet || code.is_empty()) {
            // One error per subprogram or control-flow run; the output fails anyway.
            return Ok(true);
        }
        self.grbl_quiet = body;
        match v.reason {
            VerbatimReason::Delimiter if code.starts_with('%') => {
                self.line.push_str(rest);
                self.end_line(&block.comments, false)?;
                Ok(true)
            }
            VerbatimReason::Delimiter => {
                self.line
                    .push_str(format!("(program {code}) {rest}").trim_end());
                self.end_line(&block.comments, false)?;
                Ok(true)
            }
            VerbatimReason::Subprogram => Err(grbl_subprogram(block, text)),
            _ if code.split_whitespace().any(grbl::is_subprogram_word)
                || code.starts_with(['o', 'O']) =>
            {
                Err(grbl_subprogram(block, code))
            }
            _ if v.reason == VerbatimReason::ControlFlow || code.contains(['#', '[', '<']) => {
                Err(Diagnostic::error(
                    "grbl::unevaluated",
                    format!(
                        "Grbl cannot run `{code}`: it has no parameters, expressions or control flow"
                    ),
                )
                .at_span(block.span)
                .with_help(
                    "write the line with plain numbers, or use a controller that evaluates it (LinuxCNC)",
                ))
            }
            _ => {
                let (_, removed) = grbl::split_words(code, &g);
                if removed.is_empty() || g.unsupported == rrf::Unsupported::Keep {
                    return Ok(false);
                }
                if removed.split_whitespace().any(grbl::is_unsupported_motion) {
                    return Err(Diagnostic::error(
                        "grbl::unsupported-motion",
                        format!("Grbl 1.1 has no canned cycles, splines or threading: `{code}`"),
                    )
                    .at_span(block.span)
                    .with_help("let the CAM write the cycle as G0/G1 moves (Grbl would skip the line and not cut it)"));
                }
                let msg = format!("`{removed}` is not supported by Grbl 1.1");
                if g.unsupported == rrf::Unsupported::Error {
                    return Err(Diagnostic::error("grbl::unsupported", msg)
                        .at_span(block.span)
                        .with_help("remove it, or set the grbl option `unsupported` to \"comment\" or \"keep\""));
                }
                diags.push(
                    Diagnostic::warning("grbl::unsupported", msg)
                        .at_span(block.span)
                        .with_help("the line is written as a comment; set the grbl option `unsupported = \"keep\"` for a build that runs it (grblHAL)"),
                );
                self.line
                    .push_str(format!("({}: not supported by Grbl) {rest}", code.replace(['(', ')'], "")).trim_end());
                self.end_line(&block.comments, false)?;
                self.forget(v.clobbers);
                Ok(true)
            }
        }
    }
}

/// A command split into the words kept and the words removed, with the policy for
/// the removed ones and how they are reported.
type Split = (String, String, rrf::Unsupported, Unsupported);

/// How a firmware's unsupported words are reported and noted.
struct Unsupported {
    code: &'static str,
    firmware: &'static str,
    /// The backend's options table, for the help.
    option: &'static str,
    /// Why one would keep the words anyway.
    keep_help: &'static str,
    /// The comment that takes the removed words' place.
    note: fn(&str) -> Comment,
}

/// Whether a command runs another program, whose body may change any mode: a
/// subprogram call `M98 P<n>` (a RepRapFirmware macro file `M98 P"file.g"` too: the
/// printed program cannot see what it leaves) or a macro call `G65 P<n>`.
fn calls_program(text: &str) -> bool {
    text.split_whitespace().any(|w| {
        let code = |n: f64| crate::num::parse_decimal(&w[1..]) == Some(n);
        match w.as_bytes()[0] {
            b'M' | b'm' => code(98.0),
            b'G' | b'g' => code(65.0),
            _ => false,
        }
    })
}

/// RepRapFirmware reads neither RS274/NGC parameters and expressions nor o-word control
/// flow (its own are the meta commands, with expressions in braces): a line that needs
/// them, which it would refuse or misread.
fn rrf_unevaluated(block: &Block, text: &str) -> Diagnostic {
    Diagnostic::error(
        "rrf::unevaluated",
        format!(
            "RepRapFirmware cannot run `{text}`: it has no numbered parameters, bracket expressions or o-word control flow"
        ),
    )
    .at_span(block.span)
    .with_help("have the CAM write plain numbers (pcb2gcode: no autolevelling; a post without macros), emit for a controller that evaluates the line (--emit gcode for LinuxCNC), or rewrite it with RepRapFirmware's meta commands (var, set, while)")
}

/// Grbl has no subprograms: a call, return or body left in the IR.
fn grbl_subprogram(block: &Block, text: &str) -> Diagnostic {
    Diagnostic::error(
        "grbl::subprogram",
        format!("Grbl has no subprograms, and `{text}` was not expanded"),
    )
    .at_span(block.span)
    .with_help("expand-subprograms runs before the Grbl backend; it leaves a call with arguments or an expression (see its warning): write the call without them, or inline the body")
}
