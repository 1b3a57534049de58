//! The registry: every filter by name, its description, and construction from parameter
//! overrides. The filter interface itself ([`crate::pipeline`]) knows no filter.

use super::{fxaa, passthrough, phlm, pixel_trace, taa, traa, upsample};
use crate::pipeline::{entry, Filter, FilterEntry, FilterError, FilterInfo};
use serde_json::{Map, Value};

/// Every filter, in the order they are listed.
pub fn registry() -> Vec<FilterEntry> {
    vec![
        entry::<passthrough::Passthrough>(),
        entry::<fxaa::Fxaa>(),
        entry::<taa::Taa>(),
        entry::<traa::Traa>(),
        entry::<phlm::Phlm>(),
        entry::<pixel_trace::PixelTrace>(),
        entry::<upsample::Upsample>(),
    ]
}

/// Descriptions of every filter.
pub fn list() -> Vec<FilterInfo> {
    registry().iter().map(|e| (e.info)()).collect()
}

/// The description of filter `name`, if there is one.
pub fn info(name: &str) -> Option<FilterInfo> {
    registry().iter().map(|e| (e.info)()).find(|i| i.name == name)
}

/// A new instance of filter `name` with `values` overriding its defaults.
pub fn create(name: &str, values: &Map<String, Value>) -> Result<Box<dyn Filter>, FilterError> {
    Ok(create_sized(name, values)?.0)
}

/// A new instance of filter `name` with `values` overriding its defaults, and the bytes of
/// state per pixel it will hold with those parameters.
pub fn create_sized(
    name: &str,
    values: &Map<String, Value>,
) -> Result<(Box<dyn Filter>, usize), FilterError> {
    let reg = registry();
    let entry = reg
        .iter()
        .find(|e| (e.info)().name == name)
        .ok_or_else(|| FilterError::UnknownFilter {
            got: name.to_string(),
            known: reg.iter().map(|e| (e.info)().name).collect::<Vec<_>>().join(", "),
        })?;
    (entry.create)(values)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filters::check::{sequences, sparse_sequences};
    use crate::frame::Frame;
    use crate::pipeline::params::parse_assignments;
    use crate::pipeline::{FilterState, StateError};

    fn make(name: &str, set: &[&str]) -> Box<dyn Filter> {
        let set: Vec<String> = set.iter().map(|s| s.to_string()).collect();
        create(name, &parse_assignments(&set).unwrap()).unwrap()
    }

    fn bits(f: &mut dyn Filter, frames: &[Frame]) -> Vec<Vec<u32>> {
        frames
            .iter()
            .map(|fr| {
                let out = f.process(fr).unwrap();
                out.color
                    .iter()
                    .flat_map(|p| p.data().iter().map(|v| v.to_bits()))
                    .collect()
            })
            .collect()
    }

    /// Every causal filter, stopped after any frame, saved to bytes and loaded into a new
    /// instance, gives the uninterrupted run's outputs bit for bit: across working-space
    /// switches, cuts, NaN input and a stopped-before-the-first-frame state.
    #[test]
    fn a_saved_state_continues_bit_for_bit() {
        let cases: &[(&str, &[&str])] = &[
            ("passthrough", &[]),
            ("fxaa", &[]),
            ("taa", &[]),
            ("traa", &[]),
            ("traa", &["variant=baseline"]),
            ("phlm", &[]),
            ("upsample", &[]),
            ("upsample", &["method=temporal"]),
        ];
        let (w, h, n) = (13, 7, 6);
        for &(name, set) in cases {
            let seqs = if name == "upsample" {
                sparse_sequences(w, h, n, 3, 2)
            } else {
                sequences(w, h, n, 3)
            };
            for (what, frames) in &seqs {
                let whole = bits(make(name, set).as_mut(), frames);
                for k in [0, 1, n as usize / 2, n as usize - 1] {
                    let mut a = make(name, set);
                    bits(a.as_mut(), &frames[..k]);
                    let bytes = a.save_state().unwrap().encode();
                    let st = FilterState::decode(&bytes, (w * h) as u64).unwrap();
                    let mut b = make(name, set);
                    b.load_state(&st).unwrap();
                    let rest = bits(b.as_mut(), &frames[k..]);
                    assert!(
                        rest == whole[k..],
                        "{name} {set:?}, {what}: resumed after frame {k}"
                    );
                }
            }
        }
    }

    /// A state goes only into the filter, parameters and layout it came from; a refused
    /// load leaves the filter as it was. A windowed filter says it cannot save.
    #[test]
    fn a_state_is_refused_by_any_other_filter() {
        let frames = &sequences(9, 5, 3, 1)[1].1;
        let mut taa = make("taa", &[]);
        bits(taa.as_mut(), frames);
        let st = taa.save_state().unwrap();
        for (name, set) in [
            ("phlm", &[][..]),
            ("taa", &["alpha=0.1"][..]),
            ("passthrough", &[][..]),
        ] {
            let e = make(name, set).load_state(&st).unwrap_err();
            assert!(matches!(e, StateError::Mismatch { .. }), "{name}: {e}");
        }
        let st = make("traa", &["variant=baseline"]).save_state().unwrap();
        assert!(make("traa", &[]).load_state(&st).is_err());
        // A forged state whose planes do not fit is refused, and the filter keeps its own.
        let mut forged = taa.save_state().unwrap();
        forged.planes.pop();
        let mut c = make("taa", &[]);
        bits(c.as_mut(), &frames[..2]);
        let before = c.save_state().unwrap();
        let e = c.load_state(&forged).unwrap_err().to_string();
        assert!(e.contains("planes"), "{e}");
        assert_eq!(c.save_state().unwrap(), before);
        let e = make("pixel_trace", &[]).save_state().unwrap_err();
        assert!(matches!(e, StateError::Unsupported { .. }), "{e}");
    }
}
