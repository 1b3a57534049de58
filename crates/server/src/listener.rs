//! Accepting connections for both ports: a cap on connections open at once (over both),
//! and a smaller one per client address, TCP keepalive, an optional TLS handshake (rustls)
//! with a deadline, and connections that close themselves when they do nothing: no request
//! within the header timeout of being accepted, or none in flight for the idle timeout
//! ([`Activity`]: HTTP/2 pings and their answers are not requests), or a reply the client
//! has not read for the idle timeout. Ready connections go to the HTTP server
//! ([`serve_http`]) or to tonic (as a stream of [`Conn`]).

use super::activity::{Activity, ActivityLayer};
use super::metrics::Metrics;
use axum::Router;
use hyper_util::rt::{TokioExecutor, TokioIo, TokioTimer};
use hyper_util::server::conn::auto;
use hyper_util::service::TowerToHyperService;
use std::collections::HashMap;
use std::future::Future;
use std::io;
use std::net::{IpAddr, SocketAddr};
use std::pin::Pin;
use std::sync::{Arc, Mutex};
use std::task::{Context, Poll};
use std::time::Duration;
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{mpsc, watch, OwnedSemaphorePermit, Semaphore};
use tokio::time::{Instant, Sleep};
use tokio_rustls::rustls;
use tokio_rustls::TlsAcceptor;

/// Completes when `rx` holds true (the guard `wait_for` returns is not kept, so the
/// future stays `Send` inside `select!`).
pub async fn until_true(rx: &mut watch::Receiver<bool>) {
    let _ = rx.wait_for(|v| *v).await;
}

/// How connections are accepted and kept.
#[derive(Clone)]
pub struct ConnSettings {
    /// Permits for connections open at once, shared by both ports.
    pub slots: Arc<Semaphore>,
    /// Connections open at once per client address, shared by both ports.
    pub per_ip: Arc<PerIp>,
    /// Time to finish the TLS handshake and start the first request.
    pub first_byte: Duration,
    /// Time without a request in flight, or with a reply the client does not read,
    /// before a connection is closed.
    pub idle: Duration,
    /// TLS, when configured.
    pub tls: Option<TlsAcceptor>,
}

/// Loads a PEM certificate chain and private key into a TLS acceptor offering `alpn`.
pub fn tls_acceptor(cert: &str, key: &str, alpn: &[&[u8]]) -> Result<TlsAcceptor, String> {
    use rustls_pki_types::pem::PemObject;
    use rustls_pki_types::{CertificateDer, PrivateKeyDer};
    let certs = CertificateDer::pem_file_iter(cert)
        .and_then(|it| it.collect::<Result<Vec<_>, _>>())
        .map_err(|e| format!("tls_cert {cert}: {e}"))?;
    if certs.is_empty() {
        return Err(format!("tls_cert {cert}: no certificate in the file"));
    }
    let key_der = PrivateKeyDer::from_pem_file(key).map_err(|e| format!("tls_key {key}: {e}"))?;
    let provider = Arc::new(rustls::crypto::ring::default_provider());
    let mut config = rustls::ServerConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .map_err(|e| format!("TLS: {e}"))?
        .with_no_client_auth()
        .with_single_cert(certs, key_der)
        .map_err(|e| format!("tls_cert {cert} with tls_key {key}: {e}"))?;
    config.alpn_protocols = alpn.iter().map(|p| p.to_vec()).collect();
    Ok(TlsAcceptor::from(Arc::new(config)))
}

/// Connections open per client address: one client cannot take every slot.
#[derive(Debug)]
pub struct PerIp {
    max: usize,
    open: Mutex<HashMap<IpAddr, usize>>,
}

impl PerIp {
    /// At most `max` connections from one address.
    pub fn new(max: usize) -> Arc<PerIp> {
        Arc::new(PerIp {
            max,
            open: Mutex::new(HashMap::new()),
        })
    }

    /// A slot for a connection from `ip`, or None when it has `max` open.
    fn take(self: &Arc<Self>, ip: IpAddr) -> Option<IpSlot> {
        // A short critical section with no await and no other lock inside.
        let mut open = self.open.lock().unwrap_or_else(|p| p.into_inner());
        let n = open.entry(ip).or_insert(0);
        if *n >= self.max {
            return None;
        }
        *n += 1;
        Some(IpSlot(self.clone(), ip))
    }
}

/// A connection counted against its address until dropped.
struct IpSlot(Arc<PerIp>, IpAddr);

impl Drop for IpSlot {
    fn drop(&mut self) {
        let mut open = self.0.open.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(n) = open.get_mut(&self.1) {
            *n -= 1;
            if *n == 0 {
                open.remove(&self.1);
            }
        }
    }
}

enum Io {
    Plain(TcpStream),
    Tls(Box<tokio_rustls::server::TlsStream<TcpStream>>),
}

/// An accepted connection: counts against the caps until dropped, and fails its reads and
/// writes with `TimedOut` once it does nothing: no request within the first-request
/// deadline, none in flight for the idle timeout (see [`Activity`]), or a reply the
/// client has not taken a byte of for the idle timeout.
pub struct Conn {
    io: Io,
    remote: SocketAddr,
    activity: Arc<Activity>,
    deadline: Pin<Box<Sleep>>,
    first: Duration,
    idle: Duration,
    /// Since when a write has been waiting for the client to read.
    stalled_since: Option<Instant>,
    _slot: OwnedSemaphorePermit,
    _ip: IpSlot,
}

/// What tonic is told about a connection (and puts in each request's extensions).
#[derive(Clone, Debug)]
pub struct ConnInfo {
    /// The peer.
    pub remote: SocketAddr,
    /// The connection's requests.
    pub activity: Arc<Activity>,
}

impl tonic::transport::server::Connected for Conn {
    type ConnectInfo = ConnInfo;
    fn connect_info(&self) -> ConnInfo {
        ConnInfo {
            remote: self.remote,
            activity: self.activity.clone(),
        }
    }
}

impl Conn {
    /// The connection's requests (see [`ActivityLayer`]).
    pub fn activity(&self) -> Arc<Activity> {
        self.activity.clone()
    }

    /// A write's result: a write that cannot go on starts (or continues) a stall, which
    /// is subject to the deadline (a client that stops reading).
    fn after_write(&mut self, cx: &mut Context<'_>, r: Poll<io::Result<usize>>) -> Poll<io::Result<usize>> {
        match r {
            Poll::Ready(Ok(n)) => {
                if n > 0 {
                    self.stalled_since = None;
                }
                Poll::Ready(Ok(n))
            }
            Poll::Pending => {
                self.stalled_since.get_or_insert_with(Instant::now);
                self.quiet_too_long(cx)
            }
            other => other,
        }
    }

    /// After a pending read or write: a timeout error once the connection is due (the
    /// timer wakes the task at the earliest time it can be, and is set again from there
    /// while it is not).
    fn quiet_too_long<T>(&mut self, cx: &mut Context<'_>) -> Poll<io::Result<T>> {
        while self.deadline.as_mut().poll(cx).is_ready() {
            let now = Instant::now();
            let mut due = self
                .activity
                .due(self.first, self.idle)
                .unwrap_or(now + self.idle);
            if let Some(since) = self.stalled_since {
                due = due.min(since + self.idle);
            }
            if due <= now {
                return Poll::Ready(Err(io::Error::new(
                    io::ErrorKind::TimedOut,
                    "connection idle for too long",
                )));
            }
            self.deadline.as_mut().reset(due);
        }
        Poll::Pending
    }
}

impl AsyncRead for Conn {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let r = match &mut self.io {
            Io::Plain(s) => Pin::new(s).poll_read(cx, buf),
            Io::Tls(s) => Pin::new(s.as_mut()).poll_read(cx, buf),
        };
        match r {
            Poll::Pending => self.quiet_too_long(cx),
            other => other,
        }
    }
}

impl AsyncWrite for Conn {
    fn poll_write(mut self: Pin<&mut Self>, cx: &mut Context<'_>, data: &[u8]) -> Poll<io::Result<usize>> {
        let r = match &mut self.io {
            Io::Plain(s) => Pin::new(s).poll_write(cx, data),
            Io::Tls(s) => Pin::new(s.as_mut()).poll_write(cx, data),
        };
        self.after_write(cx, r)
    }

    fn poll_write_vectored(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[io::IoSlice<'_>],
    ) -> Poll<io::Result<usize>> {
        let r = match &mut self.io {
            Io::Plain(s) => Pin::new(s).poll_write_vectored(cx, bufs),
            Io::Tls(s) => Pin::new(s.as_mut()).poll_write_vectored(cx, bufs),
        };
        self.after_write(cx, r)
    }

    fn is_write_vectored(&self) -> bool {
        match &self.io {
            Io::Plain(s) => s.is_write_vectored(),
            Io::Tls(s) => s.is_write_vectored(),
        }
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        match &mut self.io {
            Io::Plain(s) => Pin::new(s).poll_flush(cx),
            Io::Tls(s) => Pin::new(s.as_mut()).poll_flush(cx),
        }
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        match &mut self.io {
            Io::Plain(s) => Pin::new(s).poll_shutdown(cx),
            Io::Tls(s) => Pin::new(s.as_mut()).poll_shutdown(cx),
        }
    }
}

/// Accepts on `listener` until `stop` turns true; every connection that gets a slot (of
/// the server's and of its address's) and finishes its TLS handshake in time comes out of
/// the returned channel. `what` names the
/// port in logs. The task ends, and the listener is closed, when `stop` turns true:
/// await the returned handle to know the port no longer accepts.
pub fn accept(
    listener: TcpListener,
    settings: ConnSettings,
    metrics: Arc<Metrics>,
    mut stop: watch::Receiver<bool>,
    what: &'static str,
) -> (mpsc::Receiver<Conn>, tokio::task::JoinHandle<()>) {
    let (tx, rx) = mpsc::channel::<Conn>(64);
    let task = tokio::spawn(async move {
        loop {
            let (tcp, remote) = tokio::select! {
                r = listener.accept() => match r {
                    Ok(c) => c,
                    Err(e) => {
                        // Out of file descriptors and the like: wait a little, go on.
                        tracing::warn!(port = what, error = %e, "accept failed");
                        tokio::time::sleep(Duration::from_millis(50)).await;
                        continue;
                    }
                },
                _ = until_true(&mut stop) => break,
            };
            let Ok(slot) = settings.slots.clone().try_acquire_owned() else {
                metrics.error("too_many_connections");
                tracing::warn!(port = what, %remote, "connection refused: max_connections are open");
                drop(tcp);
                continue;
            };
            let Some(ip_slot) = settings.per_ip.take(remote.ip()) else {
                metrics.error("too_many_connections_per_client");
                tracing::warn!(port = what, %remote, "connection refused: max_connections_per_client are open from this address");
                drop(tcp);
                continue;
            };
            let (settings, tx) = (settings.clone(), tx.clone());
            tokio::spawn(async move {
                let _ = tcp.set_nodelay(true);
                let keepalive = socket2::TcpKeepalive::new()
                    .with_time(Duration::from_secs(60))
                    .with_interval(Duration::from_secs(10));
                let _ = socket2::SockRef::from(&tcp).set_tcp_keepalive(&keepalive);
                let io = match &settings.tls {
                    None => Io::Plain(tcp),
                    Some(acceptor) => {
                        match tokio::time::timeout(settings.first_byte, acceptor.accept(tcp)).await {
                            Ok(Ok(s)) => Io::Tls(Box::new(s)),
                            Ok(Err(e)) => {
                                tracing::debug!(port = what, %remote, error = %e, "TLS handshake failed");
                                return;
                            }
                            Err(_) => {
                                tracing::debug!(port = what, %remote, "TLS handshake timed out");
                                return;
                            }
                        }
                    }
                };
                let activity = Activity::new();
                let conn = Conn {
                    io,
                    remote,
                    deadline: Box::pin(tokio::time::sleep(settings.first_byte)),
                    first: settings.first_byte,
                    idle: settings.idle,
                    activity,
                    stalled_since: None,
                    _slot: slot,
                    _ip: ip_slot,
                };
                let _ = tx.send(conn).await;
            });
        }
    });
    (rx, task)
}

/// HTTP/1 and HTTP/2 limits of the HTTP port.
#[derive(Clone, Copy, Debug)]
pub struct HttpSettings {
    /// Time to receive a request's headers (HTTP/1; also the keep-alive wait).
    pub header_timeout: Duration,
    /// HTTP/2 keepalive ping interval.
    pub keepalive_interval: Duration,
    /// HTTP/2 keepalive ping answer timeout.
    pub keepalive_timeout: Duration,
    /// HTTP/2 streams per connection.
    pub max_concurrent_streams: u32,
}

/// Serves `router` on every connection from `conns` (HTTP/1.1 or HTTP/2, by what the
/// client speaks) until `stop` turns true, then lets open requests finish (the caller
/// bounds the wait).
pub async fn serve_http(
    mut conns: mpsc::Receiver<Conn>,
    router: Router,
    settings: HttpSettings,
    mut stop: watch::Receiver<bool>,
) {
    let mut builder = auto::Builder::new(TokioExecutor::new());
    builder
        .http1()
        .timer(TokioTimer::new())
        .header_read_timeout(settings.header_timeout)
        .max_buf_size(64 << 10);
    builder
        .http2()
        .timer(TokioTimer::new())
        .keep_alive_interval(settings.keepalive_interval)
        .keep_alive_timeout(settings.keepalive_timeout)
        .max_concurrent_streams(settings.max_concurrent_streams)
        .max_header_list_size(64 << 10);
    let graceful = hyper_util::server::graceful::GracefulShutdown::new();
    loop {
        let conn = tokio::select! {
            c = conns.recv() => match c {
                Some(c) => c,
                None => break,
            },
            _ = until_true(&mut stop) => break,
        };
        let service = TowerToHyperService::new(
            tower::ServiceBuilder::new()
                .layer(ActivityLayer::for_conn(conn.activity()))
                .service(router.clone()),
        );
        let served = builder.serve_connection(TokioIo::new(conn), service).into_owned();
        let watched = graceful.watch(served);
        tokio::spawn(async move {
            if let Err(e) = watched.await {
                tracing::debug!(error = %e, "HTTP connection ended with an error");
            }
        });
    }
    graceful.shutdown().await;
}
