//! The reference of every user-facing settings struct ([`PlannerSettings`]; the simulator's
//! `SimConfig` describes itself through the same [`Described`] trait), field by field: name,
//! unit, default, admissible range and meaning.
//!
//! One source for each column: the meaning is the field's doc comment (read through its
//! derived JSON schema), the default is the serde serialisation of [`Default`], the unit and
//! range are the [`FieldRange`] table that `validate` checks. [`settings_markdown`] renders
//! the planner's part of `docs/reference/settings.md` from them (the simulator crate appends
//! its own section: `nudge settings --format markdown`), and the Python classes' `describe()`
//! return the same rows.

use schemars::JsonSchema;
use serde::Serialize;
use serde_json::Value;

use crate::settings::{
    AdmmSettings, BoundSettings, BudgetSettings, CostSettings, FieldRange, FieldSpec,
    LaneEndSettings, ModelSettings, PlannerSettings, RepairSettings, SafetySettings,
};

/// One field of a settings struct.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FieldDoc {
    /// Dotted name of the field (as in JSON files: `cost.w_y`, or `max_steps` at the top).
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
    /// Its fields (dotted names and ranges), in declaration order; empty for a struct of
    /// groups, which describes itself through [`Described::rows`].
    const FIELDS: &'static [FieldSpec];

    /// Every field, in declaration order.
    #[must_use]
    fn rows() -> Vec<FieldDoc> {
        describe::<Self>()
    }
}

macro_rules! described {
    ($($t:ty => $name:literal),* $(,)?) => {
        $(impl Described for $t {
            const NAME: &'static str = $name;
            const FIELDS: &'static [FieldSpec] = <$t>::FIELDS;
        })*
    };
}

described! {
    ModelSettings => "ModelSettings",
    CostSettings => "CostSettings",
    BoundSettings => "BoundSettings",
    SafetySettings => "SafetySettings",
    AdmmSettings => "AdmmSettings",
    RepairSettings => "RepairSettings",
    BudgetSettings => "BudgetSettings",
    LaneEndSettings => "LaneEndSettings",
}

impl Described for PlannerSettings {
    const NAME: &'static str = "PlannerSettings";
    const FIELDS: &'static [FieldSpec] = &[];

    fn rows() -> Vec<FieldDoc> {
        let mut rows = describe::<ModelSettings>();
        rows.extend(describe::<CostSettings>());
        rows.extend(describe::<BoundSettings>());
        rows.extend(describe::<SafetySettings>());
        rows.extend(describe::<AdmmSettings>());
        rows.extend(describe::<RepairSettings>());
        rows.extend(describe::<BudgetSettings>());
        rows.extend(describe::<LaneEndSettings>());
        rows
    }
}

/// Every field of the flat struct `T` (`T::FIELDS`), in declaration order: its doc from the
/// JSON schema, its default from the serialised [`Default`], its unit and range.
#[must_use]
pub fn describe<T: Described>() -> Vec<FieldDoc> {
    let schema = schemars::schema_for!(T);
    let defaults = serde_json::to_value(T::default()).unwrap_or(Value::Null);
    let Some(props) = schema.get("properties").and_then(Value::as_object) else {
        return Vec::new();
    };
    T::FIELDS
        .iter()
        .map(|spec| {
            let leaf = spec.field.rsplit('.').next().unwrap_or(spec.field);
            let prop = props.get(leaf).unwrap_or(&Value::Null);
            let default = defaults.get(leaf).cloned().unwrap_or(Value::Null);
            FieldDoc {
                field: spec.field.to_owned(),
                unit: spec.range.as_ref().map_or("", |r| r.unit),
                range: spec
                    .range
                    .as_ref()
                    .map_or_else(|| names(&schema, prop, &default), range_text),
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

/// The Markdown table of `rows` (field, unit, default, valid values, meaning), appended to
/// `out`.
pub fn table(out: &mut String, rows: &[FieldDoc]) {
    out.push_str("| field | unit | default | valid values | meaning |\n|---|---|---|---|---|\n");
    for f in rows {
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

/// One group's subsection: its doc and table.
fn group<T: Described>(out: &mut String, name: &str) {
    out.push_str(&format!("### `{name}`\n\n{}\n\n", struct_doc::<T>()));
    table(out, &describe::<T>());
}

/// The fallback's rank keys, in the order they are compared.
fn rank_keys(out: &mut String) {
    out.push_str(
        "The fallback ranks its candidates by these keys, in order, each deciding only on a \
         tie of those before it (`decided_by` in the records names the key that chose a \
         fallback):\n\n",
    );
    for (i, key) in crate::RANK_ORDER.iter().enumerate() {
        out.push_str(&format!("{}. `{}`\n", i + 1, key.name()));
    }
    out.push('\n');
}

/// The planner's part of `docs/reference/settings.md`: its title and introduction, then every
/// field of [`PlannerSettings`] (group by group, in the order of the MPC call's phases) with
/// unit, default, valid values and meaning (Markdown). The simulator appends its `SimConfig`
/// section to it.
#[must_use]
pub fn settings_markdown() -> String {
    let mut out = String::from(
        "# Settings reference\n\n\
         <!-- Generated by `nudge settings --format markdown` (make reference-docs) from the \
         declarations of the Rust settings; do not edit. -->\n\n\
         Every setting of the planner and of the closed-loop simulator: its unit, its default \
         and the values `validate()` accepts (`[a, b]` includes an end, `(a, b)` excludes it). \
         A value outside its range is refused with an error naming the field; nothing is \
         clamped.\n\n",
    );
    out.push_str(&format!(
        "## `PlannerSettings`\n\n{}\n\nIn JSON (`--settings FILE`) the groups are nested \
         objects, e.g. `{{\"cost\": {{\"w_y\": 20}}}}`; every group and field is optional and \
         unknown ones are refused, as are the flat keys of earlier versions (with where they \
         moved or why they were removed). From Python, \
         `nudge.PlannerSettings(cost={{\"w_y\": 20}})` and `nudge.PlannerSettings.describe()`.\n\n",
        struct_doc::<PlannerSettings>()
    ));
    group::<ModelSettings>(&mut out, "model");
    group::<CostSettings>(&mut out, "cost");
    group::<BoundSettings>(&mut out, "bounds");
    group::<SafetySettings>(&mut out, "safety");
    group::<AdmmSettings>(&mut out, "admm");
    group::<RepairSettings>(&mut out, "repair");
    rank_keys(&mut out);
    group::<BudgetSettings>(&mut out, "budget");
    group::<LaneEndSettings>(&mut out, "lane_ends");
    out
}

/// The planner's fields as JSON (`{"PlannerSettings": [...]}`), for tools; the simulator adds
/// its `SimConfig` key.
#[must_use]
pub fn settings_json() -> Value {
    serde_json::json!({
        PlannerSettings::NAME: PlannerSettings::rows(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every field of the serialised default of the flat struct `T` is described once, in
    /// declaration order, with that default, a meaning and admissible values; a numeric
    /// default lies in its range.
    fn check<T: Described>() {
        let rows = describe::<T>();
        let Value::Object(defaults) = serde_json::to_value(T::default()).expect("serialise") else {
            panic!("{} does not serialise to an object", T::NAME);
        };
        let mut described: Vec<&str> = rows
            .iter()
            .map(|r| r.field.rsplit('.').next().unwrap_or(&r.field))
            .collect();
        described.sort_unstable();
        let serialised: Vec<&str> = defaults.keys().map(String::as_str).collect();
        assert_eq!(described, serialised, "{}: described fields", T::NAME);
        for (r, spec) in rows.iter().zip(T::FIELDS) {
            let leaf = r.field.rsplit('.').next().unwrap_or(&r.field);
            assert_eq!(r.default, defaults[leaf], "{}.{} default", T::NAME, r.field);
            assert!(
                r.doc.len() > 10,
                "{}.{} has no doc comment",
                T::NAME,
                r.field
            );
            assert!(!r.range.is_empty(), "{}.{} has no range", T::NAME, r.field);
            if let Some(x) = r.default.as_f64() {
                let range = spec
                    .range
                    .unwrap_or_else(|| panic!("{}.{}: no range", T::NAME, r.field));
                assert!(
                    range.contains(x),
                    "{}.{} default outside its range",
                    T::NAME,
                    r.field
                );
            }
        }
        assert!(
            struct_doc::<T>().len() > 20,
            "{} has no doc comment",
            T::NAME
        );
    }

    #[test]
    fn every_planner_setting_is_described_with_its_serialised_default() {
        check::<ModelSettings>();
        check::<CostSettings>();
        check::<BoundSettings>();
        check::<SafetySettings>();
        check::<AdmmSettings>();
        check::<RepairSettings>();
        check::<BudgetSettings>();
        check::<LaneEndSettings>();
        let rows = PlannerSettings::rows();
        assert_eq!(rows.len(), PlannerSettings::fields().count());
        let dt = rows.iter().find(|r| r.field == "model.dt").expect("dt");
        assert_eq!((dt.unit, dt.range.as_str()), ("s", "[0.01, 1]"));
        assert_eq!(dt.doc, "Step length (s).");
        let ablate = rows
            .iter()
            .find(|r| r.field == "safety.ablate_reaction")
            .expect("bool");
        assert_eq!(
            (ablate.range.as_str(), &ablate.default),
            ("true or false", &Value::Bool(false))
        );
    }

    #[test]
    fn the_page_has_a_row_of_five_cells_per_field() {
        let page = settings_markdown();
        for r in &PlannerSettings::rows() {
            assert!(
                page.contains(&format!("\n| `{}` |", r.field)),
                "{}",
                r.field
            );
        }
        // Each table row has its five cells (no stray pipe inside one).
        for line in page.lines().filter(|l| l.starts_with("| `")) {
            assert_eq!(line.replace(r"\|", "").matches('|').count(), 6, "{line}");
        }
    }
}
