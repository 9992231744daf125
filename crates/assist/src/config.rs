//! `--config FILE` (TOML) for `train`, `render` and `generate`: each key is a flag's long
//! name (`max_time` or `max-time`), each value its value; flags given on the command line
//! win. `assist train … --print-config` writes the whole configuration, defaults included,
//! in the same form.

use std::ffi::OsString;
use std::path::Path;

use anyhow::{Context, bail};
use clap::{ArgAction, CommandFactory};

/// The commands that take `--config`.
pub const CONFIGURABLE: [&str; 3] = ["train", "render", "generate"];

/// `argv` with a `--config FILE` of a configurable command expanded into flags (inserted
/// right after the command's name, skipping any flag the command line gives itself).
pub fn expand(argv: Vec<OsString>) -> anyhow::Result<Vec<OsString>> {
    let Some(cmd_name) = argv.get(1).and_then(|a| a.to_str()).map(str::to_string) else {
        return Ok(argv);
    };
    if !CONFIGURABLE.contains(&cmd_name.as_str()) {
        return Ok(argv);
    }
    let mut file = None;
    let mut rest = Vec::with_capacity(argv.len());
    let mut it = argv.into_iter();
    while let Some(a) = it.next() {
        match a.to_str() {
            Some("--config") => {
                let v = it
                    .next()
                    .context("--config: expected a TOML file after it")?;
                file = Some(std::path::PathBuf::from(v));
            }
            Some(s) if s.starts_with("--config=") => {
                file = Some(std::path::PathBuf::from(&s["--config=".len()..]));
            }
            _ => rest.push(a),
        }
    }
    let Some(file) = file else {
        return Ok(rest);
    };
    let flags = flags_from_file(&file, &cmd_name, &rest)?;
    let mut out: Vec<OsString> = rest[..2].to_vec();
    out.extend(flags.into_iter().map(OsString::from));
    out.extend(rest.into_iter().skip(2));
    Ok(out)
}

/// The flags a config file gives, minus those already on the command line.
fn flags_from_file(file: &Path, cmd_name: &str, argv: &[OsString]) -> anyhow::Result<Vec<String>> {
    let text = assist_fs::read_text(file)?;
    let table: toml::Table = toml::from_str(&text)
        .map_err(|e| anyhow::anyhow!("--config {}: not TOML: {e}", file.display()))?;
    let root = crate::Cli::command();
    let cmd = root
        .find_subcommand(cmd_name)
        .expect("configurable commands exist");
    let given = |long: &str, aliases: &[&str]| {
        argv.iter().filter_map(|a| a.to_str()).any(|a| {
            std::iter::once(long)
                .chain(aliases.iter().copied())
                .any(|l| a == format!("--{l}") || a.starts_with(&format!("--{l}=")))
        })
    };
    let mut flags = Vec::new();
    for (key, value) in &table {
        let long_key = key.replace('_', "-");
        let arg = cmd
            .get_arguments()
            .find(|a| {
                a.get_long() == Some(long_key.as_str())
                    || a.get_all_aliases()
                        .is_some_and(|al| al.contains(&long_key.as_str()))
            })
            .filter(|a| !a.is_hide_set() && !matches!(a.get_id().as_str(), "help" | "config"));
        let Some(arg) = arg else {
            let known: Vec<String> = cmd
                .get_arguments()
                .filter(|a| !a.is_hide_set())
                .filter_map(|a| a.get_long().map(|l| l.replace('-', "_")))
                .filter(|l| !matches!(l.as_str(), "help" | "print_config" | "config"))
                .collect();
            bail!(
                "--config {}: unknown key {key:?} for `assist {cmd_name}` (known: {})",
                file.display(),
                known.join(", ")
            );
        };
        let long = arg.get_long().expect("found by its long name");
        let aliases: Vec<&str> = arg.get_all_aliases().unwrap_or_default();
        // `train DATA …`: a dataset on the command line wins over the file's `data`.
        let positional_data = long == "data"
            && argv
                .get(2)
                .and_then(|a| a.to_str())
                .is_some_and(|a| !a.starts_with('-'));
        if given(long, &aliases) || positional_data {
            continue;
        }
        let is_flag = matches!(arg.get_action(), ArgAction::SetTrue);
        let text = match value {
            toml::Value::Boolean(b) if is_flag => {
                if *b {
                    flags.push(format!("--{long}"));
                }
                continue;
            }
            toml::Value::String(s) => s.clone(),
            toml::Value::Integer(i) => i.to_string(),
            toml::Value::Float(f) => f.to_string(),
            toml::Value::Boolean(b) => b.to_string(),
            toml::Value::Array(a) => a
                .iter()
                .map(|v| match v {
                    toml::Value::String(s) => s.clone(),
                    other => other.to_string(),
                })
                .collect::<Vec<_>>()
                .join(","),
            other => bail!(
                "--config {}: key {key:?}: expected a string, number, boolean or list, got {}",
                file.display(),
                other.type_str()
            ),
        };
        if is_flag {
            bail!(
                "--config {}: key {key:?} is a switch: expected true or false, got {text:?}",
                file.display()
            );
        }
        flags.push(format!("--{long}"));
        flags.push(text);
    }
    Ok(flags)
}

/// The effective configuration of a parsed command as TOML (every flag with its value,
/// defaults included; help lines as comments), ready for `--config`.
pub fn print(cmd_name: &str, m: &clap::ArgMatches) -> String {
    let root = crate::Cli::command();
    let cmd = root
        .find_subcommand(cmd_name)
        .expect("configurable commands exist");
    let mut out = format!("# assist {cmd_name} --config FILE (flags on the command line win)\n");
    for arg in cmd.get_arguments() {
        let id = arg.get_id().as_str();
        if arg.is_hide_set() || matches!(id, "help" | "config" | "print_config") {
            continue;
        }
        let Some(long) = arg.get_long() else { continue };
        let key = long.replace('-', "_");
        if let Some(h) = arg.get_help() {
            for line in h.to_string().lines() {
                out.push_str(&format!("# {line}\n"));
            }
        }
        if matches!(arg.get_action(), ArgAction::SetTrue) {
            out.push_str(&format!("{key} = {}\n", m.get_flag(id)));
            continue;
        }
        // `train DATA`: the positional dataset is the `data` key (`--data`).
        let raw = m
            .get_raw(id)
            .or_else(|| (key == "data").then(|| m.get_raw("data")).flatten());
        match raw {
            Some(vals) => {
                let v: Vec<String> = vals.map(|v| v.to_string_lossy().into_owned()).collect();
                out.push_str(&format!("{key} = {}\n", toml_value(&v.join(","))));
            }
            None => out.push_str(&format!("# {key} = (not set)\n")),
        }
    }
    out
}

/// A value as TOML: a number or boolean as it is, anything else quoted.
fn toml_value(s: &str) -> String {
    if s.parse::<i64>().is_ok()
        || (s.parse::<f64>().is_ok_and(f64::is_finite) && !s.contains(['x', 'X']))
        || s == "true"
        || s == "false"
    {
        s.to_string()
    } else {
        toml::Value::String(s.to_string()).to_string()
    }
}
