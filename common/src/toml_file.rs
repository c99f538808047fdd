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
    let message = error.message().trim_end();
    // A value read through an intermediate table comes with its key's path; one read where the
    // table was (a tagged enum) without.
    let (what, key_path) = match message.rsplit_once("\nin `") {
        Some((what, path)) => (what, path.strip_suffix('`')?),
        None => (message, ""),
    };
    let table = reported_table(text, error.span()?)?;
    let mut path: Vec<&str> = table
        .split('.')
        .chain(key_path.split('.'))
        .map(str::trim)
        .filter(|k| !k.is_empty())
        .collect();
    let document = DeTable::parse(text).ok()?;
    let mut here = document.get_ref();
    let mut span = None;
    for (i, key) in path.clone().iter().enumerate() {
        let (_, value) = here.iter().find(|(k, _)| k.get_ref().as_ref() == *key)?;
        if i + 1 < path.len() {
            let DeValue::Table(inner) = value.get_ref() else {
                return None;
            };
            here = inner;
        } else if let DeValue::Table(inner) = value.get_ref() {
            // A table read as a whole (a tagged enum such as `[fusion.model]`): the error names
            // the table, not the key; the value it quotes tells which key it is, if only one
            // holds it.
            let quoted = quoted_value(what)?;
            let mut holders = inner
                .iter()
                .filter(|(_, v)| text.get(v.span()).map(str::trim) == Some(quoted));
            let (key, value) = holders.next()?;
            if holders.next().is_some() {
                return None;
            }
            path.push(key.get_ref().as_ref());
            span = Some(value.span());
        } else {
            span = Some(value.span());
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

/// The dotted path of the table an error was reported at: its `[header]`, or the part of a
/// header up to the key the error's span covers (`[fusion.model]` reported at `fusion`).
fn reported_table(text: &str, span: std::ops::Range<usize>) -> Option<&str> {
    let reported = text.get(span.clone())?.trim();
    if let Some(header) = reported.strip_prefix('[') {
        let table = header.strip_suffix(']')?;
        // An array of tables: which element is meant cannot be told.
        return (!table.starts_with('[')).then_some(table);
    }
    let line_start = text[..span.start].rfind('\n').map_or(0, |i| i + 1);
    let before = text[line_start..span.end].trim_start();
    let table = before.strip_prefix('[')?;
    (!table.starts_with('[')).then_some(table.trim())
}

/// The value an "invalid type" message quotes, as it is written in the document: `"high"` of
/// `invalid type: string "high", expected f32`, `true` of ``invalid type: boolean `true`, …``.
fn quoted_value(what: &str) -> Option<&str> {
    let rest = what.strip_prefix("invalid type: ")?;
    let rest = rest.split_once(' ').map(|(_, r)| r)?;
    let rest = rest.strip_prefix("point ").unwrap_or(rest); // "floating point `1.5`"
    if let Some(string) = rest.strip_prefix('"') {
        let end = string.find("\", expected")? + 2;
        return Some(&rest[..end]);
    }
    let inner = rest.strip_prefix('`')?;
    Some(&inner[..inner.find('`')?])
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

    /// Read as a whole, as the fusion's tagged `[fusion.model]` is.
    #[derive(Debug, Deserialize)]
    #[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
    enum Model {
        Smooth {
            #[allow(dead_code)]
            occupied_log_odds: f32,
            #[allow(dead_code)]
            free_log_odds: f32,
            #[allow(dead_code)]
            hears: Option<bool>,
        },
    }

    #[derive(Debug, Deserialize)]
    struct Tagged {
        #[allow(dead_code)]
        model: Model,
    }

    #[derive(Debug, Deserialize)]
    struct TaggedFile {
        #[allow(dead_code)]
        fusion: Tagged,
    }

    #[test]
    fn a_wrong_type_inside_a_tagged_table_is_reported_at_its_value() {
        let text = "[fusion.model]\nkind = \"smooth\"\nfree_log_odds = -1.5\noccupied_log_odds = \"high\"\n";
        let e = parse::<TaggedFile>(text).unwrap_err();
        assert!(
            e.starts_with("TOML parse error at line 4, column 21\n"),
            "{e}"
        );
        assert!(e.contains("in `fusion.model.occupied_log_odds`"), "{e}");
        let text = "[fusion.model]\nkind = \"smooth\"\nfree_log_odds = -1.5\noccupied_log_odds = 1.0\nhears = 3\n";
        let e = parse::<TaggedFile>(text).unwrap_err();
        assert!(
            e.starts_with("TOML parse error at line 5, column 9\n"),
            "{e}"
        );
    }
}
