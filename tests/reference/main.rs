//! The `reference` test crate: one binary for the modules below (linking one test binary per
//! file cost most of the suite's build). Each module is one former test file.

mod backward;
mod density_budget;
mod forward;
mod lpm_geometry;
mod mip;
mod spacetime;
mod surfel;
mod surfel_backward;
