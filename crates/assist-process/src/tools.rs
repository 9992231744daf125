//! The external programs `process` drives — Debian's `ffmpeg` (with `ffprobe`) and
//! `colmap` — found on `PATH`, run with their output logged line by line (and passed to
//! the caller for progress), and their failures reported with the log's last lines.

use std::io::{BufRead, BufReader, Write};
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::Duration;

use crate::ProcessError;

/// A program and the Debian package that provides it.
#[derive(Debug, Clone, Copy)]
pub struct Tool {
    pub name: &'static str,
    pub package: &'static str,
}

pub const FFMPEG: Tool = Tool {
    name: "ffmpeg",
    package: "ffmpeg",
};
pub const FFPROBE: Tool = Tool {
    name: "ffprobe",
    package: "ffmpeg",
};
pub const COLMAP: Tool = Tool {
    name: "colmap",
    package: "colmap",
};

impl Tool {
    /// This program failed doing `what`.
    fn failed(self, what: &str, message: String) -> ProcessError {
        ProcessError::Tool {
            tool: self.name,
            what: what.to_string(),
            message,
        }
    }

    /// The program's path on `PATH`, or an error naming the package to install.
    pub fn find(self) -> Result<PathBuf, ProcessError> {
        let path = std::env::var_os("PATH").unwrap_or_default();
        std::env::split_paths(&path)
            .map(|d| d.join(self.name))
            .find(|p| p.is_file())
            .ok_or(ProcessError::MissingTool {
                tool: self.name,
                package: self.package,
            })
    }
}

/// Where a job's programs log, and the flag that stops them.
pub struct Runner<'a> {
    pub log: PathBuf,
    pub cancel: &'a AtomicBool,
}

impl Runner<'_> {
    /// Runs `cmd` (a `tool` doing `what`), appending everything it prints to the log and
    /// handing each line to `on_line`; a failure to start or a non-zero exit is an error
    /// with the log's last lines, and the cancel flag kills it.
    pub fn run(
        &self,
        tool: Tool,
        what: &str,
        cmd: &mut Command,
        mut on_line: impl FnMut(&str),
    ) -> Result<(), ProcessError> {
        let log = &self.log;
        let io = |e: std::io::Error| ProcessError::Io {
            path: log.to_path_buf(),
            message: e.to_string(),
        };
        let mut file = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(log)
            .map_err(io)?;
        let mut child = cmd
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| tool.failed(what, format!("could not start it: {e}")))?;
        // Both streams, line by line, into one channel (COLMAP logs to stderr, ffmpeg too).
        let (tx, rx) = mpsc::channel::<String>();
        let readers: Vec<_> = [
            child
                .stdout
                .take()
                .map(|s| Box::new(s) as Box<dyn std::io::Read + Send>),
            child
                .stderr
                .take()
                .map(|s| Box::new(s) as Box<dyn std::io::Read + Send>),
        ]
        .into_iter()
        .flatten()
        .map(|stream| {
            let tx = tx.clone();
            std::thread::spawn(move || {
                for line in BufReader::new(stream).lines().map_while(Result::ok) {
                    if tx.send(line).is_err() {
                        break;
                    }
                }
            })
        })
        .collect();
        drop(tx);
        let mut tail = std::collections::VecDeque::new();
        loop {
            if self.cancel.load(Ordering::SeqCst) {
                let _ = child.kill();
                let _ = child.wait();
                return Err(ProcessError::Cancelled);
            }
            match rx.recv_timeout(Duration::from_millis(200)) {
                Ok(line) => {
                    writeln!(file, "{line}").map_err(io)?;
                    on_line(&line);
                    tail.push_back(line);
                    if tail.len() > 12 {
                        tail.pop_front();
                    }
                }
                Err(mpsc::RecvTimeoutError::Timeout) => {}
                Err(mpsc::RecvTimeoutError::Disconnected) => break,
            }
        }
        for r in readers {
            let _ = r.join();
        }
        let status = child.wait().map_err(io)?;
        if !status.success() {
            return Err(ProcessError::Tool {
                tool: tool.name,
                what: what.to_string(),
                message: format!(
                    "exited with {status}; its last lines:\n  {}",
                    Vec::from(tail)
                        .iter()
                        .filter(|l| !l.trim().is_empty())
                        .cloned()
                        .collect::<Vec<_>>()
                        .join("\n  ")
                ),
            });
        }
        Ok(())
    }
}

/// Runs `cmd` and returns what it printed on stdout; a non-zero exit is an error with
/// its stderr.
pub fn output(tool: Tool, what: &str, cmd: &mut Command) -> Result<String, ProcessError> {
    let o = cmd
        .stdin(Stdio::null())
        .output()
        .map_err(|e| tool.failed(what, format!("could not start it: {e}")))?;
    if !o.status.success() {
        return Err(ProcessError::Tool {
            tool: tool.name,
            what: what.to_string(),
            message: format!(
                "exited with {}: {}",
                o.status,
                String::from_utf8_lossy(&o.stderr).trim()
            ),
        });
    }
    Ok(String::from_utf8_lossy(&o.stdout).into_owned())
}
