//! The `assist` binary's integration tests, one module per command or concern, built as one
//! test binary: linked one by one, the two dozen of them took a minute of every build.
//! Nextest still runs each test in its own process.

mod common;

mod cli_grammar;
mod cluster_examples;
mod code_shape;
mod dataset_cli;
mod desk_cli;
mod edit_cli;
mod embed_cli;
mod export_cli;
mod generate_cli;
mod gpu_cli;
mod kill_cli;
mod light_cli;
mod masks_cli;
mod no_lost_work;
mod prior_dir;
mod process_cli;
mod python_api;
mod recorded_dataset;
mod reliability_cli;
mod render_cli;
mod split_cli;
mod train_cli;
mod train_log;
