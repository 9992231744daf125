//! Issue 47, item 18: a scene recorded its dataset as the path given to `train`, and a
//! relative one was read against the working directory, so `cd sub && assist generate
//! --scene ../S.assist` silently used `sub/D`. Training now records the whole path; an
//! older relative record is read against the folder holding the scene, and the dataset
//! found must have the recorded fingerprint.

use assist_testkit::TempDir;

use crate::common;
use crate::common::{bin, ok, s, tiny_capture};

fn fingerprint(data: &std::path::Path) -> String {
    assist_data::load(data, &Default::default())
        .unwrap()
        .fingerprint()
}

#[test]
fn a_scene_finds_its_own_dataset_from_any_folder() {
    let tmp = TempDir::new("recorded-dataset");
    let (cap, other) = (tmp.join("cap"), tmp.join("sub/cap"));
    tiny_capture(&cap, 0);
    tiny_capture(&other, 1);
    // Trained from the scene's folder with a relative path: recorded whole.
    let out = bin()
        .current_dir(tmp.path())
        .args([
            "train",
            "cap",
            "--out",
            "S.assist",
            "--iters",
            "2",
            "--batch-samples",
            "4096",
        ])
        .output()
        .unwrap();
    ok(&out);
    let info = common::scene_info(&tmp.join("S.assist"));
    let recorded = std::path::PathBuf::from(info["dataset"].as_str().unwrap());
    assert!(recorded.is_absolute(), "{info}");
    assert_eq!(
        recorded.canonicalize().unwrap(),
        cap.canonicalize().unwrap()
    );

    // An older scene's relative record, read from another folder: the scene's own
    // dataset, not the one of the same name under the working directory.
    let scene = tmp.join("S.assist");
    let mut info = info.clone();
    info["dataset"] = "cap".into();
    let found = assist_session::recorded_dataset(&scene, &info)
        .unwrap()
        .unwrap();
    assert_eq!(found.canonicalize().unwrap(), cap.canonicalize().unwrap());
    let inside = assist_session::recorded_dataset(&tmp.join("S.assist/scene.json"), &info)
        .unwrap()
        .unwrap();
    assert_eq!(inside.canonicalize().unwrap(), cap.canonicalize().unwrap());
    // A dataset that is not the one trained on (another fingerprint): refused.
    info["dataset_fingerprint"] = fingerprint(&other).into();
    let e = assist_session::recorded_dataset(&scene, &info)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("is not the dataset") && e.contains(s(&scene)),
        "{e}"
    );
    // Gone: refused, naming it.
    info["dataset"] = "nowhere".into();
    let e = assist_session::recorded_dataset(&scene, &info)
        .unwrap_err()
        .to_string();
    assert!(e.contains("nowhere") && e.contains("not there"), "{e}");
}
