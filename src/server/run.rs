//! Starting and stopping the servers: bind both ports, sweep idle sessions, and on
//! shutdown refuse new work, let frames in flight finish, and stop within the deadline.

use super::config::Config;
use super::grpc::Grpc;
use super::http::router;
use super::service::Service;
use std::future::Future;
use std::net::SocketAddr;
use std::time::Duration;
use thiserror::Error;
use tokio::net::TcpListener;
use tokio::sync::watch;
use tokio::task::JoinHandle;

/// Why the server could not start or stopped badly.
#[derive(Debug, Error)]
pub enum ServeError {
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
        let _ = self.stop.send(true);
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

/// Binds both ports (port 0 picks a free one) and serves in the background.
pub async fn start(config: Config) -> Result<Running, ServeError> {
    let grpc_l = bind(&config.grpc_addr, "gRPC").await?;
    let http_l = bind(&config.http_addr, "HTTP").await?;
    let grpc_addr = grpc_l.local_addr().map_err(|e| ServeError::Run(e.to_string()))?;
    let http_addr = http_l.local_addr().map_err(|e| ServeError::Run(e.to_string()))?;
    let deadline = Duration::from_secs(config.shutdown_deadline_s);
    let service = Service::new(config);
    let (stop, stopped) = watch::channel(false);
    let wait = |mut rx: watch::Receiver<bool>| async move {
        let _ = rx.wait_for(|s| *s).await;
    };
    let svc = service.clone();
    let sweeper = {
        let svc = service.clone();
        let mut rx = stopped.clone();
        tokio::spawn(async move {
            let mut tick = tokio::time::interval(Duration::from_secs(1));
            loop {
                tokio::select! {
                    _ = tick.tick() => { svc.sessions.evict_idle(); }
                    _ = rx.wait_for(|s| *s) => break,
                }
            }
        })
    };
    let grpc = tonic::transport::Server::builder()
        .initial_stream_window_size(super::wire::STREAM_WINDOW_BYTES)
        .initial_connection_window_size(super::wire::CONNECTION_WINDOW_BYTES)
        .tcp_nodelay(true)
        .add_service(Grpc(service.clone()).server())
        .serve_with_incoming_shutdown(
            tokio_stream::wrappers::TcpListenerStream::new(grpc_l),
            wait(stopped.clone()),
        );
    let http = axum::serve(http_l, router(service.clone())).with_graceful_shutdown(wait(stopped.clone()));
    let mut on_stop = stopped.clone();
    let task = tokio::spawn(async move {
        let grpc = tokio::spawn(grpc);
        let http = tokio::spawn(async move { http.await });
        let _ = on_stop.wait_for(|s| *s).await;
        svc.sessions.close_all_new_work();
        tracing::info!(
            deadline_s = deadline.as_secs(),
            "shutting down: refusing new work, finishing frames in flight"
        );
        let both = async {
            let g = grpc.await;
            let h = http.await;
            (g, h)
        };
        sweeper.abort();
        match tokio::time::timeout(deadline, both).await {
            Ok((g, h)) => {
                if let Ok(Err(e)) = g {
                    return Err(ServeError::Run(format!("gRPC: {e}")));
                }
                if let Ok(Err(e)) = h {
                    return Err(ServeError::Run(format!("HTTP: {e}")));
                }
                tracing::info!("stopped");
                Ok(())
            }
            Err(_) => {
                tracing::warn!("shutdown deadline passed with work in flight; stopping anyway");
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
