//! Built-in lenses, usable by name wherever a lens path is accepted.
//!
//! `lens1` and `lens2` are the paper's lenses (supplement C); `cooke-triplet` is optiland's
//! Cooke triplet with model glasses standing in for SK16 and F2. The JSON files were written by
//! DeepLens 2.5.6 and come from the project's reference data set (see tests/data/README.md).

use super::{json, Lens};

const BUILTINS: [(&str, &str); 3] = [
    ("lens1", include_str!("builtin/lens1.json")),
    ("lens2", include_str!("builtin/lens2.json")),
    ("cooke-triplet", include_str!("builtin/cooke-triplet.json")),
];

/// Names of the built-in lenses.
pub fn builtin_names() -> Vec<&'static str> {
    BUILTINS.iter().map(|(n, _)| *n).collect()
}

/// A built-in lens by name (case-insensitive), or `None`.
pub fn builtin(name: &str) -> Option<Lens> {
    BUILTINS
        .iter()
        .find(|(n, _)| n.eq_ignore_ascii_case(name))
        .map(|(n, text)| {
            json::from_str(text).unwrap_or_else(|e| panic!("built-in lens {n} is invalid: {e}"))
        })
}

#[cfg(test)]
mod tests {
    #[test]
    fn every_builtin_loads() {
        for n in super::builtin_names() {
            assert!(super::builtin(n).is_some(), "{n}");
        }
    }
}
