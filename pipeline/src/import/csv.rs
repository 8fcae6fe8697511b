//! A small RFC 4180 CSV record reader: fields separated by one delimiter
//! byte, optionally enclosed in double quotes (a quoted field may contain
//! the delimiter, line breaks and `""` for a quote), records ended by LF or
//! CRLF. Enough for controller and metrology exports; it reports the file
//! line each record starts on.

use std::fmt;
use std::io::BufRead;

#[derive(Debug)]
pub enum CsvError {
    Io(std::io::Error),
    /// Not UTF-8, at this line.
    Utf8(u64),
    /// A quoted field never closed, opened at this line.
    Unterminated(u64),
    /// Text right after a closing quote (`"a"b`), at this line.
    AfterQuote(u64),
}

impl fmt::Display for CsvError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            CsvError::Io(e) => write!(f, "{e}"),
            CsvError::Utf8(l) => write!(f, "line {l} is not UTF-8 text"),
            CsvError::Unterminated(l) => {
                write!(f, "a quoted field opened on line {l} is never closed")
            }
            CsvError::AfterQuote(l) => write!(
                f,
                "line {l}: text after a closing quote (a quote inside a quoted field is written \"\")"
            ),
        }
    }
}

/// Records of a CSV stream.
pub struct Records<R> {
    input: R,
    delimiter: u8,
    line: u64,
    buf: Vec<u8>,
}

impl<R: BufRead> Records<R> {
    pub fn new(input: R, delimiter: u8) -> Self {
        Records {
            input,
            delimiter,
            line: 0,
            buf: Vec::new(),
        }
    }

    /// The next record and the (1-based) line it starts on; `None` at the end.
    pub fn next_record(&mut self) -> Result<Option<(u64, Vec<String>)>, CsvError> {
        let start = self.line + 1;
        let mut fields: Vec<Vec<u8>> = Vec::new();
        let mut field: Vec<u8> = Vec::new();
        // States: at field start, in an unquoted field, in a quoted field,
        // just after a quote inside a quoted field.
        #[derive(PartialEq)]
        enum S {
            Start,
            Plain,
            Quoted,
            QuoteInQuoted,
        }
        let mut s = S::Start;
        loop {
            self.buf.clear();
            let n = self
                .input
                .read_until(b'\n', &mut self.buf)
                .map_err(CsvError::Io)?;
            if n == 0 {
                if s == S::Quoted {
                    return Err(CsvError::Unterminated(start));
                }
                if fields.is_empty() && field.is_empty() && s == S::Start {
                    return Ok(None);
                }
                break;
            }
            self.line += 1;
            let line: &[u8] = &self.buf;
            let mut ended = false;
            for (i, &b) in line.iter().enumerate() {
                match s {
                    S::Quoted => {
                        if b == b'"' {
                            s = S::QuoteInQuoted;
                        } else {
                            field.push(b);
                        }
                    }
                    // `""` inside quotes is a quote; `"` opens a quoted field.
                    S::QuoteInQuoted if b == b'"' => {
                        field.push(b'"');
                        s = S::Quoted;
                    }
                    S::Start if b == b'"' => s = S::Quoted,
                    S::QuoteInQuoted | S::Start | S::Plain => {
                        if b == self.delimiter {
                            fields.push(std::mem::take(&mut field));
                            s = S::Start;
                        } else if b == b'\n' || (b == b'\r' && line.get(i + 1) == Some(&b'\n')) {
                            ended = true;
                            break;
                        } else if s == S::QuoteInQuoted {
                            return Err(CsvError::AfterQuote(self.line));
                        } else {
                            field.push(b);
                            s = S::Plain;
                        }
                    }
                }
            }
            // A record ends at the line end unless a quoted field is open
            // (then the line break belongs to the field); a last line
            // without a newline ends it too.
            if ended || s != S::Quoted {
                break;
            }
        }
        fields.push(field);
        let out = fields
            .into_iter()
            .map(|f| String::from_utf8(f).map_err(|_| CsvError::Utf8(start)))
            .collect::<Result<Vec<String>, _>>()?;
        Ok(Some((start, out)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn all(text: &str, d: u8) -> Vec<(u64, Vec<String>)> {
        let mut r = Records::new(text.as_bytes(), d);
        let mut out = Vec::new();
        while let Some(rec) = r.next_record().unwrap() {
            out.push(rec);
        }
        out
    }

    #[test]
    fn plain_quoted_crlf_and_multiline() {
        let recs = all(
            "a,b,c\r\n1,\"x, y\",3\n\"he said \"\"hi\"\"\",\"two\nlines\",\n4,5,6",
            b',',
        );
        assert_eq!(recs[0], (1, vec!["a".into(), "b".into(), "c".into()]));
        assert_eq!(recs[1].1, ["1", "x, y", "3"]);
        assert_eq!(recs[2].1, ["he said \"hi\"", "two\nlines", ""]);
        assert_eq!(recs[3], (5, vec!["4".into(), "5".into(), "6".into()]));
        assert_eq!(recs.len(), 4);
        let t = all("x;y\n1;2\n", b';');
        assert_eq!(t[1].1, ["1", "2"]);
    }

    #[test]
    fn errors_name_the_line() {
        let mut r = Records::new("a\n\"open\n".as_bytes(), b',');
        r.next_record().unwrap();
        assert!(matches!(r.next_record(), Err(CsvError::Unterminated(2))));
        let mut r = Records::new("\"a\"b,c\n".as_bytes(), b',');
        assert!(matches!(r.next_record(), Err(CsvError::AfterQuote(1))));
    }
}
