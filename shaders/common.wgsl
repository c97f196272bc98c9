// Helpers shared by every op shader. The Rust side (src/gpu/pipeline.rs) prepends this
// file to each shaders/*.wgsl before compiling, so nothing here is copied by hand.

// Flat index of a 1-D kernel whose grid was folded into x and y by gpu::grid_1d.
fn flat_index(wg: vec3<u32>, num_wg: vec3<u32>, local: u32, size: u32) -> u32 {
    return (wg.y * num_wg.x + wg.x) * size + local;
}

fn relu(x: f32) -> f32 {
    return max(x, 0.0);
}

// Logistic sigmoid that never exponentiates a positive number (no overflow to inf).
fn sigmoid(x: f32) -> f32 {
    let e = exp(-abs(x));
    let s = 1.0 / (1.0 + e);
    return select(e * s, s, x >= 0.0);
}

// tanh that stays finite for large |x| on every driver (some expand tanh into exp(2x)).
fn tanh_stable(x: f32) -> f32 {
    let e = exp(-2.0 * abs(x));
    return sign(x) * (1.0 - e) / (1.0 + e);
}
