//! The diagnosis of an observations file too large to hold: the keys are
//! read once into the [`Table`] (ids, a few stretches per run; the gap's
//! fleet sums), each row's gap and covariates one observable at a time
//! ([`ParquetValues`], or [`RowValueSpill`] written as the fleet's rows
//! were joined), so neither the fleet's covariates nor its gap are ever
//! all in memory (docs/scale.md).

use std::fs::File;
use std::path::{Path, PathBuf};

use arrow::array::{Array, AsArray, RecordBatch};
use arrow::compute::cast;
use arrow::datatypes::{DataType, Float64Type};
use parquet::arrow::arrow_reader::{ArrowReaderMetadata, ParquetRecordBatchReaderBuilder};
use parquet::arrow::ProjectionMask;

use crate::config_check::Checked;
use crate::contracts::parquet_file::{checked_batches, corrupt_page, open_parquet};
use crate::observations::{
    gap_of, is_covariate, ChunkSink, Gathered, RowValues, Table, TableParts,
};
use crate::run_length::RunLength;
use crate::{DiagnoseConfig, DiagnosisOutput, EffectScope, InputError, Result};

/// Rows per batch read from the file.
const READ_ROWS: usize = 1 << 16;

/// Diagnoses the observations in the Parquet file `path` (the contract of
/// docs/formats.md §7) without holding its covariates: the same diagnosis,
/// byte for byte, as [`crate::diagnose_checked`] on the file read whole.
/// `spilled`: each row's gap and covariates kept apart per observable as
/// the file was written ([`RowValueSpill`]), read instead of the file's
/// columns when given. `results_dir`: where the per-row results wait for
/// diagnosis.parquet ([`crate::diagnose_table`]). `progress` is told each
/// observable as its diagnosis starts.
pub fn diagnose_observations_file(
    path: &Path,
    cfg: &Checked<DiagnoseConfig>,
    scopes: &[EffectScope],
    mut spilled: Option<Spilled>,
    results_dir: Option<&Path>,
    progress: &dyn Fn(&str),
) -> Result<DiagnosisOutput> {
    let file = match spilled.as_mut().and_then(|s| s.index.take()) {
        Some(table) => IndexedFile {
            path: path.to_path_buf(),
            table,
        },
        None => index_observations_file(path)?,
    };
    diagnose_indexed(file, cfg, scopes, spilled, results_dir, progress)
}

/// The columns an index reads: every one but the covariates (keys, sim,
/// real, unit, …).
fn key_columns(schema: &arrow::datatypes::Schema) -> Vec<usize> {
    schema
        .fields()
        .iter()
        .enumerate()
        .filter(|(_, f)| !is_covariate(f.name(), f.data_type()))
        .map(|(i, _)| i)
        .collect()
}

/// The keys, sim and real of the Parquet file `path`, read batch by batch
/// into a [`Table`] (never the file's text columns at once), each batch
/// checked as [`crate::read_observations`] checks the whole table (text
/// as large_utf8 or dictionary and integer sim/real accepted; a bad row is
/// named by its row in the file). The gap is summed as the rows pass; it
/// and the covariates stay in the file: [`diagnose_indexed`] reads them
/// one observable at a time.
pub fn index_observations_file(path: &Path) -> Result<IndexedFile> {
    let builder = open_parquet(path)?;
    let meta = builder.metadata().clone();
    let mask = ProjectionMask::roots(builder.parquet_schema(), key_columns(builder.schema()));
    let mut parts = TableParts::new(path);
    let mut offset = 0usize;
    let reader = builder
        .with_projection(mask)
        .with_batch_size(READ_ROWS)
        .build()
        .map_err(|e| corrupt_page(path, &meta, 0, e))?;
    for b in checked_batches(path, &meta, 0, reader) {
        let b = b?;
        let n = b.num_rows();
        let at_row = |e: crate::Error| match e.input() {
            Some(i) if i.row.is_some() => {
                let mut i = i.clone();
                i.row = i.row.map(|r| r + offset);
                i.into()
            }
            _ => e,
        };
        parts.push_batch(b).map_err(at_row)?;
        offset += n;
    }
    Ok(IndexedFile {
        path: path.to_path_buf(),
        table: parts.finish()?,
    })
}

/// A file's table indexed by [`index_observations_file`], its gap and
/// covariates still in the file.
pub struct IndexedFile {
    path: PathBuf,
    table: Table,
}

impl IndexedFile {
    /// The observables of the file, sorted.
    pub fn observables(&self) -> &[String] {
        &self.table.obs_names
    }
}

/// Diagnoses an indexed file, each row's gap and covariates read from
/// `spilled` when given, else from the file's columns ([`ParquetValues`]);
/// the per-row results wait in `results_dir` when given
/// ([`crate::diagnose_table`]).
pub fn diagnose_indexed(
    file: IndexedFile,
    cfg: &Checked<DiagnoseConfig>,
    scopes: &[EffectScope],
    spilled: Option<Spilled>,
    results_dir: Option<&Path>,
    progress: &dyn Fn(&str),
) -> Result<DiagnosisOutput> {
    let IndexedFile { path, mut table } = file;
    match spilled {
        Some(spilled) => {
            let values = SpilledValues::new(spilled, &table.obs_names);
            table.dropped = values.dropped();
            table.values = Box::new(values);
        }
        None => {
            let values = ParquetValues::open(&path)?;
            table.dropped = values.dropped.clone();
            table.values = Box::new(values);
        }
    }
    crate::diagnose_table(table, cfg, scopes, results_dir, progress)
}

/// Each row's gap (real − sim, read as the index read them) and
/// covariates read from a Parquet file by table row (its row order), one
/// call per observable: the row groups that hold none of the rows are
/// skipped, and each covariate value is checked as the in-memory path
/// checks it (null = "not measured", never NaN or ±inf).
pub struct ParquetValues {
    path: PathBuf,
    /// Covariates with a finite value somewhere, sorted by name, and each
    /// one's column index in the file.
    names: Vec<String>,
    indices: Vec<usize>,
    /// The file's columns the gap is computed from: `real`, `sim`, and
    /// `unit` with `observable` when the file states units.
    gap_columns: Vec<usize>,
    /// Covariates with no value at all (every row null).
    dropped: Vec<String>,
    /// First table row of each row group.
    group_starts: Vec<usize>,
}

impl ParquetValues {
    pub fn open(path: &Path) -> Result<ParquetValues> {
        let builder = open_parquet(path)?;
        let meta = builder.metadata().clone();
        let schema = builder.schema().clone();
        let mut group_starts = Vec::with_capacity(meta.num_row_groups());
        let mut at = 0usize;
        for g in meta.row_groups() {
            group_starts.push(at);
            at += g.num_rows() as usize;
        }
        let mut named: Vec<(String, usize)> = Vec::new();
        let mut dropped: Vec<String> = Vec::new();
        let descr = meta.file_metadata().schema_descr();
        for (i, f) in schema.fields().iter().enumerate() {
            if !is_covariate(f.name(), f.data_type()) {
                continue;
            }
            // Every row null ⇔ no finite value (a non-null NaN or ±inf is
            // refused when read), known from the chunks' null counts where
            // the writer kept them; otherwise read.
            let leaf = (0..descr.num_columns()).find(|&j| descr.get_column_root_idx(j) == i);
            let all_null = match leaf.and_then(|leaf| {
                meta.row_groups().iter().try_fold(true, |all, g| {
                    let c = g.column(leaf);
                    let nulls = c.statistics().and_then(|s| s.null_count_opt())?;
                    Some(all && nulls == g.num_rows() as u64)
                })
            }) {
                Some(all) => all,
                None => column_all_null(path, i)?,
            };
            if all_null {
                dropped.push(f.name().clone());
            } else {
                named.push((f.name().clone(), i));
            }
        }
        named.sort();
        dropped.sort();
        let indices: Vec<usize> = named.iter().map(|(_, i)| *i).collect();
        let column = |name: &str| {
            schema.index_of(name).map_err(|_| {
                crate::Error::from(InputError::new(path, "missing required column").column(name))
            })
        };
        Ok(ParquetValues {
            path: path.to_path_buf(),
            names: named.into_iter().map(|(n, _)| n).collect(),
            indices,
            gap_columns: {
                let mut c = vec![column("real")?, column("sim")?];
                if let Ok(unit) = schema.index_of("unit") {
                    c.extend([unit, column("observable")?]);
                }
                c
            },
            dropped,
            group_starts,
        })
    }
}

fn column_all_null(path: &Path, i: usize) -> Result<bool> {
    let builder = open_parquet(path)?;
    let meta = builder.metadata().clone();
    let mask = ProjectionMask::roots(builder.parquet_schema(), [i]);
    let reader = builder
        .with_projection(mask)
        .build()
        .map_err(|e| corrupt_page(path, &meta, 0, e))?;
    for b in checked_batches(path, &meta, 0, reader) {
        let b = b?;
        if b.column(0).null_count() < b.num_rows() {
            return Ok(false);
        }
    }
    Ok(true)
}

impl RowValues for ParquetValues {
    fn names(&self) -> &[String] {
        &self.names
    }

    fn gather(&self, obs: &RunLength<u32>, asc: &[usize]) -> Result<Gathered> {
        let k = self.names.len();
        let mut covariates: Vec<Vec<f64>> = (0..k).map(|_| Vec::with_capacity(asc.len())).collect();
        let mut gap = Vec::with_capacity(asc.len());
        self.gather_chunks(obs, asc, &mut |_, g, cs| {
            gap.extend_from_slice(g);
            for (all, c) in covariates.iter_mut().zip(cs) {
                all.extend_from_slice(c);
            }
            Ok(())
        })?;
        Ok(Gathered { gap, covariates })
    }

    /// A batch of the file's rows at a time: the rows of `asc` it holds.
    fn gather_chunks(
        &self,
        _obs: &RunLength<u32>,
        asc: &[usize],
        sink: &mut ChunkSink,
    ) -> Result<()> {
        let k = self.names.len();
        let mut covariates: Vec<Vec<f64>> = vec![Vec::new(); k];
        let mut gap = Vec::new();
        if asc.is_empty() {
            return Ok(());
        }
        // The row groups holding any of the rows, and where each starts.
        let last = |g: usize| self.group_starts.get(g + 1).copied().unwrap_or(usize::MAX);
        let mut groups = Vec::new();
        let mut p = 0;
        for g in 0..self.group_starts.len() {
            while p < asc.len() && asc[p] < self.group_starts[g] {
                p += 1;
            }
            if p < asc.len() && asc[p] < last(g) {
                groups.push(g);
            }
        }
        let file = File::open(&self.path)
            .map_err(|e| InputError::new(&self.path, format!("cannot open: {e}")))?;
        let meta = ArrowReaderMetadata::load(&file, Default::default())?;
        let file_schema = meta.schema().clone();
        // A projected batch holds the columns in file order.
        let mut projected: Vec<usize> = self
            .indices
            .iter()
            .chain(&self.gap_columns)
            .copied()
            .collect();
        projected.sort_unstable();
        projected.dedup();
        let at = |i: usize| projected.binary_search(&i).expect("projected");
        let mask = ProjectionMask::roots(meta.parquet_schema(), projected.clone());
        for g in groups {
            let reader =
                ParquetRecordBatchReaderBuilder::new_with_metadata(file.try_clone()?, meta.clone())
                    .with_projection(mask.clone())
                    .with_row_groups(vec![g])
                    .with_batch_size(READ_ROWS)
                    .build()?;
            let mut offset = self.group_starts[g];
            let mut p = asc.partition_point(|&r| r < offset);
            for b in checked_batches(&self.path, meta.metadata(), offset, reader) {
                let b = b?;
                let n = b.num_rows();
                let from = p;
                while p < asc.len() && asc[p] < offset + n {
                    p += 1;
                }
                offset += n;
                if from == p {
                    continue;
                }
                let base = offset - n;
                let batch_gap = gap_of(&b, &self.path)?;
                gap.clear();
                covariates.iter_mut().for_each(Vec::clear);
                gap.extend(asc[from..p].iter().map(|&r| batch_gap[r - base]));
                for (j, &i) in self.indices.iter().enumerate() {
                    let name = file_schema.field(i).name();
                    let col = cast(b.column(at(i)), &DataType::Float64)?;
                    let v = col.as_primitive::<Float64Type>();
                    for &r in &asc[from..p] {
                        let i = r - base;
                        if v.is_null(i) {
                            covariates[j].push(f64::NAN);
                            continue;
                        }
                        let x = v.value(i);
                        if !x.is_finite() {
                            let what = if x.is_nan() { "NaN" } else { "infinite value" };
                            return Err(InputError::new(
                                &self.path,
                                format!(
                                    "{what} in covariate `{name}` (use null for \"not measured\")"
                                ),
                            )
                            .column(name)
                            .row(r)
                            .into());
                        }
                        covariates[j].push(x);
                    }
                }
                sink(from, &gap, &covariates)?;
            }
        }
        Ok(())
    }
}

/// Each row's gap and covariates as the fleet's join streams past, kept
/// apart per observable on disk (raw little-endian f64, a record per row
/// — the gap, then every covariate — in table order) so the diagnosis
/// reads each observable's rows once instead of decoding the whole
/// observations file per observable, and holds no gap column for the
/// fleet. The files live in a hidden folder of the output the join writes
/// to and go when the [`Spilled`] values are dropped.
pub struct RowValueSpill {
    dir: PathBuf,
    covariates: Vec<String>,
    /// Per observable, in first-seen order: its name, writer and file;
    /// and each name's place there.
    writers: Vec<(String, std::io::BufWriter<File>, PathBuf)>,
    writer_of: std::collections::BTreeMap<String, usize>,
    any_finite: Vec<bool>,
    /// The table's index built from the rows as they pass
    /// ([`RowValueSpill::indexing`]), so the diagnosis need not decode the
    /// file just written to index it; None once a batch fails to index
    /// (the file is indexed instead, and its errors name its rows).
    index: Option<TableParts>,
}

impl RowValueSpill {
    /// A spill under `dir` (created empty) for the covariates of `schema`
    /// (the joined table's).
    pub fn create(dir: &Path, schema: &arrow::datatypes::Schema) -> Result<RowValueSpill> {
        if dir.exists() {
            std::fs::remove_dir_all(dir)?;
        }
        std::fs::create_dir_all(dir)?;
        let covariates: Vec<String> = schema
            .fields()
            .iter()
            .filter(|f| is_covariate(f.name(), f.data_type()))
            .map(|f| f.name().clone())
            .collect();
        Ok(RowValueSpill {
            dir: dir.to_path_buf(),
            any_finite: vec![false; covariates.len()],
            covariates,
            writers: Vec::new(),
            writer_of: Default::default(),
            index: None,
        })
    }

    /// Also index the rows as they pass, as [`index_observations_file`]
    /// would index `table_path` (the file the same batches are written
    /// to, which errors name): the index is handed over with the
    /// [`Spilled`] values.
    pub fn indexing(mut self, table_path: &Path) -> RowValueSpill {
        self.index = Some(TableParts::new(table_path));
        self
    }

    /// Indexes a batch's keys, sim and real (not its covariates, as
    /// [`index_observations_file`] projects them away); a batch that does
    /// not index gives the index up.
    fn index_batch(&mut self, b: &RecordBatch) {
        let Some(parts) = &mut self.index else {
            return;
        };
        let indexed = b
            .project(&key_columns(&b.schema()))
            .map_err(crate::Error::from)
            .and_then(|b| parts.push_batch(b));
        if indexed.is_err() {
            self.index = None;
        }
    }

    /// Appends a batch's rows (read from `source`, which errors name): the
    /// gap (real − sim as the diagnosis' index reads them; NaN where
    /// either is missing — such a table is refused when indexed), then the
    /// covariates as f64, NaN where null; a NaN or ±inf covariate is
    /// refused.
    pub fn push(&mut self, b: &RecordBatch, source: &Path) -> Result<()> {
        use std::io::Write;
        let Some(obs) = b.column_by_name("observable") else {
            return Err(InputError::new(source, "missing required column")
                .column("observable")
                .into());
        };
        let obs = cast(obs, &DataType::Utf8)?;
        let obs = obs.as_string::<i32>();
        let cols: Vec<Option<arrow::array::ArrayRef>> = self
            .covariates
            .iter()
            .map(|c| {
                b.column_by_name(c)
                    .map(|a| cast(a, &DataType::Float64))
                    .transpose()
            })
            .collect::<std::result::Result<_, _>>()?;
        let cols: Vec<Option<&arrow::array::Float64Array>> = cols
            .iter()
            .map(|c| c.as_ref().map(|a| a.as_primitive::<Float64Type>()))
            .collect();
        let gap = gap_of(b, source)?;
        let mut record: Vec<u8> = Vec::with_capacity(8 * (1 + cols.len()));
        // The writer of the previous row's observable: looked up once per
        // stretch of one observable, not once per row.
        let mut current: Option<(&str, usize)> = None;
        for (i, g) in gap.iter().enumerate() {
            let o = if obs.is_null(i) { "" } else { obs.value(i) };
            record.clear();
            record.extend_from_slice(&g.to_le_bytes());
            for (k, c) in cols.iter().enumerate() {
                let x = match c {
                    Some(c) if !c.is_null(i) => {
                        let x = c.value(i);
                        if !x.is_finite() {
                            let what = if x.is_nan() { "NaN" } else { "infinite value" };
                            let name = &self.covariates[k];
                            return Err(InputError::new(
                                source,
                                format!(
                                    "{what} in covariate `{name}` (use null for \"not measured\")"
                                ),
                            )
                            .column(name)
                            .row(i)
                            .into());
                        }
                        self.any_finite[k] = true;
                        x
                    }
                    _ => f64::NAN,
                };
                record.extend_from_slice(&x.to_le_bytes());
            }
            let at = match current {
                Some((name, at)) if name == o => at,
                _ => {
                    let at = match self.writer_of.get(o) {
                        Some(&at) => at,
                        None => {
                            let path = self.dir.join(format!("{}.f64", self.writers.len()));
                            let f = File::create(&path)?;
                            self.writers.push((
                                o.to_string(),
                                std::io::BufWriter::with_capacity(1 << 20, f),
                                path,
                            ));
                            self.writer_of.insert(o.to_string(), self.writers.len() - 1);
                            self.writers.len() - 1
                        }
                    };
                    current = Some((o, at));
                    at
                }
            };
            self.writers[at].1.write_all(&record)?;
        }
        self.index_batch(b);
        Ok(())
    }

    /// The spilled values, flushed.
    pub fn finish(self) -> Result<Spilled> {
        use std::io::Write;
        let mut files = std::collections::BTreeMap::new();
        for (o, mut w, path) in self.writers {
            w.flush()?;
            files.insert(o, path);
        }
        Ok(Spilled {
            dir: self.dir,
            covariates: self.covariates,
            files,
            any_finite: self.any_finite,
            index: self.index.and_then(|p| p.finish().ok()),
        })
    }
}

/// Gaps and covariates spilled per observable ([`RowValueSpill`]);
/// removed from disk when dropped.
pub struct Spilled {
    dir: PathBuf,
    covariates: Vec<String>,
    files: std::collections::BTreeMap<String, PathBuf>,
    any_finite: Vec<bool>,
    /// The table's index, when built as the rows passed.
    pub(crate) index: Option<Table>,
}

impl Drop for Spilled {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

/// [`RowValues`] read from a [`Spilled`]: an observable's rows from its
/// own file, in one sequential read.
struct SpilledValues {
    spilled: Spilled,
    /// Covariates with a finite value somewhere, sorted, and each one's
    /// place in a record (after the gap).
    names: Vec<String>,
    at: Vec<usize>,
    /// The file of each table observable id.
    file_of: Vec<Option<PathBuf>>,
}

impl SpilledValues {
    fn new(spilled: Spilled, obs_names: &[String]) -> SpilledValues {
        let mut named: Vec<(String, usize)> = spilled
            .covariates
            .iter()
            .enumerate()
            .filter(|(k, _)| spilled.any_finite[*k])
            .map(|(k, c)| (c.clone(), k))
            .collect();
        named.sort();
        let file_of = obs_names
            .iter()
            .map(|o| spilled.files.get(o).cloned())
            .collect();
        SpilledValues {
            names: named.iter().map(|(n, _)| n.clone()).collect(),
            at: named.iter().map(|(_, k)| *k).collect(),
            spilled,
            file_of,
        }
    }

    fn dropped(&self) -> Vec<String> {
        let mut d: Vec<String> = self
            .spilled
            .covariates
            .iter()
            .zip(&self.spilled.any_finite)
            .filter(|(_, f)| !**f)
            .map(|(c, _)| c.clone())
            .collect();
        d.sort();
        d
    }
}

impl SpilledValues {
    /// Reads the records `want` (stretches of ranks, ascending) of the
    /// spill file `path`: `f(position, value)`, `value(i)` the record's
    /// i-th number (0: the gap, 1 + k: covariate k of the spill).
    fn each_record(
        &self,
        path: &Path,
        want: &[Wanted],
        mut f: impl FnMut(usize, &dyn Fn(usize) -> f64) -> Result<()>,
    ) -> Result<()> {
        use std::io::Read;
        let width = 1 + self.spilled.covariates.len();
        let mut r = std::io::BufReader::with_capacity(1 << 20, File::open(path)?);
        let mut record = vec![0u8; 8 * width];
        let mut rank = 0usize;
        for w in want {
            while rank < w.ranks.start {
                r.read_exact(&mut record)?;
                rank += 1;
            }
            for pos in w.pos..w.pos + w.ranks.len() {
                r.read_exact(&mut record)?;
                rank += 1;
                let value = |at: usize| {
                    f64::from_le_bytes(record[8 * at..8 * at + 8].try_into().expect("8 bytes"))
                };
                f(pos, &value)?;
            }
        }
        Ok(())
    }
}

/// Per observable id (of `n_obs`): the rows `asc` (ascending) as
/// stretches of their ranks among the observable's rows (its records)
/// and where each stretch starts in `asc`. An observable's rows lie in a
/// few stretches a run, so this is a few numbers a run where a pair per
/// row was 16 B of every row gathered (the gather's peak).
fn wanted_of(n_obs: usize, obs: &RunLength<u32>, asc: &[usize]) -> Vec<Vec<Wanted>> {
    let mut seen = vec![0usize; n_obs];
    let mut wanted: Vec<Vec<Wanted>> = vec![Vec::new(); n_obs];
    let mut p = 0;
    for (rows, o) in obs.spans() {
        if p == asc.len() {
            break;
        }
        let o = o as usize;
        while p < asc.len() && asc[p] < rows.end {
            let rank = seen[o] + asc[p] - rows.start;
            match wanted[o].last_mut() {
                Some(w) if w.ranks.end == rank && w.pos + w.ranks.len() == p => {
                    w.ranks.end += 1;
                }
                _ => wanted[o].push(Wanted {
                    ranks: rank..rank + 1,
                    pos: p,
                }),
            }
            p += 1;
        }
        seen[o] += rows.len();
    }
    wanted
}

/// A stretch of an observable's spilled records wanted by a gather: the
/// records `ranks` go to positions `pos..pos + ranks.len()` of the rows
/// asked for.
#[derive(Clone, Debug, PartialEq)]
struct Wanted {
    ranks: std::ops::Range<usize>,
    pos: usize,
}

impl RowValues for SpilledValues {
    fn names(&self) -> &[String] {
        &self.names
    }

    fn gather_chunks(
        &self,
        obs: &RunLength<u32>,
        asc: &[usize],
        sink: &mut ChunkSink,
    ) -> Result<()> {
        let wanted = wanted_of(self.file_of.len(), obs, asc);
        // The rows of one observable are its file's records in order: read
        // as a stream. Rows of several observables come from several
        // files in turn, not in `asc` order: gathered whole.
        let files: Vec<usize> = (0..wanted.len())
            .filter(|&o| !wanted[o].is_empty())
            .collect();
        let (&[o], Some(path)) = (
            &files[..],
            files.first().and_then(|&o| self.file_of[o].as_ref()),
        ) else {
            return crate::observations::sink_whole(self.gather(obs, asc)?, sink);
        };
        let (mut gap, mut covs) = (Vec::new(), vec![Vec::new(); self.names.len()]);
        let mut start = 0;
        let mut flush = |start: &mut usize, gap: &mut Vec<f64>, covs: &mut Vec<Vec<f64>>| {
            let got = gap.len();
            let out = sink(*start, gap, covs);
            *start += got;
            gap.clear();
            covs.iter_mut().for_each(Vec::clear);
            out
        };
        self.each_record(path, &wanted[o], |pos, value| {
            debug_assert_eq!(pos, start + gap.len(), "one file's rows in order");
            gap.push(value(0));
            for (j, &at) in self.at.iter().enumerate() {
                covs[j].push(value(1 + at));
            }
            if gap.len() == crate::covariates::READ_ROWS {
                flush(&mut start, &mut gap, &mut covs)?;
            }
            Ok(())
        })?;
        if !gap.is_empty() {
            flush(&mut start, &mut gap, &mut covs)?;
        }
        Ok(())
    }

    fn gather(&self, obs: &RunLength<u32>, asc: &[usize]) -> Result<Gathered> {
        let k = self.names.len();
        let mut out: Vec<Vec<f64>> = (0..k).map(|_| vec![f64::NAN; asc.len()]).collect();
        let mut gap = vec![f64::NAN; asc.len()];
        if asc.is_empty() {
            return Ok(Gathered {
                gap,
                covariates: out,
            });
        }
        let wanted = wanted_of(self.file_of.len(), obs, asc);
        for (o, want) in wanted.iter().enumerate() {
            if want.is_empty() {
                continue;
            }
            let Some(path) = &self.file_of[o] else {
                continue;
            };
            self.each_record(path, want, |pos, value| {
                gap[pos] = value(0);
                for (j, &at) in self.at.iter().enumerate() {
                    out[j][pos] = value(1 + at);
                }
                Ok(())
            })?;
        }
        Ok(Gathered {
            gap,
            covariates: out,
        })
    }
}

#[cfg(test)]
mod wanted_tests {
    use super::{wanted_of, Wanted};
    use crate::run_length::RunLength;

    /// The wanted rows come out as stretches of records, each at its
    /// place among the rows asked for: every row's (record, position) the
    /// pair a row-by-row listing gives, and stretches joined across the
    /// table's stretches of one observable but never across a gap.
    #[test]
    fn wanted_rows_are_stretches_of_records_at_their_positions() {
        // Observables: 0 0 0 1 1 0 0 1 2 2 0 (rows 0..11).
        let obs: RunLength<u32> = [0, 0, 0, 1, 1, 0, 0, 1, 2, 2, 0].into_iter().collect();
        let asc = [0, 1, 2, 5, 6, 7, 9, 10];
        let w = wanted_of(3, &obs, &asc);
        let ranks = |r: std::ops::Range<usize>, pos: usize| Wanted { ranks: r, pos };
        // Observable 0's records: rows 0 1 2 5 6 10 → records 0..5 at
        // positions 0..5 (one stretch across two table stretches), then
        // record 5 (row 10) at position 7.
        assert_eq!(w[0], vec![ranks(0..5, 0), ranks(5..6, 7)]);
        // Observable 1: rows 3 4 7 → only row 7 (record 2) at position 5.
        assert_eq!(w[1], vec![ranks(2..3, 5)]);
        // Observable 2: rows 8 9 → row 9 (record 1) at position 6.
        assert_eq!(w[2], vec![ranks(1..2, 6)]);
        // Row by row, the same pairs.
        let mut listed: Vec<(usize, usize, usize)> = Vec::new();
        let mut seen = [0usize; 3];
        let ids: Vec<u32> = obs.iter().collect();
        for (row, &o) in ids.iter().enumerate() {
            if let Some(p) = asc.iter().position(|&a| a == row) {
                listed.push((o as usize, seen[o as usize], p));
            }
            seen[o as usize] += 1;
        }
        let mut from_stretches: Vec<(usize, usize, usize)> = w
            .iter()
            .enumerate()
            .flat_map(|(o, ws)| {
                ws.iter().flat_map(move |w| {
                    w.ranks
                        .clone()
                        .map(move |r| (o, r, w.pos + r - w.ranks.start))
                })
            })
            .collect();
        from_stretches.sort_by_key(|t| t.2);
        assert_eq!(from_stretches, listed);
    }
}
