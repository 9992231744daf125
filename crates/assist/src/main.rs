//! The `assist` command line; everything lives in the library so tests can call it.

fn main() -> std::process::ExitCode {
    assist::run_from_env()
}
