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
