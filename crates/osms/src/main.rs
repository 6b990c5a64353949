fn main() -> std::process::ExitCode {
    osms::main_with(osms_kinds::registry())
}
