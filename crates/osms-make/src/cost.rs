//! What a make's builds cost: wall and CPU time, the machine's share, and the same by stage
//! kind (`osms make --json`'s `cost`, and the report's "Cost by stage kind").

use std::collections::BTreeMap;

use serde::Serialize;

use crate::exec::{MakeReport, Outcome};
use crate::plan::Plan;

/// What a make's builds cost (`make --json`'s `cost`): the make's wall time, the CPU time its
/// builds used, the cores it had, and the same by stage kind.
#[derive(Debug, Serialize)]
pub struct Cost {
    pub wall_secs: f64,
    pub cpu_secs: f64,
    pub cores: usize,
    /// CPU seconds over wall seconds times cores: 1 when every core was busy throughout.
    pub machine_share: f64,
    pub by_kind: Vec<KindCost>,
}

/// The builds of one stage kind (in a make, or behind a report).
#[derive(Debug, Serialize)]
pub struct KindCost {
    pub kind: String,
    pub builds: usize,
    /// The sum of the builds' wall times (builds side by side each count in full).
    pub wall_secs: f64,
    pub cpu_secs: f64,
    /// CPU seconds over the wall seconds of the builds whose CPU time was measured: how many
    /// cores a build of this kind kept busy (none when no build of it was measured).
    pub cores_busy: Option<f64>,
}

impl KindCost {
    /// Builds (kind, wall seconds, CPU seconds if measured) summed by kind, the most CPU first
    /// (then the most wall time).
    pub fn tally(builds: impl IntoIterator<Item = (String, f64, Option<f64>)>) -> Vec<Self> {
        let mut kinds: BTreeMap<String, (usize, f64, f64, f64)> = BTreeMap::new();
        for (kind, wall, cpu) in builds {
            let k = kinds.entry(kind).or_default();
            k.0 += 1;
            k.1 += wall;
            if let Some(cpu) = cpu {
                k.2 += cpu;
                k.3 += wall;
            }
        }
        let mut out: Vec<KindCost> = kinds
            .into_iter()
            .map(|(kind, (builds, wall, cpu, metered))| KindCost {
                kind,
                builds,
                wall_secs: wall,
                cpu_secs: cpu,
                cores_busy: (metered > 0.0).then(|| cpu / metered),
            })
            .collect();
        out.sort_by(|a, b| {
            b.cpu_secs
                .total_cmp(&a.cpu_secs)
                .then(b.wall_secs.total_cmp(&a.wall_secs))
        });
        out
    }
}

impl Cost {
    /// The cost of `report`'s builds (built or failed; cached ones cost nothing), by the kind of
    /// each instance in `plan`, over a make of `wall_secs` on this machine's cores.
    pub fn of(plan: &Plan, seeds: &[u64], report: &MakeReport, wall_secs: f64) -> Cost {
        let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
        let by_kind = KindCost::tally(
            report
                .instances
                .iter()
                .filter(|r| matches!(r.outcome, Outcome::Built { .. } | Outcome::Failed { .. }))
                .map(|r| {
                    let kind = plan.instance_named(&r.instance, seeds).map_or_else(
                        || r.instance.clone(),
                        |id| plan.stages[id.stage].info.name.to_string(),
                    );
                    (kind, r.wall_time_secs, Some(r.cpu_secs))
                }),
        );
        // A fold from +0: `sum` of nothing is −0.0, which a fully cached make's JSON printed.
        let cpu_secs = by_kind.iter().fold(0.0, |total, k| total + k.cpu_secs);
        let machine = wall_secs * cores as f64;
        Cost {
            wall_secs,
            cpu_secs,
            cores,
            machine_share: if machine > 0.0 {
                cpu_secs / machine
            } else {
                0.0
            },
            by_kind,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn builds_sum_by_kind_most_cpu_first_and_unmeasured_builds_count_only_in_wall() {
        let kinds = KindCost::tally([
            ("student".to_string(), 10.0, Some(18.0)),
            ("teacher".to_string(), 30.0, Some(50.0)),
            ("student".to_string(), 20.0, Some(22.0)),
            ("student".to_string(), 5.0, None),
            ("world".to_string(), 1.0, None),
        ]);
        let names: Vec<&str> = kinds.iter().map(|k| k.kind.as_str()).collect();
        assert_eq!(names, ["teacher", "student", "world"]);
        let student = &kinds[1];
        assert_eq!(student.builds, 3);
        assert_eq!(student.wall_secs, 35.0);
        assert_eq!(student.cpu_secs, 40.0);
        // 40 CPU seconds over the 30 wall seconds of the two measured builds.
        assert_eq!(student.cores_busy, Some(40.0 / 30.0));
        assert_eq!(kinds[2].cores_busy, None);
        assert!(KindCost::tally([]).is_empty());
    }
}
