//! Starting and stopping the servers: check the config (no public address without API
//! keys unless told), bind both ports, sweep idle sessions, and on shutdown drain: refuse
//! new work (`/readyz` turns 503), let frames in flight finish, then close the listeners,
//! all within the deadline. Next to the protocol, the gRPC port serves `grpc.health.v1`
//! (NOT_SERVING from the drain on, as `/readyz`) and, unless `grpc_reflection = false`,
//! server reflection.

use super::activity::ActivityLayer;
use super::config::Config;
use super::grpc::{health, reflection, Grpc};
use super::http::router;
use super::listener::{accept, serve_http, tls_acceptor, ConnSettings, HttpSettings, PerIp};
use super::service::Service;
use super::stream_route::StreamRouteLayer;
use crate::session::Keyring;
use std::future::Future;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;
use thiserror::Error;
use tokio::net::TcpListener;
use tokio::sync::{watch, Semaphore};
use tokio::task::JoinHandle;
use tokio_stream::StreamExt;

/// Why the server could not start or stopped badly.
#[derive(Debug, Error)]
pub enum ServeError {
    /// The configuration cannot be served (keys, TLS, public address without keys).
    #[error("{0}")]
    Config(String),
    /// A port could not be bound.
    #[error("cannot listen on {addr} ({what}): {source}")]
    Bind {
        /// The address.
        addr: String,
        /// gRPC or HTTP.
        what: &'static str,
        /// Why.
        source: std::io::Error,
    },
    /// A server failed while running.
    #[error("{0}")]
    Run(String),
}

/// A started server.
pub struct Running {
    /// Where gRPC listens.
    pub grpc_addr: SocketAddr,
    /// Where HTTP listens.
    pub http_addr: SocketAddr,
    /// The service (for tests and metrics).
    pub service: Service,
    stop: watch::Sender<bool>,
    task: JoinHandle<Result<(), ServeError>>,
}

impl Running {
    /// Asks the server to stop and waits for it (at most the configured deadline).
    pub async fn shutdown(self) -> Result<(), ServeError> {
        self.begin_shutdown();
        self.stopped().await
    }

    /// Asks the server to stop (drain, then close) without waiting.
    pub fn begin_shutdown(&self) {
        let _ = self.stop.send(true);
    }

    /// Waits until the server has stopped.
    pub async fn stopped(self) -> Result<(), ServeError> {
        self.task
            .await
            .map_err(|e| ServeError::Run(format!("server task: {e}")))?
    }
}

async fn bind(addr: &str, what: &'static str) -> Result<TcpListener, ServeError> {
    TcpListener::bind(addr).await.map_err(|source| ServeError::Bind {
        addr: addr.to_string(),
        what,
        source,
    })
}

/// The configured API keys; none is refused where a port is reachable from other machines,
/// unless `allow_unauthenticated` says so.
fn keyring(config: &Config) -> Result<Keyring, ServeError> {
    let keys = config.keyring().map_err(|e| ServeError::Config(e.to_string()))?;
    let public = config.public_addrs();
    if keys.is_empty() && !public.is_empty() && !config.allow_unauthenticated {
        return Err(ServeError::Config(format!(
            "refusing to serve {} without API keys: set api_keys_file or AFTERIMAGE_API_KEYS, listen on a loopback address, or set allow_unauthenticated = true",
            public.join(" and ")
        )));
    }
    Ok(keys)
}

/// Evicts idle sessions once a second until `stopped` turns true.
fn spawn_sweeper(svc: Service, mut stopped: watch::Receiver<bool>) -> JoinHandle<()> {
    tokio::spawn(async move {
        let mut tick = tokio::time::interval(Duration::from_secs(1));
        loop {
            tokio::select! {
                _ = tick.tick() => { svc.sessions.evict_idle(); }
                _ = stopped.wait_for(|s| *s) => break,
            }
        }
    })
}

/// Binds both ports (port 0 picks a free one) and serves in the background.
pub async fn start(config: Config) -> Result<Running, ServeError> {
    let keys = keyring(&config)?;
    let tls = |alpn: &[&[u8]]| -> Result<_, ServeError> {
        if config.tls_cert.is_empty() {
            return Ok(None);
        }
        tls_acceptor(&config.tls_cert, &config.tls_key, alpn)
            .map(Some)
            .map_err(ServeError::Config)
    };
    let grpc_tls = tls(&[b"h2"])?;
    let http_tls = tls(&[b"h2", b"http/1.1"])?;
    let grpc_l = bind(&config.grpc_addr, "gRPC").await?;
    let http_l = bind(&config.http_addr, "HTTP").await?;
    let grpc_addr = grpc_l.local_addr().map_err(|e| ServeError::Run(e.to_string()))?;
    let http_addr = http_l.local_addr().map_err(|e| ServeError::Run(e.to_string()))?;
    let deadline = Duration::from_secs(config.shutdown_deadline_s);
    let conn = ConnSettings {
        slots: Arc::new(Semaphore::new(config.max_connections)),
        per_ip: PerIp::new(config.connections_per_client()),
        first_byte: Duration::from_secs(config.header_timeout_s),
        idle: Duration::from_secs(config.idle_connection_timeout_s),
        tls: None,
    };
    let http_settings = HttpSettings {
        header_timeout: Duration::from_secs(config.header_timeout_s),
        keepalive_interval: Duration::from_secs(config.keepalive_interval_s),
        keepalive_timeout: Duration::from_secs(config.keepalive_timeout_s),
        max_concurrent_streams: config.max_concurrent_streams,
    };
    let grpc_builder = tonic::transport::Server::builder()
        .initial_stream_window_size(super::wire::STREAM_WINDOW_BYTES)
        .initial_connection_window_size(super::wire::CONNECTION_WINDOW_BYTES)
        .max_frame_size(super::wire::MAX_FRAME_BYTES)
        .http2_keepalive_interval(Some(Duration::from_secs(config.keepalive_interval_s)))
        .http2_keepalive_timeout(Some(Duration::from_secs(config.keepalive_timeout_s)))
        .max_concurrent_streams(config.max_concurrent_streams)
        .http2_max_header_list_size(64 << 10)
        .layer(ActivityLayer::default());
    let (reflection_v1, reflection_v1alpha) = config
        .grpc_reflection
        .then(reflection)
        .transpose()
        .map_err(|e| ServeError::Run(format!("gRPC reflection: {e}")))?
        .unzip();
    let service = Service::new(config, keys);
    let (stop, stopped) = watch::channel(false);
    // Closing the listeners comes after the drain, so it has a signal of its own.
    let (close, closed) = watch::channel(false);
    let health = health(&service, closed.clone()).await;
    let sweeper = spawn_sweeper(service.clone(), stopped.clone());
    let (grpc_conns, grpc_accept) = accept(
        grpc_l,
        ConnSettings {
            tls: grpc_tls,
            ..conn.clone()
        },
        service.metrics.clone(),
        closed.clone(),
        "gRPC",
    );
    let (http_conns, http_accept) = accept(
        http_l,
        ConnSettings {
            tls: http_tls,
            ..conn
        },
        service.metrics.clone(),
        closed.clone(),
        "HTTP",
    );
    let grpc = {
        let mut closed = closed.clone();
        grpc_builder
            .layer(StreamRouteLayer(Grpc(service.clone())))
            .add_service(Grpc(service.clone()).server())
            .add_service(health)
            .add_optional_service(reflection_v1)
            .add_optional_service(reflection_v1alpha)
            .serve_with_incoming_shutdown(
                tokio_stream::wrappers::ReceiverStream::new(grpc_conns).map(Ok::<_, std::io::Error>),
                async move {
                    let _ = closed.wait_for(|c| *c).await;
                },
            )
    };
    let http = serve_http(http_conns, router(service.clone()), http_settings, closed);
    let svc = service.clone();
    let mut on_stop = stopped;
    let task = tokio::spawn(async move {
        let grpc = tokio::spawn(grpc);
        let http = tokio::spawn(http);
        let _ = on_stop.wait_for(|s| *s).await;
        sweeper.abort();
        let started = tokio::time::Instant::now();
        svc.drain();
        tracing::info!(
            deadline_s = deadline.as_secs(),
            in_flight = svc.in_flight(),
            "draining: refusing new work, /readyz is 503, finishing frames in flight"
        );
        while svc.in_flight() > 0 && started.elapsed() < deadline {
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
        // Shared memory regions are files on a tmpfs: they would outlive the process.
        svc.sessions.close_regions();
        let _ = close.send(true);
        let left = deadline.saturating_sub(started.elapsed());
        // The accept loops close their listeners on `close`; waiting for them means a
        // stopped server's ports refuse connections.
        let served = async { (grpc.await, http.await, grpc_accept.await, http_accept.await) };
        match tokio::time::timeout(left, served).await {
            Ok((g, h, _, _)) => {
                if let Ok(Err(e)) = g {
                    return Err(ServeError::Run(format!("gRPC: {e}")));
                }
                if let Err(e) = h {
                    return Err(ServeError::Run(format!("HTTP: {e}")));
                }
                tracing::info!("stopped");
                Ok(())
            }
            Err(_) => {
                tracing::warn!(
                    in_flight = svc.in_flight(),
                    "shutdown deadline passed with work in flight; stopping anyway"
                );
                Ok(())
            }
        }
    });
    tracing::info!(%grpc_addr, %http_addr, "afterimage serving");
    Ok(Running {
        grpc_addr,
        http_addr,
        service,
        stop,
        task,
    })
}

/// Serves until `signal` completes, then shuts down gracefully.
pub async fn serve(config: Config, signal: impl Future<Output = ()>) -> Result<(), ServeError> {
    let running = start(config).await?;
    signal.await;
    running.shutdown().await
}

/// Completes on SIGINT (Ctrl-C) or SIGTERM.
pub async fn shutdown_signal() {
    let ctrl_c = async {
        let _ = tokio::signal::ctrl_c().await;
    };
    #[cfg(unix)]
    let term = async {
        match tokio::signal::unix::signal(tokio::signal::unix::SignalKind::terminate()) {
            Ok(mut s) => {
                s.recv().await;
            }
            Err(_) => std::future::pending::<()>().await,
        }
    };
    #[cfg(not(unix))]
    let term = std::future::pending::<()>();
    tokio::select! {
        _ = ctrl_c => {},
        _ = term => {},
    }
}
