//! Planner settings: a JSON object of groups only, every field validated against a documented,
//! physically sane range, a guard that no field of the serde representation escapes
//! validation, and the keys of the flat settings of earlier versions refused by name.
#![allow(clippy::unwrap_used)]
#![recursion_limit = "512"]

use nudge_planner::PlannerSettings;
use nudge_planner::settings::{GROUPS, MOVED, REMOVED};
use serde_json::{Value, json};

/// Every leaf of the serialised defaults: (dotted key, default).
fn defaults() -> Vec<(String, Value)> {
    let Value::Object(groups) = serde_json::to_value(PlannerSettings::default()).unwrap() else {
        panic!("settings serialise as an object");
    };
    let mut out = Vec::new();
    for (g, fields) in groups {
        let Value::Object(fields) = fields else {
            panic!("group {g} is not an object");
        };
        for (k, v) in fields {
            out.push((format!("{g}.{k}"), v));
        }
    }
    out
}

/// `{"group": {"field": value}}` for the dotted `key`.
fn with(key: &str, value: Value) -> String {
    let (g, f) = key.split_once('.').unwrap();
    json!({ g: { f: value } }).to_string()
}

/// The defaults are valid and unchanged (the values every front end and result relies on).
#[test]
fn shipped_defaults_are_valid_and_unchanged() {
    let d = PlannerSettings::default();
    d.validate().unwrap();
    let expected = json!({
        "model": {"horizon": 6, "dt": 0.3, "l_f": 1.4, "l_r": 1.4},
        "cost": {"w_y": 15.0, "w_v": 3.0, "w_psi": 1.0, "w_delta": 3.0, "w_ddelta": 3.0,
                 "w_a": 1.0, "w_da": 1.0},
        "bounds": {"delta_max": 0.15, "ddelta_max": 0.05, "a_min": -5.0, "a_max": 3.0,
                   "da_max": 1.5, "v_max": 30.0, "edge_margin": 0.0, "heading_max": 0.2,
                   "heading_recovery": 0.05, "overshoot_max": 0.3},
        "safety": {"ellipse_scale": std::f64::consts::SQRT_2, "margin_x": 1.5, "margin_y": 0.3,
                   "ego_segment_length": 6.0, "brake_decel": 4.0, "check_range": 60.0,
                   "safety_min": 0.0, "ablate_reaction": false},
        "admm": {"rho": 1000.0, "max_iter": 30, "eps_primal": 0.01, "eps_change": 0.01,
                 "pgd_steps": 5, "pgd_halvings": 3, "pin_weight": 10000.0, "restore_step": 1.0,
                 "v_lin_min": 1.0},
        "repair": {"refine_iters": 5, "refine_margin": 0.02, "refine_trust_delta": 0.05,
                   "refine_trust_accel": 2.0, "fallback_speed_floor": 0.5,
                   "bounds_slack": 0.05, "lattice_min_speed": 10.0, "lead_min_speed": 10.0},
        "budget": {"seconds": 0.0, "calls": 0},
        "lane_ends": {"w_deadline": 60.0, "deadline_distance": 100.0, "stop_decel": 3.0,
                      "stop_margin": 12.0}
    });
    assert_eq!(serde_json::to_value(&d).unwrap(), expected);
    assert_eq!(PlannerSettings::from_json("{}").unwrap(), d);
    assert_eq!(
        PlannerSettings::from_json(r#"{"cost": {}, "model": {}}"#).unwrap(),
        d
    );
    // At most 60 leaves, in groups that follow the MPC call's phases.
    assert!(defaults().len() <= 60, "{} fields", defaults().len());
    let names: Vec<&str> = GROUPS.iter().map(|(g, _)| *g).collect();
    assert_eq!(
        names,
        [
            "model",
            "cost",
            "bounds",
            "safety",
            "admm",
            "repair",
            "budget",
            "lane_ends"
        ]
    );
}

/// `[7, 0.5, 2.0]` used to set horizon, dt and l_f positionally.
#[test]
fn settings_must_be_a_json_object() {
    for text in ["[7, 0.5, 2.0]", "[]", "7", "\"dt\"", "null", "true"] {
        let err = PlannerSettings::from_json(text)
            .err()
            .unwrap_or_else(|| panic!("{text} accepted"));
        assert!(err.to_string().contains("JSON object"), "{text}: {err}");
    }
    // A key given twice is ambiguous, at the top and inside a group.
    assert!(PlannerSettings::from_json(r#"{"model": {}, "model": {}}"#).is_err());
    assert!(PlannerSettings::from_json(r#"{"model": {"dt": 0.3, "dt": 0.5}}"#).is_err());
    // Unknown groups and fields are refused by name.
    let err = PlannerSettings::from_json(r#"{"costs": {}}"#).unwrap_err();
    assert!(err.to_string().contains("costs"), "{err}");
    let err = PlannerSettings::from_json(r#"{"cost": {"w_q": 1}}"#).unwrap_err();
    assert!(err.to_string().contains("w_q"), "{err}");
}

/// Every key of the flat settings of earlier versions is refused, naming where it moved or
/// why it was removed; each moved key's new path exists and takes the value.
#[test]
fn old_flat_keys_are_refused_with_their_new_place_or_the_reason() {
    let leaves: Vec<String> = defaults().into_iter().map(|(k, _)| k).collect();
    for (old, new) in MOVED {
        let err = PlannerSettings::from_json(&json!({ *old: 1 }).to_string()).unwrap_err();
        assert!(
            err.to_string()
                .contains(&format!("`{old}` moved: it is now `{new}`")),
            "{err}"
        );
        assert!(leaves.iter().any(|l| l == new), "{new} is not a field");
    }
    for (old, why) in REMOVED {
        let err = PlannerSettings::from_json(&json!({ *old: true }).to_string()).unwrap_err();
        assert!(
            err.to_string().contains(&format!("`{old}` was removed")),
            "{err}"
        );
        assert!(err.to_string().contains(why), "{err}");
        assert!(!leaves.iter().any(|l| l.ends_with(&format!(".{old}"))));
    }
    // Every leaf of today's settings came from somewhere: 52 moved, 40 removed of the 92.
    assert_eq!(MOVED.len() + REMOVED.len(), 92);
    assert_eq!(MOVED.len(), leaves.len());
}

/// Values from the defect report.
#[test]
fn reported_values_are_refused() {
    for (key, value) in [
        ("admm.pin_weight", json!(-1.0)),
        ("model.dt", json!(1e300)),
        ("bounds.v_max", json!(1e6)),
        ("model.l_f", json!(1e-300)),
        ("admm.max_iter", json!(u64::MAX)),
    ] {
        let err = PlannerSettings::from_json(&with(key, value.clone()))
            .err()
            .unwrap_or_else(|| panic!("{key} = {value} accepted"));
        assert!(err.to_string().contains(&format!("`{key}`")), "{err}");
    }
}

/// Every numeric field of the serde representation is validated: an absurd value (1e300, or
/// the largest integer) is refused naming that field, and so is a negative one where the
/// default is non-negative. A new field cannot be added without a validation.
#[test]
fn every_field_is_validated() {
    let mut numeric = 0;
    for (key, default) in defaults() {
        let absurd = match &default {
            Value::Bool(_) => continue, // every boolean value is valid
            Value::Number(n) if n.is_u64() => json!(u64::MAX),
            Value::Number(_) => json!(1e300),
            other => panic!("{key}: unexpected JSON type {other}"),
        };
        numeric += 1;
        let mut bad = vec![absurd];
        if default.as_f64().unwrap() >= 0.0 && !default.is_u64() {
            bad.push(json!(-1e300));
        }
        for value in bad {
            let err = PlannerSettings::from_json(&with(&key, value.clone()))
                .err()
                .unwrap_or_else(|| panic!("{key} = {value} accepted"));
            assert!(
                err.to_string().contains(&format!("`{key}`")),
                "{key} = {value}: {err}"
            );
        }
    }
    assert_eq!(numeric, 51, "numeric settings");
}

/// The documented range table covers exactly the numeric fields, each bound is enforced, and
/// each closed end point is accepted.
#[test]
fn range_table_matches_the_fields_and_is_enforced() {
    let all = defaults();
    let numeric: Vec<&str> = all
        .iter()
        .filter(|(_, v)| v.is_number())
        .map(|(k, _)| k.as_str())
        .collect();
    let ranges: Vec<_> = PlannerSettings::fields().filter_map(|f| f.range).collect();
    let mut table: Vec<&str> = ranges.iter().map(|r| r.field).collect();
    let mut sorted_numeric = numeric.clone();
    sorted_numeric.sort_unstable();
    table.sort_unstable();
    assert_eq!(sorted_numeric, table);
    for r in &ranges {
        let default = PlannerSettings::default().numeric(r.field).unwrap();
        assert!(
            r.contains(default),
            "default {} = {default} outside {r}",
            r.field
        );
        let is_int = all.iter().any(|(k, v)| k == r.field && v.is_u64());
        let step = |x: f64, up: bool| {
            if is_int {
                if up { x + 1.0 } else { x - 1.0 }
            } else {
                let d = x.abs().max(1.0) * 1e-9;
                if up { x + d } else { x - d }
            }
        };
        for (v, ok) in [
            (step(r.min, false), false),
            (step(r.max, true), false),
            (r.min, !r.min_open),
            (r.max, !r.max_open),
        ] {
            if is_int && v < 0.0 {
                continue; // not representable in the integer field
            }
            // a_max must also exceed a_min: test a_max's own bounds with a_min at its minimum.
            let mut m: Value = serde_json::from_str(&with(
                r.field,
                if is_int { json!(v as u64) } else { json!(v) },
            ))
            .unwrap();
            if r.field == "bounds.a_max" {
                m["bounds"]["a_min"] = json!(-15.0);
            }
            let result = PlannerSettings::from_json(&m.to_string());
            if r.field == "bounds.a_max" && v <= -15.0 {
                assert!(result.is_err());
                continue;
            }
            assert_eq!(
                result.is_ok(),
                ok,
                "{} = {v} (range {r}): {result:?}",
                r.field
            );
            if let Err(e) = result {
                assert!(e.to_string().contains(&format!("`{}`", r.field)), "{e}");
            }
        }
    }
}

/// A slice length between 0 (off) and `MIN_EGO_SEGMENT_LENGTH` would cut the ego into an
/// unbounded number of safety ellipses (1e-300 m: ⌈4.8 / 1e-300⌉ slices, a hang the fuzzer
/// found): refused, naming the field; 0 and the minimum itself are accepted.
#[test]
fn an_ego_slice_is_off_or_at_least_the_minimum_length() {
    let min = PlannerSettings::MIN_EGO_SEGMENT_LENGTH;
    let key = "safety.ego_segment_length";
    for v in [1e-300, 1e-9, 0.1, min * (1.0 - 1e-9)] {
        let err = PlannerSettings::from_json(&with(key, json!(v)))
            .err()
            .unwrap_or_else(|| panic!("{key} = {v} accepted"));
        assert!(err.to_string().contains(&format!("`{key}`")), "{err}");
    }
    for v in [0.0, min, 6.0, 100.0] {
        PlannerSettings::from_json(&with(key, json!(v)))
            .unwrap_or_else(|e| panic!("{key} = {v} refused: {e}"));
    }
}

/// Longest settings message accepted (characters): a message names the item in a line a
/// person reads, not every valid alternative.
const MAX_MESSAGE: usize = 200;

/// Every way a settings text can be refused gives a message of at most `MAX_MESSAGE`
/// characters that still names the item: an unknown field of each group (serde listed every
/// field of the group: up to 263 characters, for `repair`), an unknown group, a wrong type, each
/// field out of its range or of the wrong type (serde named no field: the field is found and
/// named), each old key moved or removed.
#[test]
fn every_settings_message_is_short_and_names_its_item() {
    let mut cases: Vec<(String, String)> = Vec::new();
    for (group, _) in GROUPS {
        cases.push((
            format!(r#"{{"{group}": {{"no_such_field": 1}}}}"#),
            "`no_such_field`".into(),
        ));
    }
    cases.push((r#"{"no_such_group": {}}"#.into(), "`no_such_group`".into()));
    for (key, _) in defaults() {
        cases.push((with(&key, json!(1e308)), format!("`{key}`")));
        cases.push((with(&key, json!("text")), format!("`{key}`")));
    }
    for (old, _) in MOVED.iter().chain(REMOVED) {
        cases.push((format!(r#"{{"{old}": 1}}"#), format!("`{old}`")));
    }
    for (text, item) in cases {
        let e = PlannerSettings::from_json(&text)
            .err()
            .unwrap_or_else(|| panic!("{text} accepted"))
            .to_string();
        assert!(e.contains(&item), "{text}: {e}");
        assert!(
            e.chars().count() <= MAX_MESSAGE,
            "{text}: {} characters: {e}",
            e.chars().count()
        );
    }
}
