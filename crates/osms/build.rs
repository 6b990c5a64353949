// Embeds the MuJoCo library directory (set by .cargo/config.toml after scripts/setup-mujoco)
// as an rpath, so `osms` and its tests run without LD_LIBRARY_PATH.
//
// The wheel (scripts/build-wheel.py) installs the binary as a script into an environment's
// `bin/` and the MuJoCo library it carries into `site-packages/osms/` beside the Python
// package: the relative paths below find it there for each CPython the wheel installs into
// (3.9 on; Debian's system Python names its directory dist-packages).
fn main() {
    for minor in 9..=16 {
        for dir in ["site-packages", "dist-packages"] {
            println!(
                "cargo::rustc-link-arg-bins=-Wl,-rpath,$ORIGIN/../lib/python3.{minor}/{dir}/osms"
            );
        }
    }
    println!("cargo::rerun-if-env-changed=MUJOCO_DYNAMIC_LINK_DIR");
    if let Ok(dir) = std::env::var("MUJOCO_DYNAMIC_LINK_DIR") {
        println!("cargo::rustc-link-arg=-Wl,-rpath,{dir}");
        println!("cargo::rustc-env=OSMS_MUJOCO_LIB_DIR={dir}");
    }
}
