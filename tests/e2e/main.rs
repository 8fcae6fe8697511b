//! All end-to-end tests of the CLI in one test binary: each file under
//! tests/e2e/ is a module (one binary links polars once, instead of once per
//! file: ~8 GB of test executables and most of the link time saved).
//! Run one group with `cargo test --test e2e gantry_stages::`.

mod ae_any_rate;
mod augment;
mod bad_input_matrix;
mod can_decode;
mod can_describe;
mod can_pdo;
mod cli_fleet;
mod cli_stage_diagnose;
mod common;
mod config_defaults;
mod confounding;
mod contracts_bad_input;
mod demo_artifacts;
mod deploy_recipes;
mod diagnose_file;
mod diagnose_robust;
mod diagnose_validate;
mod docs_agree;
mod form_diagnosis_e2e;
mod form_stages;
mod fuzz_corpus;
mod gantry_e2e;
mod gantry_stages;
mod generate_robot;
mod guideway_diagnosis_e2e;
mod guideway_stages;
mod help_lists_registry;
mod hostile;
mod impossible_values;
mod machines;
mod metrology;
mod mill_diagnosis_e2e;
mod mill_stages;
mod negative_values;
mod news;
mod object_store;
mod pandas_fleet;
mod parquet_readers;
mod proptest_parsers;
mod reliability;
mod replay_cli;
mod reports;
mod robot_diagnosis_e2e;
mod robot_stages;
mod run_verdicts;
mod runless_tables;
mod servo_e2e;
mod shards;
mod stands_alone;
mod trend;
mod umich_cnc;
mod units;
