//! The Python API (`crates/assist-py`) as a user meets it: its pytest suite, run with the
//! Python of a fresh venv where `pip install ./crates/assist-py` was done (`ASSIST_PYTHON`,
//! set by `.ci/run`), against this build's `assist` binary. `assist.distributed`'s tests
//! (a real local Ray cluster) run as a test of their own, beside the others. Both are
//! given the generator's trained scene the CLI's tests share (`ASSIST_TEST_GENERATOR_SCENE`)
//! rather than training it again.

use crate::common;

use std::process::Command;

const DISTRIBUTED: &str = "test_distributed.py";

#[test]
fn python_api_pytest_suite() {
    pytest(&[tests(), "--ignore", &format!("{}/{DISTRIBUTED}", tests())]);
}

#[test]
fn python_distributed_on_a_ray_cluster() {
    pytest(&[&format!("{}/{DISTRIBUTED}", tests())]);
}

fn tests() -> &'static str {
    concat!(env!("CARGO_MANIFEST_DIR"), "/../assist-py/tests")
}

fn pytest(args: &[&str]) {
    let Ok(py) = std::env::var("ASSIST_PYTHON") else {
        if std::env::var("ASSIST_REQUIRE_PYTHON").is_ok() {
            panic!("ASSIST_REQUIRE_PYTHON is set but ASSIST_PYTHON is not");
        }
        eprintln!(
            "SKIPPED the Python API tests: set ASSIST_PYTHON to a venv's python with `pip install ./crates/assist-py pytest pillow`"
        );
        return;
    };
    let has = Command::new(&py)
        .args(["-c", "import assist, pytest, PIL"])
        .output()
        .unwrap();
    if !has.status.success() {
        let msg = format!(
            "{py} cannot import assist, pytest and PIL: {}",
            String::from_utf8_lossy(&has.stderr)
        );
        if std::env::var("ASSIST_REQUIRE_PYTHON").is_ok() {
            panic!("{msg}");
        }
        eprintln!("SKIPPED the Python API tests: {msg}");
        return;
    }
    let mut pytest = Command::new(&py);
    common::child_threads(&mut pytest);
    let o = pytest
        .args([
            "-m",
            "pytest",
            "-q",
            "-p",
            "no:cacheprovider",
            "--rootdir",
            tests(),
        ])
        .args(args)
        .env("ASSIST_BIN", env!("CARGO_BIN_EXE_assist"))
        .env("ASSIST_TEST_GENERATOR_SCENE", common::generator_fixture())
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "pytest failed:\n{out}\n{}",
        String::from_utf8_lossy(&o.stderr)
    );
    eprintln!("{}", out.lines().last().unwrap_or(""));
}
