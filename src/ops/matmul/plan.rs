//! The planner: a [`Matmul`]'s shape and operand layouts, the strided products (`Gemm`s)
//! its forward, dA and dB passes launch, and the choices that follow from the shape alone
//! (the row kernel's transposed form, vector loads, a split reduction).

use super::Loads;
use crate::gpu::{GpuError, Tensor};

/// Which kernel computes a product of more than one row of C.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Tiling {
    /// A subgroup kernel where the device has 8-lane subgroups (for products of at
    /// most 16 rows, only when they have at least 32 columns), else the block kernel.
    #[default]
    Auto,
    /// 8×8 blocks of C per invocation (`matmul`), on any device.
    Block,
    /// 32×16 tiles per 8-lane subgroup (`matmul_subgroup`), or 16×32 ones split by
    /// column for at most 16 rows (`matmul_subgroup_cols`); an error on other devices.
    Subgroup,
}

/// Operand bytes per chunk of a split reduction (about one core's L2), and the most
/// scratch its partial results may take (see [`Gemm::split_chunk`]).
const SPLIT_CHUNK_BYTES: usize = 1 << 20;
const SPLIT_PARTIALS_BYTES: usize = 32 << 20;
/// Multiply-adds along the reduction (items × k) that one invocation of the row kernel
/// sums in a split product (see [`Gemm::split_chunk`] and [`Gemm::k_split`]).
const ROW_CHUNK_MACS: usize = 4096;

/// How long the invocations of a split reduction are ([`Gemm::split_chunk`]): on a CPU
/// adapter, or on a GPU, whose thousands of lanes want many more, shorter invocations.
#[derive(Clone, Copy, Debug)]
pub(super) struct SplitLimits {
    /// Multiply-adds along the reduction per invocation of the row kernel.
    pub(super) row_macs: usize,
    /// Steps along the reduction (items × k) per invocation of a tiled kernel, at most.
    pub(super) tiled_steps: usize,
    /// Lanes that add one output's partial sums in the second launch, at most
    /// ([`Gemm::sum_lanes`]).
    pub(super) sum_lanes: usize,
}

impl SplitLimits {
    pub(super) const CPU: SplitLimits = SplitLimits {
        row_macs: ROW_CHUNK_MACS,
        tiled_steps: TILED_CHUNK_STEPS,
        sum_lanes: 1,
    };
    pub(super) const GPU: SplitLimits = SplitLimits {
        row_macs: 512,
        tiled_steps: 256,
        sum_lanes: SUM_MAX_LANES,
    };
}
/// Steps along the reduction (items × k) that one invocation of a tiled kernel sums in a
/// split product, at most (see [`Gemm::split_chunk`]).
const TILED_CHUNK_STEPS: usize = 1024;
/// The most lanes adding one output's partial sums (one workgroup of `sum_partials`),
/// the fewest partial sums each lane adds, and the most invocations of that launch
/// ([`Gemm::sum_lanes`]).
pub(super) const SUM_MAX_LANES: usize = 64;
const SUM_MIN_PER_LANE: usize = 8;
const SUM_MAX_INVOCATIONS: usize = 1 << 18;

/// Shape of one (batched) product.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Matmul {
    /// Number of products computed together (1 for a single product); C is
    /// `[batch, m, n]`.
    pub batch: usize,
    /// Rows of op(A) and of C.
    pub m: usize,
    /// Columns of op(B) and of C.
    pub n: usize,
    /// The contracted length: columns of op(A), rows of op(B).
    pub k: usize,
    /// A is stored `[k, m]` (per batch item) and used transposed.
    pub trans_a: bool,
    /// B is stored `[n, k]` and used transposed.
    pub trans_b: bool,
    /// A has no batch axis: the same matrix for every batch item.
    pub shared_a: bool,
    /// B has no batch axis.
    pub shared_b: bool,
    /// `C = op(A) · (op(B) + I)` (k = n): the identity's term, op(A) itself, is added in
    /// the epilogue of the forward and dA products, saving a copy of A into C before an
    /// accumulating product and an extra pass adding dC into dA. dB is unchanged.
    pub plus_identity: bool,
    /// The kernel for products of more than one row ([`Tiling::Auto`] unless a test or a
    /// benchmark wants one).
    pub tiling: Tiling,
}

/// A strided 2-D view with a batch stride (0 when shared).
#[derive(Clone, Copy, Debug)]
pub(super) struct View {
    pub(super) row: usize,
    pub(super) col: usize,
    pub(super) batch: usize,
}

impl View {
    /// Logical `[rows, cols]`, stored row-major or (when `trans`) as its transpose.
    fn of(rows: usize, cols: usize, trans: bool, batch: usize) -> View {
        if trans {
            View {
                row: 1,
                col: rows,
                batch,
            }
        } else {
            View {
                row: cols,
                col: 1,
                batch,
            }
        }
    }

    fn t(self) -> View {
        View {
            row: self.col,
            col: self.row,
            batch: self.batch,
        }
    }
}

impl Matmul {
    /// A single `[m, k] · [k, n]` product.
    pub fn new(m: usize, n: usize, k: usize) -> Matmul {
        Matmul {
            batch: 1,
            m,
            n,
            k,
            trans_a: false,
            trans_b: false,
            shared_a: false,
            shared_b: false,
            plus_identity: false,
            tiling: Tiling::Auto,
        }
    }

    /// The same product over `batch` items.
    pub fn batched(self, batch: usize) -> Matmul {
        Matmul { batch, ..self }
    }

    /// Sets [`Matmul::trans_a`]: A stored `[k, m]`.
    pub fn transpose_a(self, trans_a: bool) -> Matmul {
        Matmul { trans_a, ..self }
    }

    /// Sets [`Matmul::trans_b`]: B stored `[n, k]`.
    pub fn transpose_b(self, trans_b: bool) -> Matmul {
        Matmul { trans_b, ..self }
    }

    /// Sets [`Matmul::shared_a`]: one A for every batch item, its gradient summed over
    /// the batch.
    pub fn share_a(self, shared_a: bool) -> Matmul {
        Matmul { shared_a, ..self }
    }

    /// Sets [`Matmul::shared_b`]: one B for every batch item, its gradient summed over
    /// the batch.
    pub fn share_b(self, shared_b: bool) -> Matmul {
        Matmul { shared_b, ..self }
    }

    /// Sets [`Matmul::plus_identity`]: `C = op(A) · (op(B) + I)`.
    pub fn plus_identity(self, plus_identity: bool) -> Matmul {
        Matmul {
            plus_identity,
            ..self
        }
    }

    /// Sets [`Matmul::tiling`], the kernel for products of more than one row.
    pub fn tiling(self, tiling: Tiling) -> Matmul {
        Matmul { tiling, ..self }
    }

    /// `plus_identity` needs a square op(B) of more than one row, and dA per batch item
    /// (a shared A's gradient would need the batch sum of dC as well).
    pub(super) fn check_identity(&self, tensor: &Tensor) -> Result<(), GpuError> {
        if self.plus_identity && (self.k != self.n || self.n < 2 || self.shared_a) {
            return Err(GpuError::Shape {
                tensor: tensor.name().to_string(),
                expected: "a square op(B) (k = n > 1) and an unshared A for op(A)·(op(B) + I)"
                    .into(),
                got: format!("{self:?}"),
            });
        }
        Ok(())
    }

    /// Number of elements of A: `m · k`, times `batch` unless A is shared.
    pub fn a_len(&self) -> usize {
        self.m * self.k * if self.shared_a { 1 } else { self.batch }
    }

    /// Number of elements of B: `k · n`, times `batch` unless B is shared.
    pub fn b_len(&self) -> usize {
        self.k * self.n * if self.shared_b { 1 } else { self.batch }
    }

    /// Number of elements of C, `batch · m · n` (C always has the batch axis).
    pub fn c_len(&self) -> usize {
        self.batch * self.m * self.n
    }

    /// Multiply-adds counted twice, as usual for GFLOP/s.
    pub fn flops(&self) -> f64 {
        2.0 * (self.batch * self.m * self.n * self.k) as f64
    }

    fn view_a(&self) -> View {
        let stride = if self.shared_a { 0 } else { self.m * self.k };
        View::of(self.m, self.k, self.trans_a, stride)
    }

    fn view_b(&self) -> View {
        let stride = if self.shared_b { 0 } else { self.k * self.n };
        View::of(self.k, self.n, self.trans_b, stride)
    }

    fn view_c(&self) -> View {
        View::of(self.m, self.n, false, self.m * self.n)
    }

    pub(super) fn forward_gemm(&self) -> Gemm {
        Gemm {
            m: self.m,
            n: self.n,
            k: self.k,
            lhs: self.view_a(),
            rhs: self.view_b(),
            out_shared: false,
            batch: self.batch,
            plus: self.identity_on(Plus::Lhs),
            tiling: self.tiling,
            parts: 1,
        }
    }

    /// The operand a product's epilogue adds for `plus_identity`: `side`, or none.
    fn identity_on(&self, side: Plus) -> Plus {
        if self.plus_identity {
            side
        } else {
            Plus::None
        }
    }

    /// The product giving dA, and whether its left operand is B (else dC).
    pub(super) fn backward_a_gemm(&self) -> (Gemm, bool) {
        let (dcv, bv) = (self.view_c(), self.view_b());
        // op(A) grad = dC · op(B)ᵀ, stored as its transpose when A is; with the identity,
        // dC · (op(B) + I)ᵀ adds dC itself (the operand beside op(B)).
        if self.trans_a {
            let gemm = Gemm {
                m: self.k,
                n: self.m,
                k: self.n,
                lhs: bv,
                rhs: dcv.t(),
                out_shared: self.shared_a,
                batch: self.batch,
                plus: self.identity_on(Plus::Rhs),
                tiling: self.tiling,
                parts: 1,
            };
            (gemm, true)
        } else {
            let gemm = Gemm {
                m: self.m,
                n: self.k,
                k: self.n,
                lhs: dcv,
                rhs: bv.t(),
                out_shared: self.shared_a,
                batch: self.batch,
                plus: self.identity_on(Plus::Lhs),
                tiling: self.tiling,
                parts: 1,
            };
            (gemm, false)
        }
    }

    /// The product giving dB, and whether its left operand is dC (else A).
    pub(super) fn backward_b_gemm(&self) -> (Gemm, bool) {
        let (av, dcv) = (self.view_a(), self.view_c());
        // op(B) grad = op(A)ᵀ · dC, stored as its transpose when B is.
        if self.trans_b {
            let gemm = Gemm {
                m: self.n,
                n: self.k,
                k: self.m,
                lhs: dcv.t(),
                rhs: av,
                out_shared: self.shared_b,
                batch: self.batch,
                plus: Plus::None,
                tiling: self.tiling,
                parts: 1,
            };
            (gemm, true)
        } else {
            let gemm = Gemm {
                m: self.k,
                n: self.n,
                k: self.m,
                lhs: av.t(),
                rhs: dcv,
                out_shared: self.shared_b,
                batch: self.batch,
                plus: Plus::None,
                tiling: self.tiling,
                parts: 1,
            };
            (gemm, false)
        }
    }
}

/// One launch of the kernel: `out[m, n] = lhs[m, k] · rhs[k, n]` over strided views.
#[derive(Clone, Copy, Debug)]
pub(super) struct Gemm {
    pub(super) m: usize,
    pub(super) n: usize,
    pub(super) k: usize,
    pub(super) lhs: View,
    pub(super) rhs: View,
    /// The output has no batch axis: sum the products of all batch items into it.
    pub(super) out_shared: bool,
    pub(super) batch: usize,
    /// An operand added to the product in the epilogue (never with `out_shared`).
    pub(super) plus: Plus,
    pub(super) tiling: Tiling,
    /// Slices of length `k` that each batch item's reduction is cut into (1: none),
    /// summed into the same item of C ([`Gemm::item_k_split`]), or with `out_shared` into
    /// the one C with every item's ([`Gemm::shared_k_split`]).
    pub(super) parts: usize,
}

/// Which operand, if any, the epilogue adds to C: `lhs · (rhs + I)` adds element (i, j)
/// of lhs (k = n), `(lhs + I) · rhs` adds element (i, j) of rhs (k = m).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Plus {
    None,
    Lhs,
    Rhs,
}

impl Plus {
    /// The value of `matmul.wgsl`'s PLUS_I.
    pub(super) fn mode(self) -> u8 {
        match self {
            Plus::None => 0,
            Plus::Lhs => 1,
            Plus::Rhs => 2,
        }
    }

    /// The same term after the operands are swapped and transposed.
    fn swapped(self) -> Plus {
        match self {
            Plus::None => Plus::None,
            Plus::Lhs => Plus::Rhs,
            Plus::Rhs => Plus::Lhs,
        }
    }
}

impl Gemm {
    /// A product with one output column is the product with one output row of the
    /// transposed views (`Cᵀ = op(B)ᵀ · op(A)ᵀ`, the same memory since C is a vector per
    /// batch item), which the row kernel computes without wasting 7/8 of an 8×8 block.
    pub(super) fn canonical(self) -> (Gemm, bool) {
        if self.n == 1 && self.m > 1 {
            let t = Gemm {
                m: 1,
                n: self.m,
                k: self.k,
                lhs: self.rhs.t(),
                rhs: self.lhs.t(),
                plus: self.plus.swapped(),
                ..self
            };
            (t, true)
        } else {
            (self, false)
        }
    }

    /// Vector loads for each operand that allows them: contiguous along one axis, with
    /// that axis (where blocks read it unclamped), the other stride and the batch stride
    /// multiples of 4, so every vector starts on a 16-byte boundary. Loads within the
    /// k-loop step by 4 from there; a ragged K ends in scalar loads.
    pub(super) fn loads(&self) -> Loads {
        let aligned = |xs: &[usize]| xs.iter().all(|x| x % 4 == 0);
        let (l, r) = (self.lhs, self.rhs);
        // One row reads no row stride.
        let a_k = l.col == 1 && aligned(&[l.batch]) && (self.m == 1 || aligned(&[l.row]));
        let a_m = self.m > 1 && l.row == 1 && aligned(&[l.batch, l.col, self.m]);
        let b_n = r.col == 1 && aligned(&[r.batch, r.row, self.n]);
        let b_k = r.row == 1 && aligned(&[r.batch, r.col]);
        Loads {
            a_vec: a_k || a_m,
            a_along_k: !a_m,
            b_vec: b_n || b_k,
            b_along_n: !b_k,
        }
    }

    /// Reduction items per chunk when a batch-summed product (a weight gradient) is better
    /// split: each chunk's sum goes to its own slice of a scratch buffer, and a second
    /// launch adds the slices in a fixed order ([`Gemm::sum_lanes`]). A single launch
    /// sweeps all items in every invocation, so each item's operands stream from memory
    /// again for every block of C (the paper's conv weight gradient ran at 0.6 of the
    /// best matmul). Chunks whose operands fit in one core's L2 let the blocks of C that
    /// run together share them:
    /// 1.8× on that product (7.7 → 14–15.7 GFLOP/s, best with ~1 MiB chunks).
    ///
    /// A single row of C (the gradient of a rank-1 weight such as the attentions' U1, U3
    /// and W3) is split into chunks of about `limits.row_macs` multiply-adds per
    /// invocation ([`SplitLimits`]: 4 096 on a CPU adapter, 512 on a GPU): the row
    /// kernel covers 256 columns per workgroup, so unsplit such a gradient ran as one
    /// workgroup sweeping every item, a few invocations busy (on an NVIDIA H200 these
    /// products took 70 % of the paper shape's training step). Items with a long k are
    /// first cut into slices ([`Gemm::shared_k_split`]), which are then the reduction
    /// items chunked here.
    ///
    /// A chunk of the tiled kernels also sums at most `limits.tiled_steps` steps of k per
    /// invocation (1 024 on a CPU adapter, 256 on a GPU): a gradient with a small C and a short k per item (the graph
    /// convolution's W and the residual weight, [C_in, C] over B·N items of T steps) fits
    /// a core's L2 in few chunks, which left a GPU a few dozen invocations each summing
    /// thousands of items. The extra partial sums cost lavapipe nothing measurable.
    pub(super) fn split_chunk(&self, reduce: usize, limits: SplitLimits) -> Option<usize> {
        if self.parts > 1 && !self.out_shared {
            // One slice of k per invocation, unless the partial sums would outgrow the
            // scratch limit (then the unsplit launch sums every slice in each invocation).
            let partial_bytes = 4 * self.batch * self.m * self.n;
            let chunk = (reduce * partial_bytes)
                .div_ceil(SPLIT_PARTIALS_BYTES)
                .max(1);
            return (chunk < reduce).then_some(chunk);
        }
        if !self.out_shared {
            return None;
        }
        let partial_bytes = 4 * self.m * self.n;
        let k = self.k.max(1);
        let chunk = if self.m == 1 {
            limits.row_macs / k
        } else {
            (SPLIT_CHUNK_BYTES / (4 * k * (self.m + self.n))).min(limits.tiled_steps / k)
        };
        let chunk = chunk
            .max(1)
            .max((reduce * partial_bytes).div_ceil(SPLIT_PARTIALS_BYTES));
        (chunk < reduce).then_some(chunk)
    }

    /// Lanes that add each output's `partials` partial sums in the second launch of a
    /// split product (`sum_partials`; `outputs` sums in all): a power of two, each lane
    /// adding every lanes-th partial sum in order and the lanes' sums then added in a
    /// fixed tree in workgroup memory, so the result does not depend on the grid. One lane
    /// adds them all on a CPU adapter (`limits.sum_lanes` = 1, the order of every earlier
    /// build). On a GPU each lane adds at least 8, up to 64 lanes per output while the
    /// launch stays within 2¹⁸ invocations: one lane per output made that launch a chain of
    /// dependent loads as long as the partial sums are many (1 024 for each of the 14
    /// outputs of the temporal attention's U1 gradient at the paper's shape, 448 for each
    /// of the 4 096 of the graph convolution's W), which a GPU cannot overlap when a few
    /// dozen lanes are busy.
    pub(super) fn sum_lanes(partials: usize, outputs: usize, limits: SplitLimits) -> usize {
        let mut lanes = 1;
        while lanes * 2 <= limits.sum_lanes
            && lanes * 2 * SUM_MIN_PER_LANE <= partials
            && lanes * 2 * outputs <= SUM_MAX_INVOCATIONS
        {
            lanes *= 2;
        }
        lanes
    }

    /// A single row of C with a long reduction and no batch (`xw1`'s weight gradient
    /// sums over B·N·C_in = 57 344 rows at the paper's shape) as the same product summed
    /// over chunks of k: k' = a divisor of k of at most [`ROW_CHUNK_MACS`] / 8 (a multiple
    /// of 4 where one exists, for vector loads), each chunk a reduction item whose
    /// operands start k' further along, so [`Gemm::split_chunk`] then spreads the chunks
    /// over workgroups. `None` where k has no divisor in [k'/4, k'] or is short already.
    pub(super) fn k_split(&self) -> Option<Gemm> {
        if self.m != 1 || self.batch != 1 || self.out_shared || self.plus != Plus::None {
            return None;
        }
        let kc = self.row_slice()?;
        Some(Gemm {
            k: kc,
            lhs: View {
                batch: kc * self.lhs.col,
                ..self.lhs
            },
            rhs: View {
                batch: kc * self.rhs.row,
                ..self.rhs
            },
            out_shared: true,
            batch: self.k / kc,
            ..*self
        })
    }
}

impl Gemm {
    /// A batched product with few blocks of C and a long reduction per item (the graph
    /// convolution's dQ = dM·X_tᵀ: 14 × 14 outputs per window over k = C·T = 6 400 at the
    /// paper's shape) as the same product over slices of k: k' = a divisor of k in
    /// `limits.tiled_steps` / 4 ..= `limits.tiled_steps` (1 024 on a CPU adapter, 256 on
    /// a GPU) and a multiple of 4, each item's `parts` = k / k' slices summed into their
    /// own partial results by their own invocations, then added in a fixed order by a
    /// second launch. Unsplit, each 8×8 block of C swept the whole of k in one invocation: 256
    /// invocations for that product at the paper's shape, 70 GFLOP/s on an NVIDIA H200,
    /// 1.9 ms of each block's training step; in slices of 800 a GPU still ran 2 048
    /// invocations of 800 steps each, in slices of 256, 6 400 of 256. `None` for products
    /// with enough blocks of C to fill a device ([`ITEM_SPLIT_MAX_BLOCKS`]), a k under 4
    /// slices, or no such divisor.
    pub(super) fn item_k_split(&self, limits: SplitLimits) -> Option<Gemm> {
        if self.out_shared || self.parts != 1 || self.plus != Plus::None {
            return None;
        }
        let blocks = self.batch * self.m.div_ceil(8) * self.n.div_ceil(8);
        let steps = limits.tiled_steps;
        if self.k < 4 * steps || blocks >= ITEM_SPLIT_MAX_BLOCKS {
            return None;
        }
        // A multiple of 4, so that each slice starts where vector loads may (the slice
        // offsets r·k'·stride are not among the strides `loads` checks).
        let kc = (steps / 4..=steps)
            .rev()
            .find(|d| d % 4 == 0 && self.k.is_multiple_of(*d))?;
        Some(Gemm {
            k: kc,
            parts: self.k / kc,
            ..*self
        })
    }

    /// A single row of C summed over batch items whose k is long (the temporal
    /// attention's U1 and U3 and the spatial attention's W3: a row of N or C_in values
    /// summed over B items of C·T steps) with each item's k cut into slices of k' (as
    /// [`Gemm::k_split`] chooses it), so that [`Gemm::split_chunk`] can spread a long
    /// item over several invocations: without it each invocation swept at least one
    /// whole item, and a GPU ran the gradient on a few hundred lanes.
    pub(super) fn shared_k_split(&self) -> Option<Gemm> {
        if self.m != 1 || !self.out_shared || self.parts != 1 || self.plus != Plus::None {
            return None;
        }
        let kc = self.row_slice()?;
        Some(Gemm {
            k: kc,
            parts: self.k / kc,
            ..*self
        })
    }

    /// The slice length k' of a single row's long k: a divisor of k of at most
    /// [`ROW_CHUNK_MACS`] / 8, a multiple of 4 where one exists (for vector loads); `None`
    /// where k is short already or has no divisor in [k'/4, k'].
    fn row_slice(&self) -> Option<usize> {
        let target = ROW_CHUNK_MACS / 8;
        if self.k < 4 * target {
            return None;
        }
        let divides = |d: &usize| self.k.is_multiple_of(*d);
        let range = || (target / 4..=target).rev();
        range()
            .filter(|d| d % 4 == 0)
            .find(divides)
            .or_else(|| range().find(divides))
    }
}

/// Blocks of 8×8 outputs (over all batch items) from which a batched product is left
/// unsplit along k ([`Gemm::item_k_split`]): enough invocations to keep a GPU busy.
const ITEM_SPLIT_MAX_BLOCKS: usize = 2048;

/// The kernel entry and load modes `matmul.wgsl` uses for `mm`'s forward, dA and dB
/// products (in that order), for tests and profiles. The entry is the portable one
/// (`matmul` or `matmul_row`); on a device with 8-lane subgroups a product named
/// `matmul` runs on a subgroup kernel instead, with the same load modes.
pub fn plan(mm: &Matmul) -> [(&'static str, Loads); 3] {
    let describe = |g: Gemm| {
        let (g, _) = g.canonical();
        (if g.m == 1 { "matmul_row" } else { "matmul" }, g.loads())
    };
    [
        describe(mm.forward_gemm()),
        describe(mm.backward_a_gemm().0),
        describe(mm.backward_b_gemm().0),
    ]
}

#[cfg(test)]
mod tests {
    use super::{Gemm, SplitLimits};

    #[test]
    fn partial_sums_take_more_lanes_the_longer_they_are_on_a_gpu() {
        // (partial sums per output, outputs, lanes on a GPU): the paper shape's U1 (1 024
        // sums for each of 14 outputs) takes the most lanes; the graph convolution's W
        // (448 for 4 096) at least 8 sums per lane; the gated convolution's dW_fg (299
        // for 24 576) as many as 2¹⁸ invocations allow; a few sums stay on one lane.
        let gpu = [
            (1024, 14, 64),
            (448, 4096, 32),
            (299, 24576, 8),
            (20, 15, 2),
        ];
        for (partials, outputs, lanes) in gpu.into_iter().chain([(7, 10000, 1), (15, 3, 1)]) {
            let got = Gemm::sum_lanes(partials, outputs, SplitLimits::GPU);
            assert_eq!(got, lanes, "{partials} partial sums for {outputs} outputs");
            assert_eq!(Gemm::sum_lanes(partials, outputs, SplitLimits::CPU), 1);
        }
    }
}
