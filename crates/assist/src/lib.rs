//! assist: the command line that wires the crates together.
//!
//! `assist dataset info` reads any supported dataset and validates it; `assist synth`
//! generates a built-in multi-object scene; `assist demo` runs the main job on the
//! built-in default. Errors are reported with `anyhow` context chains and a non-zero exit.

#![forbid(unsafe_code)]

use std::process::ExitCode;

use clap::{Parser, Subcommand};

mod cmd_bench;
mod cmd_bench_embed;
mod cmd_bench_gpu;
mod cmd_bench_merge;
mod cmd_bench_mesh;
mod cmd_bench_process;
mod cmd_bench_render;
mod cmd_bench_sam;
mod cmd_bench_split;
mod cmd_bench_train;
mod cmd_bench_view;
mod cmd_dataset;
mod cmd_dataset_masks;
mod cmd_demo;
mod cmd_edit;
mod cmd_embed;
mod cmd_eval;
mod cmd_export;
mod cmd_generate;
mod cmd_process;
mod cmd_render;
mod cmd_scene;
mod cmd_scene_split;
mod cmd_synth;
mod cmd_train;
mod cmd_view;
mod config;
mod device;
mod edit_checks;
mod progress;

#[derive(Parser, Debug)]
#[command(
    name = "assist",
    version,
    about = "Editable object-wise neural scenes from posed photos (ASSIST)"
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand, Debug)]
pub enum Command {
    /// Inspect and validate datasets.
    Dataset {
        #[command(subcommand)]
        command: cmd_dataset::DatasetCommand,
    },
    /// Generate a built-in multi-object tabletop scene in desk format (nerfstudio
    /// transforms.json with depth, instance masks and object boxes; docs/formats.md).
    Synth(cmd_synth::SynthArgs),
    /// Run the main job on the built-in default scene (no downloads).
    Demo(cmd_demo::DemoArgs),
    /// Turn a video or a folder of photographs into a posed dataset: frames by ffmpeg
    /// (the sharpest), poses by COLMAP, written as nerfstudio's transforms.json.
    Process(cmd_process::ProcessArgs),
    /// Inspect a trained scene: nodes, boxes, poses, field files, history, provenance.
    Scene {
        #[command(subcommand)]
        command: cmd_scene::SceneCommand,
    },
    /// Train a compositional scene (background + one node per object) from a dataset.
    Train(Box<cmd_train::TrainArgs>),
    /// Measure a trained scene against a dataset split (PSNR, SSIM, panoptic mIoU, background).
    Eval(cmd_eval::EvalArgs),
    /// Edit a trained scene: plain-language instructions, action scripts, undo/redo.
    Edit(cmd_edit::EditArgs),
    /// Render a trained scene into a new labelled dataset, from a dataset's cameras, a
    /// transforms.json or an orbit.
    Render(cmd_render::RenderArgs),
    /// Export nodes as meshes or point clouds (PLY, OBJ, GLB), with an optional MuJoCo or
    /// URDF model placing them at their poses.
    Export(cmd_export::ExportArgs),
    /// Give each node a CLIP embedding from the training views (needs CLIP weights), so
    /// instructions can name objects by what they are.
    Embed(cmd_embed::EmbedArgs),
    /// Make many randomized, plausible, labelled variations of trained scenes (shardable).
    Generate(cmd_generate::GenerateArgs),
    /// Open a trained scene in the interactive viewer (a page in your browser).
    View(cmd_view::ViewArgs),
    /// Measure the speed of hot paths.
    Bench {
        #[command(subcommand)]
        command: cmd_bench::BenchCommand,
    },
}

pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Dataset { command } => cmd_dataset::run(command),
        Command::Synth(a) => cmd_synth::run(a),
        Command::Demo(a) => cmd_demo::run(a),
        Command::Process(a) => cmd_process::run(a),
        Command::Scene { command } => cmd_scene::run(command),
        Command::Train(a) => cmd_train::run(*a),
        Command::Eval(a) => cmd_eval::run(a),
        Command::Edit(a) => cmd_edit::run(a),
        Command::Render(a) => cmd_render::run(a),
        Command::Export(a) => cmd_export::run(a),
        Command::Embed(a) => cmd_embed::run(a),
        Command::Generate(a) => cmd_generate::run(a),
        Command::View(a) => cmd_view::run(a),
        Command::Bench { command } => cmd_bench::run(command),
    }
}

pub fn run_from_env() -> ExitCode {
    use clap::{CommandFactory, FromArgMatches};
    let argv = match config::expand(std::env::args_os().collect()) {
        Ok(v) => v,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::FAILURE;
        }
    };
    let m = Cli::command().get_matches_from(argv);
    let cli = Cli::from_arg_matches(&m).unwrap_or_else(|e| e.exit());
    if let Command::Train(a) = &cli.command
        && a.print_config
        && let Some(tm) = m.subcommand_matches("train")
    {
        print!("{}", config::print("train", tm));
        return ExitCode::SUCCESS;
    }
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            // A cause already said by the message before it (errors that show their
            // source and also return it) is not printed twice.
            let mut said = e.to_string();
            for cause in e.chain().skip(1) {
                let text = cause.to_string();
                if !said.contains(&text) {
                    eprintln!("  caused by: {text}");
                }
                said = text;
            }
            ExitCode::FAILURE
        }
    }
}

#[cfg(test)]
mod tests {
    use clap::CommandFactory;

    /// Every flag and argument of every command says what it is (issue 19).
    #[test]
    fn every_argument_has_a_help_line() {
        fn walk(cmd: &clap::Command, path: &str, missing: &mut Vec<String>) {
            for a in cmd.get_arguments() {
                if a.is_hide_set() || matches!(a.get_id().as_str(), "help" | "version") {
                    continue;
                }
                if a.get_help().is_none() && a.get_long_help().is_none() {
                    missing.push(format!("{path} {}", a.get_id()));
                }
            }
            for sub in cmd.get_subcommands() {
                if sub.get_name() == "help" {
                    continue;
                }
                if sub.get_about().is_none() {
                    missing.push(format!("{path} {} (no description)", sub.get_name()));
                }
                walk(sub, &format!("{path} {}", sub.get_name()), missing);
            }
        }
        let mut missing = Vec::new();
        walk(&super::Cli::command(), "assist", &mut missing);
        assert!(missing.is_empty(), "no help line: {missing:#?}");
    }
}
