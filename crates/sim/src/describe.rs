//! The reference of [`SimConfig`] (the planner's [`Described`] trait) and the whole settings
//! reference, `docs/reference/settings.md`: the planner's part
//! ([`nudge_planner::describe::settings_markdown`]) followed by the closed-loop settings.

use nudge_planner::describe::{self as planner, Described, describe, struct_doc, table};
use nudge_planner::settings::FieldSpec;
use serde_json::Value;

use crate::SimConfig;

impl Described for SimConfig {
    const NAME: &'static str = "SimConfig";
    const FIELDS: &'static [FieldSpec] = SimConfig::FIELDS;
}

/// `docs/reference/settings.md`: every field of the planner's settings (group by group, in the
/// order of the MPC call's phases) and of [`SimConfig`] with unit, default, valid values and
/// meaning (Markdown).
#[must_use]
pub fn settings_markdown() -> String {
    let mut out = planner::settings_markdown();
    out.push_str(&format!(
        "## `SimConfig`\n\n{}\n\nIn JSON (`--config FILE`) every field is optional and \
         unknown fields are refused; from Python, `nudge.SimConfig(field=value, ...)` and \
         `nudge.SimConfig.describe()`.\n\n",
        struct_doc::<SimConfig>()
    ));
    table(&mut out, &describe::<SimConfig>());
    out
}

/// Both structs' fields as JSON (`{"PlannerSettings": [...], "SimConfig": [...]}`), for tools.
#[must_use]
pub fn settings_json() -> Value {
    let mut json = planner::settings_json();
    if let Value::Object(map) = &mut json {
        map.insert(
            SimConfig::NAME.to_owned(),
            serde_json::to_value(SimConfig::rows()).unwrap_or(Value::Null),
        );
    }
    json
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_closed_loop_setting_is_described_with_its_serialised_default() {
        let rows = describe::<SimConfig>();
        let Value::Object(defaults) =
            serde_json::to_value(SimConfig::default()).expect("serialise")
        else {
            panic!("SimConfig does not serialise to an object");
        };
        let mut described: Vec<&str> = rows.iter().map(|r| r.field.as_str()).collect();
        described.sort_unstable();
        let serialised: Vec<&str> = defaults.keys().map(String::as_str).collect();
        assert_eq!(described, serialised, "described fields");
        for (r, spec) in rows.iter().zip(SimConfig::FIELDS) {
            assert_eq!(r.default, defaults[&r.field], "{} default", r.field);
            assert!(r.doc.len() > 10, "{} has no doc comment", r.field);
            assert!(!r.range.is_empty(), "{} has no range", r.field);
            if let Some(x) = r.default.as_f64() {
                let range = spec
                    .range
                    .unwrap_or_else(|| panic!("{}: no range", r.field));
                assert!(range.contains(x), "{} default outside its range", r.field);
            }
        }
        assert!(struct_doc::<SimConfig>().len() > 20);
        let world = rows.iter().find(|r| r.field == "world").expect("world");
        assert_eq!(world.range, "`teacher`, `log_replay`, `idm`");
        assert_eq!(world.default, Value::String("teacher".into()));
        let settle = rows
            .iter()
            .find(|r| r.field == "settle_y")
            .expect("settle_y");
        assert_eq!((settle.unit, settle.range.as_str()), ("m", "(0, 1.25]"));
    }

    #[test]
    fn the_page_has_a_row_per_closed_loop_field_and_escapes_pipes() {
        let page = settings_markdown();
        assert!(page.starts_with(&planner::settings_markdown()));
        for r in &describe::<SimConfig>() {
            assert!(
                page.contains(&format!("\n| `{}` |", r.field)),
                "{}",
                r.field
            );
        }
        assert!(page.contains(r"\|y − y_target\| ≤ this"));
        for line in page.lines().filter(|l| l.starts_with("| `")) {
            assert_eq!(line.replace(r"\|", "").matches('|').count(), 6, "{line}");
        }
    }
}
