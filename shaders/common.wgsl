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

// "lowbias32" integer hash (Chris Wellons): good avalanche, a few operations. Dropout's
// mask (model/block/residual_layer_norm/dropout_kernel.rs): element i of a training step is kept when
// lowbias32(i ^ key) >= threshold, key = lowbias32(seed ^ lowbias32(step)).
fn lowbias32(v: u32) -> u32 {
    var h = v;
    h ^= h >> 16u;
    h *= 0x7feb352du;
    h ^= h >> 15u;
    h *= 0x846ca68bu;
    h ^= h >> 16u;
    return h;
}

// tanh that stays finite for large |x| on every driver (some expand tanh into exp(2x)).
fn tanh_stable(x: f32) -> f32 {
    let e = exp(-2.0 * abs(x));
    return sign(x) * (1.0 - e) / (1.0 + e);
}

// A strided walk over flat indices j = o * inner + i (j = first, first + stride, ...) that
// keeps (o, i) up to date by a fixed step instead of dividing every j: an integer
// division per term, unvectorised, costs more than the loads on lavapipe.
struct FlatWalk {
    o: u32,
    i: u32,
    step_o: u32,
    step_i: u32,
    inner: u32,
}

fn flat_walk(first: u32, stride: u32, inner: u32) -> FlatWalk {
    return FlatWalk(first / inner, first % inner, stride / inner, stride % inner, inner);
}

fn flat_walk_next(w: FlatWalk) -> FlatWalk {
    var n = w;
    n.o += w.step_o;
    n.i += w.step_i;
    if n.i >= w.inner {
        n.i -= w.inner;
        n.o += 1u;
    }
    return n;
}
