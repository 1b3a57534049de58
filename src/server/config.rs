//! Server configuration in layers: built-in defaults, then an optional TOML file, then
//! `AFTERIMAGE_<FIELD>` environment variables (e.g. `AFTERIMAGE_MAX_SESSIONS=8`); validated
//! once at start with messages that name the field, the source and the expected value.

use crate::session::Limits;
use serde::{Deserialize, Serialize};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::time::Duration;
use thiserror::Error;

/// Prefix of the environment variables read.
pub const ENV_PREFIX: &str = "AFTERIMAGE_";

/// Everything `afterimage serve` can be told.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Config {
    /// gRPC listen address.
    pub grpc_addr: String,
    /// HTTP listen address (REST, health, metrics).
    pub http_addr: String,
    /// Sessions open at once.
    pub max_sessions: usize,
    /// Filter state over all sessions, MiB.
    pub memory_budget_mib: u64,
    /// Seconds a session may sit unused before it is evicted.
    pub idle_timeout_s: u64,
    /// Largest frame width.
    pub max_width: u32,
    /// Largest frame height.
    pub max_height: u32,
    /// Largest encoded frame on the wire (gRPC) or EXR body (HTTP), MiB.
    pub max_frame_mib: u64,
    /// Largest gRPC data chunk, bytes.
    pub max_chunk_bytes: usize,
    /// Largest share of NaN/Inf colour samples a frame may have.
    pub max_non_finite_fraction: f64,
    /// Replies a stream may have waiting for the client before the server stops reading
    /// its frames (flow control).
    pub queue_depth: usize,
    /// Seconds to finish frames in flight after SIGTERM/SIGINT.
    pub shutdown_deadline_s: u64,
}

impl Default for Config {
    fn default() -> Self {
        Config {
            grpc_addr: "127.0.0.1:50051".into(),
            http_addr: "127.0.0.1:8080".into(),
            max_sessions: 64,
            memory_budget_mib: 8192,
            idle_timeout_s: 300,
            max_width: 8192,
            max_height: 8192,
            max_frame_mib: 1024,
            max_chunk_bytes: super::wire::DEFAULT_MAX_CHUNK_BYTES,
            max_non_finite_fraction: 0.5,
            queue_depth: 4,
            shutdown_deadline_s: 10,
        }
    }
}

/// A configuration that cannot be used.
#[derive(Debug, Error)]
pub enum ConfigError {
    /// The file could not be read.
    #[error("config file {path}: {source}")]
    Read {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// The file or an environment variable does not parse or names an unknown field.
    #[error("{source_name}: {message}")]
    Parse {
        /// The file or variable.
        source_name: String,
        /// What is wrong.
        message: String,
    },
    /// A value out of range.
    #[error("config {field}: expected {expected}, got {got}")]
    Invalid {
        /// The field.
        field: &'static str,
        /// What is allowed.
        expected: String,
        /// What was given.
        got: String,
    },
}

impl Config {
    /// Defaults, then `file` (when given), then the `AFTERIMAGE_*` variables in `env`;
    /// validated.
    pub fn load(
        file: Option<&Path>,
        env: impl IntoIterator<Item = (String, String)>,
    ) -> Result<Config, ConfigError> {
        let mut table = toml::Table::try_from(Config::default()).expect("the defaults serialise");
        let known: Vec<String> = table.keys().cloned().collect();
        if let Some(path) = file {
            let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
                path: path.into(),
                source,
            })?;
            let from_file: toml::Table = text.parse().map_err(|e: toml::de::Error| ConfigError::Parse {
                source_name: path.display().to_string(),
                message: e.to_string(),
            })?;
            for (k, v) in from_file {
                if !known.contains(&k) {
                    return Err(ConfigError::Parse {
                        source_name: path.display().to_string(),
                        message: format!("unknown field {k:?}; the fields are {}", known.join(", ")),
                    });
                }
                table.insert(k, v);
            }
        }
        for (name, value) in env {
            let Some(field) = name.strip_prefix(ENV_PREFIX).map(str::to_ascii_lowercase) else {
                continue;
            };
            if !known.contains(&field) {
                continue; // AFTERIMAGE_LOG and friends belong to others
            }
            let v =
                match &table[&field] {
                    toml::Value::String(_) => toml::Value::String(value.clone()),
                    toml::Value::Integer(_) => value
                        .trim()
                        .parse::<i64>()
                        .map(toml::Value::Integer)
                        .map_err(|_| ConfigError::Parse {
                            source_name: name.clone(),
                            message: format!("expected a whole number, got {value:?}"),
                        })?,
                    toml::Value::Float(_) => {
                        value.trim().parse::<f64>().map(toml::Value::Float).map_err(|_| {
                            ConfigError::Parse {
                                source_name: name.clone(),
                                message: format!("expected a number, got {value:?}"),
                            }
                        })?
                    }
                    other => {
                        return Err(ConfigError::Parse {
                            source_name: name.clone(),
                            message: format!("cannot be set from the environment ({other})"),
                        })
                    }
                };
            table.insert(field, v);
        }
        let config: Config = toml::Value::Table(table)
            .try_into()
            .map_err(|e: toml::de::Error| ConfigError::Parse {
                source_name: file.map_or("environment".into(), |p| p.display().to_string()),
                message: e.to_string(),
            })?;
        config.validate()?;
        Ok(config)
    }

    /// Checks ranges and addresses.
    pub fn validate(&self) -> Result<(), ConfigError> {
        for (field, addr) in [("grpc_addr", &self.grpc_addr), ("http_addr", &self.http_addr)] {
            addr.parse::<SocketAddr>().map_err(|_| ConfigError::Invalid {
                field,
                expected: "a socket address such as 127.0.0.1:8080".into(),
                got: format!("{addr:?}"),
            })?;
        }
        let positive: [(&'static str, u64); 8] = [
            ("max_sessions", self.max_sessions as u64),
            ("memory_budget_mib", self.memory_budget_mib),
            ("max_width", self.max_width as u64),
            ("max_height", self.max_height as u64),
            ("max_frame_mib", self.max_frame_mib),
            ("max_chunk_bytes", self.max_chunk_bytes as u64),
            ("queue_depth", self.queue_depth as u64),
            ("idle_timeout_s", self.idle_timeout_s),
        ];
        for (field, v) in positive {
            if v == 0 {
                return Err(ConfigError::Invalid {
                    field,
                    expected: "at least 1".into(),
                    got: "0".into(),
                });
            }
        }
        if !(0.0..=1.0).contains(&self.max_non_finite_fraction) {
            return Err(ConfigError::Invalid {
                field: "max_non_finite_fraction",
                expected: "a share in [0, 1]".into(),
                got: self.max_non_finite_fraction.to_string(),
            });
        }
        Ok(())
    }

    /// The session limits this config sets.
    pub fn limits(&self) -> Limits {
        Limits {
            max_sessions: self.max_sessions,
            memory_budget_bytes: self.memory_budget_mib << 20,
            idle_timeout: Duration::from_secs(self.idle_timeout_s),
            max_width: self.max_width,
            max_height: self.max_height,
            max_frame_bytes: self.max_frame_mib << 20,
            max_non_finite_fraction: self.max_non_finite_fraction,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn env(pairs: &[(&str, &str)]) -> Vec<(String, String)> {
        pairs
            .iter()
            .map(|(a, b)| (a.to_string(), b.to_string()))
            .collect()
    }

    #[test]
    fn the_default_parses_and_validates() {
        let c = Config::load(None, env(&[])).unwrap();
        assert_eq!(c, Config::default());
        // The defaults written as TOML read back the same.
        let text = toml::to_string(&Config::default()).unwrap();
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("c.toml");
        std::fs::write(&p, text).unwrap();
        assert_eq!(Config::load(Some(&p), env(&[])).unwrap(), Config::default());
    }

    #[test]
    fn layers_apply_in_order_and_errors_name_the_field() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("c.toml");
        std::fs::write(&p, "max_sessions = 3\nidle_timeout_s = 9\n").unwrap();
        let c = Config::load(
            Some(&p),
            env(&[("AFTERIMAGE_MAX_SESSIONS", "5"), ("AFTERIMAGE_LOG", "debug")]),
        )
        .unwrap();
        assert_eq!((c.max_sessions, c.idle_timeout_s), (5, 9));
        let e = Config::load(None, env(&[("AFTERIMAGE_MAX_SESSIONS", "many")]))
            .unwrap_err()
            .to_string();
        assert!(e.contains("AFTERIMAGE_MAX_SESSIONS") && e.contains("many"), "{e}");
        let e = Config::load(None, env(&[("AFTERIMAGE_HTTP_ADDR", "localhost")]))
            .unwrap_err()
            .to_string();
        assert!(e.contains("http_addr") && e.contains("localhost"), "{e}");
        std::fs::write(&p, "max_sesions = 3\n").unwrap();
        let e = Config::load(Some(&p), env(&[])).unwrap_err().to_string();
        assert!(e.contains("max_sesions") && e.contains("max_sessions"), "{e}");
        let e = Config::load(None, env(&[("AFTERIMAGE_QUEUE_DEPTH", "0")]))
            .unwrap_err()
            .to_string();
        assert!(e.contains("queue_depth") && e.contains("at least 1"), "{e}");
    }
}
