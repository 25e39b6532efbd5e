//! The HTTP and WebSocket server: `GET /` (the page), `GET /viewer.js`, `GET /viewer.css`,
//! `GET /ws` (one [`Session`] per connection).
//!
//! `/ws` refuses a browser page of another origin (an `Origin` header whose host is not the
//! `Host` the request was sent to: 403), and more than [`ServerConfig::max_connections`]
//! open connections (503). A message over [`Limits::max_message_bytes`] gets a `too_large`
//! error reply and the connection stays, up to what the transport reads
//! ([`TRANSPORT_LIMIT_FACTOR`] times that limit); beyond, the server sends the reply and a
//! close frame 1009 (message too big) as far as the client still reads them, and ends the
//! connection.
//!
//! Each connection runs one task: it waits for either a client message or the next frame tick
//! (~60/s). Simulation work, message handling and the encoding of frames run on tokio's
//! blocking pool (`spawn_blocking`), so that a busy session never stalls the other
//! connections' I/O. A
//! connection whose client goes away ends its task; nothing is shared between connections
//! except the read-only scene catalog.

use std::net::SocketAddr;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use axum::extract::ws::{CloseFrame, Message, WebSocket, WebSocketUpgrade};
use axum::extract::State;
use axum::http::{header, HeaderMap, StatusCode};
use axum::response::{Html, IntoResponse, Response};
use axum::routing::get;
use axum::Router;
use tokio::net::TcpListener;

use crate::page::{INDEX_HTML, VIEWER_CSS, VIEWER_JS};
use crate::protocol::{message_type, Encoded, ErrorCode, Limits, ServerMessage};
use crate::scenes::Catalog;
use crate::session::Session;

/// Frame interval (~60 frames/s).
pub const FRAME_INTERVAL: Duration = Duration::from_micros(16_667);
/// A client that does not take a message within this time is dropped.
const SEND_TIMEOUT: Duration = Duration::from_secs(10);

/// Messages up to this many times [`Limits::max_message_bytes`] are read whole (and answered
/// with a `too_large` error); beyond, the transport cannot skip the rest of the frame and the
/// connection ends. 64 x 64 KB = 4 MB: a hostile message is answered without buffering more
/// than that per connection.
pub const TRANSPORT_LIMIT_FACTOR: usize = 64;

/// Open viewer connections a server accepts by default: each runs its own simulations on
/// the machine's cores, so a few dozen already share them thinly.
pub const DEFAULT_MAX_CONNECTIONS: usize = 32;

/// What a server serves.
#[derive(Clone, Debug)]
pub struct ServerConfig {
    pub catalog: Arc<Catalog>,
    pub limits: Limits,
    /// Open WebSocket connections at most; one more is refused with 503.
    pub max_connections: usize,
}

impl Default for ServerConfig {
    fn default() -> Self {
        ServerConfig {
            catalog: Arc::new(Catalog::shipped()),
            limits: Limits::default(),
            max_connections: DEFAULT_MAX_CONNECTIONS,
        }
    }
}

/// The server's shared state: its configuration and the open connections.
struct Shared {
    config: ServerConfig,
    open: AtomicUsize,
}

/// One open connection, counted while it lives.
struct Slot(Arc<Shared>);

impl Drop for Slot {
    fn drop(&mut self) {
        self.0.open.fetch_sub(1, Ordering::SeqCst);
    }
}

impl Shared {
    /// A slot when fewer than `max_connections` are open.
    fn take_slot(self: &Arc<Self>) -> Option<Slot> {
        let max = self.config.max_connections;
        self.open
            .fetch_update(Ordering::SeqCst, Ordering::SeqCst, |open| {
                (open < max).then_some(open + 1)
            })
            .ok()
            .map(|_| Slot(Arc::clone(self)))
    }
}

/// The router: page, assets and WebSocket.
pub fn router(config: ServerConfig) -> Router {
    Router::new()
        .route("/", get(index))
        .route("/index.html", get(index))
        .route("/viewer.js", get(script))
        .route("/viewer.css", get(style))
        .route("/ws", get(websocket))
        .with_state(Arc::new(Shared {
            config,
            open: AtomicUsize::new(0),
        }))
}

/// Whether a request with these headers comes from a page of the server's own origin, or
/// from no page at all (no `Origin` header: a program, not a browser). The origin's host
/// and port must equal the `Host` header's.
fn same_origin(headers: &HeaderMap) -> Result<(), String> {
    let Some(origin) = headers.get(header::ORIGIN) else {
        return Ok(());
    };
    let origin = origin.to_str().unwrap_or("");
    let host = headers
        .get(header::HOST)
        .and_then(|h| h.to_str().ok())
        .unwrap_or("");
    let origin_host = origin
        .split_once("://")
        .map_or(origin, |(_, rest)| rest)
        .trim_end_matches('/');
    if !host.is_empty() && origin_host.eq_ignore_ascii_case(host) {
        Ok(())
    } else {
        Err(format!(
            "a WebSocket from a page of origin `{origin}` is refused: this viewer serves `{host}` only"
        ))
    }
}

async fn index() -> Html<&'static str> {
    Html(INDEX_HTML)
}

async fn script() -> Response {
    (
        [(header::CONTENT_TYPE, "text/javascript; charset=utf-8")],
        VIEWER_JS,
    )
        .into_response()
}

async fn style() -> Response {
    (
        [(header::CONTENT_TYPE, "text/css; charset=utf-8")],
        VIEWER_CSS,
    )
        .into_response()
}

async fn websocket(
    State(shared): State<Arc<Shared>>,
    headers: HeaderMap,
    upgrade: WebSocketUpgrade,
) -> Response {
    if let Err(message) = same_origin(&headers) {
        return (StatusCode::FORBIDDEN, message).into_response();
    }
    let Some(slot) = shared.take_slot() else {
        return (
            StatusCode::SERVICE_UNAVAILABLE,
            format!(
                "too many viewer connections (at most {} at once); close one and retry",
                shared.config.max_connections
            ),
        )
            .into_response();
    };
    // Messages up to TRANSPORT_LIMIT_FACTOR x the protocol limit are read and answered with
    // an error reply; beyond that the transport gives up on the connection (it cannot skip
    // the rest of a frame), after a last error reply.
    let max = shared
        .config
        .limits
        .max_message_bytes
        .saturating_mul(TRANSPORT_LIMIT_FACTOR);
    let config = Arc::new(shared.config.clone());
    upgrade
        .max_message_size(max)
        .max_frame_size(max)
        .on_upgrade(move |socket| async move {
            connection(socket, config, max).await;
            drop(slot);
        })
}

/// Bind `addr` (port 0: any free port).
pub async fn bind(addr: SocketAddr) -> std::io::Result<TcpListener> {
    TcpListener::bind(addr).await
}

/// Serve on `listener` until the process ends.
pub async fn serve(listener: TcpListener, config: ServerConfig) -> std::io::Result<()> {
    axum::serve(listener, router(config)).await
}

/// Bind `addr`, call `ready` with the bound address, and serve forever on a new multi-thread
/// runtime (for the CLI, which has no runtime of its own).
pub fn serve_blocking(
    addr: SocketAddr,
    config: ServerConfig,
    ready: impl FnOnce(SocketAddr),
) -> std::io::Result<()> {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?;
    runtime.block_on(async move {
        let listener = bind(addr).await?;
        ready(listener.local_addr()?);
        serve(listener, config).await
    })
}

/// Send one message; false when the client is gone (or too slow).
async fn send(socket: &mut WebSocket, message: &ServerMessage) -> bool {
    match message.encode() {
        Ok(encoded) => send_encoded(socket, encoded).await,
        Err(_) => true,
    }
}

/// Send one encoded message; false when the client is gone (or too slow).
async fn send_encoded(socket: &mut WebSocket, encoded: Encoded) -> bool {
    let message = match encoded {
        Encoded::Text(text) => Message::Text(text.into()),
        Encoded::Binary(bytes) => Message::Binary(bytes.into()),
    };
    matches!(
        tokio::time::timeout(SEND_TIMEOUT, socket.send(message)).await,
        Ok(Ok(()))
    )
}

/// Run `f` on the session on the blocking pool; a panic becomes an error reply and the
/// session is kept.
async fn on_session<T: Send + 'static>(
    session: Session,
    f: impl FnOnce(&mut Session) -> T + Send + 'static,
) -> Option<(Session, Result<T, ()>)> {
    tokio::task::spawn_blocking(move || {
        let mut session = session;
        let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| f(&mut session)))
            .map_err(|_| ());
        (session, result)
    })
    .await
    .ok()
}

fn error_reply(code: ErrorCode, message: String, request: Option<String>) -> ServerMessage {
    ServerMessage::Error {
        code,
        message,
        request,
        panel: None,
    }
}

/// The end of a connection whose client sent a message the transport would not read:
/// a `too_large` error reply and a close frame 1009 (message too big), as far as the client
/// still listens.
async fn refuse_oversize(socket: &mut WebSocket, error: &axum::Error, transport_limit: usize) {
    let reply = error_reply(
        ErrorCode::TooLarge,
        format!(
            "message too large for the connection ({error}); messages over {transport_limit} bytes cannot be read, so the connection is closed"
        ),
        None,
    );
    if send(socket, &reply).await {
        let close = Message::Close(Some(CloseFrame {
            code: 1009,
            reason: "message too big".into(),
        }));
        let _ = tokio::time::timeout(SEND_TIMEOUT, socket.send(close)).await;
    }
}

/// Whether a receive error is the transport's size limit (a message or frame too long).
fn is_oversize(error: &axum::Error) -> bool {
    let text = error.to_string();
    text.contains("too long") || text.contains("Space limit")
}

/// One connection, until the client leaves.
async fn connection(mut socket: WebSocket, config: Arc<ServerConfig>, transport_limit: usize) {
    let catalog = Arc::clone(&config.catalog);
    let limits = config.limits;
    let Some((mut session, greeting)) =
        on_session(Session::new(catalog, limits), |s| s.greeting()).await
    else {
        return;
    };
    for message in greeting.unwrap_or_default() {
        if !send(&mut socket, &message).await {
            return;
        }
    }
    let mut ticks = tokio::time::interval(FRAME_INTERVAL);
    ticks.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    let mut last = Instant::now();
    loop {
        tokio::select! {
            incoming = socket.recv() => {
                let replies = match incoming {
                    None => return,
                    Some(Err(error)) => {
                        if is_oversize(&error) {
                            refuse_oversize(&mut socket, &error, transport_limit).await;
                        }
                        return;
                    }
                    Some(Ok(Message::Text(text))) => {
                        let request = message_type(text.as_str());
                        let Some((s, result)) =
                            on_session(session, move |s| s.handle_text(text.as_str())).await
                        else {
                            return;
                        };
                        session = s;
                        result.unwrap_or_else(|()| {
                            vec![error_reply(
                                ErrorCode::InternalError,
                                "internal error while handling the message".into(),
                                request,
                            )]
                        })
                    }
                    Some(Ok(Message::Binary(_))) => vec![error_reply(
                        ErrorCode::BinaryMessage,
                        "binary messages are not part of the protocol; send JSON text".into(),
                        None,
                    )],
                    Some(Ok(Message::Close(_))) => return,
                    Some(Ok(_)) => Vec::new(),
                };
                for reply in &replies {
                    if !send(&mut socket, reply).await {
                        return;
                    }
                }
            }
            _ = ticks.tick() => {
                let now = Instant::now();
                let elapsed = now.duration_since(last).as_secs_f64();
                last = now;
                // Encoded on the blocking pool too: its cost grows with the particles.
                let Some((s, frame)) = on_session(session, move |s| s.tick(elapsed)).await
                else {
                    return;
                };
                session = s;
                if let Ok(Some(frame)) = frame {
                    if !send_encoded(&mut socket, frame).await {
                        return;
                    }
                }
            }
        }
    }
}
