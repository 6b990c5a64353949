//! The osms command line with the test-only stage kinds registered, so end-to-end tests drive
//! the real CLI code over a pipeline they control.

fn main() -> std::process::ExitCode {
    osms::main_with(osms_tests::registry())
}
