//! Appending frames to a recording as they arrive.

use std::fs::{File, OpenOptions};
use std::io::{self, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::time::Instant;

use super::{
    FORMAT_VERSION, HEADER_LEN, HOST_RECORDS_FORMAT, HostRecord, MARKS_FORMAT, MAX_SURVEY_BYTES, RecordError,
    SYNC_INTERVAL, header_and_survey, parse_header, read_block,
};

/// Appends frames to a recording (see the module docs for what reaches the
/// file when).
#[derive(Debug)]
pub struct Recorder {
    /// Unbuffered: each frame is one write.
    out: File,
    path: PathBuf,
    /// When the oldest frame not yet committed was written.
    dirty_since: Option<Instant>,
    frames: u64,
    /// The file's format version (an older file appended to keeps its own).
    format: u16,
    host_records: u64,
}

/// Whether a session whose survey block would be `new` may append to a
/// file whose block is `kept`: the same block, or the same survey where
/// only one of them says what optics it was made with (the file keeps its
/// block). Other optics, or another survey, are refused.
fn appendable(kept: Option<&str>, new: &str) -> Result<(), String> {
    use super::survey_info::Survey;
    if kept == Some(new) {
        return Ok(());
    }
    let parse = |t: Option<&str>| t.map_or(Ok(Survey::default()), Survey::parse);
    if let (Ok(k), Ok(n)) = (parse(kept), parse(Some(new)))
        && (Survey { optics: None, ..k.clone() }) == (Survey { optics: None, ..n.clone() })
    {
        return match (k.optics, n.optics) {
            (Some(a), Some(b)) if a != b => Err(format!(
                "was recorded with optics {a}, this session's are {b}; refusing to append (record to a new file)"
            )),
            _ => Ok(()),
        };
    }
    Err(match kept {
        Some(_) => "holds another survey; refusing to append (record this survey to a new file)".into(),
        None => "holds no survey; refusing to append one (record the survey to a new file)".into(),
    })
}

impl Recorder {
    /// Creates `path`, or validates its header and appends to it.
    pub fn open(path: &Path) -> Result<Recorder, RecordError> {
        Recorder::open_with_survey(path, None)
    }

    /// [`Recorder::open`], a new file with `survey`'s block; appending to a
    /// file of another survey (or of none, when one is given) is refused,
    /// as is appending a session of other optics (its `[optics]`).
    pub fn open_with_survey(path: &Path, survey: Option<&str>) -> Result<Recorder, RecordError> {
        let io_err = |what, source| RecordError::Io { path: path.to_path_buf(), what, source };
        let format = |why: String| RecordError::Format { path: path.to_path_buf(), why };
        if survey.is_some_and(|t| t.len() > MAX_SURVEY_BYTES) {
            return Err(format(format!("a survey of more than {MAX_SURVEY_BYTES} bytes")));
        }
        let mut file = OpenOptions::new()
            .read(true)
            .append(true)
            .create(true)
            .open(path)
            .map_err(|e| io_err("cannot open recording", e))?;
        let len = file.metadata().map_err(|e| io_err("cannot read", e))?.len();
        let mut format_version = FORMAT_VERSION;
        if len == 0 {
            file.write_all(&header_and_survey(survey)).map_err(|e| io_err("cannot write", e))?;
        } else {
            let mut h = Vec::with_capacity(HEADER_LEN);
            (&mut file).take(HEADER_LEN as u64).read_to_end(&mut h).map_err(|e| io_err("cannot read", e))?;
            let header = parse_header(&h).map_err(|why| format(format!("{why}; refusing to append")))?;
            let block = read_block(&mut file, &h, &header).map_err(|e| io_err("cannot read", e))?;
            if let Some((why, _)) = block.damage {
                return Err(format(format!("survey block: {why}; refusing to append")));
            }
            format_version = block.header.format;
            if let Some(t) = survey {
                appendable(block.survey.as_deref(), t).map_err(format)?;
            }
            if len > HEADER_LEN as u64 + header.block_len() {
                let mut last = [0u8];
                file.seek(SeekFrom::End(-1)).map_err(|e| io_err("cannot read", e))?;
                file.read_exact(&mut last).map_err(|e| io_err("cannot read", e))?;
                if last[0] != 0 {
                    // Close the previous writer's unfinished frame.
                    file.write_all(&[0]).map_err(|e| io_err("cannot write", e))?;
                }
            }
        }
        Ok(Recorder {
            out: file,
            path: path.to_path_buf(),
            dirty_since: None,
            frames: 0,
            format: format_version,
            host_records: 0,
        })
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Frames written by this recorder.
    pub fn frames(&self) -> u64 {
        self.frames
    }

    fn err(&self, what: &'static str, source: io::Error) -> RecordError {
        RecordError::Io { path: self.path.clone(), what, source }
    }

    /// Appends one frame's wire bytes (ending with its 0x00 delimiter): in
    /// the file (the operating system's) when this returns.
    pub fn write_frame(&mut self, wire: &[u8]) -> Result<(), RecordError> {
        debug_assert_eq!(wire.last(), Some(&0));
        // One write of the whole frame: a kill between two frames leaves
        // whole frames only (a kill inside leaves a fragment readers skip).
        self.out.write_all(wire).map_err(|e| self.err("cannot write", e))?;
        self.frames += 1;
        self.dirty_since.get_or_insert_with(Instant::now);
        self.tick()
    }

    /// Whether the file's format holds host records (a file of format 3
    /// or older, appended to, does not: its readers would skip them).
    pub fn holds_host_records(&self) -> bool {
        self.format >= HOST_RECORDS_FORMAT
    }

    /// Whether the file's format holds event marks (format 5 on).
    pub fn holds_marks(&self) -> bool {
        self.format >= MARKS_FORMAT
    }

    /// The file's format version.
    pub fn format(&self) -> u16 {
        self.format
    }

    /// Host records written by this recorder.
    pub fn host_records(&self) -> u64 {
        self.host_records
    }

    /// Appends one host record (a GNSS fix, a mark), as [`Recorder::write_frame`]
    /// a frame; refused for a file of a format without host records.
    pub fn write_host_record(&mut self, r: &HostRecord) -> Result<(), RecordError> {
        let (holds, what, from) = match r {
            HostRecord::Mark(_) => (self.holds_marks(), "event marks", MARKS_FORMAT),
            _ => (self.holds_host_records(), "GNSS fixes", HOST_RECORDS_FORMAT),
        };
        if !holds {
            return Err(RecordError::Format {
                path: self.path.clone(),
                why: format!(
                    "recording format {} holds no {what} (format {from} does); record to a new file",
                    self.format
                ),
            });
        }
        self.out.write_all(&r.frame_in(self.format)).map_err(|e| self.err("cannot write", e))?;
        self.host_records += 1;
        self.dirty_since.get_or_insert_with(Instant::now);
        self.tick()
    }

    /// Commits once the oldest uncommitted frame is [`SYNC_INTERVAL`] old.
    /// Call it often (the listener does on every turn of its loop).
    pub fn tick(&mut self) -> Result<(), RecordError> {
        if self.dirty_since.is_some_and(|t| t.elapsed() >= SYNC_INTERVAL) {
            self.sync()?;
        }
        Ok(())
    }

    /// Commits everything written so far.
    pub fn finish(&mut self) -> Result<(), RecordError> {
        self.sync()
    }

    /// Commits to the storage device. A recording into a pipe or a
    /// character device has nothing to commit.
    fn sync(&mut self) -> Result<(), RecordError> {
        self.dirty_since = None;
        match self.out.sync_data() {
            Err(e) if !matches!(e.kind(), io::ErrorKind::InvalidInput | io::ErrorKind::Unsupported) => {
                Err(self.err("cannot commit", e))
            }
            _ => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::appendable;

    #[test]
    fn a_session_of_other_optics_is_not_appended() {
        let plain = "line = \"LN 1\"\n";
        let f28 = "line = \"LN 1\"\n\n[optics]\nf_number = 2.8\nwavelength_nm = 685.0\n";
        let f4 = "line = \"LN 1\"\n\n[optics]\nf_number = 4.0\nwavelength_nm = 685.0\n";
        assert!(appendable(Some(f28), f28).is_ok());
        // Only one of them says what optics: the same survey.
        assert!(appendable(Some(plain), f28).is_ok());
        assert!(appendable(Some(f28), plain).is_ok());
        assert!(appendable(None, "[optics]\nf_number = 2.8\nwavelength_nm = 685.0\n").is_ok());
        let e = appendable(Some(f28), f4).unwrap_err();
        assert!(e.contains("optics F/2.8, 685 nm, this session's are F/4, 685 nm"), "{e}");
        assert!(appendable(Some("line = \"LN 2\"\n"), f28).unwrap_err().contains("another survey"));
        assert!(appendable(None, plain).unwrap_err().contains("holds no survey"));
    }
}
