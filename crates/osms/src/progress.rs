//! Progress bars and log lines for `osms make` (stderr only).

use std::time::Duration;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use osms_make::{InstanceReport, Observer, Outcome, Progress};

pub struct MakeObserver {
    pub show_progress: bool,
    pub quiet: bool,
    pub verbose: bool,
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
            show_progress: ctx.progress,
            quiet: ctx.quiet,
            verbose: ctx.verbose,
        }
    }
}

impl Observer for MakeObserver {
    fn waiting_for_lock(&self) {
        if !self.quiet {
            eprintln!("waiting for another osms process to release the store lock...");
        }
    }

    fn note(&self, text: &str) {
        if !self.quiet {
            eprintln!("{text}");
        }
    }

    fn started(&self, instance: &str, reason: &str) -> Box<dyn Progress + '_> {
        if !self.quiet {
            eprintln!("building {instance} ({reason})");
        }
        let target = if self.show_progress {
            ProgressDrawTarget::stderr()
        } else {
            ProgressDrawTarget::hidden()
        };
        let bar = ProgressBar::with_draw_target(None, target);
        bar.set_style(
            ProgressStyle::with_template("{spinner} {prefix:.bold} {elapsed}")
                .unwrap_or_else(|_| ProgressStyle::default_spinner()),
        );
        bar.set_prefix(instance.to_string());
        bar.enable_steady_tick(Duration::from_millis(120));
        Box::new(Bar(bar))
    }

    fn finished(&self, r: &InstanceReport) {
        if self.quiet {
            return;
        }
        let hash = r.content_hash.map(|h| h.short()).unwrap_or_default();
        match &r.outcome {
            Outcome::Built { .. } => eprintln!(
                "  built {} -> {hash} in {:.2}s",
                r.instance, r.wall_time_secs
            ),
            Outcome::Failed { error } => eprintln!("  FAILED {}: {error}", r.instance),
            Outcome::Skipped { failed_input } => {
                eprintln!("  skipped {} (input {failed_input} failed)", r.instance)
            }
            Outcome::WouldBuild { reason } => eprintln!("would build {} ({reason})", r.instance),
            Outcome::Cached if self.verbose => eprintln!("  cached {} {hash}", r.instance),
            Outcome::CutOff if self.verbose => eprintln!(
                "  cut off {} {hash} (inputs rebuilt to the same bytes)",
                r.instance
            ),
            Outcome::Cached | Outcome::CutOff => {}
        }
    }
}
