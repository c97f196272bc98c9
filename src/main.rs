fn main() -> std::process::ExitCode {
    iastgcn::cli::main()
}
