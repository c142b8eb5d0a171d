//! How the `prism` binary shows progress: [`Bars`], the library's
//! [`Observer`](prism_domain::observe::Observer), draws one progress bar on stderr (a spinner
//! for phases of unknown length) and prints notes above it.
//!
//! On a terminal the bar is redrawn in place. When stderr is not a terminal (`nohup`, a cluster
//! job, a pipe into a log file), indicatif would draw nothing at all for the hours a
//! paper-scale run takes; instead, the bar's line is written to stderr as plain text, one line
//! at most every [`LOG_EVERY`], without cursor movement.

use indicatif::{
    HumanDuration, ProgressBar, ProgressDrawTarget, ProgressState, ProgressStyle, TermLike,
};
use prism_domain::observe::{Level, Observer};
use std::fmt;
use std::io::{self, IsTerminal, Write};
use std::sync::{Mutex, Once};
use std::time::{Duration, Instant};

/// Minimum time between two progress lines in a log.
pub const LOG_EVERY: Duration = Duration::from_secs(30);

const BAR: &str = "{msg} [{bar:25}] {pos}/{len} {elapsed_precise} ETA {pace_eta}";
const SPINNER: &str = "{spinner} [{elapsed_precise}] {msg}";

/// The time left at the phase's mean pace so far, elapsed·(len − pos)/pos; none before the first
/// step. indicatif's own estimate follows a recent rate that decays between rare steps (a suite's
/// cells take minutes each), and showed thousands of years.
fn pace_eta(elapsed: Duration, pos: u64, len: Option<u64>) -> Option<Duration> {
    let len = len?;
    if pos == 0 {
        return None;
    }
    let left = len.saturating_sub(pos) as f64 / pos as f64;
    Some(elapsed.mul_f64(left))
}

/// Progress on stderr (see the module docs).
pub struct Bars {
    bar: ProgressBar,
    phase: Mutex<String>,
    /// The bar is drawn from the first phase on (a command that fails before any phase, or
    /// finishes in none, leaves no empty spinner line in a log).
    shown: Once,
}

impl Bars {
    pub fn new() -> Self {
        let bar = ProgressBar::hidden();
        if let Ok(style) = ProgressStyle::with_template(SPINNER) {
            bar.set_style(style);
        }
        Bars {
            bar,
            phase: Mutex::new(String::new()),
            shown: Once::new(),
        }
    }

    /// Remove the bar (the command is done or failed).
    pub fn finish(&self) {
        self.bar.finish_and_clear();
    }
}

impl Drop for Bars {
    fn drop(&mut self) {
        self.finish();
    }
}

impl Observer for Bars {
    fn phase(&self, name: &str, total: u64) {
        let template = if total > 0 { BAR } else { SPINNER };
        if let Ok(style) = ProgressStyle::with_template(template) {
            let style = style.with_key("pace_eta", |s: &ProgressState, w: &mut dyn fmt::Write| {
                let _ = match pace_eta(s.elapsed(), s.pos(), s.len()) {
                    Some(t) => write!(w, "{}", HumanDuration(t)),
                    None => write!(w, "–"),
                };
            });
            self.bar.set_style(style.progress_chars("=> "));
        }
        self.bar.set_length(total);
        self.bar.set_position(0);
        self.bar.reset_elapsed();
        self.bar.reset_eta();
        self.bar.set_message(name.to_string());
        self.shown.call_once(|| {
            self.bar.set_draw_target(target());
            self.bar.enable_steady_tick(Duration::from_millis(200));
        });
        *self.phase.lock().unwrap_or_else(|e| e.into_inner()) = name.to_string();
    }

    fn progress(&self, done: u64, status: &str) {
        self.bar.set_position(done);
        if !status.is_empty() {
            let phase = self.phase.lock().unwrap_or_else(|e| e.into_inner());
            self.bar.set_message(format!("{phase} {status}"));
        }
    }

    fn note(&self, level: Level, text: &str) {
        let prefix = match level {
            Level::Info => "",
            Level::Warning => "warning: ",
        };
        self.bar.suspend(|| eprintln!("{prefix}{text}"));
    }
}

/// Stderr as a terminal, or as a log of [`LOG_EVERY`]-spaced lines when it is not one.
pub fn target() -> ProgressDrawTarget {
    if io::stderr().is_terminal() {
        ProgressDrawTarget::stderr()
    } else {
        ProgressDrawTarget::term_like_with_hz(
            Box::new(LogLines::new(Box::new(io::stderr()), LOG_EVERY)),
            1,
        )
    }
}

/// An indicatif terminal that writes each drawn line as plain text, skipping lines that come
/// sooner than `every` after the previous one.
pub struct LogLines {
    every: Duration,
    state: Mutex<(Option<Instant>, Box<dyn Write + Send>)>,
}

impl LogLines {
    pub fn new(out: Box<dyn Write + Send>, every: Duration) -> Self {
        LogLines {
            every,
            state: Mutex::new((None, out)),
        }
    }
}

impl fmt::Debug for LogLines {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("LogLines")
            .field("every", &self.every)
            .finish()
    }
}

impl TermLike for LogLines {
    fn width(&self) -> u16 {
        120
    }
    fn move_cursor_up(&self, _: usize) -> io::Result<()> {
        Ok(())
    }
    fn move_cursor_down(&self, _: usize) -> io::Result<()> {
        Ok(())
    }
    fn move_cursor_right(&self, _: usize) -> io::Result<()> {
        Ok(())
    }
    fn move_cursor_left(&self, _: usize) -> io::Result<()> {
        Ok(())
    }
    fn write_line(&self, s: &str) -> io::Result<()> {
        self.write_str(s)
    }
    fn write_str(&self, s: &str) -> io::Result<()> {
        let line = s.trim_end();
        if line.is_empty() {
            return Ok(());
        }
        let mut state = self.state.lock().unwrap_or_else(|e| e.into_inner());
        let now = Instant::now();
        if state.0.is_some_and(|t| now.duration_since(t) < self.every) {
            return Ok(());
        }
        state.0 = Some(now);
        writeln!(state.1, "{line}")
    }
    fn clear_line(&self) -> io::Result<()> {
        Ok(())
    }
    fn flush(&self) -> io::Result<()> {
        let mut state = self.state.lock().unwrap_or_else(|e| e.into_inner());
        state.1.flush()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    /// A writer whose bytes the test can read back.
    #[derive(Clone, Default)]
    struct Shared(Arc<Mutex<Vec<u8>>>);
    impl Write for Shared {
        fn write(&mut self, b: &[u8]) -> io::Result<usize> {
            self.0.lock().unwrap().extend_from_slice(b);
            Ok(b.len())
        }
        fn flush(&mut self) -> io::Result<()> {
            Ok(())
        }
    }

    #[test]
    fn the_eta_follows_the_mean_pace_of_the_phase() {
        let min = Duration::from_secs(60);
        // 3 of 4 cells in 30 min: one more cell at 10 min each.
        assert_eq!(pace_eta(30 * min, 3, Some(4)), Some(10 * min));
        assert_eq!(pace_eta(30 * min, 4, Some(4)), Some(Duration::ZERO));
        assert_eq!(pace_eta(30 * min, 0, Some(4)), None);
        assert_eq!(pace_eta(30 * min, 2, None), None);
        // A position past the length (a resumed phase) reads as done, not negative.
        assert_eq!(pace_eta(min, 5, Some(4)), Some(Duration::ZERO));
    }

    #[test]
    fn log_lines_are_plain_and_throttled() {
        let out = Shared::default();
        let term = LogLines::new(Box::new(out.clone()), Duration::from_millis(200));
        term.write_line("step 1/3").unwrap();
        term.write_line("step 2/3").unwrap(); // too soon: skipped
        term.write_str("   ").unwrap(); // blank: skipped, does not reset the clock
        std::thread::sleep(Duration::from_millis(250));
        term.move_cursor_up(1).unwrap();
        term.clear_line().unwrap();
        term.write_line("step 3/3").unwrap();
        let text = String::from_utf8(out.0.lock().unwrap().clone()).unwrap();
        assert_eq!(text, "step 1/3\nstep 3/3\n");
    }
}
