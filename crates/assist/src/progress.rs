//! Progress bars on stderr (hidden when not wanted or when stderr is not a terminal).

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};

pub fn bar(show: bool, message: &str) -> ProgressBar {
    let b = ProgressBar::new(0);
    if !show {
        b.set_draw_target(ProgressDrawTarget::hidden());
    }
    b.set_style(
        ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} {elapsed_precise} ETA {eta}")
            .unwrap()
            .progress_chars("=> "),
    );
    b.set_message(message.to_string());
    b
}

/// A `(done, total)` callback that moves `bar`.
pub fn steps(bar: &ProgressBar) -> impl FnMut(usize, usize) + '_ {
    |i, n| {
        bar.set_length(n as u64);
        bar.set_position(i as u64);
    }
}
