//! The per-field parts of the WGSL: every size and offset of a field's nets written as a
//! constant, so that the driver unrolls the products and keeps partial sums in registers.

use assist_field::{Field, Linear};

use crate::{Gpu, GpuError};

mod train;
pub(crate) use train::{dw_groups, dw_layers, train_header};

/// Rows of activations a field's nets need at most (the widest layer input or output).
pub(crate) fn max_rows(field: &Field) -> usize {
    let c = &field.config;
    [
        c.encoding_width(),
        c.hidden,
        1 + c.geo_features,
        c.geo_features + c.sh_width(),
        c.color_hidden,
        3,
    ]
    .into_iter()
    .max()
    .unwrap_or(1)
}

/// Samples per workgroup: the adapter's subgroup size within 32–64 (one subgroup per
/// workgroup, so the barriers between layers wait for no other; faster than 64 on NVIDIA,
/// see BENCHMARKS.md), else the largest smaller of 32, 16 whose two activation buffers
/// (rows of TILE + 4 floats in the weight-gradient kernels) fit the adapter's workgroup
/// memory and invocation limits. `ASSIST_GPU_TILE` (16, 32 or 64) puts that size first,
/// for benchmarks.
pub(crate) fn tile(gpu: &Gpu, field: &Field) -> Result<u32, GpuError> {
    let l = &gpu.limits;
    let rows = max_rows(field) as u64;
    let first = match env_u32("ASSIST_GPU_TILE", "16, 32 or 64", |t| {
        matches!(t, 16 | 32 | 64)
    })? {
        Some(t) => t,
        None => gpu.info.subgroup_max_size.clamp(32, 64),
    };
    [64u32, 32, 16]
        .into_iter()
        .filter(|&t| t <= first)
        .find(|&t| {
            2 * rows * (t as u64 + 4) * 4 <= l.max_compute_workgroup_storage_size as u64
                && t <= l.max_compute_invocations_per_workgroup
                && t <= l.max_compute_workgroup_size_x
        })
        .ok_or_else(|| GpuError::Device {
            adapter: gpu.info.name.clone(),
            message: format!(
                "a field {rows} features wide needs {} bytes of workgroup memory for 16 samples; the adapter has {}",
                2 * rows * 20 * 4,
                l.max_compute_workgroup_storage_size
            ),
        })
}

/// An environment variable that overrides a kernel setting for benchmarks: `None` when
/// unset; an error naming it and what was `expected` when not a number that `ok` accepts.
pub(crate) fn env_u32(
    name: &str,
    expected: &str,
    ok: impl Fn(u32) -> bool,
) -> Result<Option<u32>, GpuError> {
    let Ok(v) = std::env::var(name) else {
        return Ok(None);
    };
    match v.trim().parse::<u32>() {
        Ok(n) if ok(n) => Ok(Some(n)),
        _ => Err(GpuError::Run(format!(
            "{name}: expected {expected}, got {v:?}"
        ))),
    }
}

/// Rows of a training record per sample (tile-blocked like the features): what the
/// forward pass keeps for the backward pass, and the gradients the backward pass keeps for
/// the weight gradients.
#[derive(Debug, Clone)]
pub(crate) struct TapeRows {
    /// Density net hidden layer (post-ReLU), density net output (raw σ, geometry).
    pub hidden: usize,
    pub dens: usize,
    /// The colour net's product inputs (geometry + SH).
    pub cin: usize,
    /// The colour net's hidden outputs (post-ReLU), one per hidden layer.
    pub color: Vec<usize>,
    /// rgb after the sigmoid, σ after the exponential.
    pub rgb: usize,
    pub sigma: usize,
    pub total: usize,
    /// Gradients at the pre-activations: colour layers (last: rgb), density 1, density 0.
    pub d_color: Vec<usize>,
    pub d_dens: usize,
    pub d_hidden: usize,
    pub d_total: usize,
}

impl TapeRows {
    pub(crate) fn new(field: &Field) -> Self {
        let c = &field.config;
        let l = &field.layout;
        let mut r = 0;
        let mut take = |n: usize| {
            r += n;
            r - n
        };
        let hidden = take(c.hidden);
        let dens = take(1 + c.geo_features);
        let cin = take(c.geo_features + c.sh_width());
        let color = l.color[..l.color.len() - 1]
            .iter()
            .map(|ly| take(ly.out))
            .collect();
        let rgb = take(3);
        let sigma = take(1);
        let total = r;
        let mut r = 0;
        let mut take = |n: usize| {
            r += n;
            r - n
        };
        let d_color = l.color.iter().map(|ly| take(ly.out)).collect();
        let d_dens = take(1 + c.geo_features);
        let d_hidden = take(c.hidden);
        TapeRows {
            hidden,
            dens,
            cin,
            color,
            rgb,
            sigma,
            total,
            d_color,
            d_dens,
            d_hidden,
            d_total: r,
        }
    }
}

/// The WGSL constants and layer functions of one field configuration, prepended to the
/// shader. With `record`, the forward pass keeps a training record (`TapeRows`).
pub(crate) fn header(field: &Field, tile: u32, record: bool) -> String {
    let c = &field.config;
    let l = &field.layout;
    let nets = l.color.len();
    let t = TapeRows::new(field);
    let mut h = format!(
        "const LEVELS: u32 = {}u;\nconst FEAT: u32 = {}u;\nconst ENC_W: u32 = {}u;\n\
         const GEO: u32 = {}u;\nconst SH_DEGREE: u32 = {}u;\n\
         const APPEARANCE: bool = {};\nconst NUM_IMAGES: u32 = {}u;\n\
         const COLOR0_OUT: u32 = {}u;\nconst COLOR_RELU: bool = {};\n\
         const MAXW: u32 = {}u;\nconst TILE: u32 = {tile}u;\nconst Q: u32 = {}u;\n\
         const T_HIDDEN: u32 = {}u;\nconst T_DENS: u32 = {}u;\nconst T_CIN: u32 = {}u;\n\
         const T_RGB: u32 = {}u;\nconst T_SIGMA: u32 = {}u;\nconst T_ROWS: u32 = {}u;\n\
         const D_DENS: u32 = {}u;\nconst D_HIDDEN: u32 = {}u;\nconst D_ROWS: u32 = {}u;\n\
         const D_RGB: u32 = {}u;\nconst D_C0: u32 = {}u;\nconst HIDDEN: u32 = {}u;\n",
        c.levels,
        c.features_per_level,
        c.encoding_width(),
        c.geo_features,
        c.sh_degree,
        c.appearance_dim > 0,
        c.num_images,
        l.color[0].out,
        nets > 1,
        max_rows(field),
        tile / 4,
        t.hidden,
        t.dens,
        t.cin,
        t.rgb,
        t.sigma,
        t.total,
        t.d_dens,
        t.d_hidden,
        t.d_total,
        t.d_color[nets - 1],
        t.d_color[0],
        c.hidden,
    );
    h += if record {
        "fn record_rows(id: u32, rows: u32, at: u32, tile: u32, t: u32) {\n\
         \x20   let base = tile * T_ROWS * TILE + t;\n\
         \x20   for (var r = 0u; r < rows; r++) {\n\
         \x20       tape[base + (at + r) * TILE] = get_buf(id, r, t);\n\
         \x20   }\n}\n\
         fn record_out(tile: u32, t: u32, rgb: vec3<f32>, sigma: f32) {\n\
         \x20   let base = tile * T_ROWS * TILE + t;\n\
         \x20   tape[base + T_RGB * TILE] = rgb.x;\n\
         \x20   tape[base + (T_RGB + 1u) * TILE] = rgb.y;\n\
         \x20   tape[base + (T_RGB + 2u) * TILE] = rgb.z;\n\
         \x20   tape[base + T_SIGMA * TILE] = sigma;\n}\n"
    } else {
        "fn record_rows(id: u32, rows: u32, at: u32, tile: u32, t: u32) {}\n\
         fn record_out(tile: u32, t: u32, rgb: vec3<f32>, sigma: f32) {}\n"
    };
    let d = &l.density;
    let fwd = |name: &str, ly: &Linear, cols, src, dst, bias: bool, relu| {
        layer_fn(
            &Layer {
                name,
                rows: ly.out,
                cols,
                w: ly.w,
                rs: ly.inp_pad,
                cs: 1,
                bias: bias.then_some(ly.b),
                src,
                dst,
                relu,
            },
            tile,
        )
    };
    h += &fwd("layer0", &d[0], c.encoding_width(), "WA", "WB", true, true);
    h += &fwd("layer1", &d[1], c.hidden, "WB", "WA", true, false);
    h +=
        "fn density_layers(t: u32) {\n    layer0(t);\n    workgroupBarrier();\n    layer1(t);\n}\n";
    // The colour net's first layer over geometry + SH (the code is added per sample).
    let cols0 = c.geo_features + c.sh_width();
    h += &fwd("color0", &l.color[0], cols0, "WB", "WA", false, false);
    let mut body = String::new();
    for (k, ly) in l.color.iter().enumerate().skip(1) {
        let name = format!("color{k}");
        let (src, dst) = if k % 2 == 1 {
            ("WA", "WB")
        } else {
            ("WB", "WA")
        };
        h += &fwd(&name, ly, l.color[k - 1].out, src, dst, true, k + 1 < nets);
        if k > 1 {
            // The previous layer's output is complete; keep it for training.
            body += "    workgroupBarrier();\n";
            body += &format!(
                "    record_rows({src}_ID, {}u, {}u, tile, t);\n",
                l.color[k - 1].out,
                t.color[k - 1]
            );
        }
        body += &format!("    {name}(t);\n");
    }
    let last = if nets.is_multiple_of(2) { "WB" } else { "WA" };
    h += &format!(
        "fn color_rest(tile: u32, t: u32) {{\n{body}}}\n\
         fn rgb_row(r: u32, t: u32) -> f32 {{\n    return {last}[r * Q + t / 4u][t % 4u];\n}}\n\
         const T_COLOR0: u32 = {}u;\n",
        t.color.first().copied().unwrap_or(0)
    );
    h
}

/// One product as the shader runs it: `dst[r] = act(Σ_k A[r][k] src[k] + b[r])` for
/// `r < rows`, `k < cols`, with `A[r][k] = params[w + r·rs + k·cs]` (a layer's weights, or
/// their transpose for the backward pass).
pub(crate) struct Layer<'a> {
    pub name: &'a str,
    pub rows: usize,
    pub cols: usize,
    pub w: usize,
    pub rs: usize,
    pub cs: usize,
    /// The bias's offset in the parameters, if one is added here.
    pub bias: Option<usize>,
    /// Workgroup buffers read and written.
    pub src: &'a str,
    pub dst: &'a str,
    pub relu: bool,
}

/// A WGSL function computing a [`Layer`] over the workgroup's samples: invocation t takes
/// 4 rows (row block `t / SB`, then every 16th) for 16 samples (block `t % SB`),
/// accumulating 16 vec4s (one per sample, over the 4 rows).
pub(crate) fn layer_fn(y: &Layer, tile: u32) -> String {
    let sb = tile / 16;
    let ob = y.rows.div_ceil(4);
    let (w, rs, cs, om1) = (y.w, y.rs, y.cs, y.rows - 1);
    let mut f = format!("fn {}(t: u32) {{\n    let sb = t % {sb}u;\n", y.name);
    f += &format!(
        "    for (var ob = t / {sb}u; ob < {ob}u; ob += 16u) {{\n        let o0 = ob * 4u;\n"
    );
    for r in 0..4 {
        f += &format!("        let r{r} = {w}u + min(o0 + {r}u, {om1}u) * {rs}u;\n");
    }
    for j in 0..16 {
        f += &format!("        var a{j} = vec4<f32>(0.0);\n");
    }
    f += &format!("        for (var k = 0u; k < {}u; k++) {{\n", y.cols);
    f += &format!("            let kc = k * {cs}u;\n");
    f += "            let wv = vec4<f32>(params[r0 + kc], params[r1 + kc], params[r2 + kc], params[r3 + kc]);\n";
    f += "            let base = k * Q + sb * 4u;\n";
    for q in 0..4 {
        f += &format!("            let x{q} = {}[base + {q}u];\n", y.src);
    }
    for j in 0..16 {
        let comp = ["x", "y", "z", "w"][j % 4];
        f += &format!(
            "            a{j} = fma(wv, vec4<f32>(x{}.{comp}), a{j});\n",
            j / 4
        );
    }
    f += "        }\n";
    for r in 0..4 {
        f += &format!("        if (o0 + {r}u < {}u) {{\n", y.rows);
        let b = match y.bias {
            Some(b) => format!("params[{b}u + o0 + {r}u]"),
            None => "0.0".into(),
        };
        f += &format!(
            "            let b = vec4<f32>({b});\n            let row = (o0 + {r}u) * Q + sb * 4u;\n"
        );
        let comp = ["x", "y", "z", "w"][r];
        for q in 0..4 {
            let v = format!(
                "vec4<f32>(a{}.{comp}, a{}.{comp}, a{}.{comp}, a{}.{comp}) + b",
                4 * q,
                4 * q + 1,
                4 * q + 2,
                4 * q + 3
            );
            let v = if y.relu {
                format!("max({v}, vec4<f32>(0.0))")
            } else {
                v
            };
            f += &format!("            {}[row + {q}u] = {v};\n", y.dst);
        }
        f += "        }\n";
    }
    f += "    }\n}\n";
    f
}
