//! Filter parameters: declared once per filter with their bounds, set from JSON or from
//! `key=value` strings, validated with errors that give the bound.

use super::FilterError;
use serde::de::DeserializeOwned;
use serde::Serialize;
use serde_json::{Map, Value};

/// The kind and bounds of one parameter.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(rename_all = "snake_case", tag = "type")]
pub enum ParamKind {
    /// A real number (an `f32` field) in `[min, max]`.
    Float {
        /// Smallest allowed value.
        min: f64,
        /// Largest allowed value.
        max: f64,
    },
    /// An integer in `[min, max]`.
    Int {
        /// Smallest allowed value.
        min: i64,
        /// Largest allowed value.
        max: i64,
    },
    /// `true` or `false`.
    Bool,
    /// One of a list of names.
    Choice {
        /// The names allowed.
        options: &'static [&'static str],
    },
}

/// One parameter of a filter: name, what it does (with its tradeoff), kind and bounds. The
/// default is whatever the filter's `Params::default()` holds.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct ParamSpec {
    /// Name, as in `--set name=value`.
    pub name: &'static str,
    /// What it does and what raising or lowering it trades.
    pub doc: &'static str,
    /// Kind and bounds.
    pub kind: ParamKind,
}

/// Declares a filter's parameter struct once: each field with its doc comment (what it does
/// and what raising or lowering it trades), type, default, kind and bounds, one line of code
/// a parameter. Generates the struct (serde, every field defaulted, unknown fields refused),
/// its `Default`, and its [`FilterParams`] specs in field order, each spec's `doc` the field's
/// doc comment joined into one line ([`doc_text`]).
///
/// ```
/// use afterimage_core::filter_params;
/// use afterimage_core::pipeline::params::{FilterParams, ParamKind};
/// filter_params! {
///     /// Parameters of an example.
///     pub struct Params {
///         /// weight of the current
///         /// frame
///         alpha: f32 = 0.1, ParamKind::Float { min: 0.0, max: 1.0 };
///     }
/// }
/// assert_eq!(Params::default().alpha, 0.1);
/// assert_eq!(Params::SPECS[0].name, "alpha");
/// assert_eq!(Params::SPECS[0].doc, "weight of the current frame");
/// ```
///
/// A temporal filter ends its fields with `..reconstruct`: the `reconstruct` stage's
/// `pixel_filter` and `filter_width`, declared here once for every filter that has the
/// stage, and a `reconstruction()` that gives the two as a
/// [`Reconstruction`](crate::filters::reconstruct::Reconstruction).
#[macro_export]
macro_rules! filter_params {
    (
        $(#[$meta:meta])*
        pub struct $name:ident {
            $( $(#[doc = $doc:literal])* $field:ident : $ty:ty = $default:expr, $kind:expr; )*
            ..reconstruct
        }
    ) => {
        $crate::filter_params! {
            $(#[$meta])*
            pub struct $name {
                $( $(#[doc = $doc])* $field: $ty = $default, $kind; )*
                /// pixel filter of the image the output converges to (stage reconstruct): the current
                /// frame enters as its 3x3 samples weighted at their jittered positions (at the pixel
                /// centres, and wider, when the jitter is unknown: 0 on both axes). blackman_harris
                /// (Cycles' default) or gaussian match a renderer's converged image; box keeps each
                /// pixel's own sample (the box integral: sharper, more aliasing)
                pixel_filter: $crate::filters::reconstruct::PixelFilter =
                    $crate::filters::reconstruct::PixelFilter::BlackmanHarris,
                    $crate::pipeline::params::ParamKind::Choice {
                        options: $crate::filters::reconstruct::PIXEL_FILTERS,
                    };
                /// pixel filter width in pixels, Cycles' convention (blackman_harris reaches +-width,
                /// gaussian has sigma width/4; default 1.5, Cycles' default; a frame with unknown
                /// jitter is weighed with the width, never narrower, whose centred taps average as
                /// much, 1.73 for 1.5). Wider: softer, less aliasing and noise
                filter_width: f32 = $crate::filters::reconstruct::DEFAULT_FILTER_WIDTH,
                    $crate::pipeline::params::ParamKind::Float { min: 0.5, max: 4.0 };
            }
        }

        impl $name {
            /// The `reconstruct` stage these parameters ask for.
            pub fn reconstruction(&self) -> $crate::filters::reconstruct::Reconstruction {
                $crate::filters::reconstruct::Reconstruction::new(self.pixel_filter, self.filter_width)
            }
        }
    };
    (
        $(#[$meta:meta])*
        pub struct $name:ident {
            $( $(#[doc = $doc:literal])* $field:ident : $ty:ty = $default:expr, $kind:expr; )*
        }
    ) => {
        $(#[$meta])*
        #[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
        #[serde(default, deny_unknown_fields)]
        pub struct $name {
            $( $(#[doc = $doc])* pub $field: $ty, )*
        }

        impl Default for $name {
            fn default() -> Self {
                $name { $( $field: $default, )* }
            }
        }

        impl $crate::pipeline::params::FilterParams for $name {
            const SPECS: &'static [$crate::pipeline::params::ParamSpec] = &[
                $( $crate::pipeline::params::ParamSpec {
                    name: stringify!($field),
                    doc: $crate::pipeline::params::doc_text(concat!($($doc),*)),
                    kind: $kind,
                }, )*
            ];
        }
    };
}

/// A parameter's doc text from its doc comment's lines concatenated: each line starts with
/// the space after `///`, so the lines join with one space and only the first one's is cut.
pub const fn doc_text(doc: &'static str) -> &'static str {
    match doc.as_bytes() {
        [b' ', rest @ ..] => match std::str::from_utf8(rest) {
            Ok(text) => text,
            Err(_) => doc,
        },
        _ => doc,
    }
}

/// A filter's parameter set: serde (every field has a default), plus the declared specs.
/// Declared with [`filter_params!`](crate::filter_params).
pub trait FilterParams: Serialize + DeserializeOwned + Default + Clone + std::fmt::Debug {
    /// One spec per field, in field order.
    const SPECS: &'static [ParamSpec];
}

/// Parses `key=value` pairs into a JSON object: a value that is valid JSON (numbers,
/// `true`, `false`) is taken as such, anything else as a string (`variant=improved`).
pub fn parse_assignments<S: AsRef<str>>(pairs: &[S]) -> Result<Map<String, Value>, FilterError> {
    let mut map = Map::new();
    for pair in pairs {
        let pair = pair.as_ref();
        let (k, v) = pair.split_once('=').ok_or_else(|| FilterError::Assignment {
            got: pair.to_string(),
        })?;
        let value =
            serde_json::from_str::<Value>(v.trim()).unwrap_or_else(|_| Value::String(v.trim().into()));
        map.insert(k.trim().to_string(), value);
    }
    Ok(map)
}

/// Builds `P` from the defaults overridden by `values`, and validates it: unknown names,
/// wrong types and out-of-bound values are errors naming the parameter and the bound.
pub fn build<P: FilterParams>(filter: &'static str, values: &Map<String, Value>) -> Result<P, FilterError> {
    let mut merged = match serde_json::to_value(P::default()).expect("params serialize") {
        Value::Object(m) => m,
        _ => unreachable!("params are a struct"),
    };
    for (k, v) in values {
        if !merged.contains_key(k) {
            return Err(FilterError::UnknownParam {
                filter,
                param: k.clone(),
                known: P::SPECS.iter().map(|s| s.name).collect::<Vec<_>>().join(", "),
            });
        }
        merged.insert(k.clone(), v.clone());
    }
    // Check kinds and bounds on the JSON values first, so the message names the bound.
    for spec in P::SPECS {
        check(filter, spec, &merged[spec.name])?;
    }
    serde_json::from_value(Value::Object(merged)).map_err(|e| FilterError::BadParam {
        filter,
        param: String::new(),
        message: e.to_string(),
    })
}

/// Checks one value against its spec.
fn check(filter: &'static str, spec: &ParamSpec, v: &Value) -> Result<(), FilterError> {
    let bad = |message: String| FilterError::BadParam {
        filter,
        param: spec.name.to_string(),
        message,
    };
    match spec.kind {
        ParamKind::Float { min, max } => {
            let x = v
                .as_f64()
                .ok_or_else(|| bad(format!("expected a number, got {v}")))?;
            // Float parameters are f32 fields: compare at f32 precision, so a default such
            // as 0.0833f32 (0.083300002 as f64) is within a bound written 0.0833.
            if !(min as f32..=max as f32).contains(&(x as f32)) {
                return Err(bad(format!(
                    "{x} is out of bounds: expected {min} <= value <= {max}"
                )));
            }
        }
        ParamKind::Int { min, max } => {
            let x = v
                .as_i64()
                .ok_or_else(|| bad(format!("expected an integer, got {v}")))?;
            if !(min..=max).contains(&x) {
                return Err(bad(format!(
                    "{x} is out of bounds: expected {min} <= value <= {max}"
                )));
            }
        }
        ParamKind::Bool => {
            v.as_bool()
                .ok_or_else(|| bad(format!("expected true or false, got {v}")))?;
        }
        ParamKind::Choice { options } => {
            let s = v
                .as_str()
                .ok_or_else(|| bad(format!("expected one of {}, got {v}", options.join(", "))))?;
            if !options.contains(&s) {
                return Err(bad(format!("expected one of {}, got {s:?}", options.join(", "))));
            }
        }
    }
    Ok(())
}

/// Checks an already built parameter set (e.g. deserialized elsewhere) against its specs.
pub fn validate<P: FilterParams>(filter: &'static str, p: &P) -> Result<(), FilterError> {
    let v = serde_json::to_value(p).expect("params serialize");
    for spec in P::SPECS {
        check(filter, spec, &v[spec.name])?;
    }
    Ok(())
}

/// `p` as a JSON object, with f32 fields written in their shortest form (`0.1`, not the
/// `0.10000000149011612` of their f64 widening).
pub fn to_json<P: FilterParams>(p: &P) -> Map<String, Value> {
    let mut m = match serde_json::to_value(p).expect("params serialize") {
        Value::Object(m) => m,
        _ => unreachable!("params are a struct"),
    };
    for spec in P::SPECS {
        if let (ParamKind::Float { .. }, Some(v)) = (spec.kind, m.get_mut(spec.name)) {
            if let Some(x) = v.as_f64() {
                let short: f64 = (x as f32).to_string().parse().expect("a float prints as a float");
                if let Some(n) = serde_json::Number::from_f64(short) {
                    *v = Value::Number(n);
                }
            }
        }
    }
    m
}

/// The defaults of `P` as JSON (listed by `afterimage filters`).
pub fn defaults<P: FilterParams>() -> Map<String, Value> {
    to_json(&P::default())
}
