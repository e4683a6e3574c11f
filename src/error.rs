//! The one error type. Every message names what is wrong and what is allowed (a config key and its
//! range, a flag and its values, a file and why it cannot be used); the command line prints it after
//! `error: ` and exits with status 2. It sits below every other module, so any layer can return it.

use std::path::PathBuf;

/// A config error: a message naming the key, the value and the allowed range, e.g.
/// `medium.albedo = 1.3: must be within [0, 1]`.
#[derive(Clone, Debug, PartialEq)]
pub struct ConfigError(pub String);

impl std::fmt::Display for ConfigError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for ConfigError {}

#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A config value out of range, an unknown key, a file that is not the config a command needs.
    #[error("{0}")]
    Config(#[from] ConfigError),
    /// A command-line value, an input file or a combination of them that cannot run.
    #[error("{0}")]
    Input(String),
    /// A file or folder that could not be read, written or created.
    #[error("cannot {action} {}: {source}", path.display())]
    Io {
        action: &'static str,
        path: PathBuf,
        source: std::io::Error,
    },
    /// A computation that produced no usable result (non-finite values, a singular system);
    /// nothing was written.
    #[error("{0}")]
    Numerical(String),
    /// A run stopped on request (Ctrl-C in Python) before it finished; nothing was returned or
    /// written.
    #[error("interrupted before the run finished; nothing was written")]
    Interrupted,
}

/// Errors of the lower layers are messages of the same quality (they name key, value and range).
impl From<String> for Error {
    fn from(message: String) -> Self {
        Error::Input(message)
    }
}

impl From<&str> for Error {
    fn from(message: &str) -> Self {
        Error::Input(message.into())
    }
}

/// `Result` with [`Error`].
pub type Result<T, E = Error> = std::result::Result<T, E>;

impl Error {
    /// An input error from any message.
    pub fn input(message: impl Into<String>) -> Self {
        Error::Input(message.into())
    }
}
