// The node field on the GPU: hash-grid encoding, density net, colour net; f32 throughout
// (the CPU reference's arithmetic, so the two agree to rounding).
//
// Two kernels per call. `encode` runs one invocation per sample with no workgroup memory
// (so that many are in flight to hide the table gathers' latency) and writes the features
// tile-blocked to `enc`. The nets then take TILE samples per workgroup: the features are
// loaded into workgroup memory and the products run cooperatively, each invocation
// computing 4 outputs × 16 samples in registers (64 multiply-adds per 4 weight and 4 vec4
// activation loads), activations [feature][sample] ping-ponging between WA and WB.
//
// Written per field by `assist-gpu` above this line: the constants LEVELS, FEAT, ENC_W,
// GEO, SH_DEGREE, APPEARANCE, NUM_IMAGES, COLOR0_OUT, COLOR_RELU, MAXW, TILE, Q (TILE / 4),
// and the layer functions `density_layers`, `color0`, `color_rest` and `rgb_row`, with every
// size and offset a constant.

struct Call {
    n: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

// The flat parameter vector of `assist_field::Field` (grid entries, then the layers).
@group(0) @binding(0) var<storage, read> params: array<f32>;
// Per level: cells per axis, table entries, dense (1) or hashed (0), first entry.
@group(0) @binding(1) var<storage, read> levels: array<vec4<u32>>;
// The first colour layer's bias per appearance code, average code last (`code_biases`).
@group(0) @binding(2) var<storage, read> code_bias: array<f32>;
// Samples, structure of arrays: x, y, z (in [0, 1]), then dx, dy, dz (unit), n each.
@group(0) @binding(3) var<storage, read> samples: array<f32>;
// Appearance code per sample (u32::MAX: the average code).
@group(0) @binding(4) var<storage, read> image: array<u32>;
// σ (n), then rgb interleaved (3n).
@group(0) @binding(5) var<storage, read_write> out: array<f32>;
@group(0) @binding(6) var<uniform> call: Call;
// The encoded features, tile-blocked: sample s's feature f at
// (s / TILE) · ENC_W · TILE + f · TILE + s % TILE.
@group(0) @binding(7) var<storage, read_write> enc: array<f32>;

var<workgroup> WA: array<vec4<f32>, MAXW * Q>;
var<workgroup> WB: array<vec4<f32>, MAXW * Q>;
const WA_ID: u32 = 0u;
const WB_ID: u32 = 1u;

// Lane t's value of a row of WA (id 0) or WB (id 1).
fn get_buf(id: u32, row: u32, t: u32) -> f32 {
    if (id == WA_ID) {
        return WA[row * Q + t / 4u][t % 4u];
    }
    return WB[row * Q + t / 4u][t % 4u];
}
fn set_buf(id: u32, row: u32, t: u32, v: f32) {
    if (id == WA_ID) {
        WA[row * Q + t / 4u][t % 4u] = v;
    } else {
        WB[row * Q + t / 4u][t % 4u] = v;
    }
}

const MAX_RAW_DENSITY: f32 = 15.0;

fn get_a(row: u32, t: u32) -> f32 {
    return WA[row * Q + t / 4u][t % 4u];
}
fn set_a(row: u32, t: u32, v: f32) {
    WA[row * Q + t / 4u][t % 4u] = v;
}
fn set_b(row: u32, t: u32, v: f32) {
    WB[row * Q + t / 4u][t % 4u] = v;
}

// A position's cell at one level (lv: cells per axis, entries, dense, first entry) and
// its trilinear fractions within it; pc is in [0, 1]³.
struct Cell {
    c: vec3<u32>,
    f: vec3<f32>,
}

fn cell(lv: vec4<u32>, pc: vec3<f32>) -> Cell {
    let x = pc * f32(lv.x);
    let c = min(vec3<u32>(floor(x)), vec3<u32>(lv.x - 1u));
    return Cell(c, x - vec3<f32>(c));
}

// Corner k of a cell (bit 0: +x, 1: +y, 2: +z): its entry in the level's table (dense
// index, or the spatial hash `x·1 ⊕ y·2654435761 ⊕ z·805459861 mod T`) and its weight.
struct Corner {
    idx: u32,
    w: f32,
}

fn corner(lv: vec4<u32>, cl: Cell, k: u32) -> Corner {
    let d = vec3<u32>(k & 1u, (k >> 1u) & 1u, (k >> 2u) & 1u);
    let q = cl.c + d;
    var idx: u32;
    if (lv.z != 0u) {
        let side = lv.x + 1u;
        idx = q.x + side * (q.y + side * q.z);
    } else {
        idx = (q.x ^ (q.y * 2654435761u) ^ (q.z * 805459861u)) & (lv.y - 1u);
    }
    let wv = select(vec3<f32>(1.0) - cl.f, cl.f, d == vec3<u32>(1u));
    return Corner(idx, wv.x * wv.y * wv.z);
}

// The hash-grid features of sample s, written to `enc`.
fn encode_one(s: u32) {
    let pc = clamp(position(s), vec3<f32>(0.0), vec3<f32>(1.0));
    let at = (s / TILE) * ENC_W * TILE + s % TILE;
    for (var l = 0u; l < LEVELS; l++) {
        let lv = levels[l];
        let cl = cell(lv, pc);
        var acc: array<f32, FEAT>;
        for (var k = 0u; k < 8u; k++) {
            let cn = corner(lv, cl, k);
            let base = (lv.w + cn.idx) * FEAT;
            for (var j = 0u; j < FEAT; j++) {
                acc[j] += cn.w * params[base + j];
            }
        }
        for (var j = 0u; j < FEAT; j++) {
            enc[at + (l * FEAT + j) * TILE] = acc[j];
        }
    }
}

// Real spherical harmonics of a unit direction (tiny-cuda-nn's constants, as the CPU's
// `sh_encode`), written to WB's rows from `at` for lane t.
fn sh(d: vec3<f32>, t: u32, at: u32) {
    let x = d.x;
    let y = d.y;
    let z = d.z;
    set_b(at, t, 0.2820948);
    if (SH_DEGREE <= 1u) {
        return;
    }
    set_b(at + 1u, t, -0.4886025 * y);
    set_b(at + 2u, t, 0.4886025 * z);
    set_b(at + 3u, t, -0.4886025 * x);
    if (SH_DEGREE <= 2u) {
        return;
    }
    let xx = x * x;
    let yy = y * y;
    let zz = z * z;
    set_b(at + 4u, t, 1.0925484 * x * y);
    set_b(at + 5u, t, -1.0925484 * y * z);
    set_b(at + 6u, t, 0.9461747 * zz - 0.31539157);
    set_b(at + 7u, t, -1.0925484 * x * z);
    set_b(at + 8u, t, 0.5462742 * (xx - yy));
    if (SH_DEGREE <= 3u) {
        return;
    }
    set_b(at + 9u, t, 0.5900436 * y * (-3.0 * xx + yy));
    set_b(at + 10u, t, 2.8906114 * x * y * z);
    set_b(at + 11u, t, 0.4570458 * y * (1.0 - 5.0 * zz));
    set_b(at + 12u, t, 0.37317633 * z * (5.0 * zz - 3.0));
    set_b(at + 13u, t, 0.4570458 * x * (1.0 - 5.0 * zz));
    set_b(at + 14u, t, 1.4453057 * z * (xx - yy));
    set_b(at + 15u, t, 0.5900436 * x * (-xx + 3.0 * yy));
}

// This invocation's sample (clamped to the last for the tail of the batch, whose results
// are not written: every invocation takes part in the barriers).
fn sample_of(wid: vec3<u32>, nw: vec3<u32>, t: u32) -> u32 {
    return (wid.x + wid.y * nw.x) * TILE + t;
}

fn position(s: u32) -> vec3<f32> {
    let n = call.n;
    return vec3<f32>(samples[s], samples[n + s], samples[2u * n + s]);
}

@compute @workgroup_size(64)
fn encode(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nw: vec3<u32>) {
    let s = gid.x + gid.y * nw.x * 64u;
    if (s < call.n) {
        encode_one(s);
    }
}

// The features of this workgroup's samples into WA (tail lanes past the batch read
// whatever `enc` holds there; their results are never written).
fn load_features(wid: vec3<u32>, nw: vec3<u32>, t: u32) {
    let base = (wid.x + wid.y * nw.x) * ENC_W * TILE + t;
    for (var f = 0u; f < ENC_W; f++) {
        set_a(f, t, enc[base + f * TILE]);
    }
}

@compute @workgroup_size(TILE)
fn forward_nets(
    @builtin(local_invocation_index) t: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nw: vec3<u32>,
) {
    let n = call.n;
    let tile = wid.x + wid.y * nw.x;
    let s_out = sample_of(wid, nw, t);
    let s = min(s_out, n - 1u);
    load_features(wid, nw, t);
    workgroupBarrier();
    density_layers(t);
    workgroupBarrier();
    record_rows(WB_ID, HIDDEN, T_HIDDEN, tile, t);
    record_rows(WA_ID, 1u + GEO, T_DENS, tile, t);
    // Raw density in WA row 0, the geometry feature in rows 1…; the colour input to WB.
    let raw = get_a(0u, t);
    for (var g = 0u; g < GEO; g++) {
        set_b(g, t, get_a(1u + g, t));
    }
    sh(vec3<f32>(samples[3u * n + s], samples[4u * n + s], samples[5u * n + s]), t, GEO);
    record_rows(WB_ID, GEO + SH_DEGREE * SH_DEGREE, T_CIN, tile, t);
    workgroupBarrier();
    color0(t);
    workgroupBarrier();
    // The appearance code acts as the first colour layer's bias, per sample.
    var slot = 0u;
    if (APPEARANCE) {
        slot = min(image[s], NUM_IMAGES);
    }
    for (var o = 0u; o < COLOR0_OUT; o++) {
        let v = get_a(o, t) + code_bias[slot * COLOR0_OUT + o];
        set_a(o, t, select(v, max(v, 0.0), COLOR_RELU));
    }
    if (COLOR_RELU) {
        record_rows(WA_ID, COLOR0_OUT, T_COLOR0, tile, t);
    }
    workgroupBarrier();
    color_rest(tile, t);
    workgroupBarrier();
    let rgb = vec3<f32>(rgb_row(0u, t), rgb_row(1u, t), rgb_row(2u, t));
    let c = 1.0 / (1.0 + exp(-rgb));
    let sigma = exp(min(raw, MAX_RAW_DENSITY));
    record_out(tile, t, c, sigma);
    if (s_out < n) {
        out[s_out] = sigma;
        out[n + 3u * s_out] = c.x;
        out[n + 3u * s_out + 1u] = c.y;
        out[n + 3u * s_out + 2u] = c.z;
    }
}

@compute @workgroup_size(TILE)
fn density_nets(
    @builtin(local_invocation_index) t: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nw: vec3<u32>,
) {
    let n = call.n;
    let s_out = sample_of(wid, nw, t);
    load_features(wid, nw, t);
    workgroupBarrier();
    density_layers(t);
    workgroupBarrier();
    if (s_out < n) {
        out[s_out] = exp(min(get_a(0u, t), MAX_RAW_DENSITY));
    }
}
