use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Result;
use mujoco_rs::prelude::MjModel;
use osms_make::Registry;
use serde::Serialize;

use crate::EXIT_FAILURE;
use crate::cli::Global;
use crate::commands::print_json;
use crate::context::Context;

/// The MuJoCo version osms is built for; scripts/setup-mujoco fetches the same.
const MUJOCO_EXPECTED: &str = osms_sim::MUJOCO_PINNED;

#[derive(Serialize)]
struct Report {
    osms_version: &'static str,
    mujoco_version: String,
    mujoco_expected: &'static str,
    mujoco_lib_dir: Option<&'static str>,
    mujoco_smoke_test: Result<String, String>,
    /// `<arch>-libm-<8 hex>`: golden content hashes are kept per class (`osms::platform`).
    platform_class: String,
    /// What the class is made of: the libm fingerprint, glibc version, CPU features.
    platform: crate::platform::Report,
    pipeline: Option<PathBuf>,
    pipeline_check: Result<String, String>,
    store: Option<PathBuf>,
    store_check: Result<String, String>,
    setup_complete: bool,
}

/// Loads a one-body model and steps it: proves the library loads, parses MJCF and simulates.
fn smoke_test() -> Result<String, String> {
    const XML: &str = r#"<mujoco><option timestep="0.002"/><worldbody>
        <body pos="0 0 1"><freejoint/><geom type="sphere" size="0.05" mass="0.05"/></body>
        </worldbody></mujoco>"#;
    let model = MjModel::from_xml_string(XML).map_err(|e| e.to_string())?;
    let mut data = model.make_data();
    for _ in 0..250 {
        data.step();
    }
    let z = data.qpos()[2];
    // Free fall for 0.5 s from 1 m: about 1 - g t^2 / 2 = -0.23 m.
    if (z - (1.0 - 0.5 * 9.81 * 0.25)).abs() < 0.01 {
        Ok(format!("a sphere fell for 0.5 s to z = {z:.4} m"))
    } else {
        Err(format!(
            "a falling sphere reached z = {z:.4} m after 0.5 s, expected about -0.226 m"
        ))
    }
}

/// The class and what it is made of, for humans: which libm variant golden hashes are kept for.
fn print_platform(p: &crate::platform::Report) {
    outln!(
        "platform class  {} (golden content hashes are kept per class)",
        p.class
    );
    let names: Vec<&str> = p.libm.functions.iter().map(|(n, _)| *n).collect();
    outln!(
        "  libm          fingerprint {} of {} functions MuJoCo and osms may call ({}){}",
        &p.libm.digest[..16],
        names.len(),
        names.join(" "),
        p.glibc_version
            .as_ref()
            .map(|v| format!(", glibc {v}"))
            .unwrap_or_default()
    );
    let yes_no = |b: Option<bool>| if b == Some(true) { "yes" } else { "no" };
    if p.cpu_fma.is_some() {
        let masked = p
            .glibc_tunables
            .as_deref()
            .is_some_and(|t| t.contains("-FMA") || t.contains("-AVX2"));
        let fma_variants = p.cpu_fma == Some(true) && p.cpu_avx2 == Some(true);
        outln!(
            "  CPU           FMA {}, AVX2 {}, AVX-512F {}: {}",
            yes_no(p.cpu_fma),
            yes_no(p.cpu_avx2),
            yes_no(p.cpu_avx512f),
            match (fma_variants, masked) {
                (true, false) => {
                    "a glibc libm picks its FMA variants of exp/log/pow/sin/cos/tan/atan2/asin/..., \
                     whose last bits differ from the plain ones on some inputs (exp: ~1 in 1300)"
                }
                (true, true) => {
                    "but GLIBC_TUNABLES masks FMA/AVX2, so a glibc libm uses its plain variants \
                     of exp/log/pow/sin/cos/..."
                }
                (false, _) =>
                    "a glibc libm uses its plain (non-FMA) variants of exp/log/pow/sin/cos/...",
            }
        );
    }
    if let Some(t) = &p.glibc_tunables {
        outln!("  GLIBC_TUNABLES {t} (can mask CPU features from glibc, changing the class)");
    }
}

pub fn run(global: &Global, registry: &Registry, json: bool) -> Result<ExitCode> {
    let mujoco_version = mujoco_rs::mujoco_version().to_string();
    let smoke = smoke_test();
    let ctx = Context::new(global, registry.clone());
    let (pipeline, store, pipeline_check, store_check) = match &ctx {
        Ok(ctx) => {
            let pipeline_check = ctx
                .plan(None)
                .map(|p| format!("{} stages, default profile {}", p.stages.len(), p.profile))
                .map_err(|e| e.to_string());
            let store_check = if ctx.store_path.join("OSMS_STORE").is_file() {
                Ok("an osms store".to_string())
            } else if !ctx.store_path.exists() {
                Ok("not created yet; `osms make` creates it".to_string())
            } else {
                ctx.store()
                    .map(|_| "empty directory; will become a store".to_string())
                    .map_err(|e| format!("{e:#}"))
            };
            (
                Some(ctx.pipeline_path.clone()),
                Some(ctx.store_path.clone()),
                pipeline_check,
                store_check,
            )
        }
        Err(e) => (
            None,
            None,
            Err(e.to_string()),
            Err("no project found".to_string()),
        ),
    };
    let setup_complete = mujoco_version == MUJOCO_EXPECTED && smoke.is_ok();
    let platform = crate::platform::report();
    let report = Report {
        osms_version: osms_make::OSMS_VERSION,
        mujoco_version,
        mujoco_expected: MUJOCO_EXPECTED,
        mujoco_lib_dir: option_env!("OSMS_MUJOCO_LIB_DIR"),
        mujoco_smoke_test: smoke,
        platform_class: platform.class.clone(),
        platform,
        pipeline,
        pipeline_check,
        store,
        store_check,
        setup_complete,
    };
    if json {
        print_json(&report)?;
    } else {
        let show = |r: &Result<String, String>| match r {
            Ok(s) => format!("ok: {s}"),
            Err(e) => format!("PROBLEM: {e}"),
        };
        outln!("osms            {}", report.osms_version);
        outln!(
            "MuJoCo          {} (library's own mj_versionString; expected {})",
            report.mujoco_version,
            MUJOCO_EXPECTED
        );
        outln!(
            "MuJoCo library  {}",
            report
                .mujoco_lib_dir
                .unwrap_or("(found by the system loader)")
        );
        outln!("MuJoCo check    {}", show(&report.mujoco_smoke_test));
        print_platform(&report.platform);
        outln!(
            "pipeline        {} ({})",
            report
                .pipeline
                .as_ref()
                .map(|p| p.display().to_string())
                .unwrap_or("-".into()),
            show(&report.pipeline_check)
        );
        outln!(
            "store           {} ({})",
            report
                .store
                .as_ref()
                .map(|p| p.display().to_string())
                .unwrap_or("-".into()),
            show(&report.store_check)
        );
        outln!(
            "set-up          {}",
            if report.setup_complete {
                "complete"
            } else {
                "INCOMPLETE: run scripts/setup-mujoco, then rebuild"
            }
        );
    }
    Ok(if report.setup_complete {
        ExitCode::SUCCESS
    } else {
        ExitCode::from(EXIT_FAILURE)
    })
}
