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

type BoxError = Box<dyn std::error::Error + Send + Sync>;
type BoxFuture<T> = Pin<Box<dyn Future<Output = Result<T, std::convert::Infallible>> + Send>>;

/// What answers the observer's two calls. Both must return at once: the core calls `update`
/// from its tracking loop, once per frame.
pub trait ObserverCalls: Send + Sync + 'static {
    /// The component's configuration (once after connecting, again when the user edits it).
    fn set_config(&self, config: ComponentConfig) -> Result<(), Status>;
    /// One tracked frame.
    fn update(&self, experiment: Experiment) -> Result<(), Status>;
}

/// The `biotracker.Observer` service over an [`ObserverCalls`].
#[derive(Clone)]
pub struct ObserverService {
    calls: Arc<dyn ObserverCalls>,
    max_message_bytes: usize,
}

impl std::fmt::Debug for ObserverService {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ObserverService")
            .field("max_message_bytes", &self.max_message_bytes)
            .finish()
    }
}

impl ObserverService {
    /// The service; a request larger than `max_message_bytes` is answered with an error
    /// without being decoded.
    pub fn new(calls: Arc<dyn ObserverCalls>, max_message_bytes: usize) -> Self {
        Self {
            calls,
            max_message_bytes,
        }
    }
}

/// A unary method as a tower service: the message in, `Empty` or an error out, at once.
struct Unary<F>(F);

impl<M, F> tower_service::Service<Request<M>> for Unary<F>
where
    F: FnMut(M) -> Result<(), Status>,
{
    type Response = Response<Empty>;
    type Error = Status;
    type Future = std::future::Ready<Result<Response<Empty>, Status>>;

    fn poll_ready(&mut self, _cx: &mut Context<'_>) -> Poll<Result<(), Status>> {
        Poll::Ready(Ok(()))
    }

    fn call(&mut self, request: Request<M>) -> Self::Future {
        std::future::ready((self.0)(request.into_inner()).map(|()| Response::new(Empty {})))
    }
}

/// Answers one unary call of `req` with `handle`: the request (at most `max_message_bytes`,
/// else an error without decoding it) in, `Empty` or the handler's error out.
fn unary<M, B, F>(
    req: http::Request<B>,
    max_message_bytes: usize,
    handle: F,
) -> BoxFuture<http::Response<tonic::body::Body>>
where
    M: prost::Message + Default + Send + 'static,
    B: http_body::Body + Send + 'static,
    B::Error: Into<BoxError> + Send,
    F: FnMut(M) -> Result<(), Status> + Send + 'static,
{
    Box::pin(async move {
        let mut grpc = tonic::server::Grpc::new(tonic_prost::ProstCodec::<Empty, M>::default())
            .max_decoding_message_size(max_message_bytes);
        Ok(grpc.unary(Unary(handle), req).await)
    })
}

impl<B> tower_service::Service<http::Request<B>> for ObserverService
where
    B: http_body::Body + Send + 'static,
    B::Error: Into<BoxError> + Send,
{
    type Response = http::Response<tonic::body::Body>;
    type Error = std::convert::Infallible;
    type Future = BoxFuture<Self::Response>;

    fn poll_ready(&mut self, _cx: &mut Context<'_>) -> Poll<Result<(), Self::Error>> {
        Poll::Ready(Ok(()))
    }

    fn call(&mut self, req: http::Request<B>) -> Self::Future {
        let calls = Arc::clone(&self.calls);
        let max = self.max_message_bytes;
        match req.uri().path() {
            SET_CONFIG_PATH => unary(req, max, move |c: ComponentConfig| calls.set_config(c)),
            UPDATE_PATH => unary(req, max, move |e: Experiment| calls.update(e)),
            other => {
                let status = Status::unimplemented(format!(
                    "fishprobe's observer serves set_config and update, not {other}"
                ));
                Box::pin(async move { Ok(status.into_http()) })
            }
        }
    }
}

/// The core's heartbeat, as a stand-in for BioTracker's core: answers
/// `biotracker.BioTracker/heartbeat` and nothing else.
#[derive(Debug, Clone, Copy, Default)]
pub struct HeartbeatService;

impl<B> tower_service::Service<http::Request<B>> for HeartbeatService
where
    B: http_body::Body + Send + 'static,
    B::Error: Into<BoxError> + Send,
{
    type Response = http::Response<tonic::body::Body>;
    type Error = std::convert::Infallible;
    type Future = BoxFuture<Self::Response>;

    fn poll_ready(&mut self, _cx: &mut Context<'_>) -> Poll<Result<(), Self::Error>> {
        Poll::Ready(Ok(()))
    }

    fn call(&mut self, req: http::Request<B>) -> Self::Future {
        if req.uri().path() == HEARTBEAT_PATH {
            // An empty message: the smallest limit the codec takes.
            unary(req, 4096, |_: Empty| Ok(()))
        } else {
            let status = Status::unimplemented("this stand-in core answers heartbeat only");
            Box::pin(async move { Ok(status.into_http()) })
        }
    }
}

/// Serves `service` on `listener` (HTTP/2, no TLS: loopback) until `shutdown` completes.
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
    let net = |e: &dyn std::fmt::Display| crate::LiveError::Net(format!("gRPC server: {e}"));
    listener.set_nonblocking(true).map_err(|e| net(&e))?;
    let listener = tokio::net::TcpListener::from_std(listener).map_err(|e| net(&e))?;
    tonic::transport::Server::builder()
        // A frame's headers are a few hundred bytes; anything near this is not a tracker.
        .http2_max_header_list_size(16 * 1024)
        .serve_with_incoming_shutdown(
            service,
            tonic::transport::server::TcpIncoming::from(listener),
            shutdown,
        )
        .await
        .map_err(|e| net(&e))
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
