//! `assist view SCENE.assist`: the interactive viewer in a browser.

use std::net::IpAddr;
use std::path::PathBuf;

use anyhow::Context;
use clap::Args;

#[derive(Args, Debug)]
pub struct ViewArgs {
    /// Trained scene directory (NAME.assist).
    pub scene: PathBuf,
    /// Other scenes the page may take nodes from (`c`, then `a` to add, `s` to swap).
    pub others: Vec<PathBuf>,
    /// A folder of scenes the page may take nodes from too (by relative path).
    #[arg(long)]
    pub scenes: Option<PathBuf>,
    /// Dataset whose training cameras the page lists (default: the one the scene was
    /// trained on, when it is still there; else an orbit around the scene).
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// Port to listen on (0: any free port); not nerfstudio's 7007, so both viewers can run
    /// side by side.
    #[arg(long, default_value_t = 7341)]
    pub port: u16,
    /// Address to listen on.
    #[arg(long, default_value = "127.0.0.1")]
    pub host: IpAddr,
    /// Token clients must present, on every address, loopback included (generated when
    /// not given; the URL printed and opened carries it).
    #[arg(long)]
    pub token: Option<String>,
    /// Open the page in the desktop's browser (xdg-open) once listening.
    #[arg(long)]
    pub open: bool,
    /// Print the URL as JSON (`{"url": …, "addr": …}`) once listening.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub device: crate::device::DeviceArg,
}

pub fn run(a: ViewArgs) -> anyhow::Result<()> {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .context("starting the server runtime")?;
    // Without --data, the scene's own capture (as `generate` finds it), if it is there.
    let data = match &a.data {
        Some(d) => Some(d.clone()),
        None => assist_session::scene_file::load_scene_json(&a.scene)
            .ok()
            .and_then(|(_, info)| assist_session::recorded_dataset(&a.scene, &info).ok())
            .flatten(),
    };
    let device = a.device.open()?;
    rt.block_on(async move {
        let running = assist_viewer::start(assist_viewer::ViewerOptions {
            scene: a.scene.clone(),
            data,
            host: a.host,
            port: a.port,
            token: a.token.clone(),
            others: a.others.clone(),
            scenes: a.scenes.clone(),
            backend: device.field_backend(),
        })
        .await
        .with_context(|| format!("viewer for {}", a.scene.display()))?;
        if a.json {
            println!(
                "{}",
                serde_json::json!({"url": running.url, "addr": running.addr.to_string()})
            );
        } else {
            eprintln!("assist view: open {}", running.url);
            eprintln!(
                "(Ctrl+C stops the server; edits are saved only with the page's save button)"
            );
        }
        if a.open {
            match std::process::Command::new("xdg-open")
                .arg(&running.url)
                .spawn()
            {
                Ok(_) => {}
                Err(e) => {
                    eprintln!("assist view: could not open a browser ({e}); open the URL above")
                }
            }
        }
        use std::io::Write;
        let _ = std::io::stdout().flush();
        running.wait().await.context("viewer server")
    })
}
