// The glass an orbital pad removes over a batch of control ticks (Rust side:
// src/ops/removal.rs, whose f64 `rate` and `remove_tick` are the reference and the native
// path): removed[pixel] += Σ_ticks seconds · rate(pixel centre − orbit centre) over the
// pixels of glass. One workgroup per 16 × 16 tile of the map walks the ticks whose
// footprint reaches the tile (binned on the host, in tick order), 256 at a time staged in
// workgroup memory; every pixel sums its ticks in order, so a batch gives the same bits
// every run.

struct RemovalParams {
    // Pixels per side of the map, and 16-pixel tiles per side.
    n: u32,
    tiles: u32,
    // Pixel side, mm; pixel (row, col) has its centre at ((col + ½ − n/2)·pitch,
    // (row + ½ − n/2)·pitch).
    pitch: f32,
    // Pad radius R and orbit radius e, mm.
    radius: f32,
    orbit: f32,
    // Preston's K times the sliding speed, times 1e6 (mm → nm): nm/s per N/mm².
    scale: f32,
    pad0: u32,
    pad1: u32,
}

const REMOVAL_TILE: u32 = 16u;
const REMOVAL_STAGE: u32 = 256u;
const REMOVAL_PI: f32 = 3.14159265358979;

@group(0) @binding(0) var<uniform> p: RemovalParams;

// Two vec4 per tick: (centre x, centre y, mean pressure, seconds), (gradient x, gradient y,
// 0, 0).
@group(0) @binding(1) var<storage, read> ticks: array<vec4<f32>>;
// Per tile (row-major), where its ticks start in `tile_ticks`; one more than the tiles.
@group(0) @binding(2) var<storage, read> tile_start: array<u32>;
@group(0) @binding(3) var<storage, read> tile_ticks: array<u32>;
// Pixels of glass: bit (i & 31) of word i >> 5.
@group(0) @binding(4) var<storage, read> glass: array<u32>;
@group(0) @binding(5) var<storage, read_write> removed: array<f32>;

var<workgroup> staged: array<vec4<f32>, 512>;
var<workgroup> span_first: u32;
var<workgroup> span_last: u32;

// The removal rate, nm/s, at offset `d` (mm) from the orbit's centre under mean pressure
// `mean` and pressure gradient `g` (the closed form of src/ops/removal.rs `rate`).
fn removal_rate(mean: f32, g: vec2<f32>, d: vec2<f32>) -> f32 {
    let big = p.radius;
    let e = p.orbit;
    let r = length(d);
    if r >= big + e {
        return 0.0;
    }
    var beta = REMOVAL_PI;
    if r > big - e {
        beta = acos(clamp((r * r + e * e - big * big) / (2.0 * r * e), -1.0, 1.0));
    }
    var lever = 0.0;
    if r > 0.0 {
        lever = beta - e * sin(beta) / r;
    }
    let pressure = (mean * beta - dot(g, d) * lever) / REMOVAL_PI;
    return p.scale * max(pressure, 0.0);
}

@compute @workgroup_size(16, 16)
fn removal_accumulate(@builtin(workgroup_id) wg: vec3<u32>,
                      @builtin(local_invocation_id) lid: vec3<u32>,
                      @builtin(local_invocation_index) li: u32) {
    let col = wg.x * REMOVAL_TILE + lid.x;
    let row = wg.y * REMOVAL_TILE + lid.y;
    let i = row * p.n + col;
    var on = false;
    if col < p.n && row < p.n {
        on = ((glass[i >> 5u] >> (i & 31u)) & 1u) == 1u;
    }
    let half = 0.5 * f32(p.n);
    let at = vec2<f32>((f32(col) + 0.5 - half) * p.pitch, (f32(row) + 0.5 - half) * p.pitch);
    if li == 0u {
        let tile = wg.y * p.tiles + wg.x;
        span_first = tile_start[tile];
        span_last = tile_start[tile + 1u];
    }
    let first = workgroupUniformLoad(&span_first);
    let last = workgroupUniformLoad(&span_last);
    var acc = 0.0;
    for (var base = first; base < last; base += REMOVAL_STAGE) {
        let count = min(REMOVAL_STAGE, last - base);
        workgroupBarrier();
        if li < count {
            let t = tile_ticks[base + li];
            staged[2u * li] = ticks[2u * t];
            staged[2u * li + 1u] = ticks[2u * t + 1u];
        }
        workgroupBarrier();
        if on {
            for (var k = 0u; k < count; k++) {
                let a = staged[2u * k];
                let b = staged[2u * k + 1u];
                acc += a.w * removal_rate(a.z, b.xy, at - a.xy);
            }
        }
    }
    if on {
        removed[i] += acc;
    }
}
