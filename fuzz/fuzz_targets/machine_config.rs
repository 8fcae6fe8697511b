//! Any text as a machine config, checked against each built-in machine.
#![no_main]

use libfuzzer_sys::fuzz_target;
use sparkout_pipeline::contracts::config_keys::check_machine;
use sparkout_pipeline::contracts::MachineConfig;

const BUILTINS: [(&str, &str); 5] = [
    ("robot", include_str!("../../configs/machines/kr16-lab.toml")),
    ("gantry", include_str!("../../configs/machines/aplm-gantry.toml")),
    ("guideway", include_str!("../../configs/machines/guideway-grinder.toml")),
    ("mill", include_str!("../../configs/machines/xfyz-mill.toml")),
    ("form", include_str!("../../configs/machines/form-grinder.toml")),
];

fuzz_target!(|data: &[u8]| {
    let Some((&pick, rest)) = data.split_first() else {
        return;
    };
    let Ok(text) = std::str::from_utf8(rest) else {
        return;
    };
    let Ok(table) = text.parse::<toml::Table>() else {
        return;
    };
    let (plugin, builtin) = BUILTINS[pick as usize % BUILTINS.len()];
    let m = MachineConfig {
        id: "fuzz".into(),
        source: "fuzz.toml".into(),
        table,
        text: text.to_string(),
    };
    let _ = check_machine(&m, plugin, &[builtin]);
});
