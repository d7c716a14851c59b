//! The TOML spellings of "off" and "the format's own": `0` for a period or a limit that is off,
//! `[]` for no region of interest. They are read into `Option` here, at the edge, and written
//! back the same way, so that a run folder's `config.toml` reads as it always did and the code
//! behind the edge never tests a sentinel.

use serde::{Deserialize, Deserializer, Serialize, Serializer};

/// `Option<T>` as `T`, with `T::default()` (zero) meaning `None`.
pub mod zero_is_none {
    use super::*;

    /// `None` as zero.
    pub fn serialize<S: Serializer, T: Serialize + Default + Copy>(value: &Option<T>, s: S) -> Result<S::Ok, S::Error> {
        value.unwrap_or_default().serialize(s)
    }

    /// Zero as `None`.
    pub fn deserialize<'de, D: Deserializer<'de>, T: Deserialize<'de> + Default + PartialEq>(d: D) -> Result<Option<T>, D::Error> {
        let value = T::deserialize(d)?;
        Ok((value != T::default()).then_some(value))
    }
}

/// `Option<NonZeroUsize>` as a count, with 0 meaning `None`.
pub mod zero_count_is_none {
    use super::*;
    use std::num::NonZeroUsize;

    /// `None` as 0.
    pub fn serialize<S: Serializer>(value: &Option<NonZeroUsize>, s: S) -> Result<S::Ok, S::Error> {
        value.map_or(0, NonZeroUsize::get).serialize(s)
    }

    /// 0 as `None`.
    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Option<NonZeroUsize>, D::Error> {
        Ok(NonZeroUsize::new(usize::deserialize(d)?))
    }
}

/// `Option<[f64; N]>` as a list: `[]` is `None`, N numbers (`[x, y, z, radius]`, …) are `Some`.
pub mod empty_is_none {
    use super::*;

    /// `None` as `[]`.
    pub fn serialize<S: Serializer, const N: usize>(value: &Option<[f64; N]>, s: S) -> Result<S::Ok, S::Error> {
        value.as_ref().map_or(&[][..], |v| &v[..]).serialize(s)
    }

    /// `[]` as `None`; another length than N is an error.
    pub fn deserialize<'de, D: Deserializer<'de>, const N: usize>(d: D) -> Result<Option<[f64; N]>, D::Error> {
        let values = Vec::<f64>::deserialize(d)?;
        if values.is_empty() {
            return Ok(None);
        }
        let names = if N == 4 { "[x, y, z, radius]".to_string() } else { format!("{N} numbers") };
        <[f64; N]>::try_from(values.as_slice()).map(Some).map_err(|_| serde::de::Error::custom(format!("{values:?}: expected [] or {names}")))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Debug, PartialEq, Serialize, Deserialize)]
    struct Keys {
        #[serde(with = "zero_is_none")]
        every: Option<u64>,
        #[serde(with = "zero_is_none")]
        limit: Option<f64>,
        #[serde(with = "empty_is_none")]
        bound: Option<[f64; 4]>,
    }

    /// Zero and `[]` read as `None` and are written back as they were read; other values are
    /// `Some` both ways; a bound of another length is an error.
    #[test]
    fn off_reads_as_none_and_writes_back_as_it_was_spelled() {
        let off: Keys = toml::from_str("every = 0\nlimit = 0.0\nbound = []").unwrap();
        assert_eq!(off, Keys { every: None, limit: None, bound: None });
        assert_eq!(toml::to_string(&off).unwrap(), "every = 0\nlimit = 0.0\nbound = []\n");
        let on = Keys { every: Some(100), limit: Some(2.5), bound: Some([0.0, 1.0, 2.0, 3.0]) };
        assert_eq!(toml::from_str::<Keys>(&toml::to_string(&on).unwrap()).unwrap(), on);
        let err = toml::from_str::<Keys>("every = 0\nlimit = 0.0\nbound = [1.0, 2.0]").unwrap_err().to_string();
        assert!(err.contains("expected [] or [x, y, z, radius]"), "{err}");
    }
}
