use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

use crate::CoreError;

/// A handle through which long work reports progress and learns that it was cancelled.
///
/// Library crates call it from any thread (hence `Sync`); `prt-cli` draws it with indicatif;
/// tests pass [`NoProgress`] or inspect an [`AtomicProgress`]. Work should call
/// [`Progress::check`] at least every few milliseconds of computation and return
/// [`CoreError::Cancelled`] (or its own error kind wrapping it) when it fails.
pub trait Progress: Sync {
    /// Sets the total amount of work of the current stage (in the stage's own units).
    fn set_len(&self, len: u64);

    /// Adds `delta` units of completed work.
    fn inc(&self, delta: u64);

    /// Describes the current stage or state ("tracing direct", "iteration 12: loss 3.1e-3").
    fn message(&self, msg: &str);

    /// Whether the caller asked the work to stop.
    fn is_cancelled(&self) -> bool;

    /// `Err(CoreError::Cancelled)` once cancellation was requested.
    fn check(&self) -> Result<(), CoreError> {
        if self.is_cancelled() {
            Err(CoreError::Cancelled)
        } else {
            Ok(())
        }
    }
}

/// A [`Progress`] that ignores everything and is never cancelled.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoProgress;

impl Progress for NoProgress {
    fn set_len(&self, _len: u64) {}
    fn inc(&self, _delta: u64) {}
    fn message(&self, _msg: &str) {}
    fn is_cancelled(&self) -> bool {
        false
    }
}

/// A thread-safe [`Progress`] that records its state and can be cancelled from another thread
/// (or after a set amount of work, for tests of cancellation).
#[derive(Debug, Default)]
pub struct AtomicProgress {
    len: AtomicU64,
    position: AtomicU64,
    cancelled: AtomicBool,
    cancel_after: AtomicU64,
    last_message: Mutex<String>,
}

impl AtomicProgress {
    /// A fresh handle, not cancelled.
    pub fn new() -> Self {
        Self {
            cancel_after: AtomicU64::new(u64::MAX),
            ..Self::default()
        }
    }

    /// A handle that cancels itself once `units` of work have been reported.
    pub fn cancel_after(units: u64) -> Self {
        let p = Self::new();
        p.cancel_after.store(units, Ordering::Relaxed);
        p
    }

    /// Requests cancellation.
    pub fn cancel(&self) {
        self.cancelled.store(true, Ordering::Relaxed);
    }

    /// The last length set.
    pub fn len(&self) -> u64 {
        self.len.load(Ordering::Relaxed)
    }

    /// Whether no length was set yet.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Work reported since the last [`Progress::set_len`].
    pub fn position(&self) -> u64 {
        self.position.load(Ordering::Relaxed)
    }

    /// The last message.
    pub fn last_message(&self) -> String {
        self.last_message
            .lock()
            .map(|m| m.clone())
            .unwrap_or_default()
    }
}

impl Progress for AtomicProgress {
    fn set_len(&self, len: u64) {
        self.len.store(len, Ordering::Relaxed);
        self.position.store(0, Ordering::Relaxed);
    }

    fn inc(&self, delta: u64) {
        let total = self.position.fetch_add(delta, Ordering::Relaxed) + delta;
        if total >= self.cancel_after.load(Ordering::Relaxed) {
            self.cancel();
        }
    }

    fn message(&self, msg: &str) {
        if let Ok(mut m) = self.last_message.lock() {
            msg.clone_into(&mut m);
        }
    }

    fn is_cancelled(&self) -> bool {
        self.cancelled.load(Ordering::Relaxed)
    }
}
