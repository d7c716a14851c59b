//! The library's errors: what went wrong, by kind, in the context it happened in. The message
//! of an error is its own line; its causes follow as `source`s (print with `{:#}` through
//! anyhow, or walk [`std::error::Error::source`]), so a failure reads "loading the data of RUN:
//! cannot load the data folder DIR: …".

use std::fmt::Display;

/// What went wrong in a run, a run folder or an evaluation.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A configuration key or value that cannot work: names the key and what it expects.
    #[error("{0}")]
    Config(String),
    /// Input that cannot be used: data, ground truth, a checkpoint's contents, a request.
    #[error("{0}")]
    Input(String),
    /// A run folder this process may not write into: in use, another program's files, an
    /// earlier run, a file where a folder should be.
    #[error("{0}")]
    Folder(String),
    /// The loss stopped being finite.
    #[error("the loss became {loss} at step {step}")]
    Diverged {
        /// The loss.
        loss: f64,
        /// The iteration.
        step: u64,
    },
    /// Reading or writing a file (the context names it).
    #[error(transparent)]
    Io(#[from] std::io::Error),
    /// A dataset, image or golden scene.
    #[error(transparent)]
    Dataset(#[from] datasets::DatasetError),
    /// The backbone or a checkpoint's tensors.
    #[error(transparent)]
    Backbone(#[from] sdf_backbone::BackboneError),
    /// The guide's grids.
    #[error(transparent)]
    Grid(#[from] prob_grid::GridError),
    /// The error map's saved state.
    #[error(transparent)]
    ErrorMap(#[from] view_sampler::ErrorMapStateError),
    /// A mesh or point set that cannot be measured.
    #[error(transparent)]
    Metrics(#[from] eval_metrics::MetricsError),
    /// A JSON record.
    #[error(transparent)]
    Json(#[from] serde_json::Error),
    /// A TOML configuration.
    #[error(transparent)]
    Toml(#[from] toml::de::Error),
    /// A camera that cannot be made (a render's downscaled view).
    #[error(transparent)]
    Camera(#[from] camera_geom::CameraError),
    /// A whole number in a record (a checkpoint's metadata).
    #[error(transparent)]
    Integer(#[from] std::num::ParseIntError),
    /// A number in a record.
    #[error(transparent)]
    Number(#[from] std::num::ParseFloatError),
    /// A duration out of range.
    #[error(transparent)]
    Duration(#[from] std::time::TryFromFloatSecsError),
    /// A picture or plot that could not be drawn.
    #[error("{0}")]
    Drawing(String),
    /// `source`, in the context named.
    #[error("{context}")]
    Context {
        /// Where it happened.
        context: String,
        /// What happened.
        #[source]
        source: Box<Error>,
    },
}

/// The library's results.
pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    /// This error in `context`.
    pub fn context(self, context: impl Display) -> Error {
        Error::Context { context: context.to_string(), source: Box::new(self) }
    }

    /// The message and its causes, colon-separated (what anyhow's `{:#}` prints).
    pub fn chain(&self) -> String {
        let mut text = self.to_string();
        let mut cause = std::error::Error::source(self);
        while let Some(e) = cause {
            text.push_str(": ");
            text.push_str(&e.to_string());
            cause = e.source();
        }
        text
    }

    /// The innermost error, past every context.
    pub fn root(&self) -> &Error {
        match self {
            Error::Context { source, .. } => source.root(),
            other => other,
        }
    }
}

/// Context for a failure (what anyhow's `Context` does, with a typed error).
pub trait Context<T> {
    /// The error in `context`.
    fn context(self, context: impl Display) -> Result<T>;
    /// The error in the context `f` makes (only on failure).
    fn with_context<C: Display>(self, f: impl FnOnce() -> C) -> Result<T>;
}

impl<T, E: Into<Error>> Context<T> for std::result::Result<T, E> {
    fn context(self, context: impl Display) -> Result<T> {
        self.map_err(|e| e.into().context(context))
    }
    fn with_context<C: Display>(self, f: impl FnOnce() -> C) -> Result<T> {
        self.map_err(|e| e.into().context(f()))
    }
}

/// A missing value is unusable input, named by the context.
impl<T> Context<T> for Option<T> {
    fn context(self, context: impl Display) -> Result<T> {
        self.ok_or_else(|| Error::Input(context.to_string()))
    }
    fn with_context<C: Display>(self, f: impl FnOnce() -> C) -> Result<T> {
        self.ok_or_else(|| Error::Input(f().to_string()))
    }
}

/// Returns an [`Error`] of kind `$kind` (`Config`, `Input`, `Folder`) with a formatted message.
#[macro_export]
#[doc(hidden)]
macro_rules! bail {
    ($kind:ident, $($arg:tt)*) => {
        return Err($crate::error::Error::$kind(format!($($arg)*)))
    };
}
