//! `machine-settings`: the slicer's or CAM system's machine settings (`M203` speed caps, `M201` accelerations, ...) leave the program; the preset's machine decides them.
//!
//! A slicer writes its own printer's limits at the top of the program: PrusaSlicer's
//! `M203 X180 Y180 Z12 E80` is a Prusa MINI's, in Marlin's mm/s. On the preset's machine
//! these numbers mean something else (on a polar printer X is r and Y is θ, and
//! RepRapFirmware reads `M203` in mm/min), and they contradict the controller model every
//! timing pass computed with: left in, the firmware would cap r at 3 mm/s and θ at 3°/s
//! while ncpost timed the valve and the screw at 100 mm/s and 180°/s.
//!
//! The commands this pass takes out: `M92` (steps per unit), `M201` (accelerations),
//! `M203` (speed caps), `M204` (print and travel accelerations), `M205` (jerk and
//! minimum speeds), `M207` (firmware retraction), `M220` (speed factor), `M221`
//! (extrusion factor), `M566` (RepRapFirmware jerk), `M900` (linear advance).
//!
//! # Options
//! - `action` (`"comment"`): `comment` keeps each one as a comment and reports all of them
//!   in one warning at the end; `error` makes the first one an error (the preset demands a
//!   program without them); `keep` passes them through unchanged.

use serde::{Deserialize, Serialize};

use super::{Output, Pass, PassInfo};
use crate::diag::Diagnostic;
use crate::ir::{Block, BlockKind, Comment, CommentStyle};

/// The M codes that set what the preset's machine definition already says.
const SETTINGS: &[(u32, &str)] = &[
    (92, "steps per unit"),
    (201, "accelerations"),
    (203, "speed caps"),
    (204, "accelerations"),
    (205, "jerk"),
    (207, "firmware retraction"),
    (220, "speed factor"),
    (221, "extrusion factor"),
    (566, "jerk"),
    (900, "linear advance"),
];

/// What happens to a machine setting in the program.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Action {
    /// Kept as a comment, with one warning naming them all.
    #[default]
    Comment,
    /// The first one is an error.
    Error,
    /// Passed through unchanged.
    Keep,
}

/// Options of `machine-settings`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Options {
    /// What happens to each setting.
    pub action: Action,
}

/// Registry entry.
pub const INFO: PassInfo = PassInfo {
    name: "machine-settings",
    summary: "slicer/CAM machine settings (M201, M203, M204, M205, M566, ...) become comments",
    build: |t, _ctx| {
        let options: Options = super::options(t)?;
        Ok(Box::new(MachineSettings {
            options,
            seen: Vec::new(),
            first_line: None,
            failed: false,
        }))
    },
    defaults: || super::to_toml(&Options::default()),
};

/// The `machine-settings` pass.
#[derive(Debug)]
pub struct MachineSettings {
    options: Options,
    /// The settings taken out, as written the first time, with their counts.
    seen: Vec<(u32, String, u64)>,
    first_line: Option<u32>,
    /// An error was reported (`action = "error"`).
    failed: bool,
}

/// The M code of a command's first word, when it is a machine setting.
fn setting(block: &Block) -> Option<u32> {
    let BlockKind::Command(c) = &block.kind else {
        return None;
    };
    let first = c.text.split_whitespace().next()?;
    let code: u32 = first.strip_prefix(['M', 'm'])?.parse().ok()?;
    SETTINGS.iter().any(|(m, _)| *m == code).then_some(code)
}

impl MachineSettings {
    fn take(&mut self, mut block: Block, code: u32, out: &mut Output<'_>) {
        let BlockKind::Command(c) = &block.kind else {
            return;
        };
        let text = c.text.to_string();
        self.first_line.get_or_insert(block.span.line);
        match self.seen.iter_mut().find(|(m, _, _)| *m == code) {
            Some(entry) => entry.2 += 1,
            None => self.seen.push((code, text.clone(), 1)),
        }
        if self.options.action == Action::Error {
            if !self.failed {
                self.failed = true;
                out.diag(
                    Diagnostic::error(
                        "machine-settings::present",
                        format!("`{text}` sets what the preset's machine defines"),
                    )
                    .at_span(block.span)
                    .with_label("a machine setting from the slicer or CAM system")
                    .with_help(
                        "remove it from the program (or from the slicer's start code), or \
                         run machine-settings with action = \"comment\"",
                    ),
                );
            }
            return;
        }
        let mut comments = vec![Comment {
            text: format!("{text} (machine setting left out: the preset's machine decides)"),
            style: CommentStyle::Semicolon,
        }];
        comments.append(&mut block.comments);
        block.kind = BlockKind::Comment;
        block.comments = comments;
        out.push(block);
    }
}

impl Pass for MachineSettings {
    fn run(&mut self, blocks: &mut Vec<Block>, out: &mut Output<'_>) {
        if self.options.action == Action::Keep {
            out.pass_on(blocks);
            return;
        }
        for block in blocks.drain(..) {
            match setting(&block) {
                Some(code) => self.take(block, code, out),
                None => out.push(block),
            }
        }
    }

    fn finish(&mut self, out: &mut Output<'_>) {
        if self.options.action != Action::Comment || self.seen.is_empty() {
            return;
        }
        let names: Vec<String> = self
            .seen
            .iter()
            .map(|(code, text, count)| {
                let what = SETTINGS
                    .iter()
                    .find(|(m, _)| m == code)
                    .map_or("", |(_, w)| w);
                match count {
                    1 => format!("`{text}` ({what})"),
                    n => format!("`{text}` ({what}, {n} times)"),
                }
            })
            .collect();
        out.diag(
            Diagnostic::warning(
                "machine-settings::commented",
                format!(
                    "machine settings from the program left out as comments, from line {}: {}",
                    self.first_line.unwrap_or(0),
                    names.join(", ")
                ),
            )
            .with_help(
                "they were written for another machine (or in another firmware's units); the \
                 preset's [machine] or [polar] controller decides speeds and accelerations",
            ),
        );
    }
}
