//! Generation of a fleet and of one run. (Part of the robot generator; see mod.rs.)

use super::*;

// Generation

/// Stream `stream` (0‥4) of run `run_index`. Stream 4 of run i is stream 0
/// of run i+1 (the numbering predates this note; changing it would change
/// every robot fleet's bytes).
pub(super) fn run_rng(seed: u64, run_index: usize, stream: u64) -> ChaCha8Rng {
    stream_rng(seed, (run_index as u64) * 4 + stream)
}

/// `sparkout generate robot` and the robot fleet of `sparkout demo`.
pub struct RobotGenerator;

impl Generator for RobotGenerator {
    fn name(&self) -> &'static str {
        "robot"
    }
    fn known_effects(&self) -> Vec<(&'static str, &'static str)> {
        known_effects()
    }
    /// The AE log grows with the sample rate (one window per AE touch of
    /// the plan); the rest of a run is measured at the defaults.
    fn predicted_size(&self, opts: &GenerateOptions) -> Predicted {
        // An unknown --ae-signal is refused by `generate`; size it as raw.
        let cfg = fleet_config(opts).unwrap_or_default();
        let seconds_per_touch = match cfg.ae_signal {
            AeSignal::Raw => cfg.ae_pre_s + cfg.ae_post_s,
            AeSignal::Rms => AE_RMS_SECONDS_PER_TOUCH,
        };
        let ae_samples = build_plan(&cfg).len() as f64 * seconds_per_touch * cfg.ae_sample_rate_hz;
        RunSize {
            disk_bytes: RUN_BYTES_BESIDES_AE + (ae_samples * AE_BYTES_PER_SAMPLE) as u64,
            memory_bytes: RUN_MEMORY_BYTES,
        }
        .fleet(opts.runs)
    }
    fn generate(&self, out: &Path, opts: &GenerateOptions, fx: &[EffectSpec]) -> Result<Generated> {
        let cfg = fleet_config(opts)?;
        let dirs = generate_fleet(out, &cfg, fx)?;
        Ok(fleet_summary(self.name(), dirs.len(), out))
    }
    fn demo(&self) -> Option<DemoFleet> {
        let d = RobotFleetConfig::demo();
        Some(DemoFleet {
            runs: d.runs,
            seed: d.seed,
            effect: "wheel_wear",
        })
    }
    /// The demo's robot fleet also records AE at a lower rate and fewer
    /// trials than the default ([`RobotFleetConfig::demo`]).
    fn generate_demo(&self, root: &Path, fx: &[EffectSpec]) -> Result<Generated> {
        let dirs = generate_fleet(root, &RobotFleetConfig::demo(), fx)?;
        Ok(fleet_summary(self.name(), dirs.len(), root))
    }
}

/// A generated robot run at the defaults, measured (debug build, 1 MHz, one
/// run: 33.8 MB): every file but ae.parquet (motion.parquet is most of it),
/// the AE log's bytes per sample (21.96 MB over 216 windows of 25 ms:
/// 4.07; zstd packs t_s and the quantised noise well), and the peak RSS of
/// generating it above the program's own (the AE log is streamed in
/// batches, so memory does not grow with the rate).
pub(super) const RUN_BYTES_BESIDES_AE: u64 = 11_860_000;
pub(super) const AE_BYTES_PER_SAMPLE: f64 = 4.1;
pub(super) const RUN_MEMORY_BYTES: u64 = 78_000_000;

/// The fleet config `sparkout generate robot` makes of its options
/// (`--ae-signal rms` records at 250 Hz unless `--ae-rate-hz` says).
fn fleet_config(opts: &GenerateOptions) -> Result<RobotFleetConfig> {
    let mut cfg = RobotFleetConfig {
        runs: opts.runs,
        seed: opts.seed,
        ..Default::default()
    };
    if let Some(s) = &opts.ae_signal {
        cfg.ae_signal = s
            .parse()
            .map_err(|e: String| crate::err!("--ae-signal: {e}"))?;
        if cfg.ae_signal == AeSignal::Rms {
            cfg.ae_sample_rate_hz = AE_RMS_DEFAULT_RATE_HZ;
        }
    }
    if let Some(r) = opts.ae_rate_hz {
        cfg.ae_sample_rate_hz = r;
    }
    Ok(cfg)
}

/// Generate the fleet under `<root>/<machine>/r0000 …`; returns the run dirs
/// in run order. Runs are generated in parallel and are byte-identical for a
/// seed whatever the thread count.
pub fn generate_fleet(
    root: &Path,
    cfg: &RobotFleetConfig,
    effects: &[EffectSpec],
) -> Result<Vec<PathBuf>> {
    cfg.validate()?;
    let plan = build_plan(cfg);
    let bow_range = |c: &str| -> (f64, f64) {
        let vals: Vec<f64> = plan
            .iter()
            .map(|r| match c {
                "x_mm" => r.nom.x,
                "y_mm" => r.nom.y,
                "z_mm" => r.nom.z,
                "approach_mm_s" => r.speed_mm_s,
                "approach_normal_mm_s" => r.speed_mm_s * r.dir[r.face.axis()],
                _ => 0.0,
            })
            .collect();
        let lo = vals.iter().cloned().fold(f64::INFINITY, f64::min);
        let hi = vals.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
        if hi > lo {
            (lo, hi)
        } else {
            (lo, lo + 1.0)
        }
    };
    let fx = resolve_effects(effects, &bow_range)?;
    let other = build_other_program(cfg);
    let machine_dir = root.join(&cfg.machine);
    (0..cfg.runs)
        .into_par_iter()
        .map(|i| {
            let dir = machine_dir.join(format!("r{i:04}"));
            generate_run(&dir, cfg, &plan, &other, &fx, effects, i)
                .with_context(|| format!("generating robot run {}", dir.display()))?;
            Ok(dir)
        })
        .collect()
}

pub(super) struct Touch {
    pub(super) row: usize,
    pub(super) t_c: f64,
    pub(super) t_r: f64,
    pub(super) act_c: V3,
    pub(super) surface: V3,
    pub(super) registered: V3,
    pub(super) dir_b: i32,
}

pub(super) fn generate_run(
    dir: &Path,
    cfg: &RobotFleetConfig,
    plan: &[PlanRow],
    other: &[PlanRow],
    fx: &Effects,
    specs: &[EffectSpec],
    index: usize,
) -> Result<()> {
    let mut rng = run_rng(cfg.seed, index, 0);
    let run_id = format!("r{index:04}");
    let pose = Pose::draw(cfg, &mut rng);
    let alpha = uniform(&mut rng, cfg.alpha_min, cfg.alpha_max);
    let clock_offset_s = uniform(&mut rng, CLOCK_OFFSET_RANGE_S.0, CLOCK_OFFSET_RANGE_S.1);
    let has_probe = cfg.with_probe.has_probe(index);
    // The AE program, then (runs with probe.parquet only) the comparison
    // methods' program; `Touch::row` indexes `program`. The second program
    // draws from its own RNG stream, so the AE program's draws (and the AE
    // signal after them) do not depend on it.
    let program: Vec<PlanRow> = if has_probe {
        plan.iter().chain(other).cloned().collect()
    } else {
        plan.to_vec()
    };
    let mut rng_other = run_rng(cfg.seed, index, 4);
    let (path, touches) = probe(cfg, &program, fx, &pose, &mut rng, &mut rng_other)?;
    let t_probe_end = path.t;

    // ---- motion.parquet at the controller rate
    // Own RNG streams for the motion noise and the height readings: an
    // effect that moves the timeline (and so the number of motion samples)
    // leaves the other tables' noise draws unchanged, so a fleet with an
    // effect differs from its effect-free twin by the effect alone.
    let motion = motion_batch(
        &path.pieces,
        cfg.motion_rate_hz,
        &mut run_rng(cfg.seed, index, 2),
    );

    // ---- grinding cycle
    let (passes_batch, pass_truth) = passes(
        cfg,
        fx,
        alpha,
        t_probe_end,
        &mut run_rng(cfg.seed, index, 3),
    );

    // ---- AE windows (their own RNG stream: AE size does not shift the rest)
    let fs = cfg.ae_sample_rate_hz;
    let carrier = cfg.ae_carrier_hz.min(AE_CARRIER_MAX_FRAC * fs);
    let (windows, contacts) =
        ae_windows(cfg, &program, &touches, clock_offset_s, carrier, &mut rng);

    // ---- write
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    write_parquet_atomic(&dir.join("plan.parquet"), &plan_batch(plan))?;
    write_parquet_atomic(&dir.join("motion.parquet"), &motion)?;
    write_parquet_atomic(&dir.join("passes.parquet"), &passes_batch)?;
    let probe_path = dir.join("probe.parquet");
    if has_probe {
        write_parquet_atomic(&probe_path, &probe_batch(&program, &touches))?;
    } else if probe_path.exists() {
        // A stale probe table from an earlier generation would change the run.
        std::fs::remove_file(&probe_path)
            .with_context(|| format!("cannot remove stale {}", probe_path.display()))?;
    }
    let ae_schema: SchemaRef = Arc::new(Schema::new(vec![
        Field::new("t_s", DataType::Float64, false),
        Field::new("ae_v", DataType::Float32, false),
    ]));
    let ae_rng = run_rng(cfg.seed, index, 1);
    let mut contacts = contacts;
    match cfg.ae_signal {
        AeSignal::Raw => write_parquet_batches_atomic(
            &dir.join("ae.parquet"),
            ae_schema.clone(),
            AeBatches {
                windows,
                wi: 0,
                n: 0,
                fs,
                noise_v: cfg.ae_noise_v,
                rng: ae_rng,
                schema: ae_schema,
            },
        )?,
        AeSignal::Rms => {
            let rms = rms_contacts(&program, &touches, clock_offset_s, &mut contacts);
            // From the recorder's start to a while after the last contact.
            let n_end = rms
                .last()
                .map(|c| ((c.leave_s + AE_RMS_TAIL_S) * fs).ceil() as u64)
                .unwrap_or((AE_RMS_TAIL_S * fs) as u64);
            write_parquet_batches_atomic(
                &dir.join("ae.parquet"),
                ae_schema.clone(),
                RmsBatches {
                    contacts: rms,
                    ci: 0,
                    n: 0,
                    n_end,
                    fs,
                    air_v: cfg.ae_noise_v,
                    rng: ae_rng,
                    schema: ae_schema,
                },
            )?
        }
    };

    let faces = Face::ALL
        .iter()
        .map(|&f| {
            let (n, d) = pose.plane(f);
            let normal = [n.x, n.y, n.z];
            (f.label().to_string(), FaceTruth { normal, d })
        })
        .collect();
    let truth = RunTruth {
        run: run_id.clone(),
        run_index: index,
        seed: cfg.seed,
        block_origin_mm: [pose.datum_true.x, pose.datum_true.y, pose.datum_true.z],
        block_rotation_rad: pose.angles,
        block_offset_mm: [pose.offset.x, pose.offset.y, pose.offset.z],
        faces,
        // A trigger latency is the controller's: every registered method has it.
        trigger_latency_s: std::iter::once("ae")
            .chain(cfg.other_methods.iter().map(ProbeMethod::label))
            .map(|m| (m.to_string(), fx.latency_s))
            .collect(),
        touch_sigma_mm: cfg
            .speeds_mm_s
            .iter()
            .map(|&v| (format!("{v}"), ae_touch_sigma_mm(v)))
            .collect(),
        other_method_sigma_mm: if has_probe {
            cfg.other_methods
                .iter()
                .map(|m| {
                    (
                        format!("{}@{}", m.name, m.speed_mm_s),
                        touch_sigma_mm(&m.name, m.speed_mm_s),
                    )
                })
                .collect()
        } else {
            BTreeMap::new()
        },
        ae_clock_offset_s: clock_offset_s,
        ae_sample_rate_hz: fs,
        ae_signal: (cfg.ae_signal == AeSignal::Rms).then(|| "rms".to_string()),
        ae_carrier_hz: carrier,
        ae_noise_v: cfg.ae_noise_v,
        has_probe,
        contacts,
        alpha,
        passes: pass_truth,
        effects: specs.to_vec(),
    };
    write_json_atomic(&dir.join("truth.json"), &truth)?;
    write_atomic(
        &dir.join("run.toml"),
        run_toml(cfg, &run_id, index, clock_offset_s).as_bytes(),
    )?;
    Ok(())
}

/// The block's true pose in a run: the nominal datum moved by a random
/// offset and turned by small random angles about it (the first six draws
/// of the run's main stream).
struct Pose {
    offset: V3,
    angles: [f64; 3],
    rot: Rotation3<f64>,
    datum_true: V3,
}

impl Pose {
    fn draw(cfg: &RobotFleetConfig, rng: &mut ChaCha8Rng) -> Pose {
        let offset = V3::new(
            symmetric(rng, cfg.pose_offset_mm),
            symmetric(rng, cfg.pose_offset_mm),
            symmetric(rng, cfg.pose_offset_mm),
        );
        let angles = [
            symmetric(rng, cfg.pose_rotation_rad),
            symmetric(rng, cfg.pose_rotation_rad),
            symmetric(rng, cfg.pose_rotation_rad),
        ];
        Pose {
            offset,
            angles,
            rot: Rotation3::from_euler_angles(angles[0], angles[1], angles[2]),
            datum_true: V3::from(DATUM_NOM_MM) + offset,
        }
    }
    /// A face's true plane: unit normal n and offset d (n·x = d).
    fn plane(&self, f: Face) -> (V3, f64) {
        let n = self.rot * f.normal();
        (n, n.dot(&self.datum_true))
    }
}

/// The probing program of a run: the commanded path from home through every
/// approach and back, and each touch (contact, registration). AE rows draw
/// from `rng`, the comparison methods' rows from `rng_other`.
fn probe(
    cfg: &RobotFleetConfig,
    program: &[PlanRow],
    fx: &Effects,
    pose: &Pose,
    rng: &mut ChaCha8Rng,
    rng_other: &mut ChaCha8Rng,
) -> Result<(CmdPath, Vec<Touch>)> {
    let datum_nom = V3::from(DATUM_NOM_MM);
    let safe_z = datum_nom.z + SAFE_CLEARANCE_MM;
    let home = datum_nom + V3::new(BLOCK_X_MM / 2.0, BLOCK_Y_MM / 2.0, SAFE_CLEARANCE_MM + 30.0);
    let mut path = CmdPath {
        pieces: Vec::new(),
        t: 0.0,
        pos: home,
    };
    path.dwell(1.0);
    let mut touches = Vec::with_capacity(program.len());

    for (ri, row) in program.iter().enumerate() {
        let rng = if row.method == "ae" {
            &mut *rng
        } else {
            &mut *rng_other
        };
        touches.push(approach(&mut path, cfg, fx, pose, ri, row, rng)?);
    }
    let last = path.pos;
    path.line(
        V3::new(last.x, last.y, safe_z.max(last.z)),
        TRANSIT_MM_S,
        -1,
    );
    path.line(home, TRANSIT_MM_S, -1);
    path.dwell(0.5);
    Ok((path, touches))
}

/// One approach of the program (row `ri`): safe transit to the leg start,
/// the leg, settle, the approach along the row's direction until the
/// physical wheel meets the true plane, registration after the trigger
/// latency, stop, dwell and retract — appended to `path`.
fn approach(
    path: &mut CmdPath,
    cfg: &RobotFleetConfig,
    fx: &Effects,
    pose: &Pose,
    ri: usize,
    row: &PlanRow,
    rng: &mut ChaCha8Rng,
) -> Result<Touch> {
    let safe_z = DATUM_NOM_MM[2] + SAFE_CLEARANCE_MM;
    let n = row.face.normal();
    let start = row.nom + n * cfg.standoff_mm;
    let dir_b: i32 = if rng.random::<bool>() { 1 } else { -1 };
    let leg_start = if dir_b < 0 {
        start + n * LEG_OUT_MM
    } else {
        start - n * OVERTRAVEL_MM
    };
    // Safe transit: up, across, down, then the short leg along the normal.
    let p = path.pos;
    path.line(V3::new(p.x, p.y, safe_z.max(p.z)), TRANSIT_MM_S, -1);
    path.line(V3::new(leg_start.x, leg_start.y, safe_z), TRANSIT_MM_S, -1);
    path.line(leg_start, TRANSIT_MM_S, -1);
    path.line(start, LEG_MM_S, -1);
    path.pieces.push(Piece {
        t0: path.t,
        t1: path.t + SETTLE_S,
        p0: start,
        v0: V3::zeros(),
        a: V3::zeros(),
        segment: row.seq,
    });
    path.t += SETTLE_S;

    // Approach along dir at v: solve for the contact of the physical
    // wheel (cmd − o(t)) with the true plane (+ contact scatter).
    let v = row.speed_mm_s;
    let t_a = path.t;
    let (n_true, d_true) = pose.plane(row.face);
    let e_c = CONTACT_SCATTER_MM * normal(rng);
    let mut t_c = t_a;
    let mut o = V3::zeros();
    for _ in 0..4 {
        o = frame_offset(fx, row, dir_b, t_c);
        let denom = v * n_true.dot(&row.dir);
        let tau = (d_true + e_c - n_true.dot(&(start - o))) / denom;
        t_c = t_a + tau;
    }
    let tau = t_c - t_a;
    let max_travel = cfg.standoff_mm + 1.0;
    if !(tau > 0.0 && tau * v < max_travel) {
        bail!(
            "seq {}: the wheel would meet the {} face {:.3} mm into the approach (allowed (0, {max_travel}] mm): pose spread or injected offsets exceed the standoff",
            row.seq,
            row.face.label(),
            tau * v
        );
    }
    // The leg start must be clear of the surface too (reversal legs come closer).
    let leg_clear = n_true.dot(&(leg_start - frame_offset(fx, row, dir_b, t_a))) - d_true;
    if leg_clear <= 0.0 {
        bail!(
            "seq {}: the leg before the approach would enter the {} face: pose spread or injected offsets exceed the standoff",
            row.seq,
            row.face.label()
        );
    }
    let t_r = t_c + fx.latency_s;
    let act_c = start + row.dir * (v * tau);
    let surface = act_c - o;
    let sigma = touch_sigma_mm(row.method, v);
    let reg_noise = (sigma * sigma - CONTACT_SCATTER_MM * CONTACT_SCATTER_MM)
        .max(0.0)
        .sqrt()
        * normal(rng);
    let registered = act_c + row.dir * (v * fx.latency_s + reg_noise);
    // Approach piece until registration, then the stop.
    let p_r = start + row.dir * (v * (t_r - t_a));
    path.pieces.push(Piece {
        t0: t_a,
        t1: t_r,
        p0: start,
        v0: row.dir * v,
        a: V3::zeros(),
        segment: row.seq,
    });
    let t_stop = v / STOP_DECEL_MM_S2;
    path.pieces.push(Piece {
        t0: t_r,
        t1: t_r + t_stop,
        p0: p_r,
        v0: row.dir * v,
        a: -row.dir * STOP_DECEL_MM_S2,
        segment: row.seq,
    });
    path.t = t_r + t_stop;
    path.pos = p_r + row.dir * (0.5 * v * t_stop);
    path.dwell(DWELL_S);
    path.line(start + n * LEG_OUT_MM, LEG_MM_S, -1);
    Ok(Touch {
        row: ri,
        t_c,
        t_r,
        act_c,
        surface,
        registered,
        dir_b,
    })
}

/// The AE burst window of every AE touch (on the recorder clock) and its
/// truth record.
fn ae_windows(
    cfg: &RobotFleetConfig,
    program: &[PlanRow],
    touches: &[Touch],
    clock_offset_s: f64,
    carrier: f64,
    rng: &mut ChaCha8Rng,
) -> (Vec<AeWindow>, Vec<ContactTruth>) {
    let fs = cfg.ae_sample_rate_hz;
    let mut windows: Vec<AeWindow> = Vec::with_capacity(touches.len());
    let mut contacts = Vec::with_capacity(touches.len());
    for tc in touches.iter().filter(|t| program[t.row].method == "ae") {
        let onset = tc.t_c - clock_offset_s;
        let n0 = ((onset - cfg.ae_pre_s) * fs).ceil().max(0.0) as u64;
        let n1 = ((onset + cfg.ae_post_s) * fs).floor() as u64 + 1;
        let n0 = n0.max(windows.last().map(|w: &AeWindow| w.n1).unwrap_or(0));
        let amp = cfg.ae_noise_v * cfg.ae_burst_sigmas * (0.8 + 0.45 * rng.random::<f64>());
        windows.push(AeWindow {
            n0,
            n1: n1.max(n0),
            onset_s: onset,
            amp_v: amp,
            carrier_hz: carrier * (0.95 + 0.1 * rng.random::<f64>()),
            phase: 2.0 * PI * rng.random::<f64>(),
        });
        let row = &program[tc.row];
        contacts.push(ContactTruth {
            seq: row.seq,
            t_s: tc.t_c,
            ae_t_s: onset,
            registered_t_s: tc.t_r,
            x_mm: tc.act_c.x,
            y_mm: tc.act_c.y,
            z_mm: tc.act_c.z,
            surface_x_mm: tc.surface.x,
            surface_y_mm: tc.surface.y,
            surface_z_mm: tc.surface.z,
            dir: tc.dir_b * row.face.normal()[row.face.axis()] as i32,
            ae_amplitude_v: amp,
            ae_leave_t_s: None,
        });
    }
    (windows, contacts)
}

/// The contacts of a conditioned RMS log (recorder clock), in time order:
/// from the wheel meeting the surface to the retract taking it off again
/// (registration, stop, dwell, then the retract back over the overshoot),
/// at the RMS of the raw burst's amplitude (A/√2). Fills each truth
/// record's `ae_leave_t_s`.
fn rms_contacts(
    program: &[PlanRow],
    touches: &[Touch],
    clock_offset_s: f64,
    truth: &mut [ContactTruth],
) -> Vec<RmsContact> {
    let ae = touches.iter().filter(|t| program[t.row].method == "ae");
    ae.zip(truth.iter_mut())
        .map(|(tc, ct)| {
            let v = program[tc.row].speed_mm_s;
            let t_stop = v / STOP_DECEL_MM_S2;
            let overshoot = v * (tc.t_r - tc.t_c) + 0.5 * v * t_stop;
            let leave = tc.t_r + t_stop + DWELL_S + overshoot / LEG_MM_S;
            ct.ae_leave_t_s = Some(leave - clock_offset_s);
            RmsContact {
                onset_s: tc.t_c - clock_offset_s,
                leave_s: leave - clock_offset_s,
                level_v: ct.ae_amplitude_v / std::f64::consts::SQRT_2,
            }
        })
        .collect()
}

/// act − physical at a touch: what the encoders cannot see (thermal drift of
/// the structure, backlash) plus any catalogue shape applied directly to
/// touch_normal. The observable's "normal coordinate" is the coordinate of
/// the face's normal axis (z, x, y for xy, yz, zx) as the robot plugin reads
/// it, so direct shapes act along +axis and their covariates use the +axis
/// sign convention (approach_normal_mm_s = v·dir_axis, dir = sign of the
/// last move along +axis).
pub(super) fn frame_offset(fx: &Effects, row: &PlanRow, dir_b: i32, t_s: f64) -> V3 {
    let n = row.face.normal();
    let ax = row.face.axis();
    // TCP physically higher by D → the controller reads D lower.
    let mut o = V3::new(0.0, 0.0, -fx.drift_mm(t_s));
    // b/2 along the outward normal per the outward-relative dir_b equals
    // b/2·dir_axis along +axis: the catalogue's b·dir/2 in the plugin's frame.
    o += n * (fx.backlash_b_mm / 2.0 * dir_b as f64);
    if !fx.touch.is_empty() {
        let cov = |c: &str| -> f64 {
            match c {
                "x_mm" => row.nom.x,
                "y_mm" => row.nom.y,
                "z_mm" => row.nom.z,
                "approach_mm_s" => row.speed_mm_s,
                "approach_normal_mm_s" => row.speed_mm_s * row.dir[ax],
                "t_s" => t_s,
                "dir" => dir_b as f64 * n[ax],
                _ => 0.0,
            }
        };
        let g: f64 = fx.touch.iter().map(|e| e.value(&cov)).sum();
        let mut e = V3::zeros();
        e[ax] = 1.0;
        o += e * g;
    }
    o
}
