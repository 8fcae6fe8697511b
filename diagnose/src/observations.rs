//! observations.parquet (docs/formats.md §7): validated reading, and the
//! column-major table the diagnosis works on.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use arrow::array::{Array, ArrayRef, AsArray, Float64Array, RecordBatch};
use arrow::buffer::ScalarBuffer;
use arrow::compute::cast;
use arrow::datatypes::{DataType, Field, Schema};

use crate::run_length::RunLength;
use crate::units::Unit;
use crate::{InputError, Result};

/// Largest plausible |sim| or |real|: 10 m. Beyond it the table is in the
/// wrong unit (µm, nm) or corrupt — and a 1e300 would make the gap RMS inf.
pub const MAX_OBSERVED_MM: f64 = 1e4;

/// Columns that are never covariates (docs/formats.md §7, last paragraph;
/// `machine` (v1.1): a run is identified by machine and run;
/// `real_u` is the optional standard uncertainty of `real`, v1.1; `unit`
/// the optional unit of `sim`/`real`/`real_u` per observable, v1.1;
/// `sim_augmented` the sim side re-simulated with an augmented model's
/// effects in the plugin's physics, `run --augment`).
pub const RESERVED: [&str; 10] = [
    "machine",
    "run",
    "observable",
    "sim",
    "real",
    "trial",
    "point",
    "real_u",
    "unit",
    "sim_augmented",
];

/// The unit of an observable whose table has no `unit` column (docs/formats.md
/// §2: observations are in mm unless a `unit` column says otherwise).
pub const DEFAULT_UNIT: &str = "mm";

/// Reads observations.parquet (all row groups, concatenated) and validates it
/// per docs/formats.md §7: `run`/`observable` text (and `machine` when
/// present: optional, so a v1 table without it still diagnoses), `sim`/`real` float64
/// (float32 accepted and widened), no NaN/±inf in sim/real (the first bad row
/// is named), not empty. Extra columns are kept.
pub fn read_observations(path: &Path) -> Result<RecordBatch> {
    use crate::contracts::parquet_file::{open_parquet, read_all};
    let batch = read_all(path, open_parquet(path)?.with_batch_size(65_536))?;
    validate_observations(&normalise_types(batch, path)?, path)
}

/// Text written as large_utf8 / utf8-view / dictionary (pandas, polars) →
/// utf8, and sim/real written as integers or decimals → float64, with the
/// same checked conversion as every contract table (docs/formats.md).
pub(crate) fn normalise_types(batch: RecordBatch, path: &Path) -> Result<RecordBatch> {
    use crate::contracts::convert::{normalise, type_accepted, TimeOrigin};
    use crate::contracts::ColumnKind;
    let schema = batch.schema();
    let mut fields: Vec<Arc<Field>> = schema.fields().iter().cloned().collect();
    let mut cols: Vec<ArrayRef> = batch.columns().to_vec();
    for (i, f) in schema.fields().iter().enumerate() {
        let (kind, target) = match f.name().as_str() {
            "run" | "observable" | "machine" => (ColumnKind::Utf8, DataType::Utf8),
            "sim" | "real" => (ColumnKind::F64, DataType::Float64),
            _ => continue,
        };
        if f.data_type() == &target || !type_accepted(kind, f.name(), f.data_type()) {
            continue; // left to validate_observations (and its message)
        }
        cols[i] = normalise(path, f.name(), &cols[i], &target, &TimeOrigin::TableStart)?;
        fields[i] = Arc::new(Field::new(f.name(), target, f.is_nullable()));
    }
    Ok(RecordBatch::try_new(
        Arc::new(Schema::new_with_metadata(fields, schema.metadata().clone())),
        cols,
    )?)
}

/// Validation shared by the reader and `diagnose` (a batch built in memory
/// by the DAG is checked the same way). Returns the batch with sim/real as
/// float64.
pub fn validate_observations(batch: &RecordBatch, path: &Path) -> Result<RecordBatch> {
    if batch.num_rows() == 0 {
        return Err(InputError::new(path, "no observations (empty table)").into());
    }
    let schema = batch.schema();
    for name in ["machine", "run", "observable"] {
        let f = match schema.field_with_name(name) {
            Ok(f) => f,
            Err(_) if name == "machine" => continue,
            Err(_) => {
                return Err(InputError::new(path, "missing required column")
                    .column(name)
                    .into())
            }
        };
        if !matches!(f.data_type(), DataType::Utf8 | DataType::LargeUtf8) {
            return Err(InputError::new(
                path,
                format!("expected utf8 text, found {}", f.data_type()),
            )
            .column(name)
            .into());
        }
        let a = batch.column_by_name(name).expect("checked");
        if let Some(i) = (0..a.len()).find(|&i| a.is_null(i)) {
            return Err(InputError::new(path, "null value")
                .column(name)
                .row(i)
                .into());
        }
    }
    let units = check_units(batch, path)?;
    let mut fields: Vec<Arc<Field>> = schema.fields().iter().cloned().collect();
    let mut cols: Vec<ArrayRef> = batch.columns().to_vec();
    for name in ["sim", "real", "real_u", "sim_augmented"] {
        let optional = matches!(name, "real_u" | "sim_augmented");
        let (idx, f) = match schema.column_with_name(name) {
            Some(c) => c,
            None if optional => continue,
            None => {
                return Err(InputError::new(path, "missing required column")
                    .column(name)
                    .into())
            }
        };
        let a = match f.data_type() {
            DataType::Float64 => cols[idx].clone(),
            DataType::Float32 => cast(&cols[idx], &DataType::Float64)?,
            // The optional columns keep their own checks downstream.
            _ if optional => continue,
            t => {
                return Err(
                    InputError::new(path, format!("expected float64, found {t}"))
                        .column(name)
                        .into(),
                )
            }
        };
        let v = a.as_primitive::<arrow::datatypes::Float64Type>();
        // Converted values are kept only where a `unit` column may convert
        // them: a fleet's sim and real are 10⁷–10⁸ rows each.
        let converted = units
            .as_ref()
            .is_some_and(|u| u.iter().flatten().any(|u| *u != u.kind.canonical()));
        let mut out: Vec<Option<f64>> = Vec::with_capacity(if converted { v.len() } else { 0 });
        for i in 0..v.len() {
            if v.is_null(i) {
                if optional {
                    if converted {
                        out.push(None);
                    }
                    continue;
                }
                return Err(InputError::new(path, "null value")
                    .column(name)
                    .row(i)
                    .into());
            }
            let x = v.value(i);
            if !x.is_finite() {
                if optional {
                    if converted {
                        out.push(Some(x));
                    }
                    continue;
                }
                let what = if x.is_nan() { "NaN" } else { "infinite value" };
                return Err(InputError::new(path, format!("{what} in {name}"))
                    .column(name)
                    .row(i)
                    .into());
            }
            // Judged in the unit the row states: 5000 nm is 0.005 mm, not
            // an implausible 5000 mm.
            let unit = units.as_ref().and_then(|u| u[i]);
            let c = in_contract_unit(x, unit);
            if c.abs() > MAX_OBSERVED_MM && !optional {
                let msg = match unit.filter(|u| *u != u.kind.canonical()) {
                    Some(u) => format!(
                        "implausible value {x} {u} (= {c} {}; plausible for `{name}`: ±{MAX_OBSERVED_MM} {})",
                        u.kind.canonical(),
                        u.kind.canonical()
                    ),
                    None if units.is_some() => format!(
                        "implausible value {x} (plausible for `{name}`: ±{MAX_OBSERVED_MM} in the row's `unit`); state the values' unit in the `unit` column (nm, um, mm, …)"
                    ),
                    None => format!(
                        "implausible value {x} (plausible for `{name}`: ±{MAX_OBSERVED_MM} mm); values look like µm or nm — the contract's observations are in mm unless a `unit` column states another (nm, um, …)"
                    ),
                };
                return Err(InputError::new(path, msg).column(name).row(i).into());
            }
            if converted {
                out.push(Some(c));
            }
        }
        if optional && !converted {
            continue;
        }
        fields[idx] = Arc::new(Field::new(name, DataType::Float64, f.is_nullable()));
        cols[idx] = if converted {
            Arc::new(Float64Array::from(out))
        } else {
            a
        };
    }
    // The values are now in the contract's units: say so in `unit`, so
    // every later reader (the gap, augment, the reports) sees mm.
    if let (Some(units), Some((idx, _))) = (&units, schema.column_with_name("unit")) {
        if units.iter().flatten().any(|u| *u != u.kind.canonical()) {
            let text = cast(&cols[idx], &DataType::Utf8)?;
            let text = text.as_string::<i32>();
            let canon: arrow::array::StringArray = (0..text.len())
                .map(|i| match units[i] {
                    Some(u) if u != u.kind.canonical() => {
                        Some(u.kind.canonical().symbol.to_string())
                    }
                    _ => (!text.is_null(i)).then(|| text.value(i).to_string()),
                })
                .collect();
            fields[idx] = Arc::new(Field::new("unit", DataType::Utf8, true));
            cols[idx] = Arc::new(canon);
        }
    }
    // A covariate may be null ("not measured"), never NaN or ±inf: it would
    // poison every fit that uses it.
    for (f, col) in schema.fields().iter().zip(batch.columns()) {
        if !is_covariate(f.name(), f.data_type()) {
            continue;
        }
        if let Ok(c) = cast(col, &DataType::Float64) {
            let c = c.as_primitive::<arrow::datatypes::Float64Type>();
            if let Some(i) = (0..c.len()).find(|&i| !c.is_null(i) && !c.value(i).is_finite()) {
                let what = if c.value(i).is_nan() {
                    "NaN"
                } else {
                    "infinite value"
                };
                return Err(InputError::new(
                    path,
                    format!(
                        "{what} in covariate `{}` (use null for \"not measured\")",
                        f.name()
                    ),
                )
                .column(f.name())
                .row(i)
                .into());
            }
        }
    }
    Ok(RecordBatch::try_new(
        Arc::new(Schema::new_with_metadata(fields, schema.metadata().clone())),
        cols,
    )?)
}

/// Is this column a covariate? Any numeric column except the reserved ones.
pub fn is_covariate(name: &str, t: &DataType) -> bool {
    !RESERVED.contains(&name) && (t.is_integer() || t.is_floating())
}

/// The observations as the engine uses them: ids instead of strings,
/// covariates widened to f64, sorted names (deterministic order).
pub struct Table {
    pub n: usize,
    /// The run *units*: one per (machine, run), so `r0000` of two
    /// machines are two runs. Named `machine/run` when the table has a
    /// `machine` column, else by the bare run id.
    pub run_names: Vec<String>,
    /// Each run unit's `run` value as written (without the machine).
    pub run_bare: Vec<String>,
    /// Each row's run unit (an index into `run_names`).
    pub run: RunLength<u32>,
    /// Sorted machine ids ([""] without a `machine` column) and each row's
    /// index into them.
    pub machine_names: Vec<String>,
    pub machine: RunLength<u32>,
    /// Whether the table carried a `machine` column.
    pub has_machine: bool,
    pub obs_names: Vec<String>,
    pub obs: RunLength<u32>,
    /// Each observable's unit (index as `obs_names`): from the optional
    /// `unit` column, else "mm".
    pub obs_units: Vec<String>,
    /// Σ gap² and max |gap| over every row, summed in table order as the
    /// rows are indexed: the fleet's gap figures without a gap column as
    /// long as the fleet (8 B a row; the gap itself is read per
    /// observable with its covariates).
    pub gap_sums: GapSums,
    /// Each row's gap and the covariates with a finite value somewhere,
    /// read per observable (`gather`) from wherever the rows are: the
    /// input batch's buffers, a spill written as the fleet's rows were
    /// joined, or the fleet's observations file.
    pub values: Box<dyn RowValues>,
    /// Covariates dropped for non-finite values (reported as notes).
    pub dropped: Vec<String>,
    /// `trial` and `point` (i64::MIN where null).
    pub trial: Option<RunLength<i64>>,
    pub point: Option<RunLength<i64>>,
    /// `real_u`: each row's stated standard uncertainty of `real` (e.g. a
    /// logging resolution step/√12); NaN where not stated.
    pub real_u: Option<RunLength<f64>>,
}

/// A [`Table`] built from consecutive parts of one table (each indexed by
/// [`Table::from_batch`]): the fleet's keys are read in batches, never
/// concatenated. Names are ids in first-seen order until [`TableParts::finish`]
/// sorts them as [`Table::from_batch`] would have on the whole.
pub struct TableParts {
    path: PathBuf,
    acc: Option<Table>,
    /// Run units as (machine id, bare run) pairs, and their index.
    units: std::collections::HashMap<(u32, String), u32>,
    unit_keys: Vec<(u32, String)>,
    real_u: Option<RunLength<f64>>,
}

impl TableParts {
    pub fn new(path: &Path) -> TableParts {
        TableParts {
            path: path.to_path_buf(),
            acc: None,
            units: Default::default(),
            unit_keys: Vec::new(),
            real_u: None,
        }
    }

    /// Indexes and appends the next batch of rows, its types normalised
    /// and checked as a whole table's are ([`validate_observations`]);
    /// an error names a row of the batch.
    pub fn push_batch(&mut self, b: RecordBatch) -> Result<()> {
        let path = self.path.clone();
        let b = normalise_types(b, &path).and_then(|b| validate_observations(&b, &path))?;
        self.push(Table::from_batch(&b)?)
    }

    /// Appends the next part (rows after the previous parts'), indexed
    /// from a batch ([`Table::from_batch`]: its gap is in memory). The
    /// part's values are not kept: the whole table's are read later from
    /// wherever the rows are (`Table::values`).
    pub fn push(&mut self, part: Table) -> Result<()> {
        fn id_of(names: &mut Vec<String>, name: &str) -> u32 {
            match names.iter().position(|n| n == name) {
                Some(i) => i as u32,
                None => {
                    names.push(name.to_string());
                    (names.len() - 1) as u32
                }
            }
        }
        let acc = self.acc.get_or_insert_with(|| Table {
            n: 0,
            run_names: Vec::new(),
            run_bare: Vec::new(),
            run: RunLength::new(),
            machine_names: Vec::new(),
            machine: RunLength::new(),
            has_machine: part.has_machine,
            obs_names: Vec::new(),
            obs: RunLength::new(),
            obs_units: Vec::new(),
            gap_sums: GapSums::default(),
            values: Box::new(InMemory::default()),
            dropped: Vec::new(),
            trial: part.trial.as_ref().map(|_| RunLength::new()),
            point: part.point.as_ref().map(|_| RunLength::new()),
            real_u: None,
        });
        if self.real_u.is_none() && part.real_u.is_some() && acc.n == 0 {
            self.real_u = Some(RunLength::new());
        }
        let machine_map: Vec<u32> = part
            .machine_names
            .iter()
            .map(|m| id_of(&mut acc.machine_names, m))
            .collect();
        let mut obs_map = Vec::with_capacity(part.obs_names.len());
        for (o, unit) in part.obs_names.iter().zip(&part.obs_units) {
            let id = id_of(&mut acc.obs_names, o) as usize;
            if id == acc.obs_units.len() {
                acc.obs_units.push(unit.clone());
            } else if acc.obs_units[id] != *unit {
                return Err(InputError::new(
                    &self.path,
                    format!(
                        "observable `{o}` has unit `{unit}` in a later part of the table but `{}` before: one observable, one unit",
                        acc.obs_units[id]
                    ),
                )
                .column("unit")
                .into());
            }
            obs_map.push(id as u32);
        }
        // A part's run units, by their (machine, run) key.
        let mut unit_map = Vec::with_capacity(part.run_bare.len());
        let part_unit_machine: Vec<u32> = {
            let mut m = vec![0u32; part.run_bare.len()];
            for (u, mach) in part.run.iter().zip(part.machine.iter()) {
                m[u as usize] = mach;
            }
            m
        };
        for (u, bare) in part.run_bare.iter().enumerate() {
            let key = (machine_map[part_unit_machine[u] as usize], bare.clone());
            let next = self.unit_keys.len() as u32;
            let id = *self.units.entry(key.clone()).or_insert_with(|| {
                self.unit_keys.push(key);
                next
            });
            unit_map.push(id);
        }
        acc.n += part.n;
        acc.run.extend_mapped(&part.run, |u| unit_map[u as usize]);
        acc.machine
            .extend_mapped(&part.machine, |m| machine_map[m as usize]);
        acc.obs.extend_mapped(&part.obs, |o| obs_map[o as usize]);
        let Some(gap) = part.values.gap_column() else {
            unreachable!("a part indexed from a batch holds its gap");
        };
        acc.gap_sums.add(gap);
        if let (Some(a), Some(p)) = (acc.trial.as_mut(), part.trial.as_ref()) {
            a.extend_mapped(p, |v| v);
        }
        if let (Some(a), Some(p)) = (acc.point.as_mut(), part.point.as_ref()) {
            a.extend_mapped(p, |v| v);
        }
        if let (Some(a), Some(p)) = (self.real_u.as_mut(), part.real_u.as_ref()) {
            a.extend_mapped(p, |v| v);
        }
        Ok(())
    }

    /// The whole table, its names sorted and ids renumbered to match.
    pub fn finish(self) -> Result<Table> {
        let Some(mut t) = self.acc else {
            return Err(InputError::new(&self.path, "no observations (empty table)").into());
        };
        t.real_u = self.real_u;
        fn sorted_ids(names: &[String]) -> (Vec<String>, Vec<u32>) {
            let mut order: Vec<usize> = (0..names.len()).collect();
            order.sort_by(|&a, &b| names[a].cmp(&names[b]));
            let mut new_id = vec![0u32; names.len()];
            for (new, &old) in order.iter().enumerate() {
                new_id[old] = new as u32;
            }
            (order.iter().map(|&i| names[i].clone()).collect(), new_id)
        }
        let (machine_names, machine_id) = sorted_ids(&t.machine_names);
        let (obs_names, obs_id) = sorted_ids(&t.obs_names);
        t.obs_units = (0..obs_names.len())
            .map(|new| {
                let old = obs_id
                    .iter()
                    .position(|&i| i as usize == new)
                    .expect("a permutation");
                t.obs_units[old].clone()
            })
            .collect();
        t.machine = t.machine.map(|m| machine_id[m as usize]);
        t.obs = t.obs.map(|o| obs_id[o as usize]);
        // Run units in (machine, run) order, as from_batch numbers them.
        let keys: Vec<(u32, String)> = self
            .unit_keys
            .into_iter()
            .map(|(m, r)| (machine_id[m as usize], r))
            .collect();
        let mut order: Vec<usize> = (0..keys.len()).collect();
        order.sort_by(|&a, &b| keys[a].cmp(&keys[b]));
        let mut unit_id = vec![0u32; keys.len()];
        for (new, &old) in order.iter().enumerate() {
            unit_id[old] = new as u32;
        }
        t.run = t.run.map(|u| unit_id[u as usize]);
        t.run_bare = order.iter().map(|&i| keys[i].1.clone()).collect();
        t.run_names = order
            .iter()
            .map(|&i| {
                let (m, bare) = &keys[i];
                if t.has_machine {
                    format!("{}/{bare}", machine_names[*m as usize])
                } else {
                    bare.clone()
                }
            })
            .collect();
        t.machine_names = machine_names;
        t.obs_names = obs_names;
        Ok(t)
    }
}

impl Table {
    /// A text key column (`machine`, `run` or `observable`) over `rows`,
    /// from the ids: the values the input held (a run's id as written,
    /// without its machine).
    pub fn text_column(&self, name: &str, rows: &[usize]) -> ArrayRef {
        let (ids, names) = match name {
            "machine" => (&self.machine, &self.machine_names),
            "run" => (&self.run, &self.run_bare),
            "observable" => (&self.obs, &self.obs_names),
            other => unreachable!("`{other}` is not a key column"),
        };
        let text: Vec<&str> = ids
            .at(rows)
            .into_iter()
            .map(|id| names[id as usize].as_str())
            .collect();
        Arc::new(arrow::array::StringArray::from(text))
    }

    /// The observations of `rows` (ascending) as a batch the diagnosis
    /// accepts: the keys, each observable's unit, `sim` = 0 and `real` =
    /// the gap (so real − sim is the gap, bit for bit), the covariates
    /// (null where a row has none) and the optional numeric columns.
    pub fn rebuild(&self, rows: &[usize]) -> Result<RecordBatch> {
        use arrow::array::Int64Array;
        let mut fields: Vec<Field> = Vec::new();
        let mut cols: Vec<ArrayRef> = Vec::new();
        let mut keys = vec!["run", "observable"];
        if self.has_machine {
            keys.insert(0, "machine");
        }
        for k in keys {
            fields.push(Field::new(k, DataType::Utf8, false));
            cols.push(self.text_column(k, rows));
        }
        let unit: Vec<&str> = self
            .obs
            .at(rows)
            .into_iter()
            .map(|o| self.obs_units[o as usize].as_str())
            .collect();
        fields.push(Field::new("unit", DataType::Utf8, false));
        cols.push(Arc::new(arrow::array::StringArray::from(unit)));
        fields.push(Field::new("sim", DataType::Float64, false));
        cols.push(Arc::new(Float64Array::from(vec![0.0; rows.len()])));
        fields.push(Field::new("real", DataType::Float64, false));
        let values = self.values.gather(&self.obs, rows)?;
        cols.push(Arc::new(Float64Array::from(values.gap)));
        let floats = |v: Vec<f64>| -> ArrayRef {
            Arc::new(
                v.into_iter()
                    .map(|x| x.is_finite().then_some(x))
                    .collect::<Float64Array>(),
            )
        };
        for (name, v) in self.values.names().iter().zip(values.covariates) {
            fields.push(Field::new(name, DataType::Float64, true));
            cols.push(floats(v));
        }
        for (name, ints) in [("trial", &self.trial), ("point", &self.point)] {
            if let Some(ints) = ints {
                let v: Int64Array = ints
                    .at(rows)
                    .into_iter()
                    .map(|v| (v != i64::MIN).then_some(v))
                    .collect();
                fields.push(Field::new(name, DataType::Int64, true));
                cols.push(Arc::new(v));
            }
        }
        if let Some(u) = &self.real_u {
            fields.push(Field::new("real_u", DataType::Float64, true));
            cols.push(Arc::new(Float64Array::from(u.at(rows))));
        }
        Ok(RecordBatch::try_new(Arc::new(Schema::new(fields)), cols)?)
    }
}

/// Sorted distinct strings of a text column and each row's index into
/// them (no per-row allocation: 10⁶-row tables are common).
fn ids(a: &ArrayRef) -> (Vec<String>, Vec<u32>) {
    fn go<'a>(it: impl Iterator<Item = Option<&'a str>> + Clone) -> (Vec<String>, Vec<u32>) {
        let mut names: std::collections::BTreeMap<&str, u32> = std::collections::BTreeMap::new();
        // Looked up once per stretch of equal strings (a key column comes
        // in long stretches), not once per row.
        let mut previous: Option<&str> = None;
        for s in it.clone() {
            let s = s.unwrap_or("");
            if previous != Some(s) {
                names.entry(s).or_insert(0);
                previous = Some(s);
            }
        }
        for (i, v) in names.values_mut().enumerate() {
            *v = i as u32;
        }
        let mut last: (&str, u32) = ("", u32::MAX);
        let id = it
            .map(|s| {
                let s = s.unwrap_or("");
                if last.1 == u32::MAX || last.0 != s {
                    last = (s, names[s]);
                }
                last.1
            })
            .collect();
        (names.keys().map(|k| k.to_string()).collect(), id)
    }
    match a.data_type() {
        DataType::LargeUtf8 => go(a.as_string::<i64>().iter()),
        _ => go(a.as_string::<i32>().iter()),
    }
}

/// The optional `unit` column: text (null = mm), never empty, and one unit
/// per observable (a gap RMS over rows in mm and mm/s would mean nothing).
/// Returns each row's unit when it is one sparkout converts (nm, um, mm,
/// m; s, ms, us; mm/s, mm/min, um/s — docs/formats.md "Units"); `None` for
/// a unit it keeps as written (rad, N, …), or no `unit` column at all.
fn check_units(batch: &RecordBatch, path: &Path) -> Result<Option<Vec<Option<Unit>>>> {
    let Some(u) = batch.column_by_name("unit") else {
        return Ok(None);
    };
    let u = cast(u, &DataType::Utf8).map_err(|_| {
        InputError::new(path, format!("expected utf8 text, found {}", u.data_type())).column("unit")
    })?;
    let u = u.as_string::<i32>();
    let o = cast(
        batch.column_by_name("observable").expect("checked"),
        &DataType::Utf8,
    )?;
    let o = o.as_string::<i32>();
    let mut seen: std::collections::BTreeMap<&str, (&str, usize)> = Default::default();
    let mut parsed = Vec::with_capacity(u.len());
    // A row with the previous row's unit and observable passed the checks
    // as that row: rows come in long stretches of one observable, so each
    // stretch is parsed and looked up once, not each row.
    let mut previous: Option<(&str, &str, Option<Unit>)> = None;
    for i in 0..u.len() {
        // null = the default unit: a fleet table joins plugins that write
        // the column with plugins that do not.
        let unit = if u.is_null(i) {
            DEFAULT_UNIT
        } else {
            u.value(i).trim()
        };
        let obs = o.value(i);
        if let Some((pu, po, p)) = previous {
            if pu == unit && po == obs {
                parsed.push(p);
                continue;
            }
        }
        if unit.is_empty() {
            return Err(InputError::new(
                path,
                "empty unit (write null or leave the column out for mm, or name the unit)",
            )
            .column("unit")
            .row(i)
            .into());
        }
        let p = Unit::parse(unit);
        parsed.push(p);
        previous = Some((unit, obs, p));
        match seen.get(obs) {
            Some((first, at)) if *first != unit => {
                return Err(InputError::new(
                    path,
                    format!(
                        "observable `{obs}` has unit `{unit}` here but `{first}` at row {at}: one observable, one unit"
                    ),
                )
                .column("unit")
                .row(i)
                .into())
            }
            Some(_) => {}
            None => {
                seen.insert(obs, (unit, i));
            }
        }
    }
    Ok(Some(parsed))
}

/// A value in its row's stated unit, in the contract's (mm, s, mm/s);
/// a unit sparkout keeps as written (`None`) leaves it as it is.
fn in_contract_unit(x: f64, unit: Option<Unit>) -> f64 {
    unit.map_or(x, |u| u.to_canonical(x))
}

/// Each row's gap as the index computes it: real − sim, both read as f64
/// and converted from the row's stated unit to the contract's as
/// [`validate_observations`] converts them (the same bits); NaN where
/// either is missing or null — a table the index refuses. Reads the
/// batch's `real`, `sim`, and `unit` with `observable` when present.
pub(crate) fn gap_of(b: &RecordBatch, path: &Path) -> Result<Vec<f64>> {
    let b = normalise_types(b.clone(), path)?;
    let units = match b.column_by_name("observable") {
        Some(_) => check_units(&b, path)?,
        None => None,
    };
    let f64s = |name: &str| -> Option<Float64Array> {
        let c = cast(b.column_by_name(name)?, &DataType::Float64).ok()?;
        Some(c.as_primitive::<arrow::datatypes::Float64Type>().clone())
    };
    let (Some(real), Some(sim)) = (f64s("real"), f64s("sim")) else {
        return Ok(vec![f64::NAN; b.num_rows()]);
    };
    let canonical = |v: &Float64Array, i: usize| {
        in_contract_unit(v.value(i), units.as_ref().and_then(|u| u[i]))
    };
    Ok((0..b.num_rows())
        .map(|i| {
            if real.is_null(i) || sim.is_null(i) {
                f64::NAN
            } else {
                canonical(&real, i) - canonical(&sim, i)
            }
        })
        .collect())
}

/// Each observable's unit (validated by `check_units`), "mm" without a
/// `unit` column.
fn observable_units(b: &RecordBatch, obs_names: &[String], obs: &[u32]) -> Vec<String> {
    let mut units = vec![DEFAULT_UNIT.to_string(); obs_names.len()];
    let Some(u) = b.column_by_name("unit") else {
        return units;
    };
    let Ok(u) = cast(u, &DataType::Utf8) else {
        return units;
    };
    let u = u.as_string::<i32>();
    let mut done = vec![false; obs_names.len()];
    for (i, &k) in obs.iter().enumerate() {
        let k = k as usize;
        if !done[k] && !u.is_null(i) {
            units[k] = u.value(i).trim().to_string();
            done[k] = true;
        }
    }
    units
}

/// A numeric column as f64, nulls as NaN. A Float64 column without nulls
/// (what sparkout and pandas write) shares the batch's buffer instead of
/// being copied: a fleet's covariates are most of the diagnosis' memory.
fn f64s(a: &ArrayRef) -> Result<ScalarBuffer<f64>> {
    let c = cast(a, &DataType::Float64)?;
    let v = c.as_any().downcast_ref::<Float64Array>().expect("cast");
    if v.null_count() == 0 {
        return Ok(v.values().clone());
    }
    Ok((0..v.len())
        .map(|i| if v.is_null(i) { f64::NAN } else { v.value(i) })
        .collect())
}

impl Table {
    /// From a validated batch.
    pub fn from_batch(b: &RecordBatch) -> Result<Table> {
        let (bare_names, bare_run) = ids(b.column_by_name("run").expect("validated"));
        let (machine_names, machine, has_machine) = match b.column_by_name("machine") {
            Some(a) => {
                let (names, id) = ids(a);
                (names, id, true)
            }
            None => (vec![String::new()], vec![0; b.num_rows()], false),
        };
        // Run unit = (machine, run), ids in sorted (machine, run) order.
        let mut pairs: std::collections::BTreeMap<(u32, u32), u32> = Default::default();
        let mut previous = None;
        for (m, r) in machine.iter().zip(&bare_run) {
            if previous != Some((*m, *r)) {
                pairs.entry((*m, *r)).or_insert(0);
                previous = Some((*m, *r));
            }
        }
        let mut run_names = Vec::with_capacity(pairs.len());
        let mut run_bare = Vec::with_capacity(pairs.len());
        for (i, ((m, r), v)) in pairs.iter_mut().enumerate() {
            *v = i as u32;
            let bare = &bare_names[*r as usize];
            run_bare.push(bare.clone());
            run_names.push(if has_machine {
                format!("{}/{bare}", machine_names[*m as usize])
            } else {
                bare.clone()
            });
        }
        let mut previous = None;
        let run: RunLength<u32> = machine
            .iter()
            .zip(&bare_run)
            .map(|(m, r)| match previous {
                Some((key, unit)) if key == (*m, *r) => unit,
                _ => {
                    let unit = pairs[&(*m, *r)];
                    previous = Some(((*m, *r), unit));
                    unit
                }
            })
            .collect();
        let (obs_names, obs) = ids(b.column_by_name("observable").expect("validated"));
        let obs_units = observable_units(b, &obs_names, &obs);
        let sim = f64s(b.column_by_name("sim").expect("validated"))?;
        let real = f64s(b.column_by_name("real").expect("validated"))?;
        let gap: Vec<f64> = real.iter().zip(&sim).map(|(r, s)| r - s).collect();
        let mut gap_sums = GapSums::default();
        gap_sums.add(&gap);
        let mut covs = Vec::new();
        let mut dropped = Vec::new();
        let schema = b.schema();
        for (i, f) in schema.fields().iter().enumerate() {
            if !is_covariate(f.name(), f.data_type()) {
                continue;
            }
            let v = f64s(b.column(i))?;
            // Nulls are legal where a covariate does not apply to a row's
            // observable; the diagnosis decides per observable. A covariate
            // with no finite value at all is dropped here.
            if v.iter().any(|x| x.is_finite()) {
                covs.push((f.name().clone(), v));
            } else {
                dropped.push(f.name().clone());
            }
        }
        covs.sort_by(|a, b| a.0.cmp(&b.0));
        dropped.sort();
        let values = Box::new(InMemory {
            names: covs.iter().map(|(n, _)| n.clone()).collect(),
            columns: covs.into_iter().map(|(_, v)| v).collect(),
            gap,
        });
        let int = |name: &str| -> Result<Option<RunLength<i64>>> {
            match b.column_by_name(name) {
                Some(a) if a.data_type().is_integer() || a.data_type().is_floating() => Ok(Some(
                    f64s(a)?
                        .iter()
                        .map(|v| if v.is_finite() { *v as i64 } else { i64::MIN })
                        .collect(),
                )),
                _ => Ok(None),
            }
        };
        Ok(Table {
            n: b.num_rows(),
            run_names,
            run_bare,
            run,
            machine_names,
            machine: machine.into_iter().collect(),
            has_machine,
            obs_names,
            obs: obs.into_iter().collect(),
            obs_units,
            gap_sums,
            values,
            dropped,
            trial: int("trial")?,
            point: int("point")?,
            real_u: match b.column_by_name("real_u") {
                Some(a) if a.data_type().is_floating() || a.data_type().is_integer() => {
                    Some(f64s(a)?.iter().copied().collect())
                }
                _ => None,
            },
        })
    }
}

/// Where the diagnosis reads each row's gap and covariates: by table row,
/// one observable at a time, so neither the fleet's covariates nor its
/// gap need be in memory at once.
pub trait RowValues: Send + Sync {
    /// The covariates, sorted by name: those with a finite value somewhere.
    fn names(&self) -> &[String];
    /// The gap and every covariate's values (in [`RowValues::names`]
    /// order) on the table rows `asc` (ascending); NaN where a row has no
    /// covariate value. `obs` is the table's observable id per row (a
    /// source may keep each observable's rows apart).
    fn gather(&self, obs: &RunLength<u32>, asc: &[usize]) -> Result<Gathered>;
    /// [`RowValues::gather`] handed to `sink` a chunk of rows at a time,
    /// in order: `sink(first position in asc, gap, covariates)`. A source
    /// that cannot stream gathers once and hands over everything.
    fn gather_chunks(
        &self,
        obs: &RunLength<u32>,
        asc: &[usize],
        sink: &mut ChunkSink,
    ) -> Result<()> {
        sink_whole(self.gather(obs, asc)?, sink)
    }
    /// A covariate's whole column where it is held in memory.
    fn column(&self, _name: &str) -> Option<&[f64]> {
        None
    }
    /// The whole gap column where it is held in memory.
    fn gap_column(&self) -> Option<&[f64]> {
        None
    }
}

/// Rows gathered whole handed to `sink` as one chunk.
pub fn sink_whole(g: Gathered, sink: &mut ChunkSink) -> Result<()> {
    sink(0, &g.gap, &g.covariates)
}

/// Where [`RowValues::gather_chunks`] hands each chunk: (its first
/// position among the rows asked for, gaps, covariates).
pub type ChunkSink<'a> = dyn FnMut(usize, &[f64], &[Vec<f64>]) -> Result<()> + 'a;

/// What [`RowValues::gather`] reads for a set of rows, in their order.
pub struct Gathered {
    /// real − sim.
    pub gap: Vec<f64>,
    /// Per covariate (in [`RowValues::names`] order).
    pub covariates: Vec<Vec<f64>>,
}

/// Σ gap² and max |gap| of a table, added row by row in table order (the
/// same bits whether the rows come in one batch or many).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct GapSums {
    pub sum_sq: f64,
    pub max_abs: f64,
}

impl GapSums {
    /// Adds the next rows' gaps.
    pub fn add(&mut self, gap: &[f64]) {
        for g in gap {
            self.sum_sq += g * g;
            self.max_abs = self.max_abs.max(g.abs());
        }
    }
}

/// The rows' values held in memory: the input batch's buffers, shared
/// where they are Float64 without nulls (a fleet's covariates are most of
/// the diagnosis' memory), and the gap.
#[derive(Default)]
pub struct InMemory {
    names: Vec<String>,
    columns: Vec<ScalarBuffer<f64>>,
    gap: Vec<f64>,
}

impl RowValues for InMemory {
    fn names(&self) -> &[String] {
        &self.names
    }
    fn gather(&self, _obs: &RunLength<u32>, asc: &[usize]) -> Result<Gathered> {
        use rayon::prelude::*;
        Ok(Gathered {
            gap: asc.iter().map(|&i| self.gap[i]).collect(),
            covariates: self
                .columns
                .par_iter()
                .map(|v| asc.iter().map(|&i| v[i]).collect())
                .collect(),
        })
    }
    fn gap_column(&self) -> Option<&[f64]> {
        Some(&self.gap)
    }
    fn column(&self, name: &str) -> Option<&[f64]> {
        let i = self.names.iter().position(|n| n == name)?;
        Some(&self.columns[i][..])
    }
}
