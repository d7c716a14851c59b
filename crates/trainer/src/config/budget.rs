//! A run's budget ([`Budget`]) and how it is written: in TOML, on the command line (`--budget 10m`),
//! and in run folders of earlier versions.

use crate::bail;
use crate::error::{Context, Result};
use serde::{Deserialize, Serialize};
use std::time::Duration;

/// How long a run trains: a number of iterations, or training wall time (grid updates and
/// surface losses included; validation pictures, checkpoints, meshing and evaluation excluded).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "BudgetToml", into = "BudgetToml")]
pub enum Budget {
    /// This many iterations (≥ 1).
    Steps(u64),
    /// This much training time (> 0).
    Time(Duration),
}

impl Budget {
    /// A time budget of `seconds`; an error unless it is finite and positive.
    pub fn seconds(seconds: f64) -> Result<Budget> {
        positive_duration(seconds).map(Budget::Time).context("a time budget")
    }

    /// The time budget in seconds (`None` for a step budget).
    pub fn time_s(self) -> Option<f64> {
        match self {
            Budget::Time(d) => Some(d.as_secs_f64()),
            Budget::Steps(_) => None,
        }
    }

    /// The step budget (`None` for a time budget).
    pub fn steps(self) -> Option<u64> {
        match self {
            Budget::Steps(n) => Some(n),
            Budget::Time(_) => None,
        }
    }
}

impl std::fmt::Display for Budget {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Budget::Steps(n) => write!(f, "{n} steps"),
            Budget::Time(d) => write!(f, "{:.0} s budget", d.as_secs_f64()),
        }
    }
}

/// A budget as TOML writes it: exactly one of the two keys.
#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct BudgetToml {
    #[serde(skip_serializing_if = "Option::is_none")]
    steps: Option<u64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    seconds: Option<f64>,
}

impl TryFrom<BudgetToml> for Budget {
    type Error = String;
    fn try_from(text: BudgetToml) -> std::result::Result<Self, String> {
        match (text.steps, text.seconds) {
            (Some(0), None) => Err("budget.steps = 0 is out of range: expected ≥ 1".into()),
            (Some(n), None) => Ok(Budget::Steps(n)),
            (None, Some(s)) => Budget::seconds(s).map_err(|e| format!("budget.seconds: {e}")),
            _ => Err("a budget is `{ steps = N }` or `{ seconds = X }`: exactly one of the two".into()),
        }
    }
}

impl From<Budget> for BudgetToml {
    fn from(budget: Budget) -> Self {
        BudgetToml { steps: budget.steps(), seconds: budget.time_s() }
    }
}

/// Parses a duration such as `90`, `90s`, `10m`, `1.5h`, `1e3s` (a number, then an optional
/// unit: s, m, h).
pub fn parse_duration(text: &str) -> Result<Duration> {
    let t = text.trim();
    let unit_start = t.trim_end_matches(|c: char| c.is_ascii_alphabetic()).len();
    let (number, unit) = t.split_at(unit_start);
    let value: f64 = number.trim().parse().map_err(|_| crate::Error::Config(format!("{text:?} is not a duration (e.g. 90s, 10m, 1h)")))?;
    let scale = match unit {
        "" | "s" | "sec" => 1.0,
        "m" | "min" => 60.0,
        "h" => 3600.0,
        other => bail!(Config, "{text:?}: unknown unit {other:?} (s, m, h)"),
    };
    positive_duration(value * scale).with_context(|| format!("{text:?}"))
}

/// `seconds` as a duration: an error unless finite, positive and representable — the one place
/// a duration is checked (`--budget`, `budget.seconds`, `fuzz --time`, Python's `budget`).
pub fn positive_duration(seconds: f64) -> Result<Duration> {
    if !(seconds.is_finite() && seconds > 0.0) {
        bail!(Config, "a duration must be a positive number of seconds, not {seconds}");
    }
    Duration::try_from_secs_f64(seconds).with_context(|| format!("{seconds} s is too long a duration"))
}

/// The budget's short keys (`steps = N`, `time_budget_s = X`, as earlier versions wrote them)
/// turned into `budget`. Both in one table is how earlier versions wrote a run folder's
/// configuration: the time budget, unless it is 0 (then the steps).
pub(super) fn budget_from_short_keys(table: &mut toml::Table) -> Result<()> {
    let steps = table.remove("steps");
    let seconds = table.remove("time_budget_s");
    let one = |key: &str, value: toml::Value| toml::Table::from_iter([(key.to_string(), value)]);
    let budget = match (steps, seconds) {
        (None, None) => return Ok(()),
        (Some(steps), None) => one("steps", steps),
        (steps, Some(seconds)) => {
            let seconds = seconds.as_integer().map_or(seconds.clone(), |i| toml::Value::Float(i as f64));
            match steps {
                Some(steps) if seconds.as_float() == Some(0.0) => one("steps", steps),
                _ => one("seconds", seconds),
            }
        }
    };
    if table.insert("budget".into(), toml::Value::Table(budget)).is_some() {
        bail!(Config, "give the budget once: `budget`, `steps` or `time_budget_s`");
    }
    Ok(())
}
