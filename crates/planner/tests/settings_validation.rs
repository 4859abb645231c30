//! Planner settings: a JSON object only, every field validated against a documented, physically
//! sane range, and a guard that no field of the serde representation escapes validation.
#![allow(clippy::unwrap_used)]
#![recursion_limit = "512"]

use nudge_planner::PlannerSettings;
use serde_json::{Value, json};

fn defaults() -> serde_json::Map<String, Value> {
    match serde_json::to_value(PlannerSettings::default()).unwrap() {
        Value::Object(m) => m,
        other => panic!("settings serialise as {other}"),
    }
}

fn with(key: &str, value: Value) -> String {
    let mut m = serde_json::Map::new();
    m.insert(key.to_owned(), value);
    Value::Object(m).to_string()
}

/// The defaults are valid and unchanged (the values every front end and result relies on).
#[test]
fn shipped_defaults_are_valid_and_unchanged() {
    let d = PlannerSettings::default();
    d.validate().unwrap();
    let expected = json!({
        "horizon": 6, "dt": 0.3, "l_f": 1.4, "l_r": 1.4,
        "w_y": 15.0, "w_deadline": 60.0, "deadline_distance": 100.0,
        "stop_decel": 3.0, "stop_margin": 12.0, "w_v": 3.0, "w_psi": 1.0, "w_delta": 3.0, "w_ddelta": 3.0, "w_a": 1.0,
        "w_da": 1.0, "rho": 1000.0,
        "delta_max": 0.15, "ddelta_max": 0.05, "a_min": -5.0, "a_max": 3.0, "da_max": 1.5,
        "v_max": 30.0, "edge_margin": 0.0, "v_lin_min": 1.0,
        "ellipse_scale": std::f64::consts::SQRT_2, "ellipse_lateral_scale": 0.0, "margin_x": 1.5,
        "margin_y": 0.3,
        "brake_decel": 4.0,
        "check_range": 60.0, "safety_min": 0.0, "plan_buffer": 0.0,
        "max_iter": 30, "eps_primal": 0.01, "eps_change": 0.01, "pgd_steps": 5,
        "pgd_halvings": 3, "hessian_scaled": true, "pin_weight": 10000.0,
        "z_safe_step": false, "z_step_margin": 0.01, "z_cuts": 0, "safe_start": false,
        "z_retighten": 0, "z_rollout_trial": false, "relinearise": false,
        "warm_start_dual": false, "rollout_check": true, "fallback_speed_floor": 0.5,
        "fallback_brake_hold": false, "fallback_full_accel": false, "fallback_shy": false, "fallback_match_speed": false, "match_admissible_only": true, "match_min_speed": 10.0, "fallback_lattice": true, "lattice_clear_nonreactive": true, "lattice_when_fallback_hits": false,
        "lattice_min_speed": 10.0,
        "fallback_nonreactive": false, "fallback_avoid_nonreactive": false, "avoid_min_speed": 10.0,
        "lateral_drift": false, "lateral_drift_min_speed": 0.25,
        "edge_first": true, "contact_first": true, "lead_first": true, "lead_min_speed": 10.0, "lead_in_lane": true, "lead_keep_lane": true, "bounds_first": true, "bounds_slack": 0.05,
        "restore_step": 1.0,
        "ablate_reaction": false,
        "heading_max": 0.2, "heading_recovery": 0.05, "heading_governor": true,
        "overshoot_max": 0.3,
        "refine_iters": 5, "refine_margin": 0.02, "refine_trust_delta": 0.05,
        "refine_trust_accel": 2.0, "budget_s": 0.0, "budget_calls": 0,
        "safety_geometry": "ellipse", "ego_segment_length": 6.0, "contingency": false, "contingency_accel": -2.0,
        "contingency_steps": 3, "follower_ttc": 0.0, "follower_min_gap": 0.5,
        "follower_clearance": 0.8
    });
    assert_eq!(serde_json::to_value(&d).unwrap(), expected);
    assert_eq!(PlannerSettings::from_json("{}").unwrap(), d);
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
    // A key given twice is ambiguous.
    assert!(PlannerSettings::from_json(r#"{"dt": 0.3, "dt": 0.5}"#).is_err());
}

/// Values from the defect report.
#[test]
fn reported_values_are_refused() {
    for (key, value) in [
        ("pin_weight", json!(-1.0)),
        ("dt", json!(1e300)),
        ("v_max", json!(1e6)),
        ("l_f", json!(1e-300)),
        ("max_iter", json!(u64::MAX)),
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
            Value::String(_) => {
                // An enumeration: its names only.
                let err = PlannerSettings::from_json(&with(&key, json!("circle")))
                    .err()
                    .unwrap_or_else(|| panic!("{key} = circle accepted"));
                assert!(err.to_string().contains("circle"), "{key}: {err}");
                continue;
            }
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
    assert_eq!(numeric, 64, "numeric settings");
}

/// The documented range table covers exactly the numeric fields, each bound is enforced, and
/// each closed end point is accepted.
#[test]
fn range_table_matches_the_fields_and_is_enforced() {
    use nudge_planner::settings::RANGES;
    let numeric: Vec<String> = defaults()
        .into_iter()
        .filter(|(_, v)| v.is_number())
        .map(|(k, _)| k)
        .collect();
    let table: Vec<&str> = RANGES.iter().map(|r| r.field).collect();
    let mut sorted_numeric = numeric.clone();
    sorted_numeric.sort();
    let mut sorted_table: Vec<String> = table.iter().map(|s| (*s).to_owned()).collect();
    sorted_table.sort();
    assert_eq!(sorted_numeric, sorted_table);
    for r in RANGES {
        let default = PlannerSettings::default().numeric(r.field).unwrap();
        assert!(
            r.contains(default),
            "default {} = {default} outside {r}",
            r.field
        );
        let is_int = defaults()[r.field].is_u64();
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
            let mut m = serde_json::Map::new();
            if r.field == "a_max" {
                m.insert("a_min".into(), json!(-15.0));
            }
            let value = if is_int { json!(v as u64) } else { json!(v) };
            m.insert(r.field.into(), value);
            let result = PlannerSettings::from_json(&Value::Object(m).to_string());
            if r.field == "a_max" && v <= -15.0 {
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

/// A lateral scale at or below `ellipse_scale` / √2 leaves no longitudinal scale that keeps the
/// ellipse around the box-overlap rectangle: refused, naming the field; just above it, and 0
/// (off), are accepted.
#[test]
fn a_lateral_scale_must_exceed_the_scale_over_root_two() {
    for v in [0.5, 1.0] {
        let err = PlannerSettings::from_json(&with("ellipse_lateral_scale", json!(v)))
            .err()
            .unwrap_or_else(|| panic!("ellipse_lateral_scale = {v} accepted"));
        assert!(err.to_string().contains("ellipse_lateral_scale"), "{err}");
    }
    for v in [0.0, 1.001, 1.15, 4.0] {
        PlannerSettings::from_json(&with("ellipse_lateral_scale", json!(v)))
            .unwrap_or_else(|e| panic!("ellipse_lateral_scale = {v} refused: {e}"));
    }
}

/// A slice length between 0 (off) and `MIN_EGO_SEGMENT_LENGTH` would cut the ego into an
/// unbounded number of safety ellipses (1e-300 m: ⌈4.8 / 1e-300⌉ slices, a hang the fuzzer
/// found): refused, naming the field; 0 and the minimum itself are accepted.
#[test]
fn an_ego_slice_is_off_or_at_least_the_minimum_length() {
    let min = PlannerSettings::MIN_EGO_SEGMENT_LENGTH;
    for v in [1e-300, 1e-9, 0.1, min * (1.0 - 1e-9)] {
        let err = PlannerSettings::from_json(&with("ego_segment_length", json!(v)))
            .err()
            .unwrap_or_else(|| panic!("ego_segment_length = {v} accepted"));
        assert!(err.to_string().contains("`ego_segment_length`"), "{err}");
    }
    for v in [0.0, min, 6.0, 100.0] {
        PlannerSettings::from_json(&with("ego_segment_length", json!(v)))
            .unwrap_or_else(|e| panic!("ego_segment_length = {v} refused: {e}"));
    }
}
