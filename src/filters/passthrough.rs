//! `passthrough`: the input colour, repaired (non-finite and negative samples replaced).
//! The no-anti-aliasing baseline every other filter is measured against.

use crate::filter_params;
use crate::frame::{ChannelKind, ChannelSet, Frame};
use crate::pipeline::{check_needs, prepare, Filter, FilterError, FilterKind, Output, PixelCounts, Recorder};
use serde_json::Value;

filter_params! {
    /// `passthrough` has no parameters.
    pub struct Params {}
}

/// The passthrough filter (stateless).
#[derive(Debug, Default)]
pub struct Passthrough;

impl FilterKind for Passthrough {
    const NAME: &'static str = "passthrough";
    const SUMMARY: &'static str = "the input colour, repaired: the no-AA baseline";
    const STAGES: &'static [&'static str] = &["repair", "copy"];
    type Params = Params;
    fn needs() -> ChannelSet {
        ChannelSet::of(&[ChannelKind::Color])
    }
    fn uses() -> ChannelSet {
        Self::needs()
    }
    fn state_bytes_per_pixel(_: &Params) -> usize {
        0
    }
    fn new(_: Params) -> Self {
        Passthrough
    }
}

impl Filter for Passthrough {
    fn name(&self) -> &'static str {
        Self::NAME
    }
    fn params(&self) -> Value {
        Value::Object(crate::pipeline::params::to_json(&Params {}))
    }
    fn process(&mut self, frame: &Frame) -> Result<Output, FilterError> {
        check_needs(Self::NAME, Self::needs(), frame)?;
        let mut rec = Recorder::new();
        let inp = prepare(frame, Self::uses(), &mut rec)?;
        let color = rec.run("copy", || inp.color.into_owned());
        Ok(Output {
            color,
            record: rec.finish(
                Self::NAME,
                frame.meta.index,
                PixelCounts::default(),
                inp.counts,
                0,
            ),
        })
    }
    fn reset(&mut self) {}
    fn state_bytes(&self) -> usize {
        0
    }
}
