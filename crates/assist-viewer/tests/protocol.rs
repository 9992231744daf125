//! The viewer's protocol over a real socket: a client connects, gets the scene, renders,
//! selects, edits, undoes and saves; bad messages get error replies and the session goes
//! on; a non-loopback viewer refuses clients without its token.

use std::net::{IpAddr, Ipv4Addr};
use std::time::Duration;

use assist_testkit::TempDir;
use assist_viewer::{ViewerOptions, start};
use futures_util::{SinkExt, StreamExt};
use serde_json::{Value, json};
use tokio_tungstenite::tungstenite::Message;

/// A grey background box with a red and a green cube, saved as `scene.assist`.
fn scene_on_disk(dir: &TempDir) -> std::path::PathBuf {
    scene_at(&dir.join("scene.assist"))
}

fn scene_at(path: &std::path::Path) -> std::path::PathBuf {
    let scene = assist_testkit::scenes::two_boxes(0.08);
    assist_scene::scene_file::save(path, &scene, json!({}), false).unwrap();
    path.to_path_buf()
}

type Ws =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

/// The next JSON message (binary frames are returned as `{"jpeg": len}`).
async fn next(ws: &mut Ws) -> Value {
    loop {
        let m = tokio::time::timeout(Duration::from_secs(60), ws.next())
            .await
            .expect("a message within 60 s")
            .expect("open")
            .expect("valid");
        match m {
            Message::Text(t) => return serde_json::from_str(&t).unwrap(),
            Message::Binary(b) => return json!({"jpeg": b.len(), "head": [b[0], b[1]]}),
            _ => continue,
        }
    }
}

/// Reads until a message of `kind` arrives.
async fn until(ws: &mut Ws, kind: &str) -> Value {
    for _ in 0..50 {
        let m = next(ws).await;
        if m["type"] == kind {
            return m;
        }
    }
    panic!("no {kind} message");
}

/// Reads until a full (not preview) frame and its JPEG arrive.
async fn full_frame(ws: &mut Ws) -> Value {
    loop {
        let m = until(ws, "frame").await;
        let jpeg = next(ws).await;
        assert_eq!(
            jpeg["head"],
            json!([0xff, 0xd8]),
            "a JPEG follows the frame"
        );
        if m["preview"] == false {
            return m;
        }
    }
}

async fn send(ws: &mut Ws, v: Value) {
    ws.send(Message::Text(v.to_string().into())).await.unwrap();
}

fn view() -> Value {
    // Looking along +y from y = −0.8, slightly down: both cubes in view.
    json!({"type": "view", "view": {
        "world_from_camera": [[1,0,0,0],[0,0,-1,-0.8],[0,1,0,0.05],[0,0,0,1]],
        "fov_y_degrees": 40, "width": 64, "height": 48}})
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_renders_selects_edits_undoes_and_saves() {
    let dir = TempDir::new("viewer-protocol");
    let path = scene_on_disk(&dir);
    std::fs::create_dir_all(dir.join("library/shelf")).unwrap();
    let other = scene_at(&dir.join("other.assist"));
    scene_at(&dir.join("library/shelf/lamp.assist"));
    let running = start(ViewerOptions {
        scene: path.clone(),
        data: None,
        host: IpAddr::V4(Ipv4Addr::LOCALHOST),
        port: 0,
        token: None,
        others: vec![other.clone()],
        scenes: Some(dir.join("library")),
        backend: None,
    })
    .await
    .unwrap();
    // Loopback too needs the token (issue 47: any web page could drive the viewer).
    let token = running.token.clone().expect("a token on loopback too");
    assert!(running.url.contains(&token));
    // The page itself is served.
    let page = tokio::net::TcpStream::connect(running.addr).await.unwrap();
    drop(page);
    let (mut ws, _) =
        tokio_tungstenite::connect_async(format!("ws://{}/ws?token={token}", running.addr))
            .await
            .unwrap();
    let hello = next(&mut ws).await;
    assert_eq!(hello["type"], "hello");
    assert_eq!(hello["version"], 1);
    assert!(!hello["cameras"].as_array().unwrap().is_empty());
    let state = until(&mut ws, "state").await;
    assert_eq!(state["nodes"].as_array().unwrap().len(), 3);

    send(&mut ws, view()).await;
    let f = full_frame(&mut ws).await;
    assert_eq!(
        (f["width"].as_u64(), f["height"].as_u64()),
        (Some(64), Some(48))
    );

    // Bad messages: error replies, and the session goes on.
    ws.send(Message::Text("{not json".into())).await.unwrap();
    assert!(
        until(&mut ws, "error").await["message"]
            .as_str()
            .unwrap()
            .contains("bad message")
    );
    send(&mut ws, json!({"type": "fly"})).await;
    assert!(
        until(&mut ws, "error").await["message"]
            .as_str()
            .unwrap()
            .contains("unknown variant")
    );
    send(&mut ws, json!({"type": "text", "text": "x".repeat(70_000)})).await;
    assert!(
        until(&mut ws, "error").await["message"]
            .as_str()
            .unwrap()
            .contains("at most")
    );
    send(&mut ws, json!({"type": "save", "path": "../escape.assist"})).await;
    let e = until(&mut ws, "error").await;
    assert!(e["message"].as_str().unwrap().contains("save.path"), "{e}");
    assert!(!dir.join("../escape.assist").exists());
    send(&mut ws, json!({"type": "delete"})).await;
    assert!(
        until(&mut ws, "error").await["message"]
            .as_str()
            .unwrap()
            .contains("no object selected")
    );

    // Click the red cube (left of centre): selected.
    send(&mut ws, json!({"type": "click", "x": 20.0, "y": 22.0})).await;
    let s = until(&mut ws, "state").await;
    assert_eq!(s["selected"], 1, "{s}");
    // Delete it, then undo.
    send(&mut ws, json!({"type": "delete"})).await;
    let s = until(&mut ws, "state").await;
    assert!(s["nodes"].as_array().unwrap().iter().all(|n| n["id"] != 1));
    assert_eq!(s["undo"], 1);
    send(&mut ws, json!({"type": "undo"})).await;
    let s = until(&mut ws, "state").await;
    assert!(s["nodes"].as_array().unwrap().iter().any(|n| n["id"] == 1));
    // Hidden from this view: a click where it stands no longer selects it; shown again.
    send(&mut ws, json!({"type": "select", "id": null})).await;
    until(&mut ws, "state").await;
    send(&mut ws, json!({"type": "hide", "id": 1, "hidden": true})).await;
    let s = until(&mut ws, "state").await;
    assert_eq!(s["hidden"], json!([1]), "{s}");
    assert!(
        s["nodes"].as_array().unwrap().iter().any(|n| n["id"] == 1),
        "hiding keeps the node"
    );
    send(&mut ws, json!({"type": "click", "x": 20.0, "y": 22.0})).await;
    let s = until(&mut ws, "state").await;
    assert_ne!(s["selected"], 1, "{s}");
    send(&mut ws, json!({"type": "hide", "id": 1, "hidden": false})).await;
    let s = until(&mut ws, "state").await;
    assert_eq!(s["hidden"], json!([]), "{s}");
    send(&mut ws, json!({"type": "hide", "id": 99, "hidden": true})).await;
    let e = until(&mut ws, "error").await;
    assert!(e["message"].as_str().unwrap().contains("99"), "{e}");
    // Rename: a taken name is refused, a new one is one undo step.
    send(
        &mut ws,
        json!({"type": "rename", "id": 2, "label": "Red Box"}),
    )
    .await;
    let e = until(&mut ws, "error").await;
    assert!(
        e["message"].as_str().unwrap().contains("already called"),
        "{e}"
    );
    send(
        &mut ws,
        json!({"type": "rename", "id": 2, "label": "lime box"}),
    )
    .await;
    let s = until(&mut ws, "state").await;
    let two = s["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .find(|n| n["id"] == 2)
        .unwrap()
        .clone();
    assert_eq!(two["label"], "lime box", "{s}");
    send(&mut ws, json!({"type": "undo"})).await;
    let s = until(&mut ws, "state").await;
    let two = s["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .find(|n| n["id"] == 2)
        .unwrap()
        .clone();
    assert_eq!(two["label"], "green box", "{s}");
    // A drag previews, then commits as one undo step.
    send(&mut ws, json!({"type": "select", "id": 2})).await;
    until(&mut ws, "state").await;
    for k in 1..=3 {
        send(&mut ws, json!({"type": "drag", "op": "translate", "axis": "x", "amount": 0.01 * k as f64, "phase": "move"})).await;
    }
    send(
        &mut ws,
        json!({"type": "drag", "op": "translate", "axis": "x", "amount": 0.03, "phase": "commit"}),
    )
    .await;
    let s = until(&mut ws, "state").await;
    let green = s["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .find(|n| n["id"] == 2)
        .unwrap()
        .clone();
    let cx: f64 = green["corners"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c[0].as_f64().unwrap())
        .sum::<f64>()
        / 8.0;
    assert!((cx - 0.18).abs() < 1e-9, "moved 3 cm along x: {cx}");
    assert_eq!(
        s["undo"], 1,
        "after delete and undo, the drag is the one undo step: {s}"
    );
    // Cross-scene: open a scene given on the command line, or one under --scenes; paths
    // outside are refused.
    assert_eq!(hello["others"], json!(["other.assist"]));
    send(&mut ws, json!({"type": "open", "scene": "other.assist"})).await;
    let o = until(&mut ws, "other").await;
    assert_eq!(o["nodes"].as_array().unwrap().len(), 3);
    send(
        &mut ws,
        json!({"type": "open", "scene": "shelf/lamp.assist"}),
    )
    .await;
    assert_eq!(until(&mut ws, "other").await["scene"], "shelf/lamp.assist");
    for bad in [
        "../scene.assist",
        "/etc",
        "shelf/../../scene.assist",
        "missing.assist",
    ] {
        send(&mut ws, json!({"type": "open", "scene": bad})).await;
        let e = until(&mut ws, "error").await;
        assert!(
            e["message"].as_str().unwrap().contains("scene"),
            "{bad}: {e}"
        );
    }
    // `a`: the other scene's red box added on the surface under a pixel, selected.
    send(
        &mut ws,
        json!({"type": "add_from", "scene": "other.assist", "node": 1, "x": 32.0, "y": 40.0}),
    )
    .await;
    let s = until(&mut ws, "state").await;
    assert_eq!(s["nodes"].as_array().unwrap().len(), 4, "{s}");
    let added = s["selected"].as_u64().unwrap();
    assert!(added > 2, "{s}");
    send(&mut ws, json!({"type": "undo"})).await;
    let s = until(&mut ws, "state").await;
    assert_eq!(s["nodes"].as_array().unwrap().len(), 3);
    // `s`: the selected green box swapped for the other scene's red box.
    send(&mut ws, json!({"type": "select", "id": 2})).await;
    until(&mut ws, "state").await;
    send(
        &mut ws,
        json!({"type": "swap_with", "scene": "other.assist", "node": 1}),
    )
    .await;
    let s = until(&mut ws, "state").await;
    let ids: Vec<u64> = s["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|n| n["id"].as_u64().unwrap())
        .collect();
    assert!(!ids.contains(&2) && ids.len() == 3, "{s}");
    send(&mut ws, json!({"type": "undo"})).await;
    until(&mut ws, "state").await;
    // A typed instruction.
    send(
        &mut ws,
        json!({"type": "text", "text": "move the red box 5 cm up"}),
    )
    .await;
    let r = until(&mut ws, "resolved").await;
    assert_eq!(r["applied"], true);
    assert_eq!(r["actions"][0]["operation"], "translate");
    // Into the green box: applied, with a warning in the log (issue 47 item 6).
    send(
        &mut ws,
        json!({"type": "text", "text": "move the red box 25 cm right"}),
    )
    .await;
    until(&mut ws, "resolved").await;
    let st = until(&mut ws, "state").await;
    let log = st["log"].to_string();
    assert!(
        log.contains("warning") && log.contains("would reach") && log.contains("green box"),
        "{st}"
    );
    send(&mut ws, json!({"type": "undo"})).await;
    until(&mut ws, "state").await;
    send(
        &mut ws,
        json!({"type": "text", "text": "move the purple box up"}),
    )
    .await;
    let e = until(&mut ws, "error").await;
    assert!(e["message"].as_str().unwrap().contains("purple"), "{e}");
    // The background alone, then the view saved as a labelled one-view dataset.
    send(&mut ws, json!({"type": "output", "output": "background"})).await;
    // The undo's full frame may still be on its way on a slow host: skip it.
    let mut f = full_frame(&mut ws).await;
    for _ in 0..3 {
        if f["output"] == "background" {
            break;
        }
        f = full_frame(&mut ws).await;
    }
    assert_eq!(f["output"], "background");
    send(&mut ws, json!({"type": "output", "output": "rgb"})).await;
    full_frame(&mut ws).await;
    send(&mut ws, json!({"type": "save_view"})).await;
    let saved = until(&mut ws, "saved").await;
    let view_dir = std::path::PathBuf::from(saved["path"].as_str().unwrap());
    assert_eq!(view_dir, dir.join("scene-view-1"));
    let ds = assist_data::load(&view_dir, &assist_data::LoadOptions::default()).unwrap();
    assert_eq!(ds.frames.len(), 1);
    assert!(view_dir.join("panoptic/view.png").is_file());
    // Save beside the scene; it loads again.
    send(&mut ws, json!({"type": "save", "path": "edited.assist"})).await;
    let saved = until(&mut ws, "saved").await;
    assert!(saved["path"].as_str().unwrap().ends_with("edited.assist"));
    let again = assist_session::Session::open(&dir.join("edited.assist")).unwrap();
    assert_eq!(again.nodes().len(), 3);
    send(&mut ws, json!({"type": "save", "path": "edited.assist"})).await;
    let e = until(&mut ws, "error").await;
    assert!(
        e["message"].as_str().unwrap().contains("exists"),
        "never overwritten without force: {e}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_non_loopback_viewer_needs_its_token() {
    let dir = TempDir::new("viewer-token");
    let path = scene_on_disk(&dir);
    let running = start_plain(path, Ipv4Addr::UNSPECIFIED).await;
    let token = running.token.clone().expect("a generated token");
    assert!(token.len() >= 16);
    assert!(running.url.contains(&token));
    let port = running.addr.port();
    for bad in ["", "?token=wrong"] {
        let r = tokio_tungstenite::connect_async(format!("ws://127.0.0.1:{port}/ws{bad}")).await;
        assert!(r.is_err(), "refused without the token ({bad:?})");
    }
    let (mut ws, _) =
        tokio_tungstenite::connect_async(format!("ws://127.0.0.1:{port}/ws?token={token}"))
            .await
            .unwrap();
    assert_eq!(next(&mut ws).await["type"], "hello");
}

/// A raw HTTP request to the viewer; returns the status code.
async fn status_of(addr: std::net::SocketAddr, request: &str) -> u16 {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let mut c = tokio::net::TcpStream::connect(addr).await.unwrap();
    c.write_all(request.as_bytes()).await.unwrap();
    let mut buf = vec![0u8; 256];
    let n = c.read(&mut buf).await.unwrap();
    let head = String::from_utf8_lossy(&buf[..n]);
    head.split_whitespace()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(0)
}

/// Issue 47, the adversarial probe: a page of another site connects to the viewer on
/// loopback and saves over a scene beside the opened one. Now a foreign `Origin`, a
/// foreign `Host` and a missing token are refused; save-as never replaces a scene whatever
/// the message says; messages without fields refuse unknown ones; a link in the scenes
/// folder cannot reach a scene outside it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_attacker_cannot_drive_the_viewer() {
    let dir = TempDir::new("viewer-attack");
    let path = scene_on_disk(&dir);
    let victim = scene_at(&dir.join("B.assist"));
    let victim_json = std::fs::read(victim.join("scene.json")).unwrap();
    std::fs::create_dir_all(dir.join("library")).unwrap();
    let outside = TempDir::new("viewer-attack-outside");
    scene_at(&outside.join("secret.assist"));
    #[cfg(unix)]
    std::os::unix::fs::symlink(
        outside.join("secret.assist"),
        dir.join("library/link.assist"),
    )
    .unwrap();
    let running = start(ViewerOptions {
        scene: path,
        data: None,
        host: IpAddr::V4(Ipv4Addr::LOCALHOST),
        port: 0,
        token: None,
        others: Vec::new(),
        scenes: Some(dir.join("library")),
        backend: None,
    })
    .await
    .unwrap();
    let addr = running.addr;
    let token = running.token.clone().unwrap();
    // No token, a wrong one: refused.
    for q in ["", "?token=wrong"] {
        let r = tokio_tungstenite::connect_async(format!("ws://{addr}/ws{q}")).await;
        assert!(r.is_err(), "refused without the token ({q:?})");
    }
    // A foreign Origin (a page of another site), even with the token: refused.
    let upgrade = |origin: &str, host: &str| {
        format!(
            "GET /ws?token={token} HTTP/1.1\r\nHost: {host}\r\nOrigin: {origin}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Version: 13\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n\r\n"
        )
    };
    let host = addr.to_string();
    assert_eq!(
        status_of(addr, &upgrade("http://evil.example", &host)).await,
        403
    );
    // DNS rebinding: the attacker's name for our address, its own origin.
    let rebound = format!("evil.example:{}", addr.port());
    assert_eq!(
        status_of(addr, &upgrade(&format!("http://{rebound}"), &rebound)).await,
        403
    );
    // The page from another origin is refused too; from its own, served.
    let page = |origin: &str| {
        format!("GET / HTTP/1.1\r\nHost: {host}\r\nOrigin: {origin}\r\nConnection: close\r\n\r\n")
    };
    assert_eq!(status_of(addr, &page("http://evil.example")).await, 403);
    assert_eq!(status_of(addr, &page(&format!("http://{host}"))).await, 200);
    // The viewer's own page: its origin is its host; the socket opens.
    assert_eq!(
        status_of(addr, &upgrade(&format!("http://{host}"), &host)).await,
        101
    );

    let (mut ws, _) = tokio_tungstenite::connect_async(format!("ws://{addr}/ws?token={token}"))
        .await
        .unwrap();
    until(&mut ws, "state").await;
    // Save as over another scene: refused whatever the message says.
    send(
        &mut ws,
        json!({"type": "save", "path": "B.assist", "force": true}),
    )
    .await;
    let e = until(&mut ws, "error").await;
    assert!(
        e["message"].as_str().unwrap().contains("never replaces"),
        "{e}"
    );
    assert_eq!(
        std::fs::read(victim.join("scene.json")).unwrap(),
        victim_json
    );
    // A name without .assist is a scene name.
    send(&mut ws, json!({"type": "save", "path": "C"})).await;
    let saved = until(&mut ws, "saved").await;
    assert!(
        saved["path"].as_str().unwrap().ends_with("C.assist"),
        "{saved}"
    );
    // Unknown fields on messages that take none: refused, nothing written.
    for t in ["undo", "redo", "delete", "replicate", "save_view"] {
        send(&mut ws, json!({"type": t, "path": "/etc"})).await;
        let e = until(&mut ws, "error").await;
        assert!(
            e["message"].as_str().unwrap().contains("unknown field"),
            "{t}: {e}"
        );
    }
    assert!(!dir.join("scene-view-1").exists());
    // A link inside the scenes folder to a scene outside it.
    #[cfg(unix)]
    {
        send(&mut ws, json!({"type": "open", "scene": "link.assist"})).await;
        let e = until(&mut ws, "error").await;
        assert!(e["message"].as_str().unwrap().contains("outside"), "{e}");
    }
}

/// Issue 47, item 14: 20 clients took 2.7 GB. The viewer serves `MAX_CLIENTS` at once and
/// refuses the next one (503) until one leaves.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_viewer_serves_a_bounded_number_of_clients() {
    let dir = TempDir::new("viewer-clients");
    let path = scene_on_disk(&dir);
    let running = start_plain(path, Ipv4Addr::LOCALHOST).await;
    let url = socket_url(&running);
    let mut open = Vec::new();
    for _ in 0..assist_viewer::MAX_CLIENTS {
        let (mut ws, _) = tokio_tungstenite::connect_async(&url).await.unwrap();
        assert_eq!(next(&mut ws).await["type"], "hello");
        open.push(ws);
    }
    let refused = tokio_tungstenite::connect_async(&url).await;
    assert!(refused.is_err(), "a client past the limit was served");
    let mut first = open.remove(0);
    first.close(None).await.unwrap();
    drop(first);
    // The seat comes back once the server sees the socket close.
    let mut again = None;
    for _ in 0..50 {
        if let Ok((ws, _)) = tokio_tungstenite::connect_async(&url).await {
            again = Some(ws);
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let mut ws = again.expect("a seat after a client left");
    assert_eq!(next(&mut ws).await["type"], "hello");
}

/// Issue 47, item 18: a message over 1 MiB dropped the connection without a word. The
/// client is told why before the socket closes, and the viewer serves the next one.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_oversized_message_is_answered_before_the_socket_closes() {
    let dir = TempDir::new("viewer-oversized");
    let path = scene_on_disk(&dir);
    let running = start_plain(path, Ipv4Addr::LOCALHOST).await;
    let url = socket_url(&running);
    let (mut ws, _) = tokio_tungstenite::connect_async(&url).await.unwrap();
    assert_eq!(next(&mut ws).await["type"], "hello");
    let huge = json!({"type": "text", "text": "x".repeat(2 << 20)});
    let _ = ws.send(Message::Text(huge.to_string().into())).await;
    let e = until(&mut ws, "error").await;
    assert!(e["message"].as_str().unwrap().contains("at most"), "{e}");
    let (mut ws2, _) = tokio_tungstenite::connect_async(&url).await.unwrap();
    assert_eq!(next(&mut ws2).await["type"], "hello");
}

/// `Running::close` ends every client's socket, returns once their workers have ended
/// (one of them asked for a frame just before), and the viewer takes no one new.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn closing_the_viewer_ends_its_clients_and_their_workers() {
    let dir = TempDir::new("viewer-close");
    let path = scene_on_disk(&dir);
    let running = start_plain(path, Ipv4Addr::LOCALHOST).await;
    let url = socket_url(&running);
    let (mut a, _) = tokio_tungstenite::connect_async(&url).await.unwrap();
    let (mut b, _) = tokio_tungstenite::connect_async(&url).await.unwrap();
    assert_eq!(next(&mut a).await["type"], "hello");
    assert_eq!(next(&mut b).await["type"], "hello");
    send(&mut a, view()).await;
    tokio::time::timeout(Duration::from_secs(60), running.close())
        .await
        .expect("closed within 60 s");
    for ws in [&mut a, &mut b] {
        let ended = tokio::time::timeout(Duration::from_secs(10), async {
            loop {
                match ws.next().await {
                    None | Some(Err(_)) | Some(Ok(Message::Close(_))) => return,
                    Some(Ok(_)) => continue,
                }
            }
        })
        .await;
        assert!(ended.is_ok(), "a client's socket stayed open after close");
    }
    assert!(
        tokio_tungstenite::connect_async(&url).await.is_err(),
        "a closed viewer took a new client"
    );
}

/// The socket address of `running`, with its token.
fn socket_url(running: &assist_viewer::Running) -> String {
    format!(
        "ws://{}/ws?token={}",
        running.addr,
        running.token.clone().unwrap()
    )
}

/// A viewer of the scene at `path` on `host`, any port, no other scenes.
async fn start_plain(path: std::path::PathBuf, host: Ipv4Addr) -> assist_viewer::Running {
    start(ViewerOptions {
        scene: path,
        data: None,
        host: IpAddr::V4(host),
        port: 0,
        token: None,
        others: Vec::new(),
        scenes: None,
        backend: None,
    })
    .await
    .unwrap()
}
