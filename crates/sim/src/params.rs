//! Documented parameter structs and their validation.
//!
//! Every configuration struct of fishprobe is declared with [`crate::documented_params!`], which
//! writes the struct (serde, `deny_unknown_fields`, missing fields take their default), its
//! `Default` (the paper's values) and a table of the fields with unit and documentation, so
//! that `fishprobe models` and the rustdoc show the same text.

use serde::Serialize;

/// One documented field of a parameter struct.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct FieldDoc {
    /// The field's name as written in config files.
    pub name: &'static str,
    /// Its unit ("1" for dimensionless, "-" for a nested section or a switch).
    pub unit: &'static str,
    /// What it means, including where the default comes from.
    pub doc: &'static str,
}

impl FieldDoc {
    /// The documentation as one line of text.
    pub fn text(&self) -> String {
        self.doc.split_whitespace().collect::<Vec<_>>().join(" ")
    }
}

/// A parameter struct whose fields carry documentation at run time.
pub trait DocumentedParams: Serialize + Default {
    /// One entry per field, in declaration order.
    fn field_docs() -> &'static [FieldDoc];
}

/// Declares a parameter struct: `pub field: Type = default; "unit"` per field, each with a
/// doc comment. Generates serde (with `deny_unknown_fields`), `Default` and
/// [`DocumentedParams`].
#[macro_export]
macro_rules! documented_params {
    (
        $(#[$smeta:meta])*
        pub struct $name:ident {
            $(
                $(#[doc = $doc:literal])*
                $(#[serde($($serde:tt)*)])*
                pub $field:ident : $ty:ty = $default:expr ; $unit:literal
            ),* $(,)?
        }
    ) => {
        $(#[$smeta])*
        #[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
        #[serde(deny_unknown_fields, default)]
        pub struct $name {
            $(
                $(#[doc = $doc])*
                #[doc = ""]
                #[doc = concat!("Unit: ", $unit, ". Default: `", stringify!($default), "`.")]
                $(#[serde($($serde)*)])*
                pub $field: $ty,
            )*
        }
        impl Default for $name {
            fn default() -> Self {
                Self { $($field: $default),* }
            }
        }
        impl $crate::params::DocumentedParams for $name {
            fn field_docs() -> &'static [$crate::params::FieldDoc] {
                &[$($crate::params::FieldDoc {
                    name: stringify!($field),
                    unit: $unit,
                    doc: concat!($($doc, "\n"),*),
                }),*]
            }
        }
    };
}

/// A configuration value that is out of its valid range. Names the field (as a dotted path
/// from the config root) and the offending value.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("invalid configuration: `{field}` = {value}: {reason}")]
pub struct ConfigError {
    /// Dotted path of the field, e.g. `robot.max_speed_cm_s`.
    pub field: String,
    /// The value as given.
    pub value: String,
    /// What it must be instead.
    pub reason: String,
}

impl ConfigError {
    /// A new error for `prefix.field`.
    pub fn new(prefix: &str, field: &str, value: impl std::fmt::Display, reason: &str) -> Self {
        let field = if prefix.is_empty() {
            field.to_string()
        } else {
            format!("{prefix}.{field}")
        };
        Self {
            field,
            value: value.to_string(),
            reason: reason.to_string(),
        }
    }
}

/// `base` with the fields named in `table` replaced by its values, one name at a time, so that
/// an unknown name, a value of the wrong type or a missing number (TOML's `nan` and `inf`
/// arrive here as JSON's null) is refused naming `prefix.name`. For a table of a settings file
/// (e.g. a study file's `[analysis]` or `[task]`); the caller validates the result's ranges.
pub fn replace_by_name<T>(
    base: &T,
    prefix: &str,
    table: &serde_json::Map<String, serde_json::Value>,
) -> Result<T, ConfigError>
where
    T: Serialize + serde::de::DeserializeOwned + Clone,
{
    let mut obj = match serde_json::to_value(base) {
        Ok(serde_json::Value::Object(o)) => o,
        _ => return Err(ConfigError::new(prefix, "", "", "cannot be represented")),
    };
    let mut cur = base.clone();
    for (key, value) in table {
        if !obj.contains_key(key) {
            return Err(ConfigError::new(
                prefix,
                key,
                value,
                &format!("is not among the [{prefix}] settings (docs/settings.md lists them)"),
            ));
        }
        if value.is_null() {
            return Err(ConfigError::new(
                prefix,
                key,
                "nan/inf",
                "must be a finite number (NaN and infinities are refused)",
            ));
        }
        obj.insert(key.clone(), value.clone());
        cur = serde_json::from_value(serde_json::Value::Object(obj.clone())).map_err(|e| {
            ConfigError::new(prefix, key, value, &format!("has the wrong type: {e}"))
        })?;
    }
    Ok(cur)
}

/// Field checks used by the `validate` methods of parameter structs.
pub mod check {
    use super::ConfigError;

    /// `v` as an error message shows it: plainly in the range people type, in scientific
    /// notation beyond it, so that an absurd value (`1e300`) does not print three hundred
    /// digits.
    /// An `f32` prints as typed (`0.1`, not the `f64` it widens to).
    pub fn shown<T>(v: T) -> String
    where
        T: Copy + Into<f64> + std::fmt::Display + std::fmt::LowerExp,
    {
        let x: f64 = v.into();
        let a = x.abs();
        if x == 0.0 || !x.is_finite() || (1e-4..1e9).contains(&a) {
            format!("{v}")
        } else {
            format!("{v:e}")
        }
    }

    /// A finite number (not NaN, not infinite).
    pub fn finite(prefix: &str, field: &str, v: f32) -> Result<(), ConfigError> {
        if v.is_finite() {
            Ok(())
        } else {
            Err(ConfigError::new(
                prefix,
                field,
                shown(v),
                "must be a finite number",
            ))
        }
    }

    /// A finite number > 0.
    pub fn positive(prefix: &str, field: &str, v: f32) -> Result<(), ConfigError> {
        finite(prefix, field, v)?;
        if v > 0.0 {
            Ok(())
        } else {
            Err(ConfigError::new(
                prefix,
                field,
                shown(v),
                "must be greater than 0",
            ))
        }
    }

    /// A finite number >= 0.
    pub fn non_negative(prefix: &str, field: &str, v: f32) -> Result<(), ConfigError> {
        finite(prefix, field, v)?;
        if v >= 0.0 {
            Ok(())
        } else {
            Err(ConfigError::new(
                prefix,
                field,
                shown(v),
                "must not be negative",
            ))
        }
    }

    /// Largest length (cm) a setting of an animal or the robot may have: ten metres, ten
    /// times the 1 m tank. Only a typing error goes beyond it (the simulation would run, and
    /// its numbers mean nothing).
    pub const MAX_LENGTH_CM: f32 = 1000.0;
    /// Largest speed (cm/s): ten metres per second, some twenty times a guppy's burst speed
    /// and the robot's top speed.
    pub const MAX_SPEED_CM_S: f32 = 1000.0;
    /// Largest acceleration (cm/s²): 100 m/s², about 10 g.
    pub const MAX_ACCELERATION_CM_S2: f32 = 10_000.0;
    /// Largest turn rate (rad/s): some 160 turns a second, beyond any fish or robot.
    pub const MAX_TURN_RATE_RAD_S: f32 = 1000.0;
    /// Longest duration (s) a setting may have: a day, the longest episode or trial fishprobe
    /// records (`env::MAX_EPISODE_FRAMES` at 25 Hz, a live trial's habituation and control).
    pub const MAX_DURATION_S: f32 = 86_400.0;
    /// Largest dimensionless weight, factor or gain: 10,000, some 250 times the largest
    /// published one (M_Zone's wall repulsion, 40.51). Beyond it one term decides alone, as it
    /// does at 10,000, and products with other settings approach the range of `f32`.
    pub const MAX_WEIGHT: f32 = 10_000.0;
    /// Largest standard deviation of an angle noise (rad): a full turn, beyond which the
    /// noise draws a uniform heading either way.
    pub const MAX_ANGLE_NOISE_RAD: f32 = std::f32::consts::TAU;

    /// A finite number in `(0, hi]`.
    pub fn positive_at_most(prefix: &str, field: &str, v: f32, hi: f32) -> Result<(), ConfigError> {
        positive(prefix, field, v)?;
        if v <= hi {
            Ok(())
        } else {
            Err(ConfigError::new(
                prefix,
                field,
                shown(v),
                &format!("must lie in (0, {}]", shown(hi)),
            ))
        }
    }

    /// A finite number in `[lo, hi]`.
    pub fn within(prefix: &str, field: &str, v: f32, lo: f32, hi: f32) -> Result<(), ConfigError> {
        finite(prefix, field, v)?;
        if (lo..=hi).contains(&v) {
            Ok(())
        } else {
            Err(ConfigError::new(
                prefix,
                field,
                shown(v),
                &format!("must lie in [{}, {}]", shown(lo), shown(hi)),
            ))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    crate::documented_params! {
        /// A test struct.
        pub struct Example {
            /// Speed of something.
            pub speed: f32 = 6.3; "cm/s",
            /// A count.
            pub count: u32 = 3; "1",
        }
    }

    #[test]
    fn an_absurd_number_is_shown_short_and_a_typed_one_as_typed() {
        assert_eq!(check::shown(1e300), "1e300");
        assert_eq!(check::shown(-2.5e-9), "-2.5e-9");
        assert_eq!(check::shown(2.0), "2");
        assert_eq!(check::shown(0.25), "0.25");
        assert_eq!(check::shown(600.0), "600");
        assert_eq!(check::shown(0.0), "0");
        assert_eq!(check::shown(f64::INFINITY), "inf");
        assert_eq!(check::shown(f64::NAN), "NaN");
        assert_eq!(check::shown(0.1f32), "0.1");
        assert_eq!(check::shown(f32::MAX), "3.4028235e38");
        let e = check::positive_at_most("robot", "max_speed_cm_s", 1e30, 1000.0)
            .unwrap_err()
            .to_string();
        assert!(e.contains("= 1e30") && e.contains("(0, 1000]"), "{e}");
        assert!(check::positive_at_most("robot", "max_speed_cm_s", 1000.0, 1000.0).is_ok());
        assert!(check::positive_at_most("robot", "max_speed_cm_s", 0.0, 1000.0).is_err());
        let e = check::within("fish", "speed", 3e38, 0.0, 100.0)
            .unwrap_err()
            .to_string();
        assert!(e.contains("= 3e38") && e.contains("[0, 100]"), "{e}");
    }

    #[test]
    fn defaults_docs_and_unknown_fields() {
        let e = Example::default();
        assert_eq!(e.speed, 6.3);
        assert_eq!(e.count, 3);
        let docs = Example::field_docs();
        assert_eq!(docs[0].name, "speed");
        assert_eq!(docs[0].unit, "cm/s");
        assert!(docs[0].doc.contains("Speed of something"));
        let partial: Example = serde_json::from_str(r#"{"count": 5}"#).unwrap();
        assert_eq!(partial.speed, 6.3);
        assert_eq!(partial.count, 5);
        let err = serde_json::from_str::<Example>(r#"{"sped": 1}"#).unwrap_err();
        assert!(err.to_string().contains("unknown field `sped`"), "{err}");
    }

    #[test]
    fn checks_name_field_and_value() {
        let e = check::positive("robot", "max_speed_cm_s", 0.0).unwrap_err();
        assert_eq!(e.field, "robot.max_speed_cm_s");
        assert!(e.to_string().contains("= 0"), "{e}");
        assert!(check::finite("", "x", f32::NAN).is_err());
        assert!(check::non_negative("", "x", -1.0).is_err());
        assert!(check::within("", "x", 2.0, 0.0, 1.0).is_err());
        assert!(check::within("", "x", 1.0, 0.0, 1.0).is_ok());
    }
}
