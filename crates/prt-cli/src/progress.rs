//! Progress bars (indicatif) behind prt-core's `Progress` and prt-bake's `BakeProgress`, and
//! Ctrl-C cancellation.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressStyle};
use prt_core::Progress;

/// Set by the Ctrl-C handler; every stage's `Progress` reports it as cancellation.
static CANCELLED: AtomicBool = AtomicBool::new(false);

/// Installs the Ctrl-C handler (a second Ctrl-C is left to the default: it kills the process).
pub fn install_ctrlc_handler() {
    // Failure only means a handler exists already (e.g. in tests); cancellation then stays off.
    let _ = ctrlc::set_handler(|| {
        if CANCELLED.swap(true, Ordering::SeqCst) {
            std::process::exit(130);
        }
        eprintln!("\ncancelling (press Ctrl-C again to kill)...");
    });
}

/// Whether Ctrl-C was pressed (for loops that are not a progress stage, e.g. `prt view`'s server).
pub fn cancelled() -> bool {
    CANCELLED.load(Ordering::Relaxed)
}

/// One stage of long work drawn as a progress bar with ETA on stderr (hidden when stderr is not
/// a terminal).
pub struct StageBar {
    name: &'static str,
    bar: ProgressBar,
    start: Instant,
}

impl StageBar {
    /// Starts a stage.
    pub fn start(name: &'static str) -> Self {
        let bar = ProgressBar::new(0);
        let style = ProgressStyle::with_template(
            "{prefix:>10.bold} [{bar:32}] {pos}/{len} {msg} (ETA {eta})",
        )
        .unwrap_or_else(|_| ProgressStyle::default_bar())
        .progress_chars("=> ");
        bar.set_style(style);
        bar.set_prefix(name);
        bar.enable_steady_tick(Duration::from_millis(200));
        Self {
            name,
            bar,
            start: Instant::now(),
        }
    }

    /// Ends the stage, returning its wall time.
    pub fn finish(self) -> Duration {
        let elapsed = self.start.elapsed();
        self.bar.finish_and_clear();
        print_done(self.name, elapsed);
        elapsed
    }
}

impl Drop for StageBar {
    /// A stage dropped without [`StageBar::finish`] (a bake stage, or an error) clears its bar.
    fn drop(&mut self) {
        self.bar.finish_and_clear();
    }
}

fn print_done(name: &str, elapsed: Duration) {
    eprintln!("{name:>10} done in {:.2} s", elapsed.as_secs_f64());
}

/// One progress bar per stage of a bake, and a line when each stage is done.
pub struct StageBars;

impl prt_bake::BakeProgress for StageBars {
    fn begin(&self, stage: prt_bake::Stage) -> Box<dyn Progress + '_> {
        Box::new(StageBar::start(stage.name()))
    }

    fn end(&self, stage: prt_bake::Stage, elapsed: Duration) {
        print_done(stage.name(), elapsed);
    }
}

impl Progress for StageBar {
    fn set_len(&self, len: u64) {
        self.bar.set_length(len);
        self.bar.set_position(0);
    }

    fn inc(&self, delta: u64) {
        self.bar.inc(delta);
    }

    fn message(&self, msg: &str) {
        self.bar.set_message(msg.to_string());
    }

    fn is_cancelled(&self) -> bool {
        CANCELLED.load(Ordering::Relaxed)
    }
}
