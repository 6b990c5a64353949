// The module finds MuJoCo in its own directory first, where the wheel (scripts/build-wheel.py)
// puts the library it carries, then in the directory set by .cargo/config.toml after
// scripts/setup-mujoco, so it also loads from a checkout without LD_LIBRARY_PATH.
fn main() {
    println!("cargo::rustc-link-arg=-Wl,-rpath,$ORIGIN");
    println!("cargo::rerun-if-env-changed=MUJOCO_DYNAMIC_LINK_DIR");
    if let Ok(dir) = std::env::var("MUJOCO_DYNAMIC_LINK_DIR") {
        println!("cargo::rustc-link-arg=-Wl,-rpath,{dir}");
        println!("cargo::rustc-env=OSMS_MUJOCO_LIB_DIR={dir}");
    }
}
