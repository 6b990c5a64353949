//! Plan-time checks of params: a value that makes no sense (a zero learning rate, a negative
//! count, a probability of 2, an empty layer list, a size no machine builds) is refused with the
//! field's path and the valid range before anything runs.
//!
//! Each kind's params type lists its fields' ranges with these helpers; the engine prefixes the
//! stage and maps the path to the `--set` or the pipeline.toml line that set it. Upper bounds
//! are sanity caps (orders of magnitude above every profile's value), there so that a typo of
//! a few digits is an error and not a build that runs for a week.

use std::fmt::Display;

/// A param outside its valid range: its path inside the params and what would be valid.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Invalid {
    pub path: Vec<String>,
    pub message: String,
}

pub type Checked = Result<(), Invalid>;

/// Params whose fields have valid ranges.
pub trait Check {
    fn check(&self) -> Checked;
}

impl Invalid {
    pub fn new(field: &str, message: impl Into<String>) -> Self {
        Invalid {
            path: field.split('.').map(str::to_string).collect(),
            message: message.into(),
        }
    }

    /// The same error one level down, inside `field`.
    pub fn within(mut self, field: &str) -> Self {
        self.path.insert(0, field.to_string());
        self
    }
}

/// Checks the nested params `value` and prefixes its errors with `field`.
pub fn nested(field: &str, value: &impl Check) -> Checked {
    value.check().map_err(|e| e.within(field))
}

/// A number as param errors show it (`nan`, `inf`, `-inf` as TOML spells them).
pub fn shown(v: f64) -> String {
    if v.is_nan() {
        "nan".into()
    } else {
        format!("{v}")
    }
}

/// A finite number in `[lo, hi]` (`lo_open`: `(lo, hi]`).
fn real(field: &str, v: f64, lo: f64, lo_open: bool, hi: f64) -> Checked {
    let ok = v.is_finite() && (if lo_open { v > lo } else { v >= lo }) && v <= hi;
    if ok {
        return Ok(());
    }
    let range = if lo_open {
        format!("({lo}, {hi}]")
    } else {
        format!("[{lo}, {hi}]")
    };
    Err(Invalid::new(
        field,
        format!(
            "{} is not valid here: expected a finite number in {range}",
            shown(v)
        ),
    ))
}

/// A finite number in `(0, max]`: rates, scales, lengths, times.
pub fn positive(field: &str, v: impl Into<f64>, max: f64) -> Checked {
    real(field, v.into(), 0.0, true, max)
}

/// A finite number in `[min, max]`.
pub fn within(field: &str, v: impl Into<f64>, min: f64, max: f64) -> Checked {
    real(field, v.into(), min, false, max)
}

/// A probability or a fraction: `[0, 1]`.
pub fn unit(field: &str, v: impl Into<f64>) -> Checked {
    real(field, v.into(), 0.0, false, 1.0)
}

/// An integer in `[min, max]`: counts, steps, sizes.
pub fn count<T: TryInto<u64> + Display + Copy>(field: &str, v: T, min: u64, max: u64) -> Checked {
    match v.try_into() {
        Ok(x) if (min..=max).contains(&x) => Ok(()),
        _ => Err(Invalid::new(
            field,
            format!("{v} is not valid here: expected a whole number in [{min}, {max}]"),
        )),
    }
}

/// An integer in `[min, max]` that may be negative (offsets).
pub fn signed(field: &str, v: i64, min: i64, max: i64) -> Checked {
    if (min..=max).contains(&v) {
        Ok(())
    } else {
        Err(Invalid::new(
            field,
            format!("{v} is not valid here: expected a whole number in [{min}, {max}]"),
        ))
    }
}

/// A non-empty list of layer widths, each in `[1, max]`.
pub fn widths(field: &str, v: &[usize], max: u64) -> Checked {
    if v.is_empty() {
        return Err(Invalid::new(
            field,
            format!("[] is not valid here: expected at least one layer width in [1, {max}]"),
        ));
    }
    for (i, &w) in v.iter().enumerate() {
        count(&format!("{field}.{i}"), w, 1, max)?;
    }
    Ok(())
}

/// A range `[a, b]` with `min ≤ a ≤ b ≤ max`.
pub fn interval(field: &str, v: [f64; 2], min: f64, max: f64) -> Checked {
    within(&format!("{field}.0"), v[0], min, max)?;
    within(&format!("{field}.1"), v[1], min, max)?;
    if v[0] > v[1] {
        return Err(Invalid::new(
            field,
            format!(
                "[{}, {}] is not valid here: expected a range [low, high] with low ≤ high",
                v[0], v[1]
            ),
        ));
    }
    Ok(())
}

/// Every element finite and in `[min, max]`.
pub fn each(field: &str, v: &[f64], min: f64, max: f64) -> Checked {
    for (i, &x) in v.iter().enumerate() {
        within(&format!("{field}.{i}"), x, min, max)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_refuse_what_they_say_and_name_the_field() {
        assert!(positive("lr", 1e-3, 1.0).is_ok());
        for bad in [0.0, -1.0, f64::NAN, f64::INFINITY, 2.0] {
            let e = positive("lr", bad, 1.0).expect_err("refused");
            assert_eq!(e.path, ["lr"]);
            assert!(e.message.contains("(0, 1]"), "{}", e.message);
        }
        assert!(unit("p", 0.0).is_ok() && unit("p", 1.0).is_ok());
        assert!(unit("p", 1.0 + 1e-12).is_err() && unit("p", -0.0 - 1e-12).is_err());
        assert!(count("n", 0u32, 1, 10).is_err() && count("n", 10u32, 1, 10).is_ok());
        assert!(count("n", 11usize, 1, 10).is_err());
        let e = widths("hidden", &[64, 0], 4096).expect_err("a zero width");
        assert_eq!(e.path, ["hidden", "1"]);
        assert!(widths("hidden", &[], 4096).is_err());
        let e = interval("speed", [3.0, 2.0], 0.0, 10.0).expect_err("reversed");
        assert_eq!(e.path, ["speed"]);
        let e = interval("speed", [1.0, f64::NAN], 0.0, 10.0).expect_err("nan");
        assert_eq!(e.path, ["speed", "1"]);
        assert!(e.message.starts_with("nan "), "{}", e.message);
        assert!(signed("offset", -3, -10, 10).is_ok() && signed("offset", 11, -10, 10).is_err());
    }

    #[test]
    fn nested_errors_carry_the_outer_field() {
        struct Inner(f64);
        impl Check for Inner {
            fn check(&self) -> Checked {
                unit("p", self.0)
            }
        }
        let e = nested("dr", &Inner(2.0)).expect_err("refused");
        assert_eq!(e.path, ["dr", "p"]);
        assert!(nested("dr", &Inner(0.5)).is_ok());
    }
}
