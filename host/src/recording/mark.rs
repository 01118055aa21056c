//! Event marks: what the operator notes at the head's position while a run
//! is recorded (a weld, a joint, a kilometre post, a defect, free text), and
//! the one-line syntax they are typed in on the listener's terminal.
//!
//! A mark is stored as a host record ([`crate::recording::HostRecord::Mark`],
//! format 5 on) with the host's time and the odometer of the latest profile
//! received before it: the head's position when the operator asked, to
//! within the travel of one frame (plus the operator's reaction). `analyze`
//! places it at chainage by that odometer, as it places the frames.
//!
//! # The terminal's syntax
//!
//! One mark a line: a kind, then optional text after a space.
//!
//! | line | mark |
//! |---|---|
//! | `w [text]`, `weld [text]` | a weld |
//! | `j [text]`, `joint [text]` | a rail joint |
//! | `k LABEL`, `km LABEL`, `kp LABEL` | a kilometre post, e.g. `k 12.300` |
//! | `d [text]`, `defect [text]` | a defect (a squat, a burn, a broken fastening) |
//! | `n TEXT`, `note TEXT` | free text |
//!
//! Kinds are case-insensitive; an empty line is nothing. A kilometre post
//! needs its label and a note its text. Text is at most
//! [`MAX_TEXT_CHARS`] characters, printable (no control characters), and
//! trimmed.

use std::fmt;

use serde::{Deserialize, Serialize};

/// Longest text of a mark, characters.
pub const MAX_TEXT_CHARS: usize = 200;

/// What a mark marks.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[non_exhaustive]
pub enum MarkKind {
    /// A weld.
    Weld,
    /// A rail joint (fishplated or insulated).
    Joint,
    /// A kilometre post; its text is the post's label.
    KilometrePost,
    /// A defect seen on the rail.
    Defect,
    /// Free text.
    Note,
}

impl MarkKind {
    /// Every kind, in the order the page shows them.
    pub const ALL: [MarkKind; 5] =
        [MarkKind::Weld, MarkKind::Joint, MarkKind::KilometrePost, MarkKind::Defect, MarkKind::Note];

    /// Its name in files and on the wire of the page: `weld`, `joint`,
    /// `kilometre_post`, `defect`, `note`.
    pub fn name(self) -> &'static str {
        match self {
            MarkKind::Weld => "weld",
            MarkKind::Joint => "joint",
            MarkKind::KilometrePost => "kilometre_post",
            MarkKind::Defect => "defect",
            MarkKind::Note => "note",
        }
    }

    /// The kind of a [`MarkKind::name`] or a terminal's word for it.
    pub fn from_word(w: &str) -> Option<MarkKind> {
        Some(match w.to_ascii_lowercase().as_str() {
            "w" | "weld" => MarkKind::Weld,
            "j" | "joint" => MarkKind::Joint,
            "k" | "km" | "kp" | "kilometre_post" => MarkKind::KilometrePost,
            "d" | "defect" => MarkKind::Defect,
            "n" | "note" => MarkKind::Note,
            _ => return None,
        })
    }

    /// Whether a mark of this kind needs text (a post's label, a note's words).
    pub fn needs_text(self) -> bool {
        matches!(self, MarkKind::KilometrePost | MarkKind::Note)
    }
}

impl fmt::Display for MarkKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// Why a mark was not taken.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum MarkError {
    /// The first word is no kind.
    #[error(
        "`{0}` is no mark: start a line with w (weld), j (joint), k LABEL (kilometre post), d (defect) or n TEXT (note)"
    )]
    Kind(String),
    /// A kind that needs text without it.
    #[error("a {0} mark needs text after it (k 12.300, n TEXT)")]
    NoText(MarkKind),
    /// Text longer than [`MAX_TEXT_CHARS`].
    #[error("mark text of {0} characters: at most {MAX_TEXT_CHARS}")]
    TooLong(usize),
    /// Text with a control character.
    #[error("mark text with a control character (U+{0:04X}): printable text only")]
    Control(u32),
}

/// What the operator asked to mark: a kind and its text, checked.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct MarkEntry {
    /// The kind.
    pub kind: MarkKind,
    /// Its text, trimmed, printable, at most [`MAX_TEXT_CHARS`] (may be empty).
    pub text: String,
}

impl MarkEntry {
    /// A mark of `kind` with `text`, checked (see the module docs).
    pub fn new(kind: MarkKind, text: &str) -> Result<MarkEntry, MarkError> {
        let text = text.trim();
        let n = text.chars().count();
        if n > MAX_TEXT_CHARS {
            return Err(MarkError::TooLong(n));
        }
        // Bidirectional overrides too: they would turn a report's line round.
        let acts = |c: &char| c.is_control() || matches!(c, '\u{202a}'..='\u{202e}' | '\u{2066}'..='\u{2069}');
        if let Some(c) = text.chars().find(acts) {
            return Err(MarkError::Control(u32::from(c)));
        }
        if text.is_empty() && kind.needs_text() {
            return Err(MarkError::NoText(kind));
        }
        Ok(MarkEntry { kind, text: text.to_string() })
    }

    /// One line of the terminal (its line ending included or not); `None`
    /// for a blank line.
    pub fn parse_line(line: &str) -> Result<Option<MarkEntry>, MarkError> {
        let line = line.trim();
        if line.is_empty() {
            return Ok(None);
        }
        let (word, rest) = line.split_once(char::is_whitespace).unwrap_or((line, ""));
        let kind = MarkKind::from_word(word).ok_or_else(|| {
            let shown: String = word.chars().take(24).collect();
            MarkError::Kind(crate::output::printable(&shown).into_owned())
        })?;
        MarkEntry::new(kind, rest).map(Some)
    }
}

/// A mark as recorded.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Mark {
    /// The kind.
    pub kind: MarkKind,
    /// Its text (checked as [`MarkEntry::new`] does; a record whose text
    /// is not is read as damaged).
    pub text: String,
    /// Host time of the mark, µs since the listener started.
    pub host_us: u64,
    /// The latest profile received before the mark: its `seq`, its time on
    /// the head's clock (`timestamp_us`) and its odometer, µm.
    pub seq: u32,
    pub head_us: u64,
    pub odometer_um: i64,
    /// Host time from that profile's arrival to the mark, µs.
    pub after_us: u64,
}

impl Mark {
    /// Whether its text is one [`MarkEntry::new`] takes.
    pub fn is_valid(&self) -> bool {
        MarkEntry::new(self.kind, &self.text).is_ok_and(|e| e.text == self.text)
    }

    /// The head's odometer at the mark, mm.
    pub fn odometer_mm(&self) -> f64 {
        self.odometer_um as f64 / 1000.0
    }
}

/// The columns of `export --format marks`: one row a mark, in file order.
pub const CSV_HEADER: &str = "kind,text,odometer_mm,seq,head_us,host_us,after_us";

/// A text as one CSV field: quoted, its quotes doubled.
pub fn csv_text(s: &str) -> String {
    format!("\"{}\"", s.replace('"', "\"\""))
}

/// A mark's row of [`CSV_HEADER`].
pub fn csv_row(m: &Mark) -> String {
    format!(
        "{},{},{},{},{},{},{}",
        m.kind,
        csv_text(&m.text),
        crate::recording::um_to_mm(m.odometer_um),
        m.seq,
        m.head_us,
        m.host_us,
        m.after_us
    )
}

/// A mark in one line for people: kind, odometer, frame, time, text.
pub fn describe(m: &Mark) -> String {
    let text = if m.text.is_empty() { String::new() } else { format!(" \"{}\"", m.text) };
    format!(
        "{}{text} at odometer {} mm (after frame {}, {:.3} s into the listener)",
        m.kind,
        crate::recording::um_to_mm(m.odometer_um),
        m.seq,
        m.host_us as f64 / 1e6
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn terminal_lines_parse() {
        let m = |k, t: &str| Ok(Some(MarkEntry { kind: k, text: t.to_string() }));
        assert_eq!(MarkEntry::parse_line("w\n"), m(MarkKind::Weld, ""));
        assert_eq!(MarkEntry::parse_line("  WELD  thermite \r\n"), m(MarkKind::Weld, "thermite"));
        assert_eq!(MarkEntry::parse_line("j"), m(MarkKind::Joint, ""));
        assert_eq!(MarkEntry::parse_line("k 12.300"), m(MarkKind::KilometrePost, "12.300"));
        assert_eq!(MarkEntry::parse_line("kp\t41.2"), m(MarkKind::KilometrePost, "41.2"));
        assert_eq!(MarkEntry::parse_line("d squat, gauge corner"), m(MarkKind::Defect, "squat, gauge corner"));
        assert_eq!(MarkEntry::parse_line("n lubricator ÷ 3 m"), m(MarkKind::Note, "lubricator ÷ 3 m"));
        assert_eq!(MarkEntry::parse_line("   \n"), Ok(None));
    }

    #[test]
    fn bad_lines_say_why() {
        assert!(matches!(MarkEntry::parse_line("x weld"), Err(MarkError::Kind(_))));
        assert!(matches!(MarkEntry::parse_line("wel"), Err(MarkError::Kind(_))));
        assert_eq!(MarkEntry::parse_line("k"), Err(MarkError::NoText(MarkKind::KilometrePost)));
        assert_eq!(MarkEntry::parse_line("n   "), Err(MarkError::NoText(MarkKind::Note)));
        assert_eq!(MarkEntry::parse_line("d a\u{1b}[2Jb"), Err(MarkError::Control(0x1b)));
        let long = format!("n {}", "é".repeat(MAX_TEXT_CHARS + 1));
        assert_eq!(MarkEntry::parse_line(&long), Err(MarkError::TooLong(MAX_TEXT_CHARS + 1)));
        assert!(MarkEntry::parse_line(&format!("n {}", "é".repeat(MAX_TEXT_CHARS))).is_ok());
        // The message names the word, made printable, on one line.
        let e = MarkEntry::parse_line("\u{7}zz").unwrap_err().to_string();
        assert!(!e.contains('\u{7}') && !e.contains('\n'), "{e}");
    }

    #[test]
    fn csv_quotes_text() {
        let m = Mark {
            kind: MarkKind::Note,
            text: "a \"b\", c".into(),
            host_us: 1,
            seq: 2,
            head_us: 3,
            odometer_um: -4500,
            after_us: 5,
        };
        assert_eq!(csv_row(&m), "note,\"a \"\"b\"\", c\",-4.500,2,3,1,5");
        assert_eq!(CSV_HEADER.split(',').count(), csv_row(&Mark { text: String::new(), ..m }).split(',').count());
    }

    #[test]
    fn kinds_name_and_read_back() {
        for k in MarkKind::ALL {
            assert_eq!(MarkKind::from_word(k.name()), Some(k));
        }
    }
}
