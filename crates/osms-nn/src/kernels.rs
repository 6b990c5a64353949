//! f32 matrix products with a fixed summation order (ARCHITECTURE.md, "Numerics that must not
//! drift"). Every output element is `((0 + a₀b₀) + a₁b₁) + …` in increasing k, with separate
//! multiply and add (Rust never contracts them into an FMA), so the tiled kernels, the scalar
//! reference, any thread count and any x86-64 or aarch64 CPU give the same bits. The tiled
//! kernels vectorise across output columns only (a row of 16 accumulators per tile, which the
//! compiler keeps in registers with the baseline instruction set); rows are split across threads,
//! never k.

use rayon::prelude::*;

use crate::Matrix;

/// Columns per register tile.
const TILE: usize = 16;
/// Below this many multiply-adds, threads cost more than they save.
const PARALLEL_MIN_WORK: usize = 1 << 16;

/// One output row: `c_row[j] = Σ_k a_row[k] · b[k][j]` in k order, 16 columns at a time.
fn row_times(a_row: &[f32], b: &[f32], n: usize, c_row: &mut [f32]) {
    let mut j0 = 0;
    while j0 < n {
        let width = TILE.min(n - j0);
        let mut acc = [0.0f32; TILE];
        for (k, &a) in a_row.iter().enumerate() {
            let b_row = &b[k * n + j0..k * n + j0 + width];
            for (acc, &bv) in acc[..width].iter_mut().zip(b_row) {
                *acc += a * bv;
            }
        }
        c_row[j0..j0 + width].copy_from_slice(&acc[..width]);
        j0 += width;
    }
}

fn for_rows(c: &mut Matrix, work: usize, f: impl Fn(usize, &mut [f32]) + Sync + Send) {
    let n = c.cols;
    if n == 0 {
        return;
    }
    if work >= PARALLEL_MIN_WORK {
        c.data
            .par_chunks_mut(n)
            .enumerate()
            .for_each(|(i, row)| f(i, row));
    } else {
        c.data
            .chunks_mut(n)
            .enumerate()
            .for_each(|(i, row)| f(i, row));
    }
}

/// C = A · B.
pub fn matmul(a: &Matrix, b: &Matrix) -> Matrix {
    assert_eq!(
        a.cols, b.rows,
        "A·B: {}x{} times {}x{}",
        a.rows, a.cols, b.rows, b.cols
    );
    let (m, k, n) = (a.rows, a.cols, b.cols);
    let mut c = Matrix::zeros(m, n);
    for_rows(&mut c, m * k * n, |i, row| {
        row_times(&a.data[i * k..(i + 1) * k], &b.data, n, row)
    });
    c
}

/// C = Aᵀ · B (A is k × m).
pub fn matmul_tn(a: &Matrix, b: &Matrix) -> Matrix {
    assert_eq!(
        a.rows, b.rows,
        "Aᵀ·B: ({}x{})ᵀ times {}x{}",
        a.rows, a.cols, b.rows, b.cols
    );
    matmul(&a.transpose(), b)
}

/// C = A · Bᵀ (B is n × k).
pub fn matmul_nt(a: &Matrix, b: &Matrix) -> Matrix {
    assert_eq!(
        a.cols, b.cols,
        "A·Bᵀ: {}x{} times ({}x{})ᵀ",
        a.rows, a.cols, b.rows, b.cols
    );
    matmul(a, &b.transpose())
}

/// The plain triple loop the tiled kernels must match bit for bit.
pub fn matmul_reference(a: &Matrix, b: &Matrix) -> Matrix {
    assert_eq!(a.cols, b.rows);
    let mut c = Matrix::zeros(a.rows, b.cols);
    for i in 0..a.rows {
        for j in 0..b.cols {
            let mut s = 0.0f32;
            for k in 0..a.cols {
                s += a.get(i, k) * b.get(k, j);
            }
            c.set(i, j, s);
        }
    }
    c
}

/// Σ of `x` in fixed chunks of 256, chunk sums added in index order (f64 accumulation inside a
/// chunk keeps long sums accurate; the order keeps them reproducible).
pub fn sum(x: &[f32]) -> f32 {
    let mut total = 0.0f64;
    for chunk in x.chunks(256) {
        let mut s = 0.0f64;
        for &v in chunk {
            s += f64::from(v);
        }
        total += s;
    }
    total as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    fn random(rows: usize, cols: usize, seed: u64) -> Matrix {
        let mut rng = osms_make::rng::stream(seed, "kernels", "test", (rows * 1000 + cols) as u64);
        Matrix::from_fn(rows, cols, |_, _| {
            osms_make::rng::uniform(&mut rng, -1.0, 1.0) as f32
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
        ] {
            let a = random(m, k, 1);
            let b = random(k, n, 2);
            let reference = matmul_reference(&a, &b);
            assert_eq!(bits(&matmul(&a, &b)), bits(&reference), "{m}x{k}x{n}");
            assert_eq!(
                bits(&matmul_tn(&a.transpose(), &b)),
                bits(&reference),
                "tn {m}x{k}x{n}"
            );
            assert_eq!(
                bits(&matmul_nt(&a, &b.transpose())),
                bits(&reference),
                "nt {m}x{k}x{n}"
            );
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
