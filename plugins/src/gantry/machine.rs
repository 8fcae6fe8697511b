//! The gantry's machine config (configs/machines/aplm-gantry.toml): the
//! three bodies that carry the Z error — stringer 1, stringer 2 (the X
//! guides) and the bridge (Y) — their section properties and measured
//! straightness, the spindle, the grinding process (Qin's cutting force) and
//! the polishing tool (Preston). docs/models.md §2.
//!
//! Machine frame: x along the stringers (supports at x = 0 and x = span),
//! y along the bridge; stringer k runs at y = `stringerk.y_mm`, so the
//! bridge's span is the distance between the stringers.

use sparkout_pipeline::toml_f64;
use std::f64::consts::PI;

use sparkout_pipeline::contracts::MachineConfig;
use sparkout_pipeline::contracts::RunSpec;
use sparkout_pipeline::InputError;

use super::beam::Beam;
use super::straightness::Straightness;
use super::tool_influence::PolishTool;

/// One structural body.
#[derive(Debug, Clone)]
pub struct Body {
    pub name: &'static str,
    pub beam: Beam,
    pub weight_n: f64,
    pub straightness: Straightness,
}

impl Body {
    /// Self weight as a uniform load, N/mm.
    pub fn w_n_mm(&self) -> f64 {
        self.weight_n / self.beam.span_mm
    }
}

/// Which axis the raster passes run along (the moving load's axis).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PassAxis {
    /// The bridge travels along the stringers: the stringers carry a moving load.
    X,
    /// The spindle travels along the bridge: the bridge carries a moving load.
    Y,
}

/// Everything the gantry stages need from the machine config and the run's
/// `[process]` (a run's `[process]` key wins over the machine's).
#[derive(Debug, Clone)]
pub struct Gantry {
    pub source: String,
    pub e_mpa: f64,
    pub stringer1: Body,
    pub stringer2: Body,
    pub bridge: Body,
    pub y_stringer1_mm: f64,
    pub y_stringer2_mm: f64,
    pub spindle_weight_n: f64,
    pub spindle_rpm: f64,
    pub tool_diameter_mm: f64,
    /// Lever of the cutting force about the beam's neutral axis (tool
    /// attack): the travelling moment is M = F_cut·arm (docs/models.md §2.3).
    pub cut_moment_arm_mm: f64,
    pub path_velocity_mm_s: f64,
    pub k_r_mpa: f64,
    pub depth_of_cut_mm: f64,
    pub grinding_width_mm: f64,
    pub pass_axis: PassAxis,
    pub series_tol_rel: f64,
    pub polish: PolishTool,
}

pub const G_MM_S2: f64 = 9810.0;

/// Required bodies, in report order.
pub const BODIES: [&str; 3] = ["stringer1", "stringer2", "bridge"];

struct Reader<'a> {
    m: &'a MachineConfig,
    process: &'a toml::Table,
    run_toml: std::path::PathBuf,
}

impl Reader<'_> {
    fn err(&self, key: &str, msg: String) -> InputError {
        InputError::new(&self.m.source, msg).column(key)
    }
    fn table(&self, name: &str) -> Result<&toml::Table, InputError> {
        self.m.table.get(name).and_then(|v| v.as_table()).ok_or_else(|| {
            self.err(
                name,
                format!(
                    "machine config `{}` has no [{name}] table; a gantry needs the bodies {} plus [spindle], [grinding] and [polishing] (see configs/machines/aplm-gantry.toml)",
                    self.m.id,
                    BODIES.join(", ")
                ),
            )
        })
    }
    /// A positive number from the machine config, or from the run's
    /// `[process]` under `process_key` when given there.
    fn pos(&self, section: &str, key: &str, process_key: Option<&str>) -> Result<f64, InputError> {
        if let Some(pk) = process_key {
            if let Some(v) = self.process.get(pk) {
                return match toml_f64(v) {
                    Some(x) if x.is_finite() && x > 0.0 => Ok(x),
                    _ => Err(InputError::new(
                        &self.run_toml,
                        format!("[process].{pk} must be a positive number, found {v}"),
                    )
                    .column(format!("process.{pk}"))),
                };
            }
        }
        let dotted = format!("{section}.{key}");
        let v = self.table(section)?.get(key).ok_or_else(|| {
            self.err(
                &dotted,
                format!("required key [{section}].{key} is missing"),
            )
        })?;
        match toml_f64(v) {
            Some(x) if x.is_finite() && x > 0.0 => Ok(x),
            _ => Err(self.err(
                &dotted,
                format!("[{section}].{key} must be a positive number, found {v}"),
            )),
        }
    }
    fn opt_num(&self, section: &str, key: &str) -> Option<f64> {
        self.m.table.get(section)?.get(key).and_then(toml_f64)
    }
    fn list(&self, section: &str, key: &str) -> Result<Vec<f64>, InputError> {
        let dotted = format!("{section}.{key}");
        let v = self.table(section)?.get(key).ok_or_else(|| {
            self.err(
                &dotted,
                format!("required key [{section}].{key} (the measured straightness) is missing"),
            )
        })?;
        let a = v.as_array().ok_or_else(|| {
            self.err(
                &dotted,
                format!("[{section}].{key} must be an array of numbers"),
            )
        })?;
        a.iter()
            .enumerate()
            .map(|(i, x)| {
                toml_f64(x).ok_or_else(|| {
                    self.err(
                        &dotted,
                        format!("[{section}].{key}[{i}] is not a number: {x}"),
                    )
                })
            })
            .collect()
    }
    fn body(&self, name: &'static str, e_mpa: f64, span_mm: f64) -> Result<Body, InputError> {
        let weight_n = self.pos(name, "weight_n", None)?;
        let i_mm4 = self.pos(name, "i_mm4", None)?;
        let pos = self.list(name, "straightness_pos_mm")?;
        let z = self.list(name, "straightness_z_mm")?;
        let straightness = Straightness::new(pos, z).map_err(|m| {
            self.err(
                &format!("{name}.straightness_pos_mm"),
                format!("[{name}] straightness: {m}"),
            )
        })?;
        Ok(Body {
            name,
            beam: Beam {
                span_mm,
                ei_n_mm2: e_mpa * i_mm4,
                mass_t_per_mm: weight_n / G_MM_S2 / span_mm,
            },
            weight_n,
            straightness,
        })
    }
}

impl Gantry {
    /// Read and check the machine config for one run.
    pub fn from_run(m: &MachineConfig, spec: &RunSpec) -> Result<Gantry, InputError> {
        Self::read(m, &spec.process, spec.run_toml_path())
    }

    pub fn read(
        m: &MachineConfig,
        process: &toml::Table,
        run_toml: std::path::PathBuf,
    ) -> Result<Gantry, InputError> {
        let r = Reader {
            m,
            process,
            run_toml,
        };
        // Every body first, so a missing one is named before anything else.
        for b in BODIES {
            r.table(b)?;
        }
        let e_mpa = r.pos("material", "e_mpa", None)?;
        let y1 = r.opt_num("stringer1", "y_mm").unwrap_or(0.0);
        let y2 = r.pos("stringer2", "y_mm", None)?;
        if y2 <= y1 {
            return Err(r.err(
                "stringer2.y_mm",
                format!("stringer 2 (y = {y2} mm) must lie beyond stringer 1 (y = {y1} mm): the bridge spans between them"),
            ));
        }
        let s_span = r.pos("stringer1", "span_mm", None)?;
        let s2_span = r.pos("stringer2", "span_mm", None)?;
        let stringer1 = r.body("stringer1", e_mpa, s_span)?;
        let stringer2 = r.body("stringer2", e_mpa, s2_span)?;
        let bridge = r.body("bridge", e_mpa, y2 - y1)?;
        let pass_axis = match r
            .table("grinding")?
            .get("pass_axis")
            .and_then(|v| v.as_str())
            .unwrap_or("x")
        {
            "x" => PassAxis::X,
            "y" => PassAxis::Y,
            other => {
                return Err(r.err(
                    "grinding.pass_axis",
                    format!("[grinding].pass_axis must be \"x\" or \"y\", found \"{other}\""),
                ))
            }
        };
        let polish = PolishTool::read(&r.m.source, r.table("polishing")?, process, &r.run_toml)?;
        let series_tol_rel = r.opt_num("grinding", "series_tol_rel").unwrap_or(1e-10);
        if !(series_tol_rel > 0.0 && series_tol_rel < 1e-2) {
            return Err(r.err(
                "grinding.series_tol_rel",
                format!("[grinding].series_tol_rel must be in (0, 0.01), found {series_tol_rel}"),
            ));
        }
        Ok(Gantry {
            source: m.source.clone(),
            e_mpa,
            y_stringer1_mm: y1,
            y_stringer2_mm: y2,
            spindle_weight_n: r.pos("spindle", "weight_n", None)?,
            spindle_rpm: r.pos("spindle", "speed_rpm", None)?,
            tool_diameter_mm: r.pos("spindle", "tool_diameter_mm", None)?,
            cut_moment_arm_mm: r.opt_num("spindle", "cut_moment_arm_mm").unwrap_or(0.0),
            path_velocity_mm_s: r.pos("grinding", "path_velocity_mm_s", Some("grind_feed_mm_s"))?,
            k_r_mpa: r.pos("grinding", "k_r_mpa", None)?,
            depth_of_cut_mm: r.pos("grinding", "depth_of_cut_mm", Some("depth_of_cut_mm"))?,
            grinding_width_mm: r.pos("grinding", "width_mm", None)?,
            pass_axis,
            series_tol_rel,
            stringer1,
            stringer2,
            bridge,
            polish,
        })
    }

    /// Grinding wheel surface speed v_r = π·D·n/60, mm/s.
    pub fn cutting_speed_mm_s(&self) -> f64 {
        PI * self.tool_diameter_mm * self.spindle_rpm / 60.0
    }

    /// Qin's radial grinding force (docs/models.md §2.2): F_r = K_r·Q_i·b with the
    /// equivalent chip thickness Q_i = a_d·v_a/v_r. K_r (N/mm²) times a
    /// thickness (mm) is a force per unit width; b is the contact width.
    pub fn cut_force_n(&self) -> f64 {
        let q = self.depth_of_cut_mm * self.path_velocity_mm_s / self.cutting_speed_mm_s();
        self.k_r_mpa * q * self.grinding_width_mm
    }

    /// Fraction of the spindle's load carried by stringer 2 with the spindle
    /// at y (lever rule along the bridge), clamped to the bridge.
    pub fn share2(&self, y: f64) -> f64 {
        ((y - self.y_stringer1_mm) / (self.y_stringer2_mm - self.y_stringer1_mm)).clamp(0.0, 1.0)
    }
}
