//! Progress of long computations, reported to whoever runs them.
//!
//! Library code never prints. It tells an [`Observer`] what it is doing: phases (with their
//! number of steps when known), progress within the current phase, and notes such as warnings.
//! The caller decides how to show them: the `prism` binary draws progress bars and prints notes
//! on stderr; tests and batch callers pass [`Silent`].

/// How much a [`Observer::note`] matters.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Level {
    /// Something the user may want to know (a skipped stage, a predicted channel's score).
    Info,
    /// Something that may make the result wrong or surprising (unseen voxels, a clamped value).
    Warning,
}

/// Receives progress reports. Every method has a do-nothing default, so an observer implements
/// only what it shows.
pub trait Observer: Sync {
    /// A phase of `total` steps begins (0 when its length is unknown); it ends the previous one.
    fn phase(&self, _name: &str, _total: u64) {}
    /// `done` steps of the current phase are finished; `status` summarises the state in one
    /// line (a loss, a Gaussian count), or is empty.
    fn progress(&self, _done: u64, _status: &str) {}
    /// A message for the user that does not stop the computation.
    fn note(&self, _level: Level, _text: &str) {}
}

/// An observer that shows nothing.
#[derive(Clone, Copy, Debug, Default)]
pub struct Silent;

impl Observer for Silent {}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use std::sync::Mutex;

    /// Records every report as a line (tests that check what a computation says).
    #[derive(Default)]
    pub struct Recorder(pub Mutex<Vec<String>>);

    impl Observer for Recorder {
        fn phase(&self, name: &str, total: u64) {
            self.0.lock().unwrap().push(format!("phase {name} {total}"));
        }
        fn note(&self, level: Level, text: &str) {
            self.0.lock().unwrap().push(format!("{level:?}: {text}"));
        }
    }

    #[test]
    fn silent_ignores_everything_and_a_recorder_keeps_order() {
        Silent.phase("a", 3);
        Silent.progress(1, "x");
        Silent.note(Level::Warning, "w");
        let r = Recorder::default();
        r.phase("simulate", 2);
        r.note(Level::Warning, "careful");
        assert_eq!(
            *r.0.lock().unwrap(),
            ["phase simulate 2", "Warning: careful"]
        );
    }
}
