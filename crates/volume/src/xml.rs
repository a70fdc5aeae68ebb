//! Just enough XML for VTK's XML formats: start/end tags with attributes, in file order, over a
//! byte buffer that may continue with binary appended data (the scan stops where the caller says).
//! A full XML crate would also want to own the binary tail, which is the part we must stream.

/// One tag: `<Name a="1">`, `<Name/>` or `</Name>`.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Tag {
    pub name: String,
    pub attrs: Vec<(String, String)>,
    pub closing: bool,
    /// Byte offset of `<` and one past `>`.
    pub start: usize,
    pub end: usize,
}

impl Tag {
    pub(crate) fn attr(&self, key: &str) -> Option<&str> {
        self.attrs
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    }
}

/// Iterates over the tags of `text` from `pos`; comments, `<?xml ...?>` and text are skipped.
/// Yields `Err(offset)` for a tag that does not parse (unterminated, bad attribute).
pub(crate) struct Tags<'a> {
    text: &'a [u8],
    pos: usize,
}

impl<'a> Tags<'a> {
    pub(crate) fn new(text: &'a [u8]) -> Self {
        Tags { text, pos: 0 }
    }
}

impl Iterator for Tags<'_> {
    type Item = Result<Tag, usize>;

    fn next(&mut self) -> Option<Self::Item> {
        loop {
            let rel = self.text[self.pos..].iter().position(|&b| b == b'<')?;
            let start = self.pos + rel;
            let rest = &self.text[start..];
            if rest.starts_with(b"<!--") {
                let Some(e) = find(rest, b"-->") else {
                    return Some(Err(start));
                };
                self.pos = start + e + 3;
                continue;
            }
            if rest.starts_with(b"<?") || rest.starts_with(b"<!") {
                let Some(e) = rest.iter().position(|&b| b == b'>') else {
                    return Some(Err(start));
                };
                self.pos = start + e + 1;
                continue;
            }
            let Some(len) = rest.iter().position(|&b| b == b'>') else {
                self.pos = self.text.len();
                return Some(Err(start));
            };
            self.pos = start + len + 1;
            return Some(parse_tag(&rest[1..len], start, start + len + 1).ok_or(start));
        }
    }
}

fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

/// Parses the inside of `<...>`, found at `start..end`.
fn parse_tag(inner: &[u8], start: usize, end: usize) -> Option<Tag> {
    let s = std::str::from_utf8(inner).ok()?;
    let (closing, s) = match s.strip_prefix('/') {
        Some(rest) => (true, rest),
        None => (false, s),
    };
    let s = s.strip_suffix('/').unwrap_or(s).trim();
    let name_end = s.find(|c: char| c.is_whitespace()).unwrap_or(s.len());
    let name = &s[..name_end];
    if name.is_empty() {
        return None;
    }
    let mut attrs = Vec::new();
    let mut rest = s[name_end..].trim_start();
    while !rest.is_empty() {
        let eq = rest.find('=')?;
        let key = rest[..eq].trim();
        let after = rest[eq + 1..].trim_start();
        let quote = after.chars().next().filter(|c| *c == '"' || *c == '\'')?;
        let close = after[1..].find(quote)?;
        attrs.push((key.to_string(), after[1..1 + close].to_string()));
        rest = after[close + 2..].trim_start();
    }
    Some(Tag {
        name: name.to_string(),
        attrs,
        closing,
        start,
        end,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scans_tags_and_attributes() {
        let text = br#"<?xml version="1.0"?><!-- c > --><A x="1" y = '2 3'><B/>text</A>"#;
        let tags: Vec<Tag> = Tags::new(text).map(|t| t.unwrap()).collect();
        let names: Vec<(&str, bool)> = tags.iter().map(|t| (t.name.as_str(), t.closing)).collect();
        assert_eq!(names, [("A", false), ("B", false), ("A", true)]);
        assert_eq!(tags[0].attr("x"), Some("1"));
        assert_eq!(tags[0].attr("y"), Some("2 3"));
        assert_eq!(tags[0].attr("z"), None);
        assert_eq!(&text[tags[1].end..tags[2].start], b"text");
    }

    #[test]
    fn bad_tags_report_offsets() {
        assert_eq!(Tags::new(b"ab<A x=1>").next(), Some(Err(2)));
        assert_eq!(Tags::new(b"<A x='1'").next(), Some(Err(0)));
    }
}
