//! One memory budget over everything the server holds for its clients: session state, and
//! per request the body or wire bytes being received, the decoded frame and the reply.
//! Memory is taken by [`Reservation`]s, which give it back when dropped, so a request
//! that fails anywhere (or panics) cannot leak budget.

use super::error::SessionError;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

/// A limit on bytes held at once, shared by every holder.
#[derive(Debug)]
pub struct Budget {
    what: String,
    limit: u64,
    used: AtomicU64,
}

impl Budget {
    /// A budget of `limit` bytes, named `what` in errors ("the memory budget", "the memory
    /// quota of key farm").
    pub fn new(what: impl Into<String>, limit: u64) -> Arc<Budget> {
        Arc::new(Budget {
            what: what.into(),
            limit,
            used: AtomicU64::new(0),
        })
    }

    /// Bytes held now.
    pub fn used(&self) -> u64 {
        self.used.load(Ordering::SeqCst)
    }

    /// The limit.
    pub fn limit(&self) -> u64 {
        self.limit
    }

    /// Takes `bytes` if they fit; otherwise returns the bytes free.
    fn try_take(&self, bytes: u64) -> Result<(), u64> {
        let mut used = self.used.load(Ordering::SeqCst);
        loop {
            let free = self.limit.saturating_sub(used);
            if bytes > free {
                return Err(free);
            }
            match self
                .used
                .compare_exchange(used, used + bytes, Ordering::SeqCst, Ordering::SeqCst)
            {
                Ok(_) => return Ok(()),
                Err(now) => used = now,
            }
        }
    }

    fn give_back(&self, bytes: u64) {
        self.used.fetch_sub(bytes, Ordering::SeqCst);
    }
}

/// Bytes taken from one or more budgets (the server's, and the caller's key quota), given
/// back on drop.
#[derive(Debug, Default)]
pub struct Reservation {
    parts: Vec<(Arc<Budget>, u64)>,
}

impl Reservation {
    /// Takes `bytes` from every budget in `from`, or from none: the error names `what`
    /// needed them and the first budget that could not give them, with its free bytes.
    pub fn take(from: &[&Arc<Budget>], bytes: u64, what: &str) -> Result<Reservation, SessionError> {
        let mut r = Reservation::default();
        for b in from {
            if let Err(free) = b.try_take(bytes) {
                return Err(SessionError::Exhausted(format!(
                    "{what} needs {bytes} bytes; {free} of the {} bytes of {} are free",
                    b.limit, b.what
                )));
            }
            r.parts.push(((*b).clone(), bytes));
        }
        Ok(r)
    }

    /// Bytes held (the same in every budget it took from).
    pub fn bytes(&self) -> u64 {
        self.parts.first().map_or(0, |(_, n)| *n)
    }

    /// Holds `more` bytes in every budget whether they fit or not: for state that turned
    /// out larger than reserved, which exists already and must be counted.
    pub fn force_grow(&mut self, more: u64) {
        for (b, n) in &mut self.parts {
            b.used.fetch_add(more, Ordering::SeqCst);
            *n += more;
        }
    }
}

impl Drop for Reservation {
    fn drop(&mut self) {
        for (b, n) in &self.parts {
            b.give_back(*n);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reservations_are_all_or_nothing_and_give_back_on_drop() {
        let server = Budget::new("the memory budget", 100);
        let key = Budget::new("the memory quota of key k", 50);
        let a = Reservation::take(&[&server, &key], 40, "a frame").unwrap();
        assert_eq!((server.used(), key.used()), (40, 40));
        // Fits the server but not the key: nothing is taken from either.
        let e = Reservation::take(&[&server, &key], 20, "another frame").unwrap_err();
        assert_eq!(
            e.to_string(),
            "another frame needs 20 bytes; 10 of the 50 bytes of the memory quota of key k are free"
        );
        assert_eq!((server.used(), key.used()), (40, 40));
        let mut b = Reservation::take(&[&server], 60, "state").unwrap();
        assert!(Reservation::take(&[&server], 1, "x").is_err());
        b.force_grow(5);
        assert_eq!((server.used(), b.bytes()), (105, 65));
        drop(a);
        drop(b);
        assert_eq!((server.used(), key.used()), (0, 0));
    }

    #[test]
    fn concurrent_takers_never_exceed_the_limit() {
        let budget = Budget::new("the memory budget", 1000);
        let peak = AtomicU64::new(0);
        std::thread::scope(|s| {
            for _ in 0..4 {
                s.spawn(|| {
                    for _ in 0..2000 {
                        if let Ok(r) = Reservation::take(&[&budget], 300, "x") {
                            peak.fetch_max(budget.used(), Ordering::SeqCst);
                            drop(r);
                        }
                    }
                });
            }
        });
        assert!(peak.load(Ordering::SeqCst) <= 1000);
        assert!(peak.load(Ordering::SeqCst) >= 300);
        assert_eq!(budget.used(), 0);
    }
}
