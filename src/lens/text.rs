//! Text decoding for files that OpticStudio writes: UTF-16 (little or big endian, with or without
//! a byte-order mark), UTF-8 (with or without a byte-order mark), ASCII, and as a last resort
//! Latin-1 (older Windows files). Decoding never fails; invalid sequences become U+FFFD.

/// Decodes the bytes of a text file, detecting the encoding.
pub(crate) fn decode(bytes: &[u8]) -> String {
    match bytes {
        [0xFF, 0xFE, rest @ ..] => utf16(rest, u16::from_le_bytes),
        [0xFE, 0xFF, rest @ ..] => utf16(rest, u16::from_be_bytes),
        [0xEF, 0xBB, 0xBF, rest @ ..] => String::from_utf8_lossy(rest).into_owned(),
        _ => {
            // UTF-16 without a byte-order mark: ASCII text has a NUL in every other byte.
            let even = bytes.iter().step_by(2).filter(|&&b| b == 0).count();
            let odd = bytes.iter().skip(1).step_by(2).filter(|&&b| b == 0).count();
            let half = bytes.len() / 2;
            if half > 0 && odd * 4 >= half * 3 && even * 4 < half {
                utf16(bytes, u16::from_le_bytes)
            } else if half > 0 && even * 4 >= half * 3 && odd * 4 < half {
                utf16(bytes, u16::from_be_bytes)
            } else {
                match std::str::from_utf8(bytes) {
                    Ok(s) => s.to_string(),
                    Err(_) => bytes.iter().map(|&b| char::from(b)).collect(),
                }
            }
        }
    }
}

fn utf16(bytes: &[u8], unit: fn([u8; 2]) -> u16) -> String {
    let units = bytes.chunks_exact(2).map(|c| unit([c[0], c[1]]));
    char::decode_utf16(units)
        .map(|r| r.unwrap_or(char::REPLACEMENT_CHARACTER))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::decode;

    fn utf16le(s: &str, bom: bool) -> Vec<u8> {
        let mut b = if bom { vec![0xFF, 0xFE] } else { vec![] };
        for u in s.encode_utf16() {
            b.extend(u.to_le_bytes());
        }
        b
    }

    #[test]
    fn every_encoding_decodes() {
        let s = "SURF 0\r\n  DISZ INFINITY\r\n";
        assert_eq!(decode(s.as_bytes()), s);
        assert_eq!(decode(&utf16le(s, true)), s);
        assert_eq!(decode(&utf16le(s, false)), s);
        let be: Vec<u8> = [0xFE, 0xFF]
            .into_iter()
            .chain(s.encode_utf16().flat_map(u16::to_be_bytes))
            .collect();
        assert_eq!(decode(&be), s);
        let be_no_bom: Vec<u8> = s.encode_utf16().flat_map(u16::to_be_bytes).collect();
        assert_eq!(decode(&be_no_bom), s);
        let mut bom8 = vec![0xEF, 0xBB, 0xBF];
        bom8.extend(s.as_bytes());
        assert_eq!(decode(&bom8), s);
        assert_eq!(decode(b"NAME caf\xe9"), "NAME caf\u{e9}");
        assert_eq!(decode(&[0xFF, 0xFE, 0x41]), "");
        assert_eq!(decode(&[]), "");
    }
}
