//! Recording a planned product: the kernel and its grid for the device, the override
//! constants, the uniform parameters, and the two launches of a split reduction.

use super::plan::{Gemm, Matmul, Plus, SplitLimits, Tiling};
use super::{
    subgroup_kernel_available, Epilogue, BLOCK, COLS_MAX_M, COLS_MIN_N, COLS_PER_GROUP, COLS_TILE,
    KERNEL, KERNEL_ROW, KERNEL_SUBGROUP, KERNEL_SUBGROUP_COLS, KERNEL_SUM, MAX_GROUP_Y, MAX_TILES,
    ROW_BLOCK, ROW_WORKGROUP, SUBGROUP_LANES, SUM_WORKGROUP, TILE_COLS, TILE_ROWS, WORKGROUP,
};
use crate::gpu::{grid_1d, DType, Dispatch, Gpu, GpuError, Kernel, Tensor};
use crate::ops::Accumulate;

crate::gpu::uniform! {
    pub(crate) struct Params = MatmulParams in super::SHADER {
        m: u32,
        n: u32,
        k: u32,
        reduce: u32,
        a_row: u32,
        a_col: u32,
        b_row: u32,
        b_col: u32,
        a_batch: u32,
        b_batch: u32,
        c_batch: u32,
        accumulate: u32,
        a_reduce: u32,
        b_reduce: u32,
        alpha: f32,
        batches: u32,
        chunk: u32,
        slices: u32,
        a_slice: u32,
        b_slice: u32,
    }
}

impl Matmul {
    /// `c (+)= op(a) · op(b)`.
    pub fn forward(
        &self,
        gpu: &Gpu,
        a: &Tensor,
        b: &Tensor,
        c: &Tensor,
        accumulate: Accumulate,
    ) -> Result<Dispatch, GpuError> {
        self.forward_with(gpu, a, b, c, accumulate, Epilogue::default())
    }

    /// `c = op(a) · op(b) (+ bias) (+ c)`, then ReLU if asked: the epilogue's bias `[m]` is
    /// added to row i of every batch item. Fusing a channel bias or an activation into the
    /// product saves a pass over `c`.
    pub fn forward_with(
        &self,
        gpu: &Gpu,
        a: &Tensor,
        b: &Tensor,
        c: &Tensor,
        accumulate: Accumulate,
        epilogue: Epilogue,
    ) -> Result<Dispatch, GpuError> {
        a.expect_len(self.a_len())?;
        b.expect_len(self.b_len())?;
        c.expect_len(self.c_len())?;
        self.check_epilogue(c, accumulate, &epilogue)?;
        self.check_identity(c)?;
        self.forward_gemm()
            .dispatch_with(gpu, a, b, c, accumulate, epilogue)
    }

    /// Refuses an epilogue the kernel cannot apply to this product's C: a bias or a
    /// matrix of the wrong length, both at once, a tensor not laid out like C, two
    /// activations, or a sigmoid's backward onto an accumulated C.
    fn check_epilogue(
        &self,
        c: &Tensor,
        accumulate: Accumulate,
        epilogue: &Epilogue,
    ) -> Result<(), GpuError> {
        if let Some(bias) = epilogue.bias {
            bias.expect_len(self.m)?;
        }
        if let Some(matrix) = epilogue.matrix {
            matrix.expect_len(self.m * self.n)?;
            if epilogue.bias.is_some() || self.n == 1 {
                return Err(GpuError::Shape {
                    tensor: matrix.name().to_string(),
                    expected: "a matrix added alone, to a product with more than one column".into(),
                    got: format!("{self:?} with a row bias too: {}", epilogue.bias.is_some()),
                });
            }
        }
        check_activation(c, self.c_len(), accumulate, epilogue)?;
        self.check_identity(c)
    }

    /// `da (+)= ∂L/∂a` given `dc = ∂L/∂c` (needs `b`).
    pub fn backward_a(
        &self,
        gpu: &Gpu,
        b: &Tensor,
        dc: &Tensor,
        da: &Tensor,
        accumulate: Accumulate,
    ) -> Result<Dispatch, GpuError> {
        b.expect_len(self.b_len())?;
        dc.expect_len(self.c_len())?;
        da.expect_len(self.a_len())?;
        self.check_identity(da)?;
        let (gemm, b_first) = self.backward_a_gemm();
        let (lhs, rhs) = if b_first { (b, dc) } else { (dc, b) };
        gemm.dispatch(gpu, lhs, rhs, da, accumulate)
    }

    /// `db (+)= ∂L/∂b` given `dc = ∂L/∂c` (needs `a`).
    pub fn backward_b(
        &self,
        gpu: &Gpu,
        a: &Tensor,
        dc: &Tensor,
        db: &Tensor,
        accumulate: Accumulate,
    ) -> Result<Dispatch, GpuError> {
        self.backward_b_with(gpu, a, dc, db, accumulate, Epilogue::default())
    }

    /// [`Matmul::backward_b`] with an epilogue on `db` (laid out like B): e.g. the
    /// backward of a sigmoid that produced B, `db = (op(a)ᵀ·dc) ⊙ s ⊙ (1 − s)`.
    pub fn backward_b_with(
        &self,
        gpu: &Gpu,
        a: &Tensor,
        dc: &Tensor,
        db: &Tensor,
        accumulate: Accumulate,
        epilogue: Epilogue,
    ) -> Result<Dispatch, GpuError> {
        a.expect_len(self.a_len())?;
        dc.expect_len(self.c_len())?;
        db.expect_len(self.b_len())?;
        if epilogue.bias.is_some() || epilogue.matrix.is_some() || epilogue.gate.is_some() {
            return Err(GpuError::Shape {
                tensor: db.name().to_string(),
                expected: "an activation alone in the epilogue of a gradient".into(),
                got: format!("{epilogue:?}"),
            });
        }
        check_activation(db, self.b_len(), accumulate, &epilogue)?;
        let (gemm, dc_first) = self.backward_b_gemm();
        let (lhs, rhs) = if dc_first { (dc, a) } else { (a, dc) };
        gemm.dispatch_with(gpu, lhs, rhs, db, accumulate, epilogue)
    }
}

/// The epilogue's activation on an output of `len` elements: at most one, the tensor it
/// reads laid out like the output, and a sigmoid's backward never onto an accumulation.
fn check_activation(
    out: &Tensor,
    len: usize,
    accumulate: Accumulate,
    epilogue: &Epilogue,
) -> Result<(), GpuError> {
    if let Some(t) = epilogue.like_c() {
        t.expect_len(len)?;
    }
    let activations = [
        epilogue.relu,
        epilogue.gate.is_some(),
        epilogue.sigmoid,
        epilogue.sigmoid_backward.is_some(),
    ];
    if activations.iter().filter(|&&a| a).count() > 1 {
        return Err(GpuError::Shape {
            tensor: out.name().to_string(),
            expected: "one of ReLU, gate, sigmoid or its backward in an epilogue".into(),
            got: format!("{epilogue:?}"),
        });
    }
    if epilogue.sigmoid_backward.is_some() && accumulate == Accumulate::Add {
        return Err(GpuError::Shape {
            tensor: out.name().to_string(),
            expected: "a sigmoid's backward overwriting its output".into(),
            got: "accumulation onto it".into(),
        });
    }
    Ok(())
}

impl Gemm {
    /// Invocations per workgroup along n, m and the batch for the block kernel, from
    /// measurements on lavapipe (which runs 8 consecutive invocations as SIMD lanes: they
    /// had better differ in the column, sharing A, so always 8 along x):
    /// - one output (a weight gradient summed over the batch): 8×1×1, as many groups as
    ///   possible to keep every thread busy (1.3× over 8×8 on the paper's conv weight);
    /// - per-item outputs of at most two block rows or 48 blocks: 8×1×8, packing eight
    ///   batch items to a group (1.8–2.3× over 8×8 on the small shape's products);
    /// - otherwise 8×8×1 (64×64 outputs per group).
    ///
    /// Batched products whose items end mid-group along n run on a flat grid instead
    /// (see [`Gemm::block_grid`]).
    fn group(&self, batches: usize) -> [usize; 3] {
        let (nx, ny) = (self.n.div_ceil(BLOCK), self.m.div_ceil(BLOCK));
        if batches == 1 {
            [WORKGROUP, 1, 1]
        } else if ny <= 2 || nx * ny <= 48 {
            [WORKGROUP, 1, WORKGROUP]
        } else {
            [WORKGROUP, WORKGROUP, 1]
        }
    }

    /// `matmul.wgsl`'s override constants for the loads and the epilogue (`swapped`: rows
    /// of C are columns of this product). C is stored four floats at a time (C_VEC) when
    /// every row of C starts on a 16-byte boundary and ends with a whole vector.
    fn constants(&self, epilogue: &Epilogue, swapped: bool) -> Vec<(&'static str, f64)> {
        let flag = |x: bool| f64::from(u8::from(x));
        let bias_mode = match (epilogue.bias, epilogue.matrix, swapped) {
            (Some(_), _, false) => 1,
            (Some(_), _, true) => 2,
            (None, Some(_), _) => 3,
            (None, None, _) => 0,
        };
        let mut constants = self.loads().constants().to_vec();
        constants.extend([
            ("BIAS", f64::from(bias_mode)),
            ("RELU", flag(epilogue.relu)),
            ("GATE", flag(epilogue.gate.is_some())),
            ("SIGMOID", f64::from(epilogue.sigmoid_mode())),
            ("C_VEC", flag(self.n.is_multiple_of(4))),
            ("PLUS_I", f64::from(self.plus.mode())),
        ]);
        constants
    }

    /// The block kernel's workgroup shape (pushed onto `constants`) and grid for
    /// `batches` items of C.
    fn block_grid(&self, batches: usize, constants: &mut Vec<(&'static str, f64)>) -> [u32; 3] {
        let (nx, ny) = (self.n.div_ceil(BLOCK), self.m.div_ceil(BLOCK));
        // Lanes along x over (item, column block) pairs when an item's blocks would leave
        // lanes of its last group idle: 1.04–1.2× on the model's n = 100 and n = 48
        // products (FLAT_X in the shader).
        // (At most 65535 groups along x: the WebGPU default limit per dimension.)
        let flat_groups = (nx * batches).div_ceil(WORKGROUP);
        if batches > 1 && nx % WORKGROUP != 0 && flat_groups <= u16::MAX as usize {
            // All of an item's row blocks in one group where they fit (≤ 256 invocations),
            // so the groups running together share that item's operands in cache; with
            // several groups along y each would stream every item's operands again:
            // 1.2–1.25× on the temporal attention's T × T products (13 row blocks).
            let y = if ny <= MAX_GROUP_Y { ny } else { WORKGROUP };
            constants.extend([
                ("GROUP_X", WORKGROUP as f64),
                ("GROUP_Y", y as f64),
                ("GROUP_Z", 1.0),
                ("FLAT_X", 1.0),
            ]);
            return [flat_groups as u32, ny.div_ceil(y) as u32, 1];
        }
        let [x, y, z] = self.group(batches);
        constants.extend([
            ("GROUP_X", x as f64),
            ("GROUP_Y", y as f64),
            ("GROUP_Z", z as f64),
        ]);
        [
            self.n.div_ceil(BLOCK * x).max(1) as u32,
            self.m.div_ceil(BLOCK * y).max(1) as u32,
            batches.div_ceil(z) as u32,
        ]
    }

    /// One of the subgroup kernels and its grid for `batches` items of C (its workgroup
    /// size pushed onto `constants`), or `None` where the block kernel runs instead.
    /// - `matmul_subgroup` (more than 16 rows): x over (item, block of 16 columns) pairs,
    ///   y over groups of 32-row tiles (all of a column block's tiles in one group where
    ///   they fit, so the subgroups running together share its op(B) in cache);
    /// - `matmul_subgroup_cols` (at most 16 rows): x over groups of (item, block of 32
    ///   columns) pairs.
    fn subgroup_grid(
        &self,
        gpu: &Gpu,
        batches: usize,
        constants: &mut Vec<(&'static str, f64)>,
    ) -> Result<Option<(&'static Kernel, [u32; 3])>, GpuError> {
        let usable = subgroup_kernel_available(gpu);
        let cols = self.m <= COLS_MAX_M;
        let x = if cols {
            (batches * self.n.div_ceil(COLS_TILE)).div_ceil(COLS_PER_GROUP)
        } else {
            batches * self.n.div_ceil(TILE_COLS)
        };
        let fits = x <= gpu.limits().max_compute_workgroups_per_dimension as usize;
        match self.tiling {
            Tiling::Block => return Ok(None),
            Tiling::Auto if !usable || !fits || (cols && self.n < COLS_MIN_N) => return Ok(None),
            Tiling::Subgroup if !usable => {
                return Err(GpuError::Device(format!(
                    "the subgroup matmul needs {SUBGROUP_LANES}-lane subgroups; {} has {:?}",
                    gpu.info().name,
                    gpu.subgroup_size()
                )))
            }
            _ => {}
        }
        if cols {
            constants.push(("SG_COL_TILES", COLS_PER_GROUP as f64));
            return Ok(Some((&KERNEL_SUBGROUP_COLS, [x as u32, 1, 1])));
        }
        let tiles = self.m.div_ceil(TILE_ROWS);
        // More tiles than fit: the largest group that divides them evenly, if not too
        // small, so that no subgroup idles.
        let per_group = if tiles <= MAX_TILES {
            tiles
        } else {
            (MAX_TILES / 2..=MAX_TILES)
                .rev()
                .find(|&d| tiles.is_multiple_of(d))
                .unwrap_or(MAX_TILES)
        };
        constants.push(("SG_TILES", per_group as f64));
        let groups = [x as u32, tiles.div_ceil(per_group) as u32, 1];
        Ok(Some((&KERNEL_SUBGROUP, groups)))
    }

    /// The row kernel's grid for `batches` items of C: 256 columns per workgroup.
    fn row_grid(&self, batches: usize) -> [u32; 3] {
        let per_group = ROW_BLOCK * ROW_WORKGROUP;
        [self.n.div_ceil(per_group).max(1) as u32, 1, batches as u32]
    }

    /// The kernel and grid for a product of more than one row: a subgroup kernel where
    /// [`Gemm::subgroup_grid`] allows it, else the block kernel.
    fn tiled_grid(
        &self,
        gpu: &Gpu,
        batches: usize,
        constants: &mut Vec<(&'static str, f64)>,
    ) -> Result<(&'static Kernel, [u32; 3]), GpuError> {
        Ok(match self.subgroup_grid(gpu, batches, constants)? {
            Some(chosen) => chosen,
            None => (&KERNEL, self.block_grid(batches, constants)),
        })
    }

    /// The two launches of a split product: partial sums over `chunk` items each, then
    /// their sum into `out` (accumulating when `params.accumulate` is set) by as many
    /// lanes per output as [`Gemm::sum_lanes`] gives for `limits`.
    fn dispatch_split(
        self,
        gpu: &Gpu,
        [lhs, rhs, out]: [&Tensor; 3],
        params: Params,
        (chunk, limits): (usize, SplitLimits),
        flops: f64,
    ) -> Result<Dispatch, GpuError> {
        // Chunks per item of C (one item for a batch-summed gradient, one per batch item
        // for a product split along k), laid out item by item.
        let per_item = (params.reduce as usize).div_ceil(chunk);
        let items = if self.out_shared { 1 } else { self.batch };
        let chunks = items * per_item;
        let len = self.m * self.n;
        let partials = gpu.zeros(
            &format!("{} partials", out.name()),
            &[chunks, len],
            DType::F32,
        )?;
        let part = Params {
            batches: chunks as u32,
            chunk: chunk as u32,
            accumulate: 0,
            ..params
        };
        let mut constants = self.constants(&Epilogue::default(), false);
        constants.push(("REDUCE", 1.0));
        let (kernel, groups) = if self.m == 1 {
            (&KERNEL_ROW, self.row_grid(chunks))
        } else {
            self.tiled_grid(gpu, chunks, &mut constants)?
        };
        let tensors = [lhs, rhs, lhs, rhs, lhs, lhs, &partials, &partials];
        let first = gpu.dispatch(kernel, &constants, &part, &tensors, groups)?;
        let sum = Params {
            m: len as u32,
            n: (items * len) as u32,
            batches: per_item as u32,
            ..params
        };
        let lanes = Gemm::sum_lanes(per_item, items * len, limits);
        let limit = gpu.limits().max_compute_workgroups_per_dimension;
        let groups = grid_1d(items * len * lanes, SUM_WORKGROUP as u32, limit);
        let tensors = [&partials; 6]
            .into_iter()
            .chain([out, out])
            .collect::<Vec<_>>();
        let constants = [("SUM_LANES", lanes as f64)];
        let sum = gpu.dispatch(&KERNEL_SUM, &constants, &sum, &tensors, groups)?;
        Ok(first.then(sum).with_flops(flops))
    }

    fn dispatch(
        self,
        gpu: &Gpu,
        lhs: &Tensor,
        rhs: &Tensor,
        out: &Tensor,
        accumulate: Accumulate,
    ) -> Result<Dispatch, GpuError> {
        self.dispatch_with(gpu, lhs, rhs, out, accumulate, Epilogue::default())
    }

    /// The launch, with what the epilogue adds or applies to the outputs.
    fn dispatch_with(
        self,
        gpu: &Gpu,
        lhs: &Tensor,
        rhs: &Tensor,
        out: &Tensor,
        accumulate: Accumulate,
        epilogue: Epilogue,
    ) -> Result<Dispatch, GpuError> {
        let bias = epilogue.bias.or(epilogue.matrix);
        out.expect_distinct(
            [Some(lhs), Some(rhs), bias, epilogue.like_c()]
                .into_iter()
                .flatten(),
        )?;
        let flops = 2.0 * (self.batch * self.m * self.n * self.k) as f64;
        let (gemm, swapped) = self.canonical();
        let (lhs, rhs) = if swapped { (rhs, lhs) } else { (lhs, rhs) };
        let limits = if gpu.plans_for_cpu() {
            SplitLimits::CPU
        } else {
            SplitLimits::GPU
        };
        let split = gemm
            .k_split()
            .or_else(|| gemm.item_k_split(limits))
            .or_else(|| gemm.shared_k_split());
        if let Some(split) = split.filter(|_| epilogue.is_plain()) {
            return split.dispatch_with(gpu, lhs, rhs, out, accumulate, epilogue);
        }
        // The reduction: over batch items into one C (each item's slices of k in turn
        // when its k is split), or over the slices of k of each item (a single slice
        // unless split); the slices of an item lie k apart.
        let (out_batches, reduce) = if gemm.out_shared {
            (1, gemm.batch * gemm.parts)
        } else {
            (gemm.batch, gemm.parts)
        };
        let (slices, a_slice, b_slice) = if gemm.out_shared {
            (gemm.parts, gemm.k * gemm.lhs.col, gemm.k * gemm.rhs.row)
        } else {
            (1, 0, 0)
        };
        let (lb, lr) = if gemm.out_shared {
            (0, gemm.lhs.batch)
        } else {
            (gemm.lhs.batch, gemm.k * gemm.lhs.col)
        };
        let (rb, rr) = if gemm.out_shared {
            (0, gemm.rhs.batch)
        } else {
            (gemm.rhs.batch, gemm.k * gemm.rhs.row)
        };
        let params = Params {
            m: gemm.m as u32,
            n: gemm.n as u32,
            k: gemm.k as u32,
            reduce: reduce as u32,
            a_row: gemm.lhs.row as u32,
            a_col: gemm.lhs.col as u32,
            b_row: gemm.rhs.row as u32,
            b_col: gemm.rhs.col as u32,
            a_batch: lb as u32,
            b_batch: rb as u32,
            c_batch: (gemm.m * gemm.n) as u32,
            accumulate: accumulate.flag(),
            a_reduce: lr as u32,
            b_reduce: rr as u32,
            alpha: 1.0,
            batches: out_batches as u32,
            chunk: 0,
            slices: slices as u32,
            a_slice: a_slice as u32,
            b_slice: b_slice as u32,
        };
        let plain = epilogue.is_plain() && gemm.plus == Plus::None;
        if let Some(chunk) = gemm.split_chunk(reduce, limits).filter(|_| plain) {
            return gemm.dispatch_split(gpu, [lhs, rhs, out], params, (chunk, limits), flops);
        }
        let mut constants = gemm.constants(&epilogue, swapped);
        constants.push(("REDUCE", f64::from(u8::from(reduce > 1))));
        let (kernel, groups) = if gemm.m == 1 {
            (&KERNEL_ROW, gemm.row_grid(out_batches))
        } else {
            gemm.tiled_grid(gpu, out_batches, &mut constants)?
        };
        let gate = epilogue.like_c().unwrap_or(lhs);
        let tensors = [lhs, rhs, lhs, rhs, bias.unwrap_or(lhs), gate, out, out];
        let d = gpu.dispatch(kernel, &constants, &params, &tensors, groups)?;
        Ok(d.with_flops(flops))
    }
}
