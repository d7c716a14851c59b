//! Mutations of a seed input (bytes, interesting values, splices of other seeds).

use super::*;

pub(super) const INTERESTING_BYTES: [u8; 8] = [0, 1, 0x7f, 0x80, 0xff, b'\n', b'-', b'9'];
pub(super) const INTERESTING_INTS: [u64; 14] =
    [0, 1, 2, 3, 255, 65535, 0x7fff_ffff, 0x8000_0000, 0xffff_ffff, 1 << 32, 1 << 40, i64::MAX as u64, 1 << 63, u64::MAX];
pub(super) const INTERESTING_NUMBERS: [&str; 16] = [
    "0",
    "-0",
    "-1",
    "1e308",
    "-1e308",
    "1e-320",
    "nan",
    "NaN",
    "inf",
    "-inf",
    "4294967296",
    "18446744073709551616",
    "99999999999999999999",
    "2147483648",
    "0.5",
    "1e9",
];
pub(super) const INTERESTING_TEXT: [&str; 12] = ["{", "}", "[", "]", "\"", ",", "\n", " ", "\0", "é", "=", "#"];

/// Writes a mutant of `base` into `out`: 1–8 stacked mutations.
pub fn mutate(rng: &mut Xoshiro256PlusPlus, base: &[u8], others: &[Vec<u8>], out: &mut Vec<u8>) {
    out.clear();
    out.extend_from_slice(base);
    let rounds = 1 + rng.random_range(0..8usize).min(rng.random_range(0..8usize));
    for _ in 0..rounds {
        let len = out.len();
        let at = if len == 0 { 0 } else { rng.random_range(0..len) };
        match rng.random_range(0..11u32) {
            0 if len > 0 => out[at] ^= 1 << rng.random_range(0..8),
            1 if len > 0 => out[at] = INTERESTING_BYTES[rng.random_range(0..INTERESTING_BYTES.len())],
            2 => {
                let v = INTERESTING_INTS[rng.random_range(0..INTERESTING_INTS.len())];
                let v = if rng.random::<bool>() { v.wrapping_neg() } else { v };
                let width = [1usize, 2, 4, 8][rng.random_range(0..4)];
                let bytes = v.to_le_bytes();
                for (k, b) in bytes.iter().take(width).enumerate() {
                    if let Some(slot) = out.get_mut(at + k) {
                        *slot = *b;
                    }
                }
            }
            3 => out.truncate(at),
            4 if len > 0 => {
                let n = rng.random_range(1..=(len - at).min(64));
                out.drain(at..at + n);
            }
            5 => {
                let n = rng.random_range(1..=16);
                let bytes: Vec<u8> = (0..n).map(|_| rng.random()).collect();
                out.splice(at..at, bytes);
            }
            6 if len > 0 => {
                let n = rng.random_range(1..=(len - at).min(256));
                let chunk = out[at..at + n].to_vec();
                let to = rng.random_range(0..=len);
                out.splice(to..to, chunk);
            }
            7 if !others.is_empty() => {
                let other = &others[rng.random_range(0..others.len())];
                if !other.is_empty() {
                    let from = rng.random_range(0..other.len());
                    let n = rng.random_range(1..=(other.len() - from).min(256));
                    let end = (at + n).min(len);
                    out.splice(at..end, other[from..from + n].iter().copied());
                }
            }
            8 | 9 => {
                // A number in text replaced by an extreme one.
                if let Some((start, end)) = number_near(out, at) {
                    let v = INTERESTING_NUMBERS[rng.random_range(0..INTERESTING_NUMBERS.len())];
                    out.splice(start..end, v.bytes());
                }
            }
            _ => {
                let t = INTERESTING_TEXT[rng.random_range(0..INTERESTING_TEXT.len())];
                out.splice(at..at, t.bytes());
            }
        }
    }
}

/// The byte range of the first ASCII number at or after `from`.
pub(super) fn number_near(bytes: &[u8], from: usize) -> Option<(usize, usize)> {
    let is_num = |b: u8| b.is_ascii_digit() || b == b'.' || b == b'-' || b == b'e';
    let start = from + bytes.get(from..)?.iter().position(|b| b.is_ascii_digit())?;
    let start = (0..start).rev().take_while(|&i| is_num(bytes[i])).last().unwrap_or(start);
    let end = start + bytes[start..].iter().take_while(|b| is_num(**b)).count();
    Some((start, end))
}
