//! The cluster examples run as their engines would run them, so that they cannot drift
//! from the CLI: every `assist` command line in `examples/generate-slurm.sh` and
//! `examples/generate-k8s.yaml` (the commented recipes included), with the example paths
//! replaced by a test folder's. Each array task or pod gets the environment variables
//! Slurm or Kubernetes would set, set here by hand. Two Slurm tasks "fail" and are
//! resubmitted with the script's `status --rerun` recipe. Both runs merge into what one
//! process makes, file for file.

use crate::common;

use std::path::{Path, PathBuf};

use crate::common::{ok, run, run_tree, s};

const EXAMPLES: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../../examples");

/// Every `assist generate …` command in `text`: code lines up to their comment, and the
/// commands quoted in comments (after a colon, or inside `$(…)`).
fn commands(text: &str) -> Vec<Vec<String>> {
    let mut out = Vec::new();
    for line in text.lines() {
        let mut rest = line;
        while let Some(k) = rest.find("assist generate") {
            let tail = &rest[k..];
            let end = [tail.find(')'), tail.find(" #"), tail.find('"')]
                .into_iter()
                .flatten()
                .min()
                .unwrap_or(tail.len());
            out.push(tail[..end].split_whitespace().map(String::from).collect());
            rest = &tail[end..];
        }
    }
    out
}

/// `["assist", "generate", …]` arrays of a YAML `command:` line, read as JSON.
fn yaml_command(text: &str) -> Vec<String> {
    let line = text
        .lines()
        .find(|l| l.trim_start().starts_with("command:"))
        .expect("the manifest has a command");
    let array = line.split_once(':').unwrap().1.trim();
    serde_json::from_str(array).expect("the command is a flow list of quoted strings")
}

fn yaml_number(text: &str, key: &str) -> u64 {
    text.lines()
        .find_map(|l| l.trim().strip_prefix(key))
        .map(|v| v.trim().trim_matches('"').parse().unwrap())
        .unwrap_or_else(|| panic!("no {key} in the manifest"))
}

/// The example's paths and the test's.
type Subst = Vec<(String, PathBuf)>;

/// Runs `cmd` (`assist …`, the example's paths replaced) with `env`.
fn assist(cmd: &[String], subst: &Subst, env: &[(&str, String)]) -> std::process::Output {
    assert_eq!(cmd[0], "assist", "{cmd:?}");
    let args: Vec<String> = cmd[1..]
        .iter()
        .map(|a| {
            subst
                .iter()
                .find(|(from, _)| a == from)
                .map(|(_, to)| to.display().to_string())
                .unwrap_or_else(|| a.clone())
        })
        .collect();
    let mut c = common::bin();
    c.args(&args);
    for (k, v) in env {
        c.env(k, v);
    }
    for k in [
        "SLURM_ARRAY_TASK_ID",
        "SLURM_ARRAY_TASK_COUNT",
        "SLURM_ARRAY_TASK_MIN",
        "JOB_COMPLETION_INDEX",
        "JOB_COMPLETIONS",
    ] {
        if !env.iter().any(|(e, _)| *e == k) {
            c.env_remove(k);
        }
    }
    c.output().unwrap()
}

/// Runs `cmd` once per environment in `envs`, all at once (as the engine's tasks run),
/// and waits for all.
fn tasks(cmd: &[String], subst: &Subst, envs: Vec<Vec<(&'static str, String)>>) {
    std::thread::scope(|sc| {
        let kids: Vec<_> = envs
            .into_iter()
            .map(|env| sc.spawn(move || assist(cmd, subst, &env)))
            .collect();
        for k in kids {
            ok(&k.join().unwrap());
        }
    });
}

#[test]
fn slurm_and_kubernetes_examples_run_as_written() {
    let tmp = assist_testkit::TempDir::new("cluster-examples");
    let root = tmp.path();
    let (_, scene) = common::generator_scene(root);
    let spec = root.join("generate.toml");
    std::fs::write(
        &spec,
        format!(
            "count = 32\nseed = 5\n\n[[scenes]]\npath = \"{}\"\n\n[objects]\nkeep = 0.8\nmove = 0.8\n\n[output]\nwidth = 48\nheight = 36\n",
            scene.display()
        ),
    )
    .unwrap();
    let whole = root.join("whole");
    ok(&run(&["generate", "--spec", s(&spec), "--out", s(&whole)]));
    let want = run_tree(&whole);

    // Slurm: the array from #SBATCH --array, tasks 3 and 7 "fail" (never run).
    let script = std::fs::read_to_string(Path::new(EXAMPLES).join("generate-slurm.sh")).unwrap();
    let array = script
        .lines()
        .find_map(|l| l.strip_prefix("#SBATCH --array="))
        .expect("the script sets --array");
    let (lo, hi) = array.split_once('-').unwrap();
    let (lo, hi): (u64, u64) = (lo.parse().unwrap(), hi.parse().unwrap());
    let cmds = commands(&script);
    let find = |what: &str| -> Vec<String> {
        cmds.iter()
            .find(|c| c.join(" ").contains(what))
            .unwrap_or_else(|| panic!("no `{what}` command in the Slurm example: {cmds:?}"))
            .clone()
    };
    let generate = find("--spec");
    let (status, rerun, merge) = (
        cmds.iter()
            .find(|c| c[2] == "status" && c.len() == 4)
            .cloned()
            .expect("a status command"),
        find("--rerun"),
        find("generate merge"),
    );
    let slurm_out = root.join("slurm");
    let subst: Subst = vec![
        ("generate.toml".into(), spec.clone()),
        ("/shared/assist-gen".into(), slurm_out.clone()),
    ];
    let n = hi - lo + 1;
    let env_of = |id: u64| -> Vec<(&'static str, String)> {
        vec![
            ("SLURM_ARRAY_TASK_ID", id.to_string()),
            ("SLURM_ARRAY_TASK_MIN", lo.to_string()),
            ("SLURM_ARRAY_TASK_COUNT", n.to_string()),
            ("SLURM_CPUS_PER_TASK", "1".to_string()),
        ]
    };
    let failed = [lo + 3, lo + 7];
    tasks(
        &generate,
        &subst,
        (lo..=hi)
            .filter(|i| !failed.contains(i))
            .map(env_of)
            .collect(),
    );
    let st = assist(&status, &subst, &[]);
    ok(&st);
    let text = String::from_utf8_lossy(&st.stdout).into_owned();
    assert!(text.contains(&format!("{} complete", n - 2)), "{text}");
    let again = assist(&rerun, &subst, &[]);
    ok(&again);
    let list = String::from_utf8_lossy(&again.stdout).trim().to_string();
    assert_eq!(list, "3,7", "the shards to resubmit");
    let resubmit: Vec<u64> = list
        .split(',')
        .map(|i| i.parse::<u64>().unwrap() + lo)
        .collect();
    tasks(
        &generate,
        &subst,
        resubmit.into_iter().map(env_of).collect(),
    );
    ok(&assist(&merge, &subst, &[]));
    assert!(
        run_tree(&slurm_out) == want,
        "the Slurm array's run differs from one process's"
    );

    // Kubernetes: every pod of the Indexed Job with its completion index.
    let manifest = std::fs::read_to_string(Path::new(EXAMPLES).join("generate-k8s.yaml")).unwrap();
    let command = yaml_command(&manifest);
    let completions = yaml_number(&manifest, "completions:");
    assert_eq!(
        yaml_number(&manifest, "value:"),
        completions,
        "JOB_COMPLETIONS is the Job's completions"
    );
    let k8s_out = root.join("k8s");
    let subst: Subst = vec![
        ("/data/generate.toml".into(), spec.clone()),
        ("/data/out".into(), k8s_out.clone()),
    ];
    tasks(
        &command,
        &subst,
        (0..completions)
            .map(|i| {
                vec![
                    ("JOB_COMPLETION_INDEX", i.to_string()),
                    ("JOB_COMPLETIONS", completions.to_string()),
                ]
            })
            .collect(),
    );
    let k8s_cmds = commands(&manifest);
    let merge = k8s_cmds
        .iter()
        .find(|c| c[2] == "merge")
        .expect("the manifest's merge recipe");
    let status = k8s_cmds
        .iter()
        .find(|c| c[2] == "status")
        .expect("the manifest's status recipe");
    let st = assist(status, &subst, &[]);
    ok(&st);
    assert!(String::from_utf8_lossy(&st.stdout).contains("every shard is complete"));
    ok(&assist(merge, &subst, &[]));
    assert!(
        run_tree(&k8s_out) == want,
        "the Indexed Job's run differs from one process's"
    );
}
