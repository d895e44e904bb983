//! The AFF tokeniser ([`Tokens`]: whitespace-separated tokens, `{` and `}` on their own, `#`
//! and `%` comments) and [`Src`], the typed reading of one file's tokens with its errors.

use glam::DVec3;

use crate::mesh::{MeshError, Place};

pub(super) struct Tokens<'a> {
    bytes: &'a [u8],
    pos: usize,
    line: u64,
    /// The line of the last token returned (1 before any): where a truncation is reported.
    pub(super) last: u64,
}

impl<'a> Tokens<'a> {
    pub(super) fn new(bytes: &'a [u8]) -> Tokens<'a> {
        Tokens {
            bytes,
            pos: 0,
            line: 1,
            last: 1,
        }
    }

    /// The next token and its line.
    pub(super) fn next(&mut self) -> Option<(&'a [u8], u64)> {
        let b = self.bytes;
        loop {
            while self.pos < b.len() && b[self.pos].is_ascii_whitespace() {
                if b[self.pos] == b'\n' {
                    self.line += 1;
                }
                self.pos += 1;
            }
            if self.pos >= b.len() {
                return None;
            }
            if b[self.pos] == b'#' || b[self.pos] == b'%' {
                while self.pos < b.len() && b[self.pos] != b'\n' {
                    self.pos += 1;
                }
                continue;
            }
            let start = self.pos;
            if b[start] == b'{' || b[start] == b'}' {
                self.pos += 1;
            } else {
                while self.pos < b.len()
                    && !b[self.pos].is_ascii_whitespace()
                    && b[self.pos] != b'{'
                    && b[self.pos] != b'}'
                {
                    self.pos += 1;
                }
            }
            self.last = self.line;
            return Some((&b[start..self.pos], self.line));
        }
    }

    pub(super) fn peek(&self) -> Option<&'a [u8]> {
        let mut t = Tokens { ..*self };
        t.next().map(|(tok, _)| tok)
    }
}

pub(super) fn show(tok: &[u8]) -> String {
    let s = String::from_utf8_lossy(tok);
    if s.chars().count() > 40 {
        format!("{}…", s.chars().take(40).collect::<String>())
    } else {
        s.into_owned()
    }
}

pub(super) fn parse_number(tok: &[u8]) -> Option<f64> {
    let s = std::str::from_utf8(tok).ok()?;
    // Rust also reads "inf" and "nan"; those are rejected by the finiteness check.
    s.parse::<f64>().ok()
}

pub(super) fn looks_like_number(tok: &[u8]) -> bool {
    parse_number(tok).is_some()
}

/// One file being read: its tokens and its name for errors.
pub(super) struct Src<'a> {
    pub(super) tok: Tokens<'a>,
    pub(super) file: &'a str,
}

impl<'a> Src<'a> {
    pub(super) fn aff(&self, line: u64, detail: String) -> MeshError {
        MeshError::Aff {
            file: self.file.to_owned(),
            line,
            detail,
        }
    }

    pub(super) fn token(
        &mut self,
        what: &dyn Fn() -> String,
    ) -> Result<(&'a [u8], u64), MeshError> {
        self.tok.next().ok_or_else(|| MeshError::Truncated {
            file: self.file.to_owned(),
            at: Place::Line(self.tok.last),
            detail: format!("the file ends where {} should be", what()),
        })
    }

    pub(super) fn number(&mut self, what: &dyn Fn() -> String) -> Result<f64, MeshError> {
        let (tok, line) = self.token(what)?;
        match parse_number(tok) {
            Some(x) if x.is_finite() => Ok(x),
            Some(_) => Err(MeshError::BadValue {
                file: self.file.to_owned(),
                at: Place::Line(line),
                detail: format!("`{}` for {}: not a finite number", show(tok), what()),
            }),
            None => Err(MeshError::BadValue {
                file: self.file.to_owned(),
                at: Place::Line(line),
                detail: format!("expected {}, found `{}`", what(), show(tok)),
            }),
        }
    }

    pub(super) fn vec3(&mut self, what: &dyn Fn() -> String) -> Result<DVec3, MeshError> {
        Ok(DVec3::new(
            self.number(&|| format!("the x of {}", what()))?,
            self.number(&|| format!("the y of {}", what()))?,
            self.number(&|| format!("the z of {}", what()))?,
        ))
    }

    /// A non-negative integer (counts, detail levels are read with [`Self::integer`]).
    pub(super) fn count(&mut self, what: &dyn Fn() -> String) -> Result<u64, MeshError> {
        let (tok, line) = self.token(what)?;
        std::str::from_utf8(tok)
            .ok()
            .and_then(|s| s.parse::<u64>().ok())
            .ok_or_else(|| MeshError::BadValue {
                file: self.file.to_owned(),
                at: Place::Line(line),
                detail: format!(
                    "expected {} (a non-negative integer), found `{}`",
                    what(),
                    show(tok)
                ),
            })
    }

    pub(super) fn integer(&mut self, what: &dyn Fn() -> String) -> Result<(i64, u64), MeshError> {
        let (tok, line) = self.token(what)?;
        std::str::from_utf8(tok)
            .ok()
            .and_then(|s| s.parse::<i64>().ok())
            .map(|v| (v, line))
            .ok_or_else(|| MeshError::BadValue {
                file: self.file.to_owned(),
                at: Place::Line(line),
                detail: format!("expected {} (an integer), found `{}`", what(), show(tok)),
            })
    }

    /// An index into a block of `len` items.
    pub(super) fn index(&mut self, len: u64, what: &dyn Fn() -> String) -> Result<u64, MeshError> {
        let (v, line) = self.integer(what)?;
        if v < 0 || v as u64 >= len {
            return Err(self.aff(
                line,
                format!("{} is {v}, but the mesh has {len} of them", what()),
            ));
        }
        Ok(v as u64)
    }

    pub(super) fn expect(
        &mut self,
        word: &[u8],
        what: &dyn Fn() -> String,
    ) -> Result<u64, MeshError> {
        let (tok, line) = self.token(&|| format!("`{}` {}", show(word), what()))?;
        if tok != word {
            return Err(self.aff(
                line,
                format!(
                    "expected `{}` {}, found `{}`",
                    show(word),
                    what(),
                    show(tok)
                ),
            ));
        }
        Ok(line)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tokens(text: &str) -> Vec<(String, u64)> {
        let mut t = Tokens::new(text.as_bytes());
        std::iter::from_fn(|| t.next())
            .map(|(tok, line)| (String::from_utf8_lossy(tok).into_owned(), line))
            .collect()
    }

    #[test]
    fn tokens_split_braces_skip_comments_and_count_lines() {
        assert_eq!(
            tokens("xs 1 # c { }\r\n{p % x\n}}a"),
            vec![
                ("xs".into(), 1),
                ("1".into(), 1),
                ("{".into(), 2),
                ("p".into(), 2),
                ("}".into(), 3),
                ("}".into(), 3),
                ("a".into(), 3),
            ]
        );
        let mut t = Tokens::new(b"a\n\n b\n\n");
        assert_eq!(t.peek(), Some(&b"a"[..]));
        t.next();
        t.next();
        assert_eq!((t.next(), t.last), (None, 3));
    }
}
