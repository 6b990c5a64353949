//! The osms command line with only the shipped stage kinds, as `osms` itself (a binary of this
//! crate, so end-to-end tests of the shipped pipeline can run it through `CARGO_BIN_EXE_`).

fn main() -> std::process::ExitCode {
    osms::main_with(osms_kinds::registry())
}
