//! Shared helpers for the benchmarks: peak memory and strict argument parsing.

/// Peak resident set size of this process in bytes (Linux `VmHWM`), 0 if unknown.
pub fn peak_rss_bytes() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .and_then(|l| l.split_whitespace().nth(1).and_then(|kb| kb.parse::<u64>().ok()))
        })
        .map_or(0, |kb| kb * 1024)
}

/// Command-line options of a bench binary: `--name VALUE` options and `--flag` switches.
///
/// An unknown option, a missing value or one that does not parse ends the program with a
/// message and exit status 2: a typo must not quietly run another benchmark than the one
/// asked for (`--steps 5OO` used to run the default 500 steps).
pub struct Args {
    given: Vec<String>,
}

impl Args {
    /// Reads the process's arguments, accepting the options in `options` (each followed by a
    /// value) and the switches in `flags`.
    pub fn parse(options: &[&str], flags: &[&str]) -> Args {
        match Args::from(std::env::args().skip(1).collect(), options, flags) {
            Ok(a) => a,
            Err(msg) => fail(&msg),
        }
    }

    /// [`Args::parse`] of a given argument list (no program name); the error is the message.
    pub fn from(given: Vec<String>, options: &[&str], flags: &[&str]) -> Result<Args, String> {
        let mut i = 0;
        while i < given.len() {
            let a = given[i].as_str();
            if options.contains(&a) {
                if i + 1 >= given.len() {
                    return Err(format!("{a} needs a value"));
                }
                i += 2;
            } else if flags.contains(&a) {
                i += 1;
            } else {
                let mut known: Vec<&str> = options.iter().chain(flags).copied().collect();
                known.sort_unstable();
                return Err(format!("unknown argument {a:?}; accepted: {}", known.join(" ")));
            }
        }
        Ok(Args { given })
    }

    /// The text after option `name`, if given (the last one wins).
    pub fn text(&self, name: &str) -> Option<&str> {
        self.given.iter().rposition(|a| a == name).map(|i| self.given[i + 1].as_str())
    }

    /// Option `name` parsed as `T`, or `default` when absent.
    pub fn get<T: std::str::FromStr>(&self, name: &str, default: T) -> Result<T, String> {
        match self.text(name) {
            None => Ok(default),
            Some(v) => v.parse().map_err(|_| format!("{name}: cannot read {v:?} as {}", std::any::type_name::<T>())),
        }
    }

    /// [`Args::get`], ending the program on a value that does not parse.
    pub fn value<T: std::str::FromStr>(&self, name: &str, default: T) -> T {
        self.get(name, default).unwrap_or_else(|msg| fail(&msg))
    }

    /// Whether switch `name` is given.
    pub fn flag(&self, name: &str) -> bool {
        self.given.iter().any(|a| a == name)
    }
}

/// Prints `error: msg` and exits with status 2 (bad command line or input).
pub fn fail(msg: &str) -> ! {
    eprintln!("error: {msg}");
    std::process::exit(2)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args(s: &str) -> Result<Args, String> {
        Args::from(s.split_whitespace().map(String::from).collect(), &["--steps", "--radius"], &["--json"])
    }

    #[test]
    fn options_flags_and_errors() {
        let a = args("--steps 20 --json --radius 0.01").unwrap();
        assert_eq!(a.get("--steps", 500u64), Ok(20));
        assert_eq!(a.get("--radius", 0.0125), Ok(0.01));
        assert!(a.flag("--json"));
        assert_eq!(args("").unwrap().get("--steps", 500u64), Ok(500));
        let bad = args("--steps 5OO").unwrap().get("--steps", 500u64).unwrap_err();
        assert!(bad.contains("--steps") && bad.contains("5OO"), "{bad}");
        assert!(args("--steps 20 --bogus").err().unwrap().contains("\"--bogus\""));
        assert!(args("--steps").err().unwrap().contains("needs a value"));
        assert!(args("--steps -1").unwrap().get("--steps", 0u64).is_err());
    }
}
