//! What can go wrong with a session request, sorted by whose fault it is, with the class
//! that the transports map to a gRPC code and an HTTP status.

pub use crate::echo::{clip, ECHO_CHARS};
use crate::pipeline::FilterError;
use thiserror::Error;

/// Longest error message a transport sends back, in bytes (every message is cut there as
/// a last guard; [`crate::echo::clip`] keeps echoed input far below it).
pub const MAX_MESSAGE_BYTES: usize = 1024;

/// `message` cut to [`MAX_MESSAGE_BYTES`] on a character boundary.
pub fn cap_message(message: String) -> String {
    if message.len() <= MAX_MESSAGE_BYTES {
        return message;
    }
    let mut at = MAX_MESSAGE_BYTES - 16;
    while !message.is_char_boundary(at) {
        at -= 1;
    }
    format!("{}... (cut)", &message[..at])
}

/// What went wrong, sorted by whose fault it is; the server maps [`SessionError::kind`] to
/// a gRPC code and an HTTP status, and [`SessionError::reason`] to a metrics label.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum SessionError {
    /// The request is wrong: the message names the field, what was expected and what came.
    #[error("{field}: {message}")]
    Invalid {
        /// The field or value at fault.
        field: String,
        /// Expected vs got.
        message: String,
    },
    /// The request is larger than the session's frames can be (a body, a message).
    #[error("{field}: {message}")]
    TooLarge {
        /// What is too large.
        field: String,
        /// Its size against the limit.
        message: String,
    },
    /// No session of that id for this caller (never existed, closed, evicted after being
    /// idle, or created with another API key: the reply is the same, so ids do not leak).
    #[error(
        "no session {id:?} on replica {replica} (closed, evicted after {idle_s} s idle, never created, or held by another replica: send every request of a session with the same x-afterimage-route, or create it again)"
    )]
    NotFound {
        /// The id asked for (clipped).
        id: String,
        /// The idle timeout.
        idle_s: u64,
        /// The replica that answered ([`super::Limits::replica`]).
        replica: String,
    },
    /// A limit would be exceeded: sessions, the memory budget, a key's quota.
    #[error("{0}")]
    Exhausted(String),
    /// The session is filtering another frame, or is fed by a gRPC stream.
    #[error("{0}")]
    Busy(String),
    /// The session failed earlier (a filter panicked) and must be closed.
    #[error("session {id} failed: {message}; close it and open a new one")]
    Failed {
        /// The session.
        id: String,
        /// What happened.
        message: String,
    },
    /// No valid API key.
    #[error("{0}")]
    Unauthenticated(String),
    /// A bug on our side (a panic while serving the request).
    #[error("internal error: {0}")]
    Internal(String),
    /// The server is shutting down.
    #[error("the server is shutting down")]
    ShuttingDown,
    /// The client went away before its request finished; the work was stopped.
    #[error("cancelled: the client went away before the request finished")]
    Cancelled,
}

/// The class of a [`SessionError`], for status codes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ErrorKind {
    /// 400 / INVALID_ARGUMENT.
    InvalidArgument,
    /// 413 / RESOURCE_EXHAUSTED.
    TooLarge,
    /// 404 / NOT_FOUND.
    NotFound,
    /// 429 / RESOURCE_EXHAUSTED.
    ResourceExhausted,
    /// 409 / FAILED_PRECONDITION.
    FailedPrecondition,
    /// 401 / UNAUTHENTICATED.
    Unauthenticated,
    /// 500 / INTERNAL.
    Internal,
    /// 503 / UNAVAILABLE.
    Unavailable,
}

impl SessionError {
    /// Its class.
    pub fn kind(&self) -> ErrorKind {
        match self {
            SessionError::Invalid { .. } => ErrorKind::InvalidArgument,
            SessionError::TooLarge { .. } => ErrorKind::TooLarge,
            SessionError::NotFound { .. } => ErrorKind::NotFound,
            SessionError::Exhausted(_) => ErrorKind::ResourceExhausted,
            SessionError::Busy(_) | SessionError::Failed { .. } => ErrorKind::FailedPrecondition,
            SessionError::Unauthenticated(_) => ErrorKind::Unauthenticated,
            SessionError::Internal(_) => ErrorKind::Internal,
            SessionError::ShuttingDown | SessionError::Cancelled => ErrorKind::Unavailable,
        }
    }

    /// A short stable label for metrics (`errors_total{reason=...}`).
    pub fn reason(&self) -> &'static str {
        match self {
            SessionError::Invalid { .. } => "invalid_argument",
            SessionError::TooLarge { .. } => "too_large",
            SessionError::NotFound { .. } => "not_found",
            SessionError::Exhausted(_) => "resource_exhausted",
            SessionError::Busy(_) => "session_busy",
            SessionError::Failed { .. } => "session_failed",
            SessionError::Unauthenticated(_) => "unauthenticated",
            SessionError::Internal(_) => "internal",
            SessionError::ShuttingDown => "shutting_down",
            SessionError::Cancelled => "cancelled",
        }
    }

    /// An invalid-argument error.
    pub fn invalid(field: impl Into<String>, message: impl Into<String>) -> Self {
        SessionError::Invalid {
            field: field.into(),
            message: message.into(),
        }
    }

    /// A too-large error.
    pub fn too_large(field: impl Into<String>, message: impl Into<String>) -> Self {
        SessionError::TooLarge {
            field: field.into(),
            message: message.into(),
        }
    }

    /// The message a client is sent: the error's text, capped at [`MAX_MESSAGE_BYTES`].
    pub fn client_message(&self) -> String {
        cap_message(self.to_string())
    }
}

/// A filter's refusal as a session error naming the request field at fault.
pub(crate) fn filter_error(e: FilterError) -> SessionError {
    if let FilterError::Device { .. } = e {
        return SessionError::Internal(e.to_string());
    }
    let field = match &e {
        FilterError::UnknownFilter { .. } => "filter",
        FilterError::UnknownParam { .. } | FilterError::BadParam { .. } | FilterError::Assignment { .. } => {
            "params"
        }
        FilterError::MissingChannel { .. } => "channels",
        FilterError::SizeChanged { .. } => "size",
        _ => "frame",
    };
    SessionError::invalid(field, e.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cap_message_cuts_on_a_character() {
        let m = cap_message("ü".repeat(3000));
        assert!(
            m.len() <= MAX_MESSAGE_BYTES && m.ends_with("(cut)"),
            "{}",
            m.len()
        );
    }
}
