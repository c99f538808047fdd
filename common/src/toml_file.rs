//! Configuration files in TOML, with errors that point at the value at fault.
//!
//! A table read through an intermediate (the `[fusion]` and `[features]` tables are split by key
//! before their parts are read, because serde's `flatten` cannot refuse unknown keys) loses the
//! positions of its values: toml then reports a value of the wrong type at the table's header,
//! with the key's path appended ("in `grid.resolution_m`"). [`parse`] finds that key in the
//! document and reports the error at its value instead, in toml's own format; every other error is
//! toml's as it is.

use serde::de::DeserializeOwned;
use toml::de::{DeTable, DeValue};

/// Parses `text`; the error is toml's message, placed at the offending value where it can be.
pub fn parse<T: DeserializeOwned>(text: &str) -> Result<T, String> {
    toml::from_str(text).map_err(|e| at_value(text, &e).unwrap_or_else(|| e.to_string()))
}

/// The error reported at the value it names, if it was reported at a table header with the path
/// of a key that the document holds.
fn at_value(text: &str, error: &toml::de::Error) -> Option<String> {
    let (what, key_path) = error.message().trim_end().rsplit_once("\nin `")?;
    let key_path = key_path.strip_suffix('`')?;
    let header = text.get(error.span()?)?.trim();
    let table = header.strip_prefix('[')?.strip_suffix(']')?;
    if table.starts_with('[') {
        return None; // an array of tables: which element is meant cannot be told
    }
    let path: Vec<&str> = table
        .split('.')
        .chain(key_path.split('.'))
        .map(str::trim)
        .collect();
    let document = DeTable::parse(text).ok()?;
    let mut here = document.get_ref();
    let mut span = None;
    for (i, key) in path.iter().enumerate() {
        let (_, value) = here.iter().find(|(k, _)| k.get_ref().as_ref() == *key)?;
        if i + 1 == path.len() {
            span = Some(value.span());
        } else if let DeValue::Table(inner) = value.get_ref() {
            here = inner;
        } else {
            return None;
        }
    }
    let span = span?;
    let line_start = text[..span.start].rfind('\n').map_or(0, |i| i + 1);
    let line_end = text[span.start..]
        .find('\n')
        .map_or(text.len(), |i| span.start + i);
    let line_no = text[..span.start].matches('\n').count() + 1;
    let column = text[line_start..span.start].chars().count() + 1;
    let line = &text[line_start..line_end];
    let width = text[span.start..span.end.min(line_end)]
        .chars()
        .count()
        .max(1);
    let gutter = " ".repeat(line_no.to_string().len());
    Some(format!(
        "TOML parse error at line {line_no}, column {column}\n{gutter} |\n{line_no} | {line}\n\
         {gutter} | {}{}\n{what}\nin `{}`\n",
        " ".repeat(column - 1),
        "^".repeat(width),
        path.join(".")
    ))
}

#[cfg(test)]
mod tests {
    use serde::Deserialize;

    use super::*;

    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    struct Grid {
        #[allow(dead_code)]
        resolution_m: f32,
    }

    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    struct Engine {
        #[allow(dead_code)]
        grid: Option<Grid>,
    }

    /// Read through a table, as the pipeline's `[fusion]` is.
    #[derive(Debug)]
    struct Section;

    impl<'de> Deserialize<'de> for Section {
        fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
            let table = toml::Table::deserialize(d)?;
            table
                .try_into::<Engine>()
                .map_err(serde::de::Error::custom)?;
            Ok(Section)
        }
    }

    #[derive(Debug, Deserialize)]
    struct File {
        #[allow(dead_code)]
        fusion: Section,
        #[allow(dead_code)]
        seed: Option<u64>,
    }

    #[test]
    fn a_wrong_type_inside_a_split_table_is_reported_at_its_value() {
        let text = "seed = 1\n\n[fusion]\n# the grid\n\n[fusion.grid]\nresolution_m = \"big\"\n";
        let plain = toml::from_str::<File>(text).unwrap_err();
        assert!(plain.to_string().contains("line 3"), "{plain}");
        let e = parse::<File>(text).unwrap_err();
        assert!(
            e.starts_with("TOML parse error at line 7, column 16\n"),
            "{e}"
        );
        assert!(
            e.contains("7 | resolution_m = \"big\"\n  |                ^^^^^\n"),
            "{e}"
        );
        assert!(e.contains("expected f32"), "{e}");
        assert!(e.ends_with("in `fusion.grid.resolution_m`\n"), "{e}");
    }

    #[test]
    fn other_errors_are_tomls_own() {
        for text in ["seed = \"x\"\n[fusion]\n", "[fusion]\nseed = 1\n[fusion\n"] {
            let e = parse::<File>(text).unwrap_err();
            assert_eq!(e, toml::from_str::<File>(text).unwrap_err().to_string());
        }
        assert!(parse::<File>("[fusion]\n").is_ok());
    }
}
