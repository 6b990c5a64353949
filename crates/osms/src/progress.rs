//! Progress bars and log lines for `osms make` (stderr only).

use std::time::Duration;

use indicatif::{MultiProgress, ProgressBar, ProgressDrawTarget, ProgressStyle};
use osms_make::{InstanceReport, Observer, Outcome, Progress};

use crate::term::Printer;

pub struct MakeObserver {
    printer: Printer,
    /// One line per build in flight (`make --stages N` runs several).
    bars: MultiProgress,
}

struct Bar(ProgressBar);

impl Progress for Bar {
    fn set_total(&self, total: u64) {
        self.0.set_length(total);
        self.0.set_style(
            ProgressStyle::with_template(
                "{spinner} {prefix:.bold} [{bar:30}] {pos}/{len} items, {elapsed} (eta {eta})",
            )
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
        );
    }
    fn inc(&self, n: u64) {
        self.0.inc(n);
    }
}

impl Drop for Bar {
    fn drop(&mut self) {
        self.0.finish_and_clear();
    }
}

impl MakeObserver {
    /// The observer a command's global options ask for.
    pub fn of(ctx: &crate::context::Context) -> Self {
        MakeObserver {
            printer: ctx.printer,
            bars: MultiProgress::with_draw_target(if ctx.printer.progress {
                ProgressDrawTarget::stderr()
            } else {
                ProgressDrawTarget::hidden()
            }),
        }
    }

    /// A message above the bars, unless `--quiet`.
    fn say(&self, text: &str) {
        if self.printer.says() {
            self.line(text);
        }
    }

    /// A log line above the bars; plainly where they are not drawn (no terminal, or hidden),
    /// since a hidden `MultiProgress` drops what it is asked to print.
    fn line(&self, text: &str) {
        if self.bars.is_hidden() || self.bars.println(text).is_err() {
            errln!("{text}");
        }
    }
}

impl Observer for MakeObserver {
    fn waiting_for_lock(&self) {
        self.say("waiting for another osms process to release the store lock...");
    }

    fn note(&self, text: &str) {
        self.say(text);
    }

    fn started(&self, instance: &str, reason: &str) -> Box<dyn Progress + '_> {
        self.say(&format!("building {instance} ({reason})"));
        let bar = self.bars.add(ProgressBar::no_length());
        bar.set_style(
            ProgressStyle::with_template("{spinner} {prefix:.bold} {elapsed}")
                .unwrap_or_else(|_| ProgressStyle::default_spinner()),
        );
        bar.set_prefix(instance.to_string());
        bar.enable_steady_tick(Duration::from_millis(120));
        Box::new(Bar(bar))
    }

    fn finished(&self, r: &InstanceReport) {
        if !self.printer.says() {
            return;
        }
        let hash = r.content_hash.map(|h| h.short()).unwrap_or_default();
        match &r.outcome {
            Outcome::Built { .. } => self.line(&format!(
                "  built {} -> {hash} in {:.2}s",
                r.instance, r.wall_time_secs
            )),
            Outcome::Failed { error } => self.line(&format!("  FAILED {}: {error}", r.instance)),
            Outcome::Skipped { failed_input } => self.line(&format!(
                "  skipped {} (input {failed_input} failed)",
                r.instance
            )),
            Outcome::WouldBuild { reason } => {
                self.line(&format!("would build {} ({reason})", r.instance))
            }
            Outcome::Cached if self.printer.verbose => {
                self.line(&format!("  cached {} {hash}", r.instance))
            }
            Outcome::CutOff if self.printer.verbose => self.line(&format!(
                "  cut off {} {hash} (inputs rebuilt to the same bytes)",
                r.instance
            )),
            Outcome::Pulled { bytes } => self.line(&format!(
                "  pulled {} -> {hash} ({}) in {:.2}s",
                r.instance,
                osms_core::table::human_bytes(*bytes),
                r.wall_time_secs
            )),
            Outcome::Cached | Outcome::CutOff => {}
        }
    }
}
