//! What a connection is doing, as its requests see it: how many are in flight, and when the
//! last one started or ended. A connection is idle when it has no request in flight, not
//! when no byte moves: HTTP/2 keepalive pings and their answers move bytes on a connection
//! that does nothing, and counting them let ping-answering connections stay forever.
//!
//! [`ActivityLayer`] marks every request (its response body included, so a reply being
//! written counts) on its connection's [`Activity`]; the listener's `Conn` closes the
//! connection by it.

use http_body::{Body, Frame, SizeHint};
use std::future::Future;
use std::pin::Pin;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};
use std::sync::Arc;
use std::task::{Context, Poll};
use std::time::Duration;
use tokio::time::Instant;

/// `last_ms` before the first request.
const NEVER: u64 = u64::MAX;

/// One connection's requests: in flight now, and when the last started or ended.
#[derive(Debug)]
pub struct Activity {
    born: Instant,
    in_flight: AtomicUsize,
    /// Milliseconds after `born` of the last request's start or end; [`NEVER`] before one.
    last_ms: AtomicU64,
}

impl Activity {
    /// A connection accepted now, with no request yet.
    pub fn new() -> Arc<Activity> {
        Arc::new(Activity {
            born: Instant::now(),
            in_flight: AtomicUsize::new(0),
            last_ms: AtomicU64::new(NEVER),
        })
    }

    fn touch(&self) {
        let ms = self.born.elapsed().as_millis().min(u128::from(NEVER - 1)) as u64;
        self.last_ms.store(ms, Ordering::SeqCst);
    }

    /// Marks a request in flight until the guard drops.
    pub fn begin(self: &Arc<Self>) -> RequestGuard {
        self.in_flight.fetch_add(1, Ordering::SeqCst);
        self.touch();
        RequestGuard(self.clone())
    }

    /// Requests in flight now.
    pub fn in_flight(&self) -> usize {
        self.in_flight.load(Ordering::SeqCst)
    }

    /// When the connection is due to close for doing nothing: `first` after it was
    /// accepted while it never made a request, else `idle` after its last request ended;
    /// `None` while a request is in flight (requests have deadlines of their own).
    pub fn due(&self, first: Duration, idle: Duration) -> Option<Instant> {
        if self.in_flight() > 0 {
            return None;
        }
        match self.last_ms.load(Ordering::SeqCst) {
            NEVER => Some(self.born + first),
            ms => Some(self.born + Duration::from_millis(ms) + idle),
        }
    }
}

/// A request in flight on a connection (see [`Activity::begin`]).
#[derive(Debug)]
pub struct RequestGuard(Arc<Activity>);

impl Drop for RequestGuard {
    fn drop(&mut self) {
        self.0.touch();
        self.0.in_flight.fetch_sub(1, Ordering::SeqCst);
    }
}

/// A response body that keeps what its request holds (its [`RequestGuard`], a memory
/// reservation) until the body has been read to its end or dropped.
pub struct Held<B, H> {
    body: B,
    hold: Option<H>,
}

impl<B, H> Held<B, H> {
    /// `body`, keeping `hold` while it is being sent.
    pub fn new(body: B, hold: H) -> Self {
        Held {
            body,
            hold: Some(hold),
        }
    }
}

impl<B: Body + Unpin, H: Unpin> Body for Held<B, H> {
    type Data = B::Data;
    type Error = B::Error;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Self::Data>, Self::Error>>> {
        let r = Pin::new(&mut self.body).poll_frame(cx);
        if let Poll::Ready(None) = r {
            self.hold = None;
        }
        r
    }

    fn is_end_stream(&self) -> bool {
        self.body.is_end_stream()
    }

    fn size_hint(&self) -> SizeHint {
        self.body.size_hint()
    }
}

/// Marks each request on its connection's [`Activity`]: the one given, or the one in the
/// request's extensions (tonic puts the connection's [`super::listener::ConnInfo`] there).
#[derive(Clone, Default)]
pub struct ActivityLayer {
    conn: Option<Arc<Activity>>,
}

impl ActivityLayer {
    /// For the requests of one connection (HTTP, where we serve each connection).
    pub fn for_conn(activity: Arc<Activity>) -> Self {
        ActivityLayer { conn: Some(activity) }
    }
}

impl<S> tower::Layer<S> for ActivityLayer {
    type Service = ActivityService<S>;
    fn layer(&self, inner: S) -> ActivityService<S> {
        ActivityService {
            inner,
            conn: self.conn.clone(),
        }
    }
}

/// See [`ActivityLayer`].
#[derive(Clone)]
pub struct ActivityService<S> {
    inner: S,
    conn: Option<Arc<Activity>>,
}

type BoxFuture<T> = Pin<Box<dyn Future<Output = T> + Send>>;

impl<S, B, RB> tower::Service<http::Request<B>> for ActivityService<S>
where
    S: tower::Service<http::Request<B>, Response = http::Response<RB>>,
    S::Future: Send + 'static,
    RB: Body + Unpin,
{
    type Response = http::Response<Held<RB, Option<RequestGuard>>>;
    type Error = S::Error;
    type Future = BoxFuture<Result<Self::Response, S::Error>>;

    fn poll_ready(&mut self, cx: &mut Context<'_>) -> Poll<Result<(), S::Error>> {
        self.inner.poll_ready(cx)
    }

    fn call(&mut self, req: http::Request<B>) -> Self::Future {
        let activity = self.conn.clone().or_else(|| {
            req.extensions()
                .get::<super::listener::ConnInfo>()
                .map(|c| c.activity.clone())
        });
        let guard = activity.map(|a| a.begin());
        let fut = self.inner.call(req);
        Box::pin(async move {
            let resp = fut.await?;
            Ok(resp.map(|b| Held::new(b, guard)))
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn idle_counts_from_the_last_request_not_from_bytes() {
        let (first, idle) = (Duration::from_secs(10), Duration::from_secs(120));
        let a = Activity::new();
        // No request yet: due at the first-request deadline.
        assert_eq!(a.due(first, idle), Some(a.born + first));
        let g = a.begin();
        assert_eq!(a.due(first, idle), None, "never due with a request in flight");
        tokio::time::sleep(Duration::from_millis(30)).await;
        assert_eq!(a.due(first, idle), None);
        let before_end = Instant::now();
        drop(g);
        // Due `idle` after the request ended (to the millisecond it is kept at).
        let due = a.due(first, idle).unwrap();
        assert!(due + Duration::from_millis(1) >= before_end + idle, "{due:?}");
        assert!(due <= Instant::now() + idle, "{due:?}");
    }

    #[tokio::test]
    async fn a_held_body_keeps_its_hold_until_read_to_the_end() {
        use http_body_util::BodyExt;
        let a = Activity::new();
        let body = Held::new(
            http_body_util::Full::new(bytes::Bytes::from_static(b"abc")),
            Some(a.begin()),
        );
        assert_eq!(a.in_flight(), 1);
        let mut body = body;
        let frame = body.frame().await.unwrap().unwrap();
        assert_eq!(frame.into_data().unwrap().as_ref(), b"abc");
        assert_eq!(a.in_flight(), 1, "held while the body may still have frames");
        assert!(body.frame().await.is_none());
        assert_eq!(a.in_flight(), 0, "given back at the end");
    }
}
