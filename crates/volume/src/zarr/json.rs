//! A cursor over `zarr.json` that remembers where it is (`codecs[1].configuration.endian`), so
//! every metadata error names the file, the key and what was expected.

use crate::VolumeError;
use serde_json::Value;
use std::path::Path;

/// One JSON value of a metadata file, with its key path for messages.
#[derive(Clone)]
pub(crate) struct J<'a> {
    pub file: &'a Path,
    pub value: &'a Value,
    /// Key path from the document root, e.g. `codecs[0].configuration.endian`; empty at the root.
    path: String,
}

impl<'a> J<'a> {
    pub(crate) fn root(file: &'a Path, value: &'a Value) -> Self {
        J {
            file,
            value,
            path: String::new(),
        }
    }

    /// A format error at this value: "key X: expected ..., found the JSON text".
    pub(crate) fn err(&self, expected: impl Into<String>) -> VolumeError {
        let found = match self.value {
            Value::Null => "nothing".to_string(),
            Value::String(s) => s.clone(),
            v => v.to_string(),
        };
        VolumeError::format(self.file, self.at_text(), expected, found)
    }

    /// A structurally valid value this reader does not handle: "key X: msg".
    pub(crate) fn problem(&self, msg: &str) -> VolumeError {
        VolumeError::Grid {
            origin: self.file.display().to_string(),
            problem: format!("{}: {msg}", self.at_text()),
        }
    }

    fn at_text(&self) -> String {
        if self.path.is_empty() {
            "document".to_string()
        } else {
            format!("key {}", self.path)
        }
    }

    /// The member `key` (JSON null when absent, which every typed getter reports as missing).
    pub(crate) fn get(&self, key: &str) -> J<'a> {
        static NULL: Value = Value::Null;
        J {
            file: self.file,
            value: self.value.get(key).unwrap_or(&NULL),
            path: if self.path.is_empty() {
                key.to_string()
            } else {
                format!("{}.{key}", self.path)
            },
        }
    }

    pub(crate) fn is_null(&self) -> bool {
        self.value.is_null()
    }

    pub(crate) fn str(&self, expected: &str) -> Result<&'a str, VolumeError> {
        self.value.as_str().ok_or_else(|| self.err(expected))
    }

    /// The elements of an array, each with its index in the key path.
    pub(crate) fn items(&self, expected: &str) -> Result<Vec<J<'a>>, VolumeError> {
        let arr = self.value.as_array().ok_or_else(|| self.err(expected))?;
        Ok(arr
            .iter()
            .enumerate()
            .map(|(i, v)| J {
                file: self.file,
                value: v,
                path: format!("{}[{i}]", self.path),
            })
            .collect())
    }

    /// An array of unsigned integers.
    pub(crate) fn u64s(&self, expected: &str) -> Result<Vec<u64>, VolumeError> {
        self.value
            .as_array()
            .and_then(|a| a.iter().map(Value::as_u64).collect::<Option<Vec<u64>>>())
            .ok_or_else(|| self.err(expected))
    }

    /// An array of finite numbers.
    pub(crate) fn f64s(&self, expected: &str) -> Result<Vec<f64>, VolumeError> {
        self.value
            .as_array()
            .and_then(|a| {
                a.iter()
                    .map(|v| v.as_f64().filter(|x| x.is_finite()))
                    .collect::<Option<Vec<f64>>>()
            })
            .ok_or_else(|| self.err(expected))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn errors_name_the_key_path() {
        let v: Value =
            serde_json::from_str(r#"{"codecs":[{"configuration":{"endian":1}}]}"#).unwrap();
        let root = J::root(Path::new("z/zarr.json"), &v);
        let items = root.get("codecs").items("a list").unwrap();
        let e = items[0]
            .get("configuration")
            .get("endian")
            .str("\"little\" or \"big\"")
            .unwrap_err();
        assert_eq!(
            e.to_string(),
            r#"z/zarr.json: key codecs[0].configuration.endian: expected "little" or "big", found "1""#
        );
        let e = root.get("shape").u64s("a list of integers").unwrap_err();
        assert_eq!(
            e.to_string(),
            r#"z/zarr.json: key shape: expected a list of integers, found "nothing""#
        );
    }
}
