//! The per-field WGSL of training: the backward pass through the nets with its ReLU
//! masks, and the weight-gradient kernels.

use assist_field::{Field, Linear};

use super::{Layer, TapeRows, env_u32, layer_fn};
use crate::GpuError;

/// Layers whose weight gradient a `dw_*` kernel computes: name, layer, where its inputs
/// are (`enc` rows, or tape rows from an offset), how many, and its gradient's dtape rows.
pub(crate) struct DwLayer {
    pub name: String,
    pub l: Linear,
    /// Tape row of the inputs, or `None` for the encoded features.
    pub x_at: Option<usize>,
    pub inputs: usize,
    pub d_at: usize,
}

/// The layers of a field in the order their weight gradients are computed.
pub(crate) fn dw_layers(field: &Field) -> Vec<DwLayer> {
    let c = &field.config;
    let l = &field.layout;
    let t = TapeRows::new(field);
    let mut v = vec![
        DwLayer {
            name: "dw_density0".into(),
            l: l.density[0],
            x_at: None,
            inputs: c.encoding_width(),
            d_at: t.d_hidden,
        },
        DwLayer {
            name: "dw_density1".into(),
            l: l.density[1],
            x_at: Some(t.hidden),
            inputs: c.hidden,
            d_at: t.d_dens,
        },
        DwLayer {
            name: "dw_color0".into(),
            l: l.color[0],
            x_at: Some(t.cin),
            inputs: c.geo_features + c.sh_width(),
            d_at: t.d_color[0],
        },
    ];
    for (k, ly) in l.color.iter().enumerate().skip(1) {
        v.push(DwLayer {
            name: format!("dw_color{k}"),
            l: *ly,
            x_at: Some(t.color[k - 1]),
            inputs: l.color[k - 1].out,
            d_at: t.d_color[k],
        });
    }
    v
}

/// The training part's per-field WGSL: atomics, constants, `backward_nets` and `dw_*`.
/// Layers must give at most 64 blocks of 4 outputs × 16 inputs (64-wide nets).
pub(crate) fn train_header(
    field: &Field,
    tile: u32,
    float_atomics: bool,
) -> Result<String, String> {
    let c = &field.config;
    let l = &field.layout;
    let t = TapeRows::new(field);
    let nets = l.color.len();
    let mut h = if float_atomics {
        "alias GRAD_T = atomic<f32>;\n\
         fn grad_add(i: u32, v: f32) {\n    atomicAdd(&grad[i], v);\n}\n\
         fn sums_add(i: u32, v: f32) {\n    atomicAdd(&code_sums[i], v);\n}\n\
         fn sums_get(i: u32) -> f32 {\n    return atomicLoad(&code_sums[i]);\n}\n"
            .to_string()
    } else {
        // A compare-exchange loop on the float's bits, for adapters without float atomics.
        let add = |name: &str, buf: &str| {
            format!(
                "fn {name}(i: u32, v: f32) {{\n\
                 \x20   var old = atomicLoad(&{buf}[i]);\n\
                 \x20   loop {{\n\
                 \x20       let r = atomicCompareExchangeWeak(&{buf}[i], old, bitcast<u32>(bitcast<f32>(old) + v));\n\
                 \x20       if (r.exchanged) {{\n            break;\n        }}\n\
                 \x20       old = r.old_value;\n\
                 \x20   }}\n}}\n"
            )
        };
        format!(
            "alias GRAD_T = atomic<u32>;\n{}{}\
             fn sums_get(i: u32) -> f32 {{\n    return bitcast<f32>(atomicLoad(&code_sums[i]));\n}}\n",
            add("grad_add", "grad"),
            add("sums_add", "code_sums")
        )
    };
    let c0 = &l.color[0];
    h += &format!(
        "const APP_DIM: u32 = {}u;\nconst APP: u32 = {}u;\nconst C0_W: u32 = {}u;\n\
         const C0_PAD: u32 = {}u;\nconst K0: u32 = {}u;\n",
        c.appearance_dim,
        l.appearance,
        c0.w,
        c0.inp_pad,
        c.geo_features + c.sh_width(),
    );
    // Backward through the nets: transposed products, ReLU masks from the record.
    let tr = |name: &str, ly: &Linear, rows: usize, src, dst| {
        layer_fn(
            &Layer {
                name,
                rows,
                cols: ly.out,
                w: ly.w,
                rs: 1,
                cs: ly.inp_pad,
                bias: None,
                src,
                dst,
                relu: false,
            },
            tile,
        )
    };
    let other = |b: &'static str| if b == "WA" { "WB" } else { "WA" };
    let mut cur = "WA";
    let mut body = String::from(
        "    let n = call.n;\n    let tile = wid.x + wid.y * nw.x;\n    let s_out = tile * TILE + t;\n\
         \x20   let valid = s_out < n;\n    let s = min(s_out, n - 1u);\n\
         \x20   let tb = tile * T_ROWS * TILE + t;\n\
         \x20   for (var k = 0u; k < 3u; k++) {\n\
         \x20       let y = tape[tb + (T_RGB + k) * TILE];\n\
         \x20       set_buf(WA_ID, k, t, select(0.0, d_out[n + 3u * s + k] * y * (1.0 - y), valid));\n\
         \x20   }\n",
    );
    for li in (1..nets).rev() {
        let ly = &l.color[li];
        let name = format!("tcolor{li}");
        let rows = l.color[li - 1].out;
        h += &tr(&name, ly, rows, cur, other(cur));
        let mask = format!("relu_color{}", li - 1);
        h += &relu_fn(&mask, other(cur), rows, t.color[li - 1]);
        body += &format!(
            "    keep_d({cur}_ID, {}u, {}u, tile, t);\n    workgroupBarrier();\n    {name}(t);\n\
             \x20   workgroupBarrier();\n    {mask}(tile, t);\n",
            ly.out, t.d_color[li],
        );
        cur = other(cur);
    }
    h += &tr("tcolor0", c0, c.geo_features, cur, other(cur));
    body += &format!(
        "    keep_d({cur}_ID, {}u, {}u, tile, t);\n    workgroupBarrier();\n    tcolor0(t);\n\
         \x20   workgroupBarrier();\n\
         \x20   set_buf({cur}_ID, 0u, t, select(0.0, d_out[s] * tape[tb + T_SIGMA * TILE], valid));\n\
         \x20   for (var g = 0u; g < GEO; g++) {{\n\
         \x20       set_buf({cur}_ID, 1u + g, t, get_buf({o}_ID, g, t));\n    }}\n\
         \x20   keep_d({cur}_ID, 1u + GEO, D_DENS, tile, t);\n    workgroupBarrier();\n",
        c0.out,
        t.d_color[0],
        o = other(cur),
    );
    let d = &l.density;
    h += &relu_fn("relu_hidden", other(cur), c.hidden, t.hidden);
    h += &tr("tdensity1", &d[1], c.hidden, cur, other(cur));
    h += &tr("tdensity0", &d[0], c.encoding_width(), other(cur), cur);
    body += &format!(
        "    tdensity1(t);\n    workgroupBarrier();\n\
         \x20   relu_hidden(tile, t);\n\
         \x20   keep_d({o}_ID, HIDDEN, D_HIDDEN, tile, t);\n    workgroupBarrier();\n\
         \x20   tdensity0(t);\n    workgroupBarrier();\n\
         \x20   let eb = tile * ENC_W * TILE + t;\n\
         \x20   for (var f = 0u; f < ENC_W; f++) {{\n\
         \x20       d_enc[eb + f * TILE] = get_buf({cur}_ID, f, t);\n    }}\n",
        o = other(cur),
    );
    h += &format!(
        "@compute @workgroup_size(TILE)\nfn backward_nets(\n\
         \x20   @builtin(local_invocation_index) t: u32,\n\
         \x20   @builtin(workgroup_id) wid: vec3<u32>,\n\
         \x20   @builtin(num_workgroups) nw: vec3<u32>,\n) {{\n{body}}}\n"
    );
    for y in dw_layers(field) {
        h += &dw_fn(&y, tile)?;
    }
    Ok(h)
}

/// ReLU backward for lane t: zeroes the gradient rows of `buf` (WA/WB) where the recorded
/// activation (tape rows from `at`) was not > 0. Every row's record is loaded before the
/// first store: loads interleaved with stores waited for each other, one memory latency
/// per row.
fn relu_fn(name: &str, buf: &str, rows: usize, at: usize) -> String {
    let mut f =
        format!("fn {name}(tile: u32, t: u32) {{\n    let base = tile * T_ROWS * TILE + t;\n");
    for r in 0..rows {
        f += &format!("    let m{r} = tape[base + {}u * TILE] > 0.0;\n", at + r);
    }
    for r in 0..rows {
        f += &format!("    if (!m{r}) {{\n        set_buf({buf}_ID, {r}u, t, 0.0);\n    }}\n");
    }
    f + "}\n"
}

/// Invocations of a weight-gradient workgroup: 16 output rows × 16 input rows.
pub(crate) const DW_THREADS: u32 = 256;

/// Workgroups of a weight-gradient dispatch at most (each loops over the tiles
/// `g, g + G, …` and adds its partial sums with one atomic per weight): enough to fill a
/// large GPU, few enough that the atomics stay a small share. `ASSIST_GPU_DW_GROUPS`
/// overrides it, for benchmarks.
pub(crate) fn dw_groups() -> Result<u32, GpuError> {
    Ok(env_u32("ASSIST_GPU_DW_GROUPS", "a positive number", |g| g > 0)?.unwrap_or(512))
}

/// A weight-gradient kernel: `dW[o][i] += Σ_s d[o][s] x[i][s]`, `db[o] += Σ_s d[o][s]`.
/// Each tile's `d` and `x` rows are staged in workgroup memory as vec4s of 4 samples
/// (rows padded by one vec4, so that the 16 rows a warp reads fall in different banks),
/// every load of a tile issued before the first store. Invocation t takes the outputs
/// `t / 16 + 16m` and inputs `t % 16 + 16j` (vec4 partial sums over samples), which also
/// keeps the reads of one warp conflict-free.
fn dw_fn(y: &DwLayer, tile: u32) -> Result<String, String> {
    let (out, inp) = (y.l.out, y.inputs);
    let (mo, mi) = (out.div_ceil(16), inp.div_ceil(16));
    if mo > 4 || mi > 4 {
        return Err(format!(
            "{}: {out} × {inp} is wider than the GPU training kernels take (at most 64 × 64)",
            y.name
        ));
    }
    let x = |e: &str| match y.x_at {
        Some(at) => format!("tape[tb * T_ROWS + {at}u * TILE + {e}]"),
        None => format!("enc[tb * ENC_W + {e}]"),
    };
    let d = |e: &str| format!("dtape[tb * D_ROWS + {}u * TILE + {e}]", y.d_at);
    let mut f = format!(
        "@compute @workgroup_size({DW_THREADS})\nfn {}(\n\
         \x20   @builtin(local_invocation_index) t: u32,\n\
         \x20   @builtin(workgroup_id) wid: vec3<u32>,\n\
         \x20   @builtin(num_workgroups) nw: vec3<u32>,\n) {{\n\
         \x20   let tiles = (call.n + TILE - 1u) / TILE;\n\
         \x20   let ob = t / 16u;\n    let ib = t % 16u;\n",
        y.name
    );
    for m in 0..mo {
        f += &format!(
            "    let o{m} = min(ob + {}u, {}u) * ROW4;\n",
            16 * m,
            out - 1
        );
        f += &format!("    var b{m} = vec4<f32>(0.0);\n");
    }
    for j in 0..mi {
        f += &format!(
            "    let i{j} = min(ib + {}u, {}u) * ROW4;\n",
            16 * j,
            inp - 1
        );
    }
    for m in 0..mo {
        for j in 0..mi {
            f += &format!("    var a{m}_{j} = vec4<f32>(0.0);\n");
        }
    }
    f += "    for (var tile = wid.x; tile < tiles; tile += nw.x) {\n\
          \x20       let tb = tile * TILE;\n        let lanes = min(TILE, call.n - tb);\n";
    // Staging: every load of the tile into registers first, then the stores.
    let stage = |f: &mut String, buf: &str, rows: usize, src: &dyn Fn(&str) -> String| {
        let total = rows as u32 * tile;
        let k = total.div_ceil(DW_THREADS);
        for q in 0..k {
            let e = format!("(t + {}u)", q * DW_THREADS);
            let load = format!("select(0.0, {}, {e} % TILE < lanes)", src(&e));
            if (q + 1) * DW_THREADS <= total {
                *f += &format!("        let v{q} = {load};\n");
            } else {
                *f += &format!(
                    "        var v{q} = 0.0;\n        if ({e} < {total}u) {{\n            v{q} = {load};\n        }}\n"
                );
            }
        }
        for q in 0..k {
            let e = format!("(t + {}u)", q * DW_THREADS);
            let store = format!("{buf}[({e} / TILE) * ROW4 + ({e} % TILE) / 4u][{e} % 4u] = v{q};");
            if (q + 1) * DW_THREADS <= total {
                *f += &format!("        {store}\n");
            } else {
                *f += &format!("        if ({e} < {total}u) {{\n            {store}\n        }}\n");
            }
        }
    };
    f += "        {\n";
    stage(&mut f, "DS", out, &d);
    f += "        }\n        {\n";
    stage(&mut f, "XS", inp, &x);
    f += "        }\n        workgroupBarrier();\n";
    f += &format!(
        "        if (ob < {out}u) {{\n            for (var q = 0u; q < TILE / 4u; q++) {{\n"
    );
    for m in 0..mo {
        f += &format!("                let d{m} = DS[o{m} + q];\n                b{m} += d{m};\n");
    }
    for j in 0..mi {
        f += &format!("                let x{j} = XS[i{j} + q];\n");
    }
    for m in 0..mo {
        for j in 0..mi {
            f += &format!("                a{m}_{j} = fma(d{m}, x{j}, a{m}_{j});\n");
        }
    }
    f += "            }\n        }\n        workgroupBarrier();\n    }\n";
    let sum = |v: &str| format!("{v}.x + {v}.y + {v}.z + {v}.w");
    for m in 0..mo {
        let o = format!("(ob + {}u)", 16 * m);
        f += &format!(
            "    if ({o} < {out}u) {{\n        let row = {}u + {o} * {}u;\n",
            y.l.w, y.l.inp_pad
        );
        for j in 0..mi {
            let i = format!("(ib + {}u)", 16 * j);
            f += &format!(
                "        if ({i} < {inp}u) {{\n            grad_add(row + {i}, {});\n        }}\n",
                sum(&format!("a{m}_{j}"))
            );
        }
        f += &format!(
            "        if (ib == 0u) {{\n            grad_add({}u + {o}, {});\n        }}\n    }}\n",
            y.l.b,
            sum(&format!("b{m}"))
        );
    }
    f += "}\n";
    Ok(f)
}
