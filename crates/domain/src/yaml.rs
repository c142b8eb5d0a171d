//! Reading YAML files (configs, `scene.yaml`) with errors that name the file and the field, and
//! `--set key.path=value` overrides applied on top of them.

use crate::{Error, Result};
use serde::de::DeserializeOwned;
use serde_yaml_ng::{Mapping, Value};
use std::fmt;
use std::path::Path;

/// Read and parse a YAML file.
pub fn read<T: DeserializeOwned>(path: &Path) -> Result<T> {
    read_with(path, &Overrides::default())
}

/// Read a YAML file, apply `overrides`, then parse. An error about an overridden field says so.
pub fn read_with<T: DeserializeOwned>(path: &Path, overrides: &Overrides) -> Result<T> {
    let text = std::fs::read_to_string(path).map_err(|e| Error::io(path, e))?;
    parse_with(&text, path, overrides)
}

/// Parse YAML `text` (read from `file`) with `overrides` applied.
pub fn parse_with<T: DeserializeOwned>(
    text: &str,
    file: &Path,
    overrides: &Overrides,
) -> Result<T> {
    if overrides.is_empty() {
        return serde_yaml_ng::from_str(text).map_err(|e| error(file, &e));
    }
    let value = overrides.apply_to_text(text, file)?;
    // Parsed again from text: serde_yaml_ng reports field paths only when deserialising text.
    let text = serde_yaml_ng::to_string(&value).map_err(|e| error(file, &e))?;
    serde_yaml_ng::from_str(&text).map_err(|e| overrides.explain(error(file, &e)))
}

/// A YAML error as a field error of `file`. serde_yaml_ng prefixes messages with the path of the
/// offending value (`channels[1].coordinate: unknown variant …`); that path becomes the field.
pub fn error(file: &Path, e: &serde_yaml_ng::Error) -> Error {
    let msg = e.to_string();
    let is_path = |p: &str| {
        !p.is_empty()
            && p.chars()
                .all(|ch| ch.is_ascii_alphanumeric() || "_.[]".contains(ch))
    };
    match msg.split_once(": ") {
        Some((path, rest)) if is_path(path) => Error::field(file, path, rest),
        _ => Error::field(file, ".", msg),
    }
}

/// One `key.path=value` setting. The key is a dotted path of mapping keys; a segment of digits
/// indexes a sequence (`channels.1.kvp=80`). The value is YAML (`0.5`, `true`, `sart`,
/// `[1, 2]`, `{kind: mlp}`); an empty value is null.
#[derive(Clone, Debug, PartialEq)]
pub struct Override {
    key: Vec<String>,
    value: Value,
    text: String,
}

impl Override {
    /// The dotted key, e.g. `geometry.views`.
    pub fn key(&self) -> String {
        self.key.join(".")
    }
}

/// The most segments a `--set` key may have (a key nesting deeper than any config would build a
/// document whose recursive drop and serialisation overflow the stack).
pub const MAX_KEY_DEPTH: usize = 32;

impl std::str::FromStr for Override {
    type Err = Error;

    fn from_str(s: &str) -> Result<Self> {
        // The setting as the error quotes it: its first 120 characters.
        let shown: String = match s.char_indices().nth(120) {
            Some((i, _)) => format!("{}…", &s[..i]),
            None => s.to_string(),
        };
        let bad = |m: &str| Error::invalid("--set", format!("`{shown}`: {m}"));
        let (key, value) = s
            .split_once('=')
            .ok_or_else(|| bad("expected key.path=value"))?;
        let key: Vec<String> = key.trim().split('.').map(str::to_string).collect();
        if key.len() > MAX_KEY_DEPTH {
            return Err(bad(&format!(
                "a key of {} segments; no config nests more than {MAX_KEY_DEPTH} deep",
                key.len()
            )));
        }
        if key.iter().any(|k| k.is_empty()) {
            return Err(bad("empty key segment"));
        }
        let value = if value.trim().is_empty() {
            Value::Null
        } else {
            serde_yaml_ng::from_str(value).map_err(|e| bad(&format!("value is not YAML: {e}")))?
        };
        Ok(Override {
            key,
            value,
            text: s.to_string(),
        })
    }
}

impl fmt::Display for Override {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.text)
    }
}

/// `--set` overrides, applied in order (a later one wins).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Overrides(Vec<Override>);

impl Overrides {
    /// Parse `key.path=value` strings.
    pub fn parse<S: AsRef<str>>(items: impl IntoIterator<Item = S>) -> Result<Self> {
        items
            .into_iter()
            .map(|s| s.as_ref().parse())
            .collect::<Result<Vec<_>>>()
            .map(Overrides)
    }

    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    pub fn iter(&self) -> impl Iterator<Item = &Override> {
        self.0.iter()
    }

    /// Add one override after the others.
    pub fn push(&mut self, o: Override) {
        self.0.push(o);
    }

    /// These overrides followed by `later` (which win).
    pub fn then(&self, later: &Overrides) -> Overrides {
        Overrides(self.0.iter().chain(&later.0).cloned().collect())
    }

    /// The overrides as `key=value` strings, for provenance records.
    pub fn texts(&self) -> Vec<String> {
        self.0.iter().map(|o| o.text.clone()).collect()
    }

    /// Parse `text` (from `file`) and apply the overrides to the document.
    pub fn apply_to_text(&self, text: &str, file: &Path) -> Result<Value> {
        let mut value: Value = serde_yaml_ng::from_str(text).map_err(|e| error(file, &e))?;
        self.apply(&mut value).map_err(|e| e.in_file(file))?;
        Ok(value)
    }

    /// Apply the overrides to a YAML document. Missing mapping keys are created (a config's
    /// defaults are filled in by its parser); an index must exist; setting a key inside a scalar
    /// is an error naming the key.
    pub fn apply(&self, doc: &mut Value) -> Result<()> {
        for o in &self.0 {
            let mut node = &mut *doc;
            for (depth, seg) in o.key.iter().enumerate() {
                let here = || o.key[..=depth].join(".");
                if node.is_null() {
                    *node = Value::Mapping(Mapping::new());
                }
                node = match node {
                    Value::Mapping(m) => m.entry(Value::String(seg.clone())).or_insert(Value::Null),
                    Value::Sequence(s) => {
                        let len = s.len();
                        let i: usize = seg.parse().map_err(|_| {
                            Error::invalid(
                                here(),
                                format!("--set `{o}`: a list; expected an index"),
                            )
                        })?;
                        s.get_mut(i).ok_or_else(|| {
                            Error::invalid(
                                here(),
                                format!("--set `{o}`: index {i} out of range (the list has {len})"),
                            )
                        })?
                    }
                    _ => {
                        let parent = o.key[..depth].join(".");
                        return Err(Error::invalid(
                            here(),
                            format!("--set `{o}`: `{parent}` is a value, not a section"),
                        ));
                    }
                };
            }
            *node = o.value.clone();
        }
        Ok(())
    }

    /// `e` with a note naming the override when its field was set by one.
    pub fn explain(&self, e: Error) -> Error {
        match e {
            Error::Field {
                file,
                field,
                message,
            } => {
                let by = self
                    .0
                    .iter()
                    .rev()
                    .find(|o| field_matches(&field, &message, &o.key))
                    .map(|o| format!(" (set by --set {o})"));
                // Line numbers refer to the document after the overrides, not to the file.
                let message = match message.rfind(" at line ") {
                    Some(i) if !self.0.is_empty() => message[..i].to_string(),
                    _ => message,
                };
                Error::Field {
                    file,
                    field,
                    message: message + by.as_deref().unwrap_or(""),
                }
            }
            other => other,
        }
    }
}

/// Whether an error about serde's field path (`channels[1].kvp`) concerns the override key
/// (`channels.1.kvp`): the same field, a field inside it, or an unknown key it added to the
/// section the error names.
fn field_matches(field: &str, message: &str, key: &[String]) -> bool {
    let field = field.replace('[', ".").replace(']', "");
    let joined = key.join(".");
    let last = &key[key.len() - 1];
    // The section holding the unknown key: `.` (the whole file) for a top-level key.
    let section = if key.len() == 1 {
        ".".to_string()
    } else {
        key[..key.len() - 1].join(".")
    };
    let unknown_here = section == field && message.contains(&format!("unknown field `{last}`"));
    field == joined || field.starts_with(&format!("{joined}.")) || unknown_here
}

#[cfg(test)]
mod tests {
    use super::*;

    fn doc() -> Value {
        serde_yaml_ng::from_str("a: 1\nb:\n  c: x\nlist:\n  - k: 1\n  - k: 2\n").unwrap()
    }

    fn set(doc: &mut Value, items: &[&str]) -> Result<()> {
        Overrides::parse(items)?.apply(doc)
    }

    #[test]
    fn overrides_set_nested_keys_list_items_and_create_missing_sections() {
        let mut d = doc();
        set(
            &mut d,
            &[
                "a=2.5",
                "b.c=[1, 2]",
                "list.1.k=sart",
                "new.deep.flag=true",
                "a=3",
            ],
        )
        .unwrap();
        let want: Value = serde_yaml_ng::from_str(
            "a: 3\nb:\n  c: [1, 2]\nlist:\n  - k: 1\n  - k: sart\nnew:\n  deep:\n    flag: true\n",
        )
        .unwrap();
        assert_eq!(d, want);
    }

    #[test]
    fn bad_overrides_are_refused_with_the_key() {
        let deep = format!("{}=1", vec!["a"; 50_000].join("."));
        for (item, needle) in [
            ("novalue", "expected key.path=value"),
            ("a..b=1", "empty key segment"),
            ("a.b=1", "`a` is a value"),
            ("list.x=1", "expected an index"),
            ("list.5.k=1", "index 5 out of range (the list has 2)"),
            ("a=[1,", "not YAML"),
            (deep.as_str(), "50000 segments"),
        ] {
            let e = set(&mut doc(), &[item]).unwrap_err().to_string();
            assert!(e.contains(needle), "{item}: {e}");
        }
    }

    #[test]
    fn a_type_error_in_an_overridden_field_names_the_override() {
        #[derive(serde::Deserialize, Debug)]
        #[allow(dead_code)]
        struct C {
            a: u32,
        }
        let o = Overrides::parse(["a=-4"]).unwrap();
        let e = parse_with::<C>("a: 1\n", Path::new("c.yaml"), &o)
            .unwrap_err()
            .to_string();
        assert!(e.contains("c.yaml") && e.contains("--set a=-4"), "{e}");
        assert!(
            !e.contains("line"),
            "line numbers of the rewritten document: {e}"
        );
        #[derive(serde::Deserialize, Debug)]
        #[serde(deny_unknown_fields)]
        #[allow(dead_code)]
        struct Strict {
            a: u32,
        }
        #[derive(serde::Deserialize, Debug)]
        #[allow(dead_code)]
        struct D {
            s: Strict,
        }
        let o = Overrides::parse(["s.b=1"]).unwrap();
        let e = parse_with::<D>("s: {a: 1}\n", Path::new("d.yaml"), &o)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("unknown field `b`") && e.contains("--set s.b=1"),
            "{e}"
        );
        // A misspelt top-level key: the error names the file and the override, not a field.
        let o = Overrides::parse(["b=1"]).unwrap();
        let e = parse_with::<Strict>("a: 1\n", Path::new("d.yaml"), &o)
            .unwrap_err()
            .to_string();
        assert!(
            e.starts_with("d.yaml: unknown field `b`") && e.contains("--set b=1"),
            "{e}"
        );
    }
}
