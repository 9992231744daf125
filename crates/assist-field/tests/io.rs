//! Safetensors round trip, and clear errors (never a panic) for truncated, foreign or
//! mismatched files.

use assist_field::io::{from_bytes, load, save, to_bytes};
use assist_field::{Field, FieldConfig, OccupancyGrid};
use assist_testkit::TempDir;
use std::path::Path;

fn small() -> FieldConfig {
    FieldConfig {
        levels: 4,
        log2_table_size: 10,
        base_resolution: 4,
        max_resolution: 64,
        hidden: 16,
        color_hidden: 16,
        appearance_dim: 4,
        num_images: 3,
        ..FieldConfig::nerfacto(3)
    }
}

#[test]
fn round_trip_with_occupancy() {
    let tmp = TempDir::new("field-io");
    let field = Field::new(small(), 11).unwrap();
    let mut occ = OccupancyGrid::new(8);
    let sigma: Vec<f32> = (0..occ.cells()).map(|i| (i % 7) as f32 * 0.01).collect();
    occ.update_from(&sigma);
    let p = tmp.join("f.safetensors");
    save(&p, &field, Some(&occ)).unwrap();
    let (back, occ2) = load(&p).unwrap();
    assert_eq!(back.config, field.config);
    assert_eq!(back.params, field.params);
    let occ2 = occ2.unwrap();
    assert_eq!(occ2.bits, occ.bits);
    assert_eq!(occ2.density, occ.density);
    // A grid in warm-up: its warming cells load as occupied (saved as never measured),
    // whatever their estimate, and the others as they are.
    let mut warm = OccupancyGrid::new(8);
    warm.start_warmup(4);
    warm.update_from(&vec![0.0; warm.cells()]);
    assert_eq!(warm.occupied_fraction(), 1.0);
    warm.warmup[..256].fill(0);
    warm.refresh_bits();
    save(&p, &field, Some(&warm)).unwrap();
    let occ3 = load(&p).unwrap().1.unwrap();
    assert_eq!(occ3.bits, warm.bits);
    assert_eq!(occ3.occupied_fraction(), 0.5);
    // Without occupancy.
    let bytes = to_bytes(&field, None).unwrap();
    assert!(from_bytes(Path::new("x"), &bytes).unwrap().1.is_none());
}

#[test]
fn shadow_grid_round_trips_and_bad_values_are_named() {
    use assist_field::ShadeGrid;
    use assist_field::io::{from_bytes_node, to_bytes_node};
    let field = Field::new(small(), 3).unwrap();
    let mut g = ShadeGrid::new(4, 2.5);
    for (i, v) in g.values.iter_mut().enumerate() {
        *v = 0.1 + (i % 9) as f32 * 0.1;
    }
    let bytes = to_bytes_node(&field, None, Some(&g), None).unwrap();
    let l = from_bytes_node(Path::new("x"), &bytes).unwrap();
    assert!(l.occupancy.is_none() && l.proposal.is_none());
    assert_eq!(l.shade.as_ref(), Some(&g));
    // A file without one loads without one; the plain reader ignores it.
    let plain = to_bytes(&field, None).unwrap();
    assert!(
        from_bytes_node(Path::new("x"), &plain)
            .unwrap()
            .shade
            .is_none()
    );
    assert!(from_bytes(Path::new("x"), &bytes).is_ok());
    // A file written before the factors had colour (one per lattice point, `[r, r, r]`)
    // loads with that factor in every channel.
    let st = safetensors::SafeTensors::deserialize(&bytes).unwrap();
    let (_, md) = safetensors::SafeTensors::read_metadata(&bytes).unwrap();
    let grey: Vec<f32> = (0..64).map(|i| 0.2 + 0.01 * i as f32).collect();
    let grey_bytes: Vec<u8> = grey.iter().flat_map(|v| v.to_le_bytes()).collect();
    let mut views: Vec<(String, safetensors::tensor::TensorView)> = st
        .tensors()
        .into_iter()
        .filter(|(n, _)| n != "shade")
        .collect();
    views.push((
        "shade".into(),
        safetensors::tensor::TensorView::new(safetensors::Dtype::F32, vec![4, 4, 4], &grey_bytes)
            .unwrap(),
    ));
    let old = safetensors::serialize(views, md.metadata().clone()).unwrap();
    let back = from_bytes_node(Path::new("x"), &old).unwrap().shade;
    assert_eq!(back, Some(ShadeGrid::from_grey(4, 2.5, &grey)));
    // A factor above 1 is refused with the tensor and the element named.
    g.values[5] = 1.7;
    let bad = to_bytes_node(&field, None, Some(&g), None).unwrap();
    let e = from_bytes_node(Path::new("node.safetensors"), &bad)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("node.safetensors") && e.contains("shade") && e.contains("value 5"),
        "{e}"
    );
}

/// The metadata a valid file of `small()` carries.
fn good_metadata() -> std::collections::HashMap<String, String> {
    let mut md = std::collections::HashMap::new();
    md.insert("format".to_string(), "assist-field".to_string());
    md.insert("version".to_string(), "1".to_string());
    md.insert(
        "config".to_string(),
        serde_json::to_string(&small()).unwrap(),
    );
    md
}

fn err(bytes: &[u8]) -> String {
    match from_bytes(Path::new("node.safetensors"), bytes) {
        Ok(_) => panic!("expected an error"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn bad_files_give_clear_errors() {
    let field = Field::new(small(), 1).unwrap();
    let good = to_bytes(&field, None).unwrap();
    // Truncated anywhere: header, middle, last byte.
    for cut in [0, 4, 20, good.len() / 2, good.len() - 1] {
        let e = err(&good[..cut]);
        assert!(
            e.contains("node.safetensors") && e.contains("not a valid safetensors"),
            "cut {cut}: {e}"
        );
    }
    // A config that disagrees with the tensors (different table size): shape mismatch.
    let other = Field::new(
        FieldConfig {
            log2_table_size: 9,
            ..small()
        },
        1,
    )
    .unwrap();
    let mut mixed = to_bytes(&other, None).unwrap();
    // Swap in the good file's config by re-serialising the other field's tensors under it.
    let (_, meta) = safetensors::SafeTensors::read_metadata(&good).unwrap();
    let _ = meta;
    let st = safetensors::SafeTensors::deserialize(&mixed).unwrap();
    let md = good_metadata();
    let views: Vec<(String, safetensors::tensor::TensorView)> = st.tensors();
    mixed = safetensors::serialize(views, Some(md)).unwrap();
    let e = err(&mixed);
    // (The file is too small for the config's parameters: refused before their shapes.)
    assert!(
        (e.contains("shape") && e.contains("expected")) || e.contains("asks for"),
        "{e}"
    );
    // Wrong format or version in the metadata.
    let st = safetensors::SafeTensors::deserialize(&good).unwrap();
    for (k, v, needle) in [
        ("format", "something-else", "metadata.format"),
        ("version", "99", "metadata.version"),
    ] {
        let mut md = good_metadata();
        md.insert(k.to_string(), v.to_string());
        let b = safetensors::serialize(st.tensors(), Some(md)).unwrap();
        let e = err(&b);
        assert!(e.contains(needle), "{e}");
    }
    // A forged config asking for a huge appearance table or hash grid is refused before
    // anything is allocated for it (it used to panic with a capacity overflow, or abort).
    for (k, v, needle) in [
        ("num_images", 1usize << 40, "num_images"),
        ("appearance_dim", 1 << 30, "appearance_dim"),
        ("num_images", 1 << 20, "asks for"),
        ("log2_table_size", 24, "asks for"),
    ] {
        let mut cfg = serde_json::to_value(small()).unwrap();
        cfg[k] = serde_json::json!(v);
        if k == "num_images" {
            cfg["appearance_dim"] = serde_json::json!(32);
        }
        let mut md = good_metadata();
        md.insert("config".to_string(), cfg.to_string());
        let b = safetensors::serialize(st.tensors(), Some(md)).unwrap();
        let e = err(&b);
        assert!(
            e.contains(needle) && e.contains("metadata.config"),
            "{k}: {e}"
        );
    }
    // A missing tensor, and an unknown one.
    let md = good_metadata();
    let fewer: Vec<_> = st
        .tensors()
        .into_iter()
        .filter(|(n, _)| n != "color.1.bias")
        .collect();
    let e = err(&safetensors::serialize(fewer, Some(md.clone())).unwrap());
    assert!(e.contains("color.1.bias") && e.contains("missing"), "{e}");
    let extra_data = vec![0u8; 8];
    let mut more = st.tensors();
    more.push((
        "mystery".to_string(),
        safetensors::tensor::TensorView::new(safetensors::tensor::Dtype::F32, vec![2], &extra_data)
            .unwrap(),
    ));
    let e = err(&safetensors::serialize(more, Some(md)).unwrap());
    assert!(e.contains("mystery") && e.contains("not part of"), "{e}");
    // Not a file at all.
    let e = load(Path::new("/nonexistent/x.safetensors"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("/nonexistent/x.safetensors"), "{e}");
}

#[test]
fn proposal_round_trips_and_bad_ones_are_named() {
    use assist_field::io::{from_bytes_node, to_bytes_node};
    use assist_field::{Proposal, ProposalConfig, ProposalField};
    let field = Field::new(small(), 3).unwrap();
    let cfg = ProposalConfig {
        log2_table_size: 10,
        max_resolution: 32,
        ..ProposalConfig::default()
    };
    let p = Proposal {
        field: ProposalField::new(cfg, 4).unwrap(),
        samples: 40,
    };
    let bytes = to_bytes_node(&field, None, None, Some(&p)).unwrap();
    let back = from_bytes_node(Path::new("x"), &bytes).unwrap().proposal;
    assert_eq!(back.as_ref(), Some(&p));
    // The same field without a proposal is another file, read back without one.
    let plain = to_bytes(&field, None).unwrap();
    assert_ne!(plain, bytes);
    assert!(
        from_bytes_node(Path::new("x"), &plain)
            .unwrap()
            .proposal
            .is_none()
    );
    // A value that is not finite is named, with the file.
    let mut bad = p.clone();
    bad.field.params[7] = f32::NAN;
    let bytes = to_bytes_node(&field, None, None, Some(&bad)).unwrap();
    let e = from_bytes_node(Path::new("node.safetensors"), &bytes)
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("node.safetensors") && e.contains("proposal") && e.contains("element 7"),
        "{e}"
    );
    // Samples per ray out of range are refused.
    let zero = Proposal { samples: 0, ..p };
    let bytes = to_bytes_node(&field, None, None, Some(&zero)).unwrap();
    let e = from_bytes_node(Path::new("x"), &bytes)
        .unwrap_err()
        .to_string();
    assert!(e.contains("metadata.proposal.samples"), "{e}");
}

/// Where each code's photograph was taken round-trips; a field without them loads
/// without; a file whose points do not match the codes is refused by name.
#[test]
fn anchors_round_trip_and_mismatches_are_named() {
    let mut field = Field::new(small(), 5).unwrap();
    let plain = to_bytes(&field, None).unwrap();
    assert!(
        from_bytes(Path::new("x"), &plain)
            .unwrap()
            .0
            .anchors
            .is_empty()
    );
    field.anchors = vec![[0.5, -1.0, 2.0], [1.5, 0.0, 0.25], [-3.0, 1.0, 0.0]];
    let bytes = to_bytes(&field, None).unwrap();
    let (back, _) = from_bytes(Path::new("x"), &bytes).unwrap();
    assert_eq!(back.anchors, field.anchors);
    assert_eq!(back.params, field.params);
    // Two points for three codes.
    field.anchors.pop();
    let bad = to_bytes(&field, None).unwrap();
    let err = from_bytes(Path::new("f.safetensors"), &bad)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("f.safetensors")
            && err.contains("appearance.anchors")
            && err.contains("[3, 3]"),
        "{err}"
    );
    // A point that is not finite.
    field.anchors = vec![[0.0; 3], [f32::NAN, 0.0, 0.0], [1.0; 3]];
    let bad = to_bytes(&field, None).unwrap();
    let err = from_bytes(Path::new("f.safetensors"), &bad)
        .unwrap_err()
        .to_string();
    assert!(err.contains("not finite"), "{err}");
}
