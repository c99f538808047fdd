//! A flood limit for the `foxglove` crate's log lines. A client's request can make the crate log
//! a line per item (a subscribe naming 2 000 unknown channels logged 2 000 ERROR lines): per call
//! site, the first [`BURST`] lines of each [`PERIOD`] are written and the rest are counted; the
//! main loop reports the counts ([`FloodGuard::report`]) so nothing goes unnoticed. Our own lines
//! are rate-limited where they are written (`sonar_common::throttle`) and pass unchanged.

use std::collections::HashMap;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use tracing::callsite::Identifier;
use tracing::{Event, Metadata, Subscriber};
use tracing_subscriber::layer::{Context, Filter};

/// Lines written per call site and period.
pub const BURST: u32 = 5;
pub const PERIOD: Duration = Duration::from_secs(10);

/// Which lines are limited: the foxglove crate's (its targets are `foxglove::…`).
fn is_limited(meta: &Metadata<'_>) -> bool {
    meta.target() == "foxglove" || meta.target().starts_with("foxglove::")
}

#[derive(Debug)]
struct Window {
    start: Instant,
    written: u32,
    left_out: u64,
    /// `file:line` of the call site, for the report.
    place: String,
}

/// Shared between the log filter and the loop that reports what it left out.
#[derive(Debug, Clone, Default)]
pub struct FloodGuard {
    windows: Arc<Mutex<HashMap<Identifier, Window>>>,
}

impl FloodGuard {
    /// Whether a line of `meta`'s call site may be written at `now`.
    fn allow(&self, meta: &Metadata<'_>, now: Instant) -> bool {
        if !is_limited(meta) {
            return true;
        }
        let mut windows = self.windows.lock().unwrap_or_else(PoisonError::into_inner);
        let window = windows.entry(meta.callsite()).or_insert_with(|| Window {
            start: now,
            written: 0,
            left_out: 0,
            place: format!(
                "{}:{}",
                meta.file().unwrap_or(meta.target()),
                meta.line().unwrap_or(0)
            ),
        });
        if now.saturating_duration_since(window.start) >= PERIOD {
            window.start = now;
            window.written = 0;
        }
        if window.written < BURST {
            window.written += 1;
            true
        } else {
            window.left_out += 1;
            false
        }
    }

    /// The lines left out since the last call, per call site (`file:line`, count).
    pub fn take_left_out(&self) -> Vec<(String, u64)> {
        let mut windows = self.windows.lock().unwrap_or_else(PoisonError::into_inner);
        windows
            .values_mut()
            .filter(|w| w.left_out > 0)
            .map(|w| (w.place.clone(), std::mem::take(&mut w.left_out)))
            .collect()
    }

    /// Logs (at WARN, once per call site) how many lines were left out since the last report.
    pub fn report(&self) {
        for (place, left_out) in self.take_left_out() {
            tracing::warn!(
                left_out,
                from = %place,
                "foxglove server's log lines left out (at most {BURST} per call site every {}s)",
                PERIOD.as_secs()
            );
        }
    }
}

impl<S: Subscriber> Filter<S> for FloodGuard {
    fn enabled(&self, _meta: &Metadata<'_>, _cx: &Context<'_, S>) -> bool {
        // Decided line by line in `event_enabled`.
        true
    }

    fn callsite_enabled(&self, _meta: &'static Metadata<'static>) -> tracing::subscriber::Interest {
        tracing::subscriber::Interest::sometimes()
    }

    fn event_enabled(&self, event: &Event<'_>, _cx: &Context<'_, S>) -> bool {
        self.allow(event.metadata(), Instant::now())
    }
}

/// Sets up the log on standard error as `sonar_common::init_tracing` does, with `guard` limiting
/// the foxglove crate's lines.
pub fn init_tracing(guard: FloodGuard) {
    use std::io::IsTerminal;
    use tracing_subscriber::layer::SubscriberExt;
    use tracing_subscriber::util::SubscriberInitExt;
    use tracing_subscriber::{EnvFilter, Layer};

    // iceoryx2's own log into tracing, no subscriber yet: ours follows.
    sonar_common::logging::init(sonar_common::logging::LogTo::Nowhere);
    let directives =
        sonar_common::logging::filter_directives(std::env::var("RUST_LOG").ok().as_deref());
    let layer = tracing_subscriber::fmt::layer()
        .with_ansi(std::io::stderr().is_terminal())
        .with_writer(std::io::stderr)
        .with_filter(EnvFilter::new(directives))
        .with_filter(guard);
    let _ = tracing_subscriber::registry().with(layer).try_init();
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used)]
    use std::sync::atomic::{AtomicU32, Ordering};

    use tracing_subscriber::Layer;
    use tracing_subscriber::layer::SubscriberExt;

    use super::*;

    /// Counts the events that reach it and keeps the metadata of the last one.
    #[derive(Clone, Default)]
    struct Counter {
        events: Arc<AtomicU32>,
        last: Arc<Mutex<Option<&'static Metadata<'static>>>>,
    }

    impl<S: Subscriber> Layer<S> for Counter {
        fn on_event(&self, event: &Event<'_>, _: Context<'_, S>) {
            self.events.fetch_add(1, Ordering::Relaxed);
            *self.last.lock().unwrap() = Some(event.metadata());
        }
    }

    #[test]
    fn the_crates_lines_are_limited_per_call_site_and_counted() {
        let guard = FloodGuard::default();
        let counter = Counter::default();
        let subscriber =
            tracing_subscriber::registry().with(counter.clone().with_filter(guard.clone()));
        tracing::subscriber::with_default(subscriber, || {
            for id in 0..2000 {
                tracing::error!(target: "foxglove::websocket", "unknown channel {id}");
            }
            for _ in 0..3 {
                tracing::error!(target: "sonar_foxglove", "ours");
            }
        });
        assert_eq!(counter.events.load(Ordering::Relaxed), BURST + 3);
        let left_out = guard.take_left_out();
        assert_eq!(left_out.len(), 1);
        assert_eq!(left_out[0].1, 2000 - u64::from(BURST));
        assert!(left_out[0].0.contains("flood.rs"), "{left_out:?}");
        assert!(guard.take_left_out().is_empty(), "counted once");
    }

    #[test]
    fn a_new_period_writes_again() {
        let counter = Counter::default();
        let subscriber = tracing_subscriber::registry().with(counter.clone());
        tracing::subscriber::with_default(subscriber, || {
            tracing::error!(target: "foxglove", "a line");
        });
        let meta = counter.last.lock().unwrap().unwrap();
        let guard = FloodGuard::default();
        let t0 = Instant::now();
        let written = (0..20).filter(|_| guard.allow(meta, t0)).count();
        assert_eq!(written, BURST as usize);
        assert!(!guard.allow(meta, t0 + PERIOD / 2));
        assert!(guard.allow(meta, t0 + PERIOD));
        assert_eq!(guard.take_left_out()[0].1, 16);
    }
}
