//! # ncpost
//!
//! A compiler for NC programs: frontends read G-code (and, in later versions, APT CL data
//! and HPGL) into one intermediate representation ([`ir`]); [`passes`] transform it; backends
//! ([`back`]) print RepRapFirmware or plain G-code. Everything streams block by block, so
//! memory does not grow with the input.
//!
//! ```
//! use ncpost::pipeline::compile_str;
//! use ncpost::preset::Preset;
//!
//! let preset = Preset::builtin("duet-cnc").unwrap();
//! let gcode = compile_str("G20 G0 X0 Y0\nG91\nG1 X1 Y1 F10 ; one inch\n", &preset).unwrap();
//! assert!(gcode.contains("G1 X25.4 Y25.4 F254 ; one inch"));
//! ```
#![warn(missing_docs)]

pub mod back;
pub mod diag;
pub mod front;
pub mod heightmap;
pub mod ir;
pub mod machine;
pub mod motion;
pub mod num;
pub mod passes;
pub mod pipeline;
pub mod plot;
pub mod preset;
pub mod readback;
pub mod valid;

pub use diag::{Diagnostic, Kind, Severity};
pub use pipeline::Pipeline;
