// Embeds the MuJoCo library directory (set by .cargo/config.toml after scripts/setup-mujoco)
// as an rpath, so `osms` and its tests run without LD_LIBRARY_PATH.
fn main() {
    println!("cargo::rerun-if-env-changed=MUJOCO_DYNAMIC_LINK_DIR");
    if let Ok(dir) = std::env::var("MUJOCO_DYNAMIC_LINK_DIR") {
        println!("cargo::rustc-link-arg=-Wl,-rpath,{dir}");
        println!("cargo::rustc-env=OSMS_MUJOCO_LIB_DIR={dir}");
    }
}
