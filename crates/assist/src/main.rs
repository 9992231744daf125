//! The `assist` command line; everything lives in the library so tests can call it.

fn main() -> std::process::ExitCode {
    // A closed pipe (`assist edit … --history | head`) ends the process quietly, as it
    // does other Unix tools, instead of a panic at the next print. Rust ignores SIGPIPE
    // by default; the default action is restored here, before any thread starts.
    #[cfg(unix)]
    // SAFETY: first thing in `main`, single-threaded; `SIG_DFL` is a valid handler.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    assist::run_from_env()
}
