//! How far a long job has got. The library only reports (a total, then
//! how much is done); the command line draws it — an indicatif bar on a
//! terminal, nothing otherwise — so library users and tests pay nothing.
//! Reports are cheap calls, made at most every few thousand items or every
//! read buffer, never per point.

/// Receives a job's progress.
pub trait Progress {
    /// The job starts: `what` it is, `total` units of `unit` ("B" for bytes).
    fn begin(&self, what: &str, total: u64, unit: &str);
    /// `done` of the total so far.
    fn set(&self, done: u64);
    /// The job ended (done or failed).
    fn end(&self);
}

/// No progress shown.
pub struct Silent;

impl Progress for Silent {
    fn begin(&self, _: &str, _: u64, _: &str) {}
    fn set(&self, _: u64) {}
    fn end(&self) {}
}
