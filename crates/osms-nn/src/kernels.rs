//! f32 matrix products with a fixed summation order (the design sketch
//! `../shared/design/ARCHITECTURE.md`, "Numerics that must not drift"). Every output element is
//! `((0 + a₀b₀) + a₁b₁) + …` in increasing k, with separate multiply and add (Rust never
//! contracts them into an FMA), so the tiled kernels, the scalar reference, any thread count and
//! any x86-64 or aarch64 CPU give the same bits.
//!
//! The tiled kernel keeps an MR × NR block of C in registers and walks k once, reading B from
//! packed NR-wide panels. SIMD lanes run across output columns only, and each lane does exactly
//! the scalar sequence, so the instruction set changes the speed but never a bit. The widest set
//! the CPU has (AVX-512, AVX2 or the baseline) is picked once at run time; rows are split across
//! threads in whole MR-row groups, never k.

use rayon::prelude::*;

use crate::Matrix;
pub use crate::level::Level;
use crate::level::{dispatch, per_level};

/// Below this many multiply-adds, threads cost more than they save.
const PARALLEL_MIN_WORK: usize = 1 << 16;

/// A matrix operand as stored, and whether the product uses its transpose.
#[derive(Clone, Copy)]
struct Operand<'a> {
    m: &'a Matrix,
    transposed: bool,
}

impl Operand<'_> {
    fn rows(&self) -> usize {
        if self.transposed {
            self.m.cols
        } else {
            self.m.rows
        }
    }

    fn cols(&self) -> usize {
        if self.transposed {
            self.m.rows
        } else {
            self.m.cols
        }
    }
}

/// B's columns in panels of `nr`, each panel `k × nr` contiguous, the last one zero-padded.
fn pack_b(b: Operand<'_>, nr: usize) -> Vec<f32> {
    let (k, n) = (b.rows(), b.cols());
    let data = &b.m.data;
    let mut out = vec![0.0f32; n.div_ceil(nr) * k * nr];
    for (p, panel) in out.chunks_exact_mut(k * nr).enumerate() {
        let j0 = p * nr;
        let width = nr.min(n - j0);
        if b.transposed {
            // Read the stored rows contiguously; the strided writes stay inside the panel.
            for j in 0..width {
                let src = &data[(j0 + j) * k..(j0 + j + 1) * k];
                for (dst, &v) in panel.chunks_exact_mut(nr).zip(src) {
                    dst[j] = v;
                }
            }
        } else {
            for (kk, dst) in panel.chunks_exact_mut(nr).enumerate() {
                dst[..width].copy_from_slice(&data[kk * n + j0..kk * n + j0 + width]);
            }
        }
    }
    out
}

/// Rows `i0 .. i0 + group` of A interleaved by k into `panel` (`k × h`), zero-padded.
fn pack_a(a: Operand<'_>, i0: usize, group: usize, h: usize, panel: &mut [f32]) {
    let (m, k) = (a.rows(), a.cols());
    let data = &a.m.data;
    panel.fill(0.0);
    for (kk, dst) in panel.chunks_exact_mut(h).enumerate() {
        for (r, d) in dst[..group].iter_mut().enumerate() {
            *d = if a.transposed {
                data[kk * m + i0 + r]
            } else {
                data[(i0 + r) * k + kk]
            };
        }
    }
}

/// H rows × NR columns of accumulators, updated by one k step.
#[inline(always)]
fn step<const H: usize, const NR: usize>(acc: &mut [[f32; NR]; H], a: &[f32; H], b: &[f32; NR]) {
    for (acc_row, &av) in acc.iter_mut().zip(a) {
        for (acc, &bv) in acc_row.iter_mut().zip(b) {
            *acc = av.mul_add(bv, *acc);
        }
    }
}

/// Stores the first `rows` rows of `acc` into C at column `j0`. Whole-width stores keep the
/// accumulators out of memory inside the k loop; only a ragged last panel copies a prefix.
#[inline(always)]
fn store<const H: usize, const NR: usize>(
    acc: &[[f32; NR]; H],
    c: &mut [f32],
    n: usize,
    rows: usize,
    j0: usize,
) {
    let width = NR.min(n - j0);
    for (r, acc_row) in acc.iter().enumerate().take(rows) {
        let dst = &mut c[r * n + j0..r * n + j0 + width];
        if let Ok(dst) = <&mut [f32; NR]>::try_from(&mut *dst) {
            *dst = *acc_row;
        } else {
            dst.copy_from_slice(&acc_row[..width]);
        }
    }
}

/// The first `rows` rows of C at column `j0` into `acc`, for a product that continues C's sums;
/// columns past the edge stay 0 (they are never stored).
#[inline(always)]
fn load<const H: usize, const NR: usize>(
    acc: &mut [[f32; NR]; H],
    c: &[f32],
    n: usize,
    rows: usize,
    j0: usize,
) {
    let width = NR.min(n - j0);
    for (r, acc_row) in acc.iter_mut().enumerate().take(rows) {
        acc_row[..width].copy_from_slice(&c[r * n + j0..r * n + j0 + width]);
    }
}

/// One 2H × NR block of C from two H-row panels of A (`k × H` each, interleaved by k) and one
/// panel of B (`k × NR`), all walked by value with no indexing. The block is two separate H × NR
/// arrays because LLVM keeps an array of up to 128 floats in registers but spills a larger one
/// on every k step. Rows and columns past the matrix edge were zero-padded and are not stored.
#[inline(always)]
fn micro<const H: usize, const NR: usize, const ACC: bool>(
    a_lo: &[f32],
    a_hi: &[f32],
    b_panel: &[f32],
    c: &mut [f32],
    n: usize,
    rows: usize,
    j0: usize,
) {
    let (lo_ks, _) = a_lo.as_chunks::<H>();
    let (hi_ks, _) = a_hi.as_chunks::<H>();
    let (b_ks, _) = b_panel.as_chunks::<NR>();
    let mut lo = [[0.0f32; NR]; H];
    let mut hi = [[0.0f32; NR]; H];
    if ACC {
        load(&mut lo, c, n, rows.min(H), j0);
        if rows > H {
            load(&mut hi, &c[H * n..], n, rows - H, j0);
        }
    }
    if rows > H {
        for ((a_lo, a_hi), b) in lo_ks.iter().zip(hi_ks).zip(b_ks) {
            step(&mut lo, a_lo, b);
            step(&mut hi, a_hi, b);
        }
        store(&lo, c, n, H, j0);
        store(&hi, &mut c[H * n..], n, rows - H, j0);
    } else {
        for (a_lo, b) in lo_ks.iter().zip(b_ks) {
            step(&mut lo, a_lo, b);
        }
        store(&lo, c, n, rows, j0);
    }
}

/// The rows of C starting at row `i0` (as many as `c` holds), every panel of B, 2H at a time.
#[inline(always)]
fn block<const H: usize, const NR: usize, const ACC: bool>(
    a: Operand<'_>,
    i0: usize,
    packed: &[f32],
    c: &mut [f32],
    n: usize,
) {
    let k = a.cols();
    let rows = c.len() / n;
    let mut a_lo = vec![0.0f32; k * H];
    let mut a_hi = vec![0.0f32; k * H];
    for g0 in (0..rows).step_by(2 * H) {
        let group = (2 * H).min(rows - g0);
        pack_a(a, i0 + g0, group.min(H), H, &mut a_lo);
        pack_a(a, i0 + g0 + H, group.saturating_sub(H), H, &mut a_hi);
        for (p, b_panel) in packed.chunks_exact(k * NR).enumerate() {
            micro::<H, NR, ACC>(&a_lo, &a_hi, b_panel, &mut c[g0 * n..], n, group, p * NR);
        }
    }
}

/// C's rows one at a time as `c += a_k · B[k]` in k order: for a few rows, packing B would cost
/// as much as the product. The same sequence per element as every other path.
#[inline(always)]
fn rows_axpy(a: &[f32], b: &[f32], c: &mut [f32], n: usize) {
    let k = b.len() / n;
    for (a_row, c_row) in a.chunks_exact(k).zip(c.chunks_exact_mut(n)) {
        for (&av, b_row) in a_row.iter().zip(b.chunks_exact(n)) {
            for (c, &bv) in c_row.iter_mut().zip(b_row) {
                *c = av.mul_add(bv, *c);
            }
        }
    }
}

per_level!(block_baseline, block_avx2, block_avx512, [LEVEL]
    (a: Operand<'_>, i0: usize, packed: &[f32], c: &mut [f32], n: usize)
    => block::<{ LEVEL.mr() / 2 }, { LEVEL.nr() }, false>(a, i0, packed, c, n));

per_level!(block_acc_baseline, block_acc_avx2, block_acc_avx512, [LEVEL]
    (a: Operand<'_>, i0: usize, packed: &[f32], c: &mut [f32], n: usize)
    => block::<{ LEVEL.mr() / 2 }, { LEVEL.nr() }, true>(a, i0, packed, c, n));

per_level!(axpy_baseline, axpy_avx2, axpy_avx512,
    (a: &[f32], b: &[f32], c: &mut [f32], n: usize) => rows_axpy(a, b, c, n));

/// Rows of A below which the row-by-row path beats packing.
const AXPY_MAX_ROWS: usize = 2;

fn product(level: Level, a: Operand<'_>, b: Operand<'_>, what: &str) -> Matrix {
    let level = level.runnable();
    assert_eq!(
        a.cols(),
        b.rows(),
        "{what}: {}x{} times {}x{}",
        a.rows(),
        a.cols(),
        b.rows(),
        b.cols()
    );
    let (m, k, n) = (a.rows(), a.cols(), b.cols());
    let mut c = Matrix::zeros(m, n);
    if m == 0 || n == 0 || k == 0 {
        return c;
    }
    if m <= AXPY_MAX_ROWS && !a.transposed && !b.transposed {
        axpy(level, &a.m.data, &b.m.data, &mut c);
        return c;
    }
    blocks(level, a, &pack_b(b, level.nr()), &mut c, false);
    c
}

/// C += A · B row by row (plain A and B, a few rows): [`rows_axpy`] at `level`.
fn axpy(level: Level, a: &[f32], b: &[f32], c: &mut Matrix) {
    let n = c.cols;
    dispatch!(
        level,
        axpy_baseline,
        axpy_avx2,
        axpy_avx512(a, b, &mut c.data, n)
    );
}

/// C (`m × n`) from A and B's packed panels, in whole MR-row groups, on rayon's threads when
/// the product is large enough; `acc` continues each element's sum from C's value.
fn blocks(level: Level, a: Operand<'_>, packed: &[f32], c: &mut Matrix, acc: bool) {
    let n = c.cols;
    let run = |i0: usize, rows: &mut [f32]| {
        if acc {
            dispatch!(
                level,
                block_acc_baseline,
                block_acc_avx2,
                block_acc_avx512(a, i0, packed, rows, n)
            )
        } else {
            dispatch!(
                level,
                block_baseline,
                block_avx2,
                block_avx512(a, i0, packed, rows, n)
            )
        }
    };
    let mr = level.mr();
    if c.rows * a.cols() * n >= PARALLEL_MIN_WORK {
        c.data
            .par_chunks_mut(mr * n)
            .enumerate()
            .for_each(|(g, rows)| run(g * mr, rows));
    } else {
        run(0, &mut c.data);
    }
}

/// A right-hand operand B packed once for many products with different A (a layer's weights
/// when a network only runs forward): [`matmul`] packs B on every call, which at a few rows
/// costs about as much as the product.
#[derive(Debug, Clone)]
pub struct PackedB {
    level: Level,
    plain: Matrix,
    panels: Vec<f32>,
}

impl PackedB {
    /// B packed for the CPU's widest level.
    pub fn new(b: Matrix) -> Self {
        Self::at(Level::detected(), b)
    }

    /// B packed for `level` (a level the CPU lacks runs the baseline, as [`matmul_at`]).
    pub fn at(level: Level, b: Matrix) -> Self {
        let level = level.runnable();
        let panels = if b.data.is_empty() {
            Vec::new()
        } else {
            pack_b(plain(&b), level.nr())
        };
        PackedB {
            level,
            plain: b,
            panels,
        }
    }

    /// B as given.
    pub fn matrix(&self) -> &Matrix {
        &self.plain
    }
}

/// C += A · B, B packed: each element of C continues its sum from C's value in increasing k.
/// From C = 0 that is [`matmul`] bit for bit; and since a product sums k in order, splitting A's
/// columns and B's rows at any k, `C = A₁·B₁` then `C += A₂·B₂` has the bits of `[A₁ A₂]·[B₁; B₂]`
/// (a first layer whose leading inputs stay fixed over many calls multiplies them once).
pub fn matmul_acc_packed(a: &Matrix, b: &PackedB, c: &mut Matrix) {
    let (m, k, n) = (a.rows, a.cols, b.plain.cols);
    assert!(
        k == b.plain.rows && c.rows == m && c.cols == n,
        "A·B into C: {m}x{k} times {}x{} into {}x{}",
        b.plain.rows,
        n,
        c.rows,
        c.cols
    );
    if m == 0 || n == 0 || k == 0 {
        return;
    }
    if m <= AXPY_MAX_ROWS {
        axpy(b.level, &a.data, &b.plain.data, c);
        return;
    }
    blocks(b.level, plain(a), &b.panels, c, true);
}

fn plain(m: &Matrix) -> Operand<'_> {
    Operand {
        m,
        transposed: false,
    }
}

fn transposed(m: &Matrix) -> Operand<'_> {
    Operand {
        m,
        transposed: true,
    }
}

/// C = A · B.
pub fn matmul(a: &Matrix, b: &Matrix) -> Matrix {
    matmul_at(Level::detected(), a, b)
}

/// C = Aᵀ · B (A is k × m).
pub fn matmul_tn(a: &Matrix, b: &Matrix) -> Matrix {
    matmul_tn_at(Level::detected(), a, b)
}

/// C = A · Bᵀ (B is n × k).
pub fn matmul_nt(a: &Matrix, b: &Matrix) -> Matrix {
    matmul_nt_at(Level::detected(), a, b)
}

/// [`matmul`] on a given level (a level the CPU lacks runs the baseline).
pub fn matmul_at(level: Level, a: &Matrix, b: &Matrix) -> Matrix {
    product(level, plain(a), plain(b), "A·B")
}

/// [`matmul_tn`] on a given level.
pub fn matmul_tn_at(level: Level, a: &Matrix, b: &Matrix) -> Matrix {
    product(level, transposed(a), plain(b), "Aᵀ·B")
}

/// [`matmul_nt`] on a given level.
pub fn matmul_nt_at(level: Level, a: &Matrix, b: &Matrix) -> Matrix {
    product(level, plain(a), transposed(b), "A·Bᵀ")
}

/// The plain triple loop the tiled kernels must match bit for bit.
pub fn matmul_reference(a: &Matrix, b: &Matrix) -> Matrix {
    assert_eq!(a.cols, b.rows);
    let mut c = Matrix::zeros(a.rows, b.cols);
    for i in 0..a.rows {
        for j in 0..b.cols {
            let mut s = 0.0f32;
            for k in 0..a.cols {
                s = a.get(i, k).mul_add(b.get(k, j), s);
            }
            c.set(i, j, s);
        }
    }
    c
}

/// Σ of `x` in fixed chunks of 256, chunk sums added in index order (f64 accumulation inside a
/// chunk keeps long sums accurate; the order keeps them reproducible).
pub fn sum(x: &[f32]) -> f32 {
    sum_map(x, |v| v)
}

/// Σ x_i² with [`sum`]'s order, without a temporary.
pub fn sum_squares(x: &[f32]) -> f32 {
    sum_map(x, |v| v * v)
}

/// Σ f(x_i) in f64: chunks of 256 in order, each summed in 8 interleaved partial sums
/// (element i into partial i mod 8) that are then added in a fixed tree. The partial sums keep
/// the additions independent, so the loop is not bound by the latency of one long chain; the
/// order is fixed, so the bits are.
#[inline(always)]
fn sum_map(x: &[f32], f: impl Fn(f32) -> f32) -> f32 {
    let mut total = 0.0f64;
    for chunk in x.chunks(256) {
        let mut p = [0.0f64; 8];
        let mut lanes = chunk.chunks_exact(8);
        for group in &mut lanes {
            for (p, &v) in p.iter_mut().zip(group) {
                *p += f64::from(f(v));
            }
        }
        for (p, &v) in p.iter_mut().zip(lanes.remainder()) {
            *p += f64::from(f(v));
        }
        total += ((p[0] + p[1]) + (p[2] + p[3])) + ((p[4] + p[5]) + (p[6] + p[7]));
    }
    total as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    fn random(rows: usize, cols: usize, seed: u64) -> Matrix {
        let mut rng = osms_core::rng::stream(seed, "kernels", "test", (rows * 1000 + cols) as u64);
        Matrix::from_fn(rows, cols, |_, _| {
            osms_core::rng::uniform(&mut rng, -1.0, 1.0) as f32
        })
    }

    fn bits(m: &Matrix) -> Vec<u32> {
        m.data.iter().map(|v| v.to_bits()).collect()
    }

    #[test]
    fn tiled_kernels_match_the_reference_bit_for_bit_on_ragged_shapes() {
        for (m, k, n) in [
            (1, 1, 1),
            (3, 5, 7),
            (17, 33, 15),
            (16, 16, 16),
            (31, 64, 47),
            (64, 3, 129),
            (2, 300, 17),
            (9, 70, 33),
            (13, 1, 65),
            (0, 4, 5),
            (4, 0, 5),
        ] {
            let a = random(m, k, 1);
            let b = random(k, n, 2);
            let reference = matmul_reference(&a, &b);
            for level in Level::available() {
                assert_eq!(
                    bits(&matmul_at(level, &a, &b)),
                    bits(&reference),
                    "{level:?} {m}x{k}x{n}"
                );
            }
            let (at, bt) = (a.transpose(), b.transpose());
            for level in Level::available() {
                assert_eq!(
                    bits(&matmul_tn_at(level, &at, &b)),
                    bits(&reference),
                    "tn {level:?} {m}x{k}x{n}"
                );
                assert_eq!(
                    bits(&matmul_nt_at(level, &a, &bt)),
                    bits(&reference),
                    "nt {level:?} {m}x{k}x{n}"
                );
            }
        }
    }

    /// The triple loop, each element's sum continued from `c`'s value.
    fn reference_from(c: &Matrix, a: &Matrix, b: &Matrix) -> Matrix {
        Matrix::from_fn(a.rows, b.cols, |i, j| {
            (0..a.cols).fold(c.get(i, j), |s, k| a.get(i, k).mul_add(b.get(k, j), s))
        })
    }

    #[test]
    fn products_continued_from_c_with_packed_b_match_the_reference_and_any_split_of_k() {
        // (80, 300, 40) crosses the threshold above which rows go to threads.
        for (m, k, n) in [
            (1, 9, 5),
            (2, 40, 17),
            (3, 5, 7),
            (16, 70, 33),
            (31, 64, 47),
            (80, 300, 40),
        ] {
            let (a, b) = (random(m, k, 5), random(k, n, 6));
            let c0 = random(m, n, 7);
            for level in Level::available() {
                let mut c = c0.clone();
                matmul_acc_packed(&a, &PackedB::at(level, b.clone()), &mut c);
                assert_eq!(
                    bits(&c),
                    bits(&reference_from(&c0, &a, &b)),
                    "{level:?} {m}x{k}x{n}"
                );
                for split in [0, 1, k / 3, k - 1, k] {
                    let part = |x: &Matrix, r: std::ops::Range<usize>, by_cols: bool| {
                        if by_cols {
                            Matrix::from_fn(x.rows, r.len(), |i, j| x.get(i, r.start + j))
                        } else {
                            Matrix::from_fn(r.len(), x.cols, |i, j| x.get(r.start + i, j))
                        }
                    };
                    let mut c = Matrix::zeros(m, n);
                    for r in [0..split, split..k] {
                        let b_rows = PackedB::at(level, part(&b, r.clone(), false));
                        matmul_acc_packed(&part(&a, r, true), &b_rows, &mut c);
                    }
                    assert_eq!(
                        bits(&c),
                        bits(&matmul_reference(&a, &b)),
                        "{level:?} {m}x{k}x{n} split at {split}"
                    );
                }
            }
        }
    }

    #[test]
    fn a_level_the_cpu_lacks_runs_the_baseline_with_the_same_bits() {
        let (a, b) = (random(9, 40, 8), random(40, 37, 9));
        let reference = bits(&matmul_reference(&a, &b));
        for level in [Level::Baseline, Level::Avx2, Level::Avx512] {
            assert_eq!(bits(&matmul_at(level, &a, &b)), reference, "{level:?}");
            let mut c = Matrix::zeros(9, 37);
            matmul_acc_packed(&a, &PackedB::at(level, b.clone()), &mut c);
            assert_eq!(bits(&c), reference, "packed {level:?}");
        }
    }

    #[test]
    fn thread_count_does_not_change_bits() {
        let a = random(256, 64, 3);
        let b = random(64, 256, 4);
        let run = |threads| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("pool");
            pool.install(|| bits(&matmul(&a, &b)))
        };
        assert_eq!(run(1), run(2));
        assert_eq!(run(1), bits(&matmul_reference(&a, &b)));
    }

    #[test]
    fn sum_is_exact_on_integers_and_order_fixed() {
        let x: Vec<f32> = (0..1000).map(|i| i as f32).collect();
        assert_eq!(sum(&x), 499_500.0);
    }
}
