//! The fleet steps of the engine, after every run: join the runs'
//! observations (with their machine), diagnose the sim-to-real gap, write
//! the fleet report and — last — the manifest. Also the Arrow helpers these
//! steps share.

use super::*;

impl Engine {
    /// Fleet steps: join observations, diagnose, fleet report.
    pub(super) fn run_fleet_stages(
        &self,
        out: &Path,
        outcome: &mut FleetOutcome,
        progress: &dyn Progress,
    ) -> Result<()> {
        let fleet_dir = out.join("fleet");
        std::fs::create_dir_all(&fleet_dir)?;
        let previous: BTreeMap<String, StageRecord> = read_run_cache(&fleet_dir);
        let mut records = Vec::new();
        let mut diagnosis_json: Option<serde_json::Value> = None;
        let mut diagnosis_html: Option<String> = None;
        let want_diagnose = self
            .config
            .pipeline_list("stages")?
            .map(|l| l.iter().any(|s| s == "diagnose" || s == "observe"))
            .unwrap_or(true);

        let obs_paths: Vec<&PathBuf> = outcome
            .runs
            .iter()
            .filter_map(|r| r.observations.as_ref())
            .collect();
        let obs_file = fleet_dir.join("observations.parquet");
        if want_diagnose && !obs_paths.is_empty() {
            // The joined table is a function of each run's observations file
            // (whose blake3 its observe stage recorded), machine and plugin,
            // in order: keyed on those, a no-change night decides "cached"
            // without reading or re-encoding millions of rows (issue 18
            // item 4: the cached re-run of 1 000 runs in ≤ 2 s).
            let mut okey = KeyBuilder::new("fleet-observations");
            okey.part("version", "2");
            for r in outcome.runs.iter().filter(|r| r.observations.is_some()) {
                let p = r.observations.as_ref().expect("filtered");
                let recorded = r
                    .stages
                    .iter()
                    .find_map(|s| s.files.get("observations.parquet").cloned());
                let h = match recorded {
                    Some(h) => h,
                    None => hash_file(p)?,
                };
                okey.part(&format!("{}/{}/{}", r.plugin, r.machine, r.run), &h);
            }
            let okey = okey.finish();
            let obs_cached = previous
                .get("observations")
                .map(|p| record_valid(&fleet_dir, p, &okey))
                .unwrap_or(false);
            // Issue 12: every row names its machine (a `machine` column
            // beside `run`), and the observables each plugin produced are
            // what its composites apply to (issue 13 item 1).
            let join = || -> Result<(RecordBatch, BTreeMap<String, BTreeSet<String>>)> {
                progress.message(&format!("joining observations of {} runs", obs_paths.len()));
                let mut batches = Vec::new();
                let mut produced: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
                for r in outcome.runs.iter().filter(|r| r.observations.is_some()) {
                    let p = r.observations.as_ref().expect("filtered");
                    let b = with_machine_column(crate::contracts::read_parquet(p)?, &r.machine)?;
                    produced
                        .entry(r.plugin.clone())
                        .or_default()
                        .extend(observable_names(&b));
                    batches.push(b);
                }
                Ok((union_concat(&batches)?, produced))
            };
            let mut joined = None;
            if obs_cached {
                let mut rec = previous["observations"].clone();
                rec.cached = true;
                records.push(rec);
            } else {
                let (batch, produced) = join()?;
                let bytes = parquet_bytes(&batch)?;
                write_atomic(&obs_file, &bytes)?;
                records.push(StageRecord {
                    stage: "observations".into(),
                    version: 2,
                    key: okey.clone(),
                    files: [("observations.parquet".to_string(), hash_bytes(&bytes))].into(),
                    cached: false,
                });
                joined = Some((batch, produced));
            }

            let dcfg = self.diagnose_config()?;
            let effects = self.plugin_effects();
            // Which plugin's composites apply where follows from the joined
            // observations (okey) and the registered effects, so the key
            // needs only those.
            let plugins_in_batch: BTreeSet<&str> =
                outcome.runs.iter().map(|r| r.plugin.as_str()).collect();
            let mut dkey = KeyBuilder::new("diagnose");
            dkey.part("version", &DIAGNOSE_STAGE_VERSION.to_string())
                .part("config", &config_text(&self.config.section("diagnose")))
                .part("observations", &okey);
            for (plugin, effects) in effects.iter().filter(|pe| plugins_in_batch.contains(pe.0)) {
                for e in effects {
                    dkey.part("effect", &format!("{plugin}/{}", e.name()));
                }
            }
            let dkey = dkey.finish();
            let d_cached = previous
                .get("diagnose")
                .map(|p| record_valid(&fleet_dir, p, &dkey))
                .unwrap_or(false);
            if d_cached {
                let mut rec = previous["diagnose"].clone();
                rec.cached = true;
                records.push(rec);
                diagnosis_json = std::fs::read(fleet_dir.join("diagnosis.json"))
                    .ok()
                    .and_then(|b| serde_json::from_slice(&b).ok());
                diagnosis_html =
                    std::fs::read_to_string(fleet_dir.join("diagnosis_section.html")).ok();
            } else {
                let (joined, produced) = match joined.take() {
                    Some(j) => j,
                    None => join()?,
                };
                let scoped: Vec<(Vec<String>, &PluginEffects)> = effects
                    .iter()
                    .filter_map(|pe| {
                        produced
                            .get(pe.0)
                            .map(|o| (o.iter().cloned().collect::<Vec<_>>(), pe))
                    })
                    .collect();
                let scopes: Vec<diagnose::EffectScope> = scoped
                    .iter()
                    .map(|(obs, (plugin, effects))| diagnose::EffectScope {
                        plugin,
                        observables: Some(obs.as_slice()),
                        effects,
                    })
                    .collect();
                progress.message("diagnosing the sim-to-real gap");
                let d = diagnose::diagnose_scoped(&joined, &dcfg, &scopes)
                    .context("fleet diagnosis")?;
                let mut files = BTreeMap::new();
                let dj = json_bytes(&d.diagnosis)?;
                let dp = parquet_bytes(&d.per_row)?;
                let am = json_bytes(&d.augmented_model)?;
                let dh = d.report_html.clone().into_bytes();
                for (name, bytes) in [
                    ("diagnosis.json", &dj),
                    ("diagnosis.parquet", &dp),
                    ("augmented_model.json", &am),
                    ("diagnosis_section.html", &dh),
                ] {
                    write_atomic(&fleet_dir.join(name), bytes)?;
                    files.insert(name.to_string(), hash_bytes(bytes));
                }
                diagnosis_json = serde_json::to_value(&d.diagnosis).ok();
                diagnosis_html = Some(d.report_html);
                records.push(StageRecord {
                    stage: "diagnose".into(),
                    version: DIAGNOSE_STAGE_VERSION,
                    key: dkey,
                    files,
                    cached: false,
                });
            }
            outcome.diagnosis = Some(fleet_dir.join("diagnosis.json"));
        }

        // The augmented simulator (issue 13 item 4): written before the
        // report, whose key covers it; a batch without --augment removes a
        // previous one so the page never shows a stale comparison.
        let augment_file = fleet_dir.join("augment.json");
        match (&self.augment, obs_file.is_file()) {
            (Some(model), true) => {
                progress.message("re-simulating with the augmented model");
                let obs = crate::contracts::read_parquet(&obs_file)?;
                let a = crate::diagnose::augment::evaluate(model, &obs)?;
                write_atomic(&augment_file, &json_bytes(&a)?)?;
            }
            _ => {
                let _ = std::fs::remove_file(&augment_file);
            }
        }

        // Fleet report: cached on every run's stage keys + failures + diagnosis.
        let mut rkey = KeyBuilder::new("fleet-report");
        rkey.part("version", &report::REPORT_VERSION.to_string())
            .part("config", &config_text(&self.config.section("report")));
        for r in &outcome.runs {
            for s in &r.stages {
                rkey.part(&format!("{}/{}/{}", r.machine, r.run, s.stage), &s.key);
            }
        }
        for f in &outcome.failures {
            rkey.part("failure", &format!("{}: {}", f.run_dir, f.error));
        }
        for r in &records {
            rkey.part(&r.stage, &r.key);
        }
        // The augmentation's figures are shown in the verdicts when present.
        let augment = hash_file(&fleet_dir.join("augment.json")).unwrap_or_default();
        rkey.part("augment", &augment);
        let rkey = rkey.finish();
        let cached = previous
            .get("report")
            .map(|p| record_valid(&fleet_dir, p, &rkey))
            .unwrap_or(false);
        if cached {
            let mut rec = previous["report"].clone();
            rec.cached = true;
            records.push(rec);
        } else {
            let html = report::fleet_page(
                &self.config.section("report"),
                outcome,
                diagnosis_json.as_ref(),
                diagnosis_html.as_deref(),
            );
            let bytes = html.into_bytes();
            write_atomic(&fleet_dir.join("report.html"), &bytes)?;
            records.push(StageRecord {
                stage: "report".into(),
                version: report::REPORT_VERSION,
                key: rkey.clone(),
                files: [("report.html".to_string(), hash_bytes(&bytes))].into(),
                cached: false,
            });
        }
        outcome.report = Some(fleet_dir.join("report.html"));
        if let (Some((dir, night)), Some(d)) = (&self.history, diagnosis_json.as_ref()) {
            self.append_history(dir, night.as_deref(), d, outcome, out, progress)?;
        }
        // out/index.html (issue 16 item 2): cached like the report, on its
        // key and the trend page's presence.
        let mut ikey = KeyBuilder::new("fleet-index");
        ikey.part("report", &rkey).part(
            "trend",
            &out.join(report::index::TREND_PAGE).is_file().to_string(),
        );
        let ikey = ikey.finish();
        if previous
            .get("index")
            .map(|p| record_valid(out, p, &ikey))
            .unwrap_or(false)
        {
            let mut rec = previous["index"].clone();
            rec.cached = true;
            records.push(rec);
        } else {
            let bytes = report::index_page(&self.config.section("report"), outcome).into_bytes();
            write_atomic(&out.join("index.html"), &bytes)?;
            records.push(StageRecord {
                stage: "index".into(),
                version: report::REPORT_VERSION,
                key: ikey,
                files: [("index.html".to_string(), hash_bytes(&bytes))].into(),
                cached: false,
            });
        }
        let cache: Vec<&StageRecord> = records.iter().collect();
        write_json_atomic(&fleet_dir.join(cache::RUN_CACHE_FILE), &cache)?;
        outcome.fleet = records;
        Ok(())
    }

    /// `run --history`: the night's diagnosis into the history, the trend
    /// report into `<out>/trend/`.
    fn append_history(
        &self,
        dir: &Path,
        night: Option<&str>,
        diagnosis: &serde_json::Value,
        outcome: &FleetOutcome,
        out: &Path,
        progress: &dyn Progress,
    ) -> Result<()> {
        let night = match night {
            Some(n) => n.to_string(),
            None => outcome
                .runs
                .iter()
                .filter_map(|r| RunSpec::load(Path::new(&r.run_dir)).ok()?.started)
                .filter(|s| s.len() >= 10)
                .map(|s| s[..10].to_string())
                .max()
                .ok_or_else(|| {
                    anyhow!("--history: no run states [run].started, so the night is unknown — give --night YYYY-MM-DD")
                })?,
        };
        let file = report::trend::append_night(dir, &night, diagnosis)?;
        progress.message(&format!("history: {}", file.display()));
        let t = report::trend::write_trend(dir, &out.join("trend"))?;
        for a in &t.alerts {
            tracing::warn!("trend alert {} {}: {}", a.night, a.kind, a.message);
        }
        Ok(())
    }

    pub(super) fn write_manifest(
        &self,
        input_root: &Path,
        out: &Path,
        o: &FleetOutcome,
    ) -> Result<()> {
        let config: serde_json::Value =
            serde_json::to_value(&self.config.table).unwrap_or(serde_json::Value::Null);
        let manifest = serde_json::json!({
            "version": MANIFEST_VERSION,
            "sparkout_version": env!("CARGO_PKG_VERSION"),
            "input_root": input_root.display().to_string(),
            "config_source": self.config.source,
            "config": config,
            "runs": o.runs,
            "fleet": o.fleet,
            "failures": o.failures.len(),
            "stages_computed": o.stages_computed(),
            "stages_cached": o.stages_cached(),
        });
        write_json_atomic(&out.join("manifest.json"), &manifest)
    }
}

/// Parquet bytes of a batch (zstd), so the hash is known before writing.
pub fn parquet_bytes(batch: &RecordBatch) -> Result<Vec<u8>> {
    let mut buf = Vec::new();
    let mut w = parquet::arrow::ArrowWriter::try_new(
        &mut buf,
        batch.schema(),
        Some(crate::contracts::write::writer_properties(&batch.schema())),
    )?;
    w.write(batch)?;
    w.close()?;
    Ok(buf)
}

pub(super) fn json_bytes(v: &impl Serialize) -> Result<Vec<u8>> {
    let mut s = serde_json::to_string_pretty(v)?;
    s.push('\n');
    Ok(s.into_bytes())
}

/// A run's observations with a `machine` column (before `run`) when the
/// plugin did not write one (issue 12: runs are (machine, run) pairs).
pub fn with_machine_column(batch: RecordBatch, machine: &str) -> Result<RecordBatch> {
    use arrow::array::{ArrayRef, StringArray};
    use arrow::datatypes::{DataType, Field, Schema};
    if batch.column_by_name("machine").is_some() {
        return Ok(batch);
    }
    let schema = batch.schema();
    let at = schema.index_of("run").unwrap_or(0);
    let mut fields: Vec<Arc<Field>> = schema.fields().iter().cloned().collect();
    let mut cols: Vec<ArrayRef> = batch.columns().to_vec();
    fields.insert(at, Arc::new(Field::new("machine", DataType::Utf8, false)));
    cols.insert(
        at,
        Arc::new(StringArray::from(vec![machine; batch.num_rows()])),
    );
    Ok(RecordBatch::try_new(
        Arc::new(Schema::new_with_metadata(fields, schema.metadata().clone())),
        cols,
    )?)
}

/// Distinct values of a batch's `observable` column.
pub(super) fn observable_names(batch: &RecordBatch) -> BTreeSet<String> {
    use arrow::array::AsArray;
    let Some(a) = batch.column_by_name("observable") else {
        return BTreeSet::new();
    };
    match arrow::compute::cast(a, &arrow::datatypes::DataType::Utf8) {
        Ok(c) => c
            .as_string::<i32>()
            .iter()
            .flatten()
            .map(String::from)
            .collect(),
        Err(_) => BTreeSet::new(),
    }
}

/// Concatenate batches whose schemas may differ (different plugins emit
/// different covariates): the union of columns in first-seen order, nulls
/// where a batch lacks a column.
pub fn union_concat(batches: &[RecordBatch]) -> Result<RecordBatch> {
    use arrow::array::new_null_array;
    use arrow::datatypes::{Field, Schema};
    let mut fields: Vec<Field> = Vec::new();
    for b in batches {
        for f in b.schema().fields() {
            match fields.iter().position(|g| g.name() == f.name()) {
                Some(i) => {
                    if fields[i].data_type() != f.data_type() {
                        bail!(
                            "observations disagree on the type of `{}`: {} vs {}",
                            f.name(),
                            fields[i].data_type(),
                            f.data_type()
                        );
                    }
                    if f.is_nullable() {
                        fields[i] = fields[i].clone().with_nullable(true);
                    }
                }
                None => fields.push(f.as_ref().clone()),
            }
        }
    }
    for f in fields.iter_mut() {
        if batches.iter().any(|b| b.column_by_name(f.name()).is_none()) {
            *f = f.clone().with_nullable(true);
        }
    }
    let schema = Arc::new(Schema::new(fields));
    let mut columns = Vec::new();
    for f in schema.fields() {
        let parts: Vec<arrow::array::ArrayRef> = batches
            .iter()
            .map(|b| {
                b.column_by_name(f.name())
                    .cloned()
                    .unwrap_or_else(|| new_null_array(f.data_type(), b.num_rows()))
            })
            .collect();
        let refs: Vec<&dyn arrow::array::Array> = parts.iter().map(|a| a.as_ref()).collect();
        columns.push(arrow::compute::concat(&refs)?);
    }
    Ok(RecordBatch::try_new(schema, columns)?)
}
