// One Adam step over the flat parameter vector, as `assist_field::Adam::update`: moments
// flushed below 1e-30, gradients below 1e-17 counted as zero, entries of the sparse range
// (hash tables) with a zero gradient left alone and the others decayed by `table_decay`,
// L2 decay over the decay range; the gradient is zeroed for the next step. Then
// `refresh_codes` recomputes the first colour layer's per-code biases from the updated
// weights and codes.

struct Hyper {
    b1: f32,
    b2: f32,
    eps: f32,
    step_size: f32,
    inv_sqrt_c2: f32,
    weight_decay: f32,
    n: u32,
    decay_start: u32,
    decay_end: u32,
    sparse_start: u32,
    sparse_end: u32,
    // The first colour layer and the appearance codes (see `Field::code_biases`).
    c0_w: u32,
    c0_b: u32,
    c0_pad: u32,
    c0_out: u32,
    k0: u32,
    app: u32,
    app_dim: u32,
    images: u32,
    table_decay: f32,
}

@group(0) @binding(0) var<storage, read_write> p: array<f32>;
@group(0) @binding(1) var<storage, read_write> g: array<f32>;
@group(0) @binding(2) var<storage, read_write> m: array<f32>;
@group(0) @binding(3) var<storage, read_write> v: array<f32>;
@group(0) @binding(4) var<uniform> h: Hyper;
@group(0) @binding(5) var<storage, read_write> code_bias: array<f32>;

fn flush(x: f32) -> f32 {
    return select(x, 0.0, abs(x) < 1e-30);
}

@compute @workgroup_size(256)
fn adam(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nw: vec3<u32>) {
    let i = gid.x + gid.y * nw.x * 256u;
    if (i >= h.n) {
        return;
    }
    let raw = g[i];
    // Written only where it is not zero already: most table entries have no gradient.
    if (raw != 0.0) {
        g[i] = 0.0;
    }
    var gi = select(raw, 0.0, abs(raw) < 1e-17);
    let in_table = i >= h.sparse_start && i < h.sparse_end;
    if (gi == 0.0 && in_table) {
        // Left alone: its moments were flushed when last written, so flushing them again
        // would change nothing, and reading them would cost most of the step.
        return;
    }
    if (in_table) {
        gi += h.table_decay * p[i];
    }
    if (h.weight_decay != 0.0 && i >= h.decay_start && i < h.decay_end) {
        gi += h.weight_decay * p[i];
    }
    let mi = flush(h.b1 * m[i] + (1.0 - h.b1) * gi);
    let vi = flush(h.b2 * v[i] + (1.0 - h.b2) * gi * gi);
    m[i] = mi;
    v[i] = vi;
    p[i] -= h.step_size * mi / (sqrt(vi) * h.inv_sqrt_c2 + h.eps);
}

// The average code (the last slot's), computed by each workgroup of `refresh_codes`: one
// invocation per code dimension, four sums in flight (a thread per bias looping over every
// image, as before, waited on one load at a time and took most of an Adam step).
var<workgroup> avg: array<f32, 256>;

// code_bias[slot][o] = b[o] + W_app[o] · code(slot), the average code last.
@compute @workgroup_size(64)
fn refresh_codes(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(local_invocation_index) t: u32) {
    let images = h.images;
    for (var k = t; k < h.app_dim; k += 64u) {
        var a = vec4<f32>(0.0);
        var j = 0u;
        while (j + 4u <= images) {
            let at = h.app + j * h.app_dim + k;
            a += vec4<f32>(p[at], p[at + h.app_dim], p[at + 2u * h.app_dim], p[at + 3u * h.app_dim]);
            j += 4u;
        }
        while (j < images) {
            a.x += p[h.app + j * h.app_dim + k];
            j += 1u;
        }
        avg[k] = (a.x + a.y + a.z + a.w) / f32(max(images, 1u));
    }
    workgroupBarrier();
    let slots = select(1u, images + 1u, h.app_dim > 0u);
    let i = gid.x;
    if (i >= slots * h.c0_out) {
        return;
    }
    let slot = i / h.c0_out;
    let o = i % h.c0_out;
    var v = p[h.c0_b + o];
    let row = h.c0_w + o * h.c0_pad + h.k0;
    for (var k = 0u; k < h.app_dim; k++) {
        var code = avg[k];
        if (slot < images) {
            code = p[h.app + slot * h.app_dim + k];
        }
        v += p[row + k] * code;
    }
    code_bias[i] = v;
}
