//! Fair shares of the filter pool between API keys, and within a key between its sessions,
//! weighted by pixels: a client streaming 4K frames, or a key with many sessions, cannot
//! make a 720p client wait behind its queue.
//!
//! Jobs wait in one queue per session; at most `slots` run at once (each spreads its rows
//! over the whole pool). When a slot frees, the key that has been served the fewest pixels
//! goes next, and within it the session served the fewest (start-time fair queuing,
//! Goyal et al. 1996, with a job's pixels as its length). A key or session that was idle
//! starts level with the least served one still waiting, so idling earns no credit.

use std::collections::{HashMap, VecDeque};
use std::sync::{Arc, Mutex};

/// Who a job is for and how much work it is.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Share {
    /// The API key's name ("" without keys).
    pub key: String,
    /// The session ("" for work of no session, such as creating one).
    pub session: String,
    /// Pixels the job filters (1 for small work).
    pub pixels: u64,
}

type Job = Box<dyn FnOnce() + Send>;

#[derive(Default)]
struct Flow<T> {
    served: f64,
    inner: T,
}

/// A session's waiting jobs, with their pixels.
type SessionFlow = Flow<VecDeque<(u64, Job)>>;
/// A key's sessions that have jobs waiting.
type KeyFlow = Flow<HashMap<String, SessionFlow>>;

#[derive(Default)]
struct State {
    running: usize,
    keys: HashMap<String, KeyFlow>,
}

/// The least-served of `flows` (ties by name, so the order is deterministic).
fn least<'a, T>(flows: impl Iterator<Item = (&'a String, &'a Flow<T>)>) -> Option<String>
where
    T: 'a,
{
    flows
        .min_by(|a, b| a.1.served.total_cmp(&b.1.served).then(a.0.cmp(b.0)))
        .map(|(k, _)| k.clone())
}

impl State {
    /// The next job by the fair order, its flows charged for it; None when none waits.
    fn next(&mut self) -> Option<Job> {
        let key = least(self.keys.iter())?;
        let k = self.keys.get_mut(&key).expect("just found");
        let session = least(k.inner.iter()).expect("a key with no waiting session is removed");
        let s = k.inner.get_mut(&session).expect("just found");
        let (pixels, job) = s.inner.pop_front().expect("an empty session queue is removed");
        let cost = pixels.max(1) as f64;
        s.served += cost;
        k.served += cost;
        if s.inner.is_empty() {
            k.inner.remove(&session);
        }
        if k.inner.is_empty() {
            self.keys.remove(&key);
        }
        Some(job)
    }

    fn push(&mut self, share: Share, job: Job) {
        let floor = |served: &mut dyn Iterator<Item = f64>| served.fold(f64::INFINITY, f64::min);
        let key_floor = floor(&mut self.keys.values().map(|k| k.served));
        let k = self.keys.entry(share.key).or_insert_with(|| Flow {
            served: if key_floor.is_finite() { key_floor } else { 0.0 },
            inner: HashMap::new(),
        });
        let session_floor = floor(&mut k.inner.values().map(|s| s.served));
        let s = k.inner.entry(share.session).or_insert_with(|| Flow {
            served: if session_floor.is_finite() {
                session_floor
            } else {
                0.0
            },
            inner: VecDeque::new(),
        });
        s.inner.push_back((share.pixels, job));
    }
}

/// The fair queue in front of the filter pool (see the module).
#[derive(Clone)]
pub struct Scheduler {
    slots: usize,
    state: Arc<Mutex<State>>,
    run: Arc<dyn Fn(Job) + Send + Sync>,
}

impl Scheduler {
    /// At most `slots` jobs at once, each started by `run` (the pool's spawn).
    pub fn new(slots: usize, run: impl Fn(Box<dyn FnOnce() + Send>) + Send + Sync + 'static) -> Self {
        Scheduler {
            slots: slots.max(1),
            state: Arc::default(),
            run: Arc::new(run),
        }
    }

    /// Queues `job` for `share`; it runs when its turn comes.
    pub fn submit(&self, share: Share, job: impl FnOnce() + Send + 'static) {
        self.lock().push(share, Box::new(job));
        self.dispatch();
    }

    /// Jobs waiting for a slot.
    pub fn waiting(&self) -> usize {
        self.lock()
            .keys
            .values()
            .flat_map(|k| k.inner.values())
            .map(|s| s.inner.len())
            .sum()
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, State> {
        // Held only to move jobs in and out of the queues, never while one runs.
        self.state.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Starts jobs while slots are free.
    fn dispatch(&self) {
        loop {
            let job = {
                let mut st = self.lock();
                if st.running >= self.slots {
                    return;
                }
                let Some(job) = st.next() else { return };
                st.running += 1;
                job
            };
            let done = Done(self.clone());
            (self.run)(Box::new(move || {
                job();
                drop(done);
            }));
        }
    }
}

/// Gives a job's slot back and starts the next when dropped: after the job, or while a
/// panic unwinds out of it.
struct Done(Scheduler);

impl Drop for Done {
    fn drop(&mut self) {
        self.0.lock().running -= 1;
        self.0.dispatch();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::mpsc;

    /// A scheduler whose jobs run inline when dispatched, one slot, and a log of the order.
    fn inline() -> (Scheduler, Arc<Mutex<Vec<String>>>) {
        (Scheduler::new(1, |job| job()), Arc::default())
    }

    /// Starts a job of `key` that holds the only slot until the sender is used; the thread
    /// it runs on then runs the jobs queued meanwhile.
    fn hold_the_slot(s: &Scheduler, key: &str) -> (mpsc::Sender<()>, std::thread::JoinHandle<()>) {
        let (tx, rx) = mpsc::channel::<()>();
        let gate = Mutex::new(rx);
        let runner = {
            let (s, key) = (s.clone(), key.to_string());
            std::thread::spawn(move || {
                s.submit(share(&key, "blocker", 1), move || {
                    gate.lock().unwrap().recv().unwrap();
                })
            })
        };
        while s.lock().running == 0 {
            std::thread::yield_now();
        }
        (tx, runner)
    }

    fn share(key: &str, session: &str, pixels: u64) -> Share {
        Share {
            key: key.into(),
            session: session.into(),
            pixels,
        }
    }

    #[test]
    fn a_small_session_is_not_stuck_behind_a_large_ones_queue() {
        let (s, log) = inline();
        // A running job holds the only slot while the others queue.
        let (release, runner) = hold_the_slot(&s, "k");
        for i in 0..5 {
            let log = log.clone();
            s.submit(share("k", "4k", 3840 * 2160), move || {
                log.lock().unwrap().push(format!("4k{i}"))
            });
        }
        let l = log.clone();
        s.submit(share("k", "720p", 1280 * 720), move || {
            l.lock().unwrap().push("720p".into())
        });
        assert_eq!(s.waiting(), 6);
        release.send(()).unwrap();
        runner.join().unwrap();
        let order = log.lock().unwrap().clone();
        // Both start level; 4K's first frame is charged 9x what 720p's is, so 720p goes
        // second, not after the whole 4K queue (FIFO would run it last).
        assert_eq!(order, ["4k0", "720p", "4k1", "4k2", "4k3", "4k4"]);
    }

    #[test]
    fn keys_share_before_their_sessions_do() {
        let (s, log) = inline();
        let (release, runner) = hold_the_slot(&s, "a");
        // Key a has four sessions with two frames each, key b one session with two.
        for round in 0..2 {
            for session in ["a1", "a2", "a3", "a4"] {
                let l = log.clone();
                s.submit(share("a", session, 100), move || {
                    l.lock().unwrap().push(format!("{session}.{round}"))
                });
            }
        }
        for round in 0..2 {
            let l = log.clone();
            s.submit(share("b", "b1", 100), move || {
                l.lock().unwrap().push(format!("b1.{round}"))
            });
        }
        release.send(()).unwrap();
        runner.join().unwrap();
        let order = log.lock().unwrap().clone();
        // Key b gets every other job until its queue is empty, though key a has four
        // sessions waiting.
        let b_at: Vec<usize> = order
            .iter()
            .enumerate()
            .filter(|(_, n)| n.starts_with('b'))
            .map(|(i, _)| i)
            .collect();
        assert!(b_at[1] <= 3, "{order:?}");
        assert_eq!(order.len(), 10);
    }

    #[test]
    fn a_job_that_panics_gives_its_slot_back() {
        let s = Scheduler::new(1, |job| {
            let _ = std::panic::catch_unwind(std::panic::AssertUnwindSafe(job));
        });
        s.submit(share("k", "a", 1), || panic!("a job that panics"));
        let ran = Arc::new(Mutex::new(false));
        let r = ran.clone();
        s.submit(share("k", "b", 1), move || *r.lock().unwrap() = true);
        assert!(*ran.lock().unwrap(), "the next job ran in the freed slot");
        assert_eq!(s.lock().running, 0);
    }

    #[test]
    fn an_idle_flow_earns_no_credit() {
        let mut st = State::default();
        st.push(share("a", "s", 1000), Box::new(|| {}));
        let _ = st.next();
        st.push(share("a", "s", 1000), Box::new(|| {}));
        // Key b arrives after a has been served 1000: it starts level with the least
        // served waiting key (a, at 1000), not at 0.
        st.push(share("b", "t", 1000), Box::new(|| {}));
        assert_eq!(st.keys["b"].served, st.keys["a"].served);
    }
}
