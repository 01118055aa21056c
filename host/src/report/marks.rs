//! The event marks of a report: the summary's lines, the "Marks" section
//! of the HTML and Markdown reports, `marks.csv` and the JSON's `marks`,
//! each mark at its chainage ([`crate::analyze::marks`]).

use std::fmt::Write as _;

use serde_json::{Value, json};

use crate::analyze::marks::{PlacedMark, placed};
use crate::analyze::{Analysis, Source};
use crate::recording::mark::csv_text;
use crate::recording::um_to_mm;

/// The file of the marks in a report.
pub const CSV_FILE: &str = "marks.csv";
/// Its columns: one row a mark, in chainage order.
pub const CSV_HEADER: &str = "chainage_mm,chainage,run,kind,text,odometer_mm,seq,host_us";

/// The marks of an analysis, in chainage order.
pub fn of(source: &Source, a: &Analysis) -> Vec<PlacedMark> {
    placed(source, &a.joins)
}

/// One mark for people: chainage, kind, text, where it came from.
pub fn describe(m: &PlacedMark) -> String {
    let text = if m.mark.text.is_empty() { String::new() } else { format!(" \"{}\"", m.mark.text) };
    format!(
        "{} {}{text} (run {}, odometer {} mm, after frame {})",
        m.chainage(),
        m.mark.kind,
        m.run,
        um_to_mm(m.mark.odometer_um),
        m.mark.seq
    )
}

/// The summary's lines: `marks: N` and one line a mark (nothing without
/// marks: a recording from before them reads as it did).
pub fn summary(source: &Source, a: &Analysis) -> String {
    let marks = of(source, a);
    if marks.is_empty() {
        return String::new();
    }
    let mut s = format!("marks: {}\n", marks.len());
    for m in &marks {
        let _ = writeln!(s, "  {}", describe(m));
    }
    s
}

/// `marks.csv`.
pub fn csv(marks: &[PlacedMark]) -> String {
    let mut s = format!("{CSV_HEADER}\n");
    for m in marks {
        let _ = writeln!(
            s,
            "{},{},{},{},{},{},{},{}",
            m.chainage_mm.map_or(String::new(), |c| format!("{c:.3}")),
            m.chainage_mm.map_or(String::new(), crate::analyze::chainage),
            m.run,
            m.mark.kind,
            csv_text(&m.mark.text),
            um_to_mm(m.mark.odometer_um),
            m.mark.seq,
            m.mark.host_us
        );
    }
    s
}

/// The JSON's `marks`.
pub fn to_json(marks: &[PlacedMark]) -> Value {
    json!(
        marks
            .iter()
            .map(|m| json!({
                "chainage_mm": m.chainage_mm,
                "chainage": m.chainage_mm.map(crate::analyze::chainage),
                "run": m.run,
                "kind": m.mark.kind.name(),
                "text": m.mark.text,
                "odometer_mm": m.mark.odometer_mm(),
                "seq": m.mark.seq,
                "host_us": m.mark.host_us,
            }))
            .collect::<Vec<_>>()
    )
}

pub(super) fn rows(marks: &[PlacedMark]) -> Vec<Vec<String>> {
    marks
        .iter()
        .map(|m| {
            vec![
                m.chainage(),
                m.mark.kind.name().replace('_', " "),
                m.mark.text.clone(),
                m.run.to_string(),
                format!("{} mm", um_to_mm(m.mark.odometer_um)),
                m.mark.seq.to_string(),
            ]
        })
        .collect()
}

pub(super) const HEAD: [&str; 6] = ["chainage", "kind", "text", "run", "odometer", "after frame"];

/// The Markdown report's "Marks" section.
pub fn markdown(marks: &[PlacedMark]) -> String {
    let mut s = String::from("\n## Marks\n\n");
    if marks.is_empty() {
        s.push_str("No event marks were recorded.\n");
        return s;
    }
    let cell = |c: &str| c.replace('|', "\\|");
    let _ = writeln!(s, "| {} |", HEAD.join(" | "));
    let _ = writeln!(s, "|{}", "---|".repeat(HEAD.len()));
    for r in rows(marks) {
        let _ = writeln!(s, "| {} |", r.iter().map(|c| cell(c)).collect::<Vec<_>>().join(" | "));
    }
    s
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;
    use crate::recording::mark::{Mark, MarkKind};

    pub(in crate::report) fn marks() -> Vec<PlacedMark> {
        let m = |kind, text: &str, odometer_um| Mark {
            kind,
            text: text.into(),
            host_us: 1_000_000,
            seq: 30,
            head_us: 990_000,
            odometer_um,
            after_us: 10_000,
        };
        vec![
            PlacedMark { run: 1, mark: m(MarkKind::KilometrePost, "12.3", 250_000), chainage_mm: Some(12_345_250.0) },
            PlacedMark { run: 2, mark: m(MarkKind::Note, "a <b> | \"c\"", -4_000), chainage_mm: None },
        ]
    }

    #[test]
    fn csv_and_markdown_hold_every_mark() {
        let m = marks();
        let c = csv(&m);
        assert_eq!(
            c,
            "chainage_mm,chainage,run,kind,text,odometer_mm,seq,host_us\n\
             12345250.000,12+345.250,1,kilometre_post,\"12.3\",250.000,30,1000000\n\
             ,,2,note,\"a <b> | \"\"c\"\"\",-4.000,30,1000000\n"
        );
        let md = markdown(&m);
        assert!(md.contains("| 12+345.250 | kilometre post | 12.3 | 1 | 250.000 mm | 30 |"), "{md}");
        assert!(md.contains("a <b> \\| \"c\""), "{md}");
        assert_eq!(to_json(&m)[0]["chainage"], "12+345.250");
        assert!(to_json(&m)[1]["chainage_mm"].is_null());
    }
}
