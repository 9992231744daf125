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
    // Subnormal floats flushed to zero on every thread from its start, not only from its
    // first kernel (`assist_simd::denormals`): the same arithmetic whichever thread runs
    // a piece of work.
    assist_simd::denormals::on_this_thread();
    // (Fails only when a pool exists already, which then flushes from its first kernel.)
    let _ = rayon::ThreadPoolBuilder::new()
        .start_handler(|_| assist_simd::denormals::on_this_thread())
        .build_global();
    assist::run_from_env()
}
