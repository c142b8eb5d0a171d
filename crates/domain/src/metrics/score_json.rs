//! Scores in JSON without loss: JSON has no infinity or NaN (serde_json writes them as `null`,
//! and a `null` does not read back as a number), yet a PSNR is `+∞` for a volume identical to its
//! reference and a mean over nothing is NaN. Finite values are written as numbers, the others as
//! the strings `"inf"`, `"-inf"` and `"nan"`, which read back exactly. A `null` written by an
//! earlier version reads as NaN (the value it stood for is lost).
//!
//! Use with `#[serde(with = "prism_domain::metrics::score_json")]` on an `f64`, and
//! `score_json::option` on an `Option<f64>`.

use serde::de::{self, Deserializer, Visitor};
use serde::{Deserialize, Serializer};
use std::fmt;

/// Write `v`: a number when finite, else `"inf"`, `"-inf"` or `"nan"`.
pub fn serialize<S: Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
    if v.is_finite() {
        s.serialize_f64(*v)
    } else {
        s.serialize_str(if v.is_nan() {
            "nan"
        } else if *v > 0.0 {
            "inf"
        } else {
            "-inf"
        })
    }
}

/// Read a number, one of the strings [`serialize`] writes, or `null` (NaN).
pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
    d.deserialize_any(Score)
}

struct Score;

impl<'de> Visitor<'de> for Score {
    type Value = f64;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("a number, \"inf\", \"-inf\" or \"nan\"")
    }

    fn visit_f64<E: de::Error>(self, v: f64) -> Result<f64, E> {
        Ok(v)
    }

    fn visit_i64<E: de::Error>(self, v: i64) -> Result<f64, E> {
        Ok(v as f64)
    }

    fn visit_u64<E: de::Error>(self, v: u64) -> Result<f64, E> {
        Ok(v as f64)
    }

    fn visit_str<E: de::Error>(self, v: &str) -> Result<f64, E> {
        match v {
            "inf" => Ok(f64::INFINITY),
            "-inf" => Ok(f64::NEG_INFINITY),
            "nan" => Ok(f64::NAN),
            _ => Err(E::invalid_value(de::Unexpected::Str(v), &self)),
        }
    }

    fn visit_unit<E: de::Error>(self) -> Result<f64, E> {
        Ok(f64::NAN)
    }

    fn visit_none<E: de::Error>(self) -> Result<f64, E> {
        Ok(f64::NAN)
    }
}

/// The same for an optional score: `None` is `null`, `Some` as above.
pub mod option {
    use super::*;

    pub fn serialize<S: Serializer>(v: &Option<f64>, s: S) -> Result<S::Ok, S::Error> {
        match v {
            Some(x) => super::serialize(x, s),
            None => s.serialize_none(),
        }
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Option<f64>, D::Error> {
        #[derive(Deserialize)]
        struct Wrap(#[serde(with = "super")] f64);
        Ok(Option::<Wrap>::deserialize(d)?.map(|Wrap(v)| v))
    }
}

#[cfg(test)]
mod tests {
    use serde::{Deserialize, Serialize};

    #[derive(Debug, Serialize, Deserialize)]
    struct S {
        #[serde(with = "super")]
        a: f64,
        #[serde(with = "super::option", default)]
        b: Option<f64>,
    }

    #[test]
    fn every_value_reads_back_exactly() {
        for (a, b) in [
            (31.25, Some(0.5)),
            (f64::INFINITY, Some(f64::NEG_INFINITY)),
            (f64::NAN, None),
        ] {
            let json = serde_json::to_string(&S { a, b }).unwrap();
            let back: S = serde_json::from_str(&json).unwrap();
            assert!(back.a == a || (a.is_nan() && back.a.is_nan()), "{json}");
            assert_eq!(back.b, b, "{json}");
        }
        let json = serde_json::to_string(&S {
            a: f64::INFINITY,
            b: None,
        })
        .unwrap();
        assert_eq!(json, r#"{"a":"inf","b":null}"#);
        // An earlier version's null reads as NaN; another string is an error.
        let old: S = serde_json::from_str(r#"{"a":null}"#).unwrap();
        assert!(old.a.is_nan() && old.b.is_none());
        assert!(serde_json::from_str::<S>(r#"{"a":"infinity"}"#).is_err());
    }
}
