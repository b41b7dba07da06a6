//! The gRPC side of the observer: the `biotracker.Observer` service the tracker core calls, a
//! client for calls the other way (the heartbeat to the core), and a stand-in for the core's
//! heartbeat service (for tests, the benchmark and trying things without BioTracker).
//!
//! The service is written by hand over tonic's unary handler and prost's codec (what a
//! generator would emit for two methods), so building fishprobe needs no `protoc`.

use super::schema::{ComponentConfig, Empty, Experiment};
use std::future::Future;
use std::net::SocketAddr;
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};
use std::time::Duration;
use tonic::{Request, Response, Status};

/// `biotracker.Observer/set_config`.
pub const SET_CONFIG_PATH: &str = "/biotracker.Observer/set_config";
/// `biotracker.Observer/update`.
pub const UPDATE_PATH: &str = "/biotracker.Observer/update";
/// `biotracker.BioTracker/heartbeat`.
pub const HEARTBEAT_PATH: &str = "/biotracker.BioTracker/heartbeat";

type BoxFuture<T> = Pin<Box<dyn Future<Output = Result<T, std::convert::Infallible>> + Send>>;

/// What answers the observer's two calls. Both must return at once: the core calls `update`
/// from its tracking loop, once per frame.
pub trait ObserverCalls: Send + Sync + 'static {
    /// The component's configuration (once after connecting, again when the user edits it).
    fn set_config(&self, config: ComponentConfig) -> Result<(), Status>;
    /// One tracked frame.
    fn update(&self, experiment: Experiment) -> Result<(), Status>;
}

/// One method's handler: the HTTP request in, the gRPC answer out.
type Handler = dyn Fn(http::Request<tonic::body::Body>) -> BoxFuture<http::Response<tonic::body::Body>>
    + Send
    + Sync;

/// A gRPC service of unary methods, each a path and a handler that answers at once: the
/// observer, the stand-in core's heartbeat, and whatever else a test needs to serve (a
/// feature detector, say). Any other path is answered `unimplemented`, naming the ones served.
#[derive(Clone)]
pub struct Methods {
    what: &'static str,
    routes: Vec<(&'static str, Arc<Handler>)>,
}

impl std::fmt::Debug for Methods {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let paths: Vec<&str> = self.routes.iter().map(|(p, _)| *p).collect();
        f.debug_struct("Methods")
            .field("what", &self.what)
            .field("paths", &paths)
            .finish()
    }
}

impl Methods {
    /// No methods yet; `what` names the service in the answer to an unknown path.
    pub fn new(what: &'static str) -> Self {
        Self {
            what,
            routes: Vec::new(),
        }
    }

    /// Adds the unary method `path`: a request of at most `max_message_bytes` (a larger one
    /// is answered with an error without being decoded) is decoded and handed to `handle`.
    #[must_use]
    pub fn unary<M1, M2, F>(self, path: &'static str, max_message_bytes: usize, handle: F) -> Self
    where
        M1: prost::Message + Default + Send + 'static,
        M2: prost::Message + Send + 'static,
        F: Fn(M1) -> Result<M2, Status> + Send + Sync + 'static,
    {
        self.route(path, max_message_bytes, handle, false)
    }

    /// Adds the unary method `path` whose `handle` may take long (it loads files): it runs on a
    /// blocking thread of its own, so the server answers the other methods meanwhile (the
    /// core's `update`s keep flowing while a `set_config` loads a policy).
    #[must_use]
    pub fn unary_blocking<M1, M2, F>(
        self,
        path: &'static str,
        max_message_bytes: usize,
        handle: F,
    ) -> Self
    where
        M1: prost::Message + Default + Send + 'static,
        M2: prost::Message + Send + 'static,
        F: Fn(M1) -> Result<M2, Status> + Send + Sync + 'static,
    {
        self.route(path, max_message_bytes, handle, true)
    }

    /// The route of a unary method: decoded within the size limit, then handled in the
    /// server's task or (`blocking`) on a blocking thread.
    fn route<M1, M2, F>(
        mut self,
        path: &'static str,
        max_message_bytes: usize,
        handle: F,
        blocking: bool,
    ) -> Self
    where
        M1: prost::Message + Default + Send + 'static,
        M2: prost::Message + Send + 'static,
        F: Fn(M1) -> Result<M2, Status> + Send + Sync + 'static,
    {
        let handle = Arc::new(handle);
        let route = move |req: http::Request<tonic::body::Body>| -> BoxFuture<_> {
            let handle = Arc::clone(&handle);
            Box::pin(async move {
                let mut grpc =
                    tonic::server::Grpc::new(tonic_prost::ProstCodec::<M2, M1>::default())
                        .max_decoding_message_size(max_message_bytes);
                Ok(if blocking {
                    grpc.unary(Blocking(handle), req).await
                } else {
                    grpc.unary(Unary(move |m| handle(m)), req).await
                })
            })
        };
        self.routes.push((path, Arc::new(route)));
        self
    }
}

/// A unary method run on a blocking thread (see [`Methods::unary_blocking`]).
struct Blocking<F>(Arc<F>);

impl<M1, M2, F> tower_service::Service<Request<M1>> for Blocking<F>
where
    M1: Send + 'static,
    M2: Send + 'static,
    F: Fn(M1) -> Result<M2, Status> + Send + Sync + 'static,
{
    type Response = Response<M2>;
    type Error = Status;
    type Future = Pin<Box<dyn Future<Output = Result<Response<M2>, Status>> + Send>>;

    fn poll_ready(&mut self, _cx: &mut Context<'_>) -> Poll<Result<(), Status>> {
        Poll::Ready(Ok(()))
    }

    fn call(&mut self, request: Request<M1>) -> Self::Future {
        let f = Arc::clone(&self.0);
        Box::pin(async move {
            let m = request.into_inner();
            match tokio::task::spawn_blocking(move || f(m)).await {
                Ok(r) => r.map(Response::new),
                Err(e) => Err(Status::internal(format!("the handler failed: {e}"))),
            }
        })
    }
}

/// The `biotracker.Observer` service over an [`ObserverCalls`]; a request larger than
/// `max_message_bytes` is answered with an error without being decoded. `set_config` runs on a
/// blocking thread (it loads the policy), so `update`s are answered meanwhile.
pub fn observer_service(calls: Arc<dyn ObserverCalls>, max_message_bytes: usize) -> Methods {
    let other = Arc::clone(&calls);
    Methods::new("fishprobe's observer")
        .unary_blocking(SET_CONFIG_PATH, max_message_bytes, move |c| {
            calls.set_config(c).map(|()| Empty {})
        })
        .unary(UPDATE_PATH, max_message_bytes, move |e| {
            other.update(e).map(|()| Empty {})
        })
}

/// The core's heartbeat, as a stand-in for BioTracker's core: answers
/// `biotracker.BioTracker/heartbeat` and nothing else.
pub fn heartbeat_service() -> Methods {
    // An empty message: the smallest limit the codec takes.
    Methods::new("this stand-in core").unary(HEARTBEAT_PATH, 4096, |_: Empty| Ok(Empty {}))
}

/// A unary method as a tower service: the message in, the answer or an error out, at once.
struct Unary<F>(F);

impl<M1, M2, F> tower_service::Service<Request<M1>> for Unary<F>
where
    F: FnMut(M1) -> Result<M2, Status>,
{
    type Response = Response<M2>;
    type Error = Status;
    type Future = std::future::Ready<Result<Response<M2>, Status>>;

    fn poll_ready(&mut self, _cx: &mut Context<'_>) -> Poll<Result<(), Status>> {
        Poll::Ready(Ok(()))
    }

    fn call(&mut self, request: Request<M1>) -> Self::Future {
        std::future::ready((self.0)(request.into_inner()).map(Response::new))
    }
}

impl tower_service::Service<http::Request<tonic::body::Body>> for Methods {
    type Response = http::Response<tonic::body::Body>;
    type Error = std::convert::Infallible;
    type Future = BoxFuture<Self::Response>;

    fn poll_ready(&mut self, _cx: &mut Context<'_>) -> Poll<Result<(), Self::Error>> {
        Poll::Ready(Ok(()))
    }

    fn call(&mut self, req: http::Request<tonic::body::Body>) -> Self::Future {
        let path = req.uri().path();
        if let Some((_, route)) = self.routes.iter().find(|(p, _)| *p == path) {
            return route(req);
        }
        let served: Vec<&str> = self.routes.iter().map(|(p, _)| *p).collect();
        let status = Status::unimplemented(format!(
            "{} serves {}, not {path}",
            self.what,
            served.join(" and ")
        ));
        Box::pin(async move { Ok(status.into_http()) })
    }
}

/// How many connections the gRPC port holds and how long an idle one lives. Every connection
/// costs a file descriptor; without a cap, idle peers could take the descriptors the trial
/// file needs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ConnectionLimits {
    /// Connections held at once at most; one more closes the connection that has been
    /// silent longest (a tracker sends every frame, so its connection is never that one).
    pub max_connections: usize,
    /// A new connection must send its first bytes within this long (s).
    pub first_bytes_s: f64,
    /// A connection that sends nothing for this long (s) is closed.
    pub idle_s: f64,
    /// The server pings each connection this often (s), so a live peer's transport answers
    /// and is never idle while one that cannot answer is.
    pub keepalive_s: f64,
}

impl Default for ConnectionLimits {
    /// The observer's defaults (see [`super::component::ComponentGuard`]).
    fn default() -> Self {
        super::component::ComponentGuard::default().connection_limits()
    }
}

/// Serves `service` (a [`Methods`], or any tonic service) over HTTP/2 on `listener` until
/// `shutdown` resolves, with the default [`ConnectionLimits`].
pub async fn serve<S>(
    listener: std::net::TcpListener,
    service: S,
    shutdown: impl Future<Output = ()>,
) -> Result<(), crate::LiveError>
where
    S: tower_service::Service<
            http::Request<tonic::body::Body>,
            Response = http::Response<tonic::body::Body>,
            Error = std::convert::Infallible,
        > + Clone
        + Send
        + 'static,
    S::Future: Send + 'static,
{
    serve_with(listener, service, ConnectionLimits::default(), shutdown).await
}

/// [`serve`] with the given connection limits.
pub async fn serve_with<S>(
    listener: std::net::TcpListener,
    service: S,
    limits: ConnectionLimits,
    shutdown: impl Future<Output = ()>,
) -> Result<(), crate::LiveError>
where
    S: tower_service::Service<
            http::Request<tonic::body::Body>,
            Response = http::Response<tonic::body::Body>,
            Error = std::convert::Infallible,
        > + Clone
        + Send
        + 'static,
    S::Future: Send + 'static,
{
    let net = |e: &dyn std::fmt::Display| crate::LiveError::Net(format!("gRPC server: {e}"));
    listener.set_nonblocking(true).map_err(|e| net(&e))?;
    let listener = tokio::net::TcpListener::from_std(listener).map_err(|e| net(&e))?;
    let (tx, rx) = tokio::sync::mpsc::channel(1);
    let accept = tokio::spawn(limited::accept(listener, limits, tx));
    let served = tonic::transport::Server::builder()
        // A frame's headers are a few hundred bytes; anything near this is not a tracker.
        .http2_max_header_list_size(16 * 1024)
        .http2_keepalive_interval(Some(Duration::from_secs_f64(limits.keepalive_s)))
        .http2_keepalive_timeout(Some(Duration::from_secs_f64(limits.keepalive_s)))
        .serve_with_incoming_shutdown(
            service,
            tokio_stream::wrappers::ReceiverStream::new(rx),
            shutdown,
        )
        .await
        .map_err(|e| net(&e));
    accept.abort();
    served
}

/// Accepting within [`ConnectionLimits`].
mod limited {
    use super::ConnectionLimits;
    use std::collections::HashMap;
    use std::future::Future;
    use std::io;
    use std::pin::Pin;
    use std::sync::atomic::{AtomicU64, Ordering};
    use std::sync::{Arc, Mutex, PoisonError};
    use std::task::{Context, Poll};
    use std::time::{Duration, Instant};
    use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};

    /// One held connection, as the accept loop sees it: a handle to close it and when it last
    /// sent bytes (ms since the server's start, plus one; 0 until it sends any).
    struct Entry {
        close: std::net::TcpStream,
        last_ms: Arc<AtomicU64>,
    }

    type Table = Arc<Mutex<HashMap<u64, Entry>>>;

    fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
        m.lock().unwrap_or_else(PoisonError::into_inner)
    }

    pub(super) async fn accept(
        listener: tokio::net::TcpListener,
        limits: ConnectionLimits,
        tx: tokio::sync::mpsc::Sender<io::Result<Conn>>,
    ) {
        let table: Table = Arc::default();
        let start = Instant::now();
        let mut next = 0u64;
        loop {
            let stream = match listener.accept().await {
                Ok((s, _)) => s,
                Err(_) => {
                    // Out of descriptors (or another passing fault): wait instead of spinning,
                    // and make room by closing the longest-silent connection.
                    close_quietest(&table);
                    tokio::time::sleep(Duration::from_millis(50)).await;
                    continue;
                }
            };
            let Ok(close) = stream.into_std().and_then(|s| {
                let c = s.try_clone()?;
                Ok((s, c))
            }) else {
                continue;
            };
            let (std_stream, close) = close;
            let Ok(stream) = tokio::net::TcpStream::from_std(std_stream) else {
                continue;
            };
            while lock(&table).len() >= limits.max_connections {
                if !close_quietest(&table) {
                    break;
                }
            }
            next += 1;
            let last_ms = Arc::new(AtomicU64::new(0));
            lock(&table).insert(
                next,
                Entry {
                    close,
                    last_ms: Arc::clone(&last_ms),
                },
            );
            let conn = Conn {
                inner: stream,
                idle: Box::pin(tokio::time::sleep(Duration::from_secs_f64(
                    limits.first_bytes_s,
                ))),
                idle_after: Duration::from_secs_f64(limits.idle_s),
                last_ms,
                start,
                id: next,
                table: Arc::clone(&table),
            };
            if tx.send(Ok(conn)).await.is_err() {
                return;
            }
        }
    }

    /// Milliseconds since `start`, plus one (0 means "never").
    fn ms(start: Instant) -> u64 {
        u64::try_from(start.elapsed().as_millis())
            .unwrap_or(u64::MAX - 1)
            .saturating_add(1)
    }

    /// Closes the connection that has been silent longest; whether there was one.
    fn close_quietest(table: &Table) -> bool {
        let mut t = lock(table);
        // Connections that never sent a byte go first (the longest-waiting of them), then
        // the one whose last bytes are oldest.
        let Some(id) = t
            .iter()
            .min_by_key(|(id, e)| (e.last_ms.load(Ordering::Relaxed), **id))
            .map(|(id, _)| *id)
        else {
            return false;
        };
        if let Some(e) = t.remove(&id) {
            let _ = e.close.shutdown(std::net::Shutdown::Both);
        }
        true
    }

    /// A connection that ends itself when its peer stays silent too long.
    pub(super) struct Conn {
        inner: tokio::net::TcpStream,
        idle: Pin<Box<tokio::time::Sleep>>,
        idle_after: Duration,
        last_ms: Arc<AtomicU64>,
        start: Instant,
        id: u64,
        table: Table,
    }

    impl Drop for Conn {
        fn drop(&mut self) {
            lock(&self.table).remove(&self.id);
        }
    }

    impl tonic::transport::server::Connected for Conn {
        type ConnectInfo = tonic::transport::server::TcpConnectInfo;
        fn connect_info(&self) -> Self::ConnectInfo {
            self.inner.connect_info()
        }
    }

    impl AsyncRead for Conn {
        fn poll_read(
            mut self: Pin<&mut Self>,
            cx: &mut Context<'_>,
            buf: &mut ReadBuf<'_>,
        ) -> Poll<io::Result<()>> {
            let before = buf.filled().len();
            match Pin::new(&mut self.inner).poll_read(cx, buf) {
                Poll::Ready(Ok(())) => {
                    if buf.filled().len() > before {
                        let deadline = tokio::time::Instant::now() + self.idle_after;
                        self.idle.as_mut().reset(deadline);
                        let now = ms(self.start);
                        self.last_ms.store(now, Ordering::Relaxed);
                    }
                    Poll::Ready(Ok(()))
                }
                Poll::Ready(Err(e)) => Poll::Ready(Err(e)),
                Poll::Pending => match self.idle.as_mut().poll(cx) {
                    Poll::Ready(()) => Poll::Ready(Err(io::Error::new(
                        io::ErrorKind::TimedOut,
                        "the peer was silent too long",
                    ))),
                    Poll::Pending => Poll::Pending,
                },
            }
        }
    }

    impl AsyncWrite for Conn {
        fn poll_write(
            mut self: Pin<&mut Self>,
            cx: &mut Context<'_>,
            buf: &[u8],
        ) -> Poll<io::Result<usize>> {
            Pin::new(&mut self.inner).poll_write(cx, buf)
        }
        fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
            Pin::new(&mut self.inner).poll_flush(cx)
        }
        fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
            Pin::new(&mut self.inner).poll_shutdown(cx)
        }
        fn poll_write_vectored(
            mut self: Pin<&mut Self>,
            cx: &mut Context<'_>,
            bufs: &[io::IoSlice<'_>],
        ) -> Poll<io::Result<usize>> {
            Pin::new(&mut self.inner).poll_write_vectored(cx, bufs)
        }
        fn is_write_vectored(&self) -> bool {
            self.inner.is_write_vectored()
        }
    }
}

/// A gRPC client of one address (the core, or in tests an observer).
#[derive(Debug, Clone)]
pub struct Client {
    grpc: tonic::client::Grpc<tonic::transport::Channel>,
}

impl Client {
    /// A client that connects on its first call, each call bounded by `timeout`. Must be made
    /// inside a tokio runtime.
    pub fn lazy(addr: SocketAddr, timeout: Duration) -> Result<Self, crate::LiveError> {
        let endpoint = tonic::transport::Endpoint::from_shared(format!("http://{addr}"))
            .map_err(|e| crate::LiveError::Net(format!("{addr}: {e}")))?
            .connect_timeout(timeout)
            .timeout(timeout);
        Ok(Self {
            grpc: tonic::client::Grpc::new(endpoint.connect_lazy()),
        })
    }

    /// One unary call of `path` (such as [`HEARTBEAT_PATH`]).
    pub async fn call<M1, M2>(&mut self, path: &'static str, message: M1) -> Result<M2, Status>
    where
        M1: prost::Message + Send + Sync + 'static,
        M2: prost::Message + Default + Send + Sync + 'static,
    {
        self.grpc
            .ready()
            .await
            .map_err(|e| Status::unavailable(e.to_string()))?;
        self.grpc
            .unary(
                Request::new(message),
                http::uri::PathAndQuery::from_static(path),
                tonic_prost::ProstCodec::<M1, M2>::default(),
            )
            .await
            .map(Response::into_inner)
    }

    /// `biotracker.BioTracker/heartbeat`.
    pub async fn heartbeat(&mut self) -> Result<(), Status> {
        self.call::<Empty, Empty>(HEARTBEAT_PATH, Empty {})
            .await
            .map(|_| ())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A path the service does not serve is answered `unimplemented`, naming the ones it does;
    /// a served one answers.
    #[test]
    fn an_unknown_method_is_refused_naming_the_served_ones() {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .expect("a runtime");
        let listener = std::net::TcpListener::bind("127.0.0.1:0").expect("a port");
        let addr = listener.local_addr().expect("an address");
        rt.spawn(serve(listener, heartbeat_service(), std::future::pending()));
        rt.block_on(async {
            let mut c = Client::lazy(addr, Duration::from_secs(2)).expect("a client");
            assert!(c.heartbeat().await.is_ok());
            let e = c
                .call::<Experiment, Empty>(UPDATE_PATH, Experiment::default())
                .await
                .expect_err("not served");
            assert_eq!(e.code(), tonic::Code::Unimplemented);
            assert!(
                e.message().contains(HEARTBEAT_PATH) && e.message().contains(UPDATE_PATH),
                "{e:?}"
            );
        });
    }
}
