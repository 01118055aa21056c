//! HTML tables of plain-text cells, escaped, numbers right-aligned and
//! verdict words coloured: what every table of `report.html` is made of.

use std::fmt::Write as _;

/// Text made safe for HTML content and attribute values.
pub fn escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;").replace('"', "&quot;")
}

/// The class of a table cell: numbers right-aligned, verdicts coloured.
fn cell_class(c: &str) -> Option<&'static str> {
    let verdict = c.split([' ', ':']).next().unwrap_or("");
    match verdict {
        "FAIL" | "NO" | "EXCEEDS" => Some("bad"),
        "pass" | "yes" | "ok" | "within" => Some("good"),
        _ if c.parse::<f64>().is_ok() => Some("num"),
        _ => None,
    }
}

/// A table of a header row and rows of plain-text cells (escaped here),
/// every row as wide as the header.
pub fn table(class: &str, head: &[&str], rows: &[Vec<String>]) -> String {
    let mut s = format!("<table class=\"{class}\"><thead><tr>");
    for h in head {
        let _ = write!(s, "<th>{}</th>", escape(h));
    }
    s.push_str("</tr></thead><tbody>\n");
    for r in rows {
        s.push_str("<tr>");
        for i in 0..head.len() {
            let c = r.get(i).map_or("", String::as_str);
            match cell_class(c) {
                Some(k) => {
                    let _ = write!(s, "<td class=\"{k}\">{}</td>", escape(c));
                }
                None => {
                    let _ = write!(s, "<td>{}</td>", escape(c));
                }
            }
        }
        s.push_str("</tr>\n");
    }
    s.push_str("</tbody></table>\n");
    s
}

/// A two-column table of named facts: the name as a row header.
pub fn facts(class: &str, rows: &[(&str, String)]) -> String {
    let mut s = format!("<table class=\"{class}\"><tbody>\n");
    for (k, v) in rows {
        let _ = writeln!(s, "<tr><th scope=\"row\">{}</th><td>{}</td></tr>", escape(k), escape(v));
    }
    s.push_str("</tbody></table>\n");
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cells_are_escaped_and_rows_as_wide_as_the_header() {
        let t = table("t", &["a", "b<"], &[vec!["x & y".into()], vec!["1".into(), "FAIL at 50 mm".into(), "z".into()]]);
        assert!(t.contains("<th>b&lt;</th>") && t.contains("<td>x &amp; y</td><td></td></tr>"), "{t}");
        // A cell beyond the header is not shown; numbers and verdicts get their class.
        assert!(
            !t.contains(">z<") && t.contains("<td class=\"num\">1</td><td class=\"bad\">FAIL at 50 mm</td>"),
            "{t}"
        );
        assert_eq!(t.matches("<tr>").count(), t.matches("</tr>").count());
        assert_eq!(escape("\"<&>\""), "&quot;&lt;&amp;&gt;&quot;");
    }

    #[test]
    fn verdict_words_are_coloured_and_other_text_not() {
        for (c, k) in [("pass", Some("good")), ("NO", Some("bad")), ("EXCEEDS", Some("bad")), ("ok", Some("good"))] {
            assert_eq!(cell_class(c), k, "{c}");
        }
        assert_eq!(cell_class("-12.5"), Some("num"));
        assert_eq!(cell_class("not evaluated: too short"), None);
        assert_eq!(cell_class("okay"), None);
    }
}
