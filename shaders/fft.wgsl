// Discrete Fourier transforms of any length along the rows of a batch (Rust side:
// src/ops/fft.rs, with its f64 DFT reference): Bluestein's chirp z-transform over a
// radix-2 Stockham FFT of the power of two `m ≥ 2n − 1`. A length-n transform of each row
// is `fft_chirp_load` (x·w into m-long rows, zero beyond n), log2 m `fft_pass`es,
// `fft_mul` by the chirp filter's spectrum (scaled by 1/m on the host), log2 m inverse
// `fft_pass`es and `fft_chirp_store` (w·y back into the rows, times `scale`). Complex
// numbers are vec2 (re, im); the twiddles, chirps and spectra come from the host in f64
// rounded to f32 (a shader's `cos` may be off by 2^-11).

struct FftParams {
    // The power-of-two length of the Stockham transforms and the rows transformed.
    m: u32,
    rows: u32,
    // `fft_pass`: the span already transformed (1, 2, 4, …, m/2); 1 for the inverse.
    ns: u32,
    inverse: u32,
    // `fft_chirp_load`/`store`: the transform's length and where element k of row r is in
    // the data: r·row_stride + k·elem_stride.
    n: u32,
    row_stride: u32,
    elem_stride: u32,
    // `fft_mul`: data[i] *= factor[i % period] for i < count.
    period: u32,
    count: u32,
    pad0: u32,
    // `fft_chirp_store`: a factor on every value written.
    scale: f32,
    pad1: u32,
}

const FFT_WG: u32 = 256u;

@group(0) @binding(0) var<uniform> p: FftParams;

fn cmul(a: vec2<f32>, b: vec2<f32>) -> vec2<f32> {
    return vec2<f32>(a.x * b.x - a.y * b.y, a.x * b.y + a.y * b.x);
}

// One radix-2 Stockham pass over every row (Govindaraju et al., "High performance
// discrete Fourier transforms on graphics processors", SC 2008, with R = 2): element j
// and j + m/2 of the input, the second turned by exp(∓2πi·(j mod ns)/(2·ns)), go to
// (j / ns)·2·ns + (j mod ns) and ns further. `twiddle[k]` = exp(−2πi·k/m), k < m/2.
@group(0) @binding(1) var<storage, read> twiddle: array<vec2<f32>>;
@group(0) @binding(2) var<storage, read> pass_in: array<vec2<f32>>;
@group(0) @binding(3) var<storage, read_write> pass_out: array<vec2<f32>>;

@compute @workgroup_size(256)
fn fft_pass(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
            @builtin(local_invocation_index) li: u32) {
    let t = flat_index(wg, nwg, li, FFT_WG);
    let half = p.m / 2u;
    if t >= p.rows * half {
        return;
    }
    let row = t / half;
    let j = t % half;
    let base = row * p.m;
    let k = j & (p.ns - 1u);
    var w = twiddle[k * (half / p.ns)];
    if p.inverse != 0u {
        w.y = -w.y;
    }
    let v0 = pass_in[base + j];
    let v1 = cmul(pass_in[base + j + half], w);
    let d = base + (j - k) * 2u + k;
    pass_out[d] = v0 + v1;
    pass_out[d + p.ns] = v0 - v1;
}

// data[i] *= factor[i % period], in place.
@group(0) @binding(1) var<storage, read> factor: array<vec2<f32>>;
@group(0) @binding(3) var<storage, read_write> product: array<vec2<f32>>;

@compute @workgroup_size(256)
fn fft_mul(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
           @builtin(local_invocation_index) li: u32) {
    let i = flat_index(wg, nwg, li, FFT_WG);
    if i >= p.count {
        return;
    }
    product[i] = cmul(product[i], factor[i % p.period]);
}

// Row r of the m-long work array: x[r, k]·chirp[k] for k < n, 0 beyond.
@group(0) @binding(1) var<storage, read> chirp: array<vec2<f32>>;
@group(0) @binding(2) var<storage, read> chirp_in: array<vec2<f32>>;
@group(0) @binding(3) var<storage, read_write> chirp_out: array<vec2<f32>>;

@compute @workgroup_size(256)
fn fft_chirp_load(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                  @builtin(local_invocation_index) li: u32) {
    let t = flat_index(wg, nwg, li, FFT_WG);
    if t >= p.rows * p.m {
        return;
    }
    let row = t / p.m;
    let k = t % p.m;
    var v = vec2<f32>(0.0, 0.0);
    if k < p.n {
        v = cmul(chirp_in[row * p.row_stride + k * p.elem_stride], chirp[k]);
    }
    chirp_out[t] = v;
}

// x[r, j] = scale · chirp[j]·y[r, j] for j < n, from the m-long work rows y.
@compute @workgroup_size(256)
fn fft_chirp_store(@builtin(workgroup_id) wg: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>,
                   @builtin(local_invocation_index) li: u32) {
    let t = flat_index(wg, nwg, li, FFT_WG);
    if t >= p.rows * p.n {
        return;
    }
    let row = t / p.n;
    let j = t % p.n;
    chirp_out[row * p.row_stride + j * p.elem_stride] = p.scale * cmul(chirp_in[row * p.m + j], chirp[j]);
}
