//! Progress bars of the long commands (`analyze`, `export`, `bench
//! recording`, …): an indicatif bar on stderr when stderr is a terminal,
//! nothing otherwise (pipes, files and tests see no control characters).

use std::io::{self, IsTerminal as _};

use cms_host::progress::Progress;
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

/// A bar, or nothing when stderr is not a terminal.
pub struct Bar(Option<ProgressBar>);

impl Bar {
    /// A bar on stderr if it is a terminal.
    pub fn stderr() -> Bar {
        Bar(io::stderr().is_terminal().then(|| ProgressBar::with_draw_target(None, ProgressDrawTarget::stderr())))
    }
}

impl Progress for Bar {
    fn begin(&self, what: &str, total: u64, unit: &str) {
        let Some(b) = &self.0 else { return };
        let template = if unit == "B" {
            "{msg} [{bar:30}] {bytes}/{total_bytes} {bytes_per_sec} eta {eta}"
        } else {
            "{msg} [{bar:30}] {pos}/{len} {per_sec} eta {eta}"
        };
        if let Ok(style) = ProgressStyle::with_template(template) {
            b.set_style(style.progress_chars("=> "));
        }
        b.set_length(total);
        b.set_position(0);
        b.set_message(what.to_string());
        b.reset_eta();
    }
    fn set(&self, done: u64) {
        if let Some(b) = &self.0 {
            b.set_position(done);
        }
    }
    fn end(&self) {
        if let Some(b) = &self.0 {
            b.finish_and_clear();
        }
    }
}
