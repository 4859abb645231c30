//! One declaration per field: [`settings_struct!`](crate::settings_struct) generates a settings struct, its
//! [`Default`], its field table ([`FieldSpec`]: name, unit, admissible range) and the lookup of
//! a field's value, so that the validation, the reference docs and the Python classes all read
//! the same declaration. Used by every group of [`super::PlannerSettings`] and by
//! the simulator's `SimConfig`.

use std::fmt;

/// The admissible values of a numeric field: an interval, each end open or closed, and a unit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FieldRange {
    /// Name of the field (dotted path from the top of the settings, as in JSON).
    pub field: &'static str,
    /// Lower end.
    pub min: f64,
    /// The lower end itself is excluded.
    pub min_open: bool,
    /// Upper end.
    pub max: f64,
    /// The upper end itself is excluded.
    pub max_open: bool,
    /// Unit of the value (`""` for none).
    pub unit: &'static str,
}

impl FieldRange {
    /// `v` lies in the range (NaN never does).
    #[must_use]
    pub fn contains(&self, v: f64) -> bool {
        let lo = if self.min_open {
            v > self.min
        } else {
            v >= self.min
        };
        let hi = if self.max_open {
            v < self.max
        } else {
            v <= self.max
        };
        lo && hi
    }
}

/// A number as the messages and docs show it: plain, or in exponent form outside
/// [1e-3, 1e6).
#[must_use]
pub fn show(v: f64) -> String {
    let a = v.abs();
    if a != 0.0 && a.is_finite() && !(1e-3..1e6).contains(&a) {
        format!("{v:e}")
    } else {
        format!("{v}")
    }
}

impl fmt::Display for FieldRange {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{}{}, {}{}{}{}",
            if self.min_open { '(' } else { '[' },
            show(self.min),
            show(self.max),
            if self.max_open { ')' } else { ']' },
            if self.unit.is_empty() { "" } else { " " },
            self.unit
        )
    }
}

/// One field of a settings struct: its dotted name and, for a numeric field, its range.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FieldSpec {
    /// Dotted name from the top of the settings (as in JSON).
    pub field: &'static str,
    /// The admissible range; `None` for a switch or a name (valid by type).
    pub range: Option<FieldRange>,
}

/// The range part of a declaration, before the field's name is attached.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bounds {
    min: f64,
    min_open: bool,
    max: f64,
    max_open: bool,
    unit: &'static str,
}

/// [min, max] in `unit`.
#[must_use]
pub const fn closed(min: f64, max: f64, unit: &'static str) -> Option<Bounds> {
    Some(Bounds {
        min,
        min_open: false,
        max,
        max_open: false,
        unit,
    })
}

/// (min, max] in `unit`.
#[must_use]
pub const fn open_min(min: f64, max: f64, unit: &'static str) -> Option<Bounds> {
    Some(Bounds {
        min,
        min_open: true,
        max,
        max_open: false,
        unit,
    })
}

/// [min, max) in `unit`.
#[must_use]
pub const fn open_max(min: f64, max: f64, unit: &'static str) -> Option<Bounds> {
    Some(Bounds {
        min,
        min_open: false,
        max,
        max_open: true,
        unit,
    })
}

/// (min, max) in `unit`.
#[must_use]
pub const fn open(min: f64, max: f64, unit: &'static str) -> Option<Bounds> {
    Some(Bounds {
        min,
        min_open: true,
        max,
        max_open: true,
        unit,
    })
}

/// (0, ∞) in `unit`: positive and finite.
#[must_use]
pub const fn positive(unit: &'static str) -> Option<Bounds> {
    open(0.0, f64::INFINITY, unit)
}

/// No range: a switch or a name, valid by its type.
#[must_use]
pub const fn any() -> Option<Bounds> {
    None
}

/// The field `field` with `bounds`.
#[must_use]
pub const fn spec(field: &'static str, bounds: Option<Bounds>) -> FieldSpec {
    FieldSpec {
        field,
        range: match bounds {
            Some(b) => Some(FieldRange {
                field,
                min: b.min,
                min_open: b.min_open,
                max: b.max,
                max_open: b.max_open,
                unit: b.unit,
            }),
            None => None,
        },
    }
}

/// A field's value as a number, for the range check (`None` for switches and names).
pub trait FieldValue {
    /// The value as f64, `None` when the field is not numeric.
    fn number(&self) -> Option<f64>;
}

impl FieldValue for f64 {
    fn number(&self) -> Option<f64> {
        Some(*self)
    }
}

impl FieldValue for usize {
    fn number(&self) -> Option<f64> {
        Some(*self as f64)
    }
}

impl FieldValue for bool {
    fn number(&self) -> Option<f64> {
        None
    }
}

/// The first field of `fields` whose value (`value(name)`, NaN when missing) is out of its
/// range, with that value.
pub fn first_out_of_range(
    fields: &[FieldSpec],
    value: impl Fn(&str) -> Option<f64>,
) -> Option<(FieldRange, f64)> {
    fields.iter().find_map(|f| {
        let r = f.range?;
        let v = value(f.field).unwrap_or(f64::NAN);
        (!r.contains(v)).then_some((r, v))
    })
}

/// Declares a settings struct from one line per field:
///
/// ```text
/// settings_struct! {
///     /// Doc of the struct.
///     pub struct Cost("cost.") {
///         /// One-sentence doc (unit).
///         w_y: f64 = 15.0, closed(0.0, 1e6, "1/m²");
///     }
/// }
/// ```
///
/// generates the struct (serde: missing fields default, unknown fields refused), its
/// `Default` (also as the constant `DEFAULT`), `FIELDS` (a [`FieldSpec`] per field, named `prefix` + field) and `value(name)`
/// (the value of the field `name`, without the prefix, as f64).
#[macro_export]
macro_rules! settings_struct {
    (
        $(#[$meta:meta])*
        pub struct $name:ident ($prefix:literal) {
            $(
                $(#[doc = $doc:literal])*
                $field:ident : $ty:ty = $default:expr, $bounds:expr;
            )*
        }
    ) => {
        $(#[$meta])*
        #[derive(
            Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize, schemars::JsonSchema,
        )]
        #[serde(default, deny_unknown_fields)]
        pub struct $name {
            $(
                $(#[doc = $doc])*
                pub $field: $ty,
            )*
        }

        impl Default for $name {
            fn default() -> Self {
                Self::DEFAULT
            }
        }

        impl $name {
            /// The defaults.
            pub const DEFAULT: Self = Self {
                $($field: $default,)*
            };

            /// Every field: its dotted name and admissible range, in declaration order.
            pub const FIELDS: &'static [$crate::settings::schema::FieldSpec] = &[
                $($crate::settings::schema::spec(concat!($prefix, stringify!($field)), $bounds),)*
            ];

            /// The first field out of its range, with its value (NaN and infinity never are in
            /// range); `None` when every field is in range.
            #[must_use]
            pub fn out_of_range(&self) -> Option<($crate::settings::schema::FieldRange, f64)> {
                $crate::settings::schema::first_out_of_range(Self::FIELDS, |f| self.value(f))
            }

            /// The value of field `field` (its name, with or without the group prefix) as f64;
            /// `None` for a switch, a name or an unknown field.
            #[must_use]
            pub fn value(&self, field: &str) -> Option<f64> {
                match field.rsplit('.').next().unwrap_or(field) {
                    $(stringify!($field) => $crate::settings::schema::FieldValue::number(&self.$field),)*
                    _ => None,
                }
            }
        }
    };
}
