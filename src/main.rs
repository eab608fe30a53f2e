//! The `ncpost` command line.

use std::fs::File;
use std::io::{self, BufReader, IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use clap::{Args, Parser, Subcommand, ValueEnum};
use ncpost::diag::{Diagnostic, Severity};
use ncpost::passes;
use ncpost::pipeline::{Builder, Pipeline, Source, Summary};
use ncpost::preset::{BUILTIN, Emit, Preset};

#[cfg(unix)]
#[path = "main/cleanup.rs"]
mod cleanup;

/// Compiles NC programs: G-code in, RepRapFirmware or plain G-code out.
#[derive(Parser)]
#[command(name = "ncpost", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Compile INPUT and write the result.
    Run(RunArgs),
    /// Read INPUT and report diagnostics only; write nothing.
    Check(PipelineArgs),
    /// List the passes with their options.
    Passes,
    /// List the built-in presets.
    Presets,
    /// Draw a compiled program (SVG): joint values or speeds over time, or the tool path.
    Plot(PlotArgs),
    /// Report time (motion-time model), lengths, extruded amount, bounding boxes and
    /// counts of the compiled program as a table on standard output.
    Stats(StatsArgs),
    /// Facts about a preset's machine.
    #[command(subcommand)]
    Machine(MachineCommand),
    /// Height maps for Z compensation (the `heightmap` pass).
    #[command(subcommand)]
    Heightmap(HeightmapCommand),
}

#[derive(Subcommand)]
enum HeightmapCommand {
    /// Write a program that probes a grid over an area: RepRapFirmware `M557` + `G29 S0`
    /// (saves heightmap.csv), or a Grbl `G38.2` grid whose console log (`[PRB:...]`
    /// reports) the heightmap pass reads.
    ProbeProgram(ProbeArgs),
}

#[derive(Args)]
struct ProbeArgs {
    /// The area to cover, `X0,Y0,X1,Y1` in mm (work frame of the job).
    #[arg(long, value_name = "X0,Y0,X1,Y1", allow_hyphen_values = true)]
    area: String,
    /// Grid pitch, mm; the last row and column move out so the grid covers the area.
    #[arg(long)]
    pitch: f64,
    /// The controller.
    #[arg(long, value_enum)]
    emit: ProbeEmitArg,
    /// Travel height between points, mm (grbl).
    #[arg(long, default_value_t = 2.0, allow_hyphen_values = true)]
    safe_z: f64,
    /// Lowest Z a probe moves to, mm (grbl; G38.2 alarms if it does not touch).
    #[arg(long, default_value_t = -1.0, allow_hyphen_values = true)]
    depth: f64,
    /// Probing feed, mm/min (grbl).
    #[arg(long, default_value_t = 20.0)]
    feed: f64,
    /// Output file; `-` or absent for standard output.
    #[arg(short, long)]
    output: Option<PathBuf>,
}

#[derive(Clone, Copy, ValueEnum)]
enum ProbeEmitArg {
    Rrf,
    Grbl,
}

#[derive(Subcommand)]
enum MachineCommand {
    /// Print the RepRapFirmware config.g fragment (M584, M208, M203, M201) for the machine.
    ConfigG(PresetArgs),
}

#[derive(Args)]
struct PresetArgs {
    /// A built-in preset name or a preset file.
    #[arg(long, conflicts_with = "config")]
    preset: Option<String>,
    /// A preset file.
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
}

#[derive(Args)]
struct PlotArgs {
    #[command(flatten)]
    pipeline: PipelineArgs,
    /// Plot X, Y, Z and the rotary axes over time (the default).
    #[arg(long, conflicts_with_all = ["speed", "toolpath"])]
    joints: bool,
    /// Plot the tool's linear speed (for a polar machine the tip's Cartesian speed), the
    /// axes' speeds and the screw speed (`M3 S`) over time, with the motion-time model.
    #[arg(long, conflicts_with = "toolpath")]
    speed: bool,
    /// Plot the tool path from above: cuts solid, rapids dashed, plunges as rings; the tip
    /// in the part frame (forward kinematics of the emitted joints on a 5-axis machine,
    /// r cos θ / r sin θ on a polar one).
    #[arg(long)]
    toolpath: bool,
    /// Speed assumed for rapids, mm/min.
    #[arg(long, default_value_t = 3000.0)]
    rapid_feed: f64,
    /// The SVG file; `-` or absent for standard output.
    #[arg(short, long)]
    output: Option<PathBuf>,
}

#[derive(Args)]
struct StatsArgs {
    #[command(flatten)]
    pipeline: PipelineArgs,
    /// Speed assumed for rapids, mm/min (capped by the axes' max_feed); default: the
    /// preset's `stats` option, else 3000.
    #[arg(long)]
    rapid_feed: Option<f64>,
}

#[derive(Args)]
struct RunArgs {
    #[command(flatten)]
    pipeline: PipelineArgs,
    /// Output format (overrides the preset).
    #[arg(long, value_enum)]
    emit: Option<EmitArg>,
    /// Output file; `-` or absent for standard output.
    #[arg(short, long)]
    output: Option<PathBuf>,
    /// Print the IR after pass NAME (or `front`) to standard error.
    #[arg(long, value_name = "PASS")]
    dump_after: Option<String>,
    /// Read the printed program back as the controller reads it and check it against
    /// the programmed path (tip, tool axis, block times, valve leads, material, limits);
    /// a violated tolerance is an error and no output is written. Default: on for
    /// presets with a [machine] or [polar] table.
    #[arg(long, overrides_with = "no_verify")]
    verify: bool,
    /// Do not read the printed program back (see --verify).
    #[arg(long, overrides_with = "verify")]
    no_verify: bool,
}

#[derive(Args)]
struct PipelineArgs {
    /// A built-in preset name or a preset file.
    #[arg(long, conflicts_with = "config")]
    preset: Option<String>,
    /// A preset file.
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// A pass `NAME[:key=value,...]`: sets the options of a pass the preset has,
    /// otherwise appends it. Repeatable.
    #[arg(long = "pass", value_name = "SPEC")]
    passes: Vec<String>,
    /// Input language (default: from the file extension).
    #[arg(long, value_enum)]
    from: Option<FromArg>,
    /// Show errors only.
    #[arg(short, long)]
    quiet: bool,
    /// How diagnostics are printed.
    #[arg(long, value_enum, default_value = "human")]
    message_format: MessageFormat,
    /// Diagnostics of one code shown in full; the rest are summed up in one message per
    /// code at the end (how many, on which lines, the worst). 0 shows every one.
    #[arg(long, value_name = "N", default_value_t = ncpost::diag::DEFAULT_LIMIT)]
    max_repeats: u64,
    /// Timing model for every pass that needs time (stats, plots, extrusion rate, valve
    /// timing), overriding the controller's `timing`.
    #[arg(long, value_enum)]
    timing: Option<TimingArg>,
    /// The input file, or `-` for standard input.
    input: PathBuf,
}

#[derive(Clone, Copy, ValueEnum)]
enum EmitArg {
    Rrf,
    Gcode,
    Grbl,
    Ir,
}

#[derive(Clone, Copy, PartialEq, ValueEnum)]
enum FromArg {
    Gcode,
    Cl,
    Hpgl,
}

#[derive(Clone, Copy, PartialEq, ValueEnum)]
enum TimingArg {
    /// No acceleration.
    ConstantVelocity,
    /// Trapezoidal speed profiles with per-axis acceleration and jerk-limited junctions.
    Trapezoid,
}

impl From<TimingArg> for ncpost::motion::Timing {
    fn from(t: TimingArg) -> Self {
        match t {
            TimingArg::ConstantVelocity => ncpost::motion::Timing::ConstantVelocity,
            TimingArg::Trapezoid => ncpost::motion::Timing::Trapezoid,
        }
    }
}

#[derive(Clone, Copy, PartialEq, ValueEnum)]
enum MessageFormat {
    Human,
    Json,
}

/// Exit codes: input errors and usage errors.
const EXIT_INPUT: u8 = 1;
const EXIT_USAGE: u8 = 2;

fn main() -> ExitCode {
    let cli = Cli::parse();
    match cli.command {
        Command::Passes => {
            // The names in one column, as wide as the longest.
            let w = passes::REGISTRY
                .iter()
                .map(|p| p.name.len())
                .max()
                .unwrap_or(0);
            for p in passes::REGISTRY {
                print_out(format_args!("{:<w$} {}\n", p.name, p.summary));
                let defaults = (p.defaults)();
                for line in defaults.lines() {
                    print_out(format_args!("{:<w$}   {line}\n", ""));
                }
            }
            ExitCode::SUCCESS
        }
        Command::Presets => {
            let w = BUILTIN.iter().map(|(n, _)| n.len()).max().unwrap_or(0);
            for (name, _) in BUILTIN {
                let desc = Preset::builtin(name)
                    .map(|p| p.description)
                    .unwrap_or_default();
                print_out(format_args!("{name:<w$} {desc}\n"));
            }
            ExitCode::SUCCESS
        }
        Command::Run(args) => run(
            &args.pipeline,
            false,
            args.emit,
            args.output.as_deref(),
            args.dump_after.as_deref(),
            match (args.verify, args.no_verify) {
                (true, _) => Some(true),
                (_, true) => Some(false),
                _ => None,
            },
        ),
        Command::Check(args) => run(&args, true, None, None, None, None),
        Command::Plot(args) => plot(&args),
        Command::Stats(args) => stats(&args),
        Command::Machine(MachineCommand::ConfigG(args)) => config_g(&args),
        Command::Heightmap(HeightmapCommand::ProbeProgram(args)) => probe_program(&args),
    }
}

fn probe_program(args: &ProbeArgs) -> ExitCode {
    use ncpost::heightmap::{ProbeEmit, ProbeOptions};
    let area: Vec<f64> = match args
        .area
        .split(',')
        .map(|v| v.trim().parse::<f64>())
        .collect::<Result<_, _>>()
    {
        Ok(v) => v,
        Err(_) => return usage(format!("--area `{}` is not X0,Y0,X1,Y1", args.area)),
    };
    let [x0, y0, x1, y1] = area[..] else {
        return usage(format!("--area `{}` is not X0,Y0,X1,Y1", args.area));
    };
    let options = ProbeOptions {
        area: [x0, y0, x1, y1],
        pitch: args.pitch,
        emit: match args.emit {
            ProbeEmitArg::Rrf => ProbeEmit::Rrf,
            ProbeEmitArg::Grbl => ProbeEmit::Grbl,
        },
        safe_z: args.safe_z,
        depth: args.depth,
        feed: args.feed,
    };
    let text = match ncpost::heightmap::probe_program(&options) {
        Ok(t) => t,
        Err(e) => return usage(e.message),
    };
    match args.output.as_deref().filter(|o| o.as_os_str() != "-") {
        None => {
            print_out(format_args!("{text}"));
            ExitCode::SUCCESS
        }
        Some(path) => write_atomically(
            path,
            |out, _| {
                out.write_all(text.as_bytes())
                    .map(|_| ncpost::pipeline::Summary::default())
                    .map_err(|e| Diagnostic::io("io::write", e.to_string()))
            },
            &mut Printer::new("-", true, MessageFormat::Human),
        ),
    }
}

/// The preset named by `--preset` / `--config` (default: `default`).
fn load_preset(preset: Option<&str>, config: Option<&Path>) -> Result<Preset, Diagnostic> {
    match config {
        Some(path) => preset_file(path),
        None => Preset::load(preset.unwrap_or("default")),
    }
}

fn config_g(args: &PresetArgs) -> ExitCode {
    let preset = match load_preset(args.preset.as_deref(), args.config.as_deref()) {
        Ok(p) => p,
        Err(e) => return usage(e.message),
    };
    let Some(machine) = preset.machine else {
        return usage("this preset has no [machine] table; try --preset emoc-x5");
    };
    if let Err(e) = machine.check() {
        return usage(format!("[machine]: {}", e.message));
    }
    print_out(format_args!("{}", machine.config_g()));
    ExitCode::SUCCESS
}

fn plot(args: &PlotArgs) -> ExitCode {
    let _ = args.joints;
    let pipeline_args = &args.pipeline;
    let mut pipeline = match builder(pipeline_args, None, None).and_then(|b| b.build()) {
        Ok(p) => p,
        Err(e) => return usage(e.message),
    };
    let source = source_of(pipeline_args);
    let (input, file_name) = match open_input(&pipeline_args.input) {
        Ok(x) => x,
        Err(code) => return code,
    };
    let mut printer = Printer::new(
        &file_name,
        pipeline_args.quiet,
        pipeline_args.message_format,
    );
    let (summary, svg) = if args.speed {
        let mut plot = ncpost::plot::SpeedPlot::for_preset(
            pipeline.preset(),
            pipeline_args.timing.map(Into::into),
            args.rapid_feed,
        );
        let summary = pipeline.run_into(source, input, &mut plot, &mut |d| printer.print(d));
        (summary, plot.svg())
    } else if args.toolpath {
        let frame = ncpost::plot::toolpath::Frame::for_preset(pipeline.preset());
        let mut plot = ncpost::plot::toolpath::ToolpathPlot::new(frame);
        let summary = pipeline.run_into(source, input, &mut plot, &mut |d| printer.print(d));
        (summary, plot.svg())
    } else {
        let mut plot = ncpost::plot::JointPlot::new(args.rapid_feed);
        let summary = pipeline.run_into(source, input, &mut plot, &mut |d| printer.print(d));
        (summary, plot.svg())
    };
    if summary.errors > 0 {
        return finish(Ok(summary), &mut printer);
    }
    match args.output.as_deref().filter(|o| o.as_os_str() != "-") {
        None => {
            print_out(format_args!("{svg}"));
            finish(Ok(summary), &mut printer)
        }
        Some(path) => write_atomically(
            path,
            |out, _| {
                out.write_all(svg.as_bytes())
                    .map(|_| summary)
                    .map_err(|e| Diagnostic::io("io::write", e.to_string()))
            },
            &mut printer,
        ),
    }
}

/// `ncpost stats`: the preset's pipeline into a `stats` collector, the table on stdout.
fn stats(args: &StatsArgs) -> ExitCode {
    let pipeline_args = &args.pipeline;
    let timing = pipeline_args.timing.map(ncpost::motion::Timing::from);
    // A `stats` pass of the preset gives its options (a controller for a machine-less
    // preset) to the collector instead of reporting on its own.
    let built = builder(pipeline_args, None, None).and_then(|b| {
        let mut preset = b.preset_ref().clone();
        let own = preset
            .passes
            .iter()
            .position(|p| p.name == "stats")
            .map(|i| preset.passes.remove(i).options);
        let options: passes::stats::Options = match own {
            Some(t) => passes::options(&t).map_err(|e| {
                Diagnostic::settings(format!("options of pass `stats`: {}", e.message))
            })?,
            None => passes::stats::Options::default(),
        };
        let mut b = Pipeline::builder()
            .preset(preset)
            .max_repeats(pipeline_args.max_repeats);
        if let Some(t) = timing {
            b = b.timing(t);
        }
        Ok((b.build()?, options))
    });
    let (mut pipeline, mut options) = match built {
        Ok(x) => x,
        Err(e) => return usage(e.message),
    };
    let source = source_of(pipeline_args);
    let (input, file_name) = match open_input(&pipeline_args.input) {
        Ok(x) => x,
        Err(code) => return code,
    };
    let mut printer = Printer::new(
        &file_name,
        pipeline_args.quiet,
        pipeline_args.message_format,
    );
    let preset = pipeline.preset();
    let ctx = passes::Context {
        machine: preset.machine.as_ref(),
        polar: preset.polar.as_ref(),
        flavour: preset.backend_flavour(),
        timing,
        ..passes::Context::default()
    };
    if let Some(f) = args.rapid_feed {
        options.rapid_feed = f;
    }
    let mut collector = passes::stats::Stats::from_context(&options, &ctx);
    if let Some((r, theta)) = ncpost::plot::polar_axes(preset) {
        collector = collector.with_polar(r, theta);
    }
    let summary = pipeline.run_into(source, input, &mut collector, &mut |d| printer.print(d));
    if summary.errors == 0 {
        print_out(format_args!("{}", collector.table()));
    }
    finish(Ok(summary), &mut printer)
}

fn source_of(args: &PipelineArgs) -> Source {
    match args.from.unwrap_or_else(|| from_extension(&args.input)) {
        FromArg::Cl => Source::Cl,
        FromArg::Hpgl => Source::Hpgl,
        _ => Source::Gcode,
    }
}

/// Opens the input (`-` is standard input) and names it for diagnostics.
fn open_input(path: &Path) -> Result<(Box<dyn io::BufRead>, String), ExitCode> {
    if path.as_os_str() == "-" {
        return Ok((Box::new(io::stdin().lock()), "<stdin>".to_string()));
    }
    if path.is_dir() {
        return Err(usage(format!(
            "{} is a directory; give an input file",
            path.display()
        )));
    }
    match File::open(path) {
        Ok(f) => Ok((
            Box::new(BufReader::with_capacity(1 << 16, f)),
            path.display().to_string(),
        )),
        Err(e) => Err(usage(format!("cannot open {}: {e}", path.display()))),
    }
}

/// Writes to standard output; when the reader has gone (`ncpost passes | head`) the
/// program ends quietly instead of panicking as `print!` would.
fn print_out(args: std::fmt::Arguments<'_>) {
    let mut out = io::stdout().lock();
    if let Err(e) = out.write_fmt(args).and_then(|_| out.flush()) {
        if e.kind() == io::ErrorKind::BrokenPipe {
            std::process::exit(0);
        }
        eprintln!("error: cannot write to standard output: {e}");
        std::process::exit(i32::from(EXIT_INPUT));
    }
}

fn usage(msg: impl AsRef<str>) -> ExitCode {
    eprintln!("error: {}", msg.as_ref());
    ExitCode::from(EXIT_USAGE)
}

/// Runs the pipeline; with `check_only` the output is discarded. `verify` overrides the
/// preset's default of `--verify`.
fn run(
    args: &PipelineArgs,
    check_only: bool,
    emit: Option<EmitArg>,
    output: Option<&Path>,
    dump_after: Option<&str>,
    verify: Option<bool>,
) -> ExitCode {
    let builder = match builder(args, emit, dump_after) {
        Ok(b) => {
            let on = verify.unwrap_or_else(|| ncpost::pipeline::verify_by_default(b.preset_ref()));
            b.verify(on)
        }
        Err(e) => return usage(e.message),
    };
    let source = match args.from.unwrap_or_else(|| from_extension(&args.input)) {
        FromArg::Gcode => Source::Gcode,
        FromArg::Cl => Source::Cl,
        FromArg::Hpgl => Source::Hpgl,
    };
    if source == Source::Cl && !builder.preset_ref().passes.iter().any(|p| p.name == "ik") {
        let machines: Vec<&str> = BUILTIN
            .iter()
            .filter(|(n, _)| Preset::builtin(n).is_some_and(|p| p.machine.is_some()))
            .map(|(n, _)| *n)
            .collect();
        return usage(format!(
            "APT CL data gives tool poses, which need a machine and the `ik` pass: use a preset with a [machine] table ({})",
            machines.join(", ")
        ));
    }
    let mut pipeline = match builder.build() {
        Ok(p) => p,
        Err(e) => return usage(e.message),
    };

    let stdin_input = args.input.as_os_str() == "-";
    let file_name = if stdin_input {
        "<stdin>".to_string()
    } else {
        args.input.display().to_string()
    };
    if !stdin_input && args.input.is_dir() {
        return usage(format!(
            "{} is a directory; give a G-code file",
            args.input.display()
        ));
    }
    if let Some(o) = output.filter(|o| o.as_os_str() != "-" && o.is_dir()) {
        return usage(format!(
            "{} is a directory; give an output file name",
            o.display()
        ));
    }
    let input: Box<dyn io::BufRead> = if stdin_input {
        Box::new(io::stdin().lock())
    } else {
        match File::open(&args.input) {
            Ok(f) => Box::new(BufReader::with_capacity(1 << 16, f)),
            Err(e) => return usage(format!("cannot open {}: {e}", args.input.display())),
        }
    };

    let mut printer = Printer::new(&file_name, args.quiet, args.message_format);
    if !stdin_input && !args.quiet && io::stderr().is_terminal() {
        attach_progress(&mut pipeline, &args.input);
    }

    let result = if check_only {
        pipeline.run_source(source, input, io::sink(), &mut |d| printer.print(d))
    } else {
        match output.filter(|o| o.as_os_str() != "-") {
            None => pipeline.run_source(source, input, io::stdout(), &mut |d| printer.print(d)),
            Some(path) => {
                if !stdin_input && same_file(&args.input, path) {
                    return usage(format!(
                        "{} is the input; choose another output file",
                        path.display()
                    ));
                }
                return write_atomically(
                    path,
                    |out, printer| {
                        pipeline.run_source(source, input, out, &mut |d| printer.print(d))
                    },
                    &mut printer,
                );
            }
        }
    };
    finish(result, &mut printer)
}

fn finish(result: Result<Summary, Diagnostic>, printer: &mut Printer) -> ExitCode {
    match result {
        Ok(s) if s.errors == 0 => ExitCode::SUCCESS,
        Ok(s) => {
            if printer.format == MessageFormat::Human {
                eprintln!(
                    "{} error{}, {} warning{}",
                    s.errors,
                    plural(s.errors),
                    s.warnings,
                    plural(s.warnings)
                );
            }
            ExitCode::from(EXIT_INPUT)
        }
        Err(d) => {
            printer.print(d);
            ExitCode::from(EXIT_INPUT)
        }
    }
}

/// The output file of an atomic write, with each few megabytes sent to the disk as soon
/// as they are written (a helper thread's `fdatasync` on a second handle), so that the
/// `fsync` before the rename waits for the last few only instead of the whole file at the
/// end of the run (34 ms for 46 MB of 5-axis output here).
struct EarlySync<'a> {
    file: &'a mut File,
    /// Bytes written since the last request.
    unsynced: u64,
    ask: Option<std::sync::mpsc::SyncSender<()>>,
    worker: Option<std::thread::JoinHandle<()>>,
}

/// Bytes written between two requests to sync.
const EARLY_SYNC_BYTES: u64 = 8 << 20;

impl<'a> EarlySync<'a> {
    fn new(file: &'a mut File) -> Self {
        let (ask, worker) = match file.try_clone() {
            Ok(handle) => {
                let (ask, asked) = std::sync::mpsc::sync_channel::<()>(1);
                let worker = std::thread::spawn(move || {
                    // Errors are the final `fsync`'s to report.
                    while asked.recv().is_ok() {
                        let _ = handle.sync_data();
                    }
                });
                (Some(ask), Some(worker))
            }
            // Without a second handle the final `fsync` does it all, as before.
            Err(_) => (None, None),
        };
        EarlySync {
            file,
            unsynced: 0,
            ask,
            worker,
        }
    }
}

impl Write for EarlySync<'_> {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        let n = self.file.write(buf)?;
        self.unsynced += n as u64;
        if self.unsynced >= EARLY_SYNC_BYTES {
            self.unsynced = 0;
            if let Some(ask) = &self.ask {
                // A request still waiting covers these bytes too.
                let _ = ask.try_send(());
            }
        }
        Ok(n)
    }

    fn flush(&mut self) -> io::Result<()> {
        self.file.flush()
    }
}

impl Drop for EarlySync<'_> {
    fn drop(&mut self) {
        // The worker ends when its channel closes.
        self.ask = None;
        if let Some(worker) = self.worker.take() {
            let _ = worker.join();
        }
    }
}

/// Writes to a temporary file beside `path` and renames it over `path` only on success.
/// The temporary file is removed on failure, and on SIGINT, SIGTERM, SIGHUP and aborts
/// (`cleanup`).
fn write_atomically(
    path: &Path,
    body: impl FnOnce(&mut (dyn Write + Send), &mut Printer) -> Result<Summary, Diagnostic>,
    printer: &mut Printer,
) -> ExitCode {
    // What the name stands for: a device or a pipe (`-o /dev/null`, a FIFO) is written
    // in place, since renaming a file over it would replace it; a symbolic link is
    // followed, so the link stays and its target is replaced.
    let path = match std::fs::metadata(path) {
        Ok(m) if !m.is_file() => return write_in_place(path, body, printer),
        Ok(_) => path.canonicalize().unwrap_or_else(|_| path.to_path_buf()),
        Err(_) => path.to_path_buf(),
    };
    let path = path.as_path();
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    // Declared before the temporary file, so that it is dropped after it.
    #[cfg(unix)]
    let guard = cleanup::Guard::new();
    let mut tmp = match tempfile::Builder::new()
        .prefix(".ncpost-")
        .suffix(".tmp")
        .tempfile_in(&dir)
    {
        Ok(t) => t,
        Err(e) => {
            return usage(format!(
                "cannot create a temporary file in {}: {e}",
                dir.display()
            ));
        }
    };
    #[cfg(unix)]
    guard.set(tmp.path());
    let mut out = EarlySync::new(tmp.as_file_mut());
    let result = body(&mut out, printer);
    drop(out);
    let ok = matches!(result, Ok(s) if s.errors == 0);
    let code = finish(result, printer);
    if ok {
        // A new file gets ordinary permissions (the temporary file is private); a
        // replaced file keeps its own.
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let mode = std::fs::metadata(path)
                .map(|m| m.permissions().mode())
                .unwrap_or(0o644);
            let _ = tmp
                .as_file()
                .set_permissions(std::fs::Permissions::from_mode(mode));
        }
        if let Err(e) = tmp
            .as_file_mut()
            .sync_all()
            .and_then(|_| tmp.persist(path).map(|_| ()).map_err(|e| e.error))
        {
            eprintln!("error: cannot write {}: {e}", path.display());
            return ExitCode::from(EXIT_INPUT);
        }
    } else if printer.format == MessageFormat::Human {
        eprintln!("no output written: {} is unchanged", path.display());
    }
    // On failure the temporary file is removed when `tmp` drops; `path` is untouched.
    code
}

/// Writes to a device or pipe as the output comes (nothing to rename; a failed run may
/// have written part of its output there, as with standard output).
fn write_in_place(
    path: &Path,
    body: impl FnOnce(&mut (dyn Write + Send), &mut Printer) -> Result<Summary, Diagnostic>,
    printer: &mut Printer,
) -> ExitCode {
    match std::fs::OpenOptions::new().write(true).open(path) {
        Ok(mut file) => {
            let result = body(&mut file, printer);
            finish(result, printer)
        }
        Err(e) => usage(format!("cannot open {} for writing: {e}", path.display())),
    }
}

fn plural(n: u64) -> &'static str {
    if n == 1 { "" } else { "s" }
}

fn same_file(a: &Path, b: &Path) -> bool {
    match (a.canonicalize(), b.canonicalize()) {
        (Ok(x), Ok(y)) => x == y,
        _ => false,
    }
}

/// The preset in the file at `path` (`--config`).
fn preset_file(path: &Path) -> Result<Preset, Diagnostic> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| Diagnostic::settings(format!("cannot read {}: {e}", path.display())))?;
    Preset::from_toml(&text)
        .map_err(|e| Diagnostic::settings(format!("{}: {}", path.display(), e.message)))
}

fn builder(
    args: &PipelineArgs,
    emit: Option<EmitArg>,
    dump_after: Option<&str>,
) -> Result<Builder, Diagnostic> {
    let mut b = Pipeline::builder();
    if let Some(path) = &args.config {
        b = b.preset(preset_file(path)?);
    } else {
        b = b.preset_name(args.preset.as_deref().unwrap_or("default"))?;
    }
    for spec in &args.passes {
        let (name, table) = passes::parse_spec(spec)?;
        if passes::lookup(&name).is_none() {
            let names: Vec<&str> = passes::REGISTRY.iter().map(|p| p.name).collect();
            return Err(Diagnostic::settings(format!(
                "unknown pass `{name}`; the passes are: {}",
                names.join(", ")
            )));
        }
        b = b.pass(&name, table);
    }
    if let Some(t) = args.timing {
        b = b.timing(t.into());
    }
    b = b.max_repeats(args.max_repeats);
    if let Some(e) = emit {
        b = b.emit(match e {
            EmitArg::Rrf => Emit::Rrf,
            EmitArg::Gcode => Emit::Gcode,
            EmitArg::Grbl => Emit::Grbl,
            EmitArg::Ir => Emit::Ir,
        });
    }
    if let Some(name) = dump_after {
        b = b.dump_after(name, Box::new(io::stderr()));
    }
    Ok(b)
}

fn from_extension(path: &Path) -> FromArg {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    match ext.as_str() {
        "cl" | "apt" | "cls" | "clsf" => FromArg::Cl,
        "hpgl" | "plt" | "hpg" => FromArg::Hpgl,
        // NX and other CAM systems write CL listings as .txt: look at the text.
        "txt" | "lst" | "" if looks_like_cl(path) => FromArg::Cl,
        _ => FromArg::Gcode,
    }
}

/// Whether the start of a file reads like APT CL data (`GOTO/`, `TOOL PATH/`, ...).
fn looks_like_cl(path: &Path) -> bool {
    use std::io::Read;
    let mut head = Vec::new();
    let Ok(f) = File::open(path) else {
        return false;
    };
    if f.take(16 * 1024).read_to_end(&mut head).is_err() {
        return false;
    }
    const WORDS: [&str; 12] = [
        "GOTO/",
        "FROM/",
        "PARTNO",
        "TOOL PATH/",
        "MULTAX",
        "FEDRAT/",
        "TLAXIS/",
        "UNITS/",
        "CUTTER/",
        "SPINDL/",
        "LOADTL/",
        "TLDATA/",
    ];
    String::from_utf8_lossy(&head).lines().any(|l| {
        let l = l.trim_start().to_ascii_uppercase();
        WORDS.iter().any(|w| l.starts_with(w))
    })
}

fn attach_progress(pipeline: &mut Pipeline, input: &Path) {
    const LARGE: u64 = 16 << 20;
    let Ok(meta) = std::fs::metadata(input) else {
        return;
    };
    if meta.len() < LARGE {
        return;
    }
    let bar = indicatif::ProgressBar::new(meta.len());
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{bar:40} {bytes}/{total_bytes} {bytes_per_sec} eta {eta}",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    pipeline.on_progress(Box::new(move |n| {
        bar.set_position(n);
        if n >= bar.length().unwrap_or(u64::MAX) {
            bar.finish_and_clear();
        }
    }));
}

/// Prints diagnostics to standard error (the pipeline has already capped repeated ones,
/// see `--max-repeats`).
struct Printer {
    file: String,
    quiet: bool,
    format: MessageFormat,
    fancy: bool,
}

impl Printer {
    fn new(file: &str, quiet: bool, format: MessageFormat) -> Self {
        Printer {
            file: file.to_string(),
            quiet,
            format,
            fancy: io::stderr().is_terminal(),
        }
    }

    fn print(&mut self, d: Diagnostic) {
        if self.quiet && d.severity != Severity::Error {
            return;
        }
        let mut err = io::stderr().lock();
        if self.format == MessageFormat::Json {
            let _ = writeln!(err, "{}", d.to_json(&self.file));
            return;
        }
        if d.severity == Severity::Note {
            let _ = writeln!(err, "{}", d.message);
            return;
        }
        let _ = writeln!(err, "{}", d.render(&self.file, self.fancy));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Past several sync requests the file holds exactly what was written, and dropping
    /// the writer ends its helper thread.
    #[test]
    fn early_sync_writes_everything() {
        let dir = tempfile::tempdir().expect("temporary directory");
        let path = dir.path().join("out");
        let mut file = File::create(&path).expect("create");
        let chunk: Vec<u8> = (0..=255u8).cycle().take(1 << 20).collect();
        {
            let mut out = EarlySync::new(&mut file);
            assert!(out.worker.is_some());
            for _ in 0..20 {
                out.write_all(&chunk).expect("write");
            }
            out.write_all(b"end").expect("write");
        }
        file.sync_all().expect("sync");
        let back = std::fs::read(&path).expect("read");
        assert_eq!(back.len(), 20 * chunk.len() + 3);
        assert!(back.chunks(chunk.len()).take(20).all(|c| c == &chunk[..]));
        assert!(back.ends_with(b"end"));
    }
}
