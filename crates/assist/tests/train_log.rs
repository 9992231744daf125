//! The training log says why a run stopped (issue 19): the iteration budget, the time
//! budget, or an interrupt — in text and in `--json`.

mod common;
use common::{ok, run, s, tiny_capture};

#[test]
fn the_log_says_which_budget_ended_the_run() {
    let tmp = assist_testkit::TempDir::new("train-log");
    let data = tmp.join("cap");
    tiny_capture(&data, 0);
    let a = tmp.join("a.assist");
    let err = ok(&run(&[
        "train",
        s(&data),
        "--out",
        s(&a),
        "--iters",
        "2",
        "--batch-samples",
        "4096",
    ]));
    assert!(err.contains("reached --iters 2"), "{err}");
    let b = tmp.join("b.assist");
    let err = ok(&run(&[
        "train",
        s(&data),
        "--out",
        s(&b),
        "--iters",
        "100000000",
        "--max-time",
        "1",
        "--batch-samples",
        "4096",
    ]));
    assert!(
        err.contains("--max-time 1 s was spent before --iters 100000000"),
        "{err}"
    );
    let out = run(&[
        "train",
        s(&data),
        "--out",
        s(&tmp.join("c.assist")),
        "--iters",
        "2",
        "--json",
        "--batch-samples",
        "4096",
    ]);
    ok(&out);
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["stopped_by"], "iterations", "{v}");
}
