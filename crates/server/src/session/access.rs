//! API keys: who may open sessions, and what each key may hold. A key is a secret the
//! client sends (`Authorization: Bearer KEY` over HTTP, `authorization` metadata over
//! gRPC); the server keeps only its SHA-256. A session belongs to the key that created it,
//! and each key has its own quotas (sessions open, bytes of memory) inside the server's.

use super::budget::Budget;
use super::error::SessionError;
use serde::Deserialize;
use sha2::{Digest, Sha256};
use std::collections::HashMap;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use thiserror::Error;

/// Environment variable with plain keys, `name:secret[,name:secret...]` (hashed at load;
/// a keys file of hashes is the better place for long-lived keys).
pub const KEYS_ENV: &str = "AFTERIMAGE_API_KEYS";

/// A key the server accepts, with its quotas.
#[derive(Debug)]
pub struct ApiKey {
    /// Its name, for logs and metrics (never the secret).
    pub name: String,
    /// Sessions it may have open at once.
    pub max_sessions: usize,
    /// Memory its sessions and requests may hold.
    pub memory: Arc<Budget>,
    sessions: AtomicUsize,
}

impl ApiKey {
    /// Sessions open now.
    pub fn sessions(&self) -> usize {
        self.sessions.load(Ordering::SeqCst)
    }
}

/// Who is asking: a key, or nobody (a server without keys).
#[derive(Clone, Debug, Default)]
pub struct Caller(Option<Arc<ApiKey>>);

impl Caller {
    /// The caller of a server that has no keys.
    pub const ANONYMOUS: Caller = Caller(None);

    /// The holder of `key`.
    pub fn key(key: Arc<ApiKey>) -> Caller {
        Caller(Some(key))
    }

    /// The key's name (None: anonymous).
    pub fn name(&self) -> Option<&str> {
        self.0.as_deref().map(|k| k.name.as_str())
    }

    /// The key, if any.
    pub fn api_key(&self) -> Option<&Arc<ApiKey>> {
        self.0.as_ref()
    }

    /// Counts a session against the key's quota; the slot is given back on drop.
    pub(crate) fn session_slot(&self) -> Result<SessionSlot, SessionError> {
        let Some(k) = &self.0 else {
            return Ok(SessionSlot(None));
        };
        let mut now = k.sessions.load(Ordering::SeqCst);
        loop {
            if now >= k.max_sessions {
                return Err(SessionError::Exhausted(format!(
                    "key {} has {now} sessions open, its quota is {}; close one first",
                    k.name, k.max_sessions
                )));
            }
            match k
                .sessions
                .compare_exchange(now, now + 1, Ordering::SeqCst, Ordering::SeqCst)
            {
                Ok(_) => return Ok(SessionSlot(Some(k.clone()))),
                Err(n) => now = n,
            }
        }
    }
}

/// One session counted against a key's quota.
#[derive(Debug)]
pub(crate) struct SessionSlot(Option<Arc<ApiKey>>);

impl Drop for SessionSlot {
    fn drop(&mut self) {
        if let Some(k) = &self.0 {
            k.sessions.fetch_sub(1, Ordering::SeqCst);
        }
    }
}

/// A keys file or variable that cannot be used.
#[derive(Debug, Error)]
pub enum KeyError {
    /// It does not parse.
    #[error("{source_name}: {message}")]
    Parse {
        /// The file or variable.
        source_name: String,
        /// What is wrong.
        message: String,
    },
}

/// Quotas a key gets when its entry does not set them.
#[derive(Clone, Copy, Debug)]
pub struct Quotas {
    /// Sessions open at once.
    pub max_sessions: usize,
    /// Memory, bytes.
    pub memory_bytes: u64,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct KeysFile {
    #[serde(default)]
    key: Vec<KeyEntry>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct KeyEntry {
    name: String,
    sha256: String,
    max_sessions: Option<usize>,
    memory_mib: Option<u64>,
}

/// Every key the server accepts, by the SHA-256 of its secret.
#[derive(Debug, Default)]
pub struct Keyring {
    keys: HashMap<[u8; 32], Arc<ApiKey>>,
}

/// The SHA-256 of a secret.
fn digest(secret: &str) -> [u8; 32] {
    Sha256::digest(secret.as_bytes()).into()
}

/// The SHA-256 of `secret` as lowercase hex: what a keys file stores.
pub fn hash_hex(secret: &str) -> String {
    digest(secret).iter().map(|b| format!("{b:02x}")).collect()
}

fn parse_hex32(s: &str) -> Option<[u8; 32]> {
    let s = s.trim();
    if s.len() != 64 || !s.is_ascii() {
        return None;
    }
    let mut out = [0u8; 32];
    for (i, o) in out.iter_mut().enumerate() {
        *o = u8::from_str_radix(&s[2 * i..2 * i + 2], 16).ok()?;
    }
    Some(out)
}

impl Keyring {
    /// Whether no key is configured (the server then serves only loopback, unless told).
    pub fn is_empty(&self) -> bool {
        self.keys.is_empty()
    }

    /// How many keys.
    pub fn len(&self) -> usize {
        self.keys.len()
    }

    fn add(&mut self, source: &str, name: String, hash: [u8; 32], q: Quotas) -> Result<(), KeyError> {
        let bad = |message: String| KeyError::Parse {
            source_name: source.to_string(),
            message,
        };
        if name.is_empty() || name.len() > 64 || !name.chars().all(|c| c.is_ascii_graphic()) {
            return Err(bad(format!(
                "key name {:?}: expected 1-64 printable ASCII characters without spaces",
                super::error::clip(&name)
            )));
        }
        if self.keys.values().any(|k| k.name == name) {
            return Err(bad(format!("key name {name:?} is used twice")));
        }
        if self.keys.contains_key(&hash) {
            return Err(bad(format!("key {name:?} has the same secret as another key")));
        }
        let memory = Budget::new(format!("the memory quota of key {name}"), q.memory_bytes);
        self.keys.insert(
            hash,
            Arc::new(ApiKey {
                name,
                max_sessions: q.max_sessions,
                memory,
                sessions: AtomicUsize::new(0),
            }),
        );
        Ok(())
    }

    /// Adds the keys of a TOML keys file: `[[key]]` tables with `name`, `sha256` (hex of
    /// the secret's SHA-256) and optional `max_sessions` and `memory_mib`.
    pub fn add_file_text(&mut self, text: &str, source: &str, defaults: Quotas) -> Result<(), KeyError> {
        let file: KeysFile = toml::from_str(text).map_err(|e| KeyError::Parse {
            source_name: source.to_string(),
            message: e.to_string(),
        })?;
        for e in file.key {
            let hash = parse_hex32(&e.sha256).ok_or_else(|| KeyError::Parse {
                source_name: source.to_string(),
                message: format!(
                    "key {:?}: sha256 must be 64 hex digits (`afterimage keygen` prints one)",
                    e.name
                ),
            })?;
            let q = Quotas {
                max_sessions: e.max_sessions.unwrap_or(defaults.max_sessions),
                memory_bytes: e
                    .memory_mib
                    .map_or(defaults.memory_bytes, |m| m.saturating_mul(1 << 20)),
            };
            self.add(source, e.name, hash, q)?;
        }
        Ok(())
    }

    /// Adds plain keys written `name:secret[,name:secret...]` (the [`KEYS_ENV`] form).
    pub fn add_plain(&mut self, value: &str, source: &str, defaults: Quotas) -> Result<(), KeyError> {
        for item in value.split(',').map(str::trim).filter(|s| !s.is_empty()) {
            let (name, secret) = item.split_once(':').ok_or_else(|| KeyError::Parse {
                source_name: source.to_string(),
                message: "expected name:secret pairs separated by commas".into(),
            })?;
            if secret.len() < 16 {
                return Err(KeyError::Parse {
                    source_name: source.to_string(),
                    message: format!("key {name:?}: a secret needs at least 16 characters"),
                });
            }
            self.add(source, name.to_string(), digest(secret), defaults)?;
        }
        Ok(())
    }

    /// The key whose secret is `secret`, if any.
    pub fn authenticate(&self, secret: &str) -> Option<Arc<ApiKey>> {
        self.keys.get(&digest(secret)).cloned()
    }

    /// The caller presenting `authorization` (the header or metadata value, `Bearer KEY`);
    /// anonymous when the server has no keys.
    pub fn caller(&self, authorization: Option<&str>) -> Result<Caller, SessionError> {
        if self.is_empty() {
            return Ok(Caller::ANONYMOUS);
        }
        let value = authorization.ok_or_else(|| {
            SessionError::Unauthenticated(
                "this server needs an API key: send `authorization: Bearer KEY`".into(),
            )
        })?;
        let token = value
            .strip_prefix("Bearer ")
            .or_else(|| value.strip_prefix("bearer "))
            .ok_or_else(|| {
                SessionError::Unauthenticated("the authorization value must be `Bearer KEY`".into())
            })?;
        self.authenticate(token.trim())
            .map(Caller::key)
            .ok_or_else(|| SessionError::Unauthenticated("unknown API key".into()))
    }
}

/// A new random secret: 32 bytes from the OS, hex, with a recognisable prefix.
pub fn new_secret() -> Result<String, SessionError> {
    let mut b = [0u8; 32];
    getrandom::fill(&mut b)
        .map_err(|e| SessionError::Internal(format!("no OS randomness for a key: {e}")))?;
    Ok(format!(
        "aik_{}",
        b.iter().map(|x| format!("{x:02x}")).collect::<String>()
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    const Q: Quotas = Quotas {
        max_sessions: 2,
        memory_bytes: 1 << 20,
    };

    #[test]
    fn keys_from_a_file_of_hashes_and_from_plain_pairs() {
        let mut ring = Keyring::default();
        let text = format!(
            "[[key]]\nname = \"farm\"\nsha256 = \"{}\"\nmax_sessions = 5\nmemory_mib = 3\n",
            hash_hex("farm-secret-0123456789")
        );
        ring.add_file_text(&text, "keys.toml", Q).unwrap();
        ring.add_plain("ci:ci-secret-0123456789", KEYS_ENV, Q).unwrap();
        let farm = ring.authenticate("farm-secret-0123456789").unwrap();
        assert_eq!(
            (farm.name.as_str(), farm.max_sessions, farm.memory.limit()),
            ("farm", 5, 3 << 20)
        );
        let ci = ring.caller(Some("Bearer ci-secret-0123456789")).unwrap();
        assert_eq!(ci.name(), Some("ci"));
        assert_eq!(ci.api_key().unwrap().max_sessions, 2);
        for (auth, words) in [
            (None, "needs an API key"),
            (Some("Basic abc"), "Bearer KEY"),
            (Some("Bearer wrong-secret-0123456789"), "unknown API key"),
        ] {
            let e = ring.caller(auth).unwrap_err();
            assert!(
                matches!(e, SessionError::Unauthenticated(_)) && e.to_string().contains(words),
                "{e}"
            );
        }
        // Without keys everyone is anonymous.
        assert!(Keyring::default().caller(None).unwrap().name().is_none());
    }

    #[test]
    fn bad_key_entries_are_refused_with_their_name() {
        let mut ring = Keyring::default();
        let e = ring
            .add_file_text("[[key]]\nname = \"a\"\nsha256 = \"abc\"\n", "k.toml", Q)
            .unwrap_err()
            .to_string();
        assert!(e.contains("k.toml") && e.contains("64 hex"), "{e}");
        let e = ring.add_plain("a:short", KEYS_ENV, Q).unwrap_err().to_string();
        assert!(e.contains("16 characters"), "{e}");
        ring.add_plain("a:0123456789abcdef", KEYS_ENV, Q).unwrap();
        let e = ring
            .add_plain("a:fedcba9876543210", KEYS_ENV, Q)
            .unwrap_err()
            .to_string();
        assert!(e.contains("used twice"), "{e}");
        let e = ring
            .add_plain("b:0123456789abcdef", KEYS_ENV, Q)
            .unwrap_err()
            .to_string();
        assert!(e.contains("same secret"), "{e}");
    }

    #[test]
    fn session_slots_hold_the_quota_until_dropped() {
        let mut ring = Keyring::default();
        ring.add_plain("k:0123456789abcdef", KEYS_ENV, Q).unwrap();
        let c = ring.caller(Some("Bearer 0123456789abcdef")).unwrap();
        let a = c.session_slot().unwrap();
        let _b = c.session_slot().unwrap();
        let e = c.session_slot().unwrap_err().to_string();
        assert!(e.contains("key k has 2 sessions open, its quota is 2"), "{e}");
        drop(a);
        assert!(c.session_slot().is_ok());
        assert_eq!(new_secret().unwrap().len(), 68);
    }
}
