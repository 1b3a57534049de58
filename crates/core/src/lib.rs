//! afterimage's core: the frame model ([`frame`]), image I/O ([`io`]), procedural test
//! scenes ([`scene`]), per-pixel kernels ([`kernels`]), the filters ([`filters`]) behind one
//! interface ([`pipeline`]) and quality metrics ([`metrics`]). Nothing here knows of an
//! async runtime, the network or a GPU: the `afterimage-backend`, `afterimage-server` and
//! `afterimage` crates build on it. `docs/ARCHITECTURE.md` maps the layers.

#![forbid(unsafe_code)]
#![warn(missing_docs)]
// Planar kernels index several planes (and rows) with the same `x`; a range loop says that
// more plainly than zipped iterators.
#![allow(clippy::needless_range_loop)]

/// `Display` for types with a `name()`: each prints as its name. (Defined before the
/// modules so that each of them can use it.)
macro_rules! display_name {
    ($($ty:ty),+) => {
        $(impl std::fmt::Display for $ty {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                f.write_str(self.name())
            }
        })+
    };
}

/// `AddAssign` field by field, each with its own `+=`. (Defined before the modules so
/// that each of them can use it.)
macro_rules! add_assign_fields {
    ($ty:ty { $($field:ident),+ }) => {
        impl std::ops::AddAssign for $ty {
            fn add_assign(&mut self, o: $ty) {
                $(self.$field += o.$field;)+
            }
        }
    };
}

pub mod echo;
pub mod filters;
pub mod frame;
pub mod io;
pub mod kernels;
pub mod metrics;
pub mod pipeline;
pub mod rng;
pub mod scene;
pub mod tolerance;
