//! A strict reader of the OpenCV-style YAML subset used by calibration files
//! (`%YAML:1.0` header, `key: value`, nested maps by indentation, flow sequences that may span
//! lines, `!!opencv-matrix` tags). Every entry keeps its line so errors can name it.
//!
//! OpenCV's files are not valid YAML 1.2 (`%YAML:1.0`), so a general YAML crate rejects them;
//! this reader accepts exactly what calibration files need and nothing else.

/// A value: a scalar or a flow sequence of scalars.
#[derive(Clone, Debug, PartialEq)]
pub enum YamlValue {
    Scalar(String),
    Seq(Vec<String>),
    /// A key whose children follow on more indented lines.
    Map,
}

/// One `key: value`; nested keys are joined by `/` (e.g. `T_BS/data`).
#[derive(Clone, Debug, PartialEq)]
pub struct YamlEntry {
    pub key: String,
    pub value: YamlValue,
    pub line: usize,
}

/// A syntax error at a 1-based line.
#[derive(Clone, Debug, PartialEq)]
pub struct YamlSyntaxError {
    pub line: usize,
    pub message: String,
}

fn strip_comment(s: &str) -> &str {
    let mut in_q: Option<char> = None;
    for (i, c) in s.char_indices() {
        match (in_q, c) {
            (None, '"' | '\'') => in_q = Some(c),
            (Some(q), c) if c == q => in_q = None,
            (None, '#') => return &s[..i],
            _ => {}
        }
    }
    s
}

fn unquote(s: &str) -> String {
    let s = s.trim();
    if s.len() >= 2
        && ((s.starts_with('"') && s.ends_with('"')) || (s.starts_with('\'') && s.ends_with('\'')))
    {
        s[1..s.len() - 1].to_string()
    } else {
        s.to_string()
    }
}

/// Parses `text` into entries in file order.
pub fn parse(text: &str) -> Result<Vec<YamlEntry>, YamlSyntaxError> {
    let err = |line, m: &str| YamlSyntaxError {
        line,
        message: m.to_string(),
    };
    let mut out: Vec<YamlEntry> = Vec::new();
    // (indent, key) of open parent maps.
    let mut parents: Vec<(usize, String)> = Vec::new();
    let lines: Vec<&str> = text.lines().collect();
    let mut i = 0;
    while i < lines.len() {
        let line_no = i + 1;
        let raw = strip_comment(lines[i]);
        i += 1;
        let t = raw.trim();
        if t.is_empty() || t == "---" || t == "..." || t.starts_with('%') {
            continue;
        }
        if raw.contains('\t') {
            return Err(err(
                line_no,
                "tab characters are not allowed for indentation",
            ));
        }
        if t.starts_with("- ") || t == "-" {
            return Err(err(
                line_no,
                "block sequences (`- item`) are not supported; use [a, b, c]",
            ));
        }
        let indent = raw.len() - raw.trim_start().len();
        let Some((k, v)) = t.split_once(':') else {
            return Err(err(line_no, "expected `key: value`"));
        };
        let k = unquote(k);
        if k.is_empty() || k.contains(char::is_whitespace) {
            return Err(err(line_no, "invalid key"));
        }
        while parents.last().is_some_and(|(pi, _)| *pi >= indent) {
            parents.pop();
        }
        if indent > 0 && parents.is_empty() {
            return Err(err(line_no, "unexpected indentation"));
        }
        let key = parents
            .iter()
            .map(|(_, p)| p.as_str())
            .chain(std::iter::once(k.as_str()))
            .collect::<Vec<_>>()
            .join("/");
        let mut v = v.trim();
        if v.starts_with("!!") {
            // Type tags such as `!!opencv-matrix`: the value follows the tag.
            v = v
                .split_once(char::is_whitespace)
                .map(|(_, r)| r.trim())
                .unwrap_or("");
        }
        let value = if v.is_empty() {
            parents.push((indent, k));
            YamlValue::Map
        } else if let Some(rest) = v.strip_prefix('[') {
            let mut body = rest.to_string();
            while !body.contains(']') {
                let Some(next) = lines.get(i) else {
                    return Err(err(line_no, "flow sequence `[` is never closed"));
                };
                i += 1;
                body.push(' ');
                body.push_str(strip_comment(next));
            }
            let (inner, after) = body.split_once(']').unwrap_or((&body, ""));
            if !after.trim().is_empty() {
                return Err(err(line_no, "unexpected text after `]`"));
            }
            let items: Vec<String> = inner
                .split(',')
                .map(unquote)
                .filter(|s| !s.is_empty())
                .collect();
            YamlValue::Seq(items)
        } else if v.starts_with('{') {
            return Err(err(line_no, "flow maps `{...}` are not supported"));
        } else {
            YamlValue::Scalar(unquote(v))
        };
        if out.iter().any(|e| e.key == key) {
            return Err(err(line_no, &format!("duplicate key `{key}`")));
        }
        out.push(YamlEntry {
            key,
            value,
            line: line_no,
        });
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reads_opencv_flat_file() {
        let t = "%YAML:1.0\n# c\nCamera.fx: 520.0 # focal\nCamera.type: \"PinHole\"\n";
        let e = parse(t).unwrap();
        assert_eq!(e[0].key, "Camera.fx");
        assert_eq!(e[0].value, YamlValue::Scalar("520.0".into()));
        assert_eq!(e[0].line, 3);
        assert_eq!(e[1].value, YamlValue::Scalar("PinHole".into()));
    }

    #[test]
    fn reads_nested_maps_and_multiline_sequences() {
        let t = "T_BS:\n  cols: 4\n  data: [1, 2,\n         3, 4]\nrate_hz: 20\nres: [752, 480]\nM: !!opencv-matrix\n  rows: 1\n";
        let e = parse(t).unwrap();
        let get = |k: &str| e.iter().find(|x| x.key == k).unwrap().clone();
        assert_eq!(get("T_BS/cols").value, YamlValue::Scalar("4".into()));
        assert_eq!(
            get("T_BS/data").value,
            YamlValue::Seq(vec!["1".into(), "2".into(), "3".into(), "4".into()])
        );
        assert_eq!(get("rate_hz").line, 5);
        assert_eq!(get("M/rows").value, YamlValue::Scalar("1".into()));
    }

    #[test]
    fn rejects_garbage_with_line() {
        assert_eq!(parse("a: 1\nnonsense\n").unwrap_err().line, 2);
        assert_eq!(parse("a: [1, 2\n").unwrap_err().line, 1);
        assert_eq!(parse("a: 1\na: 2\n").unwrap_err().line, 2);
        assert!(parse("  a: 1\n").is_err());
    }
}
