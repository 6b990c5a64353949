//! Test-only stage kinds.

use std::time::Duration;

use mujoco_rs::prelude::MjModel;
use osms_core::rng::{self, StreamRng};
use osms_core::{Artifact, NoParams};
use osms_make::{
    Ctx, ItemStage, Numerics, Registry, Scale, Sharded, Slot, Stage, StageError, Summarize,
};
use serde::{Deserialize, Serialize};

/// All test kinds.
pub fn registry() -> Registry {
    let mut r = Registry::new();
    r.register_itemised(NumbersKind)
        .register_itemised(DropKind)
        .register(SignsKind)
        .register(ShiftKind)
        .register(OffsetKind)
        .register(SumKind)
        .register(CombineKind)
        .register_itemised(PanicKind)
        .register(FoldRowsKind)
        .register(GatherKind)
        .register(SumOfAKind);
    r
}

/// Rows of numbers.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Numbers {
    pub rows: Vec<Vec<f64>>,
}
impl Artifact for Numbers {
    const TYPE_TAG: &'static str = "test.numbers";
    /// 2: itemised kinds store it as a manifest of their shards.
    const SCHEMA_VERSION: u16 = 2;
}
impl Sharded for Numbers {
    type Item = Vec<f64>;
    fn take_items(&mut self) -> Vec<Vec<f64>> {
        std::mem::take(&mut self.rows)
    }
    fn set_items(&mut self, items: Vec<Vec<f64>>) {
        self.rows = items;
    }
}
impl Summarize for Numbers {
    fn summary(&self) -> serde_json::Value {
        let n: usize = self.rows.iter().map(Vec::len).sum();
        let sum: f64 = self.rows.iter().flatten().sum();
        serde_json::json!({ "rows": self.rows.len(), "values": n, "mean": if n > 0 { sum / n as f64 } else { 0.0 } })
    }
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NumbersParams {
    /// Number of rows (items).
    pub n: u32,
    /// Values per row.
    #[serde(default = "default_len")]
    pub len: u32,
    #[serde(default = "default_scale")]
    pub scale: f64,
    /// Sleep per item, so kill tests can interrupt a make mid-stage.
    #[serde(default)]
    pub sleep_ms: u64,
    /// Item index at which to fail (tests failure handling).
    #[serde(default)]
    pub fail_at: Option<u32>,
    /// A role for the typed-slot tests.
    #[serde(default)]
    pub role: Option<TestRole>,
}

/// Roles test numbers can play.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TestRole {
    A,
    B,
}
fn default_len() -> u32 {
    4
}
fn default_scale() -> f64 {
    1.0
}

/// Normal random rows, one item per row.
pub struct NumbersKind;
impl ItemStage for NumbersKind {
    const KIND: &'static str = "numbers";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = &[];
    const DOC: &'static str = "rows of scaled standard-normal numbers (test kind)";
    type Params = NumbersParams;
    type Prepared = ();
    type Item = Vec<f64>;
    type Output = Numbers;

    fn scale(params: &NumbersParams, _: &[(&str, f64)]) -> Scale {
        Scale::items(f64::from(params.n))
    }

    fn output_role(params: &NumbersParams) -> Option<&'static str> {
        params.role.map(|r| match r {
            TestRole::A => "a",
            TestRole::B => "b",
        })
    }
    fn prepare(&self, _: &Ctx<'_, NumbersParams>) -> Result<(), StageError> {
        Ok(())
    }
    fn n_items(&self, ctx: &Ctx<'_, NumbersParams>, _: &()) -> usize {
        ctx.params.n as usize
    }
    fn run_item(
        &self,
        ctx: &Ctx<'_, NumbersParams>,
        _: &(),
        index: usize,
        rng: &mut StreamRng,
    ) -> Result<Vec<f64>, StageError> {
        let p = ctx.params;
        if p.fail_at == Some(index as u32) {
            return Err(format!("item {index} failed on purpose (fail_at)").into());
        }
        if p.sleep_ms > 0 {
            std::thread::sleep(Duration::from_millis(p.sleep_ms));
        }
        Ok((0..p.len).map(|_| p.scale * rng::normal(rng)).collect())
    }
    fn merge(
        &self,
        _: &Ctx<'_, NumbersParams>,
        _: (),
        items: Vec<Vec<f64>>,
    ) -> Result<Numbers, StageError> {
        Ok(Numbers { rows: items })
    }
}

/// Signs of the values: many inputs map to one output, which makes early cutoff observable.
pub struct SignsKind;
impl Stage for SignsKind {
    const KIND: &'static str = "signs";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[Slot::one::<Numbers>("values")];
    const DOC: &'static str = "the sign of every value (test kind)";
    type Params = NoParams;
    type Output = Numbers;
    fn run(&self, ctx: &Ctx<'_, NoParams>) -> Result<Numbers, StageError> {
        let v: Numbers = ctx.sharded("values")?;
        Ok(Numbers {
            rows: v
                .rows
                .iter()
                .map(|r| r.iter().map(|x| x.signum()).collect())
                .collect(),
        })
    }
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShiftParams {
    pub by: f64,
}

/// Adds a constant.
pub struct ShiftKind;
impl Stage for ShiftKind {
    const KIND: &'static str = "shift";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[Slot::one::<Numbers>("values")];
    const DOC: &'static str = "every value plus a constant (test kind)";
    type Params = ShiftParams;
    type Output = Numbers;
    fn run(&self, ctx: &Ctx<'_, ShiftParams>) -> Result<Numbers, StageError> {
        let v: Numbers = ctx.sharded("values")?;
        Ok(Numbers {
            rows: v
                .rows
                .iter()
                .map(|r| r.iter().map(|x| x + ctx.params.by).collect())
                .collect(),
        })
    }
}

/// Adds the sum of the optional `offset` input, if wired (an optional slot).
pub struct OffsetKind;
impl Stage for OffsetKind {
    const KIND: &'static str = "offset";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<Numbers>("values"),
        Slot::one::<Total>("offset").optional(),
    ];
    const DOC: &'static str = "every value plus an optional total's sum (test kind)";
    type Params = NoParams;
    type Output = Numbers;
    fn run(&self, ctx: &Ctx<'_, NoParams>) -> Result<Numbers, StageError> {
        let v: Numbers = ctx.sharded("values")?;
        let by = if ctx.has_input("offset") {
            ctx.input::<Total>("offset")?.sum
        } else {
            0.0
        };
        Ok(Numbers {
            rows: v
                .rows
                .iter()
                .map(|r| r.iter().map(|x| x + by).collect())
                .collect(),
        })
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Total {
    pub count: u64,
    pub sum: f64,
}
impl Artifact for Total {
    const TYPE_TAG: &'static str = "test.total";
    const SCHEMA_VERSION: u16 = 1;
}
impl Summarize for Total {
    fn summary(&self) -> serde_json::Value {
        serde_json::json!({ "count": self.count, "sum": self.sum })
    }
}

/// Sums the values in index order.
pub struct SumKind;
impl Stage for SumKind {
    const KIND: &'static str = "sum";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[Slot::one::<Numbers>("values")];
    const DOC: &'static str = "count and sum of the values (test kind)";
    type Params = NoParams;
    type Output = Total;
    /// Streams the rows (shard by shard when the input is sharded).
    fn run(&self, ctx: &Ctx<'_, NoParams>) -> Result<Total, StageError> {
        let mut values = Vec::new();
        for row in ctx.items::<Numbers>("values")? {
            values.extend(row?);
        }
        Ok(Total {
            count: values.len() as u64,
            sum: values.iter().sum(),
        })
    }
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DropParams {
    /// Number of drops (items).
    pub n: u32,
    /// Physics steps of 2 ms per drop.
    #[serde(default = "default_steps")]
    pub steps: u32,
}
fn default_steps() -> u32 {
    400
}

/// Final states of boxes thrown onto a plane in MuJoCo.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Drops {
    /// Per drop: final qpos (7) of the free joint.
    pub finals: Vec<Vec<f64>>,
}
impl Artifact for Drops {
    const TYPE_TAG: &'static str = "test.drops";
    /// 2: itemised kinds store it as a manifest of their shards.
    const SCHEMA_VERSION: u16 = 2;
}
impl Sharded for Drops {
    type Item = Vec<f64>;
    fn take_items(&mut self) -> Vec<Vec<f64>> {
        std::mem::take(&mut self.finals)
    }
    fn set_items(&mut self, items: Vec<Vec<f64>>) {
        self.finals = items;
    }
}
impl Summarize for Drops {
    fn summary(&self) -> serde_json::Value {
        let n = self.finals.len().max(1) as f64;
        let mean_z: f64 = self.finals.iter().map(|q| q[2]).sum::<f64>() / n;
        serde_json::json!({ "drops": self.finals.len(), "mean_final_z_m": mean_z })
    }
}

const DROP_XML: &str = r#"<mujoco>
  <option timestep="0.002" integrator="implicitfast" cone="elliptic"/>
  <worldbody>
    <geom type="plane" size="2 2 0.1" friction="0.8 0.02 0.001"/>
    <body pos="0 0 0.5">
      <freejoint/>
      <geom type="box" size="0.03 0.02 0.015" mass="0.05"/>
    </body>
  </worldbody>
</mujoco>"#;

/// Throws a small box onto a plane with a random velocity and records where it comes to rest:
/// contacts, friction and the elliptic cone make this sensitive to every bit of the simulation.
pub struct DropKind;
impl ItemStage for DropKind {
    const KIND: &'static str = "drop";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = true;
    const INPUTS: &'static [Slot] = &[];
    const DOC: &'static str = "MuJoCo box throws onto a plane (test kind)";
    type Params = DropParams;
    type Prepared = MjModel;
    type Item = Vec<f64>;
    type Output = Drops;

    fn scale(params: &DropParams, _: &[(&str, f64)]) -> Scale {
        Scale::items(f64::from(params.n))
    }

    fn numerics() -> Vec<Numerics> {
        vec![Numerics {
            name: "mujoco",
            version: osms_sim::mujoco_version(),
        }]
    }

    fn prepare(&self, _: &Ctx<'_, DropParams>) -> Result<MjModel, StageError> {
        Ok(MjModel::from_xml_string(DROP_XML)?)
    }
    fn n_items(&self, ctx: &Ctx<'_, DropParams>, _: &MjModel) -> usize {
        ctx.params.n as usize
    }
    fn run_item(
        &self,
        ctx: &Ctx<'_, DropParams>,
        model: &MjModel,
        _: usize,
        rng: &mut StreamRng,
    ) -> Result<Vec<f64>, StageError> {
        let mut data = model.make_data();
        let v: Vec<f64> = (0..6).map(|_| rng::uniform(rng, -2.0, 2.0)).collect();
        data.qvel_mut().copy_from_slice(&v);
        for _ in 0..ctx.params.steps {
            data.step();
        }
        Ok(data.qpos().to_vec())
    }
    fn merge(
        &self,
        _: &Ctx<'_, DropParams>,
        _: MjModel,
        items: Vec<Vec<f64>>,
    ) -> Result<Drops, StageError> {
        Ok(Drops { finals: items })
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Combined {
    pub total: f64,
    pub drops: u64,
    pub reference_rows: u64,
}
impl Artifact for Combined {
    const TYPE_TAG: &'static str = "test.combined";
    const SCHEMA_VERSION: u16 = 1;
}
impl Summarize for Combined {
    fn summary(&self) -> serde_json::Value {
        serde_json::to_value(self).unwrap_or_default()
    }
}

/// Reads three inputs of three types.
pub struct CombineKind;
impl Stage for CombineKind {
    const KIND: &'static str = "combine";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[
        Slot::one::<Total>("total"),
        Slot::one::<Drops>("drops"),
        Slot::one::<Numbers>("reference"),
    ];
    const DOC: &'static str = "a small report over three inputs (test kind)";
    type Params = NoParams;
    type Output = Combined;
    fn run(&self, ctx: &Ctx<'_, NoParams>) -> Result<Combined, StageError> {
        let total: Total = ctx.input("total")?;
        let drops: Drops = ctx.sharded("drops")?;
        let reference: Numbers = ctx.sharded("reference")?;
        Ok(Combined {
            total: total.sum,
            drops: drops.finals.len() as u64,
            reference_rows: reference.rows.len() as u64,
        })
    }
}

#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PanicParams {
    /// Number of rows (items).
    pub n: u32,
    /// Item index whose `run_item` panics.
    #[serde(default)]
    pub panic_at_item: Option<u32>,
    #[serde(default)]
    pub panic_in_prepare: bool,
    #[serde(default)]
    pub panic_in_merge: bool,
}

/// Rows `[i]` for every item `i`, or a panic where asked: tests that a panicking kind fails its
/// own stage only. A kind of its own, so the keys of the other kinds' golden outputs stay put.
pub struct PanicKind;
impl ItemStage for PanicKind {
    const KIND: &'static str = "panicky";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[];
    const DOC: &'static str = "one row per item, or a panic on demand (test kind)";
    type Params = PanicParams;
    type Prepared = ();
    type Item = Vec<f64>;
    type Output = Numbers;

    fn prepare(&self, ctx: &Ctx<'_, PanicParams>) -> Result<(), StageError> {
        if ctx.params.panic_in_prepare {
            panic!("prepare panicked on purpose (panic_in_prepare)");
        }
        Ok(())
    }
    fn n_items(&self, ctx: &Ctx<'_, PanicParams>, _: &()) -> usize {
        ctx.params.n as usize
    }
    fn run_item(
        &self,
        ctx: &Ctx<'_, PanicParams>,
        _: &(),
        index: usize,
        _: &mut StreamRng,
    ) -> Result<Vec<f64>, StageError> {
        if ctx.params.panic_at_item == Some(index as u32) {
            panic!("item {index} panicked on purpose (panic_at_item)");
        }
        Ok(vec![index as f64])
    }
    fn merge(
        &self,
        ctx: &Ctx<'_, PanicParams>,
        _: (),
        items: Vec<Vec<f64>>,
    ) -> Result<Numbers, StageError> {
        if ctx.params.panic_in_merge {
            panic!("merge panicked on purpose (panic_in_merge)");
        }
        Ok(Numbers { rows: items })
    }
}

/// The rows of fold k of `count` (row i belongs to fold i mod count), or every row when the
/// stage has no folds: a cross-fitting split in miniature.
pub struct FoldRowsKind;
impl Stage for FoldRowsKind {
    const KIND: &'static str = "fold_rows";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[Slot::one::<Numbers>("values")];
    const DOC: &'static str = "the rows of this instance's fold (test kind)";
    type Params = NoParams;
    type Output = Numbers;
    fn run(&self, ctx: &Ctx<'_, NoParams>) -> Result<Numbers, StageError> {
        let v: Numbers = ctx.sharded("values")?;
        let keep = |i: usize| {
            ctx.fold()
                .is_none_or(|f| i % f.count as usize == f.index as usize)
        };
        Ok(Numbers {
            rows: v
                .rows
                .into_iter()
                .enumerate()
                .filter(|(i, _)| keep(*i))
                .map(|(_, r)| r)
                .collect(),
        })
    }
}

/// Every gathered total, with the instance it came from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Gathered {
    /// (`#fold@seed` of the member, its sum), in the order the slot received them.
    pub members: Vec<(String, f64)>,
}
impl Artifact for Gathered {
    const TYPE_TAG: &'static str = "test.gathered";
    const SCHEMA_VERSION: u16 = 1;
}
impl Summarize for Gathered {
    fn summary(&self) -> serde_json::Value {
        serde_json::to_value(self).unwrap_or_default()
    }
}

/// Lists the totals of a gather slot (test kind for `stage@*` and `stage#*`).
pub struct GatherKind;
impl Stage for GatherKind {
    const KIND: &'static str = "gather_totals";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[Slot::gather::<Total>("totals")];
    const DOC: &'static str = "every total of a gather slot, in order (test kind)";
    type Params = NoParams;
    type Output = Gathered;
    fn run(&self, ctx: &Ctx<'_, NoParams>) -> Result<Gathered, StageError> {
        Ok(Gathered {
            members: ctx
                .gathered::<Total>("totals")?
                .into_iter()
                .map(|(m, t)| (m.suffix(), t.sum))
                .collect(),
        })
    }
}

/// The sum of numbers of role `a` only (test kind for typed slots with roles).
pub struct SumOfAKind;
impl Stage for SumOfAKind {
    const KIND: &'static str = "sum_of_a";
    const CODE_VERSION: u32 = 1;
    const USES_RNG: bool = false;
    const INPUTS: &'static [Slot] = &[Slot::one::<Numbers>("values").roles(&["a"])];
    const DOC: &'static str = "count and sum of numbers of role a (test kind)";
    type Params = NoParams;
    type Output = Total;
    fn run(&self, ctx: &Ctx<'_, NoParams>) -> Result<Total, StageError> {
        SumKind.run(ctx)
    }
}
