//! Argument decoding for the text opcodes of protocol 0/1 and for LONG1/LONG4.

use std::num::IntErrorKind;

pub(crate) enum IntError {
    Overflow,
    Invalid,
}

/// Decimal `int` as written by INT / LONG (a trailing `L` is Python 2's long marker).
pub(crate) fn parse_int(line: &[u8]) -> Result<i64, IntError> {
    let s = std::str::from_utf8(line).map_err(|_| IntError::Invalid)?.trim();
    let s = s.strip_suffix('L').unwrap_or(s);
    s.parse::<i64>().map_err(|e| match e.kind() {
        IntErrorKind::PosOverflow | IntErrorKind::NegOverflow => IntError::Overflow,
        _ => IntError::Invalid,
    })
}

pub(crate) fn parse_float(line: &[u8]) -> Option<f64> {
    std::str::from_utf8(line).ok()?.trim().parse().ok()
}

/// Little-endian two's complement integer of LONG1/LONG4; `None` if it exceeds `i64`.
pub(crate) fn decode_long(bytes: &[u8]) -> Option<i64> {
    let Some(&last) = bytes.last() else {
        return Some(0);
    };
    let fill = if last & 0x80 != 0 { 0xff } else { 0x00 };
    if bytes.len() > 8 {
        // Non-minimal encodings are fine as long as the extra bytes only extend the sign.
        if bytes[8..].iter().any(|&b| b != fill) || (bytes[7] & 0x80 != 0) != (fill == 0xff) {
            return None;
        }
    }
    let mut buf = [fill; 8];
    let n = bytes.len().min(8);
    buf[..n].copy_from_slice(&bytes[..n]);
    Some(i64::from_le_bytes(buf))
}

/// The quoted, backslash-escaped argument of STRING (Python's `codecs.escape_decode`).
pub(crate) fn unescape_string(line: &[u8]) -> Option<Vec<u8>> {
    let quoted = line.len() >= 2 && line[0] == line[line.len() - 1] && (line[0] == b'\'' || line[0] == b'"');
    if !quoted {
        return None;
    }
    let s = &line[1..line.len() - 1];
    let mut out = Vec::with_capacity(s.len());
    let mut i = 0;
    while i < s.len() {
        let c = s[i];
        i += 1;
        if c != b'\\' {
            out.push(c);
            continue;
        }
        let e = *s.get(i)?;
        i += 1;
        match e {
            b'\n' => {}
            b'\\' | b'\'' | b'"' => out.push(e),
            b'a' => out.push(0x07),
            b'b' => out.push(0x08),
            b'f' => out.push(0x0c),
            b'n' => out.push(b'\n'),
            b'r' => out.push(b'\r'),
            b't' => out.push(b'\t'),
            b'v' => out.push(0x0b),
            b'0'..=b'7' => {
                let mut v = u32::from(e - b'0');
                for _ in 0..2 {
                    match s.get(i) {
                        Some(&d @ b'0'..=b'7') => {
                            v = v * 8 + u32::from(d - b'0');
                            i += 1;
                        }
                        _ => break,
                    }
                }
                out.push((v & 0xff) as u8);
            }
            b'x' => {
                let hex = std::str::from_utf8(s.get(i..i + 2)?).ok()?;
                out.push(u8::from_str_radix(hex, 16).ok()?);
                i += 2;
            }
            other => out.extend_from_slice(&[b'\\', other]),
        }
    }
    Some(out)
}

/// The argument of UNICODE: latin-1 with `\uXXXX` / `\UXXXXXXXX` escapes (`raw-unicode-escape`).
pub(crate) fn raw_unicode_escape(s: &[u8]) -> Option<String> {
    let mut out = String::with_capacity(s.len());
    let mut i = 0;
    while i < s.len() {
        if s[i] != b'\\' {
            out.push(char::from(s[i]));
            i += 1;
            continue;
        }
        // Only an odd run of backslashes escapes the following u/U.
        let start = i;
        while i < s.len() && s[i] == b'\\' {
            out.push('\\');
            i += 1;
        }
        let width = match s.get(i) {
            Some(b'u') => 4,
            Some(b'U') => 8,
            _ => continue,
        };
        if (i - start) % 2 == 0 {
            continue;
        }
        out.pop();
        let hex = std::str::from_utf8(s.get(i + 1..i + 1 + width)?).ok()?;
        out.push(char::from_u32(u32::from_str_radix(hex, 16).ok()?)?);
        i += 1 + width;
    }
    Some(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn longs() {
        assert_eq!(decode_long(&[]), Some(0));
        assert_eq!(decode_long(&[0xff]), Some(-1));
        assert_eq!(decode_long(&[0x00, 0x80]), Some(-32768));
        assert_eq!(decode_long(&[0xff, 0x00]), Some(255));
        let max = i64::MAX.to_le_bytes();
        assert_eq!(decode_long(&max), Some(i64::MAX));
        assert_eq!(decode_long(&[max.as_slice(), &[0]].concat()), Some(i64::MAX));
        // 2**63 needs 9 bytes and does not fit.
        assert_eq!(decode_long(&[0, 0, 0, 0, 0, 0, 0, 0x80, 0]), None);
        let min = i64::MIN.to_le_bytes();
        assert_eq!(decode_long(&[min.as_slice(), &[0xff]].concat()), Some(i64::MIN));
        assert_eq!(decode_long(&[0, 0, 0, 0, 0, 0, 0, 0, 1]), None);
    }

    #[test]
    fn strings() {
        assert_eq!(unescape_string(b"'a\\nb\\x41\\101\\\\'").unwrap(), b"a\nbAA\\");
        assert_eq!(unescape_string(b"\"it's\"").unwrap(), b"it's");
        assert!(unescape_string(b"'unterminated").is_none());
        assert!(unescape_string(b"'\\x4'").is_none());
        assert_eq!(raw_unicode_escape(b"caf\xe9 \\u20ac").unwrap(), "café €");
        assert_eq!(raw_unicode_escape(b"\\\\u20ac").unwrap(), "\\\\u20ac");
        assert_eq!(raw_unicode_escape(b"\\U0001F600").unwrap(), "😀");
        assert!(raw_unicode_escape(b"\\u12").is_none());
    }

    #[test]
    fn ints() {
        assert_eq!(parse_int(b"-12").ok(), Some(-12));
        assert_eq!(parse_int(b"12L").ok(), Some(12));
        assert!(matches!(parse_int(b"99999999999999999999"), Err(IntError::Overflow)));
        assert!(matches!(parse_int(b"x"), Err(IntError::Invalid)));
    }
}
