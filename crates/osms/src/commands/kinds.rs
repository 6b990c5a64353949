//! `osms kinds`: the stage kinds this osms knows, with their inputs and code versions.

use std::process::ExitCode;

use anyhow::Result;
use osms_make::Registry;

use crate::commands::print_json;

pub fn kinds(registry: &Registry, json: bool) -> Result<ExitCode> {
    let infos = registry.infos();
    if json {
        print_json(&infos)?;
    } else if infos.is_empty() {
        outln!("no stage kinds are registered in this build of osms");
    } else {
        for k in infos {
            let shape = if k.itemised {
                ", itemised (shardable)"
            } else {
                ""
            };
            let rng = if k.uses_rng { ", seeded" } else { "" };
            outln!(
                "{} v{} -> {}{shape}{rng}",
                k.name,
                k.code_version,
                k.output_tag
            );
            outln!(
                "    inputs: {}",
                if k.inputs.is_empty() {
                    "none".to_string()
                } else {
                    k.inputs
                        .iter()
                        .map(|s| {
                            let mut text = format!("{}: {}", s.name, s.tag);
                            if !s.roles.is_empty() {
                                text.push_str(&format!(" ({})", s.roles.join(" | ")));
                            }
                            if s.gather {
                                text.push_str(" (gather)");
                            }
                            if s.optional {
                                text.push_str(" (optional)");
                            }
                            text
                        })
                        .collect::<Vec<_>>()
                        .join(", ")
                }
            );
            outln!("    {}", k.doc);
        }
    }
    Ok(ExitCode::SUCCESS)
}
