//! `assist export SCENE --out DIR`: per-node meshes (marching tetrahedra on each node's
//! density, vertex colours from its field) or point clouds, in the world frame or the
//! nodes' own, with an optional MuJoCo (MJCF) or URDF model placing them at the nodes'
//! poses — so an object becomes a collision body in MuJoCo, PyBullet or Isaac.

use std::io::IsTerminal;
use std::path::PathBuf;

use anyhow::Context;
use assist_session::{
    DEFAULT_DENSITY, DEFAULT_MATERIAL_DENSITY, DEFAULT_MAX_TRIANGLES, DEFAULT_MIN_PART,
    DEFAULT_POINTS, DEFAULT_RESOLUTION, DEFAULT_SMOOTH, ExportJob, ExtractOptions, MeshFormat,
    MeshFrame, Session, SimModel,
};
use clap::{Args, ValueEnum};

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum FormatArg {
    /// Binary PLY mesh with normals and vertex colours.
    Ply,
    /// Wavefront OBJ with vertex colours and normals.
    Obj,
    /// Binary glTF 2.0 with normals and vertex colours.
    Glb,
    /// A point cloud on the surface (binary PLY with normals and colours).
    Points,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum FrameArg {
    /// The scene's world frame (meshes overlay the scene as it renders).
    World,
    /// Each node's own frame (box centre, box axes, world units).
    Node,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum SimArg {
    /// MuJoCo: scene.xml with a free body per object and the background static.
    Mjcf,
    /// URDF: one file per object and scene.urdf with every object fixed at its pose.
    Urdf,
}

#[derive(Args, Debug)]
pub struct ExportArgs {
    /// Trained scene directory.
    pub scene: PathBuf,
    /// Output folder (staged and swapped in whole; see --force).
    #[arg(long)]
    pub out: PathBuf,
    /// Nodes by id or name, comma-separated or repeated; `all` = every object node,
    /// `background` = the background's inner box.
    #[arg(long, value_delimiter = ',', default_value = "all")]
    pub node: Vec<String>,
    /// File format.
    #[arg(long, value_enum, default_value = "obj")]
    pub format: FormatArg,
    /// Coordinate frame of the files [default: world; node with --sim].
    #[arg(long, value_enum)]
    pub frame: Option<FrameArg>,
    /// Grid cells along the longest side of each node's box.
    #[arg(long, default_value_t = DEFAULT_RESOLUTION)]
    pub resolution: u32,
    /// Surface level in the field's density units (per box diagonal; the default is
    /// where 1% of the diagonal is half opaque), for the background and with
    /// --opacity 0. Lower keeps fainter matter.
    #[arg(long, default_value_t = DEFAULT_DENSITY)]
    pub density: f32,
    /// Drop parts of a node's surface enclosing less than this share of its largest
    /// part's volume (floaters), and cavities inside it; 0 keeps everything.
    #[arg(long, default_value_t = DEFAULT_MIN_PART)]
    pub min_part: f64,
    /// Smooth the density grid with a Gaussian of this many cells before taking the
    /// surface (removes noise finer than the views resolve); 0 = none.
    #[arg(long, default_value_t = DEFAULT_SMOOTH)]
    pub smooth: f32,
    /// An object's surface lies where it is this opaque seen from outside (from the best
    /// of 26 directions: what the renderer shows, solid where the field is a gappy shell
    /// around fog); 0 takes the density's level set (--density) instead, as the
    /// background always does.
    #[arg(long, default_value_t = assist_session::DEFAULT_OPACITY)]
    pub opacity: f32,
    /// Fill tunnels and pinholes narrower than about twice this many cells before the
    /// surface is taken (they are where no view constrained the density, each a handle
    /// of the mesh); 0 = none.
    #[arg(long, default_value_t = assist_session::DEFAULT_CLOSE)]
    pub close: u32,
    /// Largest number of triangles per node: more are reduced by quadric-error edge
    /// collapse, keeping the shape and the mesh closed; 0 = no limit.
    #[arg(long, default_value_t = DEFAULT_MAX_TRIANGLES)]
    pub triangles: usize,
    /// Points per node with --format points.
    #[arg(long, default_value_t = DEFAULT_POINTS)]
    pub points: usize,
    /// Also write a simulator model that places the meshes at the nodes' poses (needs
    /// --format obj).
    #[arg(long, value_enum)]
    pub sim: Option<SimArg>,
    /// Material density in kg/m³ for the masses and inertias of the model.
    #[arg(long, default_value_t = DEFAULT_MATERIAL_DENSITY)]
    pub material_density: f64,
    /// Replace an existing output folder that assist wrote.
    #[arg(long)]
    pub force: bool,
    /// Print a JSON summary on stdout (per node: file, vertices, triangles, closed, volume).
    #[arg(long)]
    pub json: bool,
}

pub fn job(a: &ExportArgs) -> ExportJob {
    ExportJob {
        nodes: a.node.clone(),
        format: match a.format {
            FormatArg::Ply => MeshFormat::Ply,
            FormatArg::Obj => MeshFormat::Obj,
            FormatArg::Glb => MeshFormat::Glb,
            FormatArg::Points => MeshFormat::Points,
        },
        frame: a.frame.map(|f| match f {
            FrameArg::World => MeshFrame::World,
            FrameArg::Node => MeshFrame::Node,
        }),
        sim: a.sim.map(|s| match s {
            SimArg::Mjcf => SimModel::Mjcf,
            SimArg::Urdf => SimModel::Urdf,
        }),
        extract: ExtractOptions {
            resolution: a.resolution,
            density: a.density,
            min_part: a.min_part,
            smooth: a.smooth,
            max_triangles: a.triangles,
            close: a.close,
            opacity: a.opacity,
        },
        points: a.points,
        material_density: a.material_density,
        out: a.out.clone(),
        force: a.force,
    }
}

pub fn run(a: ExportArgs) -> anyhow::Result<()> {
    assist_fs::check_replaceable_as(&a.out, a.force, assist_fs::Kind::Export)?;
    assist_fs::check_not_input(&a.out, &[a.scene.as_path()])?;
    let mut session =
        Session::open(&a.scene).with_context(|| format!("loading scene {}", a.scene.display()))?;
    let bar = crate::progress::bar(std::io::stderr().is_terminal(), "export");
    let quiet = a.json;
    let done = session.export(&job(&a), |k, n, node| {
        bar.set_length(n as u64);
        bar.set_position(k as u64 + 1);
        if !quiet {
            bar.suspend(|| {
                eprintln!(
                    "node {} {:?}: {} ({} vertices, {} triangles, {}{:.1} s)",
                    node.id,
                    node.label,
                    node.file,
                    node.vertices,
                    node.triangles,
                    match (node.volume_m3, node.genus) {
                        (Some(v), Some(g)) => format!("closed, genus {g}, {:.1} cm³, ", v * 1e6),
                        (Some(v), None) => format!("closed, {:.1} cm³, ", v * 1e6),
                        _ => "open, ".into(),
                    },
                    node.seconds
                );
                for w in &node.warnings {
                    eprintln!("warning: node {} {:?}: {w}", node.id, node.label);
                }
            });
        }
    })?;
    bar.finish_and_clear();
    if a.json {
        println!("{}", serde_json::to_string_pretty(&done)?);
    } else {
        eprintln!(
            "exported {} node(s) into {}{}",
            done.nodes.len(),
            done.out.display(),
            done.model
                .as_ref()
                .map(|m| format!(" with the model {m}"))
                .unwrap_or_default()
        );
    }
    Ok(())
}
