//! An unscrambled Sobol low-discrepancy sequence (Joe–Kuo direction numbers), used to draw the
//! shooting directions of section 4.1 in the latent space and, for an ablation, perturbation
//! directions in the action space.
//!
//! Everything is integer arithmetic on 32-bit direction numbers; a coordinate is an integer
//! divided by 2^32, which an `f64` holds exactly, so the points are identical on every platform.

/// Most dimensions the embedded table supports.
pub const MAX_DIM: usize = 64;

/// Bits per coordinate, and so the length (2^32 points) of the sequence.
const BITS: usize = 32;

/// 2^32: a coordinate is its 32-bit integer numerator divided by this.
const SCALE: f64 = 4_294_967_296.0;

/// Primitive polynomials and initial direction numbers for dimensions 2 to 64, one row
/// `(s, a, [m_1, …, m_s])` per dimension: `s` is the degree of the primitive polynomial over
/// GF(2), `a` packs its interior coefficients (bit `s − 1 − k` holds the coefficient of
/// `x^(s−k)`), and the `m_k` are the initial direction numbers (odd, `m_k < 2^k`).
///
/// Source: S. Joe and F. Y. Kuo, "Constructing Sobol sequences with better two-dimensional
/// projections", SIAM J. Sci. Comput. 30 (2008), 2635–2654; the first 64 dimensions of their
/// file `new-joe-kuo-6.21201` (search criterion D^(6), the authors' recommended set), published
/// at <https://web.maths.unsw.edu.au/~fkuo/sobol/>. Dimension 1 has no row: it is the van der
/// Corput sequence (all `m_k = 1`).
const JOE_KUO: [(usize, u32, &[u32]); MAX_DIM - 1] = [
    (1, 0, &[1]),
    (2, 1, &[1, 3]),
    (3, 1, &[1, 3, 1]),
    (3, 2, &[1, 1, 1]),
    (4, 1, &[1, 1, 3, 3]),
    (4, 4, &[1, 3, 5, 13]),
    (5, 2, &[1, 1, 5, 5, 17]),
    (5, 4, &[1, 1, 5, 5, 5]),
    (5, 7, &[1, 1, 7, 11, 19]),
    (5, 11, &[1, 1, 5, 1, 1]),
    (5, 13, &[1, 1, 1, 3, 11]),
    (5, 14, &[1, 3, 5, 5, 31]),
    (6, 1, &[1, 3, 3, 9, 7, 49]),
    (6, 13, &[1, 1, 1, 15, 21, 21]),
    (6, 16, &[1, 3, 1, 13, 27, 49]),
    (6, 19, &[1, 1, 1, 15, 7, 5]),
    (6, 22, &[1, 3, 1, 15, 13, 25]),
    (6, 25, &[1, 1, 5, 5, 19, 61]),
    (7, 1, &[1, 3, 7, 11, 23, 15, 103]),
    (7, 4, &[1, 3, 7, 13, 13, 15, 69]),
    (7, 7, &[1, 1, 3, 13, 7, 35, 63]),
    (7, 8, &[1, 3, 5, 9, 1, 25, 53]),
    (7, 14, &[1, 3, 1, 13, 9, 35, 107]),
    (7, 19, &[1, 3, 1, 5, 27, 61, 31]),
    (7, 21, &[1, 1, 5, 11, 19, 41, 61]),
    (7, 28, &[1, 3, 5, 3, 3, 13, 69]),
    (7, 31, &[1, 1, 7, 13, 1, 19, 1]),
    (7, 32, &[1, 3, 7, 5, 13, 19, 59]),
    (7, 37, &[1, 1, 3, 9, 25, 29, 41]),
    (7, 41, &[1, 3, 5, 13, 23, 1, 55]),
    (7, 42, &[1, 3, 7, 3, 13, 59, 17]),
    (7, 50, &[1, 3, 1, 3, 5, 53, 69]),
    (7, 55, &[1, 1, 5, 5, 23, 33, 13]),
    (7, 56, &[1, 1, 7, 7, 1, 61, 123]),
    (7, 59, &[1, 1, 7, 9, 13, 61, 49]),
    (7, 62, &[1, 3, 3, 5, 3, 55, 33]),
    (8, 14, &[1, 3, 1, 15, 31, 13, 49, 245]),
    (8, 21, &[1, 3, 5, 15, 31, 59, 63, 97]),
    (8, 22, &[1, 3, 1, 11, 11, 11, 77, 249]),
    (8, 38, &[1, 3, 1, 11, 27, 43, 71, 9]),
    (8, 47, &[1, 1, 7, 15, 21, 11, 81, 45]),
    (8, 49, &[1, 3, 7, 3, 25, 31, 65, 79]),
    (8, 50, &[1, 3, 1, 1, 19, 11, 3, 205]),
    (8, 52, &[1, 1, 5, 9, 19, 21, 29, 157]),
    (8, 56, &[1, 3, 7, 11, 1, 33, 89, 185]),
    (8, 67, &[1, 3, 3, 3, 15, 9, 79, 71]),
    (8, 70, &[1, 3, 7, 11, 15, 39, 119, 27]),
    (8, 84, &[1, 1, 3, 1, 11, 31, 97, 225]),
    (8, 97, &[1, 1, 1, 3, 23, 43, 57, 177]),
    (8, 103, &[1, 3, 7, 7, 17, 17, 37, 71]),
    (8, 115, &[1, 3, 1, 5, 27, 63, 123, 213]),
    (8, 122, &[1, 1, 3, 5, 11, 43, 53, 133]),
    (9, 8, &[1, 3, 5, 5, 29, 17, 47, 173, 479]),
    (9, 13, &[1, 3, 3, 11, 3, 1, 109, 9, 69]),
    (9, 16, &[1, 1, 1, 5, 17, 39, 23, 5, 343]),
    (9, 22, &[1, 3, 1, 5, 25, 15, 31, 103, 499]),
    (9, 25, &[1, 1, 1, 11, 11, 17, 63, 105, 183]),
    (9, 44, &[1, 1, 5, 11, 9, 29, 97, 231, 363]),
    (9, 47, &[1, 1, 5, 15, 19, 45, 41, 7, 383]),
    (9, 52, &[1, 3, 7, 7, 31, 19, 83, 137, 221]),
    (9, 55, &[1, 1, 1, 3, 23, 15, 111, 223, 83]),
    (9, 59, &[1, 1, 5, 13, 31, 15, 55, 25, 161]),
    (9, 62, &[1, 1, 3, 13, 25, 47, 39, 87, 257]),
];

/// The 32 direction numbers `v_1 … v_32` of one dimension, each `m_k · 2^(32−k)`.
type Directions = [u32; BITS];

/// Extends the initial `m_1 … m_s` of one table row by the Bratley–Fox recurrence
/// `m_k = 2 a_1 m_{k−1} ⊕ 2² a_2 m_{k−2} ⊕ … ⊕ 2^(s−1) a_{s−1} m_{k−s+1} ⊕ 2^s m_{k−s} ⊕ m_{k−s}`
/// and scales them to 32-bit direction numbers.
fn directions_of(s: usize, a: u32, initial: &[u32]) -> Directions {
    // m_k < 2^k, so u64 holds every m_k up to k = 32 with room for the shifts.
    let mut m = [0u64; BITS + 1];
    for (slot, &mk) in m[1..].iter_mut().zip(initial) {
        *slot = u64::from(mk);
    }
    for k in s + 1..=BITS {
        let mut mk = (m[k - s] << s) ^ m[k - s];
        for i in 1..s {
            if (a >> (s - 1 - i)) & 1 == 1 {
                mk ^= m[k - i] << i;
            }
        }
        m[k] = mk;
    }
    let mut v = [0u32; BITS];
    for (k, vk) in (1..=BITS).zip(v.iter_mut()) {
        // m_k < 2^k makes the shifted value < 2^32; the mask only restates that for the cast.
        *vk = ((m[k] << (BITS - k)) & u64::from(u32::MAX)) as u32;
    }
    v
}

/// An unscrambled Sobol sequence in `dim` dimensions (Joe–Kuo direction numbers), 32-bit.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Sobol {
    /// Direction numbers, one array per dimension.
    v: Vec<Directions>,
}

impl Sobol {
    /// Fails (returns None) for dim == 0 or dim > MAX_DIM.
    pub fn new(dim: usize) -> Option<Sobol> {
        if dim == 0 || dim > MAX_DIM {
            return None;
        }
        let mut v = Vec::with_capacity(dim);
        // Van der Corput: every m_k = 1, so v_k is the single bit 2^(32−k).
        v.push(std::array::from_fn(|b| 1u32 << (BITS - 1 - b)));
        for &(s, a, initial) in &JOE_KUO[..dim - 1] {
            v.push(directions_of(s, a, initial));
        }
        Some(Sobol { v })
    }

    /// Number of coordinates of every point.
    pub fn dim(&self) -> usize {
        self.v.len()
    }

    /// Point `index` (index 0 is the origin), each coordinate in [0, 1).
    ///
    /// Random access and stateless: coordinate j is the XOR of the direction numbers `v_{j,b}`
    /// over the set bits b of the Gray code `g = i ⊕ (i >> 1)` of `i = index mod 2^32`, divided
    /// by 2^32. Using the Gray code rather than `index` itself makes point `index` equal to the
    /// `index`-th point that Joe and Kuo's generator, SciPy (`scramble=False`) and TensorFlow
    /// emit, so published values check this code; both orders visit the same set of points in
    /// every block `[q·2^m, (q+1)·2^m)`, so the net properties are the same.
    ///
    /// The 32-bit sequence has 2^32 points; larger indices wrap around.
    pub fn point(&self, index: u64) -> Vec<f64> {
        let i = index & u64::from(u32::MAX);
        let gray = i ^ (i >> 1);
        self.v
            .iter()
            .map(|v| {
                let mut x = 0u32;
                let mut bits = gray;
                while bits != 0 {
                    x ^= v[bits.trailing_zeros() as usize];
                    // Clears the lowest set bit.
                    bits &= bits - 1;
                }
                f64::from(x) / SCALE
            })
            .collect()
    }
}

/// `k` shooting directions in [-1, 1)^dim: Sobol points `first`, `first + 1`, … mapped by
/// x ↦ 2x − 1. Fails (returns None) where [`Sobol::new`] does.
///
/// The map is exact in `f64` (a coordinate is a multiple of 2^−32), so the directions are as
/// reproducible as the points.
pub fn directions(dim: usize, first: u64, k: usize) -> Option<Vec<Vec<f64>>> {
    let sobol = Sobol::new(dim)?;
    Some(
        (0..k as u64)
            .map(|offset| {
                // Indices are taken mod 2^32 anyway, so wrapping keeps `first` near u64::MAX
                // meaningful instead of panicking.
                sobol
                    .point(first.wrapping_add(offset))
                    .into_iter()
                    .map(|x| 2.0 * x - 1.0)
                    .collect()
            })
            .collect(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sobol(dim: usize) -> Sobol {
        Sobol::new(dim).expect("dimension within 1..=MAX_DIM")
    }

    /// The integer numerators `x · 2^32` of a point, for exact comparisons of digits.
    fn raw(point: &[f64]) -> Vec<u32> {
        point.iter().map(|&x| (x * SCALE) as u32).collect()
    }

    #[test]
    fn dimension_bounds() {
        assert!(Sobol::new(0).is_none());
        assert!(Sobol::new(MAX_DIM + 1).is_none());
        assert_eq!(sobol(1).dim(), 1);
        assert_eq!(sobol(MAX_DIM).dim(), MAX_DIM);
        assert!(directions(0, 0, 3).is_none());
        assert!(directions(MAX_DIM + 1, 0, 3).is_none());
    }

    /// Guards the transcription: every row must be a well-formed Joe–Kuo row.
    #[test]
    fn table_rows_are_well_formed() {
        let mut previous_degree = 1;
        for (row, &(s, a, m)) in JOE_KUO.iter().enumerate() {
            let d = row + 2;
            assert_eq!(
                m.len(),
                s,
                "dimension {d}: degree and number of m_k disagree"
            );
            assert!(
                s >= previous_degree,
                "dimension {d}: degrees must not decrease"
            );
            assert!(
                a < 1 << (s - 1),
                "dimension {d}: a has more than s − 1 bits"
            );
            for (k, &mk) in (1..).zip(m) {
                assert!(
                    mk % 2 == 1 && mk < 1 << k,
                    "dimension {d}: m_{k} = {mk} not odd or ≥ 2^{k}"
                );
            }
            previous_degree = s;
        }
        // A few rows read off new-joe-kuo-6.21201 again, including dimension 10 whose last m is
        // 19 (a truncated copy in circulation has 1) and the last row.
        assert_eq!(JOE_KUO[10 - 2], (5, 7, &[1, 1, 7, 11, 19][..]));
        assert_eq!(
            JOE_KUO[38 - 2],
            (8, 14, &[1, 3, 1, 15, 31, 13, 49, 245][..])
        );
        assert_eq!(
            JOE_KUO[64 - 2],
            (9, 62, &[1, 1, 3, 13, 25, 47, 39, 87, 257][..])
        );
    }

    #[test]
    fn first_points_in_three_dimensions() {
        // The first points as printed by Joe and Kuo's generator and by SciPy's unscrambled
        // Sobol (Gray-code order).
        let expected = [
            [0.0, 0.0, 0.0],
            [0.5, 0.5, 0.5],
            [0.75, 0.25, 0.25],
            [0.25, 0.75, 0.75],
            [0.375, 0.375, 0.625],
            [0.875, 0.875, 0.125],
            [0.625, 0.125, 0.875],
            [0.125, 0.625, 0.375],
            [0.1875, 0.3125, 0.9375],
            [0.6875, 0.8125, 0.4375],
        ];
        let s = sobol(3);
        for (index, e) in (0..).zip(&expected) {
            assert_eq!(s.point(index), e.to_vec(), "point {index}");
        }
    }

    #[test]
    fn first_points_in_eight_dimensions() {
        // Points 1..=20 in 8 dimensions from the test `test_sobol_seq` in src/sobol.rs of
        // github.com/aldanor/qrng-rust (commit 3a9519b), a generator built on the same
        // new-joe-kuo-6.21201 numbers; its first 5 columns also agree with `test_more_known_values`
        // in tensorflow/python/ops/sobol_ops_test.py.
        let expected = [
            [0.5, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5],
            [0.75, 0.25, 0.25, 0.25, 0.75, 0.75, 0.25, 0.75],
            [0.25, 0.75, 0.75, 0.75, 0.25, 0.25, 0.75, 0.25],
            [0.375, 0.375, 0.625, 0.875, 0.375, 0.125, 0.375, 0.875],
            [0.875, 0.875, 0.125, 0.375, 0.875, 0.625, 0.875, 0.375],
            [0.625, 0.125, 0.875, 0.625, 0.625, 0.875, 0.125, 0.125],
            [0.125, 0.625, 0.375, 0.125, 0.125, 0.375, 0.625, 0.625],
            [
                0.1875, 0.3125, 0.9375, 0.4375, 0.5625, 0.3125, 0.4375, 0.9375,
            ],
            [
                0.6875, 0.8125, 0.4375, 0.9375, 0.0625, 0.8125, 0.9375, 0.4375,
            ],
            [
                0.9375, 0.0625, 0.6875, 0.1875, 0.3125, 0.5625, 0.1875, 0.1875,
            ],
            [
                0.4375, 0.5625, 0.1875, 0.6875, 0.8125, 0.0625, 0.6875, 0.6875,
            ],
            [
                0.3125, 0.1875, 0.3125, 0.5625, 0.9375, 0.4375, 0.0625, 0.0625,
            ],
            [
                0.8125, 0.6875, 0.8125, 0.0625, 0.4375, 0.9375, 0.5625, 0.5625,
            ],
            [
                0.5625, 0.4375, 0.0625, 0.8125, 0.1875, 0.6875, 0.3125, 0.8125,
            ],
            [
                0.0625, 0.9375, 0.5625, 0.3125, 0.6875, 0.1875, 0.8125, 0.3125,
            ],
            [
                0.09375, 0.46875, 0.46875, 0.65625, 0.28125, 0.96875, 0.53125, 0.84375,
            ],
            [
                0.59375, 0.96875, 0.96875, 0.15625, 0.78125, 0.46875, 0.03125, 0.34375,
            ],
            [
                0.84375, 0.21875, 0.21875, 0.90625, 0.53125, 0.21875, 0.78125, 0.09375,
            ],
            [
                0.34375, 0.71875, 0.71875, 0.40625, 0.03125, 0.71875, 0.28125, 0.59375,
            ],
            [
                0.46875, 0.09375, 0.84375, 0.28125, 0.15625, 0.84375, 0.90625, 0.21875,
            ],
        ];
        let s = sobol(8);
        assert_eq!(s.point(0), vec![0.0; 8]);
        for (index, e) in (1..).zip(&expected) {
            assert_eq!(s.point(index), e.to_vec(), "point {index}");
        }
    }

    #[test]
    fn later_points_in_five_dimensions() {
        // Points 22..=31 in 5 dimensions from `test_more_known_values` in
        // tensorflow/python/ops/sobol_ops_test.py (github.com/tensorflow/tensorflow).
        let expected = [
            [0.71875, 0.34375, 0.59375, 0.03125, 0.90625],
            [0.21875, 0.84375, 0.09375, 0.53125, 0.40625],
            [0.15625, 0.15625, 0.53125, 0.84375, 0.84375],
            [0.65625, 0.65625, 0.03125, 0.34375, 0.34375],
            [0.90625, 0.40625, 0.78125, 0.59375, 0.09375],
            [0.40625, 0.90625, 0.28125, 0.09375, 0.59375],
            [0.28125, 0.28125, 0.15625, 0.21875, 0.71875],
            [0.78125, 0.78125, 0.65625, 0.71875, 0.21875],
            [0.53125, 0.03125, 0.40625, 0.46875, 0.46875],
            [0.03125, 0.53125, 0.90625, 0.96875, 0.96875],
        ];
        let s = sobol(5);
        for (index, e) in (22..).zip(&expected) {
            assert_eq!(s.point(index), e.to_vec(), "point {index}");
        }
    }

    /// The first 2^m points of every one-dimensional projection are exactly {i / 2^m}, i.e. a
    /// (0, m, 1)-net, for every dimension of the table.
    #[test]
    fn one_dimensional_projections_are_nets() {
        const M_MAX: u32 = 10;
        let s = sobol(MAX_DIM);
        let points: Vec<Vec<u32>> = (0..1u64 << M_MAX).map(|i| raw(&s.point(i))).collect();
        for m in 0..=M_MAX {
            let n = 1usize << m;
            for j in 0..MAX_DIM {
                let mut seen = vec![false; n];
                for p in &points[..n] {
                    let x = p[j];
                    assert_eq!(
                        x & (u32::MAX >> m),
                        0,
                        "dim {}: x not a multiple of 2^-{m}",
                        j + 1
                    );
                    let cell = if m == 0 { 0 } else { (x >> (32 - m)) as usize };
                    assert!(
                        !seen[cell],
                        "dim {}, m = {m}: value {cell}/2^{m} repeated",
                        j + 1
                    );
                    seen[cell] = true;
                }
            }
        }
    }

    /// Smallest t for which the 2-d points `(x, y)` (numerators of 2^32, `2^m` of them) form a
    /// (t, m, 2)-net: every dyadic box of volume 2^(t−m) holds exactly 2^t points.
    fn t_value(points: &[(u32, u32)], m: u32) -> u32 {
        (0..=m)
            .find(|&t| {
                (0..=m - t).all(|a| {
                    let b = m - t - a;
                    let mut count = vec![0u32; 1 << (m - t)];
                    for &(x, y) in points {
                        let cx = if a == 0 { 0 } else { (x >> (32 - a)) as usize };
                        let cy = if b == 0 { 0 } else { (y >> (32 - b)) as usize };
                        count[(cx << b) | cy] += 1;
                    }
                    count.iter().all(|&c| c == 1 << t)
                })
            })
            .unwrap_or(m)
    }

    /// Every pair among the first 8 dimensions: the first 2^m points form a (t, m, 2)-net with t
    /// at most Sobol's bound (s_i − 1) + (s_j − 1), at most 4 overall (the value this table
    /// attains, kept as a regression guard), and t = 0 for the first two dimensions.
    #[test]
    fn two_dimensional_projections_are_nets() {
        const D: usize = 8;
        const M_MAX: u32 = 10;
        let s = sobol(D);
        let points: Vec<Vec<u32>> = (0..1u64 << M_MAX).map(|i| raw(&s.point(i))).collect();
        // Degree − 1 per dimension; dimension 1 (van der Corput) behaves as degree 1.
        let excess: Vec<u32> = std::iter::once(0)
            .chain(JOE_KUO[..D - 1].iter().map(|&(deg, _, _)| deg as u32 - 1))
            .collect();
        let mut worst = 0;
        for i in 0..D {
            for j in i + 1..D {
                for m in 1..=M_MAX {
                    let pair: Vec<(u32, u32)> =
                        points[..1 << m].iter().map(|p| (p[i], p[j])).collect();
                    let t = t_value(&pair, m);
                    assert!(
                        t <= excess[i] + excess[j],
                        "dims ({}, {}), m = {m}: t = {t} above Sobol's bound",
                        i + 1,
                        j + 1
                    );
                    if i == 0 && j == 1 {
                        assert_eq!(t, 0, "dims (1, 2) must be a (0, m, 2)-net, m = {m}");
                    }
                    worst = worst.max(t);
                }
            }
        }
        assert!(worst <= 4, "worst t = {worst}");
    }

    #[test]
    fn point_is_random_access_and_wraps_at_two_to_the_32() {
        let s = sobol(MAX_DIM);
        let later = s.point(123_456_789);
        assert_eq!(later, s.point(123_456_789));
        assert_eq!(s.point(123_456_789 + (1 << 32)), later);
        assert_eq!(s.point(1 << 32), vec![0.0; MAX_DIM]);
        // The last point of the 32-bit sequence is still inside [0, 1).
        assert!(
            s.point(u64::from(u32::MAX))
                .iter()
                .all(|&x| (0.0..1.0).contains(&x))
        );
    }

    #[test]
    fn directions_map_points_into_the_half_open_cube() {
        for &dim in &[1, 8, 56, MAX_DIM] {
            let s = sobol(dim);
            let first = 1;
            let k = 300;
            let d = directions(dim, first, k).expect("valid dimension");
            assert_eq!(d.len(), k);
            for (offset, u) in (0..).zip(&d) {
                assert_eq!(u.len(), dim);
                assert!(u.iter().all(|&x| (-1.0..1.0).contains(&x)));
                let x = s.point(first + offset);
                assert!(u.iter().zip(&x).all(|(&u, &x)| u == 2.0 * x - 1.0));
            }
            assert_eq!(directions(dim, first, k), Some(d));
        }
        assert_eq!(directions(8, 0, 1), Some(vec![vec![-1.0; 8]]));
        assert_eq!(directions(8, 1, 1), Some(vec![vec![0.0; 8]]));
        assert_eq!(directions(8, 5, 0), Some(vec![]));
        // Start near the end of u64: wraps instead of overflowing.
        let tail = directions(3, u64::MAX, 2).expect("valid dimension");
        assert_eq!(tail[1], vec![-1.0; 3]);
    }

    /// The recurrence, checked where it can be worked out by hand, and the structural property
    /// of every direction number that the one-dimensional net property rests on.
    #[test]
    fn sampled_direction_numbers() {
        let s = sobol(MAX_DIM);
        // Dimension 2 (x + 1): m_k = 2 m_{k-1} ⊕ m_{k-1}, so v has the Pascal-triangle mod 2
        // pattern: v_1 = 2^31, v_2 = 3·2^30, v_3 = 5·2^29, v_4 = 15·2^28.
        assert_eq!(&s.v[1][..4], &[1 << 31, 3 << 30, 5 << 29, 15 << 28]);
        for v in &s.v {
            // Column k of the generator matrix has its lowest set bit on the diagonal, which is
            // what makes every dimension a (0, m, 1)-net.
            for (k, &vk) in v.iter().enumerate() {
                assert_eq!(vk.trailing_zeros() as usize, BITS - 1 - k);
            }
        }
    }
}
