//! assist-viewer: the interactive viewer. An axum server serves one page embedded in the
//! binary (nothing is fetched from the network) and a WebSocket per client; each client
//! gets its own [`assist_session::Session`] on a worker thread ([`worker`]), speaking the
//! versioned JSON messages of [`protocol`]. Frames come back as JPEG: a low-resolution
//! preview at once, the full frame when the view rests.
//!
//! Security: the server binds 127.0.0.1 unless told otherwise. Every client needs the
//! viewer's token (given, or generated and put in the URL it prints and opens), checked
//! when the socket opens, loopback included: a page of another site in the same browser
//! must not drive it. Every request's `Host` must be an address the viewer serves, and a
//! browser's `Origin` must be that host (no cross-site page, no DNS rebinding). Only the
//! embedded files are served; saves go only beside the opened scene, and "save as" never
//! replaces anything.

#![forbid(unsafe_code)]

pub mod protocol;
mod thumbnails;
mod worker;

use std::net::{IpAddr, SocketAddr};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use axum::Router;
use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::extract::{Query, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use serde::Deserialize;

use assist_session::{CameraSource, Session};
use protocol::{CameraState, ClientMsg, MAX_MESSAGE_BYTES, PROTOCOL_VERSION, ServerMsg, View};
pub use worker::{Outgoing, PREVIEW_DIVISOR, encode_jpeg};

/// The page, embedded at build time.
const INDEX_HTML: &str = include_str!("../page/index.html");

/// Clients served at once (each holds a session and a worker thread, ~100 MB on desk);
/// more are refused until one leaves.
pub const MAX_CLIENTS: usize = 8;

/// Messages a client may send per second; more are answered with an error and dropped.
pub const MAX_MESSAGES_PER_SECOND: u32 = 240;

/// Frames larger than this close the socket (smaller ones over [`MAX_MESSAGE_BYTES`] get
/// an error reply and the session goes on).
const MAX_FRAME_BYTES: usize = 1 << 20;

#[derive(Debug, thiserror::Error)]
pub enum ViewerError {
    #[error("{0}")]
    Session(#[from] assist_session::SessionError),
    #[error("cannot listen on {addr}: {source}")]
    Bind {
        addr: SocketAddr,
        source: std::io::Error,
    },
    #[error("{what}: {message}")]
    Options { what: &'static str, message: String },
    #[error("server: {0}")]
    Io(#[from] std::io::Error),
}

/// How the viewer is started.
#[derive(Debug, Clone)]
pub struct ViewerOptions {
    pub scene: PathBuf,
    /// A dataset whose training cameras the page lists (else an orbit around the scene).
    pub data: Option<PathBuf>,
    pub host: IpAddr,
    /// 0 = any free port.
    pub port: u16,
    /// What clients must present (`?token=`); generated when not given.
    pub token: Option<String>,
    /// Other scenes clients may take nodes from (by file name).
    pub others: Vec<PathBuf>,
    /// A folder of scenes clients may take nodes from (by relative path).
    pub scenes: Option<PathBuf>,
    /// Where renders query the fields (a GPU: `--device`; `None`: this CPU).
    pub backend: Option<std::sync::Arc<dyn assist_session::FieldBackend>>,
}

struct App {
    scene: PathBuf,
    /// The dataset given (`--data`).
    data: Option<PathBuf>,
    others: worker::OtherScenes,
    token: Option<String>,
    /// The `Host` values requests may carry (`None`: listening on every address, any).
    hosts: Option<Vec<String>>,
    /// Clients connected now.
    clients: std::sync::atomic::AtomicUsize,
    hello: ServerMsg,
    backend: Option<std::sync::Arc<dyn assist_session::FieldBackend>>,
    /// Set by [`Running::close`]: every client's socket ends.
    closing: tokio::sync::watch::Sender<bool>,
    /// The clients' worker threads (finished ones are pruned as new ones start).
    workers: std::sync::Mutex<Vec<std::thread::JoinHandle<()>>>,
}

/// A running viewer: its address, the token clients need (if any) and the URL to open.
pub struct Running {
    pub addr: SocketAddr,
    pub token: Option<String>,
    pub url: String,
    server: tokio::task::JoinHandle<std::io::Result<()>>,
    app: Arc<App>,
}

impl Running {
    /// Serves until the process ends (or the server fails).
    pub async fn wait(self) -> Result<(), ViewerError> {
        match self.server.await {
            Ok(r) => Ok(r?),
            Err(e) => Err(ViewerError::Io(std::io::Error::other(e))),
        }
    }

    /// Stops serving: no new clients, every connected one's socket ends, and this returns
    /// once their worker threads have ended (a frame in progress is stopped). Nothing of
    /// the viewer's then runs, so a GPU it queried can be torn down safely.
    pub async fn close(self) {
        self.server.abort();
        self.app.closing.send_replace(true);
        // A client still opening its session registers its worker before its seat goes.
        while self.app.clients.load(std::sync::atomic::Ordering::SeqCst) > 0 {
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        let app = self.app.clone();
        let _ = tokio::task::spawn_blocking(move || {
            let mut workers = app.workers.lock().unwrap_or_else(|e| e.into_inner());
            for w in workers.drain(..) {
                let _ = w.join();
            }
        })
        .await;
    }
}

/// A token of 128 random bits from the OS (`/dev/urandom`; elsewhere the OS-seeded hash
/// keys and the clock).
fn new_token() -> String {
    use std::io::Read;
    let mut bytes = [0u8; 16];
    if std::fs::File::open("/dev/urandom")
        .and_then(|mut f| f.read_exact(&mut bytes))
        .is_ok()
    {
        return bytes.iter().map(|b| format!("{b:02x}")).collect();
    }
    use std::hash::{BuildHasher, Hasher};
    let mut s = String::new();
    for i in 0..2u64 {
        let mut h = std::collections::hash_map::RandomState::new().build_hasher();
        h.write_u64(i);
        h.write_u128(
            std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map(|d| d.as_nanos())
                .unwrap_or(0),
        );
        h.write_u32(std::process::id());
        s.push_str(&format!("{:016x}", h.finish()));
    }
    s
}

/// The `Host` header values of the viewer's own address (`localhost` too on loopback);
/// `None` when it listens on every address.
fn served_hosts(addr: SocketAddr) -> Option<Vec<String>> {
    if addr.ip().is_unspecified() {
        return None;
    }
    let port = addr.port();
    let mut hosts = vec![addr.to_string()];
    if addr.ip().is_loopback() {
        hosts.push(format!("localhost:{port}"));
        hosts.push(format!("127.0.0.1:{port}"));
        hosts.push(format!("[::1]:{port}"));
    }
    Some(hosts)
}

/// Refuses a request whose `Host` is not the viewer's or whose `Origin` (sent by
/// browsers) is another site.
fn check_origin(headers: &HeaderMap, app: &App) -> Result<(), String> {
    let refuse = |why: String| Err(why);
    let host = headers
        .get(header::HOST)
        .and_then(|h| h.to_str().ok())
        .unwrap_or("");
    if let Some(hosts) = &app.hosts
        && !hosts.iter().any(|h| h.eq_ignore_ascii_case(host))
    {
        return refuse(format!(
            "Host {host:?} is not this viewer's address ({})",
            hosts.join(", ")
        ));
    }
    if let Some(origin) = headers.get(header::ORIGIN) {
        let origin = origin.to_str().unwrap_or("");
        let same = ["http://", "https://"]
            .iter()
            .any(|scheme| origin.eq_ignore_ascii_case(&format!("{scheme}{host}")));
        if !same {
            return refuse(format!(
                "cross-origin request from {origin:?} refused: open the viewer's own URL"
            ));
        }
    }
    Ok(())
}

/// Loads the scene (to check it and list its cameras), binds, and starts serving.
pub async fn start(opts: ViewerOptions) -> Result<Running, ViewerError> {
    let session = Session::open(&opts.scene)?;
    let description = session.description().clone();
    let cameras = CameraSource::train_or_orbit(opts.data.as_deref()).cameras(&description)?;
    let token = Some(opts.token.clone().unwrap_or_else(new_token));
    if token.as_deref().is_some_and(|t| t.len() < 8) {
        return Err(ViewerError::Options {
            what: "token",
            message: "expected at least 8 characters".into(),
        });
    }
    for p in &opts.others {
        Session::describe(p)?;
    }
    if let Some(d) = &opts.scenes
        && !d.is_dir()
    {
        return Err(ViewerError::Options {
            what: "scenes",
            message: format!("{} is not a folder", d.display()),
        });
    }
    let others = worker::OtherScenes {
        named: opts.others.clone(),
        folder: opts.scenes.clone(),
    };
    let thumbs = match &opts.data {
        Some(d) => {
            let names: Vec<String> = cameras.iter().map(|c| c.name.clone()).collect();
            thumbnails::thumbnails(d, &names)
        }
        None => vec![None; cameras.len()],
    };
    let hello = ServerMsg::Hello {
        version: PROTOCOL_VERSION,
        scene: scene_name(&opts.scene),
        others: others.names(),
        up: description.up.to_array(),
        meters_per_unit: description.meters_per_unit,
        cameras: cameras
            .iter()
            .zip(thumbs)
            .map(|(c, thumbnail)| CameraState {
                name: c.name.clone(),
                view: View::of_camera(&c.camera),
                thumbnail,
            })
            .collect(),
        max_message_bytes: MAX_MESSAGE_BYTES,
    };
    let addr = SocketAddr::new(opts.host, opts.port);
    let listener = tokio::net::TcpListener::bind(addr)
        .await
        .map_err(|source| ViewerError::Bind { addr, source })?;
    let addr = listener.local_addr()?;
    let app = Arc::new(App {
        scene: opts.scene.clone(),
        data: opts.data.clone(),
        others,
        token: token.clone(),
        hosts: served_hosts(addr),
        clients: std::sync::atomic::AtomicUsize::new(0),
        hello,
        backend: opts.backend.clone(),
        closing: tokio::sync::watch::channel(false).0,
        workers: std::sync::Mutex::new(Vec::new()),
    });
    let kept = app.clone();
    let router = Router::new()
        .route("/", get(index))
        .route("/ws", get(ws))
        .with_state(app);
    let url = match &token {
        Some(t) => format!("http://{addr}/?token={t}"),
        None => format!("http://{addr}/"),
    };
    let server = tokio::spawn(async move { axum::serve(listener, router).await });
    Ok(Running {
        addr,
        token,
        url,
        server,
        app: kept,
    })
}

fn scene_name(p: &Path) -> String {
    p.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| p.display().to_string())
}

async fn index(headers: HeaderMap, State(app): State<Arc<App>>) -> Response {
    if let Err(why) = check_origin(&headers, &app) {
        return (StatusCode::FORBIDDEN, why).into_response();
    }
    (
        [
            (header::CONTENT_TYPE, "text/html; charset=utf-8"),
            (header::CACHE_CONTROL, "no-store"),
        ],
        INDEX_HTML,
    )
        .into_response()
}

#[derive(Deserialize)]
struct WsQuery {
    token: Option<String>,
}

async fn ws(
    upgrade: WebSocketUpgrade,
    headers: HeaderMap,
    Query(q): Query<WsQuery>,
    State(app): State<Arc<App>>,
) -> Response {
    if let Err(why) = check_origin(&headers, &app) {
        return (StatusCode::FORBIDDEN, why).into_response();
    }
    if let Some(t) = &app.token
        && q.token.as_deref() != Some(t.as_str())
    {
        return (
            StatusCode::UNAUTHORIZED,
            "this viewer needs its token: open the URL it printed (…/?token=…)",
        )
            .into_response();
    }
    let seat = match Seat::take(&app) {
        Some(s) => s,
        None => {
            return (
                StatusCode::SERVICE_UNAVAILABLE,
                format!("this viewer serves at most {MAX_CLIENTS} clients at once; close one"),
            )
                .into_response();
        }
    };
    upgrade
        .max_message_size(MAX_FRAME_BYTES)
        .max_frame_size(MAX_FRAME_BYTES)
        .on_upgrade(move |socket| async move {
            client(socket, app).await;
            drop(seat);
        })
}

/// One of the [`MAX_CLIENTS`] places, given back when dropped.
struct Seat(Arc<App>);

impl Seat {
    fn take(app: &Arc<App>) -> Option<Seat> {
        use std::sync::atomic::Ordering;
        let before = app.clients.fetch_add(1, Ordering::SeqCst);
        if before >= MAX_CLIENTS {
            app.clients.fetch_sub(1, Ordering::SeqCst);
            return None;
        }
        Some(Seat(app.clone()))
    }
}

impl Drop for Seat {
    fn drop(&mut self) {
        self.0
            .clients
            .fetch_sub(1, std::sync::atomic::Ordering::SeqCst);
    }
}

async fn send_json(socket: &mut WebSocket, m: &ServerMsg) -> bool {
    let text = serde_json::to_string(m).unwrap_or_else(|e| {
        format!(r#"{{"type":"error","message":"cannot encode a reply: {e}"}}"#)
    });
    socket.send(Message::Text(text.into())).await.is_ok()
}

/// One client: a worker thread with its own session, and this task moving messages.
async fn client(mut socket: WebSocket, app: Arc<App>) {
    if !send_json(&mut socket, &app.hello).await {
        return;
    }
    let path = app.scene.clone();
    let backend = app.backend.clone();
    // The file's stamp is taken before it is read: a save in between makes the stamp older
    // than the session, so a later save is refused rather than lost.
    let opened = tokio::task::spawn_blocking(move || {
        let stamp = worker::disk_stamp(&path);
        Session::open(&path).map(|mut s| {
            s.set_backend(backend);
            (s, stamp)
        })
    })
    .await;
    let opened = match opened {
        Ok(r) => r.map_err(|e| e.to_string()),
        Err(e) => Err(e.to_string()),
    };
    let (session, stamp) = match opened {
        Ok(s) => s,
        Err(message) => {
            send_json(&mut socket, &ServerMsg::Error { message }).await;
            return;
        }
    };
    let (in_tx, in_rx) = std::sync::mpsc::channel::<ClientMsg>();
    let (out_tx, mut out_rx) = tokio::sync::mpsc::unbounded_channel::<Outgoing>();
    let scene = app.scene.clone();
    let others = app.others.clone();
    let data = app.data.clone();
    let gone = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let worker_gone = gone.clone();
    let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let worker_stop = stop.clone();
    let worker = std::thread::Builder::new()
        .name("assist-view-client".into())
        .spawn(move || {
            worker::Worker::new(session, &scene, others)
                .with_disk_stamp(stamp)
                .with_gone_flag(worker_gone)
                .with_stop_flag(worker_stop)
                .with_data(data)
                .run(in_rx, |o| out_tx.send(o).is_ok())
        });
    let Ok(worker) = worker else {
        send_json(
            &mut socket,
            &ServerMsg::Error {
                message: "cannot start a worker thread".into(),
            },
        )
        .await;
        return;
    };
    {
        let mut workers = app.workers.lock().unwrap_or_else(|e| e.into_inner());
        workers.retain(|w| !w.is_finished());
        workers.push(worker);
    }
    let mut closing = app.closing.subscribe();
    let mut window = (Instant::now(), 0u32);
    loop {
        tokio::select! {
            // `wait_for` sees a close made before this client subscribed too.
            _ = async { let _ = closing.wait_for(|c| *c).await; } => break,
            incoming = socket.recv() => {
                let msg = match incoming {
                    Some(Ok(m)) => m,
                    Some(Err(e)) => {
                        // An oversized frame ends the socket: say why before it closes.
                        let e = ServerMsg::Error {
                            message: format!("closing the connection: {e} (a message is at most {MAX_MESSAGE_BYTES} bytes)"),
                        };
                        send_json(&mut socket, &e).await;
                        break;
                    }
                    None => break,
                };
                let text = match msg {
                    Message::Text(t) => t.to_string(),
                    Message::Binary(_) => {
                        let e = ServerMsg::Error { message: "expected JSON text messages".into() };
                        if !send_json(&mut socket, &e).await { break }
                        continue;
                    }
                    Message::Close(_) => break,
                    _ => continue,
                };
                if window.0.elapsed() > Duration::from_secs(1) {
                    window = (Instant::now(), 0);
                }
                window.1 += 1;
                if window.1 > MAX_MESSAGES_PER_SECOND {
                    let e = ServerMsg::Error {
                        message: format!("more than {MAX_MESSAGES_PER_SECOND} messages per second; this one was dropped"),
                    };
                    if !send_json(&mut socket, &e).await { break }
                    continue;
                }
                match protocol::parse_client(&text) {
                    Ok(m) => {
                        // A stop acts at once: the worker may be busy with the split.
                        if m == ClientMsg::Stop {
                            stop.store(true, std::sync::atomic::Ordering::SeqCst);
                        }
                        if in_tx.send(m).is_err() { break }
                    }
                    Err(message) => {
                        if !send_json(&mut socket, &ServerMsg::Error { message }).await { break }
                    }
                }
            }
            out = out_rx.recv() => {
                let ok = match out {
                    Some(Outgoing::Json(m)) => send_json(&mut socket, &m).await,
                    Some(Outgoing::Jpeg(b)) => socket.send(Message::Binary(b.into())).await.is_ok(),
                    None => false,
                };
                if !ok { break }
            }
        }
    }
    // Dropping `in_tx` ends the worker; the flag stops a frame it is rendering.
    gone.store(true, std::sync::atomic::Ordering::Relaxed);
    stop.store(true, std::sync::atomic::Ordering::SeqCst);
}
