//! The viewer with its fields queried on a GPU (`assist view --device gpu`; lavapipe in
//! CI): the same view, and the same view after a move, arrive as the CPU viewer's frames
//! within JPEG rounding. Skipped loudly without an adapter unless `ASSIST_REQUIRE_GPU=1`.

use std::net::{IpAddr, Ipv4Addr};
use std::sync::Arc;
use std::time::Duration;

use assist_gpu::{DeviceChoice, Gpu, GpuBackend, GpuError};
use assist_session::FieldBackend;
use assist_testkit::TempDir;
use assist_viewer::{Running, ViewerOptions, start};
use futures_util::{SinkExt, StreamExt};
use serde_json::{Value, json};
use tokio_tungstenite::tungstenite::Message;

type Ws =
    tokio_tungstenite::WebSocketStream<tokio_tungstenite::MaybeTlsStream<tokio::net::TcpStream>>;

fn backend() -> Option<Arc<dyn FieldBackend>> {
    match Gpu::open(DeviceChoice::Gpu) {
        Ok(g) => Some(Arc::new(GpuBackend::new(g.expect("gpu")))),
        Err(GpuError::NoAdapter) if std::env::var("ASSIST_REQUIRE_GPU").as_deref() != Ok("1") => {
            eprintln!("SKIPPED: no GPU adapter (install mesa-vulkan-drivers for lavapipe)");
            None
        }
        Err(e) => panic!("{e}"),
    }
}

/// The next text message, or a binary one's bytes as `Err`.
async fn next(ws: &mut Ws) -> Result<Value, Vec<u8>> {
    loop {
        let m = tokio::time::timeout(Duration::from_secs(120), ws.next())
            .await
            .expect("a message within 120 s")
            .expect("open")
            .expect("valid");
        match m {
            Message::Text(t) => return Ok(serde_json::from_str(&t).unwrap()),
            Message::Binary(b) => return Err(b.to_vec()),
            _ => continue,
        }
    }
}

/// The pixels of the next full (not preview) frame.
async fn full_frame(ws: &mut Ws) -> image::RgbImage {
    loop {
        if let Ok(m) = next(ws).await
            && m["type"] == "frame"
        {
            let jpeg = next(ws).await.expect_err("a JPEG follows the frame");
            if m["preview"] == false {
                return image::load_from_memory(&jpeg).unwrap().to_rgb8();
            }
        }
    }
}

async fn send(ws: &mut Ws, v: Value) {
    ws.send(Message::Text(v.to_string().into())).await.unwrap();
}

/// A viewer of `path` (on `backend`), connected: the viewer, its socket after the first
/// full frame of the test's view, and that frame.
async fn client(
    path: &std::path::Path,
    backend: Option<Arc<dyn FieldBackend>>,
) -> (Running, Ws, image::RgbImage) {
    let running = start(ViewerOptions {
        scene: path.to_path_buf(),
        data: None,
        host: IpAddr::V4(Ipv4Addr::LOCALHOST),
        port: 0,
        token: None,
        others: Vec::new(),
        scenes: None,
        backend,
    })
    .await
    .unwrap();
    let url = format!(
        "ws://{}/ws?token={}",
        running.addr,
        running.token.clone().unwrap()
    );
    let (mut ws, _) = tokio_tungstenite::connect_async(url).await.unwrap();
    // Looking along +y from y = −0.8, slightly down: both cubes in view.
    send(
        &mut ws,
        json!({"type": "view", "view": {
            "world_from_camera": [[1,0,0,0],[0,0,-1,-0.8],[0,1,0,0.05],[0,0,0,1]],
            "fov_y_degrees": 40, "width": 64, "height": 48}}),
    )
    .await;
    let f = full_frame(&mut ws).await;
    (running, ws, f)
}

fn psnr(a: &image::RgbImage, b: &image::RgbImage) -> f64 {
    assert_eq!(a.dimensions(), b.dimensions());
    assist_testkit::psnr_u8(a.as_raw(), b.as_raw())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_viewer_on_the_gpu_shows_the_cpu_viewers_frames() {
    let Some(gpu) = backend() else { return };
    let dir = TempDir::new("viewer-gpu");
    let path = dir.join("scene.assist");
    let scene = assist_testkit::scenes::two_boxes(0.08);
    assist_scene::scene_file::save(&path, &scene, json!({}), false).unwrap();
    let (cpu_viewer, mut on_cpu, a) = client(&path, None).await;
    let (gpu_viewer, mut on_gpu, b) = client(&path, Some(gpu)).await;
    let lit = a.as_raw().iter().filter(|&&v| v > 40).count();
    assert!(lit > a.as_raw().len() / 4, "the view shows the scene");
    let q = psnr(&a, &b);
    assert!(q > 40.0, "{q:.1} dB between the CPU's and the GPU's frames");
    // The red cube moved 5 cm: both re-render it alike.
    let mv = json!({"type": "text", "text": "move the red box 5 cm to the left"});
    for ws in [&mut on_cpu, &mut on_gpu] {
        send(ws, mv.clone()).await;
    }
    let (a2, b2) = (full_frame(&mut on_cpu).await, full_frame(&mut on_gpu).await);
    assert!(psnr(&a, &a2) < 40.0, "the move shows");
    let q = psnr(&a2, &b2);
    assert!(q > 40.0, "after the move: {q:.1} dB between the frames");
    // The viewers' workers end before the process does: a worker still querying the GPU
    // while the process exits would race the Vulkan driver's own teardown.
    for v in [cpu_viewer, gpu_viewer] {
        tokio::time::timeout(Duration::from_secs(120), v.close())
            .await
            .expect("the viewer closes within 120 s");
    }
}
