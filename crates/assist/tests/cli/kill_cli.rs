//! The kill test of the reliability issue: `kill -9` at 20 random moments during training
//! and during edit saves, against the built binary. After every kill the scene loads,
//! `--resume` continues from the last checkpoint, at most one checkpoint interval (plus a
//! save's duration) is lost, and no temporary survives the next command.

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

use assist_testkit::TempDir;

const KILLS: usize = 20;
const CHECKPOINT_EVERY: f64 = 0.4;
/// A checkpoint is written at the first step boundary after the interval and takes a
/// moment to save: what a kill may lose beyond the interval itself (a loaded host's step
/// and save).
const SLACK: f64 = 3.0;

use crate::common;
use crate::common::{bin, ok, s};

fn assist(args: &[&str]) -> Output {
    common::run(args)
}

/// A small deterministic generator of kill moments.
struct Lcg(u64);
impl Lcg {
    fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        lo + (hi - lo) * ((self.0 >> 11) as f64 / (1u64 << 53) as f64)
    }
}

fn kill9(child: &mut Child) {
    let pid = child.id().to_string();
    let _ = Command::new("kill").args(["-9", &pid]).status();
    let _ = child.wait();
}

/// The scene loads whole: every field and the history (a render reads all of them).
fn assert_loads(scene: &Path, tmp: &TempDir, when: &str) {
    let out = assist(&[
        "render",
        s(scene),
        "--out",
        s(&tmp.join("check")),
        "--frames",
        "1",
        "--size",
        "8x6",
        "--force",
    ]);
    assert!(
        out.status.success(),
        "{when}: the scene does not load: {}",
        String::from_utf8_lossy(&out.stderr)
    );
}

fn info(scene: &Path) -> serde_json::Value {
    common::scene_info(scene)
}

#[test]
fn kill_9_during_training_and_edit_saves_loses_at_most_one_checkpoint() {
    let tmp = TempDir::new("kill9");
    let data = tmp.join("cap");
    common::tiny_capture(&data, 0);
    let sc = tmp.join("s.assist");
    let mut rng = Lcg(17);
    let every = CHECKPOINT_EVERY.to_string();
    let mut worst_loss: f64 = 0.0;
    for k in 0..KILLS {
        let exists = sc.join("scene.json").is_file();
        let before = if exists {
            info(&sc)["elapsed_seconds"].as_f64().unwrap()
        } else {
            0.0
        };
        let mut cmd = bin();
        cmd.args(["train", s(&data), "--out", s(&sc), "--iters", "100000000"])
            .args(["--checkpoint-every", &every, "--batch-samples", "4096"]);
        if exists {
            cmd.arg("--resume");
        } else {
            cmd.arg("--force");
        }
        let mut child = cmd
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        let mut lines = BufReader::new(child.stderr.take().unwrap()).lines();
        let mut started = None;
        for line in lines.by_ref() {
            if line.unwrap().starts_with("nodes:") {
                started = Some(Instant::now());
                break;
            }
        }
        let started = started.expect("training started");
        std::thread::spawn(move || for _ in lines {});
        let wait = rng.uniform(0.05, 2.0);
        std::thread::sleep(Duration::from_secs_f64(wait));
        let trained = started.elapsed().as_secs_f64();
        kill9(&mut child);
        if !sc.join("scene.json").is_file() {
            // Killed before the first checkpoint of a new scene: nothing was promised.
            assert!(
                trained < CHECKPOINT_EVERY + SLACK,
                "kill {k}: no checkpoint after {trained:.2} s"
            );
            continue;
        }
        assert_loads(&sc, &tmp, &format!("training kill {k} at {wait:.2} s"));
        let after = info(&sc)["elapsed_seconds"].as_f64().unwrap();
        let lost = before + trained - after;
        worst_loss = worst_loss.max(lost);
        assert!(
            lost <= CHECKPOINT_EVERY + SLACK,
            "kill {k}: {lost:.2} s of training lost (checkpoints every {CHECKPOINT_EVERY} s)"
        );
    }
    // The next command continues from the last checkpoint and leaves nothing behind.
    let it = info(&sc)["iteration"].as_u64().unwrap();
    ok(&assist(&[
        "train",
        s(&data),
        "--out",
        s(&sc),
        "--resume",
        "--max-time",
        "0.3",
    ]));
    assert!(info(&sc)["iteration"].as_u64().unwrap() >= it);
    common::assert_no_leftovers(tmp.path());
    eprintln!("training: worst loss over {KILLS} kills {worst_loss:.2} s");

    // Edit saves, in place.
    let undo_len = |p: &Path| -> usize {
        std::fs::read(p.join("history.json"))
            .ok()
            .map(|b| {
                let v: serde_json::Value = serde_json::from_slice(&b).unwrap();
                v["undo"].as_array().map_or(0, |a| a.len())
            })
            .unwrap_or(0)
    };
    // Kill moments spread over an edit's whole run (load, apply, save).
    let t = Instant::now();
    ok(&common::edit_in_place(&sc, "move the ball 1 cm left"));
    let edit_secs = t.elapsed().as_secs_f64();
    for k in 0..KILLS {
        let n = undo_len(&sc);
        let mut child = bin()
            .args([
                "edit",
                s(&sc),
                "--do",
                "move the ball 1 cm left",
                "--out",
                s(&sc),
                "--force",
            ])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        std::thread::sleep(Duration::from_secs_f64(rng.uniform(0.0, 1.2 * edit_secs)));
        kill9(&mut child);
        assert_loads(&sc, &tmp, &format!("edit kill {k}"));
        let m = undo_len(&sc);
        assert!(
            m == n || m == n + 1,
            "edit kill {k}: history went from {n} to {m}"
        );
    }
    ok(&common::edit_in_place(&sc, "move the ball 1 cm right"));
    common::assert_no_leftovers(tmp.path());
}
