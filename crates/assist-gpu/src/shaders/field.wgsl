// The node field on the GPU: hash-grid encoding, density net, colour net, one invocation
// per sample, f32 throughout (the CPU reference's arithmetic, so the two agree to rounding).
// The constants above this line (LEVELS, FEAT, ENC_W, GEO, SH_DEGREE, APPEARANCE,
// NUM_IMAGES, MAXW) and the layer functions (`layer0`, `layer1`, `color_net`) are written by
// `assist-gpu` per field, with every size and offset a constant: the driver then unrolls
// the products and keeps the activations in registers rather than in local memory.

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

const MAX_RAW_DENSITY: f32 = 15.0;

fn encode(p: vec3<f32>, enc: ptr<function, array<f32, MAXW>>) {
    for (var i = 0u; i < ENC_W; i++) {
        (*enc)[i] = 0.0;
    }
    let pc = clamp(p, vec3<f32>(0.0), vec3<f32>(1.0));
    for (var l = 0u; l < LEVELS; l++) {
        let lv = levels[l];
        let x = pc * f32(lv.x);
        let c = min(vec3<u32>(floor(x)), vec3<u32>(lv.x - 1u));
        let f = x - vec3<f32>(c);
        for (var k = 0u; k < 8u; k++) {
            let d = vec3<u32>(k & 1u, (k >> 1u) & 1u, (k >> 2u) & 1u);
            let q = c + d;
            var idx: u32;
            if (lv.z != 0u) {
                let s = lv.x + 1u;
                idx = q.x + s * (q.y + s * q.z);
            } else {
                idx = (q.x ^ (q.y * 2654435761u) ^ (q.z * 805459861u)) & (lv.y - 1u);
            }
            let wv = select(vec3<f32>(1.0) - f, f, d == vec3<u32>(1u));
            let w = wv.x * wv.y * wv.z;
            let base = (lv.w + idx) * FEAT;
            for (var j = 0u; j < FEAT; j++) {
                (*enc)[l * FEAT + j] += w * params[base + j];
            }
        }
    }
}

// Real spherical harmonics of a unit direction (tiny-cuda-nn's constants, as the CPU's
// `sh_encode`), written at y[at..].
fn sh(d: vec3<f32>, y: ptr<function, array<f32, MAXW>>, at: u32) {
    let x = d.x;
    let yy_ = d.y;
    let z = d.z;
    (*y)[at] = 0.2820948;
    if (SH_DEGREE <= 1u) {
        return;
    }
    (*y)[at + 1u] = -0.4886025 * yy_;
    (*y)[at + 2u] = 0.4886025 * z;
    (*y)[at + 3u] = -0.4886025 * x;
    if (SH_DEGREE <= 2u) {
        return;
    }
    let xx = x * x;
    let yy = yy_ * yy_;
    let zz = z * z;
    (*y)[at + 4u] = 1.0925484 * x * yy_;
    (*y)[at + 5u] = -1.0925484 * yy_ * z;
    (*y)[at + 6u] = 0.9461747 * zz - 0.31539157;
    (*y)[at + 7u] = -1.0925484 * x * z;
    (*y)[at + 8u] = 0.5462742 * (xx - yy);
    if (SH_DEGREE <= 3u) {
        return;
    }
    (*y)[at + 9u] = 0.5900436 * yy_ * (-3.0 * xx + yy);
    (*y)[at + 10u] = 2.8906114 * x * yy_ * z;
    (*y)[at + 11u] = 0.4570458 * yy_ * (1.0 - 5.0 * zz);
    (*y)[at + 12u] = 0.37317633 * z * (5.0 * zz - 3.0);
    (*y)[at + 13u] = 0.4570458 * x * (1.0 - 5.0 * zz);
    (*y)[at + 14u] = 1.4453057 * z * (xx - yy);
    (*y)[at + 15u] = 0.5900436 * x * (-xx + 3.0 * yy);
}

fn sample_index(gid: vec3<u32>, nw: vec3<u32>) -> u32 {
    return gid.x + gid.y * nw.x * 64u;
}

fn position(s: u32) -> vec3<f32> {
    let n = call.n;
    return vec3<f32>(samples[s], samples[n + s], samples[2u * n + s]);
}

// Encoding and density net; leaves raw density in a[0] and the geometry feature in a[1..].
fn density_net(s: u32, a: ptr<function, array<f32, MAXW>>, b: ptr<function, array<f32, MAXW>>) {
    encode(position(s), a);
    layer0(a, b);
    layer1(b, a);
}

@compute @workgroup_size(64)
fn forward(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nw: vec3<u32>) {
    let s = sample_index(gid, nw);
    let n = call.n;
    if (s >= n) {
        return;
    }
    var a: array<f32, MAXW>;
    var b: array<f32, MAXW>;
    density_net(s, &a, &b);
    let raw = a[0];
    for (var g = 0u; g < GEO; g++) {
        b[g] = a[1u + g];
    }
    let d = vec3<f32>(samples[3u * n + s], samples[4u * n + s], samples[5u * n + s]);
    sh(d, &b, GEO);
    // The colour net: geometry + SH through the products, the appearance code as the
    // first layer's bias.
    var slot = 0u;
    if (APPEARANCE) {
        slot = min(image[s], NUM_IMAGES);
    }
    let rgb = color_net(slot, &b, &a);
    out[s] = exp(min(raw, MAX_RAW_DENSITY));
    let c = 1.0 / (1.0 + exp(-rgb));
    out[n + 3u * s] = c.x;
    out[n + 3u * s + 1u] = c.y;
    out[n + 3u * s + 2u] = c.z;
}

@compute @workgroup_size(64)
fn density(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nw: vec3<u32>) {
    let s = sample_index(gid, nw);
    if (s >= call.n) {
        return;
    }
    var a: array<f32, MAXW>;
    var b: array<f32, MAXW>;
    density_net(s, &a, &b);
    out[s] = exp(min(a[0], MAX_RAW_DENSITY));
}
