//! Aggregation over run seeds (mean and sample standard deviation), and the confidence
//! intervals of the claims check: differences between two policies evaluated on the same
//! held-out conditions over a few training seeds, and differences between two proportions.
//!
//! docs/report.md ("Claims check") gives the method and its references.

use serde::{Deserialize, Serialize};

/// Mean and sample standard deviation (n − 1) of per-seed values.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MeanSd {
    pub mean: f64,
    /// `None` for a single value.
    pub sd: Option<f64>,
    pub n: usize,
}

impl MeanSd {
    /// `None` for no values.
    pub fn of(values: &[f64]) -> Option<MeanSd> {
        let n = values.len();
        if n == 0 {
            return None;
        }
        let mean = values.iter().sum::<f64>() / n as f64;
        let sd = (n > 1).then(|| {
            let ss: f64 = values.iter().map(|v| (v - mean) * (v - mean)).sum();
            (ss / (n - 1) as f64).sqrt()
        });
        Some(MeanSd { mean, sd, n })
    }
}

/// A difference `a − b` with its 95 % confidence interval.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Difference {
    pub estimate: f64,
    pub low: f64,
    pub high: f64,
    /// The interval's half-width: the smallest |difference| this comparison could have
    /// resolved (a true difference of this size is excluded from 0 about half the time).
    pub resolvable: f64,
    /// Degrees of freedom of the t quantile (`None`: a score interval).
    pub df: Option<f64>,
    /// Run seeds of `a` and of `b`.
    pub seeds: [usize; 2],
    /// Paired conditions, or (unpaired) the values of `a` and of `b` pooled over seeds.
    pub n: [usize; 2],
    pub method: Method,
    /// The measured variance components of a paired difference, to project the interval to
    /// other seed and condition counts.
    pub parts: Option<VarianceParts>,
}

/// What a paired difference's variance is made of, per rollout and per seed.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct VarianceParts {
    /// Each policy's training-seed variance τ² (`None`: one seed, unknown).
    pub tau2: [Option<f64>; 2],
    /// The variance over conditions of the per-condition difference of the seed-averaged
    /// outcomes, at the measured seed counts.
    pub condition: f64,
    /// The seed counts `condition` was measured at.
    pub seeds: [usize; 2],
}

impl VarianceParts {
    /// The 95 % half-width had the policies been built with `seeds` run seeds each and
    /// evaluated on `n` conditions, with this run's variance components. The condition part
    /// is kept as measured (more seeds would shrink its rollout noise, so this is
    /// conservative); an unknown τ² counts as 0.
    pub fn resolvable_with(&self, seeds: [usize; 2], n: usize) -> f64 {
        let seed_part =
            |i: usize| self.tau2[i].map(|t| (t / seeds[i] as f64, (seeds[i].max(2) - 1) as f64));
        let condition = Some((self.condition / n as f64, (n.max(2) - 1) as f64));
        t_interval(
            0.0,
            &[seed_part(0), seed_part(1), condition],
            seeds,
            [n, n],
            Method::Paired,
        )
        .resolvable
    }

    /// The fewest run seeds per policy (a policy built once keeps its one) at which a
    /// difference of `target` would be resolved on `n` conditions, up to `max_seeds`.
    pub fn seeds_to_resolve(&self, target: f64, n: usize, max_seeds: usize) -> Option<usize> {
        (2..=max_seeds).find(|&s| {
            let seeds = self.seeds.map(|m| if m == 1 { 1 } else { s });
            self.resolvable_with(seeds, n) <= target.abs()
        })
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Method {
    /// Same conditions for both policies, every rollout defined: [`paired_difference`].
    Paired,
    /// Values on different subsets of the conditions: [`unpaired_difference`].
    Unpaired,
    /// Two counts out of totals: [`proportion_difference`].
    Proportions,
    /// Replicates of the difference on resampled conditions: [`bootstrap_difference`].
    Bootstrap,
}

impl Difference {
    /// Where the interval lies against 0, for a claim that `a` is higher (or lower) than `b`.
    pub fn decide(&self, a_higher: bool) -> Decision {
        let (favour, against) = if a_higher {
            (self.low > 0.0, self.high < 0.0)
        } else {
            (self.high < 0.0, self.low > 0.0)
        };
        if favour {
            Decision::Holds
        } else if against {
            Decision::Contradicted
        } else {
            Decision::Unresolved
        }
    }
}

/// A claim's verdict from a confidence interval.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Decision {
    /// The interval excludes 0 in the claimed direction.
    Holds,
    /// The interval excludes 0 in the other direction.
    Contradicted,
    /// The interval spans 0.
    Unresolved,
}

/// The 95 % interval's two-sided quantile.
const LEVEL: f64 = 0.975;

/// `a − b` for two policies evaluated on the same `n` conditions: `a[s][c]` is run seed `s`'s
/// value on condition `c` (1 or 0 for success). The estimate is the difference of the mean
/// over seeds of the per-seed means, as the tables show them.
///
/// Its variance has three parts, each estimated from the data (a two-way random-effects
/// decomposition, seeds × conditions, per policy):
/// - each policy's training-seed variance τ² over its number of seeds, τ² from the two-way
///   ANOVA without replication, (MS_seed − MS_residual) / n, floored at 0;
/// - the conditions' variance, shared by both policies and so paired: the variance over
///   conditions of the per-condition difference of the seed-averaged values, over n (it
///   holds the rollouts' own noise once).
///
/// The interval is t with Welch–Satterthwaite degrees of freedom (seed parts: seeds − 1;
/// condition part: n − 1). A policy with one seed contributes no seed variance: its training
/// spread is unknown and not in the interval. `None` without conditions, without seeds, or
/// when the two policies' condition counts differ.
pub fn paired_difference(a: &[Vec<f64>], b: &[Vec<f64>]) -> Option<Difference> {
    let n = a.first()?.len();
    if n < 2 || b.is_empty() || a.iter().chain(b).any(|s| s.len() != n) {
        return None;
    }
    let (ma, sa) = seed_part(a);
    let (mb, sb) = seed_part(b);
    let per_condition =
        |v: &[Vec<f64>], c: usize| v.iter().map(|s| s[c]).sum::<f64>() / v.len() as f64;
    let d: Vec<f64> = (0..n)
        .map(|c| per_condition(a, c) - per_condition(b, c))
        .collect();
    let condition_variance = sample_variance(&d);
    let condition = (condition_variance / n as f64, (n - 1) as f64);
    let seeds = [a.len(), b.len()];
    let mut diff = t_interval(
        ma - mb,
        &[sa, sb, Some(condition)],
        seeds,
        [n, n],
        Method::Paired,
    );
    diff.parts = Some(VarianceParts {
        tau2: [
            sa.map(|(v, _)| v * seeds[0] as f64),
            sb.map(|(v, _)| v * seeds[1] as f64),
        ],
        condition: condition_variance,
        seeds,
    });
    Some(diff)
}

/// Mean over seeds of the per-seed means, and the seed part of its variance: τ² / S with
/// S − 1 degrees of freedom (`None` for one seed).
fn seed_part(v: &[Vec<f64>]) -> (f64, Option<(f64, f64)>) {
    let s = v.len();
    let n = v[0].len();
    let rows: Vec<f64> = v.iter().map(|r| mean(r)).collect();
    let grand = mean(&rows);
    if s < 2 {
        return (grand, None);
    }
    let cols: Vec<f64> = (0..n)
        .map(|c| v.iter().map(|r| r[c]).sum::<f64>() / s as f64)
        .collect();
    let ms_seed = n as f64 * rows.iter().map(|m| (m - grand).powi(2)).sum::<f64>() / (s - 1) as f64;
    let ss_res: f64 = v
        .iter()
        .zip(&rows)
        .map(|(r, m)| {
            (0..n)
                .map(|c| (r[c] - m - cols[c] + grand).powi(2))
                .sum::<f64>()
        })
        .sum();
    let ms_res = ss_res / ((s - 1) * (n - 1)) as f64;
    let tau2 = ((ms_seed - ms_res) / n as f64).max(0.0);
    (grand, Some((tau2 / s as f64, (s - 1) as f64)))
}

/// `a − b` for a quantity defined on different rollouts of each policy (f_max over catch
/// completions): `a[s]` holds run seed `s`'s defined values. The estimate is the difference
/// of the mean over seeds of the per-seed means. The sets of completions differ, so rollouts
/// are not paired: each policy's variance is the variance over seeds of its per-seed means
/// over S, plus the variance of its values over the mean number per seed. The second part
/// counts the rollouts' own noise a second time, so the interval is conservative. A seed
/// without values is left out; `None` when a policy has no values at all or fewer than two.
pub fn unpaired_difference(a: &[Vec<f64>], b: &[Vec<f64>]) -> Option<Difference> {
    let (ma, pa, na, sa) = unpaired_part(a)?;
    let (mb, pb, nb, sb) = unpaired_part(b)?;
    let parts: Vec<Option<(f64, f64)>> = pa.into_iter().chain(pb).map(Some).collect();
    Some(t_interval(
        ma - mb,
        &parts,
        [sa, sb],
        [na, nb],
        Method::Unpaired,
    ))
}

type UnpairedPart = (f64, Vec<(f64, f64)>, usize, usize);

fn unpaired_part(v: &[Vec<f64>]) -> Option<UnpairedPart> {
    let seeds: Vec<&Vec<f64>> = v.iter().filter(|s| !s.is_empty()).collect();
    let total: usize = seeds.iter().map(|s| s.len()).sum();
    if seeds.is_empty() || total < 2 {
        return None;
    }
    let means: Vec<f64> = seeds.iter().map(|s| mean(s)).collect();
    let grand = mean(&means);
    let s = seeds.len();
    let per_seed = total as f64 / s as f64;
    let within: f64 = seeds
        .iter()
        .zip(&means)
        .map(|(v, m)| v.iter().map(|x| (x - m).powi(2)).sum::<f64>())
        .sum::<f64>()
        / (total - s).max(1) as f64;
    let mut parts = vec![(within / per_seed, (total - s).max(1) as f64)];
    if s > 1 {
        parts.push((sample_variance(&means) / s as f64, (s - 1) as f64));
    }
    Some((grand, parts, total, s))
}

fn t_interval(
    estimate: f64,
    parts: &[Option<(f64, f64)>],
    seeds: [usize; 2],
    n: [usize; 2],
    method: Method,
) -> Difference {
    let parts: Vec<(f64, f64)> = parts.iter().flatten().copied().collect();
    let var: f64 = parts.iter().map(|(v, _)| v).sum();
    // Welch–Satterthwaite; a part with no variance adds nothing to either sum.
    let denom: f64 = parts.iter().map(|(v, df)| v * v / df).sum();
    let df = if denom > 0.0 {
        (var * var / denom).max(1.0)
    } else {
        f64::INFINITY
    };
    let half = student_t_quantile(LEVEL, df) * var.sqrt();
    Difference {
        estimate,
        low: estimate - half,
        high: estimate + half,
        resolvable: half,
        df: Some(df),
        seeds,
        n,
        method,
        parts: None,
    }
}

/// `x_a / n_a − x_b / n_b` with Newcombe's hybrid score interval (Newcombe 1998, "Interval
/// estimation for the difference between independent proportions", method 10), built from
/// the two Wilson score intervals. For counts over the same conditions (coverage, repair) the
/// pairing is ignored, which widens the interval when the two are positively correlated.
/// `None` for an empty total or a count above its total.
pub fn proportion_difference(xa: usize, na: usize, xb: usize, nb: usize) -> Option<Difference> {
    if na == 0 || nb == 0 || xa > na || xb > nb {
        return None;
    }
    let z = normal_quantile(LEVEL);
    let (pa, pb) = (xa as f64 / na as f64, xb as f64 / nb as f64);
    let (la, ua) = wilson(xa, na, z);
    let (lb, ub) = wilson(xb, nb, z);
    let d = pa - pb;
    let low = d - ((pa - la).powi(2) + (ub - pb).powi(2)).sqrt();
    let high = d + ((ua - pa).powi(2) + (pb - lb).powi(2)).sqrt();
    Some(Difference {
        estimate: d,
        low,
        high,
        resolvable: 0.5 * (high - low),
        df: None,
        seeds: [1, 1],
        n: [na, nb],
        method: Method::Proportions,
        parts: None,
    })
}

/// `a − b` from one estimate and its bootstrap replicates (the same statistic on resamples of
/// the `n` conditions, drawn with replacement and shared by both sides, so paired), with the
/// percentile interval: the replicates' 2.5 % and 97.5 % quantiles (Efron & Tibshirani 1993,
/// "An Introduction to the Bootstrap", ch. 13; linear interpolation between order
/// statistics). `None` with fewer than 2 replicates or a non-finite one.
pub fn bootstrap_difference(estimate: f64, replicates: &[f64], n: usize) -> Option<Difference> {
    if replicates.len() < 2 || !estimate.is_finite() || replicates.iter().any(|r| !r.is_finite()) {
        return None;
    }
    let mut sorted = replicates.to_vec();
    sorted.sort_by(f64::total_cmp);
    let quantile = |p: f64| {
        let h = p * (sorted.len() - 1) as f64;
        let (i, f) = (h.floor() as usize, h - h.floor());
        let next = sorted[(i + 1).min(sorted.len() - 1)];
        sorted[i] + f * (next - sorted[i])
    };
    let (low, high) = (quantile(1.0 - LEVEL), quantile(LEVEL));
    Some(Difference {
        estimate,
        low,
        high,
        resolvable: 0.5 * (high - low),
        df: None,
        seeds: [1, 1],
        n: [n, n],
        method: Method::Bootstrap,
        parts: None,
    })
}

/// The Wilson score interval of `x` out of `n`.
pub fn wilson(x: usize, n: usize, z: f64) -> (f64, f64) {
    let (n, p) = (n as f64, x as f64 / n as f64);
    let z2 = z * z;
    let centre = (p + z2 / (2.0 * n)) / (1.0 + z2 / n);
    let half = z * (p * (1.0 - p) / n + z2 / (4.0 * n * n)).sqrt() / (1.0 + z2 / n);
    (centre - half, centre + half)
}

/// The Wilson score interval of `x` out of `n` as a reader expects it printed: clamped to
/// [0, 1], and exactly 0 (1) at its lower (upper) end when `x` is 0 (`n`), where
/// [`wilson`]'s two terms cancel only up to rounding. `None` for `n` = 0 or `x` > `n`.
pub fn wilson_bounds(x: usize, n: usize, z: f64) -> Option<(f64, f64)> {
    if n == 0 || x > n {
        return None;
    }
    let (low, high) = wilson(x, n, z);
    let low = if x == 0 { 0.0 } else { low.clamp(0.0, 1.0) };
    let high = if x == n { 1.0 } else { high.clamp(0.0, 1.0) };
    Some((low, high))
}

fn mean(v: &[f64]) -> f64 {
    v.iter().sum::<f64>() / v.len() as f64
}

fn sample_variance(v: &[f64]) -> f64 {
    let m = mean(v);
    v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64
}

/// The standard normal quantile, by bisection on its CDF (erfc from `libm`).
pub fn normal_quantile(p: f64) -> f64 {
    let cdf = |x: f64| 0.5 * libm::erfc(-x / std::f64::consts::SQRT_2);
    bisect(cdf, p, -40.0, 40.0)
}

/// Student's t quantile with `df` degrees of freedom (`df` = ∞: the normal's).
pub fn student_t_quantile(p: f64, df: f64) -> f64 {
    if !df.is_finite() {
        return normal_quantile(p);
    }
    // Two forms of the same CDF, each where it does not cancel: near 0 through
    // I_{t²/(df+t²)}(1/2, df/2), in the tails through I_{df/(df+t²)}(df/2, 1/2).
    let cdf = |t: f64| {
        let t2 = t * t;
        if t2 < df {
            let half = 0.5 * regularized_beta(t2 / (df + t2), 0.5, 0.5 * df);
            if t >= 0.0 { 0.5 + half } else { 0.5 - half }
        } else {
            let tail = 0.5 * regularized_beta(df / (df + t2), 0.5 * df, 0.5);
            if t >= 0.0 { 1.0 - tail } else { tail }
        }
    };
    bisect(cdf, p, -1e7, 1e7)
}

/// The x at which an increasing `f` reaches `p`, to machine precision.
fn bisect(f: impl Fn(f64) -> f64, p: f64, mut lo: f64, mut hi: f64) -> f64 {
    for _ in 0..200 {
        let mid = 0.5 * (lo + hi);
        if mid == lo || mid == hi {
            break;
        }
        if f(mid) < p {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// I_x(a, b), the regularized incomplete beta function, by its continued fraction (modified
/// Lentz), using the symmetry I_x(a, b) = 1 − I_{1−x}(b, a) where the fraction converges slowly.
fn regularized_beta(x: f64, a: f64, b: f64) -> f64 {
    if x <= 0.0 {
        return 0.0;
    }
    if x >= 1.0 {
        return 1.0;
    }
    let ln_front = libm::lgamma(a + b) - libm::lgamma(a) - libm::lgamma(b)
        + a * libm::log(x)
        + b * libm::log(1.0 - x);
    if x < (a + 1.0) / (a + b + 2.0) {
        libm::exp(ln_front) * beta_fraction(x, a, b) / a
    } else {
        1.0 - libm::exp(ln_front) * beta_fraction(1.0 - x, b, a) / b
    }
}

fn beta_fraction(x: f64, a: f64, b: f64) -> f64 {
    const TINY: f64 = 1e-300;
    let guard = |v: f64| if v.abs() < TINY { TINY } else { v };
    let mut c = 1.0;
    let mut d = 1.0 / guard(1.0 - (a + b) * x / (a + 1.0));
    let mut h = d;
    for m in 1..1000 {
        let m = f64::from(m);
        let even = m * (b - m) * x / ((a + 2.0 * m - 1.0) * (a + 2.0 * m));
        d = 1.0 / guard(1.0 + even * d);
        c = guard(1.0 + even / c);
        h *= d * c;
        let odd = -(a + m) * (a + b + m) * x / ((a + 2.0 * m) * (a + 2.0 * m + 1.0));
        d = 1.0 / guard(1.0 + odd * d);
        c = guard(1.0 + odd / c);
        let step = d * c;
        h *= step;
        if (step - 1.0).abs() < 1e-15 {
            break;
        }
    }
    h
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::{normal, stream, uniform01};

    #[test]
    fn wilson_bounds_are_exact_at_the_ends_and_agree_inside() {
        let z = 1.959963984540054;
        // x = 0: the upper end is z² / (n + z²) in closed form, the lower exactly 0.
        let (low, high) = wilson_bounds(0, 40, z).expect("n > 0");
        assert_eq!(low, 0.0);
        assert!((high - z * z / (40.0 + z * z)).abs() < 1e-15, "{high}");
        let (low, high) = wilson_bounds(40, 40, z).expect("n > 0");
        assert_eq!(high, 1.0);
        assert!((low - 40.0 / (40.0 + z * z)).abs() < 1e-15, "{low}");
        assert_eq!(wilson_bounds(7, 40, z), Some(wilson(7, 40, z)));
        assert_eq!(wilson_bounds(0, 0, z), None);
        assert_eq!(wilson_bounds(5, 4, z), None);
    }

    #[test]
    fn sample_sd_divides_by_n_minus_one() {
        let m = MeanSd::of(&[0.80, 0.90, 0.85]).expect("values");
        assert!((m.mean - 0.85).abs() < 1e-12);
        // Deviations ±0.05 and 0: (0.0025 + 0.0025) / 2 = 0.0025.
        assert!((m.sd.expect("sd") - 0.05).abs() < 1e-12);
        assert_eq!(m.n, 3);
        assert_eq!(MeanSd::of(&[2.0]).expect("one").sd, None);
        assert_eq!(MeanSd::of(&[]), None);
    }

    #[test]
    fn quantiles_match_the_printed_tables() {
        // Student's t table, two-sided 95 %, and the normal's 1.959964.
        for (df, t) in [
            (1.0, 12.7062),
            (2.0, 4.3027),
            (4.0, 2.7764),
            (10.0, 2.2281),
            (30.0, 2.0423),
        ] {
            let q = student_t_quantile(0.975, df);
            assert!((q - t).abs() < 1e-4, "df {df}: {q} vs {t}");
        }
        assert!((normal_quantile(0.975) - 1.959964).abs() < 1e-6);
        assert!((student_t_quantile(0.975, 1e7) - 1.959964).abs() < 1e-5);
        assert!(
            student_t_quantile(0.5, 3.0).abs() < 1e-9,
            "{}",
            student_t_quantile(0.5, 3.0)
        );
    }

    #[test]
    fn newcombes_worked_example() {
        // Newcombe (1998), Table II, example (a): 56/70 vs 48/80, method 10: 0.0524 to 0.3339.
        let d = proportion_difference(56, 70, 48, 80).expect("counts");
        assert!((d.estimate - 0.2).abs() < 1e-12);
        assert!((d.low - 0.0524).abs() < 1e-4, "{}", d.low);
        assert!((d.high - 0.3339).abs() < 1e-4, "{}", d.high);
        assert_eq!(proportion_difference(3, 2, 1, 4), None);
    }

    /// Synthetic evaluations with a known difference: per condition a base success
    /// probability shared by both policies (uniform, `spread` wide, centred on 0.45), per training seed a random shift, each rollout a
    /// Bernoulli draw. The true difference of the expected success is `delta`.
    fn draw(
        rng: &mut crate::rng::StreamRng,
        delta: f64,
        seeds: usize,
        n: usize,
        tau: f64,
        spread: f64,
    ) -> [Vec<Vec<f64>>; 2] {
        let base: Vec<f64> = (0..n)
            .map(|_| 0.45 - 0.5 * spread + spread * uniform01(rng))
            .collect();
        let mut policy = |shift: f64| -> Vec<Vec<f64>> {
            (0..seeds)
                .map(|_| {
                    let a = shift + tau * normal(rng);
                    base.iter()
                        .map(|p| f64::from(u8::from(uniform01(rng) < p + a)))
                        .collect()
                })
                .collect()
        };
        [policy(delta), policy(0.0)]
    }

    #[test]
    fn the_paired_interval_covers_a_known_difference_about_95_percent_of_the_time() {
        let mut rng = stream(7, "stats", "coverage", 0);
        let (reps, delta) = (1000, 0.05);
        // Condition noise dominant, then training seeds dominant (3 seeds: few degrees of
        // freedom, where a normal quantile would undercover).
        for tau in [0.02, 0.06] {
            let mut covered = 0;
            for _ in 0..reps {
                let [a, b] = draw(&mut rng, delta, 3, 300, tau, 0.5);
                let d = paired_difference(&a, &b).expect("paired");
                covered += usize::from(d.low <= delta && delta <= d.high);
            }
            let rate = covered as f64 / reps as f64;
            // 1000 draws at 95 %: a binomial sd of 0.7 points.
            assert!((0.925..=0.975).contains(&rate), "τ {tau}: coverage {rate}");
        }
    }

    /// Percentile intervals of the mean paired difference over `reps` synthetic draws of
    /// `n` conditions whose true difference is `delta` (skewed per-condition noise); returns
    /// how often the interval covered `delta` and how often it excluded 0.
    fn bootstrap_rates(seed: u64, delta: f64, reps: usize) -> (f64, f64) {
        let (n, resamples) = (150, 400);
        let mut rng = stream(seed, "stats", "bootstrap", 0);
        let (mut covered, mut decided) = (0, 0);
        for _ in 0..reps {
            let diffs: Vec<f64> = (0..n)
                .map(|_| {
                    let base = -libm::log(1.0 - uniform01(&mut rng));
                    let noise = 0.5 * normal(&mut rng);
                    delta + (base - 1.0) + noise
                })
                .collect();
            let estimate = mean(&diffs);
            let replicates: Vec<f64> = (0..resamples)
                .map(|_| {
                    (0..n)
                        .map(|_| diffs[crate::rng::below(&mut rng, n as u64) as usize])
                        .sum::<f64>()
                        / n as f64
                })
                .collect();
            let d = bootstrap_difference(estimate, &replicates, n).expect("replicates");
            assert_eq!(d.method, Method::Bootstrap);
            assert!(d.low <= d.high);
            covered += usize::from(d.low <= delta && delta <= d.high);
            decided += usize::from(d.decide(delta >= 0.0) != Decision::Unresolved);
        }
        (covered as f64 / reps as f64, decided as f64 / reps as f64)
    }

    #[test]
    fn the_bootstrap_interval_covers_a_known_difference_and_rarely_decides_a_null() {
        // 500 draws at 95 %: a binomial sd of 1 point; the percentile interval of a mean
        // undercovers slightly at n = 150.
        let (coverage, _) = bootstrap_rates(11, 0.3, 500);
        assert!((0.92..=0.975).contains(&coverage), "coverage {coverage}");
        let (_, decided) = bootstrap_rates(12, 0.0, 500);
        assert!(decided <= 0.09, "a null decided in {decided}");
        let (_, decided) = bootstrap_rates(13, 0.5, 100);
        assert!(decided >= 0.99, "a large difference decided in {decided}");
        assert_eq!(bootstrap_difference(0.0, &[1.0], 3), None);
        assert_eq!(bootstrap_difference(0.0, &[1.0, f64::NAN], 3), None);
    }

    #[test]
    fn a_null_difference_is_rarely_decided_and_a_large_one_is() {
        let mut rng = stream(8, "stats", "null", 0);
        let reps = 1000;
        let mut decided = 0;
        for _ in 0..reps {
            let [a, b] = draw(&mut rng, 0.0, 3, 300, 0.02, 0.5);
            let d = paired_difference(&a, &b).expect("paired");
            decided += usize::from(d.decide(true) != Decision::Unresolved);
        }
        let rate = decided as f64 / reps as f64;
        assert!((0.025..=0.075).contains(&rate), "false decisions {rate}");
        let [a, b] = draw(&mut rng, 0.15, 3, 600, 0.01, 0.5);
        let d = paired_difference(&a, &b).expect("paired");
        assert_eq!(d.decide(true), Decision::Holds, "{d:?}");
        assert_eq!(d.decide(false), Decision::Contradicted, "{d:?}");
        let d = paired_difference(&b, &a).expect("paired");
        assert!(d.estimate < 0.0 && d.high < 0.0, "{d:?}");
    }

    #[test]
    fn the_seed_spread_widens_the_interval_and_pairing_narrows_it() {
        let mut rng = stream(9, "stats", "parts", 0);
        let [a, b] = draw(&mut rng, 0.0, 3, 600, 0.0, 0.8);
        let calm = paired_difference(&a, &b).expect("paired");
        let [a2, b2] = draw(&mut rng, 0.0, 3, 600, 0.08, 0.8);
        let spread = paired_difference(&a2, &b2).expect("paired");
        assert!(
            spread.resolvable > 1.5 * calm.resolvable,
            "{calm:?} {spread:?}"
        );
        // The same values with the conditions' order broken are no longer paired: the shared
        // condition difficulty then shows as variance.
        let mut shuffled = b.clone();
        for s in &mut shuffled {
            s.rotate_left(1);
        }
        let unpaired = paired_difference(&a, &shuffled).expect("paired");
        assert!(
            unpaired.resolvable > 1.25 * calm.resolvable,
            "{calm:?} {unpaired:?}"
        );
        // Projected to the measured counts, the interval is the measured one; more seeds and
        // conditions narrow it.
        let parts = spread.parts.expect("paired");
        assert!((parts.resolvable_with([3, 3], 600) - spread.resolvable).abs() < 1e-12);
        assert!(parts.resolvable_with([10, 10], 3000) < 0.5 * spread.resolvable);
        let s = parts.seeds_to_resolve(0.05, 600, 50).expect("reachable");
        assert!(parts.resolvable_with([s, s], 600) <= 0.05);
        assert!(s > 3 && parts.resolvable_with([s - 1, s - 1], 600) > 0.05);
        assert_eq!(parts.seeds_to_resolve(1e-6, 600, 50), None);
        // One seed: no seed part, and the degrees of freedom are the conditions'.
        let one = paired_difference(&a[..1], &b).expect("paired");
        assert_eq!(one.seeds, [1, 3]);
        assert_eq!(paired_difference(&a, &[vec![1.0; 5]]), None);
    }

    /// Eq. of `paired_difference`'s doc on a 2 × 3 and a 1 × 3 matrix, by hand: a's row means
    /// 1 and 1/3 (grand 2/3), MS_seed = 3 · 2/9 = 2/3, residual SS = 1/3 over 2 df, so
    /// τ² = (2/3 − 1/6) / 3 = 1/6 and the seed part τ² / 2 = 1/12 on 1 df; b has one seed (no
    /// seed part). The per-condition differences 1/2, 1/2, 0 have variance 1/12, so the
    /// condition part is 1/36 on 2 df: variance 1/9, Welch–Satterthwaite df
    /// (1/9)² / ((1/12)² + (1/36)² / 2) = 32/19, estimate 2/3 − 1/3.
    #[test]
    fn a_hand_computed_paired_decomposition() {
        let a = [vec![1.0, 1.0, 1.0], vec![0.0, 0.0, 1.0]];
        let b = [vec![0.0, 0.0, 1.0]];
        let d = paired_difference(&a, &b).expect("paired");
        let close = |x: f64, y: f64| (x - y).abs() < 1e-12;
        assert!(close(d.estimate, 1.0 / 3.0), "{d:?}");
        let parts = d.parts.expect("parts");
        assert!(
            close(parts.tau2[0].expect("two seeds"), 1.0 / 6.0),
            "{parts:?}"
        );
        assert_eq!(parts.tau2[1], None);
        assert!(close(parts.condition, 1.0 / 12.0), "{parts:?}");
        let df = d.df.expect("t");
        assert!(close(df, 32.0 / 19.0), "{df}");
        let half = student_t_quantile(LEVEL, 32.0 / 19.0) * (1.0f64 / 9.0).sqrt();
        assert!(
            close(d.resolvable, half) && close(d.low, 1.0 / 3.0 - half),
            "{d:?}"
        );
    }

    /// An interval that touches 0 decides nothing; one just off it decides, in either
    /// direction of the claim.
    #[test]
    fn decide_at_its_boundaries() {
        let interval = |low: f64, high: f64| Difference {
            estimate: 0.5 * (low + high),
            low,
            high,
            resolvable: 0.5 * (high - low),
            df: None,
            seeds: [1, 1],
            n: [10, 10],
            method: Method::Proportions,
            parts: None,
        };
        let tiny = f64::MIN_POSITIVE;
        for (low, high, higher, lower) in [
            (0.0, 1.0, Decision::Unresolved, Decision::Unresolved),
            (-1.0, 0.0, Decision::Unresolved, Decision::Unresolved),
            (tiny, 1.0, Decision::Holds, Decision::Contradicted),
            (-1.0, -tiny, Decision::Contradicted, Decision::Holds),
            (0.0, 0.0, Decision::Unresolved, Decision::Unresolved),
        ] {
            let d = interval(low, high);
            assert_eq!(d.decide(true), higher, "[{low}, {high}], a higher");
            assert_eq!(d.decide(false), lower, "[{low}, {high}], a lower");
        }
    }

    #[test]
    fn the_unpaired_interval_covers_a_known_difference_at_least_95_percent_of_the_time_and_is_not_vacuous()
     {
        let mut rng = stream(10, "stats", "force", 0);
        let (reps, delta) = (600, 3.0);
        let mut covered = 0;
        let mut half_sum = 0.0;
        for _ in 0..reps {
            let mut policy = |mu: f64| -> Vec<Vec<f64>> {
                (0..3)
                    .map(|_| {
                        let a = mu + 1.5 * normal(&mut rng);
                        (0..250).map(|_| a + 12.0 * normal(&mut rng)).collect()
                    })
                    .collect()
            };
            let (x, y) = (policy(40.0 + delta), policy(40.0));
            let d = unpaired_difference(&x, &y).expect("values");
            covered += usize::from(d.low <= delta && delta <= d.high);
            half_sum += d.resolvable;
        }
        let rate = covered as f64 / reps as f64;
        assert!(rate >= 0.93, "coverage {rate}");
        // Conservative by design (the rollouts' noise counts twice), but not vacuous: it
        // misses sometimes, and it is at most 1.6 times as wide as the normal interval with
        // the estimate's true standard deviation, √(2 (1.5² + 12² / 250) / 3).
        assert!(rate <= 0.995, "coverage {rate}: the interval never misses");
        let exact = 1.96 * (2.0 * (1.5f64.powi(2) + 12.0f64.powi(2) / 250.0) / 3.0).sqrt();
        let half = half_sum / reps as f64;
        assert!(
            half <= 1.6 * exact,
            "mean half-width {half} against {exact}"
        );
        assert_eq!(unpaired_difference(&[vec![]], &[vec![1.0, 2.0]]), None);
    }
}
