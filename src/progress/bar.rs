//! A progress bar on stderr for the builder's phases and a stream's rays: what `oavm-pack`,
//! `oavm-trace` and the Python bindings' `oavm.pack` draw (feature `progress`, on with `cli`). The library itself never
//! draws: [`super::Progress`] only reports.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

/// A progress bar on stderr for the library's phases ([`super::Progress`]): a spinner
/// with the phase and the elapsed time, or a bar with a rate and the time left when the amount
/// of work is known. It stays hidden for the first second, so quick runs print nothing, and
/// never draws when stderr is not a terminal.
pub struct Bar {
    bar: ProgressBar,
    done: Arc<AtomicBool>,
    /// The phase's name, which a note follows.
    name: std::sync::Mutex<String>,
}

impl Bar {
    pub fn new(enabled: bool) -> Bar {
        let bar = ProgressBar::hidden();
        bar.set_style(spinner());
        let done = Arc::new(AtomicBool::new(false));
        if enabled {
            let (bar, done) = (bar.clone(), done.clone());
            std::thread::spawn(move || {
                std::thread::sleep(Duration::from_secs(1));
                if !done.load(Ordering::Acquire) {
                    bar.set_draw_target(ProgressDrawTarget::stderr());
                    bar.enable_steady_tick(Duration::from_millis(120));
                }
            });
        }
        Bar {
            bar,
            done,
            name: std::sync::Mutex::new(String::new()),
        }
    }

    pub fn finish(&self) {
        self.done.store(true, Ordering::Release);
        self.bar.finish_and_clear();
    }
}

fn spinner() -> ProgressStyle {
    ProgressStyle::with_template("{spinner} [{elapsed_precise}] {msg}")
        .unwrap_or_else(|_| ProgressStyle::default_spinner())
}

impl super::Progress for Bar {
    fn phase(&self, name: &str, total: Option<u64>, bytes: bool) {
        let style = match (total, bytes) {
            (None, _) => spinner(),
            (Some(_), true) => ProgressStyle::with_template(
                "{spinner} [{elapsed_precise}] {msg:<16} [{bar:30}] {bytes}/{total_bytes} \
                 {binary_bytes_per_sec}, {eta} left",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
            (Some(_), false) => ProgressStyle::with_template(
                "{spinner} [{elapsed_precise}] {msg:<16} [{bar:30}] {pos}/{len} {per_sec}, {eta} \
                 left",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar()),
        };
        self.bar.set_style(style.progress_chars("=> "));
        if let Some(total) = total {
            self.bar.set_length(total);
        }
        self.bar.set_position(0);
        self.bar.reset_eta();
        self.bar.set_message(name.to_string());
        *self.name.lock().unwrap_or_else(|p| p.into_inner()) = name.to_string();
    }

    fn note(&self, text: &str) {
        let name = self.name.lock().unwrap_or_else(|p| p.into_inner()).clone();
        self.bar.set_message(format!("{name}, {text}"));
    }

    fn at(&self, done: u64) {
        self.bar.set_position(done);
    }
}

impl Drop for Bar {
    fn drop(&mut self) {
        self.finish();
    }
}
