//! JSON text read strictly: a key repeated in any object is an error naming the key.
//!
//! `serde_json` keeps the last of repeated keys when it builds a [`serde_json::Value`], so a
//! config whose second `"horizon"` silently replaces the first would be accepted. Every
//! config nudge reads (weights' model config, planner settings, closed-loop settings) goes
//! through [`parse`] first.

use serde::de::{self, Deserialize, Deserializer, MapAccess, SeqAccess, Visitor};
use serde_json::{Map, Number, Value};

/// Parses JSON `text` into a [`Value`], refusing a key repeated within one object (at any
/// depth).
///
/// # Errors
/// The `serde_json` error: invalid JSON, or ``duplicate key `k` `` with its line and column.
///
/// # Examples
///
/// ```
/// let v = nudge_predictor::json::parse(r#"{"a": 1, "b": {"c": 2}}"#)?;
/// assert_eq!(v["b"]["c"], 2);
/// let e = nudge_predictor::json::parse(r#"{"a": 1, "a": 2}"#).unwrap_err();
/// assert!(e.to_string().starts_with("duplicate key `a`"));
/// # Ok::<(), serde_json::Error>(())
/// ```
pub fn parse(text: &str) -> serde_json::Result<Value> {
    serde_json::from_str::<Unique>(text).map(|u| u.0)
}

/// A [`Value`] built by a visitor that refuses repeated keys.
struct Unique(Value);

impl<'de> Deserialize<'de> for Unique {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        d.deserialize_any(UniqueVisitor)
    }
}

struct UniqueVisitor;

impl<'de> Visitor<'de> for UniqueVisitor {
    type Value = Unique;

    fn expecting(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("a JSON value")
    }

    fn visit_bool<E>(self, v: bool) -> Result<Unique, E> {
        Ok(Unique(Value::Bool(v)))
    }

    fn visit_i64<E>(self, v: i64) -> Result<Unique, E> {
        Ok(Unique(Value::Number(v.into())))
    }

    fn visit_u64<E>(self, v: u64) -> Result<Unique, E> {
        Ok(Unique(Value::Number(v.into())))
    }

    fn visit_f64<E: de::Error>(self, v: f64) -> Result<Unique, E> {
        Number::from_f64(v)
            .map(|n| Unique(Value::Number(n)))
            .ok_or_else(|| E::custom(format!("non-finite number {v}")))
    }

    fn visit_str<E>(self, v: &str) -> Result<Unique, E> {
        Ok(Unique(Value::String(v.to_owned())))
    }

    fn visit_string<E>(self, v: String) -> Result<Unique, E> {
        Ok(Unique(Value::String(v)))
    }

    fn visit_unit<E>(self) -> Result<Unique, E> {
        Ok(Unique(Value::Null))
    }

    fn visit_none<E>(self) -> Result<Unique, E> {
        Ok(Unique(Value::Null))
    }

    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Unique, A::Error> {
        let mut out = Vec::new();
        while let Some(Unique(v)) = seq.next_element()? {
            out.push(v);
        }
        Ok(Unique(Value::Array(out)))
    }

    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Unique, A::Error> {
        let mut out = Map::new();
        while let Some(key) = map.next_key::<String>()? {
            if out.contains_key(&key) {
                return Err(de::Error::custom(format!("duplicate key `{key}`")));
            }
            let Unique(v) = map.next_value()?;
            out.insert(key, v);
        }
        Ok(Unique(Value::Object(out)))
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use super::*;

    #[test]
    fn same_values_as_serde_json_and_repeats_refused_at_any_depth() {
        for text in [
            r#"{"a": [1, -2, 3.5, "x", null, true, {"b": {}}], "c": 1e300}"#,
            "[]",
            "0",
            r#""s""#,
            "{}",
        ] {
            let want: Value = serde_json::from_str(text).unwrap();
            assert_eq!(parse(text).unwrap(), want, "{text}");
        }
        for (text, key) in [
            (r#"{"a": 1, "a": 1}"#, "a"),
            (r#"{"x": {"k": 1, "y": 2, "k": 3}}"#, "k"),
            (r#"[{"q": 1}, {"q": 2, "q": 2}]"#, "q"),
        ] {
            let e = parse(text).unwrap_err().to_string();
            assert!(e.contains(&format!("duplicate key `{key}`")), "{text}: {e}");
            assert!(e.contains("line 1"), "{e}");
        }
        // Equal keys in different objects are fine.
        parse(r#"{"a": {"a": {"a": 1}}}"#).unwrap();
    }
}

/// Longest list of expected names [`brief`] keeps (characters).
const MAX_EXPECTED_LIST: usize = 60;

/// `e`'s message with serde's list of the valid names cut short: ``unknown field `x`,
/// expected one of `a`, `b`, ...`` lists every field of the struct (hundreds of characters for
/// a settings group); the unknown name is kept whole, the list only while it is short, else
/// a pointer to the reference (`reference`, e.g. `docs/reference/settings.md`) replaces it.
#[must_use]
pub fn brief(e: &serde_json::Error, reference: &str) -> String {
    let msg = e.to_string();
    let Some(at) = msg.find(", expected one of ") else {
        return msg;
    };
    let (head, rest) = msg.split_at(at);
    // serde_json appends " at line L column C"; keep it.
    let (list, position) = match rest.rfind(" at line ") {
        Some(p) => rest.split_at(p),
        None => (rest, ""),
    };
    if list.len() <= MAX_EXPECTED_LIST {
        return msg;
    }
    format!("{head}{position} (valid names: {reference})")
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod brief_tests {
    use serde::Deserialize;

    /// A struct with many fields: serde's message for an unknown one lists all of them; the
    /// brief message names the unknown field and its position, and stays short.
    #[test]
    fn an_unknown_field_keeps_its_name_and_loses_the_long_list() {
        #[derive(Debug, Deserialize)]
        #[serde(deny_unknown_fields)]
        #[allow(dead_code)]
        struct Many {
            alpha_one: Option<f64>,
            beta_two: Option<f64>,
            gamma_three: Option<f64>,
            delta_four: Option<f64>,
            epsilon_five: Option<f64>,
            zeta_six: Option<f64>,
        }
        let e = serde_json::from_str::<Many>(r#"{"omega": 1}"#).unwrap_err();
        assert!(e.to_string().len() > 100, "{e}");
        let b = super::brief(&e, "docs/x.md");
        assert!(
            b.starts_with("unknown field `omega` at line 1 column 8"),
            "{b}"
        );
        assert!(b.ends_with("(valid names: docs/x.md)"), "{b}");
        assert!(b.len() < 80, "{b}");
        #[derive(Debug, Deserialize)]
        #[serde(deny_unknown_fields)]
        #[allow(dead_code)]
        struct Few {
            a: Option<f64>,
        }
        let e = serde_json::from_str::<Few>(r#"{"b": 1}"#).unwrap_err();
        assert_eq!(super::brief(&e, "docs/x.md"), e.to_string());
    }
}
