//! Filter state files: everything a causal filter carries from one frame to the next, in a
//! versioned, checksummed file, so that a run can stop and continue later (elsewhere) with
//! bit-identical output. `afterimage batch` checkpoints shots with it; the server exports and
//! imports sessions with it.
//!
//! Layout (integers little-endian):
//!
//! | bytes | what |
//! |---|---|
//! | 8 | magic `AFTSTATE` |
//! | 4 | format version ([`STATE_VERSION`]) |
//! | 4 | header length `H` (at most [`MAX_HEADER_BYTES`]) |
//! | `H` | header, JSON: filter, params, size, plane components, flags, caller's notes |
//! | ... | each plane's samples as f32, rows in order |
//! | 32 | SHA-256 of every byte before it, or with a [`StateKey`] their HMAC-SHA-256 |
//!
//! The plain SHA-256 catches damage, not forgery: anyone can recompute it. A server or a
//! batch given a state key signs what it writes and refuses state it did not sign, so a
//! client or a neighbour on shared storage cannot plant a history. Whatever the trailer,
//! the filters check every plane they load (finite, in range).
//!
//! Reading is written for untrusted bytes (a client uploading a session): the checksum is
//! checked first, the header is bounded, the size is checked against a pixel limit and the
//! planes' length against the bytes there are, all with checked arithmetic, before anything
//! is allocated.

use crate::echo::clip;
use crate::frame::Plane;
use serde::{Deserialize, Serialize};
use serde_json::{Map, Value};
use sha2::{Digest, Sha256};
use thiserror::Error;

/// The first bytes of every state file.
pub const STATE_MAGIC: &[u8; 8] = b"AFTSTATE";
/// The format version this build writes and reads.
pub const STATE_VERSION: u32 = 1;
/// Largest header accepted (the JSON part).
pub const MAX_HEADER_BYTES: usize = 1 << 20;
const CHECKSUM_BYTES: usize = 32;
const PREAMBLE_BYTES: usize = 16;

/// The environment variable holding the secret that signs state files: the server's
/// session exports and `afterimage batch`'s checkpoints.
pub const STATE_KEY_ENV: &str = "AFTERIMAGE_STATE_KEY";

/// A secret that signs state files (HMAC-SHA-256, RFC 2104): see the module.
#[derive(Clone, PartialEq, Eq)]
pub struct StateKey(Vec<u8>);

impl std::fmt::Debug for StateKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("StateKey(..)")
    }
}

impl StateKey {
    /// A key of the bytes of `secret`; None when it is empty.
    pub fn new(secret: &[u8]) -> Option<StateKey> {
        (!secret.is_empty()).then(|| StateKey(secret.to_vec()))
    }

    /// The key in [`STATE_KEY_ENV`], if set and not empty.
    pub fn from_env() -> Option<StateKey> {
        StateKey::new(std::env::var(STATE_KEY_ENV).unwrap_or_default().as_bytes())
    }

    /// HMAC-SHA-256 of `data` (RFC 2104, with SHA-256's 64-byte block).
    pub fn sign(&self, data: &[u8]) -> [u8; 32] {
        const BLOCK: usize = 64;
        let mut k = [0u8; BLOCK];
        if self.0.len() > BLOCK {
            k[..32].copy_from_slice(&Sha256::digest(&self.0));
        } else {
            k[..self.0.len()].copy_from_slice(&self.0);
        }
        let pad = |b: u8| k.map(|x| x ^ b);
        let inner = Sha256::new()
            .chain_update(pad(0x36))
            .chain_update(data)
            .finalize();
        Sha256::new()
            .chain_update(pad(0x5c))
            .chain_update(inner)
            .finalize()
            .into()
    }
}

/// The trailer of `body`: its HMAC with `key`, else its SHA-256.
fn trailer(body: &[u8], key: Option<&StateKey>) -> [u8; 32] {
    match key {
        Some(k) => k.sign(body),
        None => Sha256::digest(body).into(),
    }
}

/// Equal in time that does not depend on where they differ.
fn same_bytes(a: &[u8], b: &[u8]) -> bool {
    a.len() == b.len() && a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y)) == 0
}

/// Why a state file was refused. All are the sender's: the bytes, or a state that does not
/// fit the filter it is loaded into.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum StateError {
    /// Not a state file at all.
    #[error("not an afterimage state file (its first bytes are not {:?})", std::str::from_utf8(STATE_MAGIC).unwrap_or(""))]
    Magic,
    /// Written by another format version.
    #[error("state file version {got}, but this build reads version {expected}")]
    Version {
        /// The file's version.
        got: u32,
        /// The version read here.
        expected: u32,
    },
    /// Shorter than its own layout says.
    #[error("state file truncated: {what} needs {expected} bytes, {got} there")]
    Truncated {
        /// The part that is short.
        what: &'static str,
        /// Bytes it needs.
        expected: u64,
        /// Bytes there are.
        got: u64,
    },
    /// The bytes do not match their checksum.
    #[error("state file corrupted: its SHA-256 checksum does not match its contents (or it is signed with a state key this reader was not given)")]
    Checksum,
    /// Not signed with the reader's state key.
    #[error(
        "state file not signed with this server's state key: refused (a state exported elsewhere, or forged)"
    )]
    Unsigned,
    /// A plane holds a value the filter never writes there.
    #[error("state file plane {plane}: {message}")]
    Plane {
        /// Which plane (its index in the file).
        plane: usize,
        /// What is wrong, where.
        message: String,
    },
    /// The header is not what this version writes.
    #[error("state file header: {0}")]
    Header(String),
    /// Larger than the reader accepts.
    #[error("state file is {width}x{height} pixels; at most {limit} pixels are accepted here")]
    TooLarge {
        /// Width in the header.
        width: usize,
        /// Height in the header.
        height: usize,
        /// Pixels accepted.
        limit: u64,
    },
    /// Bytes left over after the planes.
    #[error("state file has {extra} bytes after its planes")]
    Trailing {
        /// How many.
        extra: u64,
    },
    /// A state of another filter, or one whose planes differ from what the filter keeps.
    #[error("state of {what} does not fit filter {filter}: {message}")]
    Mismatch {
        /// What the state holds.
        what: String,
        /// The filter it was loaded into.
        filter: &'static str,
        /// What differs.
        message: String,
    },
    /// Not the caller's: the device holding a GPU filter's state failed to hand it over.
    #[error("the device holding the state failed: {0}")]
    Device(String),
    /// The filter keeps no state that can be saved this way.
    #[error("filter {filter} cannot save or load its state: {why}")]
    Unsupported {
        /// The filter.
        filter: &'static str,
        /// Why.
        why: &'static str,
    },
}

/// What a filter carries between frames: its history planes (the read side of its double
/// buffer), their size and layout, and flags, with the filter's name and parameters so a
/// state is never loaded into a filter that would read it differently.
#[derive(Clone, Debug, PartialEq)]
pub struct FilterState {
    /// The filter's registry name.
    pub filter: String,
    /// The parameters in effect ([`super::Filter::params`]).
    pub params: Value,
    /// The history's size in pixels; `None` when it holds no frame (first frame next, or
    /// after a reset).
    pub size: Option<(usize, usize)>,
    /// Channels per pixel of each history plane (interleaved).
    pub components: Vec<usize>,
    /// The history planes (empty when `size` is `None`); plane `k` is
    /// `components[k] * width` samples wide.
    pub planes: Vec<Plane<f32>>,
    /// Filter flags (for example whether the colour history is tonemapped).
    pub flags: Map<String, Value>,
    /// The caller's notes (a batch's next frame, a session's frame count), kept verbatim.
    pub notes: Map<String, Value>,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct Header {
    filter: String,
    params: Value,
    size: Option<(usize, usize)>,
    components: Vec<usize>,
    flags: Map<String, Value>,
    notes: Map<String, Value>,
}

impl FilterState {
    /// The state of a filter with nothing to carry (a spatial filter, or a temporal one
    /// before its first frame).
    pub fn empty(filter: &str, params: Value) -> Self {
        FilterState {
            filter: filter.to_string(),
            params,
            size: None,
            components: Vec::new(),
            planes: Vec::new(),
            flags: Map::new(),
            notes: Map::new(),
        }
    }

    /// Bytes [`Self::encode`] writes.
    pub fn encoded_len(&self) -> usize {
        let samples: usize = self.planes.iter().map(|p| p.data().len()).sum();
        PREAMBLE_BYTES + self.header_json().len() + samples * 4 + CHECKSUM_BYTES
    }

    fn header_json(&self) -> Vec<u8> {
        serde_json::to_vec(&Header {
            filter: self.filter.clone(),
            params: self.params.clone(),
            size: self.size,
            components: self.components.clone(),
            flags: self.flags.clone(),
            notes: self.notes.clone(),
        })
        .expect("a state header is plain JSON")
    }

    /// The state as a file (see the module for the layout), with a SHA-256 trailer.
    pub fn encode(&self) -> Vec<u8> {
        self.encode_with(None)
    }

    /// The state as a file, signed with `key` when given.
    pub fn encode_with(&self, key: Option<&StateKey>) -> Vec<u8> {
        let header = self.header_json();
        let mut out = Vec::with_capacity(self.encoded_len());
        out.extend_from_slice(STATE_MAGIC);
        out.extend_from_slice(&STATE_VERSION.to_le_bytes());
        out.extend_from_slice(&(header.len() as u32).to_le_bytes());
        out.extend_from_slice(&header);
        for p in &self.planes {
            for v in p.data() {
                out.extend_from_slice(&v.to_le_bytes());
            }
        }
        let sum = trailer(&out, key);
        out.extend_from_slice(&sum);
        out
    }

    /// Reads a state file from untrusted bytes, refusing a history larger than
    /// `max_pixels` (see the module for what is checked, and in what order).
    pub fn decode(bytes: &[u8], max_pixels: u64) -> Result<FilterState, StateError> {
        Self::decode_with(bytes, max_pixels, None)
    }

    /// [`Self::decode`], refusing a file not signed with `key` when one is given.
    pub fn decode_with(
        bytes: &[u8],
        max_pixels: u64,
        key: Option<&StateKey>,
    ) -> Result<FilterState, StateError> {
        let truncated = |what, expected: usize| StateError::Truncated {
            what,
            expected: expected as u64,
            got: bytes.len() as u64,
        };
        if bytes.len() < STATE_MAGIC.len() || &bytes[..STATE_MAGIC.len()] != STATE_MAGIC {
            return Err(StateError::Magic);
        }
        if bytes.len() < PREAMBLE_BYTES + CHECKSUM_BYTES {
            return Err(truncated(
                "the preamble and checksum",
                PREAMBLE_BYTES + CHECKSUM_BYTES,
            ));
        }
        let u32_at = |at: usize| u32::from_le_bytes(bytes[at..at + 4].try_into().expect("4 bytes"));
        let version = u32_at(8);
        if version != STATE_VERSION {
            return Err(StateError::Version {
                got: version,
                expected: STATE_VERSION,
            });
        }
        let (body, sum) = bytes.split_at(bytes.len() - CHECKSUM_BYTES);
        if !same_bytes(&trailer(body, key), sum) {
            return Err(if key.is_some() {
                StateError::Unsigned
            } else {
                StateError::Checksum
            });
        }
        let header_len = u32_at(12) as usize;
        if header_len > MAX_HEADER_BYTES {
            return Err(StateError::Header(format!(
                "{header_len} bytes; at most {MAX_HEADER_BYTES} are accepted"
            )));
        }
        let header_end = PREAMBLE_BYTES + header_len;
        if body.len() < header_end {
            return Err(truncated("the header", header_end + CHECKSUM_BYTES));
        }
        let header: Header = serde_json::from_slice(&body[PREAMBLE_BYTES..header_end])
            .map_err(|e| StateError::Header(e.to_string()))?;
        let (width, height) = header.size.unwrap_or((0, 0));
        let pixels = (width as u64).checked_mul(height as u64);
        if pixels.is_none_or(|p| p > max_pixels) {
            return Err(StateError::TooLarge {
                width,
                height,
                limit: max_pixels,
            });
        }
        if header.components.len() > 64 || header.components.iter().any(|&c| c == 0 || c > 64) {
            return Err(StateError::Header(format!(
                "plane components {}: expected at most 64 planes of 1 to 64 channels",
                clip(&format!("{:?}", header.components))
            )));
        }
        let data = &body[header_end..];
        let mut planes = Vec::new();
        if header.size.is_some() {
            let too_large = || StateError::TooLarge {
                width,
                height,
                limit: max_pixels,
            };
            let samples: Vec<usize> = header
                .components
                .iter()
                .map(|&c| c.checked_mul(width)?.checked_mul(height))
                .collect::<Option<_>>()
                .ok_or_else(too_large)?;
            let need = samples
                .iter()
                .try_fold(0usize, |a, &s| a.checked_add(s.checked_mul(4)?))
                .ok_or_else(too_large)?;
            if data.len() < need {
                let whole = need.saturating_add(header_end + CHECKSUM_BYTES);
                return Err(truncated("the planes", whole));
            }
            if data.len() > need {
                return Err(StateError::Trailing {
                    extra: (data.len() - need) as u64,
                });
            }
            let mut at = 0;
            for (&c, &n) in header.components.iter().zip(&samples) {
                let values: Vec<f32> = data[at..at + n * 4]
                    .chunks_exact(4)
                    .map(|b| f32::from_le_bytes(b.try_into().expect("4 bytes")))
                    .collect();
                at += n * 4;
                planes.push(Plane::from_vec(c * width, height, values).expect("length checked above"));
            }
        } else if !data.is_empty() {
            return Err(StateError::Trailing {
                extra: data.len() as u64,
            });
        }
        Ok(FilterState {
            filter: header.filter,
            params: header.params,
            size: header.size,
            components: header.components,
            planes,
            flags: header.flags,
            notes: header.notes,
        })
    }

    /// Checks that this is a state of `filter` with `params` (as [`super::Filter::params`]
    /// gives them): anything else would continue a different computation.
    pub fn check_for(&self, filter: &'static str, params: &Value) -> Result<(), StateError> {
        let mismatch = |message: String| StateError::Mismatch {
            what: clip(&self.filter).into_owned(),
            filter,
            message,
        };
        if self.filter != filter {
            return Err(mismatch(format!(
                "it is a state of filter {}",
                clip(&self.filter)
            )));
        }
        if &self.params != params {
            return Err(mismatch(format!(
                "it was saved with parameters {} but the filter has {}",
                clip(&self.params.to_string()),
                params
            )));
        }
        Ok(())
    }

    /// Checks that this is the (empty) state of a filter that carries nothing between
    /// frames, `filter` with `params`.
    pub fn check_stateless(&self, filter: &'static str, params: &Value) -> Result<(), StateError> {
        self.check_for(filter, params)?;
        if self.size.is_some() || !self.planes.is_empty() {
            return Err(StateError::Mismatch {
                what: clip(&self.filter).into_owned(),
                filter,
                message: "it holds history planes, but the filter keeps none".into(),
            });
        }
        Ok(())
    }

    /// Checks that every sample of every plane is finite: no filter writes NaN or an
    /// infinity into its history (its input is repaired first), so a state holding one was
    /// not written by a filter.
    pub fn check_finite(&self) -> Result<(), StateError> {
        for (k, p) in self.planes.iter().enumerate() {
            if let Some(i) = p.data().iter().position(|v| !v.is_finite()) {
                let (w, c) = (p.width(), self.components.get(k).copied().unwrap_or(1));
                return Err(StateError::Plane {
                    plane: k,
                    message: format!(
                        "sample {} of pixel ({}, {}) is {}, but a filter's history is always finite",
                        (i % w) % c,
                        (i % w) / c,
                        i / w,
                        p.data()[i]
                    ),
                });
            }
        }
        Ok(())
    }

    /// A boolean flag, or an error naming it.
    pub fn flag(&self, name: &str, filter: &'static str) -> Result<bool, StateError> {
        self.flags
            .get(name)
            .and_then(Value::as_bool)
            .ok_or_else(|| StateError::Mismatch {
                what: clip(&self.filter).into_owned(),
                filter,
                message: format!("it has no boolean flag {name:?}"),
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;
    use serde_json::json;

    fn sample() -> FilterState {
        let mut rng = SplitMix64::new(7);
        let mut st = FilterState::empty("taa", json!({"alpha": 0.1}));
        st.size = Some((5, 3));
        st.components = vec![1, 3];
        st.planes = vec![
            Plane::from_fn(5, 3, |_, _| rng.next_f64() as f32),
            Plane::from_fn(15, 3, |x, _| if x == 4 { f32::NAN } else { -0.0 }),
        ];
        st.flags.insert("tonemapped".into(), json!(true));
        st.notes.insert("next".into(), json!(17));
        st
    }

    fn bits(st: &FilterState) -> Vec<Vec<u32>> {
        st.planes
            .iter()
            .map(|p| p.data().iter().map(|v| v.to_bits()).collect())
            .collect()
    }

    #[test]
    fn hmac_matches_rfc_4231() {
        let hex = |b: &[u8]| b.iter().map(|x| format!("{x:02x}")).collect::<String>();
        // RFC 4231, test cases 2 (a short key) and 6 (a key longer than the block).
        let k = StateKey::new(b"Jefe").unwrap();
        assert_eq!(
            hex(&k.sign(b"what do ya want for nothing?")),
            "5bdcc146bf60754e6a042426089575c75a003f089d2739839dec58b964ec3843"
        );
        let k = StateKey::new(&[0xaa; 131]).unwrap();
        assert_eq!(
            hex(&k.sign(b"Test Using Larger Than Block-Size Key - Hash Key First")),
            "60e431591ee0b67f0d8a26aacbf5b77f8e0bc6213728c5140546040f0ee37f54"
        );
        assert!(StateKey::new(b"").is_none());
    }

    #[test]
    fn a_signed_state_reads_only_with_its_key() {
        let mut st = sample();
        st.planes[1].data_mut().fill(0.25);
        let key = StateKey::new(b"server secret").unwrap();
        let signed = st.encode_with(Some(&key));
        assert_eq!(
            FilterState::decode_with(&signed, 1 << 20, Some(&key)).unwrap(),
            st
        );
        // A plain file (anyone can write one) and one signed with another key are refused.
        let plain = st.encode();
        assert_eq!(
            FilterState::decode_with(&plain, 1 << 20, Some(&key)),
            Err(StateError::Unsigned)
        );
        let other = st.encode_with(StateKey::new(b"other").as_ref());
        assert_eq!(
            FilterState::decode_with(&other, 1 << 20, Some(&key)),
            Err(StateError::Unsigned)
        );
        // Without a key, a signed file is not mistaken for a plain one.
        assert_eq!(FilterState::decode(&signed, 1 << 20), Err(StateError::Checksum));
    }

    #[test]
    fn a_non_finite_plane_is_named() {
        let mut st = sample();
        st.planes[1].data_mut().fill(0.25);
        assert_eq!(st.check_finite(), Ok(()));
        let w = st.planes[1].width();
        // Row 1, the second channel of pixel 3.
        st.planes[1].data_mut()[w + 10] = f32::INFINITY;
        let e = st.check_finite().unwrap_err().to_string();
        assert!(
            e.contains("plane 1") && e.contains("sample 1 of pixel (3, 1) is inf"),
            "{e}"
        );
    }

    #[test]
    fn a_state_comes_back_bit_for_bit() {
        let st = sample();
        let bytes = st.encode();
        assert_eq!(bytes.len(), st.encoded_len());
        let back = FilterState::decode(&bytes, 15).unwrap();
        assert_eq!(bits(&back), bits(&st));
        assert_eq!(
            (back.size, &back.components, &back.flags, &back.notes),
            (st.size, &st.components, &st.flags, &st.notes)
        );
        let empty = FilterState::empty("fxaa", json!({}));
        assert_eq!(FilterState::decode(&empty.encode(), 0).unwrap(), empty);
    }

    #[test]
    fn damaged_or_foreign_bytes_are_refused_with_the_reason() {
        let bytes = sample().encode();
        let err = |b: &[u8], max| FilterState::decode(b, max).unwrap_err();
        assert_eq!(err(b"PNG....", 15), StateError::Magic);
        let mut v = bytes.clone();
        v[8] = 2;
        assert_eq!(err(&v, 15), StateError::Version { got: 2, expected: 1 });
        // Every single flipped byte after the preamble is caught.
        for at in [16, 40, bytes.len() / 2, bytes.len() - 40, bytes.len() - 1] {
            let mut v = bytes.clone();
            v[at] ^= 0x10;
            assert_eq!(err(&v, 15), StateError::Checksum, "byte {at}");
        }
        assert!(matches!(err(&bytes[..20], 15), StateError::Truncated { .. }));
        // Cut short (with a valid checksum over what is left): the planes are short.
        let mut cut = bytes[..bytes.len() - 32 - 8].to_vec();
        let sum = Sha256::digest(&cut);
        cut.extend_from_slice(&sum);
        assert!(
            matches!(
                err(&cut, 15),
                StateError::Truncated {
                    what: "the planes",
                    ..
                }
            ),
            "{:?}",
            err(&cut, 15)
        );
        // A history larger than the reader accepts is refused before it is read.
        assert_eq!(
            err(&bytes, 14),
            StateError::TooLarge {
                width: 5,
                height: 3,
                limit: 14
            }
        );
    }

    /// A hostile header (huge size, absurd layout) is refused without allocating for it.
    #[test]
    fn a_hostile_header_is_refused_before_allocating() {
        let forge = |header: &str| {
            let mut v = STATE_MAGIC.to_vec();
            v.extend_from_slice(&STATE_VERSION.to_le_bytes());
            v.extend_from_slice(&(header.len() as u32).to_le_bytes());
            v.extend_from_slice(header.as_bytes());
            let sum = Sha256::digest(&v);
            v.extend_from_slice(&sum);
            v
        };
        let h = |size: &str, comps: &str| {
            format!(
                r#"{{"filter":"taa","params":{{}},"size":{size},"components":{comps},"flags":{{}},"notes":{{}}}}"#
            )
        };
        let max = 1 << 24;
        let e = FilterState::decode(&forge(&h("[18446744073709551615,2]", "[1]")), max).unwrap_err();
        assert!(matches!(e, StateError::TooLarge { .. }), "{e:?}");
        // With no pixel limit at all, sizes whose byte count overflows are still refused.
        for size in ["[4294967296,4294967296]", "[2147483648,2147483648]"] {
            let e = FilterState::decode(&forge(&h(size, "[4]")), u64::MAX).unwrap_err();
            assert!(matches!(e, StateError::TooLarge { .. }), "{size}: {e:?}");
        }
        let e = FilterState::decode(&forge(&h("[4096,4096]", "[1]")), max).unwrap_err();
        assert!(matches!(e, StateError::Truncated { .. }), "{e:?}");
        let e = FilterState::decode(&forge(&h("[2,2]", "[0]")), max).unwrap_err();
        assert!(matches!(e, StateError::Header(_)), "{e:?}");
        let e = FilterState::decode(&forge(&h("[2,2]", "[1000000]")), max).unwrap_err();
        assert!(matches!(e, StateError::Header(_)), "{e:?}");
        let e = FilterState::decode(&forge(r#"{"filter":"taa"}"#), max).unwrap_err();
        assert!(matches!(e, StateError::Header(_)), "{e:?}");
        let mut v = forge(&h("null", "[]"));
        v[12..16].copy_from_slice(&u32::MAX.to_le_bytes());
        let e = FilterState::decode(&v, max).unwrap_err();
        assert!(matches!(e, StateError::Checksum), "{e:?}");
    }

    #[test]
    fn a_state_fits_only_its_own_filter_and_parameters() {
        let st = sample();
        st.check_for("taa", &json!({"alpha": 0.1})).unwrap();
        let e = st
            .check_for("phlm", &json!({"alpha": 0.1}))
            .unwrap_err()
            .to_string();
        assert!(e.contains("state of filter taa"), "{e}");
        let e = st
            .check_for("taa", &json!({"alpha": 0.2}))
            .unwrap_err()
            .to_string();
        assert!(e.contains("parameters"), "{e}");
    }
}
