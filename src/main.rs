fn main() -> std::process::ExitCode {
    skyfuse::cli::main()
}
