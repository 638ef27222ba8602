//! An XDF header or footer (liblsl's pugixml output) as a small element
//! tree: names, text (entity and character references decoded, CDATA
//! kept) and child elements; attributes, comments, the `<?xml …?>`
//! declaration and processing instructions are read past. The tokenizer
//! is `quick-xml` (well-formedness: matching end tags, one root, quoted
//! attributes); this module keeps the tree bounded: the input by the
//! caller (a chunk of at most [`super::MAX_XML_BYTES`]), the nesting by
//! [`MAX_DEPTH`], the element count by [`MAX_ELEMENTS`] and a list by
//! [`ListCap`].

use quick_xml::events::Event;
use quick_xml::reader::Reader;

/// Deepest element nesting accepted.
pub const MAX_DEPTH: usize = 64;
/// Most elements one document keeps: a stream header of the largest
/// channel count ([`super::reader::MAX_CHANNELS`]) with four fields per
/// channel, plus room for the rest. A parsed element costs ~100 bytes
/// against the ~20 of its text, so this (not the text's size) bounds the
/// tree: ~30 MB.
pub const MAX_ELEMENTS: usize = 4 * super::reader::MAX_CHANNELS + 4096;

/// What is wrong with an XML document, and at which byte of its text.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("byte {byte}: {what}")]
pub struct XmlError {
    /// Offset into the document's text where the problem was found.
    pub byte: u64,
    /// What is wrong.
    pub what: String,
}

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
pub fn parse(text: &str) -> Result<Element, XmlError> {
    parse_capped(text, None)
}

/// [`parse`], keeping at most `cap.keep` children of each `cap.list`
/// element and at most [`MAX_ELEMENTS`] elements in all (more is an
/// error): the tree is bounded by what the document declares, not by how
/// much it lists.
pub fn parse_capped(text: &str, cap: Option<ListCap<'_>>) -> Result<Element, XmlError> {
    let mut reader = Reader::from_str(text);
    // Ends must match their starts (quick-xml's default, said here
    // because the tree below relies on it).
    reader.config_mut().check_end_names = true;
    let mut tree = Tree {
        stack: Vec::new(),
        root: None,
        kept: 0,
        cap,
    };
    loop {
        let at = reader.buffer_position();
        let event = reader.read_event().map_err(|e| XmlError {
            byte: reader.error_position(),
            what: e.to_string(),
        })?;
        let fail = |what: String| XmlError { byte: at, what };
        match event {
            Event::Start(ref start) | Event::Empty(ref start) => {
                let empty = matches!(event, Event::Empty(_));
                let name = String::from_utf8_lossy(start.name().as_ref()).into_owned();
                if tree.stack.len() >= MAX_DEPTH {
                    return Err(fail(format!("elements nested deeper than {MAX_DEPTH}")));
                }
                if tree.root.is_some() {
                    return Err(fail(format!("a second root element <{name}>")));
                }
                let el = Element {
                    name,
                    ..Element::default()
                };
                if empty {
                    tree.close(el).map_err(fail)?;
                } else {
                    tree.stack.push(el);
                }
            }
            Event::End(_) => {
                // quick-xml has checked that the name matches.
                let Some(open) = tree.stack.pop() else {
                    return Err(fail("a closing tag with no open element".to_owned()));
                };
                tree.close(open).map_err(fail)?;
            }
            Event::Text(t) => {
                let raw = t.decode().map_err(|e| fail(e.to_string()))?;
                tree.text(&raw).map_err(fail)?;
            }
            Event::CData(c) => {
                let raw = c.decode().map_err(|e| fail(e.to_string()))?;
                match tree.stack.last_mut() {
                    Some(e) => e.text.push_str(&raw),
                    None => return Err(fail("CDATA outside the root element".to_owned())),
                }
            }
            Event::GeneralRef(r) => {
                let c = if r.is_char_ref() {
                    r.resolve_char_ref().ok().flatten().map(String::from)
                } else {
                    let name = r.decode().map_err(|e| fail(e.to_string()))?;
                    quick_xml::escape::resolve_xml_entity(&name).map(str::to_owned)
                };
                let Some(c) = c else {
                    let name = String::from_utf8_lossy(&r);
                    return Err(fail(format!("unknown entity `&{name};`")));
                };
                tree.text(&c).map_err(fail)?;
            }
            Event::Comment(_) | Event::Decl(_) | Event::PI(_) | Event::DocType(_) => {}
            Event::Eof => break,
        }
    }
    if let Some(open) = tree.stack.last() {
        return Err(XmlError {
            byte: text.len() as u64,
            what: format!("the text ends inside <{}>", open.name),
        });
    }
    tree.root.ok_or_else(|| XmlError {
        byte: 0,
        what: "no element".to_owned(),
    })
}

/// The tree being built: the open elements (the root is the first one
/// closed at depth 0) and the count of elements kept.
struct Tree<'c> {
    stack: Vec<Element>,
    root: Option<Element>,
    kept: usize,
    cap: Option<ListCap<'c>>,
}

impl Tree<'_> {
    /// Character data: kept in the open element; outside the root only
    /// whitespace may stand.
    fn text(&mut self, raw: &str) -> Result<(), String> {
        match self.stack.last_mut() {
            Some(e) => e.text.push_str(raw),
            None if raw.trim().is_empty() => {}
            None => return Err("text outside the root element".to_owned()),
        }
        Ok(())
    }

    /// An element is complete: into its parent (unless its list is full)
    /// or, at depth 0, the root.
    fn close(&mut self, el: Element) -> Result<(), String> {
        match self.stack.last_mut() {
            Some(parent) => {
                if self
                    .cap
                    .is_some_and(|c| parent.name == c.list && parent.children.len() >= c.keep)
                {
                    // Read past: its own children were counted as they closed.
                    self.kept -= descendants(&el);
                    return Ok(());
                }
                self.kept += 1;
                if self.kept > MAX_ELEMENTS {
                    return Err(format!(
                        "more than {MAX_ELEMENTS} elements (a header of {} channels has fewer)",
                        super::reader::MAX_CHANNELS
                    ));
                }
                parent.children.push(el)
            }
            None if self.root.is_none() => self.root = Some(el),
            None => return Err("a second root element".to_owned()),
        }
        Ok(())
    }
}

/// How many elements are below `el`.
fn descendants(el: &Element) -> usize {
    el.children.iter().map(|c| 1 + descendants(c)).sum()
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
        assert!(parse(&deep).unwrap_err().to_string().contains("nested"));
        let flood = format!("<a>{}</a>", "<b/>".repeat(MAX_ELEMENTS + 1));
        assert!(parse(&flood).unwrap_err().to_string().contains("elements"));
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
