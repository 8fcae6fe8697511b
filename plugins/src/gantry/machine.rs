//! The gantry's machine config (configs/machines/aplm-gantry.toml): the
//! three bodies that carry the Z error — stringer 1, stringer 2 (the X
//! guides) and the bridge (Y) — their section properties and measured
//! straightness, the spindle, the grinding process (Qin's cutting force) and
//! the polishing tool (Preston). docs/models.md §2.
//!
//! Machine frame: x along the stringers (supports at x = 0 and x = span),
//! y along the bridge; stringer k runs at y = `stringerk.y_mm`, so the
//! bridge's span is the distance between the stringers.

use serde::{Deserialize, Serialize};
use sparkout_pipeline::config_check::{Check, Section, SectionCheck};
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

/// `[material]` of a gantry machine config.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MachineMaterial {
    /// Young's modulus of the bodies (MPa).
    pub e_mpa: Option<f64>,
}

impl Section for MachineMaterial {
    const CHECKS: &'static [(&'static str, Check)] = &[("e_mpa", Check::Positive)];
}

/// `[stringer1]`, `[stringer2]` and `[bridge]`: one structural body.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MachineBody {
    /// Where a stringer runs across the bed (mm; the bridge spans between).
    pub y_mm: Option<f64>,
    pub span_mm: Option<f64>,
    pub weight_n: Option<f64>,
    pub i_mm4: Option<f64>,
    /// The measured straightness: positions along the body and Z there (mm).
    pub straightness_pos_mm: Option<Vec<f64>>,
    pub straightness_z_mm: Option<Vec<f64>>,
}

impl Section for MachineBody {
    const CHECKS: &'static [(&'static str, Check)] = &[
        ("y_mm", Check::Number),
        ("span_mm", Check::Positive),
        ("weight_n", Check::Positive),
        ("i_mm4", Check::Positive),
    ];
}

/// `[spindle]`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MachineSpindle {
    pub weight_n: Option<f64>,
    pub speed_rpm: Option<f64>,
    pub tool_diameter_mm: Option<f64>,
    pub cut_moment_arm_mm: Option<f64>,
}

impl Section for MachineSpindle {
    const CHECKS: &'static [(&'static str, Check)] = &[
        ("weight_n", Check::Positive),
        ("speed_rpm", Check::Positive),
        ("tool_diameter_mm", Check::Positive),
        ("cut_moment_arm_mm", Check::NonNegative),
    ];
}

/// `[grinding]`.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MachineGrinding {
    pub path_velocity_mm_s: Option<f64>,
    pub k_r_mpa: Option<f64>,
    pub depth_of_cut_mm: Option<f64>,
    pub width_mm: Option<f64>,
    pub pass_axis: Option<String>,
    pub series_tol_rel: Option<f64>,
}

impl Section for MachineGrinding {
    const CHECKS: &'static [(&'static str, Check)] = &[
        ("path_velocity_mm_s", Check::Positive),
        ("k_r_mpa", Check::Positive),
        ("depth_of_cut_mm", Check::Positive),
        ("width_mm", Check::Positive),
        ("pass_axis", Check::OneOf(&["x", "y"])),
        ("series_tol_rel", Check::Positive),
    ];
}

/// `[polishing]`: the Preston tool (a run's `[process]` key of the same
/// name wins, `PolishTool::read`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MachinePolishing {
    pub k_p_per_pa: Option<f64>,
    pub pressure_pa: Option<f64>,
    pub spring_rate_n_mm: Option<f64>,
    pub tool_area_mm2: Option<f64>,
    pub tool_radius_mm: Option<f64>,
    pub rev_per_s: Option<f64>,
    pub linear_speed_mm_s: Option<f64>,
    pub spring_compression_mm: Option<f64>,
    pub feed_mm_s: Option<f64>,
    pub step_over_mm: Option<f64>,
    pub accel_mm_s2: Option<f64>,
}

impl Section for MachinePolishing {
    const CHECKS: &'static [(&'static str, Check)] = &[
        ("k_p_per_pa", Check::Positive),
        ("pressure_pa", Check::Positive),
        ("spring_rate_n_mm", Check::Positive),
        ("tool_area_mm2", Check::Positive),
        ("tool_radius_mm", Check::Positive),
        ("rev_per_s", Check::Positive),
        ("linear_speed_mm_s", Check::Positive),
        ("spring_compression_mm", Check::Positive),
        ("feed_mm_s", Check::Positive),
        ("step_over_mm", Check::Positive),
        ("accel_mm_s2", Check::Positive),
    ];
}

impl MachinePolishing {
    /// A number of the section by its key (the keys `PolishTool::read`
    /// takes from a run's `[process]` first).
    pub fn value(&self, key: &str) -> Option<f64> {
        match key {
            "k_p_per_pa" => self.k_p_per_pa,
            "pressure_pa" => self.pressure_pa,
            "spring_rate_n_mm" => self.spring_rate_n_mm,
            "tool_area_mm2" => self.tool_area_mm2,
            "tool_radius_mm" => self.tool_radius_mm,
            "rev_per_s" => self.rev_per_s,
            "linear_speed_mm_s" => self.linear_speed_mm_s,
            "spring_compression_mm" => self.spring_compression_mm,
            "feed_mm_s" => self.feed_mm_s,
            "step_over_mm" => self.step_over_mm,
            "accel_mm_s2" => self.accel_mm_s2,
            _ => None,
        }
    }
}

/// The gantry machine config's sections, read and checked once when the
/// machine is loaded (an unknown key, a wrong type or a value out of range
/// is an error naming the file and `section.key`).
pub const MACHINE_SECTIONS: &[(&str, SectionCheck)] = &[
    ("material", SectionCheck::of::<MachineMaterial>()),
    ("stringer1", SectionCheck::of::<MachineBody>()),
    ("stringer2", SectionCheck::of::<MachineBody>()),
    ("bridge", SectionCheck::of::<MachineBody>()),
    ("spindle", SectionCheck::of::<MachineSpindle>()),
    ("grinding", SectionCheck::of::<MachineGrinding>()),
    ("polishing", SectionCheck::of::<MachinePolishing>()),
];

struct Reader<'a> {
    m: &'a MachineConfig,
    process: &'a toml::Table,
    run_toml: std::path::PathBuf,
}

impl Reader<'_> {
    fn err(&self, key: &str, msg: String) -> InputError {
        InputError::new(&self.m.source, msg).column(key)
    }
    /// That the machine config has section `name` (the sections' values
    /// were read and checked when the machine was loaded).
    fn table(&self, name: &str) -> Result<(), InputError> {
        match self.m.table.get(name) {
            Some(v) if v.is_table() => Ok(()),
            _ => Err(self.err(
                name,
                format!(
                    "machine config `{}` has no [{name}] table; a gantry needs the bodies {} plus [spindle], [grinding] and [polishing] (see configs/machines/aplm-gantry.toml)",
                    self.m.id,
                    BODIES.join(", ")
                ),
            )),
        }
    }
    /// Section `name` as its serde struct (checked: wrong types and values
    /// out of range are refused naming the file and `name.key`).
    fn section<T: Section + Clone>(&self, name: &str) -> Result<T, InputError> {
        self.table(name)?;
        self.m.typed_section::<T>(name)
    }
    /// A required number of the machine config.
    fn req(&self, v: Option<f64>, section: &str, key: &str) -> Result<f64, InputError> {
        v.ok_or_else(|| {
            self.err(
                &format!("{section}.{key}"),
                format!("required key [{section}].{key} is missing"),
            )
        })
    }
    /// A required number, or the run's `[process]` value under
    /// `process_key` when given there (it wins).
    fn over(
        &self,
        v: Option<f64>,
        section: &str,
        key: &str,
        process_key: &str,
    ) -> Result<f64, InputError> {
        if let Some(pv) = self.process.get(process_key) {
            return match toml_f64(pv) {
                Some(x) if x.is_finite() && x > 0.0 => Ok(x),
                _ => Err(InputError::new(
                    &self.run_toml,
                    format!("[process].{process_key} must be a positive number, found {pv}"),
                )
                .column(format!("process.{process_key}"))),
            };
        }
        self.req(v, section, key)
    }
    fn list(&self, v: Option<Vec<f64>>, section: &str, key: &str) -> Result<Vec<f64>, InputError> {
        v.ok_or_else(|| {
            self.err(
                &format!("{section}.{key}"),
                format!("required key [{section}].{key} (the measured straightness) is missing"),
            )
        })
    }
    fn body(
        &self,
        name: &'static str,
        b: MachineBody,
        e_mpa: f64,
        span_mm: f64,
    ) -> Result<Body, InputError> {
        let weight_n = self.req(b.weight_n, name, "weight_n")?;
        let i_mm4 = self.req(b.i_mm4, name, "i_mm4")?;
        let pos = self.list(b.straightness_pos_mm, name, "straightness_pos_mm")?;
        let z = self.list(b.straightness_z_mm, name, "straightness_z_mm")?;
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
        let material: MachineMaterial = r.section("material")?;
        let e_mpa = r.req(material.e_mpa, "material", "e_mpa")?;
        let s1: MachineBody = r.section("stringer1")?;
        let s2: MachineBody = r.section("stringer2")?;
        let y1 = s1.y_mm.unwrap_or(0.0);
        let y2 = r.req(s2.y_mm, "stringer2", "y_mm")?;
        if y2 <= y1 {
            return Err(r.err(
                "stringer2.y_mm",
                format!("stringer 2 (y = {y2} mm) must lie beyond stringer 1 (y = {y1} mm): the bridge spans between them"),
            ));
        }
        let s_span = r.req(s1.span_mm, "stringer1", "span_mm")?;
        let s2_span = r.req(s2.span_mm, "stringer2", "span_mm")?;
        let stringer1 = r.body("stringer1", s1, e_mpa, s_span)?;
        let stringer2 = r.body("stringer2", s2, e_mpa, s2_span)?;
        let bridge = r.body("bridge", r.section("bridge")?, e_mpa, y2 - y1)?;
        let grinding: MachineGrinding = r.section("grinding")?;
        let pass_axis = match grinding.pass_axis.as_deref().unwrap_or("x") {
            "y" => PassAxis::Y,
            // `[grinding].pass_axis` is "x" or "y" (checked at load).
            _ => PassAxis::X,
        };
        let polishing: MachinePolishing = r.section("polishing")?;
        let polish = PolishTool::read(&r.m.source, &polishing, process, &r.run_toml)?;
        let series_tol_rel = grinding.series_tol_rel.unwrap_or(1e-10);
        if !(series_tol_rel > 0.0 && series_tol_rel < 1e-2) {
            return Err(r.err(
                "grinding.series_tol_rel",
                format!("[grinding].series_tol_rel must be in (0, 0.01), found {series_tol_rel}"),
            ));
        }
        let spindle: MachineSpindle = r.section("spindle")?;
        Ok(Gantry {
            source: m.source.clone(),
            e_mpa,
            y_stringer1_mm: y1,
            y_stringer2_mm: y2,
            spindle_weight_n: r.req(spindle.weight_n, "spindle", "weight_n")?,
            spindle_rpm: r.req(spindle.speed_rpm, "spindle", "speed_rpm")?,
            tool_diameter_mm: r.req(spindle.tool_diameter_mm, "spindle", "tool_diameter_mm")?,
            cut_moment_arm_mm: spindle.cut_moment_arm_mm.unwrap_or(0.0),
            path_velocity_mm_s: r.over(
                grinding.path_velocity_mm_s,
                "grinding",
                "path_velocity_mm_s",
                "grind_feed_mm_s",
            )?,
            k_r_mpa: r.req(grinding.k_r_mpa, "grinding", "k_r_mpa")?,
            depth_of_cut_mm: r.over(
                grinding.depth_of_cut_mm,
                "grinding",
                "depth_of_cut_mm",
                "depth_of_cut_mm",
            )?,
            grinding_width_mm: r.req(grinding.width_mm, "grinding", "width_mm")?,
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The built-in machine with `from` replaced by `to`, read as a run-less
    /// stage reads it (sections checked through their serde types).
    fn read_with(from: &str, to: &str) -> Result<Gantry, InputError> {
        let text = super::super::APLM_GANTRY_TOML.replace(from, to);
        assert!(
            from == to || text != super::super::APLM_GANTRY_TOML,
            "{from} not in the config"
        );
        let m = MachineConfig {
            id: "aplm-gantry".into(),
            source: "aplm-gantry.toml".into(),
            table: text.parse().unwrap(),
            text,
            ..Default::default()
        };
        Gantry::read(&m, &toml::Table::new(), "run.toml".into())
    }

    #[test]
    fn machine_sections_refuse_unknown_keys_wrong_types_and_bad_values_by_name() {
        let g = read_with("[spindle]\n", "[spindle]\n").unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(g.bridge.beam.span_mm, 1800.0);
        // The bodies share a type; each is read under its own name.
        assert_ne!(g.stringer1.straightness, g.stringer2.straightness);
        for (from, to, key, needle) in [
            (
                "[spindle]\n",
                "[spindle]\nspeed_rmp = 3.0\n",
                "spindle.speed_rmp",
                "unknown key",
            ),
            (
                "weight_n = 768.9",
                "weight_n = \"heavy\"",
                "spindle.weight_n",
                "weight_n",
            ),
            (
                "k_r_mpa = 2255.53",
                "k_r_mpa = -1.0",
                "grinding.k_r_mpa",
                "k_r_mpa",
            ),
            (
                "pass_axis = \"x\"",
                "pass_axis = \"z\"",
                "grinding.pass_axis",
                "pass_axis",
            ),
            (
                "rev_per_s = 2.5",
                "rev_per_s = 0.0",
                "polishing.rev_per_s",
                "rev_per_s",
            ),
        ] {
            let e = read_with(from, to).unwrap_err();
            let text = e.to_string();
            assert!(text.contains("aplm-gantry.toml"), "{to}: {text}");
            assert!(text.contains(needle), "{to}: {text}");
            assert_eq!(e.column.as_deref(), Some(key), "{to}: {text}");
        }
        let e = read_with("tool_diameter_mm = 177.0", "").unwrap_err();
        assert!(
            e.to_string()
                .contains("required key [spindle].tool_diameter_mm"),
            "{e}"
        );
    }
}
