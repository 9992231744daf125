//! One command-line grammar (issue 19): the dataset is `--data` wherever one is taken,
//! sizes are `--size WxH`, objects are taken by id or name, every command has `--json`
//! with machine output on stdout while human reports go to stderr.

use crate::common;

use crate::common::{ok, run, s, tiny_scene};

#[test]
fn the_dataset_is_data_the_report_goes_to_stderr_and_json_to_stdout() {
    let tmp = assist_testkit::TempDir::new("cli-grammar");
    let (data, scene) = tiny_scene(tmp.path());

    // eval: text on stderr, nothing on stdout; --json on stdout.
    let out = run(&["eval", s(&scene), "--data", s(&data)]);
    let err = ok(&out);
    assert!(
        out.stdout.is_empty(),
        "{}",
        String::from_utf8_lossy(&out.stdout)
    );
    assert!(err.contains("PSNR"), "{err}");
    let out = run(&["eval", s(&scene), "--data", s(&data), "--json"]);
    ok(&out);
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(v["psnr"].is_number(), "{v}");
    // --align-poses: each image's camera fit is in the report; its step count alone is
    // refused.
    let out = run(&[
        "eval",
        s(&scene),
        "--data",
        s(&data),
        "--json",
        "--align-poses",
        "--align-steps",
        "3",
    ]);
    ok(&out);
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    for im in v["per_image"].as_array().unwrap() {
        let a = &im["alignment"];
        assert!(
            a["mse_before"].is_number() && a["applied"].is_boolean(),
            "{v}"
        );
    }
    let out = run(&["eval", s(&scene), "--data", s(&data), "--align-steps", "3"]);
    assert!(!out.status.success());
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("--align-poses"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );

    // render: --data names the dataset, --select takes a name, --json on stdout.
    let r = tmp.path().join("r");
    let out = run(&[
        "render",
        s(&scene),
        "--data",
        s(&data),
        "--split",
        "test",
        "--select",
        "ball",
        "--out",
        s(&r),
        "--json",
    ]);
    ok(&out);
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(v["views"].as_u64().unwrap() >= 1, "{v}");
    assert_eq!(v["highlight"], 2, "the ball is node 2: {v}");
    assert!(r.join("transforms.json").is_file());

    // train: the dataset as --data too, but not twice.
    let t = tmp.path().join("t.assist");
    ok(&run(&[
        "train",
        "--data",
        s(&data),
        "--out",
        s(&t),
        "--iters",
        "1",
        "--batch-samples",
        "4096",
        "--eval-views",
        "0",
    ]));
    let o = run(&[
        "train",
        s(&data),
        "--data",
        s(&data),
        "--out",
        s(&tmp.path().join("t2.assist")),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success() && err.contains("--data"), "{err}");

    // edit: directions relative to a camera of --data.
    let frame = {
        let t: serde_json::Value =
            serde_json::from_slice(&std::fs::read(data.join("transforms.json")).unwrap()).unwrap();
        let p = t["frames"][0]["file_path"].as_str().unwrap().to_string();
        std::path::Path::new(&p)
            .file_stem()
            .unwrap()
            .to_string_lossy()
            .to_string()
    };
    let out = run(&[
        "edit",
        s(&scene),
        "--data",
        s(&data),
        "--frame",
        &frame,
        "--do",
        "move the ball 1 cm left",
        "--dry-run",
        "--json",
    ]);
    ok(&out);
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v[0]["operation"], "translate", "{v}");

    // An object moved where the capture never looked: a warning, or under --strict a
    // refusal that writes nothing.
    let far = "move the ball 1 m up";
    let out = run(&["edit", s(&scene), "--do", far, "--dry-run"]);
    let err = ok(&out);
    assert!(
        err.contains("warning") && err.contains("captured region"),
        "{err}"
    );
    let e = tmp.path().join("e.assist");
    let out = run(&["edit", s(&scene), "--do", far, "--strict", "--out", s(&e)]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success() && err.contains("--strict"), "{err}");
    assert!(!e.exists());
    let out = run(&[
        "edit",
        s(&scene),
        "--do",
        "move the ball 1 cm left",
        "--dry-run",
    ]);
    let err = ok(&out);
    assert!(!err.contains("warning"), "{err}");

    // synth: --size WxH.
    let sz = tmp.path().join("sz");
    let out = run(&[
        "synth",
        "--out",
        s(&sz),
        "--size",
        "40x30",
        "--views",
        "6",
        "--objects",
        "3",
        "--json",
    ]);
    ok(&out);
    let img = image::open(
        sz.join("images")
            .read_dir()
            .unwrap()
            .next()
            .unwrap()
            .unwrap()
            .path(),
    )
    .unwrap();
    assert_eq!((img.width(), img.height()), (40, 30));
}

/// `--config FILE` (TOML) gives flags to train and render, the command line wins, an
/// unknown key is an error naming it; `train --print-config` writes a file `--config`
/// reads back.
#[test]
fn config_files_give_flags_and_print_config_round_trips() {
    let tmp = assist_testkit::TempDir::new("cli-config");
    let (data, scene) = tiny_scene(tmp.path());
    let out = run(&[
        "train",
        s(&data),
        "--out",
        s(&tmp.path().join("unused.assist")),
        "--iters",
        "2",
        "--batch-samples",
        "4096",
        "--eval-views",
        "0",
        "--lambda-obj-share",
        "0.25",
        "--shadows",
        "off",
        "--print-config",
    ]);
    ok(&out);
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(
        text.contains("iters = 2") && text.contains("batch_samples = 4096"),
        "{text}"
    );
    assert!(
        !tmp.path().join("unused.assist").exists(),
        "--print-config trains nothing"
    );
    let cfg = tmp.path().join("train.toml");
    std::fs::write(&cfg, &text).unwrap();
    // The file's dataset, iterations and batch; the command line's --out and --iters.
    let t = tmp.path().join("t.assist");
    let out = run(&[
        "train",
        "--config",
        s(&cfg),
        "--out",
        s(&t),
        "--iters",
        "3",
        "--json",
    ]);
    ok(&out);
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["iterations"], 3, "{v}");
    let info = common::scene_info(&t);
    assert_eq!(info["options"]["batch_samples"], 4096, "{info}");
    // A loss weight and an option of the term table and the config, through the file.
    assert_eq!(info["options"]["lambdas"]["obj_share"], 0.25, "{info}");
    assert_eq!(info["train_config"]["lambda_obj_share"], 0.25, "{info}");
    assert_eq!(info["train_config"]["shadows"], "off", "{info}");
    // What was drawn for the objects: enough to bring them to the least share asked for.
    let (share, extra) = (
        info["object_rays"]["share"].as_f64().unwrap(),
        info["object_rays"]["extra"].as_f64().unwrap(),
    );
    let least = info["train_config"]["object_rays"].as_f64().unwrap();
    assert!(share > 0.0 && share < least, "{info}");
    assert!(
        (extra + (1.0 - extra) * share - least).abs() < 1e-9,
        "{info}"
    );
    // The learning-rate floor left to the scene: 1e-3 with a bounded background (this
    // capture has depth), 3e-3 with an unbounded one; recorded as used.
    let lr_end = |info: &serde_json::Value| info["options"]["lr_end"].as_f64().unwrap() as f32;
    assert_eq!(lr_end(&info), 1e-3, "{info}");
    assert_eq!(
        info["train_config"]["lr_end"].as_f64().unwrap() as f32,
        1e-3
    );
    let u = tmp.path().join("u.assist");
    let unbounded = |extra: &[&str]| {
        let mut args = vec!["train", s(&data), "--out", s(&u), "--iters", "1"];
        args.extend_from_slice(&["--eval-views", "0", "--background", "contracted", "--force"]);
        args.extend_from_slice(extra);
        ok(&run(&args));
        common::scene_info(&u)
    };
    let info = unbounded(&[]);
    assert_eq!(lr_end(&info), 3e-3, "{info}");
    assert_eq!(
        info["train_config"]["lr_end"].as_f64().unwrap() as f32,
        3e-3
    );
    // A floor given is kept.
    assert_eq!(lr_end(&unbounded(&["--lr-end", "2e-3"])), 2e-3);
    // So is the pruning: off where the background is bounded, 1e-4 where it is not.
    let prune = |info: &serde_json::Value| info["options"]["prune_eps"].as_f64().unwrap() as f32;
    assert_eq!(prune(&common::scene_info(&t)), 0.0);
    let info = unbounded(&[]);
    assert_eq!(prune(&info), 1e-4, "{info}");
    assert_eq!(
        info["train_config"]["prune_eps"].as_f64().unwrap() as f32,
        1e-4
    );
    assert_eq!(prune(&unbounded(&["--prune-eps", "0"])), 0.0);
    // And the proposal: none with a bounded background, 24 samples a ray drawn from one
    // with an unbounded background (saved with it), none when told 0.
    let proposal = |info: &serde_json::Value| info["options"]["proposal_samples"].as_u64().unwrap();
    let has_proposal = |scene: &std::path::Path| {
        let bytes = std::fs::read(scene.join("fields").join("background.safetensors")).unwrap();
        String::from_utf8_lossy(&bytes[..bytes.len().min(1 << 16)]).contains("\"proposal\"")
    };
    let info = common::scene_info(&t);
    assert_eq!(
        (proposal(&info), &info["train_config"]["proposal"]),
        (0, &0.into())
    );
    assert!(!has_proposal(&t));
    let info = unbounded(&[]);
    assert_eq!(proposal(&info), 24, "{info}");
    assert_eq!(info["train_config"]["proposal"], 24, "{info}");
    assert!(has_proposal(&u));
    assert_eq!(proposal(&unbounded(&["--proposal", "0"])), 0);
    assert!(!has_proposal(&u));
    // And the error map's share: none with a bounded background, half with an unbounded
    // one, and what is given.
    let error_rays = |info: &serde_json::Value| info["options"]["error_rays"].as_f64().unwrap();
    let info = common::scene_info(&t);
    assert_eq!(
        (error_rays(&info), &info["train_config"]["error_rays"]),
        (0.0, &0.0.into())
    );
    let info = unbounded(&[]);
    assert_eq!(error_rays(&info), 0.5, "{info}");
    assert_eq!(info["train_config"]["error_rays"], 0.5, "{info}");
    assert_eq!(error_rays(&unbounded(&["--error-rays", "0"])), 0.0);
    // And the background's finest grid resolution: Nerfacto's 2048 unless given; auto
    // (one cell per pixel at the views' median depth) within 2048 and 8192; recorded as
    // used and saved in the field's config.
    let res = |info: &serde_json::Value| info["train_config"]["grid_resolution"].as_u64();
    assert_eq!(res(&common::scene_info(&t)), Some(2048));
    let info = unbounded(&["--grid-resolution", "auto"]);
    assert!(
        res(&info).is_some_and(|r| (2048..=8192).contains(&r)),
        "{info}"
    );
    let info = unbounded(&["--grid-resolution", "4096"]);
    assert_eq!(info["train_config"]["grid_resolution"], 4096, "{info}");
    let bytes = std::fs::read(u.join("fields").join("background.safetensors")).unwrap();
    let head = String::from_utf8_lossy(&bytes[..bytes.len().min(1 << 16)]).replace('\\', "");
    assert!(head.contains("\"max_resolution\":4096"), "{head}");
    // Out of range: refused with an error naming the flag and its limit, nothing written.
    let none = tmp.path().join("none.assist");
    let refused = |flag: &str, value: &str, limit: &str| {
        let o = run(&["train", s(&data), "--out", s(&none), flag, value]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(
            !o.status.success() && err.contains(flag) && err.contains(limit),
            "{err}"
        );
        assert!(!none.exists());
    };
    refused("--grid-resolution", "8", "65536");
    refused("--error-rays", "0.95", "0.9");
    let o = run(&[
        "train",
        s(&data),
        "--out",
        s(&u),
        "--proposal",
        "2000",
        "--force",
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("--proposal") && err.contains("1024"),
        "{err}"
    );
    let o = run(&[
        "train",
        s(&data),
        "--out",
        s(&u),
        "--prune-eps",
        "1",
        "--force",
    ]);
    assert!(
        !o.status.success() && String::from_utf8_lossy(&o.stderr).contains("--prune-eps"),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );

    // The hash tables' decay: none unless given, then as given and recorded; a negative
    // one refused by name.
    let decay = |info: &serde_json::Value| info["options"]["grid_decay"].as_f64().unwrap() as f32;
    assert_eq!(decay(&common::scene_info(&t)), 0.0);
    assert_eq!(decay(&unbounded(&["--layout", "facing"])), 0.0);
    // The synthetic capture's cameras stand all around its table. Trained unbounded, with
    // its objects or without, it is the walk-around the defaults are for (the finest level
    // matched to the pixels, the decay, Nerfacto's distortion weight) unless told
    // `--layout facing` or given each; bounded (its depth maps) it takes none of them.
    // Recorded as used.
    let dist = |info: &serde_json::Value| {
        info["options"]["lambdas"]["distortion"].as_f64().unwrap() as f32
    };
    let info = common::scene_info(&t);
    assert_eq!(info["train_config"]["layout"], "walk-around", "{info}");
    assert_eq!(
        (decay(&info), dist(&info), res(&info)),
        (0.0, 0.0, Some(2048))
    );
    let info = unbounded(&[]);
    assert_eq!(info["train_config"]["layout"], "walk-around", "{info}");
    assert_eq!((decay(&info), dist(&info)), (1e-6, 0.002), "{info}");
    assert!((2048..=8192).contains(&res(&info).unwrap()), "{info}");
    let info = unbounded(&["--no-objects"]);
    assert_eq!((decay(&info), dist(&info)), (1e-6, 0.002), "{info}");
    assert_eq!(
        info["train_config"]["grid_decay"].as_f64().unwrap() as f32,
        1e-6
    );
    let auto_cells = res(&info).unwrap();
    assert!((2048..=8192).contains(&auto_cells), "{info}");
    let info = unbounded(&["--no-objects", "--layout", "facing"]);
    assert_eq!(info["train_config"]["layout"], "facing", "{info}");
    assert_eq!(
        (decay(&info), dist(&info), res(&info)),
        (0.0, 0.0, Some(2048))
    );
    let given = [
        "--no-objects",
        "--grid-decay",
        "0",
        "--lambda-distortion",
        "0.01",
        "--grid-resolution",
        "3000",
    ];
    let info = unbounded(&given);
    assert_eq!(
        (decay(&info), dist(&info), res(&info)),
        (0.0, 0.01, Some(3000))
    );
    let info = unbounded(&["--grid-decay", "1e-6"]);
    assert_eq!(decay(&info), 1e-6, "{info}");
    assert_eq!(
        info["train_config"]["grid_decay"].as_f64().unwrap() as f32,
        1e-6
    );
    let o = run(&[
        "train",
        s(&data),
        "--out",
        s(&u),
        "--grid-decay=-1",
        "--force",
    ]);
    assert!(
        !o.status.success() && String::from_utf8_lossy(&o.stderr).contains("--grid-decay"),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );

    let bad = tmp.path().join("bad.toml");
    std::fs::write(&bad, "colour = 3\n").unwrap();
    let o = run(&["train", s(&data), "--out", s(&t), "--config", s(&bad)]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        !o.status.success() && err.contains("colour") && err.contains("bad.toml"),
        "{err}"
    );

    let rc = tmp.path().join("render.toml");
    std::fs::write(
        &rc,
        "outputs = [\"rgb\", \"depth\"]\nsize = \"40x30\"\nframes = 2\n",
    )
    .unwrap();
    let r = tmp.path().join("r");
    let out = run(&[
        "render",
        s(&scene),
        "--out",
        s(&r),
        "--config",
        s(&rc),
        "--json",
    ]);
    ok(&out);
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["views"], 2, "{v}");
    assert!(r.join("depth").is_dir() && !r.join("panoptic").exists());
}
