// The glass an orbital pad removes over a batch of control ticks (Rust side:
// src/ops/removal.rs, whose f64 `rate` and `remove_tick` are the reference and the native
// path): removed[pixel] += Σ_ticks seconds · rate(pixel centre − orbit centre) over the
// pixels of glass. One workgroup per 16 × 16 tile of the map walks the ticks whose
// footprint reaches the tile (binned on the host, in tick order), 256 at a time staged in
// workgroup memory; every pixel sums its ticks in order, so a batch gives the same bits
// every run. Where a tick's pad overhangs the rim of the glass somewhere on its orbit,
// the pressure at the pad's centre changes along the orbit (the force over the part on
// the glass): a pixel under the pad for part of the orbit integrates it over its arc
// with Gauss-Legendre's 16 points, as the reference does.

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
    // Radius of the glass, mm (a disc on the map's axis).
    glass: f32,
    pad0: u32,
}

const REMOVAL_TILE: u32 = 16u;
const REMOVAL_STAGE: u32 = 256u;
const REMOVAL_PI: f32 = 3.14159265358979;

@group(0) @binding(0) var<uniform> p: RemovalParams;

// Two vec4 per tick: (centre x, centre y, the orbit's mean pressure at the pad's centre,
// seconds), (gradient x, gradient y, force, 1 where the pad overhangs the rim or 0).
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

// x − sin x, by its series below 1 (src/ops/removal.rs `chord_segment`).
fn removal_chord_segment(x: f32) -> f32 {
    if x < 1.0 {
        let x2 = x * x;
        return x * x2 / 6.0
            * (1.0 - x2 / 20.0 * (1.0 - x2 / 42.0 * (1.0 - x2 / 72.0 * (1.0 - x2 / 110.0))));
    }
    return x - sin(x);
}

// The pressure at the pad's centre when that centre is at `c`: the force `force` over the
// part of the pad on the glass, (F + g·S)/A, S that part's first moment about the pad's
// centre (src/ops/removal.rs `on_glass`, `centre_pressure`).
fn removal_centre_pressure(force: f32, g: vec2<f32>, c: vec2<f32>) -> f32 {
    let a = p.radius;
    let big = p.glass;
    let d = length(c);
    var area = REMOVAL_PI * a * a;
    var s = vec2<f32>(0.0, 0.0);
    if d >= a + big {
        area = 0.0;
    } else if d + a > big {
        let h = ((d - big) * (d + big) + a * a) / (2.0 * d);
        let hg = d - h;
        let w = sqrt(max(a * a - h * h, 0.0));
        let small = a * a * acos(clamp(h / a, -1.0, 1.0)) - h * w;
        let glass = 0.5 * big * big * removal_chord_segment(2.0 * atan2(w, hg));
        area = small + glass;
        s = -c * glass;
    }
    return (max(force, 0.0) + dot(g, s)) / max(area, 0.25 * REMOVAL_PI * a * a);
}

// Gauss-Legendre's 16-point rule, its positive half: (node, weight).
const REMOVAL_ARC = array<vec2<f32>, 8>(
    vec2<f32>(0.0950125098376374, 0.1894506104550685),
    vec2<f32>(0.2816035507792589, 0.1826034150449236),
    vec2<f32>(0.4580167776572274, 0.1691565193950025),
    vec2<f32>(0.6178762444026438, 0.1495959888165767),
    vec2<f32>(0.7554044083550030, 0.1246289712555339),
    vec2<f32>(0.8656312023878318, 0.0951585116824928),
    vec2<f32>(0.9445750230732326, 0.0622535239386479),
    vec2<f32>(0.9894009349916499, 0.0271524594117541),
);

// The removal rate, nm/s, at offset `d` (mm) from the orbit's centre `centre` under the
// orbit's mean pressure `mean`, pressure gradient `g`, force `force`, `rim` whether the
// pad overhangs the rim (src/ops/removal.rs `rate`).
fn removal_rate(centre: vec2<f32>, mean: f32, g: vec2<f32>, force: f32, rim: bool,
                d: vec2<f32>) -> f32 {
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
    var arc = mean * beta;
    if rim && r > big - e {
        let theta = atan2(d.y, d.x);
        var sum = 0.0;
        var nodes = REMOVAL_ARC;
        for (var k = 0u; k < 8u; k++) {
            let node = nodes[k];
            let up = theta + beta * node.x;
            let down = theta - beta * node.x;
            sum += node.y * (
                removal_centre_pressure(force, g, centre + e * vec2<f32>(cos(up), sin(up)))
                + removal_centre_pressure(force, g, centre + e * vec2<f32>(cos(down), sin(down))));
        }
        arc = 0.5 * beta * sum;
    }
    var lever = 0.0;
    if r > 0.0 {
        lever = beta - e * sin(beta) / r;
    }
    let pressure = (arc - dot(g, d) * lever) / REMOVAL_PI;
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
                acc += a.w * removal_rate(a.xy, a.z, b.xy, b.z, b.w > 0.5, at - a.xy);
            }
        }
    }
    if on {
        removed[i] += acc;
    }
}
