//! The reference of every user-facing settings struct ([`PlannerSettings`], [`SimConfig`]),
//! field by field: name, unit, default, admissible range and meaning.
//!
//! One source for each column: the meaning is the field's doc comment (read through its
//! derived JSON schema), the default is the serde serialisation of [`Default`], the unit and
//! range are the [`FieldRange`] table that `validate` checks. [`settings_markdown`] renders
//! `docs/reference/settings.md` from them (`nudge settings --format markdown`), and the Python
//! classes' `describe()` return the same rows.

use schemars::JsonSchema;
use serde::Serialize;
use serde_json::Value;

use crate::settings::{FieldRange, PlannerSettings, RANGES};
use crate::sim::SimConfig;

/// One field of a settings struct.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FieldDoc {
    /// Name of the field (as in the serde representation: JSON files, Python keywords).
    pub field: String,
    /// Unit of the value (`""` when it has none: weights, tolerances, booleans, names).
    pub unit: &'static str,
    /// The default, as serialised.
    pub default: Value,
    /// The admissible values: a range as `validate` checks it (`[a, b]` closed, `(a, b)`
    /// open), `true or false`, or the accepted names.
    pub range: String,
    /// What the field means: its doc comment.
    pub doc: String,
}

/// A settings struct that can describe its fields.
pub trait Described: JsonSchema + Serialize + Default {
    /// Name of the struct (as in Rust and Python).
    const NAME: &'static str;
    /// The ranges its `validate` checks, one per numeric field.
    const RANGES: &'static [FieldRange];
}

impl Described for PlannerSettings {
    const NAME: &'static str = "PlannerSettings";
    const RANGES: &'static [FieldRange] = RANGES;
}

impl Described for SimConfig {
    const NAME: &'static str = "SimConfig";
    const RANGES: &'static [FieldRange] = SimConfig::RANGES;
}

/// Every field of `T`, in alphabetical order (the order of its serde serialisation).
#[must_use]
pub fn describe<T: Described>() -> Vec<FieldDoc> {
    let schema = schemars::schema_for!(T);
    let defaults = serde_json::to_value(T::default()).unwrap_or(Value::Null);
    let Some(props) = schema.get("properties").and_then(Value::as_object) else {
        return Vec::new();
    };
    props
        .iter()
        .map(|(field, prop)| {
            let range = T::RANGES.iter().find(|r| r.field == field);
            let default = defaults.get(field).cloned().unwrap_or(Value::Null);
            FieldDoc {
                field: field.clone(),
                unit: range.map_or("", |r| r.unit),
                range: range.map_or_else(|| names(&schema, prop, &default), range_text),
                default,
                doc: doc_text(prop),
            }
        })
        .collect()
}

/// The doc comment of the class itself (its schema's description).
#[must_use]
pub fn struct_doc<T: Described>() -> String {
    doc_text(schemars::schema_for!(T).as_value())
}

/// A range as `validate` reports it, without the unit (which has its own column).
fn range_text(r: &FieldRange) -> String {
    FieldRange { unit: "", ..*r }.to_string()
}

/// The admissible values of a field without a numeric range: a boolean's, or the names of an
/// enumeration (looked up in the schema's definitions).
fn names(schema: &schemars::Schema, prop: &Value, default: &Value) -> String {
    if default.is_boolean() {
        return "true or false".to_owned();
    }
    let def = prop
        .get("$ref")
        .and_then(Value::as_str)
        .and_then(|r| r.strip_prefix("#/$defs/"))
        .and_then(|name| schema.get("$defs")?.get(name));
    // Documented variants are a `oneOf` of constants, undocumented ones an `enum`.
    let one_of = def.and_then(|d| d.get("oneOf")).and_then(Value::as_array);
    let variants: Vec<&Value> = match one_of {
        Some(vs) => vs.iter().filter_map(|v| v.get("const")).collect(),
        None => def
            .and_then(|d| d.get("enum"))
            .and_then(Value::as_array)
            .map(|vs| vs.iter().collect())
            .unwrap_or_default(),
    };
    let names: Vec<String> = variants
        .iter()
        .filter_map(|v| v.as_str())
        .map(|n| format!("`{n}`"))
        .collect();
    names.join(", ")
}

/// A schema description as plain text: intra-doc links become code spans, lines of one
/// paragraph are joined.
fn doc_text(v: &Value) -> String {
    let text = v.get("description").and_then(Value::as_str).unwrap_or("");
    text.replace("[`", "`")
        .replace("`]", "`")
        .replace("`crate::", "`")
        .split("\n\n")
        .map(|p| p.split_whitespace().collect::<Vec<_>>().join(" "))
        .collect::<Vec<_>>()
        .join("\n\n")
}

/// A default for a table cell: numbers and booleans as serialised, names as code.
fn default_text(v: &Value) -> String {
    match v {
        Value::String(s) => format!("`{s}`"),
        other => other.to_string(),
    }
}

/// Text safe inside a Markdown table cell (pipes escaped, paragraphs on one line).
fn cell(text: &str) -> String {
    text.replace('|', "\\|").replace("\n\n", "<br>")
}

/// One struct's section of the reference page: its description and a table of its fields.
fn section<T: Described>(out: &mut String, json_name: &str) {
    out.push_str(&format!("## `{}`\n\n{}\n\n", T::NAME, struct_doc::<T>()));
    out.push_str(&format!(
        "In JSON (`{json_name}`) every field is optional and unknown fields are refused; from \
         Python, `nudge.{}(field=value, ...)` and `nudge.{}.describe()`.\n\n",
        T::NAME,
        T::NAME
    ));
    out.push_str("| field | unit | default | valid values | meaning |\n|---|---|---|---|---|\n");
    for f in describe::<T>() {
        out.push_str(&format!(
            "| `{}` | {} | {} | {} | {} |\n",
            f.field,
            if f.unit.is_empty() { "–" } else { f.unit },
            default_text(&f.default),
            cell(&f.range),
            cell(&f.doc)
        ));
    }
    out.push('\n');
}

/// `docs/reference/settings.md`: every field of [`PlannerSettings`] and [`SimConfig`] with
/// unit, default, valid values and meaning (Markdown).
#[must_use]
pub fn settings_markdown() -> String {
    let mut out = String::from(
        "# Settings reference\n\n\
         <!-- Generated by `nudge settings --format markdown` (make reference-docs) from the doc \
         comments, defaults and validation ranges of the Rust settings; do not edit. -->\n\n\
         Every setting of the planner and of the closed-loop simulator: its unit, its default \
         and the values `validate()` accepts (`[a, b]` includes an end, `(a, b)` excludes it). \
         A value outside its range is refused with an error naming the field; nothing is \
         clamped.\n\n",
    );
    section::<PlannerSettings>(&mut out, "--settings FILE");
    section::<SimConfig>(&mut out, "--config FILE");
    out
}

/// Both structs' fields as JSON (`{"PlannerSettings": [...], "SimConfig": [...]}`), for tools.
#[must_use]
pub fn settings_json() -> Value {
    serde_json::json!({
        PlannerSettings::NAME: describe::<PlannerSettings>(),
        SimConfig::NAME: describe::<SimConfig>(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every field of the serialised default is described once, in order, with that default,
    /// a meaning and admissible values; every range names a described field.
    fn check<T: Described>() {
        let rows = describe::<T>();
        let Value::Object(defaults) = serde_json::to_value(T::default()).expect("serialise") else {
            panic!("{} does not serialise to an object", T::NAME);
        };
        let described: Vec<&str> = rows.iter().map(|r| r.field.as_str()).collect();
        let serialised: Vec<&str> = defaults.keys().map(String::as_str).collect();
        assert_eq!(described, serialised, "{}: described fields", T::NAME);
        for r in &rows {
            assert_eq!(
                r.default,
                defaults[&r.field],
                "{}.{} default",
                T::NAME,
                r.field
            );
            assert!(
                r.doc.len() > 10,
                "{}.{} has no doc comment",
                T::NAME,
                r.field
            );
            assert!(!r.range.is_empty(), "{}.{} has no range", T::NAME, r.field);
            if let Some(x) = r.default.as_f64() {
                let range = T::RANGES.iter().find(|g| g.field == r.field);
                let range = range.unwrap_or_else(|| panic!("{}.{}: no range", T::NAME, r.field));
                assert!(
                    range.contains(x),
                    "{}.{} default outside its range",
                    T::NAME,
                    r.field
                );
            }
        }
        for g in T::RANGES {
            assert!(
                described.contains(&g.field),
                "{}: range of unknown {}",
                T::NAME,
                g.field
            );
        }
        assert!(
            struct_doc::<T>().len() > 20,
            "{} has no doc comment",
            T::NAME
        );
    }

    #[test]
    fn every_planner_setting_is_described_with_its_serialised_default() {
        check::<PlannerSettings>();
        let rows = describe::<PlannerSettings>();
        let dt = rows.iter().find(|r| r.field == "dt").expect("dt");
        assert_eq!((dt.unit, dt.range.as_str()), ("s", "[0.01, 1]"));
        assert_eq!(dt.doc, "Step length (s).");
        let check = rows
            .iter()
            .find(|r| r.field == "rollout_check")
            .expect("bool");
        assert_eq!(
            (check.range.as_str(), &check.default),
            ("true or false", &Value::Bool(true))
        );
    }

    #[test]
    fn every_closed_loop_setting_is_described_with_its_serialised_default() {
        check::<SimConfig>();
        let rows = describe::<SimConfig>();
        let world = rows.iter().find(|r| r.field == "world").expect("world");
        assert_eq!(world.range, "`teacher`, `log_replay`, `idm`");
        assert_eq!(world.default, Value::String("teacher".into()));
        let settle = rows
            .iter()
            .find(|r| r.field == "settle_y")
            .expect("settle_y");
        assert_eq!((settle.unit, settle.range.as_str()), ("m", "(0, inf)"));
    }

    #[test]
    fn the_page_has_a_row_per_field_and_escapes_pipes() {
        let page = settings_markdown();
        for r in describe::<PlannerSettings>()
            .iter()
            .chain(&describe::<SimConfig>())
        {
            assert!(
                page.contains(&format!("\n| `{}` |", r.field)),
                "{}",
                r.field
            );
        }
        assert!(page.contains(r"\|y − y_target\| ≤ settle_y"));
        // Each table row has its five cells (no stray pipe inside one).
        for line in page.lines().filter(|l| l.starts_with("| `")) {
            assert_eq!(line.replace(r"\|", "").matches('|').count(), 6, "{line}");
        }
    }
}
