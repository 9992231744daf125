//! Actions: JSON shape, validation against a scene, units and frames, composition of
//! cascaded edits, resting placement for swaps, and undo/redo.

use std::collections::BTreeSet;

use assist_core::action::NoSources;
use assist_core::edit::{History, apply, world_aabb};
use assist_core::{Action, DMat3, DQuat, DVec3, Edit, Obb, Scene, SceneNode};

fn scene() -> Scene {
    let n = |id: u16, at: [f64; 3], half: [f64; 3], yaw: f64| {
        SceneNode::from_obb(
            id,
            &format!("object {id}"),
            &format!("f{id}"),
            &Obb::new(
                DVec3::from_array(at),
                DVec3::from_array(half) * 2.0,
                DMat3::from_rotation_z(yaw),
            ),
        )
    };
    Scene {
        nodes: vec![
            n(0, [0.0, 0.0, 0.0], [2.0, 2.0, 1.0], 0.0),
            n(1, [0.0, 0.0, 0.8], [0.05, 0.05, 0.05], 0.3),
            n(2, [0.5, 0.0, 0.9], [0.05, 0.05, 0.15], 0.0),
        ],
        up: DVec3::Z,
        meters_per_unit: 0.5,
        background_color: [0.0; 3],
        backdrop: Default::default(),
        selected: None,
        near: 0.0,
        classes: Vec::new(),
        light: None,
        relight: false,
    }
}

fn validate(s: &Scene, json: &str) -> Result<Edit, String> {
    let a: Action = serde_json::from_str(json).map_err(|e| e.to_string())?;
    a.validate(s, &mut NoSources, &BTreeSet::new())
        .map_err(|e| e.to_string())
}

fn run(s: &mut Scene, json: &str) {
    let e = validate(s, json).unwrap();
    apply(s, &e).unwrap();
}

#[test]
fn json_shape_is_exactly_instance_id_operation_config() {
    let a: Action = serde_json::from_str(
        r#"{"instance_id": 3, "operation": "translate", "config": {"offset": [-0.17, 0.12, 0.0]}}"#,
    )
    .unwrap();
    let v = serde_json::to_value(&a).unwrap();
    let keys: Vec<&String> = v.as_object().unwrap().keys().collect();
    assert_eq!(keys, ["config", "instance_id", "operation"]);
    assert_eq!(
        v["config"],
        serde_json::json!({"offset": [-0.17, 0.12, 0.0]})
    );
    assert!(
        serde_json::from_str::<Action>(r#"{"instance_id": 1, "operation": "fly", "config": {}}"#)
            .is_err()
    );
    assert!(
        serde_json::from_str::<Action>(
            r#"{"instance_id": 1, "operation": "delete", "config": {}, "extra": 1}"#
        )
        .is_err()
    );
}

#[test]
fn units_are_converted_through_meters_per_unit() {
    // One world unit is half a metre: 10 cm is 0.2 units.
    let s = scene();
    match validate(&s, r#"{"instance_id":1,"operation":"translate","config":{"axis":"x","distance":10,"unit":"cm"}}"#).unwrap() {
        Edit::Translate { offset, .. } => assert!((offset - DVec3::new(0.2, 0.0, 0.0)).length() < 1e-12),
        e => panic!("{e:?}"),
    }
    match validate(
        &s,
        r#"{"instance_id":1,"operation":"translate","config":{"vector":[1,2,3],"unit":"units"}}"#,
    )
    .unwrap()
    {
        Edit::Translate { offset, .. } => assert_eq!(offset, DVec3::new(1.0, 2.0, 3.0)),
        e => panic!("{e:?}"),
    }
    match validate(
        &s,
        r#"{"instance_id":1,"operation":"rotate","config":{"axis":"z","angle":1.5,"unit":"rad"}}"#,
    )
    .unwrap()
    {
        Edit::Rotate { angle, .. } => assert_eq!(angle, 1.5),
        e => panic!("{e:?}"),
    }
}

#[test]
fn object_frame_axes_follow_the_node() {
    let s = scene();
    // Node 1 is yawed by 0.3 rad: its own x axis is (cos 0.3, sin 0.3, 0).
    match validate(&s, r#"{"instance_id":1,"operation":"translate","config":{"axis":"x","distance":1,"unit":"units","frame":"object"}}"#).unwrap() {
        Edit::Translate { offset, .. } => {
            assert!((offset - DVec3::new(0.3f64.cos(), 0.3f64.sin(), 0.0)).length() < 1e-12)
        }
        e => panic!("{e:?}"),
    }
    // A world axis 17° off the node's axes is refused for per-axis scaling (it would shear).
    assert!(
        validate(
            &s,
            r#"{"instance_id":1,"operation":"scale","config":{"axis":"x","factor":2}}"#
        )
        .is_ok()
    );
    let mut s2 = s.clone();
    run(
        &mut s2,
        r#"{"instance_id":1,"operation":"rotate","config":{"degrees":30}}"#,
    );
    let e = validate(
        &s2,
        r#"{"instance_id":1,"operation":"scale","config":{"axis":"x","factor":2}}"#,
    )
    .unwrap_err();
    assert!(e.contains("shear"), "{e}");
}

#[test]
fn invalid_values_are_refused_with_the_field_named() {
    let s = scene();
    let cases = [
        (
            r#"{"instance_id":1,"operation":"scale","config":{"factor":0}}"#,
            "config.factor",
        ),
        (
            r#"{"instance_id":1,"operation":"scale","config":{"factors":[1,-1,1]}}"#,
            "config.factors",
        ),
        (
            r#"{"instance_id":1,"operation":"translate","config":{"axis":"w","distance":1}}"#,
            "config.axis",
        ),
        (
            r#"{"instance_id":1,"operation":"translate","config":{"axis":"x","distance":1,"unit":"furlong"}}"#,
            "config.unit",
        ),
        (
            r#"{"instance_id":1,"operation":"translate","config":{"axis":"x","distance":1,"vector":[1,0,0]}}"#,
            "not both",
        ),
        (
            r#"{"instance_id":1,"operation":"rotate","config":{"axis":[0,0,0],"degrees":5}}"#,
            "non-zero",
        ),
        (
            r#"{"instance_id":1,"operation":"rotate","config":{"degrees":5,"radians":1}}"#,
            "only one",
        ),
        (
            r#"{"instance_id":1,"operation":"delete","config":{"factor":2}}"#,
            "not a field of delete",
        ),
        (
            r#"{"instance_id":1,"operation":"swap","config":{"with":1}}"#,
            "two different",
        ),
        (
            r#"{"instance_id":1,"operation":"replicate","config":{"new_id":2}}"#,
            "already used",
        ),
        (
            r#"{"instance_id":7,"operation":"select","config":{}}"#,
            "instance_id 7: no such node",
        ),
        (
            r#"{"instance_id":0,"operation":"add","config":{"scene":"x.assist","node":1}}"#,
            "x.assist",
        ),
    ];
    for (json, want) in cases {
        let e = validate(&s, json).unwrap_err();
        assert!(e.contains(want), "{json}: {e:?} does not say {want:?}");
    }
}

#[test]
fn cascaded_edits_compose() {
    // scale ×2, move +x, rotate 90° about z: the box's corners follow the product.
    let mut s = scene();
    let before = s.node(2).unwrap().clone();
    run(
        &mut s,
        r#"{"instance_id":2,"operation":"scale","config":{"factor":2}}"#,
    );
    run(
        &mut s,
        r#"{"instance_id":2,"operation":"translate","config":{"vector":[0.5,0,0],"unit":"units"}}"#,
    );
    run(
        &mut s,
        r#"{"instance_id":2,"operation":"rotate","config":{"axis":"z","degrees":90}}"#,
    );
    let after = s.node(2).unwrap();
    let q = DQuat::from_rotation_z(std::f64::consts::FRAC_PI_2);
    let centre = before.world_from_local.translation + DVec3::new(0.5, 0.0, 0.0);
    for (p, c) in before
        .local_aabb()
        .corners()
        .iter()
        .zip(after.world_corners())
    {
        let want = centre + q * (before.world_from_local.rotation * (*p * 2.0));
        assert!((want - c).length() < 1e-12, "{want} vs {c}");
    }
    // A pivot other than the centre moves the centre around it.
    let mut s = scene();
    run(
        &mut s,
        r#"{"instance_id":2,"operation":"rotate","config":{"axis":"z","degrees":180,"center":[0,0,0.9]}}"#,
    );
    assert!(
        (s.node(2).unwrap().world_from_local.translation - DVec3::new(-0.5, 0.0, 0.9)).length()
            < 1e-12
    );
}

#[test]
fn swap_rests_each_where_the_other_stood() {
    let mut s = scene();
    let (a, b) = (s.node(1).unwrap().clone(), s.node(2).unwrap().clone());
    run(
        &mut s,
        r#"{"instance_id":1,"operation":"swap","config":{"with":2}}"#,
    );
    let (a2, b2) = (s.node(1).unwrap(), s.node(2).unwrap());
    // Across the floor: exchanged. Bottoms: each at the other's bottom height.
    let xy = |n: &SceneNode| n.world_from_local.translation.truncate();
    assert!((xy(a2) - xy(&b)).length() < 1e-12 && (xy(b2) - xy(&a)).length() < 1e-12);
    assert!((world_aabb(a2).min.z - world_aabb(&b).min.z).abs() < 1e-12);
    assert!((world_aabb(b2).min.z - world_aabb(&a).min.z).abs() < 1e-12);
}

#[test]
fn replicate_finds_a_free_spot_and_to_action_round_trips() {
    let mut s = scene();
    let e = validate(
        &s,
        r#"{"instance_id":1,"operation":"replicate","config":{}}"#,
    )
    .unwrap();
    apply(&mut s, &e).unwrap();
    let copy = world_aabb(s.node(3).unwrap());
    for id in [1, 2] {
        let o = world_aabb(s.node(id).unwrap());
        let overlap = (copy.min.cmplt(o.max) & o.min.cmplt(copy.max)).all();
        assert!(!overlap, "the copy overlaps node {id}");
    }
    // Every edit written back as an action validates to the same edit.
    let s0 = scene();
    for json in [
        r#"{"instance_id":1,"operation":"translate","config":{"axis":"y","distance":3,"unit":"cm"}}"#,
        r#"{"instance_id":1,"operation":"rotate","config":{"axis":[1,1,0],"degrees":33}}"#,
        r#"{"instance_id":2,"operation":"scale","config":{"factors":[1,2,3]}}"#,
        r#"{"instance_id":1,"operation":"replicate","config":{}}"#,
        r#"{"instance_id":2,"operation":"swap","config":{"with":1}}"#,
    ] {
        let e = validate(&s0, json).unwrap();
        let back = serde_json::to_string(&e.to_action(s0.meters_per_unit)).unwrap();
        let e2 = validate(&s0, &back).unwrap();
        match (&e, &e2) {
            (Edit::Translate { offset: a, .. }, Edit::Translate { offset: b, .. })
            | (Edit::Replicate { offset: a, .. }, Edit::Replicate { offset: b, .. }) => {
                assert!((*a - *b).length() < 1e-12, "{json} → {back}")
            }
            (
                Edit::Rotate {
                    axis: a, angle: x, ..
                },
                Edit::Rotate {
                    axis: b, angle: y, ..
                },
            ) => {
                assert!(
                    (*a - *b).length() < 1e-12 && (x - y).abs() < 1e-12,
                    "{json} → {back}"
                )
            }
            _ => assert_eq!(e, e2, "{json} → {back}"),
        }
    }
}

#[test]
fn history_undoes_and_redoes_exactly() {
    let mut s = scene();
    let original = s.clone();
    let mut h = History::default();
    for json in [
        r#"{"instance_id":1,"operation":"translate","config":{"vector":[0.1,0.2,0.3]}}"#,
        r#"{"instance_id":2,"operation":"delete","config":{}}"#,
        r#"{"instance_id":1,"operation":"select","config":{}}"#,
    ] {
        let e = validate(&s, json).unwrap();
        h.apply(&mut s, &e).unwrap();
    }
    let edited = s.clone();
    assert_eq!(s.selected, Some(1));
    while h.undo(&mut s) {}
    assert_eq!(s, original);
    while h.redo(&mut s) {}
    assert_eq!(s, edited);
    // A new edit after undo drops the redo list.
    h.undo(&mut s);
    let e = validate(&s, r#"{"instance_id":1,"operation":"delete","config":{}}"#).unwrap();
    h.apply(&mut s, &e).unwrap();
    assert!(!h.redo(&mut s));
}

/// A copy is named "mug 2", "mug 3" and keeps the class "mug"; class ids stay what they were
/// when a class's last node is deleted, and after undo.
#[test]
fn replicas_are_numbered_and_class_ids_are_stable() {
    let mut s = scene();
    s.nodes[1].label = "mug".into();
    s.nodes[2].label = "book".into();
    let mut h = History::default();
    let before = s.class_names();
    assert_eq!(before, ["background", "mug", "book"]);
    for _ in 0..2 {
        let e = validate(
            &s,
            r#"{"instance_id":1,"operation":"replicate","config":{}}"#,
        )
        .unwrap();
        h.apply(&mut s, &e).unwrap();
    }
    let copies: Vec<(&str, &str)> = s.nodes[3..]
        .iter()
        .map(|n| (n.label.as_str(), n.class_name()))
        .collect();
    assert_eq!(copies, [("mug 2", "mug"), ("mug 3", "mug")]);
    // A copy of a copy is a "mug" too, with the next free number.
    let e = validate(
        &s,
        r#"{"instance_id":4,"operation":"replicate","config":{}}"#,
    )
    .unwrap();
    h.apply(&mut s, &e).unwrap();
    assert_eq!(
        (s.nodes[5].label.as_str(), s.nodes[5].class_name()),
        ("mug 4", "mug")
    );
    assert_eq!(s.class_names(), before, "copies add no class");
    // Deleting every mug keeps "book" at class 2.
    for id in [1, 3, 4, 5] {
        let e = validate(
            &s,
            &format!(r#"{{"instance_id":{id},"operation":"delete"}}"#),
        )
        .unwrap();
        h.apply(&mut s, &e).unwrap();
    }
    assert_eq!(s.class_names(), before);
    // A "book" brought in from another scene is "book 2", of class "book".
    let mut node = s.node(2).unwrap().clone();
    node.id = 9;
    let add = Edit::Add {
        imported: assist_core::action::Imported {
            node,
            source: "other.assist".into(),
            source_field: "f2".into(),
            source_id: 2,
        },
    };
    h.apply(&mut s, &add).unwrap();
    let n = s.node(9).unwrap();
    assert_eq!((n.label.as_str(), n.class_name()), ("book 2", "book"));
    // The scene file keeps the list.
    let back: Scene = serde_json::from_str(&serde_json::to_string(&s).unwrap()).unwrap();
    assert_eq!(back.class_names(), before);
}

/// An object moved down into a table (a thin opaque shell at z = 0.75, its resting
/// height, with a hole where the object hid it) sinks by what it moved; resting on it, or
/// moved off its edge, it does not.
#[test]
fn sinking_depth_measures_how_far_a_base_is_below_the_support() {
    use assist_core::edit::sinking_depth;
    let s = scene(); // 0.5 m per unit; node 1 rests at z = 0.75, 0.1 units wide
    let table = |pts: &[DVec3]| {
        pts.iter()
            .map(|p| {
                let shell = (0.74..0.75).contains(&p.z) && p.x < 1.0;
                let hole = p.x.abs() < 0.06 && p.y.abs() < 0.06;
                if shell && !hole { 3000.0f32 } else { 0.0 }
            })
            .collect::<Vec<_>>()
    };
    let n = s.node(1).unwrap().clone();
    let depth = |n: &SceneNode| sinking_depth(n, s.up, s.meters_per_unit, &mut |p| table(p));
    let rest = depth(&n).expect("the table is found");
    assert!(rest <= 0.0026, "resting on the table: {rest} m");
    for (down_units, metres) in [(0.04, 0.02), (0.1, 0.05)] {
        let mut m = n.clone();
        m.world_from_local.translation.z -= down_units;
        let d = depth(&m).unwrap();
        assert!(
            (d - metres).abs() <= 0.0026,
            "{down_units} units down: {d} m"
        );
    }
    // Far below the table it is out of reach: nothing is found.
    let mut m = n.clone();
    m.world_from_local.translation.z -= 1.0;
    assert_eq!(depth(&m), None);
    // Moved down past the table's edge (x = 1): nothing under it.
    let mut m = n.clone();
    m.world_from_local.translation += DVec3::new(1.5, 0.0, -0.1);
    assert_eq!(depth(&m), None);
    // Lying on its side (turned 90° about x), then moved down 2 cm.
    let mut m = n.clone();
    m.world_from_local.rotation = DQuat::from_rotation_x(std::f64::consts::FRAC_PI_2);
    m.world_from_local.translation.z -= 0.04;
    let d = depth(&m).unwrap();
    assert!((d - 0.02).abs() <= 0.0026, "{d}");
}

/// Issue 47, item 6: an edit that pushed one object into another or left it floating
/// said nothing. Each is found against the scene before the edit: the overlap by the
/// boxes' depth of interpenetration, the gap down to the table (a shell at z = 0.75 with a
/// hole where the object hid it) or to the top of an object under it.
#[test]
fn placement_problems_find_overlaps_and_floating_objects() {
    use assist_core::placement::{Problem, penetration, placement_problems};
    let before = scene(); // 0.5 m per unit; node 1 rests at z = 0.75, node 2 beside it
    let mut table = |pts: &[DVec3]| {
        pts.iter()
            .map(|p| {
                let shell = (0.74..0.75).contains(&p.z);
                let hole = p.x.abs() < 0.06 && p.y.abs() < 0.06;
                if shell && !hole { 3000.0f32 } else { 0.0 }
            })
            .collect::<Vec<_>>()
    };
    let moved = |id: u16, by: [f64; 3]| {
        let mut s = before.clone();
        s.node_mut(id).unwrap().world_from_local.translation += DVec3::from_array(by);
        s
    };
    // Apart, then 0.05 units (2.5 cm) into node 2 along x.
    let (a, b) = (before.node(1).unwrap(), before.node(2).unwrap());
    assert_eq!(penetration(a, b), 0.0);
    let mut c = b.clone();
    c.world_from_local.translation = a.world_from_local.translation + DVec3::new(0.1, 0.0, 0.0);
    // Along x, node 1 (turned 0.3 rad) reaches 0.05 (cos 0.3 + sin 0.3) = 0.0626 from its
    // centre and c 0.05, 0.1 apart: 0.0126 deep, the least of the 15 axes.
    let want = 0.05 * (0.3f64.cos() + 0.3f64.sin()) + 0.05 - 0.1;
    assert!(
        (penetration(a, &c) - want).abs() < 1e-9,
        "{}",
        penetration(a, &c)
    );
    // Nothing moved, or moved along the table: no problem.
    assert!(
        placement_problems(&before, &before, &mut table)
            .0
            .is_empty()
    );
    assert!(
        placement_problems(&before, &moved(1, [0.0, -0.3, 0.0]), &mut table)
            .0
            .is_empty()
    );
    // Into node 2 (it stands at x = 0.5): an overlap of about 0.1 units = 5 cm.
    let p = placement_problems(&before, &moved(1, [0.45, 0.0, 0.05]), &mut table).0;
    assert!(
        matches!(p.as_slice(), [q] if matches!(q.problem, Problem::Overlap { other: 2, depth_m, .. } if depth_m > 0.03)),
        "{p:?}"
    );
    // 0.24 units (12 cm) up: floating about 12 cm above the table.
    let p = placement_problems(&before, &moved(1, [0.0, 0.0, 0.24]), &mut table).0;
    match p.as_slice() {
        [q] => match q.problem {
            Problem::Floating {
                gap_m,
                support: None,
            } => assert!((gap_m - 0.12).abs() < 0.01, "{gap_m}"),
            _ => panic!("{q:?}"),
        },
        _ => panic!("{p:?}"),
    }
    // On top of node 2 (its top at z = 1.05): carried by it; 0.2 units above it: floating
    // above node 2.
    let top = 1.05 + 0.05 - 0.8;
    let p = placement_problems(&before, &moved(1, [0.5, 0.0, top]), &mut table).0;
    assert!(p.is_empty(), "{p:?}");
    let p = placement_problems(&before, &moved(1, [0.5, 0.0, top + 0.2]), &mut table).0;
    assert!(
        matches!(p.as_slice(), [q] if q.problem == Problem::Floating { gap_m: 0.1, support: Some(2) } || matches!(q.problem, Problem::Floating { support: Some(2), gap_m } if (gap_m - 0.1).abs() < 1e-6)),
        "{p:?}"
    );
}

/// Issue 47, item 14: replication had no bound (66,000 actions did not finish). A scene
/// holds at most `MAX_NODES` nodes: one more replicate or add is refused, naming the
/// count; an error listing the nodes of a huge scene names the first few only.
#[test]
fn a_scene_holds_a_bounded_number_of_nodes() {
    let mut s = scene();
    let proto = s.node(1).unwrap().clone();
    let mut id = 100u16;
    while s.nodes.len() < assist_core::scene::MAX_NODES {
        let mut n = proto.clone();
        n.id = id;
        s.nodes.push(n);
        id += 1;
    }
    let e = validate(
        &s,
        r#"{"instance_id": 1, "operation": "replicate", "config": {}}"#,
    )
    .unwrap_err();
    assert!(e.contains("the most a scene may hold"), "{e}");
    let e = validate(
        &s,
        r#"{"instance_id": 7, "operation": "delete", "config": {}}"#,
    )
    .unwrap_err();
    assert!(
        e.contains("more)") && e.len() < 2000,
        "{} bytes: {e}",
        e.len()
    );
    // One fewer: replication goes through.
    s.nodes.pop();
    validate(
        &s,
        r#"{"instance_id": 1, "operation": "replicate", "config": {}}"#,
    )
    .unwrap();
}
