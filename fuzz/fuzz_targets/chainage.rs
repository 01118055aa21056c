//! The chainage and placement parsers (`analyze --chainage 12+345.6:down`,
//! a survey's `start_chainage`: `Chainage` and `Placement` from text) on
//! arbitrary text.
//!
//! Besides "never panics": a chainage that parses is finite and within
//! ±10⁸ m, and its printed form (`km+m`, to the mm) reads back within half a
//! millimetre; a placement that parses says the same when printed and read
//! back.

#![no_main]

use cms_host::recording::survey_info::{Chainage, Heading, Placement};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let Ok(text) = std::str::from_utf8(data) else { return };
    if let Ok(c) = text.parse::<Chainage>() {
        assert!(c.0.is_finite() && c.0.abs() <= 1e8, "{text:?}: {c:?}");
        let printed = c.to_string();
        let back = printed.parse::<Chainage>().unwrap_or_else(|e| panic!("{text:?} printed {printed:?}: {e}"));
        assert!((back.0 - c.0).abs() <= 5e-4 + 1e-9 * c.0.abs(), "{text:?} → {printed:?} → {back:?}");
    }
    if let Ok(p) = text.parse::<Placement>() {
        let start = p.start_m.map(|m| Chainage(m).to_string()).unwrap_or_default();
        let heading = p.heading.map_or("", |h| if h == Heading::Up { ":up" } else { ":down" });
        let printed = if p.start_m.is_none() && p.heading.is_none() { "auto".to_string() } else { start + heading };
        let back = printed.parse::<Placement>().unwrap_or_else(|e| panic!("{text:?} printed {printed:?}: {e}"));
        assert_eq!(back.heading, p.heading, "{text:?}");
        match (back.start_m, p.start_m) {
            (Some(a), Some(b)) => assert!((a - b).abs() <= 5e-4 + 1e-9 * b.abs(), "{text:?}"),
            (a, b) => assert_eq!(a, b, "{text:?}"),
        }
    }
});
