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
    pub fn unary<M1, M2, F>(
        mut self,
        path: &'static str,
        max_message_bytes: usize,
        handle: F,
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
                Ok(grpc.unary(Unary(move |m| handle(m)), req).await)
            })
        };
        self.routes.push((path, Arc::new(route)));
        self
    }
}

impl Methods {
    /// Adds the unary method `path` whose `handle` may take long (it loads files): it runs on a
    /// blocking thread of its own, so the server answers the other methods meanwhile (the
    /// core's `update`s keep flowing while a `set_config` loads a policy).
    #[must_use]
    pub fn unary_blocking<M1, M2, F>(
        mut self,
        path: &'static str,
        max_message_bytes: usize,
        handle: F,
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
                Ok(grpc.unary(Blocking(handle), req).await)
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
