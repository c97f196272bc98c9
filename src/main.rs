//! The `iastgcn` command line: it parses arguments, calls the library and prints.

mod cli;

fn main() -> std::process::ExitCode {
    cli::main()
}
