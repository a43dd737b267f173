//! Checks of user settings, shared by the command line and the config file: a setting's allowed
//! range, and the error that names a bad value by its key (so the config can point at its line).

use std::fmt::Display;
use std::str::FromStr;

/// A value the settings refuse: the key it was given under (dotted below its table, as in
/// `thresholds.gyro`) and the message, which names the key, the value and what is allowed.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{message}")]
pub struct Invalid {
    pub key: &'static str,
    pub message: String,
}

impl Invalid {
    pub fn new(key: &'static str, message: impl Into<String>) -> Self {
        Self {
            key,
            message: message.into(),
        }
    }
}

/// The inclusive range a numeric setting may take.
#[derive(Clone, Copy, Debug)]
pub struct Bounds<T> {
    pub lo: T,
    pub hi: T,
}

impl<T: PartialOrd + Display + Copy> Bounds<T> {
    pub const fn new(lo: T, hi: T) -> Self {
        Self { lo, hi }
    }

    /// Not a number is out of every range.
    pub fn contains(&self, v: T) -> bool {
        self.lo <= v && v <= self.hi
    }

    fn out_of_range(&self, v: T) -> String {
        format!("{v} is out of range {}..={}", self.lo, self.hi)
    }

    /// `key = v is out of range LO..=HI` unless `v` is in range.
    pub fn check(&self, key: &'static str, v: T) -> Result<(), Invalid> {
        if self.contains(v) {
            Ok(())
        } else {
            Err(Invalid::new(
                key,
                format!("{key} = {}", self.out_of_range(v)),
            ))
        }
    }

    /// A command-line value parser that refuses what [`Bounds::check`] would.
    pub fn parser(self) -> impl Fn(&str) -> Result<T, String> + Clone + Send + Sync + 'static
    where
        T: FromStr + Send + Sync + 'static,
        T::Err: Display,
    {
        move |s: &str| {
            let v: T = s.trim().parse().map_err(|e| format!("{e}"))?;
            if self.contains(v) {
                Ok(v)
            } else {
                Err(self.out_of_range(v))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_value_out_of_range_is_named_with_its_key_and_the_range() {
        let b = Bounds::new(0.01f32, 10.0);
        assert_eq!(b.check("lambda", 0.3), Ok(()));
        let e = b.check("lambda", 99.0).unwrap_err();
        assert_eq!(e.key, "lambda");
        assert_eq!(e.to_string(), "lambda = 99 is out of range 0.01..=10");
        assert!(b.check("lambda", f32::NAN).is_err());
        let parse = b.parser();
        assert_eq!(parse("0.5"), Ok(0.5));
        assert_eq!(parse("11").unwrap_err(), "11 is out of range 0.01..=10");
        assert!(parse("much").is_err());
        assert!(Bounds::new(1u8, 100).parser()("300").is_err());
    }
}
