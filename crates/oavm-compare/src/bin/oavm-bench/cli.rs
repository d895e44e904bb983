//! What `oavm-bench` takes of the helpers the binaries of `oavm` share (their `src/bin/cli`,
//! copied here since a binary's modules are not a library's): running `main` with errors
//! printed once with their whole chain, printing text and JSON, `X,Y,Z` values and `--leaf`.

use std::io::Write;
use std::process::ExitCode;

use oavm::Error;

/// Runs `run`, printing an error (and its sources) prefixed by the program name; exit status 1
/// on an error. A broken pipe on stdout is not an error.
pub fn main_with(program: &str, run: impl FnOnce() -> Result<(), Error>) -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(Error::Io { source, .. }) if source.kind() == std::io::ErrorKind::BrokenPipe => {
            ExitCode::SUCCESS
        }
        Err(e) => {
            let mut msg = format!("{program}: error: {e}");
            for cause in e.causes() {
                msg.push_str(&format!("\n  caused by: {cause}"));
            }
            eprintln!("{msg}");
            ExitCode::FAILURE
        }
    }
}

/// Prints `text` to stdout.
pub fn print_text(text: &str) -> Result<(), Error> {
    std::io::stdout()
        .lock()
        .write_all(text.as_bytes())
        .map_err(|e| Error::io("stdout", e))
}

/// Prints `value` as pretty JSON, one object.
pub fn print_json(value: &impl serde::Serialize) -> Result<(), Error> {
    let text = serde_json::to_string_pretty(value)
        .map_err(|e| Error::Invalid(format!("cannot write the report as JSON: {e}")))?;
    print_text(&(text + "\n"))
}

/// Parses `X,Y,Z` (three finite numbers).
pub fn parse_vec3(s: &str) -> Result<[f64; 3], String> {
    let v: Vec<f64> = s
        .split(',')
        .map(|p| p.trim().parse::<f64>().map_err(|e| format!("{p:?}: {e}")))
        .collect::<Result<_, _>>()?;
    match v[..] {
        [x, y, z] if v.iter().all(|c| c.is_finite()) => Ok([x, y, z]),
        _ => Err(format!("expected three finite numbers X,Y,Z, got {s:?}")),
    }
}

/// `--leaf`: what a solid leaf holds (`oavm::pack::LeafKind`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum LeafArg {
    Cluster,
    List,
}

impl LeafArg {
    pub fn kind(self) -> oavm::pack::LeafKind {
        match self {
            LeafArg::Cluster => oavm::pack::LeafKind::Cluster,
            LeafArg::List => oavm::pack::LeafKind::List,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vectors() {
        assert_eq!(parse_vec3("1, 2,-3"), Ok([1.0, 2.0, -3.0]));
        assert!(parse_vec3("1,2").is_err());
        assert!(parse_vec3("1,2,inf").is_err());
    }
}
