//! The fleet steps of the engine, after every run: join the runs'
//! observations (with their machine), diagnose the sim-to-real gap, write
//! the fleet report and — last — the manifest. Also the Arrow helpers these
//! steps share.

use super::*;

/// The fleet steps' cache: last night's records (`fleet/.sparkout-cache`)
/// and tonight's, in step order. A step either reuses its files (valid
/// for its key) or writes new ones.
struct FleetCache {
    previous: BTreeMap<String, StageRecord>,
    records: Vec<StageRecord>,
}

impl FleetCache {
    /// True, with the record kept (marked cached), when `stage`'s files
    /// under `dir` are those its `key` made.
    fn reuse(&mut self, stage: &str, dir: &Path, key: &str) -> bool {
        match self.previous.get(stage) {
            Some(p) if record_valid(dir, p, key) => {
                let mut rec = p.clone();
                rec.cached = true;
                self.records.push(rec);
                true
            }
            _ => false,
        }
    }

    /// Write a step's files under `dir` (each atomically) and record them.
    fn write(
        &mut self,
        stage: &str,
        version: u32,
        key: String,
        dir: &Path,
        files: &[(&str, &[u8])],
    ) -> Result<()> {
        let mut hashes = BTreeMap::new();
        for (name, bytes) in files {
            write_atomic(&dir.join(name), bytes)?;
            hashes.insert(name.to_string(), hash_bytes(bytes));
        }
        self.push_record(stage, version, key, hashes);
        Ok(())
    }

    fn push_record(
        &mut self,
        stage: &str,
        version: u32,
        key: String,
        files: BTreeMap<String, String>,
    ) {
        self.records.push(StageRecord {
            stage: stage.into(),
            version,
            key,
            files,
            cached: false,
        });
    }
}

impl FleetCache {
    /// Record a step whose files were written in place (atomically, by a
    /// stream) under `dir`.
    fn record_written(
        &mut self,
        stage: &str,
        version: u32,
        key: String,
        dir: &Path,
        names: &[&str],
    ) -> Result<()> {
        let mut hashes = BTreeMap::new();
        for name in names {
            hashes.insert(name.to_string(), hash_file(&dir.join(name))?);
        }
        self.push_record(stage, version, key, hashes);
        Ok(())
    }
}

/// Per plugin, the observables it produced.
type Produced = BTreeMap<String, BTreeSet<String>>;

impl Engine {
    /// Fleet steps, in order: join observations, diagnose, the augmented
    /// simulator, the fleet report, the history, the index page.
    pub(super) fn run_fleet_stages(
        &self,
        out: &Path,
        outcome: &mut FleetOutcome,
        progress: &dyn Progress,
    ) -> Result<()> {
        let fleet_dir = out.join("fleet");
        std::fs::create_dir_all(&fleet_dir)?;
        let mut cache = FleetCache {
            previous: read_run_cache(&fleet_dir),
            records: Vec::new(),
        };
        let want_diagnose = self
            .checked
            .pipeline
            .stages
            .as_ref()
            .map(|l| l.iter().any(|s| s == "diagnose" || s == "observe"))
            .unwrap_or(true);
        let has_observations = outcome.runs.iter().any(|r| r.observations.is_some());
        let mut diagnosis: (Option<diagnose::Diagnosis>, Option<String>) = (None, None);
        if want_diagnose && has_observations {
            let (okey, joined) =
                self.fleet_observations(&mut cache, &fleet_dir, outcome, progress)?;
            diagnosis =
                self.fleet_diagnosis(&mut cache, &fleet_dir, outcome, &okey, joined, progress)?;
            outcome.diagnosis = Some(fleet_dir.join("diagnosis.json"));
        }
        self.fleet_augment(&fleet_dir, progress)?;
        outcome.night = Night::of(
            self.history.as_ref().and_then(|h| h.night.as_deref()),
            &outcome.runs,
        );
        // The trend before the pages: both open with the night's alerts.
        if let (Some(h), Some(d)) = (&self.history, diagnosis.0.as_ref()) {
            self.append_history(h, d, outcome, out, progress)?;
        }
        // The diagnosis' columns are freed: their pages go back before the
        // report reads the fleet tables again.
        crate::alloc::release_freed_memory();
        let rkey = self.fleet_report(&mut cache, &fleet_dir, outcome, &diagnosis, progress)?;
        self.fleet_index(&mut cache, out, outcome, &rkey)?;
        let records: Vec<&StageRecord> = cache.records.iter().collect();
        write_json_atomic(&fleet_dir.join(cache::RUN_CACHE_FILE), &records)?;
        outcome.fleet = cache.records;
        Ok(())
    }

    /// `fleet/observations.parquet`, written as a stream: every run's
    /// observations with a `machine` column beside `run`, conformed to the
    /// union of the runs' columns (known from the files' schemas before a
    /// row is read), one run at a time — the fleet's rows are never in
    /// memory at once (docs/scale.md). Returns the observables each plugin
    /// produced (what its composites apply to) and the covariates spilled
    /// per observable for the diagnosis to read (removed when dropped).
    fn join_observations(
        &self,
        outcome: &FleetOutcome,
        path: &Path,
        progress: &dyn Progress,
    ) -> Result<(Produced, diagnose::observations_file::Spilled)> {
        let runs: Vec<&RunResult> = outcome
            .runs
            .iter()
            .filter(|r| r.observations.is_some())
            .collect();
        progress.message(&format!("joining observations of {} runs", runs.len()));
        let schemas = runs
            .iter()
            .map(|r| {
                let p = r.observations.as_ref().expect("filtered");
                let builder = crate::contracts::parquet_file::open_parquet(p)?;
                Ok(with_machine_field(builder.schema()))
            })
            .collect::<Result<Vec<_>>>()?;
        let union = Arc::new(union_schema(schemas.iter())?);
        drop(schemas);
        let mut produced = Produced::new();
        let mut spill =
            diagnose::observations_file::RowValueSpill::create(&spill_dir(path), &union)?
                .indexing(path);
        // Reading (decode, conform, spill) runs on a thread of its own, a few
        // runs ahead of the encoder: on two cores the join takes the longer
        // of the two instead of their sum. The batches keep their order, so
        // the file is the one a single thread writes. A reading error goes
        // down the channel and fails the write (no file under the final
        // name); a failed write drops the receiver, which stops the reader.
        // The end is sent explicitly: a reader that stopped without it (a
        // panic) fails the write too.
        let (tx, rx) =
            std::sync::mpsc::sync_channel::<Option<Result<RecordBatch>>>(READ_AHEAD_RUNS);
        let written = std::thread::scope(|scope| {
            let union = &union;
            let reader = scope.spawn(move || {
                for r in &runs {
                    let p = r.observations.as_ref().expect("filtered");
                    let batch = (|| -> Result<RecordBatch> {
                        let b =
                            with_machine_column(crate::contracts::read_parquet(p)?, &r.machine)?;
                        produced
                            .entry(r.plugin.clone())
                            .or_default()
                            .extend(observable_names(&b));
                        let b = conform(b, union)?;
                        spill.push(&b, p)?;
                        Ok(b)
                    })();
                    let failed = batch.is_err();
                    if tx.send(Some(batch)).is_err() || failed {
                        return (produced, spill);
                    }
                }
                let _ = tx.send(None);
                (produced, spill)
            });
            let batches = sparkout_core::ahead::received(rx, || {
                err!("the join stopped reading before its last run")
            });
            let written =
                crate::contracts::write::write_parquet_batches_atomic(path, union.clone(), batches);
            let (produced, spill) = reader.join().expect("the join's reader does not panic");
            written.map(|()| (produced, spill))
        });
        let (produced, spill) = written?;
        Ok((produced, spill.finish()?))
    }

    /// The observables each plugin's runs produced, read from the runs'
    /// `observable` columns alone (a night whose joined table is cached).
    fn produced_observables(&self, outcome: &FleetOutcome) -> Result<Produced> {
        let mut produced = Produced::new();
        for r in &outcome.runs {
            let Some(p) = &r.observations else { continue };
            let builder = crate::contracts::parquet_file::open_parquet(p)?;
            let Some(i) = builder.schema().index_of("observable").ok() else {
                continue;
            };
            let mask = parquet::arrow::ProjectionMask::roots(builder.parquet_schema(), [i]);
            let names = produced.entry(r.plugin.clone()).or_default();
            for b in builder.with_projection(mask).build()? {
                names.extend(observable_names(&b?));
            }
        }
        Ok(produced)
    }

    /// `fleet/observations.parquet`. The joined table is a function of each
    /// run's observations file (whose blake3 its observe stage recorded),
    /// machine and plugin, in order: keyed on those, a no-change night
    /// decides "cached" without reading or re-encoding millions of rows
    /// (the cached re-run of 1 000 runs in ≤ 2 s). Returns
    /// the key and the joined table when it was built.
    fn fleet_observations(
        &self,
        cache: &mut FleetCache,
        fleet_dir: &Path,
        outcome: &FleetOutcome,
        progress: &dyn Progress,
    ) -> Result<(
        String,
        Option<(Produced, diagnose::observations_file::Spilled)>,
    )> {
        let mut okey = KeyBuilder::new("fleet-observations");
        okey.part("version", "3");
        for r in outcome.runs.iter().filter(|r| r.observations.is_some()) {
            let p = r.observations.as_ref().expect("filtered");
            let recorded = r
                .stages
                .iter()
                .find_map(|s| s.files.get(OBSERVATIONS_FILE).cloned());
            let h = match recorded {
                Some(h) => h,
                None => hash_file(p)?,
            };
            okey.part(&format!("{}/{}/{}", r.plugin, r.machine, r.run), &h);
        }
        let okey = okey.finish();
        if cache.reuse("observations", fleet_dir, &okey) {
            return Ok((okey, None));
        }
        let joined =
            self.join_observations(outcome, &fleet_dir.join(OBSERVATIONS_FILE), progress)?;
        cache.record_written(
            "observations",
            3,
            okey.clone(),
            fleet_dir,
            &[OBSERVATIONS_FILE],
        )?;
        Ok((okey, Some(joined)))
    }

    /// The fleet diagnosis (`fleet/diagnosis.*`, augmented_model.json), each
    /// plugin's composites scoped to the observables it produced. Returns
    /// diagnosis.json as its serde type and its report section.
    fn fleet_diagnosis(
        &self,
        cache: &mut FleetCache,
        fleet_dir: &Path,
        outcome: &FleetOutcome,
        okey: &str,
        joined: Option<(Produced, diagnose::observations_file::Spilled)>,
        progress: &dyn Progress,
    ) -> Result<(Option<diagnose::Diagnosis>, Option<String>)> {
        let dcfg = &self.checked.diagnose;
        let effects = self.plugin_effects();
        // Which plugin's composites apply where follows from the joined
        // observations (okey) and the registered effects, so the key
        // needs only those.
        let plugins_in_batch: BTreeSet<&str> =
            outcome.runs.iter().map(|r| r.plugin.as_str()).collect();
        let mut dkey = KeyBuilder::new("diagnose");
        dkey.part("version", &DIAGNOSE_STAGE_VERSION.to_string())
            .part("config", dcfg.effective())
            .part("observations", okey);
        for (plugin, effects) in effects.iter().filter(|pe| plugins_in_batch.contains(pe.0)) {
            // The key (name and covariates), not the name alone: one name
            // may have a form per family of observables (the servo's lag).
            for e in effects {
                dkey.part("effect", &format!("{plugin}/{}", e.key()));
            }
        }
        let dkey = dkey.finish();
        if cache.reuse("diagnose", fleet_dir, &dkey) {
            return Ok((
                std::fs::read(fleet_dir.join("diagnosis.json"))
                    .ok()
                    .and_then(|b| serde_json::from_slice::<diagnose::Diagnosis>(&b).ok()),
                std::fs::read_to_string(fleet_dir.join("diagnosis_section.html")).ok(),
            ));
        }
        // Tonight's join hands its spilled covariates over; a cached join
        // has none and the diagnosis reads the file's columns instead.
        let (produced, spilled) = match joined {
            Some((p, s)) => (p, Some(s)),
            None => {
                // A spill a killed night left behind is not tonight's.
                let _ = std::fs::remove_dir_all(spill_dir(&fleet_dir.join(OBSERVATIONS_FILE)));
                (self.produced_observables(outcome)?, None)
            }
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
        // Read from the joined file one observable at a time: the fleet's
        // covariates are never all in memory.
        let d = diagnose::diagnose_observations_file(
            &fleet_dir.join(OBSERVATIONS_FILE),
            dcfg,
            &scopes,
            spilled,
            Some(&fleet_dir.join(RESULTS_SPILL_DIR)),
            &|msg: &str| progress.message(msg),
        )
        .context("fleet diagnosis")?;
        progress.message("writing the diagnosis");
        crate::alloc::release_freed_memory();
        // The per-row table is built a slice at a time as it is written.
        d.per_row
            .write_parquet(&fleet_dir.join("diagnosis.parquet"))?;
        let files: [(&str, &[u8]); 3] = [
            ("diagnosis.json", &json_bytes(&d.diagnosis)?),
            ("augmented_model.json", &json_bytes(&d.augmented_model)?),
            ("diagnosis_section.html", d.report_html.as_bytes()),
        ];
        for (name, bytes) in files {
            write_atomic(&fleet_dir.join(name), bytes)?;
        }
        cache.record_written(
            "diagnose",
            DIAGNOSE_STAGE_VERSION,
            dkey,
            fleet_dir,
            &[
                "diagnosis.json",
                "diagnosis.parquet",
                "augmented_model.json",
                "diagnosis_section.html",
            ],
        )?;
        Ok((Some(d.diagnosis), Some(d.report_html)))
    }

    /// The augmented simulator: written before the
    /// report, whose key covers it; a batch without --augment removes a
    /// previous one so the page never shows a stale comparison.
    fn fleet_augment(&self, fleet_dir: &Path, progress: &dyn Progress) -> Result<()> {
        let augment_file = fleet_dir.join("augment.json");
        let obs_file = fleet_dir.join(OBSERVATIONS_FILE);
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
        Ok(())
    }

    /// The fleet report, cached on every run's stage keys, the failures,
    /// the fleet steps before it and the augmentation. Returns its key.
    fn fleet_report(
        &self,
        cache: &mut FleetCache,
        fleet_dir: &Path,
        outcome: &mut FleetOutcome,
        (diagnosis, diagnosis_html): &(Option<diagnose::Diagnosis>, Option<String>),
        progress: &dyn Progress,
    ) -> Result<String> {
        let mut rkey = KeyBuilder::new("fleet-report");
        rkey.part("version", &report::REPORT_VERSION.to_string())
            .part("config", self.checked.report.effective());
        for r in &outcome.runs {
            for s in &r.stages {
                rkey.part(&format!("{}/{}/{}", r.machine, r.run, s.stage), &s.key);
            }
        }
        for f in &outcome.failures {
            rkey.part("failure", &format!("{}: {}", f.run_dir, f.error));
        }
        for r in &cache.records {
            rkey.part(&r.stage, &r.key);
        }
        // The augmentation's figures are shown in the verdicts when present.
        let augment = hash_file(&fleet_dir.join("augment.json")).unwrap_or_default();
        rkey.part("augment", &augment);
        // The night's news: its date and the trend's alerts (both pages).
        let night = &outcome.night;
        rkey.part(
            "night",
            &format!("{:?} {:?} {}", night.date, night.first, night.given),
        );
        let trend =
            hash_file(&outcome.out_dir.join("trend").join("trend.json")).unwrap_or_default();
        rkey.part("trend", &trend);
        let rkey = rkey.finish();
        if !cache.reuse("report", fleet_dir, &rkey) {
            progress.message("writing the fleet report");
            let html = report::fleet_page(
                &self.checked.report,
                outcome,
                diagnosis.as_ref(),
                diagnosis_html.as_deref(),
            );
            cache.write(
                "report",
                report::REPORT_VERSION,
                rkey.clone(),
                fleet_dir,
                &[("report.html", html.as_bytes())],
            )?;
        }
        outcome.report = Some(fleet_dir.join("report.html"));
        Ok(rkey)
    }

    /// out/index.html: cached like the report, on its key
    /// and the trend page's presence.
    fn fleet_index(
        &self,
        cache: &mut FleetCache,
        out: &Path,
        outcome: &FleetOutcome,
        rkey: &str,
    ) -> Result<()> {
        let mut ikey = KeyBuilder::new("fleet-index");
        ikey.part("report", rkey).part(
            "trend",
            &out.join(report::index::TREND_PAGE).is_file().to_string(),
        );
        let ikey = ikey.finish();
        if !cache.reuse("index", out, &ikey) {
            let html = report::index_page(&self.checked.report, outcome);
            cache.write(
                "index",
                report::REPORT_VERSION,
                ikey,
                out,
                &[("index.html", html.as_bytes())],
            )?;
        }
        Ok(())
    }

    /// `run --history`: the night's diagnosis into the history, the trend
    /// report into `<out>/trend/`.
    fn append_history(
        &self,
        h: &super::History,
        diagnosis: &diagnose::Diagnosis,
        outcome: &FleetOutcome,
        out: &Path,
        progress: &dyn Progress,
    ) -> Result<()> {
        let dir = &h.dir;
        let night = outcome.night.date.clone().ok_or_else(|| {
            err!("--history: no run's [run].started begins with a date YYYY-MM-DD, so the night is unknown — give --night YYYY-MM-DD")
        })?;
        let events = h
            .events
            .iter()
            .map(|e| report::trend::parse_event(e, Some(&night)))
            .collect::<Result<Vec<_>>>()?;
        // What the night's results depend on: every section but the
        // report's title and the trend's own settings, and the code that
        // made them — an update of sparkout that changes a stage or the
        // diagnosis' candidates (an effect renamed, a form added) is an
        // event that restarts the baselines, not a night of alerts.
        let mut settings = self.config.table.clone();
        settings.remove("report");
        settings.remove("trend");
        let config = report::trend::fingerprint(&format!(
            "{}\n{}",
            super::config_text(&settings),
            models_text(
                &self.plugins,
                &outcome.runs.iter().map(|r| r.plugin.as_str()).collect()
            )
        ));
        let file = report::trend::append_night(dir, &night, diagnosis, &config)?;
        report::trend::append_events(dir, &events)?;
        progress.message(&format!("history: {}", file.display()));
        let t = report::trend::write_trend(dir, &out.join("trend"), &[], &self.checked.trend)?;
        for a in t.alerts_on(&night) {
            tracing::warn!(
                "trend alert {} #{} {}: {}",
                a.night,
                a.rank,
                a.kind,
                a.message
            );
        }
        Ok(())
    }

    pub(super) fn write_manifest(
        &self,
        input_root: &Path,
        out: &Path,
        o: &FleetOutcome,
    ) -> Result<()> {
        let manifest = crate::outcome::Manifest {
            config: serde_json::to_value(&self.config.table).unwrap_or(serde_json::Value::Null),
            config_source: self.config.source.clone(),
            failures: o.failures.len(),
            fleet: o.fleet.clone(),
            input_root: input_root.display().to_string(),
            runs: o.runs.clone(),
            sparkout_version: env!("CARGO_PKG_VERSION").to_string(),
            stages_cached: o.stages_cached(),
            stages_computed: o.stages_computed(),
            version: MANIFEST_VERSION,
        };
        manifest.write(&out.join("manifest.json"))
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
/// plugin did not write one (runs are (machine, run) pairs).
pub fn with_machine_column(batch: RecordBatch, machine: &str) -> Result<RecordBatch> {
    use arrow::array::{ArrayRef, StringArray};
    if batch.column_by_name("machine").is_some() {
        return Ok(batch);
    }
    let schema = with_machine_field(&batch.schema());
    let at = schema.index_of("machine").expect("just added");
    let mut cols: Vec<ArrayRef> = batch.columns().to_vec();
    cols.insert(
        at,
        Arc::new(StringArray::from(vec![machine; batch.num_rows()])),
    );
    Ok(RecordBatch::try_new(Arc::new(schema), cols)?)
}

/// Where the diagnosis keeps each observable's per-row results until
/// diagnosis.parquet is written: a hidden folder of fleet/, removed then
/// (and, left by a killed night, at the next diagnosis).
const RESULTS_SPILL_DIR: &str = ".diagnosis-results";

/// Where the join spills each observable's covariates for the diagnosis:
/// a hidden folder beside the joined file, removed once diagnosed.
/// Runs the join's reader decodes ahead of the encoder (a run's batch is
/// ≈ 15 k rows, a few MB).
const READ_AHEAD_RUNS: usize = 4;

fn spill_dir(observations: &Path) -> PathBuf {
    observations.with_file_name(".observations-spill")
}

/// The schema [`with_machine_column`] gives a run's observations.
pub fn with_machine_field(schema: &arrow::datatypes::Schema) -> arrow::datatypes::Schema {
    use arrow::datatypes::{DataType, Field, Schema};
    if schema.field_with_name("machine").is_ok() {
        return schema.clone();
    }
    let at = schema.index_of("run").unwrap_or(0);
    let mut fields: Vec<Arc<Field>> = schema.fields().iter().cloned().collect();
    fields.insert(at, Arc::new(Field::new("machine", DataType::Utf8, false)));
    Schema::new_with_metadata(fields, schema.metadata().clone())
}

/// Distinct values of a batch's `observable` column.
/// The code a night's results come from, as text (a part of the history's
/// config fingerprint): the fleet diagnosis' version and, for each plugin
/// in `in_batch`, its stages' versions and its effects' keys.
pub fn models_text(plugins: &[Arc<dyn MachinePlugin>], in_batch: &BTreeSet<&str>) -> String {
    let mut text = format!("diagnose v{DIAGNOSE_STAGE_VERSION}");
    for p in plugins.iter().filter(|p| in_batch.contains(p.name())) {
        let stages: Vec<String> = p
            .stages()
            .iter()
            .map(|s| format!("{} v{}", s.name(), s.spec().version))
            .collect();
        let effects: Vec<String> = p.effects().iter().map(|e| e.key()).collect();
        text.push_str(&format!(
            "\n{}: {}; {}",
            p.name(),
            stages.join(", "),
            effects.join(", ")
        ));
    }
    text
}

pub(super) fn observable_names(batch: &RecordBatch) -> BTreeSet<String> {
    use arrow::array::AsArray;
    let Some(a) = batch.column_by_name("observable") else {
        return BTreeSet::new();
    };
    let Ok(c) = arrow::compute::cast(a, &arrow::datatypes::DataType::Utf8) else {
        return BTreeSet::new();
    };
    // A run's rows come an observable at a time: a name is looked up once
    // per stretch of equal names and copied once per observable, not per row.
    let mut names = BTreeSet::new();
    let mut last: Option<&str> = None;
    for s in c.as_string::<i32>().iter().flatten() {
        if last != Some(s) {
            if !names.contains(s) {
                names.insert(s.to_string());
            }
            last = Some(s);
        }
    }
    names
}

/// The union of the runs' columns in first-seen order (different plugins
/// emit different covariates); a column is nullable where any run's is or
/// a run lacks it. Columns of one name must agree on their type.
pub fn union_schema<'a>(
    schemas: impl Iterator<Item = &'a arrow::datatypes::Schema> + Clone,
) -> Result<arrow::datatypes::Schema> {
    use arrow::datatypes::{Field, Schema};
    let mut fields: Vec<Field> = Vec::new();
    for s in schemas.clone() {
        for f in s.fields() {
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
        if schemas
            .clone()
            .any(|s| s.field_with_name(f.name()).is_err())
        {
            *f = f.clone().with_nullable(true);
        }
    }
    Ok(Schema::new(fields))
}

/// A run's batch with the columns of `union` (nulls where it lacks one).
pub fn conform(b: RecordBatch, union: &arrow::datatypes::SchemaRef) -> Result<RecordBatch> {
    let n = b.num_rows();
    let cols = union
        .fields()
        .iter()
        .map(|f| {
            b.column_by_name(f.name())
                .cloned()
                .unwrap_or_else(|| arrow::array::new_null_array(f.data_type(), n))
        })
        .collect();
    Ok(RecordBatch::try_new(union.clone(), cols)?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use arrow::array::{ArrayRef, Float64Array, StringArray};
    use arrow::datatypes::{Field, Schema};

    fn batch(cols: &[(&str, ArrayRef)]) -> RecordBatch {
        let fields: Vec<Field> = cols
            .iter()
            .map(|(n, a)| Field::new(*n, a.data_type().clone(), false))
            .collect();
        let arrays: Vec<ArrayRef> = cols.iter().map(|(_, a)| a.clone()).collect();
        RecordBatch::try_new(Arc::new(Schema::new(fields)), arrays).unwrap()
    }

    /// Streamed to a file one at a time, batches of differing columns read
    /// back as their union: columns in first-seen order, nullable where a
    /// batch lacks one, values and nulls.
    /// Every name once, whether the rows come in stretches or interleaved.
    #[test]
    fn observable_names_are_the_distinct_names_in_any_row_order() {
        let obs: ArrayRef = Arc::new(StringArray::from(vec![
            Some("a"),
            Some("a"),
            Some("b"),
            Some("a"),
            Some("c"),
            Some("c"),
            Some("b"),
        ]));
        let names: Vec<String> = observable_names(&batch(&[("observable", obs)]))
            .into_iter()
            .collect();
        assert_eq!(names, ["a", "b", "c"]);
    }

    #[test]
    fn a_union_streamed_to_a_file_is_the_union() {
        let f = |v: Vec<f64>| -> ArrayRef { Arc::new(Float64Array::from(v)) };
        let t = |v: Vec<&str>| -> ArrayRef { Arc::new(StringArray::from(v)) };
        let batches: Vec<RecordBatch> = (0..7)
            .map(|i| {
                let x = f(vec![i as f64; 3]);
                let run = t(vec!["r"; 3]);
                if i % 3 == 1 {
                    batch(&[("run", run), ("x", x), ("load_n", f(vec![1.0, 2.0, 3.0]))])
                } else {
                    batch(&[("run", run), ("x", x)])
                }
            })
            .collect();
        let union =
            Arc::new(union_schema(batches.iter().map(|b| b.schema_ref().as_ref())).unwrap());
        let conformed: Vec<RecordBatch> = batches
            .iter()
            .map(|b| conform(b.clone(), &union).unwrap())
            .collect();
        let whole = arrow::compute::concat_batches(&union, &conformed).unwrap();
        assert_eq!(whole.num_rows(), 21);
        assert!(whole
            .schema()
            .field_with_name("load_n")
            .unwrap()
            .is_nullable());
        // The streamed join: each batch conformed to the union schema and
        // written one after another reads back as the union.
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("observations.parquet");
        crate::contracts::write::write_parquet_batches_atomic(
            &path,
            union.clone(),
            conformed.into_iter().map(Ok),
        )
        .unwrap();
        assert_eq!(crate::contracts::read_parquet(&path).unwrap(), whole);
    }
}
