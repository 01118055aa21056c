//! The survey file parser (`listen --survey FILE.toml`, a recording's
//! survey block: `cms_host::recording::survey_info::Survey::parse`) on
//! arbitrary text.
//!
//! Besides "never panics": a survey that parses places its run
//! (`placement` succeeds, its start chainage finite), its stored text
//! (`to_text`) parses back to the same survey, and its description for
//! people holds no character that would act on a terminal.

#![no_main]

use cms_host::recording::survey_info::{MAX_BYTES, Survey};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    let Ok(s) = Survey::parse(text) else { return };
    let p = s.placement().expect("a parsed survey places its run");
    assert!(p.start_m.is_none_or(f64::is_finite), "{p:?}");
    let stored = s.to_text();
    if stored.len() <= MAX_BYTES {
        assert_eq!(Survey::parse(&stored).as_ref(), Ok(&s), "{stored:?}");
    }
    let d = s.describe();
    let acts = |c: char| c.is_control() || matches!(c, '\u{202a}'..='\u{202e}' | '\u{2066}'..='\u{2069}');
    assert!(!d.chars().any(acts), "{d:?}");
});
