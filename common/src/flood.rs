//! A flood limit for the log lines of the libraries a process serves the network with. A peer's
//! request can make a library log a line per item (a subscribe naming 2 000 unknown channels made
//! the `foxglove` crate log 2 000 ERROR lines; each TLS handshake a peer without a certificate
//! tries makes zenoh log a WARN line): per call site of the given targets, the first [`BURST`]
//! lines of each [`PERIOD`] are written and the rest are counted; the process's loop reports the
//! counts ([`FloodGuard::report`]) so nothing goes unnoticed. Our own lines are rate-limited where
//! they are written ([`crate::throttle`]) and pass unchanged.

use std::collections::HashMap;
use std::sync::{Arc, Mutex, PoisonError};
use std::time::{Duration, Instant};

use tracing::callsite::Identifier;
use tracing::{Event, Metadata, Subscriber};
use tracing_subscriber::layer::{Context, Filter};

/// Lines written per call site and period.
pub const BURST: u32 = 5;
pub const PERIOD: Duration = Duration::from_secs(10);

/// Whether `target` is `crate_name` or one of its modules (`zenoh` takes `zenoh_link_tls` too: the
/// crates of one library share its name as a prefix).
fn is_of(target: &str, crate_name: &str) -> bool {
    target.starts_with(crate_name)
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
#[derive(Debug, Clone)]
pub struct FloodGuard {
    /// The libraries whose lines are limited (target prefixes, e.g. `foxglove`, `zenoh`).
    libraries: &'static [&'static str],
    windows: Arc<Mutex<HashMap<Identifier, Window>>>,
}

impl FloodGuard {
    /// Limits the lines of `libraries` (target prefixes).
    pub fn new(libraries: &'static [&'static str]) -> Self {
        Self {
            libraries,
            windows: Arc::default(),
        }
    }

    /// Whether a line of `meta`'s call site may be written at `now`.
    fn allow(&self, meta: &Metadata<'_>, now: Instant) -> bool {
        if !self.libraries.iter().any(|l| is_of(meta.target(), l)) {
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
                "log lines of {} left out (at most {BURST} per call site every {}s)",
                self.libraries.join(", "),
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

/// Sets up the log on standard error as [`crate::init_tracing`] does, with `guard` limiting its
/// libraries' lines.
pub fn init_tracing(guard: FloodGuard) {
    use std::io::IsTerminal;
    use tracing_subscriber::Layer;
    use tracing_subscriber::layer::SubscriberExt;
    use tracing_subscriber::util::SubscriberInitExt;

    // iceoryx2's own log into tracing, no subscriber yet: ours follows.
    crate::logging::init(crate::logging::LogTo::Nowhere);
    let directives = crate::logging::filter_directives(std::env::var("RUST_LOG").ok().as_deref());
    let layer = tracing_subscriber::fmt::layer()
        .with_ansi(std::io::stderr().is_terminal())
        .with_writer(std::io::stderr)
        .with_filter(limited(&directives, guard));
    let _ = tracing_subscriber::registry().with(layer).try_init();
}

/// `RUST_LOG`'s filter, then the guard: only lines the level lets through are counted, and a
/// library's DEBUG lines under `info` are neither written nor reported as left out.
fn limited<S: Subscriber + for<'a> tracing_subscriber::registry::LookupSpan<'a>>(
    directives: &str,
    guard: FloodGuard,
) -> impl Filter<S> + use<S> {
    use tracing_subscriber::filter::FilterExt;
    tracing_subscriber::EnvFilter::new(directives).and(guard)
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
        let guard = FloodGuard::new(&["foxglove"]);
        let counter = Counter::default();
        let subscriber =
            tracing_subscriber::registry().with(counter.clone().with_filter(guard.clone()));
        tracing::subscriber::with_default(subscriber, || {
            for id in 0..2000 {
                tracing::error!(target: "foxglove::websocket", "unknown channel {id}");
            }
            for _ in 0..3 {
                tracing::error!(target: "sonar_foxglove", "ours");
                tracing::warn!(target: "zenoh_link_tls::unicast", "not limited here");
            }
        });
        assert_eq!(counter.events.load(Ordering::Relaxed), BURST + 6);
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
        let guard = FloodGuard::new(&["zenoh", "foxglove"]);
        let t0 = Instant::now();
        let written = (0..20).filter(|_| guard.allow(meta, t0)).count();
        assert_eq!(written, BURST as usize);
        assert!(!guard.allow(meta, t0 + PERIOD / 2));
        assert!(guard.allow(meta, t0 + PERIOD));
        assert_eq!(guard.take_left_out()[0].1, 16);
    }

    #[test]
    fn lines_below_the_level_are_neither_written_nor_counted() {
        let guard = FloodGuard::new(&["zenoh"]);
        let counter = Counter::default();
        let subscriber = tracing_subscriber::registry()
            .with(counter.clone().with_filter(limited("info", guard.clone())));
        tracing::subscriber::with_default(subscriber, || {
            for _ in 0..20 {
                tracing::debug!(target: "zenoh::net", "chatter");
                tracing::warn!(target: "zenoh_link_tls::unicast", "handshake failed");
            }
        });
        assert_eq!(counter.events.load(Ordering::Relaxed), BURST);
        let left_out = guard.take_left_out();
        assert_eq!(left_out.len(), 1, "{left_out:?}");
        assert_eq!(left_out[0].1, 20 - u64::from(BURST));
    }
}
