//! Server configuration in layers: built-in defaults, then an optional TOML file, then
//! `AFTERIMAGE_<FIELD>` environment variables (e.g. `AFTERIMAGE_MAX_SESSIONS=8`); validated
//! once at start with messages that name the field, the source and the expected value.
//! API keys come from `api_keys_file` and the `AFTERIMAGE_API_KEYS` variable.

use crate::pipeline::state::{StateKey, STATE_KEY_ENV};
use crate::session::access::{KeyError, KEYS_ENV};
use crate::session::{Keyring, Limits, Quotas};
use serde::{Deserialize, Serialize};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::time::Duration;
use thiserror::Error;

/// The largest `max_chunk_bytes` taken: a chunk and its framing fit a gRPC message's 4-byte
/// length with room to spare.
pub const MAX_CHUNK_BYTES_LIMIT: usize = 1 << 30;
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
    /// TOML file of API keys (`[[key]]` with `name`, `sha256`, optional `max_sessions` and
    /// `memory_mib`; `afterimage keygen` writes entries). Empty: none from a file.
    pub api_keys_file: String,
    /// Share of the server (sessions and memory) a key gets when its entry sets no quota
    /// of its own: one key cannot take every session slot and the whole budget from the
    /// others by default. 1 gives each key the whole server.
    pub key_default_share: f64,
    /// Serve a non-loopback address without API keys (refused unless set).
    pub allow_unauthenticated: bool,
    /// `/metrics` needs an API key too (when the server has keys).
    pub metrics_require_key: bool,
    /// Serve gRPC server reflection (`grpc.reflection.v1` and `v1alpha`: the service's
    /// methods and messages, for `grpcurl` and the like) on the gRPC port, without a key.
    /// The health service (`grpc.health.v1`) is always served.
    pub grpc_reflection: bool,
    /// Serve shared memory regions (`OpenRegion`): a client on this machine (same user,
    /// same process namespace: it opens the region through `/proc`) writes its frames into
    /// a sealed memfd and the stream carries offsets (`afterimage stream --transport shm`).
    /// A region counts twice its size against the memory budgets.
    pub shared_memory: bool,
    /// PEM certificate chain for TLS on both ports (with `tls_key`); empty: plain TCP.
    pub tls_cert: String,
    /// PEM private key for TLS.
    pub tls_key: String,
    /// Seconds a client has to send a request's headers (HTTP/1), or to finish the TLS
    /// handshake and send its first bytes (any connection). Also how long an HTTP/1
    /// keep-alive connection may wait for its next request.
    pub header_timeout_s: u64,
    /// Seconds a connection may go without reading or writing a byte before it is closed.
    pub idle_connection_timeout_s: u64,
    /// Seconds to receive one frame: an HTTP body, or the chunks of one gRPC frame.
    pub request_timeout_s: u64,
    /// Connections open at once over both ports; more are closed at accept.
    pub max_connections: usize,
    /// Connections open at once from one client address over both ports (0: as many as
    /// `max_connections`); more are closed at accept. Behind a proxy every client has the
    /// proxy's address: raise it there.
    pub max_connections_per_client: usize,
    /// Seconds between HTTP/2 keepalive pings on an idle connection (gRPC and h2).
    pub keepalive_interval_s: u64,
    /// Seconds to wait for a ping's answer before closing the connection.
    pub keepalive_timeout_s: u64,
    /// Concurrent HTTP/2 streams per connection (gRPC calls, h2 requests).
    pub max_concurrent_streams: u32,
    /// Channels an EXR frame may hold over all its parts (checked from its header).
    pub max_exr_channels: usize,
    /// Parts an EXR frame may have.
    pub max_exr_parts: usize,
    /// This replica's name, said in "no such session" answers (empty: the `HOSTNAME`
    /// variable, which Kubernetes sets to the pod's name, else `local`).
    pub replica: String,
    /// Where the filters of sessions that do not say run: cpu, gpu or auto, or gpu-f16 or
    /// auto-f16 (the GPU with the colour uploaded as f16; see `afterimage info --backends`).
    /// gpu and gpu-f16 need a build with `--features gpu`.
    pub default_backend: crate::backend::BackendChoice,
    /// Plain API keys from the environment (`AFTERIMAGE_API_KEYS`); never printed.
    #[serde(skip)]
    pub api_keys_plain: Option<String>,
    /// The secret that signs exported session state (`AFTERIMAGE_STATE_KEY`, environment
    /// only; never printed): with one, an import of state this server (or a replica with
    /// the same secret) did not export is refused.
    #[serde(skip)]
    pub state_key: Option<crate::pipeline::state::StateKey>,
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
            api_keys_file: String::new(),
            key_default_share: 0.5,
            allow_unauthenticated: false,
            metrics_require_key: false,
            grpc_reflection: true,
            shared_memory: true,
            tls_cert: String::new(),
            tls_key: String::new(),
            header_timeout_s: 10,
            idle_connection_timeout_s: 120,
            request_timeout_s: 60,
            max_connections: 256,
            max_connections_per_client: 64,
            keepalive_interval_s: 30,
            keepalive_timeout_s: 10,
            max_concurrent_streams: 16,
            max_exr_channels: 64,
            max_exr_parts: 16,
            replica: String::new(),
            default_backend: crate::backend::BackendChoice::Cpu,
            api_keys_plain: None,
            state_key: None,
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
    /// The API keys cannot be used.
    #[error(transparent)]
    Keys(#[from] KeyError),
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
            for k in from_file.keys() {
                if !known.contains(k) {
                    return Err(ConfigError::Parse {
                        source_name: path.display().to_string(),
                        message: format!("unknown field {k:?}; the fields are {}", known.join(", ")),
                    });
                }
            }
            // Typed from the text, so a wrong value is shown at its line and column.
            toml::from_str::<Config>(&text).map_err(|e| ConfigError::Parse {
                source_name: path.display().to_string(),
                message: e.to_string().trim_end().to_string(),
            })?;
            table.extend(from_file);
        }
        let mut api_keys_plain = None;
        let mut state_key = None;
        for (name, value) in env {
            if name == KEYS_ENV {
                api_keys_plain = Some(value);
                continue;
            }
            if name == STATE_KEY_ENV {
                state_key = StateKey::new(value.as_bytes());
                continue;
            }
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
                    toml::Value::Boolean(_) => match value.trim().to_ascii_lowercase().as_str() {
                        "true" | "1" | "yes" => toml::Value::Boolean(true),
                        "false" | "0" | "no" => toml::Value::Boolean(false),
                        _ => {
                            return Err(ConfigError::Parse {
                                source_name: name.clone(),
                                message: format!("expected true or false, got {value:?}"),
                            })
                        }
                    },
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
            // Typed alone, so a value out of the field's range or a name that is none is
            // blamed on this variable, not on the file under it.
            let alone = toml::Table::from_iter([(field.clone(), v.clone())]);
            toml::Value::Table(alone)
                .try_into::<Config>()
                .map_err(|e: toml::de::Error| ConfigError::Parse {
                    source_name: name.clone(),
                    message: format!("{} (got {value:?})", e.to_string().trim_end().replace('\n', " ")),
                })?;
            table.insert(field, v);
        }
        // Each layer was typed above; this cannot fail on a value any more.
        let mut config: Config = toml::Value::Table(table)
            .try_into()
            .map_err(|e: toml::de::Error| ConfigError::Parse {
                source_name: "the merged config".into(),
                message: e.to_string(),
            })?;
        config.api_keys_plain = api_keys_plain;
        config.state_key = state_key;
        config.validate()?;
        Ok(config)
    }

    /// The API keys: the keys file's, then `AFTERIMAGE_API_KEYS`'; each key's quotas
    /// default to [`Self::key_default_share`] of the server's limits.
    pub fn keyring(&self) -> Result<Keyring, ConfigError> {
        let share = self.key_default_share;
        let defaults = Quotas {
            max_sessions: ((self.max_sessions as f64 * share).ceil() as usize).max(1),
            memory_bytes: ((self.memory_budget_mib << 20) as f64 * share) as u64,
        };
        let mut ring = Keyring::default();
        if !self.api_keys_file.is_empty() {
            let path = Path::new(&self.api_keys_file);
            let text = std::fs::read_to_string(path).map_err(|source| ConfigError::Read {
                path: path.into(),
                source,
            })?;
            ring.add_file_text(&text, &self.api_keys_file, defaults)?;
        }
        if let Some(plain) = &self.api_keys_plain {
            ring.add_plain(plain, KEYS_ENV, defaults)?;
        }
        Ok(ring)
    }

    /// The addresses this config listens on that are not loopback.
    pub fn public_addrs(&self) -> Vec<&str> {
        [&self.grpc_addr, &self.http_addr]
            .into_iter()
            .filter(|a| a.parse::<SocketAddr>().is_ok_and(|s| !s.ip().is_loopback()))
            .map(String::as_str)
            .collect()
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
        let positive: [(&'static str, u64); 17] = [
            ("max_sessions", self.max_sessions as u64),
            ("memory_budget_mib", self.memory_budget_mib),
            ("max_width", self.max_width as u64),
            ("max_height", self.max_height as u64),
            ("max_frame_mib", self.max_frame_mib),
            ("max_chunk_bytes", self.max_chunk_bytes as u64),
            ("queue_depth", self.queue_depth as u64),
            ("idle_timeout_s", self.idle_timeout_s),
            ("header_timeout_s", self.header_timeout_s),
            ("idle_connection_timeout_s", self.idle_connection_timeout_s),
            ("request_timeout_s", self.request_timeout_s),
            ("max_connections", self.max_connections as u64),
            ("keepalive_interval_s", self.keepalive_interval_s),
            ("keepalive_timeout_s", self.keepalive_timeout_s),
            ("max_concurrent_streams", self.max_concurrent_streams as u64),
            ("max_exr_channels", self.max_exr_channels as u64),
            ("max_exr_parts", self.max_exr_parts as u64),
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
        // A chunk and its framing must fit gRPC's 4-byte message length.
        if self.max_chunk_bytes > MAX_CHUNK_BYTES_LIMIT {
            return Err(ConfigError::Invalid {
                field: "max_chunk_bytes",
                expected: format!("at most {MAX_CHUNK_BYTES_LIMIT} (1 GiB)"),
                got: self.max_chunk_bytes.to_string(),
            });
        }
        if self.tls_cert.is_empty() != self.tls_key.is_empty() {
            return Err(ConfigError::Invalid {
                field: if self.tls_cert.is_empty() {
                    "tls_cert"
                } else {
                    "tls_key"
                },
                expected: "both tls_cert and tls_key, or neither".into(),
                got: "only one of them".into(),
            });
        }
        if self.default_backend.requires_gpu() && !crate::backend::GPU_BUILT {
            return Err(ConfigError::Invalid {
                field: "default_backend",
                expected: "cpu or auto (this build has no GPU backend: rebuild with --features gpu)".into(),
                got: self.default_backend.to_string(),
            });
        }
        if !(self.key_default_share > 0.0 && self.key_default_share <= 1.0) {
            return Err(ConfigError::Invalid {
                field: "key_default_share",
                expected: "a share in (0, 1]".into(),
                got: self.key_default_share.to_string(),
            });
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

    /// Connections one client address may hold open ([`Self::max_connections_per_client`],
    /// 0 meaning `max_connections`).
    pub fn connections_per_client(&self) -> usize {
        match self.max_connections_per_client {
            0 => self.max_connections,
            n => n.min(self.max_connections),
        }
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
            replica: self.replica_name(),
            default_backend: self.default_backend,
            state_key: self.state_key.clone(),
            shared_memory: self.shared_memory,
        }
    }

    /// This replica's name: `replica`, else `HOSTNAME`, else `local`.
    pub fn replica_name(&self) -> String {
        let host = std::env::var("HOSTNAME").ok().filter(|h| !h.trim().is_empty());
        match (self.replica.trim(), host) {
            ("", Some(h)) => crate::session::clip(h.trim()).into_owned(),
            ("", None) => "local".into(),
            (r, _) => crate::session::clip(r).into_owned(),
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
        let e = Config::load(None, env(&[("AFTERIMAGE_MAX_CHUNK_BYTES", "2147483648")]))
            .unwrap_err()
            .to_string();
        assert!(e.contains("max_chunk_bytes") && e.contains("at most"), "{e}");
    }

    /// The sessions' default backend comes from the file or the environment; a name that
    /// is none, or gpu in a build without it, is refused at start.
    #[test]
    fn the_default_backend_is_configured_and_checked() {
        use crate::backend::BackendChoice;
        let c = Config::load(None, env(&[("AFTERIMAGE_DEFAULT_BACKEND", "auto")])).unwrap();
        assert_eq!(c.limits().default_backend, BackendChoice::Auto);
        let e = Config::load(None, env(&[("AFTERIMAGE_DEFAULT_BACKEND", "tpu")]))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("AFTERIMAGE_DEFAULT_BACKEND") && e.contains("tpu"),
            "{e}"
        );
        for (name, choice) in [("gpu", BackendChoice::Gpu), ("gpu-f16", BackendChoice::GpuF16)] {
            let gpu = Config::load(None, env(&[("AFTERIMAGE_DEFAULT_BACKEND", name)]));
            match crate::backend::GPU_BUILT {
                true => assert_eq!(gpu.unwrap().default_backend, choice),
                false => {
                    let e = gpu.unwrap_err().to_string();
                    assert!(
                        e.contains("default_backend") && e.contains("--features gpu") && e.contains(name),
                        "{e}"
                    );
                }
            }
        }
    }

    /// A wrong value names its source (the file with line and column, or the variable),
    /// the key, what was expected and what came; a variable's value is never blamed on the
    /// file under it. (`figment` 0.10, tried for issue #42, says of the same variables
    /// `for key "MAX_SESSIONS" in \`AFTERIMAGE_\` environment variable(s)`, gives no line for
    /// the file, and refuses `AFTERIMAGE_ALLOW_UNAUTHENTICATED=1` and a numeric
    /// `AFTERIMAGE_REPLICA`; see docs/server.md.)
    #[test]
    fn bad_values_name_the_source_the_key_and_what_was_expected() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("c.toml");
        let file = p.display().to_string();
        std::fs::write(&p, "idle_timeout_s = 9\nmax_sessions = \"many\"\n").unwrap();
        let e = Config::load(Some(&p), env(&[])).unwrap_err().to_string();
        assert!(e.starts_with(&format!("{file}: ")), "{e}");
        for says in [
            "line 2, column 16",
            "max_sessions = \"many\"",
            "expected usize",
            "string \"many\"",
        ] {
            assert!(e.contains(says), "no {says:?} in {e}");
        }

        std::fs::write(&p, "max_sessions = 3\n").unwrap();
        for (var, value, says) in [
            ("AFTERIMAGE_MAX_SESSIONS", "many", "expected a whole number"),
            ("AFTERIMAGE_MAX_SESSIONS", "-1", "expected usize"),
            ("AFTERIMAGE_MAX_WIDTH", "99999999999", "expected u32"),
            ("AFTERIMAGE_DEFAULT_BACKEND", "tpu", "expected one of `cpu`"),
            (
                "AFTERIMAGE_ALLOW_UNAUTHENTICATED",
                "maybe",
                "expected true or false",
            ),
            ("AFTERIMAGE_KEY_DEFAULT_SHARE", "half", "expected a number"),
        ] {
            let e = Config::load(Some(&p), env(&[(var, value)]))
                .unwrap_err()
                .to_string();
            assert!(e.starts_with(&format!("{var}: ")), "{e}");
            assert!(!e.contains(&file), "blamed on the file: {e}");
            assert!(e.contains(says) && e.contains(&format!("{value:?}")), "{e}");
        }
        // What figment would refuse is read as before.
        let c = Config::load(
            Some(&p),
            env(&[
                ("AFTERIMAGE_ALLOW_UNAUTHENTICATED", "1"),
                ("AFTERIMAGE_REPLICA", "3"),
            ]),
        )
        .unwrap();
        assert!(c.allow_unauthenticated);
        assert_eq!(c.replica, "3");
    }

    #[test]
    fn shared_memory_is_on_unless_turned_off() {
        assert!(Config::default().limits().shared_memory);
        let c = Config::load(None, env(&[("AFTERIMAGE_SHARED_MEMORY", "false")])).unwrap();
        assert!(!c.limits().shared_memory);
    }

    #[test]
    fn grpc_reflection_is_on_by_default_and_can_be_turned_off() {
        assert!(Config::default().grpc_reflection);
        let c = Config::load(None, env(&[("AFTERIMAGE_GRPC_REFLECTION", "false")])).unwrap();
        assert!(!c.grpc_reflection);
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("c.toml");
        std::fs::write(&p, "grpc_reflection = false\n").unwrap();
        assert!(!Config::load(Some(&p), env(&[])).unwrap().grpc_reflection);
        assert!(toml::to_string(&c).unwrap().contains("grpc_reflection = false"));
    }
}
