// The training half of the field on the GPU, appended to field.wgsl (whose forward pass,
// compiled with recording on, fills `tape`). Written per field above: `grad_add`,
// `sums_add`, `sums_get` (float atomics, or a compare-exchange loop where the adapter has
// none), `backward_nets` with its ReLU masks and the weight-gradient kernels `dw_*`.

// What the forward pass kept, per tile: T_ROWS rows of TILE lanes (see `TapeRows`).
@group(1) @binding(0) var<storage, read_write> tape: array<f32>;
// Gradients at each layer's pre-activation, per tile: D_ROWS rows of TILE lanes.
@group(1) @binding(1) var<storage, read_write> dtape: array<f32>;
// Gradient of the loss at the encoded features (laid out as `enc`).
@group(1) @binding(2) var<storage, read_write> d_enc: array<f32>;
// The loss's gradient: dL/dσ (n), then dL/drgb interleaved (3n).
@group(1) @binding(3) var<storage, read_write> d_out: array<f32>;
// dL/dθ, laid out as `params`; summed into by atomics.
@group(1) @binding(4) var<storage, read_write> grad: array<GRAD_T>;
// Per appearance code (average last), Σ over its samples of dL/d(first colour layer
// pre-activation).
@group(1) @binding(5) var<storage, read_write> code_sums: array<GRAD_T>;

// The weight-gradient kernels' staging: rows of TILE / 4 vec4s (4 samples each) plus one,
// so that rows 1 apart start 4 banks apart and the 16 rows a warp reads at once spread
// over the banks.
const ROW4: u32 = TILE / 4u + 1u;
var<workgroup> DS: array<vec4<f32>, MAXW * ROW4>;
var<workgroup> XS: array<vec4<f32>, MAXW * ROW4>;

// Keeps rows of WA/WB (lane t) as pre-activation gradients at dtape rows from `at`.
fn keep_d(id: u32, rows: u32, at: u32, tile: u32, t: u32) {
    let base = tile * D_ROWS * TILE + t;
    for (var r = 0u; r < rows; r++) {
        dtape[base + (at + r) * TILE] = get_buf(id, r, t);
    }
}

// dL/dθ of the hash-grid entries from dL/d(features): 8 corners × F per level and sample.
@compute @workgroup_size(64)
fn encode_backward(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nw: vec3<u32>) {
    let s = gid.x + gid.y * nw.x * 64u;
    if (s >= call.n) {
        return;
    }
    let pc = clamp(position(s), vec3<f32>(0.0), vec3<f32>(1.0));
    let eb = (s / TILE) * ENC_W * TILE + s % TILE;
    for (var l = 0u; l < LEVELS; l++) {
        let lv = levels[l];
        var de: array<f32, FEAT>;
        var any = false;
        for (var j = 0u; j < FEAT; j++) {
            de[j] = d_enc[eb + (l * FEAT + j) * TILE];
            any = any || de[j] != 0.0;
        }
        if (!any) {
            continue;
        }
        let cl = cell(lv, pc);
        for (var k = 0u; k < 8u; k++) {
            let cn = corner(lv, cl, k);
            let base = (lv.w + cn.idx) * FEAT;
            for (var j = 0u; j < FEAT; j++) {
                grad_add(base + j, cn.w * de[j]);
            }
        }
    }
}

// Σ per appearance code of the first colour layer's pre-activation gradient: one
// workgroup per tile, an invocation per output, one atomic per run of equal codes.
@compute @workgroup_size(TILE)
fn code_sums_of_tile(
    @builtin(local_invocation_index) t: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nw: vec3<u32>,
) {
    let n = call.n;
    let tile = wid.x + wid.y * nw.x;
    let d0 = tile * D_ROWS * TILE + D_C0 * TILE;
    for (var o = t; o < COLOR0_OUT; o += TILE) {
        var slot = 0xffffffffu;
        var acc = 0.0;
        for (var l = 0u; l < TILE; l++) {
            let s = tile * TILE + l;
            if (s >= n) {
                break;
            }
            let sl = min(image[s], NUM_IMAGES);
            if (sl != slot) {
                if (slot != 0xffffffffu) {
                    sums_add(slot * COLOR0_OUT + o, acc);
                }
                slot = sl;
                acc = 0.0;
            }
            acc += dtape[d0 + o * TILE + l];
        }
        if (slot != 0xffffffffu) {
            sums_add(slot * COLOR0_OUT + o, acc);
        }
    }
}

// The appearance part of the first colour layer from the per-code sums: the codes'
// gradients (the average code's spread evenly over every image) and the code columns'
// weight gradients.
@compute @workgroup_size(64)
fn code_backward(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    let a = max(APP_DIM, 1u);
    let ni = NUM_IMAGES;
    let spread = 1.0 / f32(max(ni, 1u));
    if (i < ni * a) {
        let img = i / a;
        let k = i % a;
        var d = 0.0;
        for (var o = 0u; o < COLOR0_OUT; o++) {
            let w = params[C0_W + o * C0_PAD + K0 + k];
            d += w * (sums_get(img * COLOR0_OUT + o) + sums_get(ni * COLOR0_OUT + o) * spread);
        }
        grad_add(APP + img * a + k, d);
    } else if (i < ni * a + COLOR0_OUT * a) {
        let j = i - ni * a;
        let o = j / a;
        let k = j % a;
        var avg = 0.0;
        var d = 0.0;
        for (var sl = 0u; sl < ni; sl++) {
            let code = params[APP + sl * a + k];
            avg += code;
            d += sums_get(sl * COLOR0_OUT + o) * code;
        }
        d += sums_get(ni * COLOR0_OUT + o) * avg * spread;
        grad_add(C0_W + o * C0_PAD + K0 + k, d);
    }
}
