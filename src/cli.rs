//! Command-line arguments (clap). Exit codes: 0 all good, 2 some runs failed
//! (or problems found), 1 usage or config error.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Args, Parser, Subcommand};

use crate::bounds::{f64_above_at_most, MAX_AE_RATE_HZ, MAX_FOLDS, MAX_RUNS};
pub use crate::config_args::ConfigArgs;

#[derive(Parser, Debug)]
#[command(
    name = "sparkout",
    version,
    about = "Batch processor for precision grinding and polishing machines: datums, compensation, \
             prediction, removal, reports — and a diagnosis of the sim-to-real gap.",
    after_help = "Start with `sparkout demo`. Exit codes: 0 all good, 2 some runs failed, 1 usage or config error."
)]
pub struct Cli {
    /// More log output (-v debug, -vv trace).
    #[arg(short, long, global = true, action = clap::ArgAction::Count)]
    pub verbose: u8,
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Run the DAG over every recorded run under --input (the nightly batch).
    #[command(
        after_help = "Example: sparkout run --input runs/ --out out/ --set diagnose.folds=4\n\
                      Writes <out>/<machine>/<run>/*.parquet, report.html; <out>/fleet/{observations.parquet,\
                      diagnosis.json,report.html}; <out>/failures.json; <out>/manifest.json (last).\n\
                      Unchanged stages are skipped (content-hash cache)."
    )]
    #[command(allow_negative_numbers = true)]
    Run {
        #[command(flatten)]
        config: ConfigArgs,
        /// Root of the recorded runs: <root>/<machine>/<run>/run.toml; a
        /// directory or s3:// gs:// az:// file:// URL (docs/scale.md).
        #[arg(long, value_name = "DIR|URL")]
        input: PathBuf,
        /// Output directory, or a bucket URL the outputs are published to.
        #[arg(long, value_name = "DIR|URL")]
        out: PathBuf,
        /// Local directory for staged remote inputs and outputs bound for
        /// object storage (default: under the system temp dir, per URL).
        #[arg(long, value_name = "DIR")]
        work: Option<PathBuf>,
        /// Worker threads across runs (default: all cores; more than the
        /// cores are clamped to them).
        #[arg(long, value_name = "N")]
        jobs: Option<usize>,
        /// Process only shard i of n (0-based) and write <out>/shard.json
        /// instead of the fleet steps; join the shards with `sparkout
        /// aggregate` (docs/scale.md).
        #[arg(long, value_name = "I/N")]
        shard: Option<String>,
        /// How --shard splits the runs: `hash` of (machine, run) — stable —
        /// or `size`: greedy by input bytes.
        #[arg(
            long,
            value_name = "hash|size",
            default_value = "hash",
            requires = "shard"
        )]
        balance: String,
        /// Append the night's diagnosis to this fleet history, a directory or
        /// a bucket URL (staged into --work, published back after the night)
        /// (DIR/night=YYYY-MM-DD/diagnosis.parquet) and write <out>/trend/.
        #[arg(long, value_name = "DIR", conflicts_with = "shard")]
        history: Option<PathBuf>,
        /// The night's date for --history (default: the latest [run].started
        /// of the batch's runs).
        #[arg(long, value_name = "YYYY-MM-DD", requires = "history")]
        night: Option<String>,
        /// A deliberate change the trend starts a new baseline at instead
        /// of alerting (repeatable): machine=ID,kind=KIND[,note=TEXT][,night=D]
        /// with KIND one of wheel_change, dressing, repair, config, other
        /// (no machine: the whole fleet; night: this one). Kept in
        /// <history>/events.toml.
        #[arg(long = "event", value_name = "SPEC", requires = "history")]
        events: Vec<String>,
        /// Add the effects of an earlier diagnosis (its
        /// fleet/augmented_model.json) to the sim side and report the plain
        /// vs augmented gap on the runs it was not fitted on
        /// (fleet/augment.json, fleet page verdicts).
        #[arg(long, value_name = "JSON", conflicts_with = "shard")]
        augment: Option<PathBuf>,
        /// Process exactly the runs listed in this night snapshot (written
        /// by `sparkout snapshot` when the night started): runs that
        /// arrived later are left for the next night, a listed run that is
        /// gone is a failure. Give every shard of a night the same file.
        #[arg(long, value_name = "FILE")]
        snapshot: Option<PathBuf>,
    },
    /// List the night's runs once, when the night starts, so every shard
    /// (and a re-run) partitions the same run set however late it starts.
    #[command(
        after_help = "Example:\n  sparkout snapshot --input runs/ --out night.json\n  \
                      sparkout run --input runs/ --out shards/0 --shard 0/2 --snapshot night.json\n\
                      The file lists run directories relative to the input (docs/scale.md)."
    )]
    Snapshot {
        /// Root of the recorded runs: a directory or a bucket URL (only the
        /// run.toml files are fetched).
        #[arg(long, value_name = "DIR|URL")]
        input: PathBuf,
        /// The snapshot file to write (JSON).
        #[arg(long, value_name = "FILE")]
        out: PathBuf,
        /// Local directory for a staged bucket input.
        #[arg(long, value_name = "DIR")]
        work: Option<PathBuf>,
    },
    /// Each diagnosed effect over nights, from a fleet history: trend.html and
    /// trend.json (ranked alerts when a material effect appears, disappears
    /// or moves beyond its night-to-night spread; docs/diagnosis.md "History
    /// and trend").
    #[command(
        after_help = "Example: sparkout trend --history history/ --out trend/ \\\n                          --event night=2026-11-20,machine=form-1,kind=wheel_change,note=\"new wheel\"\n\
                      Events in <history>/events.toml ([[event]] night, machine, kind, note) apply too. \
                      Settings: [trend] of --config, --set trend.KEY=VALUE."
    )]
    Trend {
        #[command(flatten)]
        config: ConfigArgs,
        /// A deliberate change for this report (repeatable):
        /// night=D,machine=ID,kind=KIND[,note=TEXT]; see `run --event`.
        #[arg(long = "event", value_name = "SPEC")]
        events: Vec<String>,
        /// The history written by `sparkout run --history DIR`.
        #[arg(long, value_name = "DIR")]
        history: PathBuf,
        /// Where trend.html and trend.json go.
        #[arg(long, value_name = "DIR")]
        out: PathBuf,
        /// Print trend.json to stdout.
        #[arg(long)]
        json: bool,
    },
    /// Join the outputs of `sparkout run --shard i/n` (every i) and run the
    /// fleet steps once: observations, diagnosis, fleet report, index, manifest.
    #[command(
        after_help = "Example:\n  sparkout run --input runs/ --out shards/0 --shard 0/2\n  \
                      sparkout run --input runs/ --out shards/1 --shard 1/2\n  \
                      sparkout aggregate --shards shards/0 shards/1 --out out/\n\
                      The fleet outputs equal those of `sparkout run --input runs/ --out out/`."
    )]
    Aggregate {
        #[command(flatten)]
        config: ConfigArgs,
        /// The shards' output directories or bucket URLs (each holds shard.json).
        #[arg(long, value_name = "DIR|URL", num_args = 1.., required = true)]
        shards: Vec<PathBuf>,
        /// Output directory (may be one of the shards' directories) or URL.
        #[arg(long, value_name = "DIR|URL")]
        out: PathBuf,
        /// Local directory for staged shards and outputs bound for object
        /// storage (default: under the system temp dir, per URL).
        #[arg(long, value_name = "DIR")]
        work: Option<PathBuf>,
    },
    /// Copy a directory tree to or from object storage: a local directory to
    /// s3:// gs:// az:// (uploaded under temporary keys, renamed into place,
    /// manifest.json last), or a bucket prefix to a local directory.
    #[command(
        after_help = "Examples:\n  sparkout sync runs/ s3://fleet-data/2026-11-25/runs\n  \
                      sparkout sync s3://fleet-data/2026-11-25/out out/\n\
                      Credentials and endpoint from AWS_* / GOOGLE_* / AZURE_* (docs/scale.md)."
    )]
    Sync {
        /// Source: a directory or a bucket URL.
        from: PathBuf,
        /// Destination: a bucket URL or a directory.
        to: PathBuf,
    },
    /// Run one stage of one run (its upstream stages are computed in memory),
    /// or a stage that takes its inputs from flags (e.g. datum --planes).
    #[command(
        after_help = "Examples:\n  sparkout stage datum --run runs/kr16-lab/r0000 --out /tmp/d --json\n  \
                      sparkout stage datum --planes \"0,0,1,12.4;1,0,0,-20;0,1,0,-13\" --json\n  \
                      sparkout stage cycle --weld-mm 2.27 --rough 7 --finish 2 --spark 2 --doc-rough 0.3 \
                      --doc-finish 0.1 --first-cut 0.2 --json\n\
                      Stage-specific flags (--planes, --weld-mm, ...) are passed to the stage and checked like \
                      config keys; stage cycle: --rough/--finish/--spark 0 to 100000 passes, --weld-mm and the \
                      depths > 0."
    )]
    #[command(allow_negative_numbers = true)]
    Stage {
        /// Stage name (every stage of this build is listed below).
        name: String,
        /// The run directory (holds run.toml).
        #[arg(long, value_name = "DIR")]
        run: Option<PathBuf>,
        /// Where the stage's artifacts go (<artifact>.parquet).
        #[arg(long, value_name = "DIR")]
        out: Option<PathBuf>,
        /// Print the stage's JSON summary to stdout.
        #[arg(long)]
        json: bool,
        #[command(flatten)]
        config: ConfigArgs,
        /// Stage-specific flags, e.g. --planes "a,b,c,d;..." or --weld-mm 2.27.
        #[arg(
            trailing_var_arg = true,
            allow_hyphen_values = true,
            value_name = "STAGE FLAGS"
        )]
        extra: Vec<String>,
    },
    /// Check every run under ROOT against the data contracts; writes nothing.
    #[command(
        after_help = "Example: sparkout validate-input runs/\nExit 0 when clean, 2 when problems were found."
    )]
    ValidateInput {
        root: PathBuf,
        /// The same --config/--set/--machines as `run`: the checks are the same.
        #[command(flatten)]
        config: ConfigArgs,
    },
    /// Turn CSV (or Parquet) files with foreign column names into recorded runs.
    #[command(
        after_help = "Examples:\n  sparkout import datasets/samples/umich_cnc/*.csv.gz --mapping umich_cnc --out runs/\n  \
                      sparkout import log.csv --out runs/ --table motion --machine mill-3 --plugin servo \\\n    \
                      --map time=t_s --map Xcmd=cmd_x_mm --map Xact=act_x_mm --map Ycmd=cmd_y_mm --map Zcmd=cmd_z_mm \\\n    \
                      --map F=feed_mm_s*0.0166667\n\
                      SRC may be #N for the N-th column (0-based). Writes <out>/<machine>/<run>/{run.toml,<table>.parquet}; \
                      one run per file (or per value of [import].split_by). Format: docs/import.md. \
                      Exit 2 when a file was refused (the others are imported)."
    )]
    Import {
        /// Input files: .csv, .csv.gz, .tsv or .parquet.
        files: Vec<PathBuf>,
        /// Fleet root the runs are written under.
        #[arg(long, value_name = "DIR")]
        out: Option<PathBuf>,
        /// A built-in mapping name (e.g. umich_cnc) or a mapping TOML file.
        #[arg(long, value_name = "NAME|TOML")]
        mapping: Option<String>,
        /// Map a column: SRC=DEST or SRC=DEST*FACTOR (repeatable; overrides the mapping).
        #[arg(long = "map", value_name = "SRC=DEST[*F]", allow_hyphen_values = true)]
        maps: Vec<String>,
        /// Contract table the rows become (motion, probe, tracker, ...).
        #[arg(long)]
        table: Option<String>,
        /// Machine id of the runs.
        #[arg(long)]
        machine: Option<String>,
        /// Plugin of the runs.
        #[arg(long)]
        plugin: Option<String>,
        /// t_s = row index × this period, when no column is mapped to t_s.
        #[arg(long, value_name = "S")]
        sample_period_s: Option<f64>,
        /// List the built-in mappings and exit.
        #[arg(long)]
        list_mappings: bool,
    },
    /// Generate a synthetic fleet (or an observations table) with injected effects.
    #[command(
        after_help = "Examples:\n  sparkout generate robot --runs 6 --seed 1 --out runs/ --effect wheel_wear\n  \
                      sparkout generate observations --runs 8 --seed 3 --out obs.parquet \
                      --effect drift:t_s=amplitude_mm=0.02,tau_s=600\n\
                      Effects: NAME[:COVARIATE]=KEY=VALUE,... (repeatable). `sparkout generate robot --list-effects` lists them."
    )]
    #[command(allow_negative_numbers = true)]
    Generate {
        /// What to generate: one of the generators listed below.
        what: String,
        /// Number of runs, 1 to 100000.
        #[arg(long, default_value_t = 4, value_parser = clap::value_parser!(u64).range(1..=MAX_RUNS))]
        runs: u64,
        /// Random seed (same seed → identical bytes).
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Output: a fleet root directory (plugins) or a .parquet file (observations).
        #[arg(long, value_name = "PATH")]
        out: Option<PathBuf>,
        /// Inject an effect: NAME[:COVARIATE]=KEY=VALUE,... (repeatable).
        #[arg(long = "effect", value_name = "SPEC")]
        effects: Vec<String>,
        /// AE sample rate for plugins that record AE, at most 10 MHz
        /// (default: the generator's, 1 MHz).
        #[arg(long, value_name = "HZ", value_parser = f64_above_at_most(0.0, MAX_AE_RATE_HZ))]
        ae_rate_hz: Option<f64>,
        /// What the AE log holds, for plugins that record AE: `raw` (the
        /// sensor voltage, triggered windows) or `rms` (a conditioned RMS,
        /// recorded continuously at 250 Hz unless --ae-rate-hz says).
        #[arg(long, value_name = "KIND", value_parser = ["raw", "rms"])]
        ae_signal: Option<String>,
        /// List the injectable effects and exit.
        #[arg(long)]
        list_effects: bool,
        /// Overwrite runs (or an observations file) that already exist at --out.
        #[arg(long)]
        force: bool,
        /// Generate even when the fleet is predicted to write more than
        /// 10 GB or to hold more than half of this machine's memory.
        #[arg(long)]
        force_size: bool,
    },
    /// Generate a small fleet, run everything, print where the report is.
    #[command(after_help = "Example: sparkout demo --out /tmp/sparkout-demo")]
    Demo {
        /// Where the demo fleet and outputs go.
        #[arg(long, value_name = "DIR", default_value = "sparkout-demo")]
        out: PathBuf,
    },
    /// Diagnose the sim-to-real gap of a paired-observations table.
    #[command(
        after_help = "Example: sparkout diagnose out/fleet/observations.parquet --out diag/ --folds 5 --json\n\
                      Settings: the [diagnose] section of --config (default: the built-in nightly.toml), \
                      then --set diagnose.KEY=VALUE, then --folds/--seed/--effects.\n\
                      The catalogue applies to every observable; --plugin NAME adds that plugin's composites \
                      (to the observables it produces when the table has them, else to all).\n\
                      Writes diagnosis.json (v1), diagnosis.parquet, augmented_model.json, report.html."
    )]
    #[command(allow_negative_numbers = true)]
    Diagnose {
        /// observations.parquet (docs/formats.md §7).
        observations: PathBuf,
        #[arg(long, value_name = "DIR")]
        out: PathBuf,
        #[command(flatten)]
        flags: DiagnoseFlags,
        /// Append this diagnosis to a fleet history (needs --night).
        #[arg(long, value_name = "DIR", requires = "night")]
        history: Option<PathBuf>,
        /// The night's date for --history.
        #[arg(long, value_name = "YYYY-MM-DD", requires = "history")]
        night: Option<String>,
        /// A deliberate change, kept in the history (repeatable); see `run --event`.
        #[arg(long = "event", value_name = "SPEC", requires = "history")]
        events: Vec<String>,
    },
    /// Stream a run's (compensated) commanded path to CiA 402 drives over CANopen,
    /// inside a safety envelope; record what the drives did as a new run.
    #[command(
        after_help = "Examples:\n  sparkout replay --run runs/kr16-lab/r0000 --bus sim --record /tmp/replayed\n  \
                      sparkout replay --run runs/kr16-lab/r0000 --compensation comp.parquet --bus log:/tmp/replay.log\n  \
                      sparkout replay --run runs/kr16-lab/r0000 --bus socketcan:can0 --dry-run\n  \
                      sparkout replay --run runs/kr16-lab/r0000 --bus sim --sim-fault heartbeat@1.5s:2\n\
                      A compensation is a Parquet with t_s and any of dx_mm, dy_mm, dz_mm. Exit codes: 0 replay completed, \
                      2 ended by a quick stop (the reason is printed), 1 usage/config/input error (nothing sent)."
    )]
    #[command(allow_negative_numbers = true)]
    Replay(ReplayArgs),
    /// CAN tools for commissioning: describe a drive's EDS/DCF, decode a bus log.
    #[command(subcommand)]
    Can(CanCommand),
    /// Check the diagnosis on generated fleets whose effect is known (withheld from sim);
    /// with --nights, the trend's alert rule on generated sequences of nights.
    #[command(
        after_help = "Examples:\n  sparkout validate --quick --out validation/\n  \
                      sparkout validate --nights --out validation/   (false alerts per 100 stationary \
                      night-fleets, detection delay of 20/40/100 % steps, a drift, an event)"
    )]
    #[command(allow_negative_numbers = true)]
    Validate {
        /// A smaller grid of fleets (under 30 s in release).
        #[arg(long)]
        quick: bool,
        /// Validate the trend across nights instead (writes nights.txt and
        /// nights.json with --out); settings from [diagnose] and [trend].
        #[arg(long)]
        nights: bool,
        #[arg(long, value_name = "DIR")]
        out: Option<PathBuf>,
        #[arg(long, default_value_t = 0)]
        seed: u64,
        /// Print the report as JSON to stdout.
        #[arg(long)]
        json: bool,
        /// Research: diagnose every fleet with each covariate rounded to the
        /// centre of one of B equal cells across its range (2 to 100000),
        /// the effects still made from the exact values — what a selection
        /// on coarse fixed cells would lose (docs/validation.md).
        #[arg(long, value_name = "B", conflicts_with = "nights", value_parser = clap::value_parser!(u32).range(2..=100_000))]
        cells: Option<u32>,
        // The diagnosis settings: [diagnose] of --config, --set diagnose.KEY=VALUE.
        #[command(flatten)]
        config: ConfigArgs,
    },
}

/// `sparkout can …`.
#[derive(Subcommand, Debug)]
pub enum CanCommand {
    /// A candump log (`candump -l`/`-L` log format, or the screen format with
    /// or without -ta/-td/-tz timestamps) as CiA 301/402 events: NMT and
    /// boot-ups, heartbeats, SYNC, EMCY by name, SDO reads, writes and aborts
    /// by name, PDO1 as controlword/statusword with CiA 402 state transitions.
    #[command(after_help = "Example: sparkout can decode drive-startup.log
                               sparkout can decode drive-startup.log --format jsonl --out events.jsonl
                      Exit codes: 0 decoded, 1 the log cannot be read (the message names file and line).")]
    /// A drive's EDS or DCF (CiA 306) as the replay reads it: identity, the
    /// CiA 402 objects of each axis with their types and access, and the
    /// default PDO mappings. A file missing an object the master needs is
    /// refused naming it; a standard object of another width is a warning.
    #[command(after_help = "Example: sparkout can describe vendor-drive.eds --node 3")]
    Describe {
        /// The EDS or DCF file.
        file: PathBuf,
        /// The node id `$NODEID` stands for (a DCF's own NodeID wins).
        #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u8).range(1..=127))]
        node: u8,
        /// Print the description as JSON.
        #[arg(long)]
        json: bool,
    },
    Decode {
        /// The log file.
        log: PathBuf,
        /// `text` (a readable listing), `jsonl` (one JSON object per frame)
        /// or `parquet` (one row per frame; needs --out).
        #[arg(long, default_value = "text", value_parser = ["text", "jsonl", "parquet"])]
        format: String,
        /// Write there instead of standard output (never over an existing file).
        #[arg(long, value_name = "FILE")]
        out: Option<PathBuf>,
        /// A node's EDS or DCF (repeatable): NODE=FILE. Its PDO mappings
        /// name what each RPDO/TPDO carries (SDO writes to the mapping in
        /// the log win from where they happen).
        #[arg(long = "eds", value_name = "NODE=FILE")]
        eds: Vec<String>,
    },
    /// What a master sent to the drives in a bus log (target positions and
    /// velocities in RPDOs and SDO writes, per node through its mapping)
    /// against a safety envelope: every frame outside it is listed.
    #[command(
        after_help = "Example: sparkout can compare replay.log --max-step-mm 0.5 --eds 1=drive.eds\n\
                      Exit codes: 0 every frame inside the envelope, 2 frames outside it (listed), 1 the log cannot be read."
    )]
    Compare {
        /// The log file (candump -l/-L or screen format).
        log: PathBuf,
        /// A node's EDS or DCF (repeatable): NODE=FILE.
        #[arg(long = "eds", value_name = "NODE=FILE")]
        eds: Vec<String>,
        /// Which drive axis a machine axis is (repeatable): AXIS=NODE[:N].
        #[arg(long = "axis", value_name = "AXIS=NODE[:N]")]
        axes: Vec<String>,
        /// Envelope: largest setpoint step per cycle per axis (mm).
        #[arg(long, default_value_t = 1.0, value_name = "MM")]
        max_step_mm: f64,
        /// Envelope: largest change of that step between cycles (mm).
        #[arg(long, default_value_t = 0.5, value_name = "MM")]
        max_step_change_mm: f64,
        /// Drive increments per mm.
        #[arg(long, default_value_t = 10000.0, value_name = "N")]
        counts_per_mm: f64,
        /// The SYNC cycle (ms) for velocities; default: the log's SYNC period.
        #[arg(long, value_name = "MS")]
        cycle_ms: Option<f64>,
        /// Print the findings as JSON.
        #[arg(long)]
        json: bool,
    },
}

/// `sparkout diagnose` settings: the config, then flags over it.
#[derive(Args, Debug, Clone)]
pub struct DiagnoseFlags {
    #[command(flatten)]
    pub config: ConfigArgs,
    /// Cross-validation folds (by machine and run), 2 to 1000.
    #[arg(long, value_parser = clap::value_parser!(u64).range(2..=MAX_FOLDS))]
    pub folds: Option<u64>,
    /// Restrict the catalogue: comma-separated effect names.
    #[arg(long, value_delimiter = ',')]
    pub effects: Option<Vec<String>>,
    #[arg(long)]
    pub seed: Option<u64>,
    /// Add this plugin's composite effects (repeatable), e.g. --plugin form.
    #[arg(long = "plugin", value_name = "NAME")]
    pub plugins: Vec<String>,
    /// Print diagnosis.json to stdout.
    #[arg(long)]
    pub json: bool,
}

/// `sparkout replay` flags.
#[derive(Args, Debug, Clone)]
pub struct ReplayArgs {
    /// The recorded run whose commanded path (motion.parquet cmd_*) is replayed.
    #[arg(long, value_name = "DIR", required_unless_present = "compare")]
    pub run: Option<PathBuf>,
    /// Replay nothing: read what a master sent in this recorded bus log
    /// (targets in RPDOs and SDO writes, per node through its mapping:
    /// --eds, --axis or --nodes) and list every frame outside this
    /// command's envelope (--max-step-mm, --max-step-change-mm); the same
    /// as `sparkout can compare`. Exit 2 when any frame is outside.
    #[arg(long, value_name = "LOG", conflicts_with_all = ["run", "bus", "record", "compensation", "dry_run"])]
    pub compare: Option<PathBuf>,
    /// Offsets added to the path: Parquet with t_s and any of dx_mm, dy_mm, dz_mm.
    #[arg(long, value_name = "FILE")]
    pub compensation: Option<PathBuf>,
    /// sim | log:FILE (candump -l log, simulated drives) | socketcan:IFACE (Linux hardware).
    #[arg(long, value_name = "BUS", required_unless_present = "compare")]
    pub bus: Option<String>,
    /// SYNC / setpoint cycle in ms, 1 to 1000 (a shorter cycle means more
    /// setpoints for the same path).
    #[arg(long, default_value_t = 4.0, value_name = "MS", value_parser = f64_above_at_most(0.0, 1000.0))]
    pub cycle_ms: f64,
    /// Open no hardware and send nothing: simulated drives answer, and the
    /// frames that would be sent are printed (all of them with --bus log:FILE).
    #[arg(long)]
    pub dry_run: bool,
    /// Envelope: largest |compensation| per axis (mm).
    #[arg(long, default_value_t = 0.5, value_name = "MM")]
    pub max_comp_mm: f64,
    /// Envelope: largest setpoint step per cycle per axis (mm).
    #[arg(long, default_value_t = 1.0, value_name = "MM")]
    pub max_step_mm: f64,
    /// Envelope: largest change of that step between cycles (mm).
    #[arg(long, default_value_t = 0.5, value_name = "MM")]
    pub max_step_change_mm: f64,
    /// Envelope: largest following error |target − actual| from the feedback (mm).
    #[arg(long, default_value_t = 0.5, value_name = "MM")]
    pub max_following_mm: f64,
    /// Write the drives' feedback as a new recorded run in this directory.
    #[arg(long, value_name = "OUT")]
    pub record: Option<PathBuf>,
    /// Drive increments per mm.
    #[arg(long, default_value_t = 10000.0, value_name = "N")]
    pub counts_per_mm: f64,
    /// CANopen node ids of the x, y, z drives.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "1,2,3",
        value_name = "X,Y,Z"
    )]
    pub nodes: Vec<u8>,
    /// Producer heartbeat time written to every drive (ms); timeout = 3 periods.
    #[arg(long, default_value_t = 20, value_name = "MS")]
    pub heartbeat_ms: u16,
    /// Simulated drives: position-loop time constant (s).
    #[arg(long, default_value_t = 0.002, value_name = "S")]
    pub sim_lag_s: f64,
    /// Simulated drives: speed limit (mm/s).
    #[arg(long, default_value_t = 500.0, value_name = "MM_S")]
    pub sim_max_speed_mm_s: f64,
    /// Inject a fault into the simulated drives (repeatable): heartbeat@T[:NODE],
    /// emcy@T[:NODE], busoff@T, following@T[:NODE], refuse[:NODE], sigint@T (T like 1.5s or 200ms).
    #[arg(long = "sim-fault", value_name = "SPEC")]
    pub sim_faults: Vec<String>,
    /// A drive's EDS or DCF (repeatable): NODE=FILE. The master checks it
    /// holds every object it needs and configures the PDOs it declares;
    /// over `[replay] eds` of the machine config.
    #[arg(long = "eds", value_name = "NODE=FILE")]
    pub eds: Vec<String>,
    /// Which drive axis a machine axis is (repeatable): AXIS=NODE or
    /// AXIS=NODE:N, e.g. --axis y=1:2 for the second axis (objects at
    /// +0x800, RPDO2/TPDO2) of node 1; over --nodes and `[replay] axes`.
    #[arg(long = "axis", value_name = "AXIS=NODE[:N]")]
    pub axes: Vec<String>,
    /// With --bus log:FILE, replace an existing log (written to a temporary
    /// name and renamed over it at the end); without it an existing file is refused.
    #[arg(long)]
    pub force: bool,
    /// Directory of machine configs (<machine>.toml) whose [replay] table is
    /// read; also SPARKOUT_MACHINES, then ./configs/machines.
    #[arg(long, value_name = "DIR")]
    pub machines: Option<PathBuf>,
    /// Print the replay report as JSON to stdout.
    #[arg(long)]
    pub json: bool,
}

/// Parse argv; help/version print and exit 0, usage errors exit 1.
pub fn parse() -> Result<Cli, ExitCode> {
    // The derived command plus the registries' listings in `--help`.
    let cmd = crate::help::with_registry(<Cli as clap::CommandFactory>::command());
    let parsed = cmd
        .try_get_matches()
        .and_then(|m| <Cli as clap::FromArgMatches>::from_arg_matches(&m));
    match parsed {
        Ok(c) => Ok(c),
        Err(e) => {
            use clap::error::ErrorKind;
            let _ = e.print();
            match e.kind() {
                ErrorKind::DisplayHelp
                | ErrorKind::DisplayVersion
                | ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand => Err(ExitCode::SUCCESS),
                _ => Err(ExitCode::from(1)),
            }
        }
    }
}
