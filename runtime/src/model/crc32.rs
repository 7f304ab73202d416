//! CRC-32 (IEEE 802.3, the zlib/PNG polynomial), written by hand so the runtime needs no crate for
//! it.
//!
//! Parameters: reflected polynomial `0xEDB8_8320`, initial value `0xFFFF_FFFF`, final XOR
//! `0xFFFF_FFFF`; `crc32(b"123456789") == 0xCBF4_3926` (the standard check value). The 1 KiB
//! table is computed at compile time and lives in flash.

/// Byte-at-a-time lookup table, built by the compiler.
const TABLE: [u32; 256] = build_table();

// Evaluated by the compiler only: an out-of-range index here would be a build error, not a
// run-time panic.
#[allow(clippy::indexing_slicing)]
const fn build_table() -> [u32; 256] {
    let mut table = [0u32; 256];
    let mut byte = 0usize;
    while byte < 256 {
        let mut crc = byte as u32;
        let mut bit = 0;
        while bit < 8 {
            // Reflected form: shift right, fold the polynomial in when the dropped bit was set.
            crc = if crc & 1 == 1 {
                (crc >> 1) ^ 0xEDB8_8320
            } else {
                crc >> 1
            };
            bit += 1;
        }
        table[byte] = crc;
        byte += 1;
    }
    table
}

/// CRC-32 of `bytes`.
pub fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = 0xFFFF_FFFFu32;
    for &byte in bytes {
        let index = usize::from((crc as u8) ^ byte);
        // `index` is a u8, always inside the 256-entry table.
        let entry = TABLE.get(index).copied().unwrap_or(0);
        crc = (crc >> 8) ^ entry;
    }
    !crc
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_the_standard_check_values() {
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
        assert_eq!(crc32(b""), 0);
        assert_eq!(
            crc32(b"The quick brown fox jumps over the lazy dog"),
            0x414F_A339
        );
    }
}
