//! The small XML subset an XDF header or footer is written in (liblsl's
//! pugixml output): elements, text, entity and character references,
//! CDATA, comments, the `<?xml …?>` declaration and attributes (read past,
//! not kept). The input is bounded by the caller (a chunk of at most
//! [`super::MAX_XML_BYTES`]) and the nesting by [`MAX_DEPTH`], so nothing
//! here grows without a bound.

/// Deepest element nesting accepted.
pub const MAX_DEPTH: usize = 64;
/// Most elements one document keeps: a stream header of the largest
/// channel count ([`super::reader::MAX_CHANNELS`]) with four fields per
/// channel, plus room for the rest. A parsed element costs ~100 bytes
/// against the ~20 of its text, so this (not the text's size) bounds the
/// tree: ~30 MB.
pub const MAX_ELEMENTS: usize = 4 * super::reader::MAX_CHANNELS + 4096;

/// A list element whose children beyond a count are read past and not
/// kept: a stream header's `<channels>` holds at most its own
/// `channel_count` entries.
#[derive(Clone, Copy, Debug)]
pub struct ListCap<'a> {
    /// The list element's name (`channels`).
    pub list: &'a str,
    /// How many of its children are kept.
    pub keep: usize,
}

/// One element: its name, its text (the concatenated character data
/// directly inside it, entities decoded) and its child elements.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Element {
    pub name: String,
    pub text: String,
    pub children: Vec<Element>,
}

impl Element {
    /// The first child called `name`.
    pub fn child(&self, name: &str) -> Option<&Element> {
        self.children.iter().find(|c| c.name == name)
    }

    /// Every child called `name`.
    pub fn children_named<'a>(&'a self, name: &'a str) -> impl Iterator<Item = &'a Element> + 'a {
        self.children.iter().filter(move |c| c.name == name)
    }

    /// The element at `path` below this one (first match at each step).
    pub fn at(&self, path: &[&str]) -> Option<&Element> {
        path.iter().try_fold(self, |e, name| e.child(name))
    }

    /// The trimmed text of the child `name`, if there is one.
    pub fn text_of(&self, name: &str) -> Option<&str> {
        self.child(name).map(|c| c.text.trim())
    }
}

/// Parses one XML document into its root element; the error says what is
/// wrong and at which byte of the text.
pub fn parse(text: &str) -> Result<Element, String> {
    parse_capped(text, None)
}

/// [`parse`], keeping at most `cap.keep` children of each `cap.list`
/// element and at most [`MAX_ELEMENTS`] elements in all (more is an
/// error): the tree is bounded by what the document declares, not by how
/// much it lists.
pub fn parse_capped(text: &str, cap: Option<ListCap<'_>>) -> Result<Element, String> {
    let b = text.as_bytes();
    let mut i = 0usize;
    let mut kept = 0usize;
    // The open elements; the root is the first one closed at depth 0.
    let mut stack: Vec<Element> = Vec::new();
    let mut root: Option<Element> = None;
    while i < b.len() {
        if b[i] == b'<' {
            if text[i..].starts_with("<?") {
                i = find(text, i, "?>")? + 2;
            } else if text[i..].starts_with("<!--") {
                i = find(text, i, "-->")? + 3;
            } else if text[i..].starts_with("<![CDATA[") {
                let end = find(text, i, "]]>")?;
                match stack.last_mut() {
                    Some(e) => e.text.push_str(&text[i + 9..end]),
                    None => return Err(format!("byte {i}: CDATA outside the root element")),
                }
                i = end + 3;
            } else if text[i..].starts_with("<!") {
                i = find(text, i, ">")? + 1;
            } else if text[i..].starts_with("</") {
                let end = find(text, i, ">")?;
                let name = text[i + 2..end].trim();
                let Some(open) = stack.pop() else {
                    return Err(format!(
                        "byte {i}: closing tag </{name}> with no open element"
                    ));
                };
                if open.name != name {
                    return Err(format!(
                        "byte {i}: closing tag </{name}> does not match <{}>",
                        open.name
                    ));
                }
                close(open, &mut stack, &mut root, i, cap, &mut kept)?;
                i = end + 1;
            } else {
                // A start tag: name, attributes (quoted values may hold '>').
                let mut j = i + 1;
                while j < b.len() && !matches!(b[j], b' ' | b'\t' | b'\r' | b'\n' | b'/' | b'>') {
                    j += 1;
                }
                let name = &text[i + 1..j];
                if name.is_empty() {
                    return Err(format!("byte {i}: a `<` that starts no tag"));
                }
                let mut quote: Option<u8> = None;
                while j < b.len() {
                    match (quote, b[j]) {
                        (Some(q), c) if c == q => quote = None,
                        (Some(_), _) => {}
                        (None, b'"' | b'\'') => quote = Some(b[j]),
                        (None, b'>') => break,
                        _ => {}
                    }
                    j += 1;
                }
                if j >= b.len() {
                    return Err(format!("byte {i}: tag <{name} is never closed"));
                }
                let self_closing = b[j - 1] == b'/';
                if stack.len() >= MAX_DEPTH {
                    return Err(format!("byte {i}: elements nested deeper than {MAX_DEPTH}"));
                }
                if root.is_some() {
                    return Err(format!("byte {i}: a second root element <{name}>"));
                }
                let el = Element {
                    name: name.to_owned(),
                    ..Element::default()
                };
                if self_closing {
                    close(el, &mut stack, &mut root, i, cap, &mut kept)?;
                } else {
                    stack.push(el);
                }
                i = j + 1;
            }
        } else {
            let end = text[i..].find('<').map_or(b.len(), |k| i + k);
            let raw = &text[i..end];
            match stack.last_mut() {
                Some(e) => decode_into(raw, &mut e.text, i)?,
                None if raw.trim().is_empty() => {}
                None => return Err(format!("byte {i}: text outside the root element")),
            }
            i = end;
        }
    }
    if let Some(open) = stack.last() {
        return Err(format!("the text ends inside <{}>", open.name));
    }
    root.ok_or_else(|| "no element".to_owned())
}

fn find(text: &str, from: usize, what: &str) -> Result<usize, String> {
    text[from..]
        .find(what)
        .map(|k| from + k)
        .ok_or_else(|| format!("byte {from}: no `{what}` to end what starts here"))
}

fn close(
    el: Element,
    stack: &mut [Element],
    root: &mut Option<Element>,
    at: usize,
    cap: Option<ListCap<'_>>,
    kept: &mut usize,
) -> Result<(), String> {
    match stack.last_mut() {
        Some(parent) => {
            if cap.is_some_and(|c| parent.name == c.list && parent.children.len() >= c.keep) {
                // Read past: its own children were counted as they closed.
                *kept -= descendants(&el);
                return Ok(());
            }
            *kept += 1;
            if *kept > MAX_ELEMENTS {
                return Err(format!(
                    "byte {at}: more than {MAX_ELEMENTS} elements (a header of {} channels \
                     has fewer)",
                    super::reader::MAX_CHANNELS
                ));
            }
            parent.children.push(el)
        }
        None if root.is_none() => *root = Some(el),
        None => return Err(format!("byte {at}: a second root element")),
    }
    Ok(())
}

/// How many elements are below `el`.
fn descendants(el: &Element) -> usize {
    el.children.iter().map(|c| 1 + descendants(c)).sum()
}

/// Appends `raw` to `out` with the predefined entities and character
/// references decoded.
fn decode_into(raw: &str, out: &mut String, at: usize) -> Result<(), String> {
    let mut rest = raw;
    while let Some(k) = rest.find('&') {
        out.push_str(&rest[..k]);
        let tail = &rest[k..];
        let Some(semi) = tail.find(';') else {
            return Err(format!("byte {at}: `&` starts no entity"));
        };
        let name = &tail[1..semi];
        let c = match name {
            "lt" => '<',
            "gt" => '>',
            "amp" => '&',
            "quot" => '"',
            "apos" => '\'',
            _ => {
                let code = if let Some(h) = name.strip_prefix("#x").or(name.strip_prefix("#X")) {
                    u32::from_str_radix(h, 16).ok()
                } else if let Some(d) = name.strip_prefix('#') {
                    d.parse::<u32>().ok()
                } else {
                    None
                };
                code.and_then(char::from_u32)
                    .ok_or_else(|| format!("byte {at}: unknown entity `&{name};`"))?
            }
        };
        out.push(c);
        rest = &tail[semi + 1..];
    }
    out.push_str(rest);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_stream_header_with_entities_and_empty_elements() {
        let x = "<?xml version=\"1.0\"?>\n<info><name>a &amp; b&#x21;</name><desc/>\
                 <desc2 k=\"x>y\"><![CDATA[<raw>]]></desc2><!-- c --></info>";
        let e = parse(x).unwrap();
        assert_eq!(e.name, "info");
        assert_eq!(e.text_of("name"), Some("a & b!"));
        assert_eq!(e.child("desc").map(|d| d.children.len()), Some(0));
        assert_eq!(e.text_of("desc2"), Some("<raw>"));
    }

    #[test]
    fn broken_documents_are_errors_not_panics() {
        for bad in [
            "<info><name>x</info>",
            "<info>",
            "<info></info><b/>",
            "text",
            "<info>&bogus;</info>",
            "<info attr=\"never closed></info>",
            "",
            "<",
            "</x>",
        ] {
            assert!(parse(bad).is_err(), "{bad}");
        }
        let deep = "<a>".repeat(MAX_DEPTH + 1);
        assert!(parse(&deep).unwrap_err().contains("nested"));
        let flood = format!("<a>{}</a>", "<b/>".repeat(MAX_ELEMENTS + 1));
        assert!(parse(&flood).unwrap_err().contains("elements"));
    }

    #[test]
    fn a_list_keeps_only_its_declared_entries() {
        let x = "<info><channels><channel>a</channel><channel>b</channel>\
                 <channel>c</channel></channels><channel>d</channel></info>";
        let cap = ListCap {
            list: "channels",
            keep: 2,
        };
        let e = parse_capped(x, Some(cap)).unwrap();
        let kept: Vec<&str> = e.children[0]
            .children
            .iter()
            .map(|c| c.text.as_str())
            .collect();
        assert_eq!(kept, ["a", "b"]);
        assert_eq!(e.text_of("channel"), Some("d"), "only the list is capped");
    }
}
