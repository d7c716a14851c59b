//! Progress of a run in every phase (training, meshing, evaluation) on one bar with the time
//! left: an indicatif bar on a terminal, a log line every few seconds otherwise (CI, pipes).

use crate::config::TrainConfig;
use std::sync::Mutex;
use std::time::Instant;

/// The run's progress display.
pub struct Progress {
    bar: Option<indicatif::ProgressBar>,
    /// The step budget (`None`: a time budget).
    steps: Option<u64>,
    /// (last line printed, the phase it was for) for the log-line mode.
    last: Mutex<(Instant, String)>,
    /// The current post-training phase and when it started (for its ETA).
    phase_start: Mutex<(String, Instant)>,
    started: Instant,
}

/// Seconds as `1h02m`, `3m05s` or `42s`.
pub fn format_seconds(s: f64) -> String {
    let s = s.max(0.0).round() as u64;
    if s >= 3600 {
        format!("{}h{:02}m", s / 3600, (s % 3600) / 60)
    } else if s >= 60 {
        format!("{}m{:02}s", s / 60, s % 60)
    } else {
        format!("{s}s")
    }
}

impl Progress {
    /// A display for `config`'s run (a bar when stderr is a terminal).
    pub fn new(config: &TrainConfig) -> Progress {
        let bar = std::io::IsTerminal::is_terminal(&std::io::stderr()).then(|| {
            let bar = indicatif::ProgressBar::new(1000);
            bar.set_style(indicatif::ProgressStyle::with_template("{bar:30} {percent:>3}% {msg}").expect("a valid template"));
            bar
        });
        Progress {
            bar,
            steps: config.budget.steps(),
            last: Mutex::new((Instant::now(), String::new())),
            phase_start: Mutex::new((String::new(), Instant::now())),
            started: Instant::now(),
        }
    }

    /// Training at iteration `step`, `progress` ∈ [0, 1], `left` seconds to go.
    pub fn set(&self, step: u64, progress: f64, left: f64, message: &str) {
        let what = match self.steps {
            Some(steps) => format!("iteration {step}/{steps}"),
            None => format!("iteration {step}"),
        };
        let line = format!("train {what}, {} left · {message}", format_seconds(left));
        self.show(progress, "train", line);
    }

    /// A post-training phase (`mesh`, `eval`) at `done` of `total` items, with its ETA.
    pub fn phase(&self, name: &str, done: usize, total: usize) {
        let unit = match name {
            "mesh" => "blocks",
            "eval" => "views",
            _ => "",
        };
        let elapsed = match self.phase_start.lock() {
            Ok(mut p) => {
                if p.0 != name {
                    *p = (name.to_string(), Instant::now());
                }
                p.1.elapsed().as_secs_f64()
            }
            Err(_) => 0.0,
        };
        let left = if done > 0 { elapsed / done as f64 * (total - done.min(total)) as f64 } else { f64::NAN };
        let eta = if left.is_finite() { format!(", {} left", format_seconds(left)) } else { String::new() };
        self.show(done as f64 / total.max(1) as f64, name, format!("{name} {done}/{total} {unit}{eta}"));
    }

    fn show(&self, fraction: f64, phase: &str, line: String) {
        match &self.bar {
            Some(bar) => {
                bar.set_position((fraction.clamp(0.0, 1.0) * 1000.0) as u64);
                bar.set_message(line);
            }
            None => {
                let Ok(mut last) = self.last.lock() else { return };
                let new_phase = last.1 != phase;
                if new_phase || last.0.elapsed().as_secs_f64() >= 10.0 || fraction >= 1.0 {
                    eprintln!("[{}] {line}", format_seconds(self.started.elapsed().as_secs_f64()));
                    *last = (Instant::now(), phase.to_string());
                }
            }
        }
    }

    /// Ends the current phase (the bar stays, the next phase restarts it).
    pub fn finish_phase(&self) {
        if let Some(bar) = &self.bar {
            bar.set_position(1000);
        }
    }

    /// Leaves the bar as it is (an interrupted run).
    pub fn abandon(&self) {
        if let Some(bar) = &self.bar {
            bar.abandon();
        }
    }
}

impl Drop for Progress {
    fn drop(&mut self) {
        if let Some(bar) = &self.bar {
            bar.finish_and_clear();
        }
    }
}
